"""Crack-growth direction at a crack tip (model.md §6): the direction that maximises the
effective stress s̆(θ) on trial planes through the tip.

Sampling [our choice, documented]: ``n_angles`` trial directions θ between −``max_angle`` and
+``max_angle`` from the crack's own direction at the tip; on each, the stress is evaluated at
the point a distance ``r`` ahead of the tip along θ, and the traction on the trial plane
through the tip along θ (normal n = (−sin, cos) of the absolute angle) gives
s̆(θ) = sqrt(<s_n>² + (β s_t)²), the effective stress of the damage law (eq. 10, with the
bulk traction in place of the bonded Riemann traction: in a cell they coincide, the field
being continuous there).  The growth direction is the maximiser, refined by a parabola
through the best sample and its neighbours.

:class:`GrowthDriver` grows the tips with remeshing: it inserts the new segments as bonded
paths, has Gmsh remesh the scene and moves fields and interface state to the new mesh
(:mod:`hydrofrac.transfer`).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
from mpi4py import MPI

from . import riemann as rm
from ._jit import njit
from .adapt import RemeshDriver, check_interval
from .material import ROCK
from .probes import fields_at


#: trial directions closer than this [deg] to the plane of a crack that a tip met are not
#: sampled for crossing: those points lie next to the crack met, where its own near field
#: (not the transmitted stress) dominates
FAR_SIDE_MARGIN = 15.0

#: a tip that would stop within SNAP * da of another crack meets it (GrowthDriver._crossing)
SNAP = 0.25

#: the default branching speed [m/s], 0.5 c_R of the paper's rock (docs/model.md §6,
#: "Branching": experiments branch from 0.36 c_R (PMMA microbranches) to about 0.5 c_R
#: (macroscopic branches); the criterion on the exact moving-crack field splits at 0.60 c_s)
BRANCH_SPEED = 0.5 * ROCK.cR


def renshaw_pollard_friction(sigma_n, sigma_p, T0):
    """The smallest friction coefficient for which a crack normal to a frictional interface
    crosses it (Renshaw & Pollard 1995): -σ_n / (T0 - σ_p) = (0.35 + 0.35/μ) / 1.06, with σ_n
    the remote stress normal to the interface (compression < 0), σ_p the one parallel to it
    (normal to the crack) and T0 the tensile strength.  A reference for the crossing study
    and its test, not used by the criterion."""
    return 0.35 / (1.06 * (-sigma_n) / (T0 - sigma_p) - 0.35)


@dataclass(frozen=True)
class GrowthParams:
    """Sampling of the growth criterion: distance ``r`` [m] ahead of the tip, ``n_angles``
    trial directions within ±``max_angle`` [deg] of the crack direction, shear factor β.

    ``fit_window`` [deg]: the maximiser is the vertex of a least-squares parabola through
    the samples within this window around the best sample (0: the three-point parabola).  The
    criterion is flat near its maximum (mode I: s̆ ∝ cos²(θ/2), 0.03 % below the peak at 2°),
    so the fit over many samples keeps the direction from following local noise of the
    discrete near-tip field.  A maximum within ``edge_margin`` [deg] of the window's edge is
    not acted on (the tip waits): the field there is not the tip's own.

    ``direction``: "sampled" (default) takes the maximiser of the sampled s̆(θ); "cod" takes
    the onset from the samples but the angle from the singular near-tip field, with
    K_II/K_I from the crack's own slip and opening within ``r`` behind the tip
    (:func:`cod_direction`; a tip with no grown segment yet uses the samples).
    ``cod_window`` [m]: how far behind the tip opening and slip are correlated (None: ``r``).
    ``cod_relax``: the fraction of that angle taken per extension.  1 turns a straight crack
    by the full predicted kink at once (the mixed-mode test); below 1 the crack turns over
    several extensions towards K_II = 0.  On a grown, kinked crack the full angle can
    overshoot: a kink puts slip of the other sign into the next window, and the paths of
    the full-size intersection problem zigzag with growing amplitude beyond ~1 m with 1;
    with 0.5 they stay within 2° of radial (docs/studies/growth.md).

    Branching (docs/model.md §6, "Branching"): a ready tip whose current speed (its last
    extension's) is at least ``branch_speed`` [m/s] (None: no branching) and whose sampled
    s̆(θ) has two local maxima above the onset, at least ``branch_min_angle`` [deg] apart and
    each standing ``branch_prominence`` (a fraction of the lower one) above the lowest sample
    between them, on either side of the crack's direction and each at least half that angle
    from it (a fork), splits into two tips, one along each maximum."""

    r: float
    n_angles: int = 121
    max_angle: float = 85.0
    beta: float = 1.0
    fit_window: float = 30.0
    edge_margin: float = 5.0
    direction: str = "sampled"
    cod_window: float | None = None
    cod_relax: float = 1.0
    branch_speed: float | None = None
    branch_min_angle: float = 20.0
    branch_prominence: float = 0.02

    def __post_init__(self):
        if not self.r > 0:
            raise ValueError(f"growth sampling distance r must be > 0 m; got {self.r}")
        if self.n_angles < 3:
            raise ValueError(f"growth n_angles must be >= 3; got {self.n_angles}")
        if not 0 < self.max_angle < 180:
            raise ValueError(f"growth max_angle must be in (0, 180) degrees; got {self.max_angle}")
        if not self.beta >= 0:
            raise ValueError(f"growth beta must be >= 0; got {self.beta}")
        if not 0 <= self.fit_window < 180:
            raise ValueError(f"growth fit_window must be in [0, 180) degrees; got {self.fit_window}")
        if self.direction not in ("sampled", "cod"):
            raise ValueError(f"growth direction must be 'sampled' or 'cod'; got {self.direction!r}")
        if self.cod_window is not None and not self.cod_window > 0:
            raise ValueError(f"growth cod_window must be > 0 m (or None for r); got {self.cod_window}")
        if not 0 < self.cod_relax <= 1:
            raise ValueError(f"growth cod_relax must be in (0, 1]; got {self.cod_relax}")
        if self.branch_speed is not None and not self.branch_speed > 0:
            raise ValueError(f"growth branch_speed must be > 0 m/s (or None: no branching); got {self.branch_speed}")
        if not 0 < self.branch_min_angle < 2 * self.max_angle:
            raise ValueError(f"growth branch_min_angle must be in (0, {2 * self.max_angle}) degrees; "
                             f"got {self.branch_min_angle}")
        if not 0 <= self.branch_prominence < 1:
            raise ValueError(f"growth branch_prominence must be in [0, 1); got {self.branch_prominence}")


def effective_stress_profile(solver, tip, direction, params: GrowthParams):
    """(theta [rad, relative to ``direction``], s̆(theta)) sampled as documented above."""
    return effective_stress_profiles(solver, [(tip, direction)], params)[0]


def effective_stress_profiles(solver, tips, params: GrowthParams):
    """:func:`effective_stress_profile` of several (tip, direction) pairs, with one stress
    evaluation for all their sample points (collective; the same values as one by one)."""
    theta = np.radians(np.linspace(-params.max_angle, params.max_angle, params.n_angles))
    if not len(tips):
        return []
    P = np.array([np.asarray(tip, dtype=float) for tip, _ in tips]).reshape(-1, 2)
    D = np.array([np.asarray(d, dtype=float) for _, d in tips]).reshape(-1, 2)
    ang = np.arctan2(D[:, 1], D[:, 0])[:, None] + theta  # (tips, samples), all tips at once
    c, s = np.cos(ang).ravel(), np.sin(ang).ravel()   # t = (c, s) along the trial plane, n = (-s, c) its normal
    X = P.repeat(theta.size, axis=0) + params.r * np.column_stack([c, s])
    # (each tip's samples located once, while it stays)
    F = np.concatenate(fields_at(solver, np.split(X, len(tips))))
    seff = np.empty(F.shape[0])
    _plane_effective_stress(F, c, s, float(params.beta), seff)
    return [(theta, row) for row in seff.reshape(len(tips), theta.size)]


@njit(exact=True)
def _plane_effective_stress(F, c, s, beta, out):
    """out[k] = s̆ of the traction sigma n on the plane through sample k along (c, s) (its
    normal n = (-s, c)), from the fields F[k] = (v_x, v_y, s_xx, s_yy, s_xy); NaN where F is
    (a point outside the mesh).  One pass, operation for operation the NumPy expressions'."""
    for k in range(F.shape[0]):
        sxx, syy, sxy = F[k, 2], F[k, 3], F[k, 4]
        tr_x = -sxx * s[k] + sxy * c[k]
        tr_y = -sxy * s[k] + syy * c[k]
        out[k] = rm.effective_stress_pt(-tr_x * s[k] + tr_y * c[k], tr_x * c[k] + tr_y * s[k], beta)


def growth_direction(solver, tip, direction, params: GrowthParams):
    """Angle [rad] (relative to the crack direction, counter-clockwise positive) that
    maximises s̆, and the maximum value [Pa]."""
    return profile_maximum(*effective_stress_profile(solver, tip, direction, params), params)


def profile_maximum(theta, s, params: GrowthParams):
    """(theta*, s*) of a sampled profile as ``params`` asks: the least-squares parabola over
    ``fit_window`` (:func:`argmax_fit`), or the three-point parabola when it is 0."""
    if params.fit_window > 0:
        return argmax_fit(theta, s, np.radians(params.fit_window))
    return argmax_parabola(theta, s)


def separated_maxima(theta, s, threshold, min_sep, prominence=0.02, edge=None, fork=False):
    """The two largest local maxima of sampled ``s(theta)`` that reach ``threshold``, lie at
    least ``min_sep`` [rad] apart, and each stand ``prominence`` (a fraction of the lower
    maximum) above the lowest sample between them; maxima within ``edge`` [rad] of the window's
    ends are not counted.  ``fork``: only a pair on either side of theta = 0 (the crack's
    direction), each at least ``min_sep / 2`` from it, counts.  Returns [(theta*, s*), (theta*, s*)] ordered by |theta*| (then
    theta* > 0 first), each refined by a parabola, or [] when there are not two."""
    s = np.asarray(s, float)
    n = len(s)
    lo = theta[0] + (edge or 0.0)
    hi = theta[-1] - (edge or 0.0)
    peaks = [k for k in range(1, n - 1) if s[k] >= threshold and s[k] > s[k - 1] and s[k] >= s[k + 1]
             and lo <= theta[k] <= hi]
    peaks.sort(key=lambda k: -s[k])
    for a_ in range(len(peaks)):
        for b_ in range(a_ + 1, len(peaks)):
            i, j = sorted((peaks[a_], peaks[b_]))
            if theta[j] - theta[i] < min_sep or (fork and not theta[i] <= -0.5 * min_sep < 0.5 * min_sep <= theta[j]):
                continue
            low = s[i:j + 1].min()
            if min(s[i], s[j]) - low < prominence * min(s[i], s[j]):
                continue
            out = []
            for k in (i, j):
                sub = slice(max(k - 1, 0), min(k + 2, n))
                t_, v_ = argmax_parabola(theta[sub], s[sub])
                out.append((t_, v_))
            return sorted(out, key=lambda m: (round(abs(m[0]), 9), -m[0]))
    return []


def argmax_fit(theta, s, window):
    """Vertex of the least-squares parabola through the samples within ``window`` [rad] of the
    best sample (falls back to the best sample if the fit is not concave or leaves the
    window); returns (theta*, fitted maximum)."""
    ok, t, v = _fit_vertex(np.ascontiguousarray(theta, dtype=float), np.ascontiguousarray(s, dtype=float),
                           float(window))
    if not ok:
        return argmax_parabola(theta, s)
    return float(t), float(v)


@njit
def _fit_vertex(theta, s, window):
    """:func:`argmax_fit`'s parabola, compiled (NumPy's set-up of the 3 x 3 solve cost
    0.13 ms a call, a third of the criterion): the normal equations in u = theta - theta_k
    for the samples within ``window`` of the best one k, solved by Gaussian elimination with
    partial pivoting.  Returns (ok, theta*, s*); ok False: fewer than 3 samples, not concave,
    or the vertex beyond the window."""
    k = -1
    for i in range(s.size):  # nanargmax
        if not np.isnan(s[i]) and (k < 0 or s[i] > s[k]):
            k = i
    if k < 0:
        return False, 0.0, 0.0
    A = np.zeros((3, 4))
    p = np.zeros(5)
    m = 0
    for i in range(s.size):
        u = theta[i] - theta[k]
        if abs(u) <= window:
            m += 1
            w = 1.0
            for j in range(5):
                p[j] += w
                w *= u
            A[0, 3] += u * u * s[i]
            A[1, 3] += u * s[i]
            A[2, 3] += s[i]
    if m < 3:
        return False, 0.0, 0.0
    for r in range(3):
        for c in range(3):
            A[r, c] = p[4 - r - c]
    for c in range(3):  # elimination with partial pivoting
        piv = c
        for r in range(c + 1, 3):
            if abs(A[r, c]) > abs(A[piv, c]):
                piv = r
        if piv != c:
            for j in range(4):
                A[c, j], A[piv, j] = A[piv, j], A[c, j]
        for r in range(c + 1, 3):
            f = A[r, c] / A[c, c]
            for j in range(c, 4):
                A[r, j] -= f * A[c, j]
    c0 = A[2, 3] / A[2, 2]
    c1 = (A[1, 3] - A[1, 2] * c0) / A[1, 1]
    c2 = (A[0, 3] - A[0, 1] * c1 - A[0, 2] * c0) / A[0, 0]
    if not c2 < 0.0:
        return False, 0.0, 0.0
    t = -c1 / (2.0 * c2)
    if abs(t) > window:
        return False, 0.0, 0.0
    return True, theta[k] + t, c0 - c1 * c1 / (4.0 * c2)


def argmax_parabola(theta, s):
    """Maximiser of sampled s(theta), refined by the parabola through the best sample and its
    two neighbours; returns (theta*, s*)."""
    k = int(np.nanargmax(s))
    if 0 < k < len(s) - 1:
        y0, y1, y2 = s[k - 1], s[k], s[k + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            d = 0.5 * (y0 - y2) / den
            h = theta[1] - theta[0]
            return float(theta[k] + d * h), float(y1 - 0.25 * (y0 - y2) * d)
    return float(theta[k]), float(s[k])


def near_tip_direction(K_I, K_II, beta=1.0, n=401, n_fine=201):
    """Analytical growth angle of the maximum-s̆ criterion from the singular near-tip field
    (Williams): sigma_thth = cos(θ/2)[K_I cos²(θ/2) − 3/2 K_II sin θ] / sqrt(2πr),
    tau_rθ = cos(θ/2)[K_I sin θ + K_II (3 cos θ − 1)] / (2 sqrt(2πr)); maximise
    sqrt(<sigma_thth>² + (β tau_rθ)²) over θ in (−π, π): the best of ``n`` angles, then
    ``n_fine`` angles between its two neighbours, refined by a parabola (a spacing of
    1.6e-4 rad, finer than one grid of 20001 angles, at 3 % of its cost)."""
    def seff(th):
        c = np.cos(th / 2)
        stt = c * (K_I * c * c - 1.5 * K_II * np.sin(th))
        trt = 0.5 * c * (K_I * np.sin(th) + K_II * (3 * np.cos(th) - 1))
        # rm.effective_stress_pt, operation for operation, in NumPy: a run without nucleation
        # would otherwise load the compiled ufunc (about 40 ms) at its first check
        a = np.where(stt > 0.0, stt, 0.0)
        b = beta * trt
        return np.sqrt(a * a + b * b)
    th = np.linspace(-np.pi * 0.999, np.pi * 0.999, n)
    k = int(np.argmax(seff(th)))
    fine = np.linspace(th[max(k - 1, 0)], th[min(k + 1, n - 1)], n_fine)
    return argmax_parabola(fine, seff(fine))[0]


@dataclass
class Tip:
    """A crack tip: position, unit direction of the crack at the tip (outward), and whether
    it may still advance (False once it reached the boundary or another crack)."""

    point: np.ndarray
    direction: np.ndarray
    active: bool = True


def cod_direction(iface, tag, tip, params: GrowthParams):
    """Growth angle [rad] from the crack's opening and slip near the tip (displacement
    correlation): behind a tip, opening δ and slip s both grow like sqrt(r), with
    K_I ∝ δ and K_II ∝ −s (the interface's slip is the jump u− − u+ along its tangent, and
    for either orientation of a facet that is minus Williams' upper-minus-lower jump along
    the crack direction).  The ratio K_II/K_I = −Σ s / Σ δ over the Gauss points of crack
    ``tag`` within ``params.cod_window`` (default ``params.r``) of the tip then gives the angle
    of the maximum-s̆ criterion of the singular field (:func:`near_tip_direction`, with
    ``params.beta``), times ``params.cod_relax``.  None if the crack has no points there or
    is not open."""
    return cod_angle(cod_sums(iface, [(tag, tip)], params)[0], params)


def cod_angle(tot, params: GrowthParams):
    """:func:`cod_direction` from the sums (Σ w δ, Σ w s, points) of :func:`cod_sums`."""
    if tot[2] == 0 or not tot[0] > 0:
        return None
    return params.cod_relax * near_tip_direction(1.0, -tot[1] / tot[0], params.beta)


def cod_sums(iface, tips, params: GrowthParams):
    """(Σ w δ, Σ w s, number of Gauss points) of crack ``tag`` within the window of ``tip``, for
    each (tag, tip) pair, over all ranks (one reduction; collective)."""
    sums = np.zeros((len(tips), 3))
    for k, (tag, tip) in enumerate(tips):
        on = iface.points_near(tag, tip, params.cod_window or params.r)
        w = iface.weights.reshape(-1)[on]
        sums[k] = w @ iface.state[1].reshape(-1)[on], w @ iface.state[2].reshape(-1)[on], w.size
    iface.solver.comm.Allreduce(MPI.IN_PLACE, sums, op=MPI.SUM)
    return sums


def advance_tips(solver, tips, params: GrowthParams, da: float, threshold: float, ready=None, direction_of=None,
                 speeds=None, branches=None):
    """Evaluate the criterion at every active (and, if ``ready`` is given, ready) tip; where
    the maximum effective stress reaches
    ``threshold`` (the damage onset s_ by default in the drivers), move the tip by ``da`` in
    the maximising direction.  Returns the list of (index, angle [rad] relative to the old
    direction, s̆ max, new point) of the tips that advanced; ``tips`` are updated in place.
    ``direction_of(i)``, if given, may return the angle to use instead of the sampled
    maximiser (None: the sampled one).

    Branching: with ``params.branch_speed``, ``speeds[i]`` (the tip's current speed [m/s], None
    if unknown) and a dict ``branches``, a tip at or above that speed whose profile has two
    separated maxima (:func:`separated_maxima`) advances along the first of them and
    ``branches[i] = (angle [rad], s̆, new point)`` gives the second: the caller starts a tip
    there."""
    if not da > 0:
        raise ValueError(f"growth increment da must be > 0 m; got {da}")
    moved = []
    todo = [i for i, tip in enumerate(tips) if tip.active and (ready is None or ready[i])]
    profiles = dict(zip(todo, effective_stress_profiles(solver, [(tips[i].point, tips[i].direction) for i in todo],
                                                        params)))
    for i in todo:
        tip = tips[i]
        th_s, s_s = profiles[i]
        theta, smax = profile_maximum(th_s, s_s, params)
        if not smax >= threshold:
            continue
        two = []
        if (params.branch_speed is not None and branches is not None and speeds is not None
                and speeds[i] is not None and speeds[i] >= params.branch_speed):
            two = separated_maxima(th_s, s_s, threshold, np.radians(params.branch_min_angle),
                                   params.branch_prominence, np.radians(params.edge_margin), fork=True)
        if two:
            phi0 = np.arctan2(tip.direction[1], tip.direction[0])
            (theta, smax), (th2, s2) = two
            d2 = np.array([np.cos(phi0 + th2), np.sin(phi0 + th2)])
            branches[i] = (th2, s2, np.round(tip.point + da * d2, 9))
            phi = phi0 + theta
            d = np.array([np.cos(phi), np.sin(phi)])
            new_point = np.round(tip.point + da * d, 9)
            moved.append((i, theta, smax, new_point))
            tip.point, tip.direction = new_point, d
            continue
        other = direction_of(i) if direction_of is not None else None
        if other is not None:
            theta = other
        elif abs(np.degrees(theta)) > params.max_angle - params.edge_margin:
            # the maximum sits at the edge of the sampled window: the field there is not the
            # tip's (e.g. a passing wave); wait for a maximum inside the window
            continue
        phi = np.arctan2(tip.direction[1], tip.direction[0]) + theta
        d = np.array([np.cos(phi), np.sin(phi)])
        # snapped to 1 nm: the fields, hence the angle, differ by round-off between runs on
        # different partitions, and Gmsh meshes a round-off-different geometry differently
        new_point = np.round(tip.point + da * d, 9)
        moved.append((i, theta, smax, new_point))
        tip.point, tip.direction = new_point, d
    return moved


@dataclass(frozen=True)
class NucleationParams:
    """Nucleation of new cracks (microcracks) in the bulk.

    Where the effective stress s̆ = sqrt(<s_n>² + (β s_t)²) on the maximising plane (the
    damage law's weighting, eq. 10) reaches the strength ``s_bar`` at a cell centre, a crack of
    ``length`` [m] starts there along that plane, bonded (D = 0): the damage law decides
    whether it opens.  Exclusion: no site within ``exclusion`` [m] of an existing crack or tip,
    and only where the driver's ``inside`` holds (the boundary margin).  At most one crack per
    check, ``cap`` per run.  The plane is found on ``n_angles`` orientations in [0°, 180°),
    refined by a parabola."""

    s_bar: float
    length: float
    beta: float = 1.0
    exclusion: float = 0.0
    cap: int = 10
    n_angles: int = 72

    def __post_init__(self):
        for key in ("s_bar", "length"):
            if not getattr(self, key) > 0:
                raise ValueError(f"nucleation {key} must be > 0; got {getattr(self, key)}")
        if not self.beta >= 0 or not self.exclusion >= 0:
            raise ValueError(f"nucleation beta and exclusion must be >= 0; got {self.beta}, {self.exclusion}")
        if not (isinstance(self.cap, int) and self.cap >= 0) or self.n_angles < 8:
            raise ValueError(f"nucleation cap must be an integer >= 0 and n_angles >= 8; got {self.cap}, "
                             f"{self.n_angles}")


def nucleation_site(solver, params: NucleationParams, lines=(), inside=None):
    """(s̆ max, centre (2,), plane angle φ [rad] of its normal) of the best nucleation site over
    all ranks (the same on every rank; collective), or None where no cell is allowed.

    One vectorised pass over the owned cells: the stress at each cell's centre, s̆ on
    ``n_angles`` planes, the maximum per cell; cells within ``params.exclusion`` of a polyline
    of ``lines`` or outside ``inside`` are skipped.  Ties (a uniform stress) go to the cell
    nearest the origin, then the smallest x, y, and ties between planes (the two conjugate
    planes of shear) to the first angle: the choice does not depend on the partition."""
    from . import compat
    comm = solver.comm
    nloc = compat.num_cells_local(solver.mesh)
    g = solver.geometry
    cent = g.centroid[:nloc]
    phi_c = solver.ref.tabulate(np.array([[1.0 / 3.0, 1.0 / 3.0]]))[0]
    U = solver.x.array_r.reshape(-1, 5)
    sig = np.einsum("n,cnk->ck", phi_c, U[compat.cell_dofs(solver.V)[:nloc]])[:, 2:5]
    ang = np.linspace(0.0, np.pi, params.n_angles, endpoint=False)
    c, s_ = np.cos(ang), np.sin(ang)
    sn = sig[:, :1] * c * c + sig[:, 1:2] * s_ * s_ + 2 * sig[:, 2:3] * c * s_
    st = (sig[:, 1:2] - sig[:, :1]) * c * s_ + sig[:, 2:3] * (c * c - s_ * s_)
    seff = rm.effective_stress(np.stack([sn, st], axis=-1), params.beta)  # (cells, angles)
    best = seff.max(axis=1)
    ok = np.ones(nloc, bool)
    if inside is not None:
        ok &= np.array([bool(inside(p)) for p in cent], dtype=bool) if nloc else ok
    for line in lines:
        line = np.asarray(line, float)
        for a, b in zip(line[:-1], line[1:]):
            e = b - a
            u = np.clip((cent - a) @ e / max(e @ e, 1e-300), 0.0, 1.0)
            ok &= np.linalg.norm(cent - (a + u[:, None] * e), axis=1) >= params.exclusion
    cand = None
    if ok.any():
        idx = np.flatnonzero(ok)
        top = best[idx].max()
        tie = idx[best[idx] >= top * (1 - 1e-9)]
        key = np.lexsort((cent[tie, 1], cent[tie, 0], np.round(np.linalg.norm(cent[tie], axis=1), 9)))
        k = tie[key[0]]
        row = seff[k]
        # the first plane within 1e-9 of the maximum: conjugate shear planes tie exactly, and
        # argmax would pick between them by round-off, differently on 1 and 2 ranks
        kk = int(np.flatnonzero(row >= row.max() * (1 - 1e-9))[0])  # parabola through the neighbours (periodic in 180°)
        y0, y1, y2 = row[kk - 1], row[kk], row[(kk + 1) % len(row)]
        den = y0 - 2 * y1 + y2
        phi = ang[kk] + (0.5 * (y0 - y2) / den * (ang[1] - ang[0]) if den < 0 else 0.0)
        cand = (float(top), float(np.linalg.norm(cent[k])), float(cent[k][0]), float(cent[k][1]), float(phi))
    cands = [c_ for c_ in comm.allgather(cand) if c_ is not None]
    if not cands:
        return None
    top = max(c_[0] for c_ in cands)
    win = min((c_ for c_ in cands if c_[0] >= top * (1 - 1e-9)), key=lambda c_: (round(c_[1], 9), c_[2], c_[3]))
    return win[0], np.array(win[2:4]), win[4]


def segment_damage(iface, tag, p0, p1):
    """Mean damage (all ranks) of the Gauss points of crack ``tag`` on the segment p0 -> p1:
    a growth driver advances a tip only once its last inserted segment has debonded, so that
    growth speed is set by the damage law, not by how often the criterion is evaluated."""
    return segment_damages(iface, [(tag, p0, p1)])[0]


def segment_damages(iface, segments):
    """:func:`segment_damage` of each (tag, p0, p1) of ``segments``, in one reduction (none
    for no segments: the paths, and so the segments, are the same on every rank)."""
    if not segments:
        return []
    D_all = iface.state[0].reshape(-1)
    local = np.zeros((len(segments), 2))
    for k, on in enumerate(iface.points_on_segments(segments)):
        D = D_all[on]
        local[k] = D.sum(), D.size
    iface.solver.comm.Allreduce(MPI.IN_PLACE, local, op=MPI.SUM)
    return [t[0] / t[1] if t[1] else float("nan") for t in local]


def _record_json(data: dict) -> str:
    """``data`` as JSON with one line per top-level entry and per list item: readable, and
    written by the C encoder (``indent`` makes json fall back to its Python encoder, 3x slower;
    the record is rewritten at every remesh)."""
    import json

    def one(v):
        return json.dumps(v, default=float)

    def entry(v):
        return "[\n  " + ",\n  ".join(one(x) for x in v) + "\n ]" if isinstance(v, list) and v else one(v)
    return "{\n" + ",\n".join(f" {one(k)}: {entry(v)}" for k, v in data.items()) + "\n}\n"

_SNAP_TOL = 1e-7  # (crack points are snapped to 1 nm)


def _through(line, x):
    """(segment starts, segment vectors, indices of the segments of ``line`` that pass within
    1e-7 of the point ``x``)."""
    a, e = line[:-1], np.diff(line, axis=0)
    ee = np.maximum((e * e).sum(axis=1), 1e-300)
    u = np.clip(((x - a) * e).sum(axis=1) / ee, 0.0, 1.0)
    return a, e, np.flatnonzero(np.linalg.norm(a + u[:, None] * e - x, axis=1) <= _SNAP_TOL)


class GrowthDriver(RemeshDriver):
    """Free crack growth with remeshing, as a ``remesh`` hook of :func:`hydrofrac.run.run`.

    ``build((paths, tags)) -> Problem`` meshes the scene with the growth paths (polylines
    (k, 2), one per tip, facet tag ``tags[i]``, bonded D = 0 crack) and builds its
    :class:`~hydrofrac.problem.Problem`.  Every ``check_every`` steps (of rk4 at its CFL step:
    :func:`check_interval`) the driver evaluates the criterion at the tips whose
    last segment has mostly debonded (mean D >= ``ready_damage``, default 0.5: the far end of a
    segment, where the stress is below s̄, may only damage towards D_t < 1); tips where s̆ reaches
    ``threshold`` advance by ``da`` (all of them at once: one remesh per batch), tips leaving
    ``inside`` stop.  ``domain_size`` [m], if given, rejects a ``da`` that is not smaller.
    A new segment that crosses another crack (one of the ``obstacles`` polylines, e.g.
    natural fractures, or another growth path) ends on it and its tip stops: the crack joins
    that one (the mesh shares the vertex, so union-find merges their networks).  Then it remeshes, transfers fields and interface state
    (:mod:`hydrofrac.transfer`) and returns the new problem; otherwise None.

    ``max_speed`` [m/s], if given, bounds each tip's speed: a tip advances ``da`` no sooner than
    ``da / max_speed`` after its previous extension (without it, a tip runs as fast as the
    check interval and its segment's debonding allow, which measured above c_R).
    Remeshes happen only when a tip advanced; ``count`` and the "remesh" timer report them.
    ``record``: a JSON file rewritten (on rank 0) after every growth batch with the tip paths,
    the growth events (time, tip, angle, s̆ max) and the joins, so that a run that stops keeps
    the paths it grew.
    """

    adapt = None  # (class defaults: a driver restored from a checkpoint state alone has them)
    adapt_count = 0

    def __init__(self, build, tips, params: GrowthParams, da: float, threshold: float, tags,
                 check_every: int = 10, ready_damage: float = 0.5, inside=None, domain_size=None,
                 obstacles=(), record=None, max_speed=None, nucleation: "NucleationParams | None" = None,
                 adapt=None):
        if not da > 0:
            raise ValueError(f"growth increment da must be > 0 m; got {da}")
        if max_speed is not None and not max_speed > 0:
            raise ValueError(f"growth max_speed must be > 0 m/s (or None: no limit); got {max_speed}")
        self.max_speed = max_speed
        self.nucleation = nucleation
        # adaptive meshes (hydrofrac.adapt.Adaptivity, whose levels ``build`` meshes with): its
        # checks may remesh an unchanged geometry; ``adapt_count`` counts those remeshes
        self.adapt, self.adapt_count = adapt, 0
        self.nucleations = []  # (t, centre, crack angle [deg], s̆)
        if domain_size is not None and not da < domain_size:
            raise ValueError(f"growth increment da = {da} m is not smaller than the domain ({domain_size} m); "
                             "use a da of a few crack-facet sizes")
        if check_every < 1:
            raise ValueError(f"check_every must be >= 1 step; got {check_every}")
        self.build, self.tips, self.params, self.da, self.threshold = build, list(tips), params, da, threshold
        self.tags = list(tags)
        from .meshes.fractures import PATH
        self._tag0 = PATH  # nucleated cracks take the next path tags
        self.check_every, self.ready_damage, self.inside = check_every, ready_damage, inside
        self.obstacles = [np.asarray(o, float) for o in obstacles]
        self.record = record
        self.joined = []  # (t, tip index, point)
        self.paths = [[np.asarray(t.point, float).copy()] for t in tips]
        self.count = 0
        self.meshes = []  # per mesh: (t it starts at, cells, time step [s]) (growth.json's "meshes")
        self.last_criterion_s = 0.0  # criterion and nucleation time of the last call [s]
        self.events = []  # (t, tip index, angle [deg], s̆ max)
        self.modes = []  # per event: (mode mixity [deg], the crack carried load), :meth:`_tip_mode`
        self.tree = []  # growth events with parent and child tips (growth.json's "tree")
        self.arrested = {}  # tip index -> (point, unit tangent of the crack it met)
        self._first_mesh = []  # the first mesh, kept until the driver goes (RemeshDriver)
        for i, tip in enumerate(self.tips):  # a tip that starts on a crack is arrested there
            for line in self.obstacles:
                if min(np.linalg.norm(line[0] - tip.point), np.linalg.norm(line[-1] - tip.point)) < 1e-9:
                    continue  # the crack's own end (a natural fracture's tip), not a crack met
                for a, b in zip(line[:-1], line[1:]):
                    e = b - a
                    u = float(np.clip((tip.point - a) @ e / max(e @ e, 1e-300), 0.0, 1.0))
                    if i not in self.arrested and np.linalg.norm(a + u * e - tip.point) < 1e-9:
                        tip.active = False
                        self.arrested[i] = (np.asarray(tip.point, float).copy(), e / np.linalg.norm(e))
                        self.tree.append({"event": "arrest", "t": 0.0, "parent": i, "child": None,
                                          "angle_deg": None, "speed": None, "point": tip.point.tolist()})
        self.problem = self._build()
        self._log_mesh()

    def _mesh_args(self):
        return self._polylines()

    def _check_every(self):
        return self.check_every

    def _polylines(self):
        keep = [i for i, p in enumerate(self.paths) if len(p) > 1]
        return [np.array(self.paths[i]) for i in keep], [self.tags[i] for i in keep]

    def _first_crossing(self, p, q, me):
        """First point where segment p -> q meets an obstacle, another tip's path, or the
        tip's own path short of its last segment (a crack that curls back onto itself joins
        itself there instead of making a self-intersecting geometry)."""
        hit = self._crossing(p, q, me)
        return None if hit is None else hit[0]

    def _crossing(self, p, q, me):
        """(point, unit tangent of the crack segment met) of :meth:`_first_crossing`, or None
        (``me``: the tip whose own path counts short of its last segment; None: a segment of no
        tip's path yet).

        A segment that would end within ``SNAP * da`` of another crack (short of it, or past
        the end of a crack beside it) meets it too, at the crossing of its extension or at
        the nearest point: a thinner gap would make Gmsh cells of that size, and the CFL
        step with them (a tip 0.5 µm short of a fracture gave a 5e-11 s step).  For the same
        reason a meeting point within ``SNAP * da`` of a vertex of the crack met moves onto
        that vertex (:meth:`_at_vertex`)."""
        own = np.array(self.paths[me][:-1]) if me is not None else np.zeros((0, 2))
        parts = [self._segments_of(None)] + [self._segments_of(j) for j, pth in enumerate(self.paths)
                                             if j != me and len(pth) > 1]
        if len(own) > 1:
            parts.append((own[:-1], np.diff(own, axis=0)))
        if not sum(len(a) for a, _ in parts):
            return None
        # every segment of every line at once (the same arithmetic as one by one)
        A = np.concatenate([a for a, _ in parts])
        E = np.concatenate([e for _, e in parts])
        d = q - p
        snap = SNAP * self.da
        length = max(float(np.linalg.norm(d)), 1e-300)
        reach = snap / length
        # a hit closer to p than 0.1 µm is p itself: a tip that starts on a crack (a crossing)
        # sits on it within the 1 nm snap of the points, and leaves it at an angle
        near0 = 1e-7 / length
        den = d[0] * E[:, 1] - d[1] * E[:, 0]
        W = A - p
        with np.errstate(divide="ignore", invalid="ignore"):
            s_ = (W[:, 0] * E[:, 1] - W[:, 1] * E[:, 0]) / den  # along p -> q
            u = (W[:, 0] * d[1] - W[:, 1] * d[0]) / den  # along a -> b
        hit = (np.abs(den) >= 1e-14) & (near0 < s_) & (s_ <= 1 + reach) & (-1e-12 <= u) & (u <= 1 + 1e-12)
        if hit.any():
            k = np.flatnonzero(hit)[np.argmin(s_[hit])]  # the first of the nearest along p -> q
            e = E[k]
            return self._at_vertex(p + s_[k] * d, A[k], E[k], p), e / np.linalg.norm(e)
        # ends beside a crack (e.g. next to its end point): the nearest point
        ee = np.maximum(E[:, 0] * E[:, 0] + E[:, 1] * E[:, 1], 1e-300)
        U = np.clip(((q[0] - A[:, 0]) * E[:, 0] + (q[1] - A[:, 1]) * E[:, 1]) / ee, 0.0, 1.0)
        C = A + U[:, None] * E
        R, S = q - C, C - p
        dist = np.sqrt(R[:, 0] * R[:, 0] + R[:, 1] * R[:, 1])
        ok = (dist < snap) & (np.sqrt(S[:, 0] * S[:, 0] + S[:, 1] * S[:, 1]) > 1e-7)
        if not ok.any():
            return None
        k = np.flatnonzero(ok)[np.argmin(dist[ok])]
        e = E[k]
        return (self._at_vertex(C[k], A[k], E[k], p), e / np.linalg.norm(e))

    def _segments_of(self, j):
        """(segment starts, segment vectors) of tip ``j``'s path, or of all the obstacles for
        None; kept while the path is (it only grows, or is replaced by a restore)."""
        cache = self.__dict__.setdefault("_segment_cache", {})
        line = self.paths[j] if j is not None else self.obstacles
        hit = cache.get(j)
        if hit is not None and hit[0] is line and hit[1] == len(line):
            return hit[2]
        if j is None:
            got = ((np.concatenate([o[:-1] for o in line]), np.concatenate([np.diff(o, axis=0) for o in line]))
                   if line else (np.zeros((0, 2)), np.zeros((0, 2))))
        else:
            pts = np.array(line, float)
            got = (pts[:-1], np.diff(pts, axis=0))
        cache[j] = (line, len(line), got)
        return got

    def _at_vertex(self, x, a, e, p):
        """The meeting point ``x`` on the crack segment a -> a + e, moved onto the nearest point
        of the geometry on that segment (its ends, vertices of the crack met, and the points
        where other cracks already meet it or leave it) when it lies within ``SNAP * da`` of it.
        Gmsh keeps both points, and an edge between them as short as their distance: in the
        full-size re-fracture a tip that met a grown path 0.4 mm from its vertex cut the step
        43x, and one that met a perforation 1.4 mm from where another tip had met it cut it 11x
        (docs/model.md, "Crossing or arrest"; docs/benchmarks.md, "A junction beside a
        junction").  A vertex outside the tips' region (``inside``: the wall end of a
        perforation) is no place to meet: the point returned is then the tip's own ``p``, and
        the tip stops where it is (:meth:`_extend`)."""
        ee = max(float(e @ e), 1e-300)
        P = np.array([q for pth in self.paths for q in pth], float).reshape(-1, 2)
        u = np.clip((P - a) @ e / ee, 0.0, 1.0)
        V = np.vstack([a, a + e, P[np.hypot(*(P - a - u[:, None] * e).T) < _SNAP_TOL]])
        dist = np.hypot(*(V - x).T)
        k = int(np.argmin(dist))
        v, dv = V[k], dist[k]
        if not dv < SNAP * self.da:
            return x
        if self.inside is not None and not self.inside(v):
            return np.asarray(p, float).copy()
        return np.asarray(v, float).copy()

    def __call__(self, problem):
        solver = problem.solver
        self.last_criterion_s = 0.0
        adapt_due = self.adapt is not None and self.adapt.due(solver)
        if solver.step_count % check_interval(solver, self.check_every):
            return self._adapt_remesh(problem) if adapt_due else None
        import time as _time
        t_crit = _time.perf_counter()
        # (the tips that may still move: the active ones, and the arrested ones that may cross)
        extended = [i for i, p in enumerate(self.paths) if len(p) >= 2 and (self.tips[i].active or i in self.arrested)]
        damage = dict(zip(extended, segment_damages(self.iface, [(self.tags[i], self.paths[i][-2], self.paths[i][-1])
                                                                 for i in extended])))
        ready = [i not in damage or damage[i] >= self.ready_damage for i in range(len(self.paths))]
        if self.max_speed is not None:  # a tip advances da no sooner than da / max_speed after its last step
            last = self._last_extensions()[1]
            ready = [r and (i not in last or solver.t - last[i] >= self.da / self.max_speed * (1 - 1e-12))
                     for i, r in enumerate(ready)]
        before_state = self._state_before_check()  # (the fall-back if the remesh fails)
        before = [(t.point.copy(), t.direction.copy()) for t in self.tips]
        speeds = self.current_speeds()
        branches = {}
        n_before = len(self.tips)
        crossed = self._cross(solver, ready)  # arrested tips whose far side reaches the onset
        direction_of = None
        if self.params.direction == "cod":  # (every tip that may advance, in one reduction)
            cod = [i for i in range(n_before) if self.tips[i].active and ready[i] and i not in crossed
                   and len(self.paths[i]) > 1]
            sums = dict(zip(cod, cod_sums(self.iface, [(self.tags[i], self.tips[i].point) for i in cod],
                                          self.params)))

            def direction_of(i):  # (the angle only for the tips that reach the onset)
                return cod_angle(sums[i], self.params) if i in sums else None
        moved = advance_tips(solver, self.tips[:n_before], self.params, self.da, self.threshold,
                             ready=[r and i not in crossed for i, r in enumerate(ready)],
                             direction_of=direction_of, speeds=speeds, branches=branches)
        grown = list(crossed.values())
        for i, theta, smax, point in moved:
            if self.inside is not None and not self.inside(point):
                self.tips[i].point, self.tips[i].direction = before[i]
                self.tips[i].active = False  # reached the boundary: stops
                continue
            start = self.paths[i][-1]
            self._extend(solver, i, point, theta, smax)
            grown.append(i)
            if i in branches:
                th2, s2, p2 = branches[i]
                if self.inside is not None and not self.inside(p2):
                    continue  # the branch would leave the domain: the tip goes on alone
                phi = np.arctan2(before[i][1][1], before[i][1][0]) + th2
                j = self._new_tip(start, np.array([np.cos(phi), np.sin(phi)]))
                self.tips[j].point = p2
                self._extend(solver, j, p2, th2, s2)
                self.tree.append({"event": "branch", "t": solver.t, "parent": i, "child": [i, j],
                                  "angle_deg": [float(np.degrees(theta)), float(np.degrees(th2))],
                                  "speed": speeds[i], "point": np.asarray(start).tolist()})
                grown.append(j)
        t_nuc = _time.perf_counter()
        if self._nucleate(solver):
            grown.append(len(self.tips) - 1)
        # the criterion's share of this call (tips, crossing checks; nucleation has its own
        # timer), reported as "growth criterion"; run() counts the rest of a remeshing call
        # as "remesh"
        crit = t_nuc - t_crit
        solver.timers.add("growth criterion", crit)
        self.last_criterion_s = crit + (_time.perf_counter() - t_nuc)
        if not grown:
            return self._adapt_remesh(problem) if adapt_due else None
        if adapt_due:  # the new mesh takes the indicators' levels too
            _, spent = self.adapt.check(problem)
            self.last_criterion_s += spent
        try:
            new = self._build()
        except Exception:
            # keep the driver at the last good geometry (the one a checkpoint of the last good
            # state belongs to; with adaptive meshes, the levels before this check); the failing
            # geometry is in the exception's message and files
            self._restore_before_check(before_state)
            raise
        self.count += 1
        return self._adopt(problem, new)

    def _adopt(self, problem, new):
        """:meth:`RemeshDriver._adopt`, and the paths recorded (``record``)."""
        super()._adopt(problem, new)
        self.write()
        return new

    def _adapt_remesh(self, problem):
        """An adaptive check with no crack extension: remesh the same geometry when the
        indicators ask for it (:class:`hydrofrac.adapt.Adaptivity`); the new problem or None."""
        new, spent = self._adaptive_build(problem)
        self.last_criterion_s += spent
        if new is None:
            return None
        self.adapt_count += 1
        return self._adopt(problem, new)

    def _new_tip(self, start, direction):
        """A new tip at ``start`` (its path's first point) heading along ``direction``; returns
        its index (its tag is the next free path tag)."""
        self.tips.append(Tip(np.round(np.asarray(start, float), 9), np.asarray(direction, float)))
        self.paths.append([np.round(np.asarray(start, float), 9)])
        self.tags.append(max(self.tags, default=self._tag0 - 1) + 1)
        return len(self.tips) - 1

    def _extend(self, solver, i, point, theta, smax):
        """Tip ``i`` grows to ``point``; a segment that meets another crack ends on it and the tip
        is arrested there (it may cross later: :meth:`_cross`)."""
        start = np.asarray(self.paths[i][-1], float)
        hit = self._crossing(start, point, i)
        if hit is not None and (np.linalg.norm(hit[0] - start) < SNAP * self.da
                                or self._leaves_along(hit[0], start)[0]):
            # the crack met is closer than SNAP * da to the tip (a tip that starts on one crack
            # next to another): the segment would be a sliver (a 0.3 mm one gave a 1000x smaller
            # step), so the tip stops where it is, arrested for good (it does not cross); so
            # does one whose segment, moved onto a junction, would lie along a crack from there
            self.tips[i].point, self.tips[i].active = start.copy(), False
            self.tree.append({"event": "arrest", "t": solver.t, "parent": i, "child": None,
                              "angle_deg": None, "speed": None, "point": start.tolist()})
            return
        if hit is not None:
            point = np.round(hit[0], 9)
            self.tips[i].point = point
            d = (point - start) / np.linalg.norm(point - start)
            if abs(d[0] * self.tips[i].direction[1] - d[1] * self.tips[i].direction[0]) > 1e-9:
                self.tips[i].direction = d  # moved onto a vertex of the crack met: the segment's own direction
            self.tips[i].active = False  # arrested on the crack it met
            self.joined.append((solver.t, i, point.copy()))
            self.arrested[i] = (point.copy(), np.asarray(hit[1], float))
            self.tree.append({"event": "arrest", "t": solver.t, "parent": i, "child": None,
                              "angle_deg": None, "speed": None, "point": point.tolist()})
        self.modes.append(self._tip_mode(i))
        self.paths[i].append(np.asarray(point, float).copy())
        self.events.append((solver.t, i, float(np.degrees(theta)), smax))

    def _tip_mode(self, i):
        """(mode mixity [deg], loaded) of tip ``i``'s crack before it extends (collective):
        the mixity is atan(|Σ w s| / Σ w δ⁺) over the crack's Gauss points within the
        criterion's distance r behind the tip (slip s and opening δ grow like √r there, as
        K_II and K_I: 0° pure opening, 90° pure shear, closed and slipping included); loaded:
        the crack carries hydraulic load anywhere (Σ f_p w > 0).  NaN mixity where the crack
        has no points yet (a nucleated crack's first segments)."""
        iface = getattr(self, "iface", None)
        if iface is None:
            return (float("nan"), False)
        tag, tip = self.tags[i], np.asarray(self.paths[i][-1], float)
        mine = iface.points_of_crack(tag)
        near = iface.points_near(tag, tip, self.params.cod_window or self.params.r)
        w = iface.weights.reshape(-1)
        hyd = getattr(getattr(self, "problem", None), "hydraulics", None)
        fp = hyd.fp_q.reshape(-1) if hyd is not None else np.zeros(w.size)
        tot = iface.solver.comm.allreduce(np.array([w[near] @ np.maximum(iface.state[1].reshape(-1)[near], 0.0),
                                                    w[near] @ iface.state[2].reshape(-1)[near],
                                                    float(near.size), w[mine] @ fp[mine]]), op=MPI.SUM)
        mix = float(np.degrees(np.arctan2(abs(tot[1]), tot[0]))) if tot[2] > 0 else float("nan")
        return (mix, bool(tot[3] > 0))

    def far_side_profile(self, solver, i):
        """(theta [rad, relative to the arrested tip's direction], s̆) sampled as for growth,
        from the point where tip ``i`` met a crack, on the far side of that crack only: the
        trial directions at least ``FAR_SIDE_MARGIN`` from the crack's plane.  The stress there
        is what the interface transmits in its current mode (its Riemann solutions), so
        crossing depends on bonding, contact and friction only through them."""
        point, tangent = self.arrested[i]
        d = self.tips[i].direction
        theta, s_ = effective_stress_profile(solver, point, d, self.params)
        nrm = np.array([-tangent[1], tangent[0]])
        side = np.sign(d @ nrm) or 1.0
        ang = np.arctan2(d[1], d[0]) + theta
        off = side * (np.cos(ang) * nrm[0] + np.sin(ang) * nrm[1])  # sine of the angle to the plane
        far = off >= np.sin(np.radians(FAR_SIDE_MARGIN))
        return theta[far], s_[far]

    def _cross(self, solver, ready):
        """Arrested tips whose approach segment has debonded (``ready``) and whose far-side
        s̆ reaches the onset cross: a new tip starts at the meeting point along the far-side
        maximiser (no offset along the crack met).  Returns {arrested tip: new tip}."""
        out = {}
        for i in sorted(self.arrested):
            if not ready[i]:
                continue
            theta, s_ = self.far_side_profile(solver, i)
            if theta.size < 3:
                continue
            th, smax = profile_maximum(theta, s_, self.params)
            if not smax >= self.threshold:
                continue
            if min(th - theta[0], theta[-1] - th) < np.radians(self.params.edge_margin):
                continue  # the maximum sits at the edge of the far-side window: not the transmitted field's
            point, _ = self.arrested.pop(i)
            d0 = self.tips[i].direction
            phi = np.arctan2(d0[1], d0[0]) + th
            d = np.array([np.cos(phi), np.sin(phi)])
            new_point = np.round(point + self.da * d, 9)
            if (self.inside is not None and not self.inside(new_point)) or self._runs_along(point, new_point):
                self.arrested[i] = (point, _)
                continue
            j = self._new_tip(point, d)
            self.tips[j].point, self.tips[j].direction = new_point, d
            self.tree.append({"event": "crossing", "t": solver.t, "parent": i, "child": j,
                              "angle_deg": float(np.degrees(th)), "speed": None, "point": point.tolist()})
            self._extend(solver, j, new_point, th, smax)
            out[i] = j
        return out

    def _runs_along(self, p, q):
        """Whether the segment p -> q would lie along a crack through ``p``: one with a vertex
        there (a tip arrested on a crack moves onto a vertex of it within ``SNAP * da``, where
        the crack may turn, so the far side of one of its segments can hold the other's
        direction), or a segment through it.  It would when it leaves within
        ``params.edge_margin`` of that crack (:meth:`_leaves_along`), or when its end would move
        onto that crack: an end within ``SNAP * da`` of a crack meets it (:meth:`_crossing`), so
        up to asin(SNAP) = 14.5° off a crack the segment would end on it (the full-size
        re-fracture at h_crack = 0.0385 m stopped with "path 10 and path 12 overlap" at 5.5°
        off).  Gmsh cannot mesh two cracks on one line."""
        along, lines = self._leaves_along(p, q)
        if along:
            return True
        hit = self._crossing(p, q, None) if lines else None
        return hit is not None and any(_through(line, hit[0])[2].size for line in lines)

    def _leaves_along(self, p, q):
        """(whether a crack through ``p`` leaves it within ``params.edge_margin`` of the direction
        to ``q``, the cracks through ``p``): along one, a segment p -> q would lie on it."""
        cos_min = np.cos(np.radians(self.params.edge_margin))
        d = (q - p) / np.linalg.norm(q - p)
        lines = []
        for line in list(self.obstacles) + [np.asarray(pth, float) for pth in self.paths if len(pth) > 1]:
            a, e, ks = _through(line, p)
            if ks.size:
                lines.append(line)
            for k in ks:  # the directions from p along the crack: to the segment's ends
                for v in (a[k], a[k] + e[k]):
                    r = v - p
                    n = np.linalg.norm(r)
                    if n > _SNAP_TOL and float(r @ d) >= cos_min * n:
                        return True, lines
        return False, lines

    def current_speeds(self):
        """Each tip's current speed [m/s]: that of its last extension (None before its second)."""
        return list(self._last_extensions()[0])

    def _last_extensions(self):
        """(:meth:`current_speeds`, {tip: time of its last extension}); kept while the events and
        paths are (asked for at every criterion check)."""
        key = (len(self.events), len(self.tips), tuple(len(p) for p in self.paths))
        cached = getattr(self, "_speeds", None)
        if cached is not None and cached[0] == key:
            return cached[1:]
        last, prev = {}, {}
        for t, i, _, _ in self.events:
            if i in last:
                prev[i] = last[i]
            last[i] = t
        out = [None] * len(self.tips)
        for i, t in last.items():  # (tip_speeds of each tip's last event: its path's last segment)
            p = prev.get(i)
            if p is not None and t > p:
                seg = np.asarray(self.paths[i][-1]) - np.asarray(self.paths[i][-2])
                out[i] = float(np.linalg.norm(seg) / (t - p))
        self._speeds = (key, out, last)
        return out, last

    def _nucleate(self, solver):
        """Start a crack at the best nucleation site if its s̆ reaches the strength (and the
        cap allows): two new tips back to back, each with its own path from the centre."""
        n = self.nucleation
        if n is None or len(self.nucleations) >= n.cap:
            return False
        import time as _time
        t0 = _time.perf_counter()
        network = getattr(self.problem, "network", None)
        lines = ([c.points for c in network.cracks] if network is not None else
                 list(self.obstacles) + [np.array(p) for p in self.paths if len(p) > 1])
        lines += [np.array([t.point, t.point]) for t in self.tips]  # and keep away from the tips
        site = nucleation_site(solver, n, lines, self.inside)
        solver.timers.add("nucleation", _time.perf_counter() - t0)
        if site is None or site[0] < n.s_bar:
            return False
        seff, centre, phi = site
        d = np.array([-np.sin(phi), np.cos(phi)])  # along the plane (its normal at phi)
        centre = np.round(centre, 9)
        kids = []
        for sign in (1.0, -1.0):
            end = np.round(centre + sign * 0.5 * n.length * d, 9)
            j = self._new_tip(centre, sign * d)
            self.tips[j].point = end
            self.paths[j].append(end)
            kids.append(j)
        self.tree.append({"event": "nucleation", "t": solver.t, "parent": None, "child": kids,
                          "angle_deg": float(np.degrees(np.arctan2(d[1], d[0]))) % 180.0, "speed": None,
                          "point": centre.tolist()})
        self.nucleations.append((solver.t, centre.copy(), float(np.degrees(np.arctan2(d[1], d[0]))) % 180.0, seff))
        return True

    def tip_speeds(self):
        """Speed of every extension [m/s] (None for a tip's first): the segment's length over
        the time since the tip's previous extension; in the order of ``events``.  A nucleated
        crack's first segment (from its centre) is not an extension."""
        n_ev = {}
        for _, i, _, _ in self.events:
            n_ev[i] = n_ev.get(i, 0) + 1
        out, seen, last = [], {}, {}
        for t, i, _, _ in self.events:
            k = seen.get(i, 0) + (len(self.paths[i]) - 1 - n_ev[i])
            seg = np.asarray(self.paths[i][k + 1]) - np.asarray(self.paths[i][k])
            prev = last.get(i)
            out.append(float(np.linalg.norm(seg) / (t - prev)) if prev is not None and t > prev else None)
            seen[i], last[i] = seen.get(i, 0) + 1, t
        return out

    def _modes(self):
        """:attr:`modes`, one per event (NaN, False for events of a checkpoint without them)."""
        return self.modes + [(float("nan"), False)] * (len(self.events) - len(self.modes))

    def counts(self):
        """Tips (all, active), branches, nucleations, crossings and arrests (tips arrested now),
        and the extensions in shear (mode mixity above 45°: slip beyond opening near the tip),
        of them those of cracks that carried no hydraulic load."""
        ev = [e["event"] for e in self.tree]
        shear = [ld for m, ld in self._modes() if m > 45.0]
        return {"tips": len(self.tips), "active_tips": sum(t.active for t in self.tips),
                "branches": ev.count("branch"), "nucleations": ev.count("nucleation"),
                "crossings": ev.count("crossing"), "arrests": len(self.arrested),
                "shear_extensions": len(shear), "unloaded_shear_extensions": shear.count(False)}

    def report(self):
        """What a summary reports of the growth (its ``accuracy``): remeshes, extensions,
        joins, the event counts (:meth:`counts`), the grown length [m] and the fastest
        extension [m/s]."""
        speeds = [v for v in self.tip_speeds() if v is not None]
        return {"remeshes": self.count, "extensions": len(self.events), "joined": len(self.joined),
                **self.counts(),
                "grown_length": sum(float(np.linalg.norm(np.diff(np.array(p), axis=0), axis=1).sum())
                                    for p in self.paths),
                "tip_speed_max": max(speeds) if speeds else 0.0,
                **self.time_step_report(),
                **self.remesh_kinds(),
                **({"adaptive_remeshes": self.adapt_count, **self.adapt.report()} if self.adapt is not None else {})}

    def time_step_report(self):
        """What the meshes made of the time step (collective): the first and the last mesh's dt,
        the steps taken beyond those the first mesh's dt needs for the same time (a share: a cell
        smaller than the first mesh's sets a shorter step on every mesh after it), and the cell
        that sets the last mesh's step (2 x inradius [m] and where)."""
        solver = getattr(self.problem, "solver", None)  # (the tests' stand-in problems have none)
        m = self.meshes
        if solver is None or not m or float(solver.t) <= m[0][0]:
            return {}
        t_end = float(solver.t)
        ends = [b[0] for b in m[1:]] + [t_end]
        steps = sum((e - t) / dt for (t, _, dt), e in zip(m, ends))
        h, at = solver.smallest_cell()
        return {"dt_first_mesh": m[0][2], "dt_last_mesh": m[-1][2],
                "steps_beyond_first_dt": steps * m[0][2] / (t_end - m[0][0]) - 1.0,
                "smallest_cell_2r": h, "smallest_cell_at": [round(v, 4) for v in at]}

    def remesh_kinds(self):
        """With local remeshing: the remeshes made by a patch, those that fell back to the whole
        domain, and why (empty otherwise)."""
        kinds = getattr(self.build, "kinds", None)
        if kinds is None or not getattr(self.build, "local", False):
            return {}
        return {"local_remeshes": kinds["patch"], "patches_retried": kinds.get("retried", 0),
                "rebalanced": kinds.get("rebalanced", 0),
                "full_remesh_fallbacks": kinds["full_fallback"], "fallback_reasons": dict(self.build.fallbacks)}

    #: the attributes :meth:`checkpoint_state` reads (the mesh and adaptive levels aside)
    _STATE = ("paths", "tags", "tips", "nucleations", "events", "modes", "joined", "tree", "arrested", "count",
              "meshes")

    def _state_before_check(self):
        """What a check falls back to when its remesh fails (:meth:`_restore_before_check`): the
        state's lists as shallow copies (their items are never changed in place: the lists only
        grow, and a tip or arrest point changes by a new value), the tips as new Tips.  O(state)
        pointer copies, not the checkpoint's text (that grew to 3 ms per check at the end of the
        full-size re-fracture).  With adaptive meshes, the checkpoint's text (their levels are
        state too)."""
        if self.adapt is not None:
            return self.checkpoint_state(with_mesh=False)
        snap = {k: copy.copy(getattr(self, k)) for k in self._STATE}
        snap["paths"] = [list(p) for p in self.paths]
        snap["tips"] = [Tip(np.array(t.point, float), np.array(t.direction, float), bool(t.active))
                        for t in self.tips]
        return snap

    def _restore_before_check(self, snap):
        """Set the state of :meth:`_state_before_check`."""
        if isinstance(snap, str):
            return self.restore_state(snap)
        self._speeds = None  # (the cache of current_speeds)
        for k in self._STATE:
            setattr(self, k, copy.copy(snap[k]))
        self.paths = [list(p) for p in snap["paths"]]
        self.tips = [Tip(t.point.copy(), t.direction.copy(), t.active) for t in snap["tips"]]

    def checkpoint_state(self, with_mesh=True):
        """The geometry state (JSON text): paths, tips, events, joins, remesh count, and with
        local remeshing the mesh (``with_mesh``)."""
        import json
        return json.dumps({
            "paths": [np.asarray(p).tolist() for p in self.paths],
            "tips": [{"point": np.asarray(t.point).tolist(), "direction": np.asarray(t.direction).tolist(),
                      "active": bool(t.active)} for t in self.tips],
            "events": [list(map(float, e)) for e in self.events],
            "modes": [[float(m), bool(ld)] for m, ld in self.modes],
            "joined": [[float(t), int(i), np.asarray(p).tolist()] for t, i, p in self.joined],
            "tags": list(map(int, self.tags)),
            "nucleations": [[float(t), np.asarray(c).tolist(), a, float(s_)] for t, c, a, s_ in self.nucleations],
            "tree": self.tree,
            "arrested": [[int(i), np.asarray(p).tolist(), np.asarray(e).tolist()] for i, (p, e) in self.arrested.items()],
            "count": self.count,
            "meshes": [list(m) for m in self.meshes],
            "adapt": None if self.adapt is None else {**self.adapt.state(), "count": self.adapt_count},
            # a local remesh's mesh, which a full remesh of the same geometry would not give again
            "mesh": self.build.mesh_state() if with_mesh and hasattr(self.build, "mesh_state") else None},
            default=float)

    def restore_state(self, text):
        """Set the geometry state from :meth:`checkpoint_state` (no remesh)."""
        import json
        d = json.loads(text)
        tags = d.get("tags", self.tags)
        if len(d["tips"]) != len(tags) or tags[:len(self.tags)] != self.tags[:len(tags)]:
            raise ValueError(f"checkpoint has {len(d['tips'])} crack tips with tags {tags}, this run's tags are "
                             f"{self.tags}: restart with the same growth options")
        self._speeds = None  # (the cache of current_speeds)
        self.paths = [[np.asarray(q, float) for q in p] for p in d["paths"]]
        self.tags = list(tags)
        self.tips = [Tip(np.asarray(st["point"]), np.asarray(st["direction"]), st["active"]) for st in d["tips"]]
        self.nucleations = [(t, np.asarray(c), a, s_) for t, c, a, s_ in d.get("nucleations", [])]
        self.events = [(e[0], int(e[1]), e[2], e[3]) for e in d["events"]]
        self.modes = [(float(m), bool(ld)) for m, ld in d.get("modes", [])]
        self.joined = [(t, i, np.asarray(p)) for t, i, p in d["joined"]]
        self.tree = list(d.get("tree", []))
        self.arrested = {int(i): (np.asarray(p, float), np.asarray(e, float)) for i, p, e in d.get("arrested", [])}
        self.count = int(d["count"])
        self.meshes = [(float(t), int(n), float(dt)) for t, n, dt in d.get("meshes", [])]
        if self.adapt is not None and d.get("adapt") is not None:
            self.adapt.restore(d["adapt"])
            self.adapt_count = int(d["adapt"]["count"])

    def restart(self, text):
        """Rebuild the mesh of a checkpoint's geometry state; returns the new problem (at its
        initial state: the checkpoint's fields are loaded into it next)."""
        self.restore_state(text)
        self._keep_first_mesh(self.problem)
        import json
        mesh = json.loads(text).get("mesh")
        if mesh is not None:
            self.build.restore_mesh(mesh)
            self.problem = self._build(count=False)
        else:
            self.problem = self._build()
        return self.problem

    def write(self, path=None):
        """Write the paths, events and joins as JSON (rank 0) to ``path`` or ``record``."""
        path = path or self.record
        if path is None or self.solver.comm.rank != 0:
            return
        import json
        from pathlib import Path
        data = {"paths": [np.asarray(p).tolist() for p in self.paths],
                "events": [{"t": t, "tip": i, "angle_deg": a, "s_max": s_, "speed": v, "mixity_deg": m[0],
                            "loaded": m[1]}
                           for (t, i, a, s_), v, m in zip(self.events, self.tip_speeds(), self._modes())],
                "joined": [{"t": t, "tip": i, "point": np.asarray(p).tolist()} for t, i, p in self.joined],
                "nucleations": [{"t": t, "centre": np.asarray(c).tolist(), "angle_deg": a, "s_eff": s_}
                                for t, c, a, s_ in self.nucleations],
                "tree": self.tree, "counts": self.counts(),
                "remeshes": self.count,
                "meshes": [{"t": t, "cells": n, "dt": dt} for t, n, dt in self.meshes]}
        network = getattr(self.problem, "network", None)
        if network is not None:  # the current geometry: cracks, junctions and tips
            data["network"] = network.as_dict()
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(_record_json(data))
