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
    """

    tag: int
    state: Callable = field(compare=False)
    kinds = ("state", "state")


BoundaryCondition = Union[Traction, Velocity, Absorbing, Symmetry, Slider, OuterState]

#: boundary conditions whose power counts as "radiated" in the energy budget
RADIATING = (Absorbing, OuterState)
