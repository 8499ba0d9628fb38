"""C kernels, compiled at first use with the machine's C compiler (docs/benchmarks.md,
"Volume kernels in C").

The hot loops of the matrix-free operator (the volume terms with the inverse mass, the
interior facets' upwind fluxes, ADER's corrector) and the energy budget's cell energies, in
``hydrofrac/volume.c``, run in blocks of cells (facets) with the cells in the vector lanes: that
is what lets the compiler use the SIMD units, which the numba kernels' cell-by-cell loops do not.
The other kernels stay in numba.  The compiler is the one DOLFINx already needs for its form
compiler (Debian's libdolfinx-dev depends on g++); ``$CC`` names another.

Which kernels run: ``HYDROFRAC_KERNELS`` = ``c`` (the default) or ``numba`` (the numba kernels
alone).  With ``c``, a compiler that fails is an error that says so; nothing falls back
silently.  The summary names the kernels a run used.

Libraries are cached in ``$HYDROFRAC_CACHE`` (default ``~/.cache/hydrofrac``), one per source,
flags, compiler and CPU (``-march=native``), written atomically, so ranks and runs that start
together are safe.
"""
from __future__ import annotations

import contextlib
import ctypes
import functools
import hashlib
import os
import platform
import subprocess
import time
from pathlib import Path

import numpy as np

from ._jit import add_compile_seconds, cache_root

#: the kernel sets ``HYDROFRAC_KERNELS`` may name
BACKENDS = ("c", "numba")
#: cells per block (vector lanes) of the C volume kernel
LANES = 4
CFLAGS = ("-O3", "-march=native", "-std=c99", "-shared", "-fPIC")
_SOURCE = Path(__file__).with_name("volume.c")


class NativeError(RuntimeError):
    """The C kernels could not be built or loaded."""


def backend() -> str:
    """The kernels to use, from ``HYDROFRAC_KERNELS`` (default ``c``)."""
    b = os.environ.get("HYDROFRAC_KERNELS", "c").strip().lower()
    if b not in BACKENDS:
        raise ValueError(f"HYDROFRAC_KERNELS must be one of {', '.join(BACKENDS)}; got "
                         f"{os.environ['HYDROFRAC_KERNELS']!r}")
    return b


@contextlib.contextmanager
def using(name: str):
    """``HYDROFRAC_KERNELS`` = ``name`` for the solvers made inside the block (a benchmark's
    side-by-side runs of both kernel sets); the variable as it was after it."""
    old = os.environ.get("HYDROFRAC_KERNELS")
    os.environ["HYDROFRAC_KERNELS"] = name
    try:
        yield
    finally:
        if old is None:
            del os.environ["HYDROFRAC_KERNELS"]
        else:
            os.environ["HYDROFRAC_KERNELS"] = old


def _compiler():
    return os.environ.get("CC", "cc")


@functools.lru_cache(maxsize=None)
def _identity() -> str:
    """What a cached library depends on besides its source: compiler, its version, CPU."""
    cc = _compiler()
    try:
        version = subprocess.run([cc, "--version"], capture_output=True, text=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError) as err:
        raise NativeError(f"no C compiler {cc!r} ({err}); install one (gcc), set CC, or run with "
                          "HYDROFRAC_KERNELS=numba") from None
    cpu = ""
    try:
        with open("/proc/cpuinfo") as f:
            cpu = "".join(line for line in f if line.startswith(("model name", "flags")))[:4096]
    except OSError:
        pass
    return "\n".join([cc, version, platform.machine(), cpu, " ".join(CFLAGS)])


