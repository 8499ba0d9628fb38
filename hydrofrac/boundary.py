"""Boundary conditions and load histories (frozen, validated on construction).

Every boundary condition is a Riemann problem between the interior trace and an
outer state (see :mod:`hydrofrac.forms.elastodynamics`).  ``kinds`` gives, for
the (normal, tangential) components, what the outer state prescribes.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence, Union

import numpy as np

Stress = tuple  # ((sxx, sxy), (sxy, syy))
ZERO_STRESS = ((0.0, 0.0), (0.0, 0.0))


@dataclass(frozen=True)
class PiecewiseLinear:
    """Piecewise-linear history g(t) through (times[i], values[i]); constant outside."""

    times: Sequence[float]
    values: Sequence[float]

    def __post_init__(self):
        t = np.asarray(self.times, dtype=float)
        v = np.asarray(self.values, dtype=float)
        if t.ndim != 1 or t.size == 0 or t.shape != v.shape:
            raise ValueError(f"history needs equally long, non-empty times and values; got {t.size} and {v.size}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
            raise ValueError("history times and values must be finite")
        if np.any(np.diff(t) <= 0):
            i = int(np.argmax(np.diff(t) <= 0))
            raise ValueError(f"history times must increase strictly; times[{i}] = {t[i]} is followed by {t[i + 1]}")
        object.__setattr__(self, "times", tuple(float(x) for x in t))
        object.__setattr__(self, "values", tuple(float(x) for x in v))

    def __call__(self, t):
        if isinstance(t, (float, int)):  # scalar fast path (called every Runge-Kutta stage)
            ts, vs = self.times, self.values
            if t <= ts[0]:
                return vs[0]
            if t >= ts[-1]:
                return vs[-1]
            i = bisect.bisect_right(ts, t)
            w = (t - ts[i - 1]) / (ts[i] - ts[i - 1])
            return vs[i - 1] + w * (vs[i] - vs[i - 1])
        return float(np.interp(t, self.times, self.values))

    @staticmethod
    def constant(value):
        return PiecewiseLinear((0.0,), (float(value),))


def _stress(s):
    a = np.asarray(s, dtype=float)
    if a.shape != (2, 2) or not np.allclose(a, a.T) or not np.all(np.isfinite(a)):
        raise ValueError(f"a stress must be a finite symmetric 2x2 matrix; got {s!r}")
    return tuple(tuple(float(x) for x in row) for row in a)


@dataclass(frozen=True)
class Traction:
    """Prescribed traction S = stress . n - p(t) n.

    ``pressure`` is a number or a :class:`PiecewiseLinear` history p(t) [Pa].
    """

    tag: int
    stress: Stress = ZERO_STRESS
    pressure: Union[float, PiecewiseLinear] = 0.0
    kinds = ("traction", "traction")

    def __post_init__(self):
        object.__setattr__(self, "stress", _stress(self.stress))
        if not isinstance(self.pressure, PiecewiseLinear):
            object.__setattr__(self, "pressure", PiecewiseLinear.constant(self.pressure))


@dataclass(frozen=True)
class Velocity:
    """Prescribed velocity V = value * g(t)."""

    tag: int
    value: tuple = (0.0, 0.0)
    history: Optional[PiecewiseLinear] = None
    kinds = ("velocity", "velocity")


@dataclass(frozen=True)
class Absorbing:
    """Non-reflecting boundary: the outer state is at rest under ``stress`` (the initial
    stress), with the interior impedances, so outgoing waves leave without reflection
    at normal incidence."""

    tag: int
    stress: Stress = ZERO_STRESS
    kinds = ("state", "state")

    def __post_init__(self):
        object.__setattr__(self, "stress", _stress(self.stress))


@dataclass(frozen=True)
class Symmetry:
    """Mirror plane: zero normal velocity, zero tangential traction."""

    tag: int
    kinds = ("velocity", "traction")


@dataclass(frozen=True)
class Slider:
    """Zero normal traction, zero tangential velocity (the mirror plane of a shear wave)."""

    tag: int
    kinds = ("traction", "velocity")


@dataclass(frozen=True)
class OuterState:
    """Characteristic boundary with a given outer state, e.g. an exact solution.

    ``state(x, t)`` takes points (3, m) and returns (5, m): (v_x, v_y, s_xx, s_yy, s_xy).
    ``point``, optional: the same state as a compiled (numba ``njit``) point function
    ``point(x, y, t) -> (v_x, v_y, s_xx, s_yy, s_xy)``; the matrix-free operator then
    evaluates it inside its compiled code at every stage instead of calling ``state``
    (the solver checks that the two agree).
    """

    tag: int
    state: Callable = field(compare=False)
    point: Optional[Callable] = field(default=None, compare=False)
    kinds = ("state", "state")

    def __post_init__(self):
        if self.point is not None and not hasattr(self.point, "py_func"):
            raise ValueError(f"OuterState(point=...) must be a numba.njit point function point(x, y, t) -> "
                             f"(v_x, v_y, s_xx, s_yy, s_xy); got {self.point!r} (compile it with numba.njit, or "
                             "leave point unset)")


BoundaryCondition = Union[Traction, Velocity, Absorbing, Symmetry, Slider, OuterState]

#: boundary conditions whose power counts as "radiated" in the energy budget
RADIATING = (Absorbing, OuterState)


# ----------------------------------------------------------------------------- boundary data
# What the solver's forms need of the boundary conditions: the facet tags for ds (with the
# traction-free rest of the boundary), and each condition's data as UFL expressions.


def check_boundary_tags(comm, facet_tags, bcs):
    """Each boundary condition has its own tag, and every tag is in the mesh's facet tags."""
    tags = [bc.tag for bc in bcs]
    if len(set(tags)) != len(tags):
        raise ValueError(f"each boundary tag may carry one boundary condition; got tags {tags}")
    if not tags:
        return
    from . import compat
    compat.require_tags(comm, facet_tags, tags, "boundary", "the mesh's facet tags",
                        "fix the tag in the boundary condition or the mesh generator")


