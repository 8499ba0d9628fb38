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


def njit(fn):
    """``numba.njit`` (cached, numpy error model: no Python-style zero-division checks),
    or ``fn`` itself without numba."""
    return numba.njit(cache=True, error_model="numpy", fastmath=FASTMATH)(fn) if HAVE_NUMBA else fn


def vectorize(point_fn, signatures):
    """A broadcasting ufunc made from a scalar point function (compiled with numba)."""
    if not HAVE_NUMBA:
        return np.vectorize(point_fn, otypes=[float])
    return numba.vectorize(list(signatures), cache=True)(point_fn.py_func)
