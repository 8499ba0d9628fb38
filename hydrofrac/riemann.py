"""Exact local Riemann solutions of the contact modes and their combination.

This is the one implementation of model.md §2–4 used by the interface kernels and the
tests.  The formulas are written once, as scalar *point functions* (``*_pt``) compiled
with numba, so that the compiled interface kernel (:mod:`hydrofrac.kernels`) calls them
per Gauss point.  The vectorised functions below (``bonded``, ``slip``, ``combine``,
``eta_regularized``, ...) apply the same point functions to arrays: arrays of shape
``(N, 2)`` hold per-point vectors in the local interface frame, column 0 = normal
component (index 1 in the paper), column 1 = tangential component (index 2).
The point functions are compiled without the fast-math flags (``njit(exact=True)``), as the
kernels that inline them are: with the flags, the inlined code could still be contracted
differently in a run that compiles the kernels and in one that loads them from numba's cache
(docs/benchmarks.md, "Runs that compile the interface kernels").
Impedances ``Z`` are ``(N, 2)`` arrays ``[rho c_d, rho c_s]`` per side.

Sign conventions (model.md §2): ``n`` points from side + to side -, tractions
``s = sigma . n`` use the same ``n`` on both sides, tension is positive.
"""
from __future__ import annotations

import numpy as np

from ._jit import njit, vectorize


# --------------------------------------------------------------------------
# Point functions: the formulas (scalars; per component where they decouple)
# --------------------------------------------------------------------------
@njit(exact=True)
def macaulay_pt(x):
    """<x> = max(x, 0)."""
    return x if x > 0.0 else 0.0


@njit(exact=True)
def sign_pt(x):
    """sign(x) with sign(0) = 0 (as numpy)."""
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


@njit(exact=True)
def bonded_pt(vp, vm, sp, sm, Zp, Zm):
    """Bonded / stick solution of one component (eq. 5): returns (s_B, v_B)."""
    Zsum = Zp + Zm
    s = (Zm * sp + Zp * sm) / Zsum + Zp * Zm / Zsum * (vm - vp)
    v = (Zp * vp + Zm * vm + sm - sp) / Zsum
    return s, v


@njit(exact=True)
def bonded_jump_pt(jv, js, Zp, Zm):
    """:func:`bonded_pt` as corrections to each side's trace, from the jumps
    [v] = v- - v+ and [s] = s- - s+ of one component: returns
    (s_B - s+, v_B - v+, s_B - s-, v_B - v-).  The bulk facet flux only needs these, and
    they depend on the jumps alone (the matrix-free kernel solves them at facet nodes)."""
    r = 1.0 / (Zp + Zm)
    b = Zp * Zm * r
    return Zp * r * js + b * jv, r * (Zm * jv + js), -Zm * r * js + b * jv, r * (js - Zp * jv)


#: boundary component kinds of :func:`boundary_pt` (``kinds`` of :mod:`hydrofrac.boundary`)
BOUNDARY_KINDS = {"traction": 0, "velocity": 1, "state": 2}


@njit(exact=True)
def boundary_pt(kind, v, s, Z, V, S):
    """Riemann problem between an interior trace (v, s) of one component and an outer
    condition (forms.elastodynamics.outer_riemann_component): returns the corrections
    (s* - s, v* - v).  ``kind`` 0: traction S prescribed; 1: velocity V prescribed; 2: an
    outer state (V, S) of the same impedance Z (bonded)."""
    if kind == 0:
        return S - s, (S - s) / Z
    if kind == 1:
        return Z * (V - v), V - v
    ds, dv, _, _ = bonded_jump_pt(V - v, S - s, Z, Z)
    return ds, dv


@njit(exact=True)
def separation_pt(vp, vm, sp, sm, Zp, Zm, S):
    """Prescribed traction S on one component (eq. 4): returns (S, v+, v-), each side's
    velocity from its own characteristic."""
    return S, vp + (S - sp) / Zp, vm - (S - sm) / Zm


@njit(exact=True)
def friction_traction_pt(k, sB_n, sB_t):
    """Coulomb slip traction k <-s_B^1> sign(s_B^2) (slip along the stick predictor)."""
    return k * macaulay_pt(-sB_n) * sign_pt(sB_t)


@njit(exact=True)
def stick_pt(k, sB_n, sB_t):
    """gamma = 1 (stick) if |s_B^2| <= k <-s_B^1>, else 0 (slip)."""
    return 1.0 if abs(sB_t) <= k * macaulay_pt(-sB_n) else 0.0