def boundary_tags(mesh, facet_tags, bcs):
    """Facet tags for ds: the user's tags plus a fresh tag on exterior facets that
    carry no boundary condition (traction-free). Returns (meshtags, free tag or None)."""
    from mpi4py import MPI

    from . import compat
    tdim = mesh.topology.dim
    ext = compat.exterior_facet_indices(mesh)
    idx = np.zeros(0, dtype=np.int32)
    val = np.zeros(0, dtype=np.int32)
    if facet_tags is not None:
        idx, val = facet_tags.indices, facet_tags.values
    bc_tags = [bc.tag for bc in bcs]
    free = np.setdiff1d(ext, idx[np.isin(val, bc_tags)])
    if mesh.comm.allreduce(free.size, op=MPI.SUM) == 0:
        return facet_tags, None
    free_tag = int(mesh.comm.allreduce(int(val.max()) if val.size else 0, op=MPI.MAX)) + 1
    keep = ~np.isin(idx, free)
    mt = compat.meshtags(mesh, tdim - 1, np.r_[idx[keep], free], np.r_[val[keep], np.full(free.size, free_tag)])
    return mt, free_tag


def ufl_data(bc, n, unit=False, uext=None):
    """Per-component UFL data of a boundary condition.

    unit=False: the constant part; unit=True: the part multiplied by the history;
    uext: outer-state Function/trial for OuterState.
    """
    import ufl

    from .forms import elastodynamics as ef
    t = ef.tangent(n)
    zero = ufl.as_ufl(0.0)
    if isinstance(bc, Traction):
        if unit:
            S = -n  # times p(t)
        else:
            S = ufl.as_matrix(bc.stress) * n
        return (ufl.dot(S, n), ufl.dot(S, t))
    if isinstance(bc, Velocity):
        V = ufl.as_vector(bc.value)
        return (ufl.dot(V, n), ufl.dot(V, t))
    if isinstance(bc, Absorbing):
        S = ufl.as_matrix(bc.stress) * n
        return ((zero, ufl.dot(S, n)), (zero, ufl.dot(S, t)))
    if isinstance(bc, OuterState):
        if uext is None:
            return ((zero, zero), (zero, zero))
        ve, se = ef.fields(uext)
        S = se * n
        return ((ufl.dot(ve, n), ufl.dot(S, n)), (ufl.dot(ve, t), ufl.dot(S, t)))
    return (zero, zero)  # Symmetry, Slider: homogeneous


def point_data(bc, n):
    """What :func:`ufl_data` gives, at facets with unit normals ``n`` (m, 2), as the outer
    (V_n, V_t, S_n, S_t) of :func:`hydrofrac.riemann.boundary_pt` in each facet's frame
    (t = n rotated by +90 degrees): returns (constant part (m, 4), history or None, the
    part it multiplies (m, 4) or None).  An :class:`OuterState`'s data are its state at the
    facet nodes at each time (the matrix-free operator evaluates it)."""
    m = n.shape[0]
    t = np.stack([-n[:, 1], n[:, 0]], axis=1)
    const = np.zeros((m, 4))
    if isinstance(bc, (Traction, Absorbing)):
        S = n @ np.asarray(bc.stress)  # (symmetric) stress . n per facet
        const[:, 2], const[:, 3] = np.einsum("fi,fi->f", S, n), np.einsum("fi,fi->f", S, t)
        if isinstance(bc, Traction) and any(bc.pressure.values):
            unit = np.zeros((m, 4))
            unit[:, 2] = -1.0  # S = - p(t) n
            return const, bc.pressure, unit
    elif isinstance(bc, Velocity):
        V = np.asarray(bc.value, dtype=float)
        const[:, 0], const[:, 1] = n @ V, t @ V
        if bc.history is not None:
            return np.zeros((m, 4)), bc.history, const
    return const, None, None
