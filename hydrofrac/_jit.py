"""Compilation helpers: numba when it is installed (Debian's python3-numba), plain
Python otherwise (same results, much slower).  Compiled code is cached in
``$HYDROFRAC_CACHE/numba-<key>`` (default ``~/.cache/hydrofrac``), the key a hash of every
module's source in ``hydrofrac/`` (:func:`use_keyed_cache`), so only the first run after a change
pays the compile time, and no run uses code compiled from older sources."""
from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

try:
    import numba
except ImportError:  # pragma: no cover - numba is a listed dependency
    numba = None

HAVE_NUMBA = numba is not None


def writable(path: Path) -> bool:
    """Whether the folder ``path`` exists, or can be made, and a file can be written in it."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path):
            return True
    except (OSError, RuntimeError, KeyError):
        return False


def _temp_root() -> Path:
    return Path(tempfile.gettempdir()) / f"hydrofrac-{os.getuid()}"


def cache_root() -> Path:
    """The folder of this package's compiled caches: ``$HYDROFRAC_CACHE``, by default
    ``~/.cache/hydrofrac``, or a per-user folder in the temp dir where the home cannot be
    written (a compute node that mounts it read-only).  A set folder that cannot be written
    is an error."""
    d = os.environ.get("HYDROFRAC_CACHE")
    if d:
        if not writable(Path(d)):
            raise OSError(f"HYDROFRAC_CACHE={d} cannot be written: set it to a writable folder, or unset it")
        return Path(d)
    try:
        home = Path.home() / ".cache" / "hydrofrac"
    except (RuntimeError, KeyError):  # (no home)
        home = None
    if home is not None and writable(home):
        return home
    path = _temp_root()
    path.mkdir(parents=True, exist_ok=True)
    return path


def source_key(*folders) -> str:
    """A hash of the sources of every module in ``folders``: the compiled ones, and the others
    too, since numba freezes the values of the globals a compiled function reads (a material
    constant, a table) into its code."""
    h = hashlib.sha256()
    for folder in folders:
        for f in sorted(Path(folder).glob("*.py")):
            h.update(f"{Path(folder).name}/{f.name}".encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:16]


#: numba caches of other sources are removed after this many seconds unused
STALE_CACHE_S = 7 * 86400


def use_keyed_cache(*folders) -> None:
    """Cache numba's compiled functions in a folder keyed by :func:`source_key` of ``folders``
    (under ``$NUMBA_CACHE_DIR`` if set, else :func:`cache_root`).

    A compiled kernel holds the code of the functions it calls (numba inlines them), but numba's
    cache checks only the kernel's own file.  A kernel cached before an edit of
    ``hydrofrac/riemann.py`` would therefore go on running the old formula (seen: the interface
    kernels kept the point functions' fast-math code after they were made exact).  With the key,
    an edit of any module in ``folders`` compiles every kernel again, once."""
    if not HAVE_NUMBA:
        return
    name = f"numba-{source_key(*folders)}"
    base = os.environ.get("NUMBA_CACHE_DIR", "")
    if Path(base).name.startswith("numba-"):  # (set by a parent process: its base)
        base = str(Path(base).parent)
    if base and not writable(Path(base) / name):
        raise OSError(f"NUMBA_CACHE_DIR={os.environ['NUMBA_CACHE_DIR']} cannot be written: set it to a writable "
                      f"folder, or unset it")
    base = Path(base) if base else cache_root()
    path = base / name
    path.mkdir(parents=True, exist_ok=True)
    now = time.time()
    for old in base.glob("numba-*"):  # (the caches of sources long gone)
        try:
            if old.name != name and now - old.stat().st_mtime > STALE_CACHE_S:
                shutil.rmtree(old, ignore_errors=True)
        except OSError:
            pass
    try:
        os.utime(path)
    except OSError:
        pass
    # (both: numba re-reads its settings from the environment when that changes)
    os.environ["NUMBA_CACHE_DIR"] = str(path)
    numba.config.CACHE_DIR = str(path)


#: the folder whose modules key the cache: ``hydrofrac/``, whose functions and constants the
#: kernels inline.  A kernel elsewhere (``meshes/patch.py``, a study in ``postprocess/``) reads
#: only its own file, which numba's cache checks itself, and ``hydrofrac/``; an edit of the
#: forms (``forms/``, for FFCx) compiles no kernel again
SOURCES = [Path(__file__).parent]
use_keyed_cache(*SOURCES)


#: seconds this process spent compiling kernels: numba's compiles (not its cache loads) and the
#: C library's (:mod:`hydrofrac.native`); a run reports what fell inside its time loop
_COMPILED = {"s": 0.0}


def compile_seconds() -> float:
    """Seconds this process has spent compiling kernels so far."""
    return _COMPILED["s"]


def add_compile_seconds(seconds: float) -> None:
    _COMPILED["s"] += seconds


if HAVE_NUMBA:
    from numba.core import event as _event

    class _CompileClock(_event.Listener):
        """Times numba's compiles, once for a kernel and the functions compiled within it."""
        depth, t0 = 0, 0.0

        def on_start(self, event):
            if self.depth == 0:
                self.t0 = time.perf_counter()
            self.depth += 1

        def on_end(self, event):
            self.depth -= 1
            if self.depth == 0:
                add_compile_seconds(time.perf_counter() - self.t0)

    _event.register("numba:compile", _CompileClock())


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