@njit(exact=True)
def mode_weights_pt(D, eta, gamma):
    """Fractions (a_B, a_SL, a_S) of bonded(+stick), slip and separation (eqs. 6-7)."""
    return 1.0 - D + D * eta * gamma, D * eta * (1.0 - gamma), D * (1.0 - eta)


@njit(exact=True)
def weighted_pt(aB, aSL, aS, xB, xSL, xS):
    """The damage-model combination of one target value (eqs. 6-7)."""
    return aB * xB + aSL * xSL + aS * xS


@njit(exact=True)
def reduced_impedance_pt(Zp, Zm):
    """Z~ = 2 Z+ Z- / (Z+ + Z-) (eq. 12)."""
    return 2.0 * Zp * Zm / (Zp + Zm)


@njit(exact=True)
def penalty_traction_pt(kappa, delta_n):
    """Normal traction of the penalty baseline (contact by interpenetration, no Riemann
    contact mode): -kappa <-delta> [Pa], added to S^1."""
    return -kappa * macaulay_pt(-delta_n)


@njit(exact=True)
def separation_jump_pt(sB_n, S_n, Zt_n):
    """Normal velocity jump of the separation mode, [[v_S^1]] = (2 / Z~^1)(s_B^1 - S^1)
    (eqs. 11-12)."""
    return 2.0 / Zt_n * (sB_n - S_n)


@njit(exact=True)
def hydraulic_law_pt(on, fp):
    """Eq. (16) at one point as the affine separation law S^1 = p_h S0^1 + cS <-s_B^1>:
    returns (S0^1, cS) = (-on f_p, -on (1 - f_p)), ``on`` the point's loaded fraction (0 on an
    unloaded facet, 1 on a loaded one, its wet fraction behind a finite fluid's front) and
    ``fp`` its pressure factor f_p."""
    return -on * fp, -on * (1.0 - fp)


@njit(exact=True)
def effective_stress_pt(sB_n, sB_t, beta):
    """s_eff = sqrt(<s_B^1>^2 + (beta |s_B^2|)^2)."""
    a = macaulay_pt(sB_n)
    b = beta * sB_t
    return np.sqrt(a * a + b * b)


@njit(exact=True)
def target_damage_pt(s_eff, s_onset, s_bar):
    """D_t: 0 below the onset, linear up to the strength s_bar, then 1."""
    x = (s_eff - s_onset) / (s_bar - s_onset)
    return min(max(x, 0.0), 1.0)


@njit(exact=True)
def damage_rate_pt(D, D_t, tau, a):
    """dD/dt = (1 - exp(-a <D_t - D>)) / tau for D < 1, else 0 (eq. 8)."""
    if D >= 1.0:
        return 0.0
    return (1.0 - np.exp(-a * macaulay_pt(D_t - D))) / tau


@njit(exact=True)
def smoothstep_pt(x):
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


@njit(exact=True)
def eta_regularized_pt(delta_n, w_n, delta0, w0):
    """Regularised contact fraction eta = r(delta') q(w') (model.md §4, fig. 4).

    delta_n : normalised normal opening delta/delta~ (positive = open)
    w_n : normalised separation-velocity jump [[v_S^1]]/v~
    delta0 : maximum penetration delta'_0 < 0;  w0 : velocity width w'_0 > 0
    """
    return smoothstep_pt(delta_n / delta0) * (1.0 - smoothstep_pt(w_n / w0))


@njit(exact=True)
def eta_exact_pt(delta_n, w_n):
    """Unregularised map (fig. 3): contact only when closed and pressed together."""
    return 1.0 if (delta_n <= 0.0 and w_n < 0.0) else 0.0


@njit(exact=True)
def _band_depth_integral(u):
    """G at x = 1 - 1/u: G(x) = int_0^x dx' / (1 - r(x')) with 1 - r = (1 - x)^2 (1 + 2x), in
    closed form (partial fractions): G = u/3 + (2/9) ln u + (2/9) ln(3 - 2/u) - 1/3 - (2/9) ln 3."""
    return u / 3.0 + (2.0 / 9.0) * np.log(u) + (2.0 / 9.0) * np.log((3.0 - 2.0 / u) / 3.0) - 1.0 / 3.0