@functools.lru_cache(maxsize=None)
def _library(defines: tuple) -> ctypes.CDLL:
    source = _SOURCE.read_text()
    flags = list(CFLAGS) + [f"-D{k}={v}" for k, v in defines]
    key = hashlib.sha256("\n".join([source, " ".join(flags), _identity()]).encode()).hexdigest()[:20]
    lib = cache_root() / f"{_SOURCE.stem}_{key}.so"
    if not lib.exists():
        tmp = lib.with_name(f"{lib.name}.{platform.node()}.{os.getpid()}.tmp")  # (a cache shared by hosts)
        cmd = [_compiler(), *flags, str(_SOURCE), "-o", str(tmp)]
        t0 = time.perf_counter()
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
        add_compile_seconds(time.perf_counter() - t0)
        if res.returncode != 0:
            tmp.unlink(missing_ok=True)
            raise NativeError(f"compiling {_SOURCE.name} failed ({' '.join(cmd)}):\n{res.stderr.strip()}\n"
                              "Fix the compiler, or run with HYDROFRAC_KERNELS=numba")
        os.replace(tmp, lib)
    return ctypes.CDLL(str(lib))


def describe() -> str:
    """The summary's words for the C kernels."""
    return (f"C volume, facet, ADER, energy and dissipation kernels ({_compiler()} {' '.join(CFLAGS[:2])}, {LANES} cells per block)"
            " + numba")


def _check(name, arrays):
    """Raise unless each (array, dtype, shape or None) is contiguous with that dtype and shape:
    the kernels get raw pointers."""
    for a, dt, shape in arrays:
        if a.dtype != dt or not a.flags.c_contiguous or (shape is not None and a.shape != shape):
            raise NativeError(f"the C {name} kernel got an array of {a.dtype} {a.shape} (contiguous: "
                              f"{a.flags.c_contiguous}); expected {np.dtype(dt)} {shape}")


def _function(nb, nk, name, argtypes):
    fn = getattr(_library((("NB", int(nb)), ("NK", int(nk)), ("W", LANES))), name)
    fn.argtypes, fn.restype = argtypes, None
    return fn


_P, _N = ctypes.c_void_p, ctypes.c_long


def _chain_size(nb, nk):
    """The length of :func:`hydrofrac.matfree.taylor_chain` at degree nk - 1."""
    from .element import dimension as dim
    p = nk - 1
    return sum(2 * dim(p - m) * dim(p - m + 1) + nb * dim(p - m) for m in range(1, p + 1))


class VolumeKernel:
    """The C ``volume_and_inverse`` for ``nb`` basis functions per cell (``nk`` per facet)
    and ``n`` owned cells, bound to one operator's constant arrays: ``kernel(out, R, X)``
    computes out (owned values) = M^{-1}(R + volume terms of X) and clears R, as the numba
    kernel does for a cell-contiguous space."""

    def __init__(self, nb: int, nk: int, n: int, S0, S1, Jinv, invdet, Minv_ref, mat, Btab):
        self._fn = _function(nb, nk, "volume_and_inverse", [_P, _P, _P, _N, _P, _P, _P, _P, _P, _P, _P])
        n = int(n)
        _check("volume", [(S0, np.float64, (nb, nb)), (S1, np.float64, (nb, nb)), (Jinv, np.float64, None),
                          (invdet, np.float64, None), (Minv_ref, np.float64, (nb, nb)), (mat, np.int32, None),
                          (Btab, np.float64, None)])
        if Jinv.shape[0] < n or invdet.shape[0] < n or mat.shape[0] < n or Btab.shape[1:] != (11,) \
                or (n and int(mat[:n].max()) >= Btab.shape[0]):
            raise NativeError("the C volume kernel's cell data do not cover the owned cells")
        self._arrays = (S0, S1, Jinv, invdet, Minv_ref, mat, Btab)  # (kept alive: the pointers below)
        self._n, self._size, self._Rshape = n, n * nb * 5, (n, nb, 5)
        self._const = tuple(a.ctypes.data for a in self._arrays)

    def __call__(self, out, R, X):
        _check("volume", [(R, np.float64, self._Rshape)])
        _check_values(out, X, self._size, "volume")
        self._fn(out.ctypes.data, R.ctypes.data, X.ctypes.data, self._n, *self._const)


