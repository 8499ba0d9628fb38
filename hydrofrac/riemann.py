"""Exact local Riemann solutions of the contact modes and their combination.

This is the one implementation of model.md §2–4 used by the bulk flux
checks, the interface kernels and the tests.  Everything is vectorised over
points: arrays of shape ``(N, 2)`` hold per-point vectors in the local
interface frame, column 0 = normal component (index 1 in the paper), column 1
= tangential component (index 2).  Impedances ``Z`` are ``(N, 2)`` arrays
``[rho c_d, rho c_s]`` per side.

Sign conventions (model.md §2): ``n`` points from side + to side -, tractions
``s = sigma . n`` use the same ``n`` on both sides, tension is positive.
"""
from __future__ import annotations

import numpy as np


def macaulay(x):
    """<x> = max(x, 0)."""
    return np.maximum(x, 0.0)


# --------------------------------------------------------------------------
# Single-mode Riemann solutions (model.md §2)
# --------------------------------------------------------------------------
def bonded(vp, vm, sp, sm, Zp, Zm):
    """Bonded / contact-stick solution (eq. 5): ``v+ = v- = v``.

    Returns
    -------
    s_B, v_B : target traction and the common target velocity.
    """
    Zsum = Zp + Zm
    v = (Zp * vp + Zm * vm + sm - sp) / Zsum
    s = (Zm * sp + Zp * sm) / Zsum + Zp * Zm / Zsum * (vm - vp)
    return s, v


def separation(vp, vm, sp, sm, Zp, Zm, S):
    """Separation with prescribed target traction ``S`` (eq. 4).

    Returns
    -------
    s_S, v_S_plus, v_S_minus
    """
    S = np.broadcast_to(S, np.shape(sp))
    return S.copy(), vp + (S - sp) / Zp, vm - (S - sm) / Zm


def slip(vp, vm, sp, sm, Zp, Zm, k, s_B=None, v_B=None):
    """Contact-slip with Coulomb friction ``k``.

    Normal component = bonded; tangential traction
    ``k <-s_B^1> sign(s_B^2)`` (slip direction = stick-predictor direction);
    tangential velocities follow from each side's characteristic.
    """
    if s_B is None:
        s_B, v_B = bonded(vp, vm, sp, sm, Zp, Zm)
    k = np.asarray(k, dtype=float)
    s = np.empty_like(s_B)
    s[:, 0] = s_B[:, 0]
    s[:, 1] = k * macaulay(-s_B[:, 0]) * np.sign(s_B[:, 1])
    v_p = np.empty_like(s_B)
    v_m = np.empty_like(s_B)
    v_p[:, 0] = v_B[:, 0]
    v_m[:, 0] = v_B[:, 0]
    v_p[:, 1] = vp[:, 1] + (s[:, 1] - sp[:, 1]) / Zp[:, 1]
    v_m[:, 1] = vm[:, 1] - (s[:, 1] - sm[:, 1]) / Zm[:, 1]
    return s, v_p, v_m


def stick_flag(s_B, k):
    """gamma = 1 (stick) if ``|s_B^2| <= k <-s_B^1>``, else 0 (slip)."""
    return (np.abs(s_B[:, 1]) <= np.asarray(k) * macaulay(-s_B[:, 0])).astype(float)


def reduced_impedance(Zp, Zm):
    """Z~ = 2 Z+ Z- / (Z+ + Z-) (eq. 12), per component."""
    return 2.0 * Zp * Zm / (Zp + Zm)


# --------------------------------------------------------------------------
# Combination: the interfacial damage model (eqs. 6-7)
# --------------------------------------------------------------------------
def mode_weights(D, eta, gamma):
    """Fractions (a_B, a_SL, a_S) of bonded(+stick), slip and separation."""
    a_B = 1.0 - D + D * eta * gamma
    a_SL = D * eta * (1.0 - gamma)
    a_S = D * (1.0 - eta)
    return a_B, a_SL, a_S


def combine(D, eta, gamma, bonded_sol, slip_sol, sep_sol):
    """Weighted target values ``s*``, ``v*+``, ``v*-`` (eqs. 6-7)."""
    a_B, a_SL, a_S = (a[:, None] for a in mode_weights(D, eta, gamma))
    s_B, v_B = bonded_sol
    s_SL, vp_SL, vm_SL = slip_sol
    s_S, vp_S, vm_S = sep_sol
    s = a_B * s_B + a_SL * s_SL + a_S * s_S
    vp = a_B * v_B + a_SL * vp_SL + a_S * vp_S
    vm = a_B * v_B + a_SL * vm_SL + a_S * vm_S
    return s, vp, vm


# --------------------------------------------------------------------------
# Damage law (eqs. 8-10)
# --------------------------------------------------------------------------
def effective_stress(s_B, beta):
    """s_eff = sqrt(<s_B^1>^2 + (beta |s_B^2|)^2)."""
    return np.sqrt(macaulay(s_B[:, 0]) ** 2 + (beta * s_B[:, 1]) ** 2)


def target_damage(s_eff, s_onset, s_bar):
    """D_t: 0 below the onset, linear up to the strength ``s_bar``, then 1."""
    return np.clip((s_eff - s_onset) / (s_bar - s_onset), 0.0, 1.0)


def damage_rate(D, D_t, tau, a):
    """dD/dt = (1 - exp(-a <D_t - D>)) / tau for D < 1, else 0 (eq. 8)."""
    rate = (1.0 - np.exp(-a * macaulay(D_t - D))) / tau
    return np.where(D < 1.0, rate, 0.0)


# --------------------------------------------------------------------------
# Contact fraction eta in the (delta', w') phase space (model.md §4)
# --------------------------------------------------------------------------
def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def eta_regularized(delta_n, w_n, delta0, w0):
    """Regularised contact fraction ``eta = r(delta') q(w')`` (fig. 4).

    Parameters
    ----------
    delta_n : normalised normal opening delta/delta~ (positive = open)
    w_n : normalised separation-velocity jump [[v_S^1]]/v~
    delta0 : maximum penetration delta'_0 < 0
    w0 : velocity width w'_0 > 0
    """
    r = _smoothstep(np.asarray(delta_n) / delta0)  # 0 at delta'=0, 1 at delta'=delta0
    q = 1.0 - _smoothstep(np.asarray(w_n) / w0)
    return r * q


def eta_exact(delta_n, w_n):
    """Unregularised map (fig. 3): contact only when closed and pressed together."""
    return ((np.asarray(delta_n) <= 0.0) & (np.asarray(w_n) < 0.0)).astype(float)


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