@njit(exact=True)
def closing_flow_pt(delta, dxi, band):
    """The opening after a closing increment ``dxi`` < 0 of the free opening (the time integral
    of D [[v_S^1]]) from ``delta``, by the exact flow of d(delta)/d(xi) = 1 - eta with eta =
    r(delta') (pressed together, q = 1; model.md §4): linear down to delta = 0, then inside the band
    [-band, 0] (band = |delta'_0| delta~) x = -delta / band obeys dx/d(-xi) = (1 - r(x)) / band,
    and x -> 1 only as -xi -> infinity.  The result is never below -band: the regularised map
    stays admissible by construction, for any step."""
    if dxi >= 0.0:
        return delta + dxi
    if delta + dxi >= 0.0:
        return delta + dxi
    if delta > 0.0:
        x0, s = 0.0, -(delta + dxi)
    else:
        x0, s = -delta / band, -dxi
    if x0 >= 1.0:
        return delta  # at (or, with the clip off, past) the floor: eta = 1, d(delta)/d(xi) = 0
    u0 = 1.0 / (1.0 - x0)
    target = _band_depth_integral(u0) + s / band
    u = max(u0, 3.0 * target + 1.0)  # G ~ u/3: Newton from above the root's neighbourhood
    for _ in range(60):
        g = _band_depth_integral(u) - target
        dg = 1.0 / 3.0 + 2.0 / (9.0 * u) + (4.0 / 9.0) / (u * u * (3.0 - 2.0 / u))
        du = g / dg
        u = max(u - du, 0.5 * (u + u0))
        if abs(du) <= 1e-14 * u:
            break
    return -band * (1.0 - 1.0 / u)


@njit(exact=True)
def combine_point(vp_n, vp_t, vm_n, vm_t, sp_n, sp_t, sm_n, sm_t, Zp_n, Zp_t, Zm_n, Zm_t, k, D, eta, S_n, S_t,
                  sB_n, vB_n, sB_t, vB_t):
    """The combined target values at one point (eqs. 6-7), given its bonded solution
    (s_B, v_B): bonded(+stick), Coulomb slip and separation with traction S, weighted by
    D, eta and the stick flag.  Returns (s*_n, s*_t, v*+_n, v*+_t, v*-_n, v*-_t, gamma)."""
    _, vpS_n, vmS_n = separation_pt(vp_n, vm_n, sp_n, sm_n, Zp_n, Zm_n, S_n)
    _, vpS_t, vmS_t = separation_pt(vp_t, vm_t, sp_t, sm_t, Zp_t, Zm_t, S_t)
    # slip: normal = bonded, tangential = prescribed friction traction
    sSL_t, vpSL_t, vmSL_t = separation_pt(vp_t, vm_t, sp_t, sm_t, Zp_t, Zm_t, friction_traction_pt(k, sB_n, sB_t))
    gamma = stick_pt(k, sB_n, sB_t)
    aB, aSL, aS = mode_weights_pt(D, eta, gamma)
    return (weighted_pt(aB, aSL, aS, sB_n, sB_n, S_n), weighted_pt(aB, aSL, aS, sB_t, sSL_t, S_t),
            weighted_pt(aB, aSL, aS, vB_n, vB_n, vpS_n), weighted_pt(aB, aSL, aS, vB_t, vpSL_t, vpS_t),
            weighted_pt(aB, aSL, aS, vB_n, vB_n, vmS_n), weighted_pt(aB, aSL, aS, vB_t, vmSL_t, vmS_t), gamma)


# --------------------------------------------------------------------------
# Vectorised forms of the point functions (arrays of points)
# --------------------------------------------------------------------------
def _pairs(*arrays):
    """Broadcast to (N, 2) float arrays."""
    out = np.broadcast_arrays(*[np.asarray(a, dtype=float) for a in arrays])
    return [np.ascontiguousarray(a).reshape(-1, 2) for a in out]


def _points(n, *arrays):
    """Broadcast per-point scalars to (n,) float arrays."""
    return [np.ascontiguousarray(np.broadcast_to(np.asarray(a, dtype=float), (n,))) for a in arrays]


@njit(exact=True)
def _bonded_loop(vp, vm, sp, sm, Zp, Zm, s, v):
    for i in range(vp.shape[0]):
        for c in range(2):
            s[i, c], v[i, c] = bonded_pt(vp[i, c], vm[i, c], sp[i, c], sm[i, c], Zp[i, c], Zm[i, c])


@njit(exact=True)
def _separation_loop(vp, vm, sp, sm, Zp, Zm, S, s, v_p, v_m):
    for i in range(vp.shape[0]):
        for c in range(2):
            s[i, c], v_p[i, c], v_m[i, c] = separation_pt(vp[i, c], vm[i, c], sp[i, c], sm[i, c],
                                                          Zp[i, c], Zm[i, c], S[i, c])


def macaulay(x):
    """<x> = max(x, 0)."""
    return np.maximum(x, 0.0)