class AderKernel(VolumeKernel):
    """The C ``ader_corrector`` (ADER's corrector and next predictor), bound to the same
    constant arrays as :class:`VolumeKernel` plus the predictor's matrices in the degrees its
    terms have (``chain``: :func:`hydrofrac.matfree.taylor_chain`): ``kernel(x, I, R, dt, order)``."""

    def __init__(self, nb: int, nk: int, n: int, S0, S1, Jinv, invdet, Minv_ref, mat, Btab, chain):
        super().__init__(nb, nk, n, S0, S1, Jinv, invdet, Minv_ref, mat, Btab)
        _check("ADER", [(chain, np.float64, (_chain_size(nb, nk),))])
        self._fn = _function(nb, nk, "ader_corrector", [_P, _P, _P, _N] + [_P] * 8 + [ctypes.c_double, _N])
        self._arrays += (chain,)
        self._const = tuple(a.ctypes.data for a in self._arrays)

    def __call__(self, x, I, R, dt, order):
        _check("ADER", [(R, np.float64, self._Rshape)])
        _check_values(x, I, self._size, "ADER")
        if not I.flags.writeable:
            raise NativeError("the C ADER kernel's predictor array is read-only")
        self._fn(x.ctypes.data, I.ctypes.data, R.ctypes.data, self._n, *self._const, float(dt), int(order))


class TaylorKernel:
    """The C ``taylor_values``: ``kernel(Q, X, cells, taus, order)`` writes ADER's cell-local
    Taylor predictor from ``X`` (local values, ghosts included) at the times ``taus`` into the
    rows of ``Q`` (len(taus), X.size), on the listed ``cells`` (owned or ghost), for a
    cell-contiguous space; the cell data (Jinv, mat) cover every local cell."""

    MAX_TIMES = 4  # (MAXT in volume.c)

    def __init__(self, nb: int, nk: int, ncells: int, Jinv, mat, Btab, chain):
        self._fn = _function(nb, nk, "taylor_values", [_P, _N, _P, _N, _P, _P, _P, _P, _P, _P, _N, _N])
        _check("Taylor", [(Jinv, np.float64, None), (mat, np.int32, None), (Btab, np.float64, None),
                          (chain, np.float64, (_chain_size(nb, nk),))])
        ncells = int(ncells)
        if Jinv.shape[0] < ncells or mat.shape[0] < ncells or Btab.shape[1:] != (11,) \
                or (ncells and int(mat[:ncells].max()) >= Btab.shape[0]):
            raise NativeError("the C Taylor kernel's cell data do not cover the local cells")
        self._arrays = (Jinv, mat, Btab, chain)  # (kept alive: the pointers below)
        self._ncells, self._size = ncells, ncells * nb * 5
        self._const = tuple(a.ctypes.data for a in self._arrays)

    def __call__(self, Q, X, cells, taus, order):
        taus = np.ascontiguousarray(taus, dtype=np.float64)
        _check("Taylor", [(Q, np.float64, (taus.size, X.size)), (cells, np.int64, None)])
        _check_values(Q.reshape(-1), X, self._size, "Taylor")
        if taus.size > self.MAX_TIMES:
            raise NativeError(f"the C Taylor kernel takes at most {self.MAX_TIMES} times; got {taus.size}")
        if cells.size and (int(cells.max()) >= self._ncells or int(cells.min()) < 0):
            raise NativeError("the C Taylor kernel got a cell outside the local cells")
        self._fn(Q.ctypes.data, X.size, X.ctypes.data, cells.size, cells.ctypes.data, *self._const,
                 taus.ctypes.data, taus.size, int(order))


def _check_values(out, X, size, name):
    for a in (out, X):
        if a.dtype != np.float64 or not a.flags.c_contiguous or a.size < size:
            raise NativeError(f"the C {name} kernel needs contiguous float64 arrays of >= {size} values; got "
                              f"{a.dtype} {a.shape}")
    if not out.flags.writeable:
        raise NativeError(f"the C {name} kernel's output array is read-only")


