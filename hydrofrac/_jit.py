"""Compilation helpers: numba when it is installed (Debian's python3-numba), plain
Python otherwise (same results, much slower).  Compiled code is cached next to the
sources (``__pycache__``), so only the first run after a change pays the compile time."""
from __future__ import annotations

import numpy as np

try:
    import numba
except ImportError:  # pragma: no cover - numba is a listed dependency
    numba = None

HAVE_NUMBA = numba is not None


#: floating-point flags of the compiled kernels: reassociation and FMA contraction let
#: LLVM vectorise the small dense loops; NaN and Inf keep their IEEE meaning (no
#: "nnan"/"ninf"), so a blow-up still shows as NaN in the energy check.
FASTMATH = {"contract", "reassoc", "nsz", "arcp"}


def njit(fn=None, *, exact=False):
    """``numba.njit`` (cached, numpy error model: no Python-style zero-division checks),
    or ``fn`` itself without numba.  ``exact=True`` (as ``@njit(exact=True)``) compiles without
    the :data:`FASTMATH` flags, so that the arithmetic is NumPy's operation for operation, bit
    for bit (for a pass that replaces NumPy code whose results decide thresholds)."""
    if fn is None:
        return lambda f: njit(f, exact=exact)
    if not HAVE_NUMBA:
        return fn
    return numba.njit(cache=True, error_model="numpy", fastmath=set() if exact else FASTMATH)(fn)


class _LazyUfunc:
    """A numba ufunc built at its first call: loading one from the cache takes ~50 ms, and a
    run calls few of the ufuncs a module defines (hydrofrac.riemann has 14)."""

    def __init__(self, point_fn, signatures):
        self._args = (point_fn, list(signatures))
        self._ufunc = None
        self.__doc__ = point_fn.__doc__

    def __call__(self, *args, **kwargs):
        if self._ufunc is None:
            point_fn, signatures = self._args
            self._ufunc = numba.vectorize(signatures, cache=True)(point_fn.py_func)
        return self._ufunc(*args, **kwargs)


def vectorize(point_fn, signatures):
    """A broadcasting ufunc made from a scalar point function (compiled with numba, when first
    called)."""
    if not HAVE_NUMBA:
        return np.vectorize(point_fn, otypes=[float])
    return _LazyUfunc(point_fn, signatures)


if HAVE_NUMBA:
    from llvmlite import ir
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic

    @intrinsic
    def prefetch(typingctx, arr, flat_index):
        """Hint the CPU to fetch the cache line holding element ``flat_index`` of the
        C-contiguous array ``arr`` (LLVM ``llvm.prefetch``: read, keep in all levels).  A
        hint only: no effect on results, and no fault for an index past the end."""
        if not isinstance(arr, types.Array) or not isinstance(flat_index, types.Integer):
            return None

        def codegen(context, builder, signature, args):
            ary = context.make_array(signature.args[0])(context, builder, args[0])
            ptr = builder.gep(ary.data, [args[1]])
            i8p, i32 = ir.IntType(8).as_pointer(), ir.IntType(32)
            fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                                                "llvm.prefetch.p0i8")
            builder.call(fn, [builder.bitcast(ptr, i8p), i32(0), i32(3), i32(1)])
            return context.get_dummy_value()

        return types.void(arr, flat_index), codegen
else:  # pragma: no cover
    def prefetch(arr, flat_index):
        pass