def bonded(vp, vm, sp, sm, Zp, Zm):
    """Bonded / contact-stick solution (eq. 5): ``v+ = v- = v``.

    Returns ``s_B, v_B``: target traction and the common target velocity, (N, 2)."""
    args = _pairs(vp, vm, sp, sm, Zp, Zm)
    s, v = np.empty_like(args[0]), np.empty_like(args[0])
    _bonded_loop(*args, s, v)
    return s, v


def separation(vp, vm, sp, sm, Zp, Zm, S):
    """Separation with prescribed target traction ``S`` (eq. 4): ``s_S, v_S+, v_S-``."""
    args = _pairs(vp, vm, sp, sm, Zp, Zm, S)
    s, v_p, v_m = (np.empty_like(args[0]) for _ in range(3))
    _separation_loop(*args, s, v_p, v_m)
    return s, v_p, v_m


def slip(vp, vm, sp, sm, Zp, Zm, k, s_B=None, v_B=None):
    """Contact-slip with Coulomb friction ``k``: normal component = bonded; tangential
    traction ``k <-s_B^1> sign(s_B^2)`` (slip along the stick predictor), tangential
    velocities from each side's characteristic."""
    if s_B is None:
        s_B, v_B = bonded(vp, vm, sp, sm, Zp, Zm)
    vp, vm, sp, sm, Zp, Zm, s_B, v_B = _pairs(vp, vm, sp, sm, Zp, Zm, s_B, v_B)
    k, = _points(s_B.shape[0], k)
    S_t = _friction_traction_u(k, s_B[:, 0], s_B[:, 1])
    s_t, vp_t, vm_t = separation(vp[:, 1], vm[:, 1], sp[:, 1], sm[:, 1], Zp[:, 1], Zm[:, 1], S_t)
    s = np.stack([s_B[:, 0], s_t.reshape(-1)], axis=1)
    return s, np.stack([v_B[:, 0], vp_t.reshape(-1)], axis=1), np.stack([v_B[:, 0], vm_t.reshape(-1)], axis=1)


def stick_flag(s_B, k):
    """gamma = 1 (stick) if ``|s_B^2| <= k <-s_B^1>``, else 0 (slip)."""
    s_B = np.asarray(s_B, dtype=float)
    return _stick_u(k, s_B[:, 0], s_B[:, 1])


def reduced_impedance(Zp, Zm):
    """Z~ = 2 Z+ Z- / (Z+ + Z-) (eq. 12), per component."""
    return _reduced_impedance_u(Zp, Zm)


def mode_weights(D, eta, gamma):
    """Fractions (a_B, a_SL, a_S) of bonded(+stick), slip and separation."""
    D, eta, gamma = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (D, eta, gamma)))
    return _aB_u(D, eta, gamma), _aSL_u(D, eta, gamma), _aS_u(D, eta, gamma)


def combine(D, eta, gamma, bonded_sol, slip_sol, sep_sol):
    """Weighted target values ``s*``, ``v*+``, ``v*-`` (eqs. 6-7)."""
    a = [x[:, None] for x in mode_weights(D, eta, gamma)]
    s_B, v_B = bonded_sol
    s_SL, vp_SL, vm_SL = slip_sol
    s_S, vp_S, vm_S = sep_sol
    return (_weighted_u(*a, s_B, s_SL, s_S), _weighted_u(*a, v_B, vp_SL, vp_S),
            _weighted_u(*a, v_B, vm_SL, vm_S))


def effective_stress(s_B, beta):
    """s_eff = sqrt(<s_B^1>^2 + (beta |s_B^2|)^2) (eq. 10); ``s_B`` (..., 2) in local
    (normal, tangential) components.  NaN where ``s_B`` is NaN (a growth criterion's sample
    point outside the mesh), without a warning."""
    s_B = np.asarray(s_B, dtype=float)
    with np.errstate(invalid="ignore"):
        return _effective_stress_u(s_B[..., 0], s_B[..., 1], beta)


def separation_jump(sB_n, S_n, Zt_n):
    """[[v_S^1]] = (2 / Z~^1)(s_B^1 - S^1) (eqs. 11-12), broadcasting."""
    return _separation_jump_u(sB_n, S_n, Zt_n)


def mode_fractions(D, eta, gamma):
    """The four contact-mode fractions (eqs. 6-7), (..., 4): bonded 1 - D, stick D eta gamma,
    slip D eta (1 - gamma), separation D (1 - eta); they add up to one."""
    D, eta, gamma = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (D, eta, gamma)))
    return np.stack([1 - D, D * eta * gamma, D * eta * (1 - gamma), D * (1 - eta)], axis=-1)