class FacetKernel:
    """The C ``facet_fluxes``: ``kernel(R, X)`` adds the upwind flux corrections of the
    listed interior facets to R on their owned sides, as the numba kernel does for a
    cell-contiguous space.  ``coef`` (pairs, 16) and ``pair`` (facets,): the bonded Riemann
    solution's coefficients per impedance pair (:func:`bonded_coefficients`)."""

    def __init__(self, nb: int, nk: int, ncells: int, nowned: int, fcells, fcodes, normal, length, fnodes, Mf,
                 coef, pair):
        self._fn = _function(nb, nk, "facet_fluxes", [_P, _P, _N, _P, _P, _P, _P, _P, _P, _P, _P, _N])
        nf = fcells.shape[0]
        _check("facet", [(fcells, np.int64, (nf, 2)), (fcodes, np.int64, (nf, 2)), (normal, np.float64, (nf, 2)),
                         (length, np.float64, (nf,)), (fnodes, np.int64, (9, nk)), (Mf, np.float64, (nk, nk)),
                         (coef, np.float64, None), (pair, np.int32, (nf,))])
        if nf and (fcells.max() >= ncells or fcells.min() < 0 or fcodes.min() < 0 or fcodes.max() > 8
                   or fnodes.max() >= nb or pair.max() >= coef.shape[0] or coef.shape[1:] != (16,)):
            raise NativeError("the C facet kernel's facet data point outside its cells")
        self._arrays = (fcells, fcodes, normal, length, fnodes, Mf, coef, pair)
        self._nf, self._nowned = nf, int(nowned)
        self._size, self._Rshape = int(ncells) * nb * 5, (int(nowned), nb, 5)
        self._const = tuple(a.ctypes.data for a in self._arrays)

    def __call__(self, R, X):
        _check("facet", [(R, np.float64, self._Rshape)])
        _check_values(R.reshape(-1), X, 0, "facet")
        if X.size < self._size:
            raise NativeError(f"the C facet kernel needs the values of all {self._size // 5} nodes, ghosts "
                              f"included; got {X.size // 5}")
        self._fn(R.ctypes.data, X.ctypes.data, self._nf, *self._const, self._nowned)


class DissipationKernel:
    """The C ``facet_dissipation``: ``kernel(X)`` is the upwind flux's dissipation rate on the
    owned listed interior facets (``own``), as the numba kernel ``facet_dissipation`` computes it
    for a cell-contiguous space; per impedance pair (:func:`impedance_pairs`) the
    coefficients Z+ Z- / (Z+ + Z-) and 1 / (Z+ + Z-) of the normal and tangential jumps."""

    def __init__(self, nb: int, nk: int, ncells: int, fcells, fcodes, normal, length, fnodes, Mf, own,
                 Zpn, Zmn, Zpt, Zmt):
        fn = _function(nb, nk, "facet_dissipation", [_P, _N] + [_P] * 9)
        fn.restype = ctypes.c_double
        self._fn = fn
        nf = fcells.shape[0]
        own = np.ascontiguousarray(own, dtype=np.uint8)
        table, pair = impedance_pairs(Zpn, Zmn, Zpt, Zmt)
        zpn, zmn, zpt, zmt = table.T
        dcoef = np.ascontiguousarray(np.stack([zpn * zmn / (zpn + zmn), zpt * zmt / (zpt + zmt),
                                               1.0 / (zpn + zmn), 1.0 / (zpt + zmt)], axis=1))
        _check("dissipation", [(fcells, np.int64, (nf, 2)), (fcodes, np.int64, (nf, 2)),
                               (normal, np.float64, (nf, 2)), (length, np.float64, (nf,)),
                               (fnodes, np.int64, (9, nk)), (Mf, np.float64, (nk, nk)), (own, np.uint8, (nf,))])
        if nf and (fcells.max() >= ncells or fcells.min() < 0 or fcodes.min() < 0 or fcodes.max() > 8
                   or fnodes.max() >= nb):
            raise NativeError("the C dissipation kernel's facet data point outside its cells")
        self._arrays = (fcells, fcodes, normal, length, fnodes, Mf, dcoef, pair, own)
        self._nf, self._size = nf, int(ncells) * nb * 5
        self._const = tuple(a.ctypes.data for a in self._arrays)

    def __call__(self, X):
        if X.dtype != np.float64 or not X.flags.c_contiguous or X.size < self._size:
            raise NativeError(f"the C dissipation kernel needs the values of all {self._size // 5} nodes, ghosts "
                              f"included, contiguous float64; got {X.dtype} {X.shape}")
        return float(self._fn(X.ctypes.data, self._nf, *self._const))