def hydraulic_law(fp, loaded, wet=None):
    """Eq. (16) as the affine separation law of the interface kernel,
    S^1 = p_h S0 + cS <-s_B^1>, S^2 = 0: on loaded facets S^1 = -f_p p_h - (1 - f_p) <-s_B^1>,
    elsewhere S = 0.  ``fp`` (nf, nq), ``loaded`` (nf,); returns (S0 (nf, nq, 2), cS (nf, nq)).
    ``wet`` (nf, nq): the fraction of each point behind a finite fluid's front (docs/model.md,
    "A finite fluid volume"); its dry part is as an unloaded crack's, S = 0, so that
    S^1 = -wet [f_p p_h + (1 - f_p) <-s_B^1>].  (:func:`hydraulic_law_pt` at every point.)"""
    fp = np.ascontiguousarray(fp, dtype=float)
    on = np.ascontiguousarray(np.broadcast_to(np.asarray(loaded, dtype=bool)[:, None] * (
        1.0 if wet is None else np.asarray(wet, dtype=float)), fp.shape))
    S0 = np.zeros(fp.shape + (2,))
    cS = np.empty(fp.shape)
    _hydraulic_law_loop(on.reshape(-1), fp.reshape(-1), S0.reshape(-1, 2), cS.reshape(-1))
    return S0, cS


@njit(exact=True)
def _hydraulic_law_loop(on, fp, S0, cS):
    for i in range(fp.size):
        S0[i, 0], cS[i] = hydraulic_law_pt(on[i], fp[i])


def target_damage(s_eff, s_onset, s_bar):
    """D_t: 0 below the onset, linear up to the strength ``s_bar``, then 1."""
    return _target_damage_u(s_eff, s_onset, s_bar)


def damage_rate(D, D_t, tau, a):
    """dD/dt = (1 - exp(-a <D_t - D>)) / tau for D < 1, else 0 (eq. 8)."""
    return _damage_rate_u(D, D_t, tau, a)


def eta_regularized(delta_n, w_n, delta0, w0):
    """Regularised contact fraction ``eta = r(delta') q(w')`` (fig. 4), broadcasting;
    see :func:`eta_regularized_pt`."""
    return _eta_regularized_u(delta_n, w_n, delta0, w0)


def eta_exact(delta_n, w_n):
    """Unregularised map (fig. 3): contact only when closed and pressed together."""
    return _eta_exact_u(delta_n, w_n)


def closing_flow(delta, dxi, band):
    """:func:`closing_flow_pt`, broadcasting."""
    return _closing_flow_u(delta, dxi, band)


@njit(exact=True)
def _aB_pt(D, eta, gamma):
    return mode_weights_pt(D, eta, gamma)[0]


@njit(exact=True)
def _aSL_pt(D, eta, gamma):
    return mode_weights_pt(D, eta, gamma)[1]


@njit(exact=True)
def _aS_pt(D, eta, gamma):
    return mode_weights_pt(D, eta, gamma)[2]


_F2, _F3, _F4 = ("float64(float64, float64)",), ("float64(float64, float64, float64)",), \
    ("float64(float64, float64, float64, float64)",)
_friction_traction_u = vectorize(friction_traction_pt, _F3)
_stick_u = vectorize(stick_pt, _F3)
_reduced_impedance_u = vectorize(reduced_impedance_pt, _F2)
_separation_jump_u = vectorize(separation_jump_pt, _F3)
_aB_u = vectorize(_aB_pt, _F3)
_aSL_u = vectorize(_aSL_pt, _F3)
_aS_u = vectorize(_aS_pt, _F3)
_weighted_u = vectorize(weighted_pt, ("float64(float64, float64, float64, float64, float64, float64)",))
_effective_stress_u = vectorize(effective_stress_pt, _F3)
_target_damage_u = vectorize(target_damage_pt, _F3)
_damage_rate_u = vectorize(damage_rate_pt, _F4)
_eta_regularized_u = vectorize(eta_regularized_pt, _F4)
_eta_exact_u = vectorize(eta_exact_pt, _F2)
_closing_flow_u = vectorize(closing_flow_pt, _F3)


# --------------------------------------------------------------------------
# Frame helpers
# --------------------------------------------------------------------------
def tangent(n):
    """t = n rotated by +90 degrees."""
    return np.stack([-n[..., 1], n[..., 0]], axis=-1)


def to_local(vec, n):
    """Cartesian (N, 2) vectors -> (normal, tangential) components."""
    t = tangent(n)
    return np.stack([np.einsum("...i,...i->...", vec, n), np.einsum("...i,...i->...", vec, t)], axis=-1)


def to_global(loc, n):
    """(normal, tangential) components -> Cartesian vectors."""
    t = tangent(n)
    return loc[..., :1] * n + loc[..., 1:2] * t