class EnergyKernel:
    """The C ``cell_energies``: ``kernel(X, X0)`` is the (kinetic, strain) energy of X - X0 on
    the owned cells (X0: the uniform initial state, 5 values), as the numba kernel computes it
    for a cell-contiguous space; ``Ctab[mat[c]]`` = rho, rho and the 3x3 compliance block."""

    def __init__(self, nb: int, nk: int, n: int, Mref, absdet, mat, Ctab):
        self._fn = _function(nb, nk, "cell_energies", [_P, _P, _P, _N, _P, _P, _P, _P])
        n = int(n)
        _check("energy", [(Mref, np.float64, (nb, nb)), (absdet, np.float64, None), (mat, np.int32, None),
                          (Ctab, np.float64, None)])
        if absdet.shape[0] < n or mat.shape[0] < n or Ctab.shape[1:] != (11,) \
                or (n and int(mat[:n].max()) >= Ctab.shape[0]):
            raise NativeError("the C energy kernel's cell data do not cover the owned cells")
        self._arrays = (Mref, absdet, mat, Ctab)  # (kept alive: the pointers below)
        self._n, self._size = n, n * nb * 5
        self._out = np.zeros(2)
        self._const = tuple(a.ctypes.data for a in self._arrays)

    def __call__(self, X, X0):
        X0 = np.ascontiguousarray(X0, dtype=np.float64)
        if X.dtype != np.float64 or not X.flags.c_contiguous or X.size < self._size or X0.shape != (5,):
            raise NativeError(f"the C energy kernel needs a contiguous float64 array of >= {self._size} values "
                              f"and the 5 initial values; got {X.dtype} {X.shape} and {X0.shape}")
        self._fn(self._out.ctypes.data, X.ctypes.data, X0.ctypes.data, self._n, *self._const)
        return float(self._out[0]), float(self._out[1])


def impedance_pairs(Zpn, Zmn, Zpt, Zmt):
    """(table (pairs, 4), pair (facets,) int32): the distinct (Z+n, Z-n, Z+t, Z-t) of the facets
    and each facet's row in that table; no facet: one row of ones."""
    quad = np.stack([Zpn, Zmn, Zpt, Zmt], axis=1)
    if quad.shape[0] == 0:
        return np.ones((1, 4)), np.zeros(0, dtype=np.int32)
    if (quad == quad[0]).all():  # one material: one pair, without np.unique's sort (6 ms at 8k facets)
        return quad[:1], np.zeros(quad.shape[0], dtype=np.int32)
    table, pair = np.unique(quad, axis=0, return_inverse=True)
    return table, np.ascontiguousarray(pair.reshape(-1), dtype=np.int32)


def bonded_coefficients(Zpn, Zmn, Zpt, Zmt, bonded_jump_pt):
    """(coef (pairs, 16), pair (facets,) int32): the coefficients of the jumps [v] and [s] in
    ``bonded_jump_pt``'s four corrections, for the normal (impedances Zpn, Zmn) and the
    tangential component (Zpt, Zmt) of each distinct impedance pair (:func:`impedance_pairs`),
    from the formula itself on unit jumps (it is linear in them)."""
    table, pair = impedance_pairs(Zpn, Zmn, Zpt, Zmt)
    coef = np.empty((table.shape[0], 16))
    for q, (zpn, zmn, zpt, zmt) in enumerate(table):
        coef[q] = (bonded_jump_pt(1.0, 0.0, zpn, zmn) + bonded_jump_pt(0.0, 1.0, zpn, zmn)
                   + bonded_jump_pt(1.0, 0.0, zpt, zmt) + bonded_jump_pt(0.0, 1.0, zpt, zmt))
    return np.ascontiguousarray(coef), np.ascontiguousarray(pair.reshape(-1), dtype=np.int32)
