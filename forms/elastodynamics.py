r"""Weak form of 2D plane-strain elastodynamics in velocity-stress form.

Unknowns are packed in one 5-component DG vector ``U = (v_x, v_y, s_xx, s_yy, s_xy)``.
The discrete problem, per cell K with outward normal n, is (model.md §1):

.. math::

   \int_K \rho \dot v\cdot w + C^{-1}\dot\sigma : \tau
     = \int_K (\nabla\cdot\sigma)\cdot w + \varepsilon(v) : \tau
     + \int_{\partial K} (s^* - \sigma n)\cdot w + (v^* - v)\cdot(\tau n)

where ``s*`` and ``v*`` are the Riemann target traction and velocity on each facet.
Each term below is a small function returning a UFL integrand; the solver
(:mod:`hydrofrac.solver`) assembles them once per mesh.  Edit them here: the
matrix-free kernels are tested against these forms.
"""
from __future__ import annotations

import ufl

from hydrofrac.material import plane_strain_kappa

#: component layout of U
NCOMP = 5


def fields(U):
    """Split the packed state into velocity v (2-vector) and symmetric stress sigma (2x2)."""
    v = ufl.as_vector((U[0], U[1]))
    sigma = ufl.as_matrix(((U[2], U[4]), (U[4], U[3])))
    return v, sigma


def compliance(sigma, lam, mu):
    r"""Plane-strain compliance :math:`C^{-1}:\sigma = (\sigma - \frac{\lambda}{2(\lambda+\mu)}\mathrm{tr}\,\sigma\, I)/(2\mu)`."""
    return (sigma - plane_strain_kappa(lam, mu) * ufl.tr(sigma) * ufl.Identity(2)) / (2 * mu)


def impedances(rho, lam, mu):
    """(Z_d, Z_s) = (rho c_d, rho c_s) as UFL expressions of the cellwise material fields."""
    return ufl.sqrt(rho * (lam + 2 * mu)), ufl.sqrt(rho * mu)


def tangent(n):
    """t = n rotated by +90 degrees."""
    return ufl.as_vector((-n[1], n[0]))


def mass(U, W, rho, lam, mu, dx):
    r"""Mass term :math:`\int \rho\,\dot v\cdot w + C^{-1}\dot\sigma:\tau` (U stands for the rate)."""
    v, sigma = fields(U)
    w, tau = fields(W)
    return (rho * ufl.dot(v, w) + ufl.inner(compliance(sigma, lam, mu), tau)) * dx


def volume(U, W, dx):
    r"""Volume terms (strong form): :math:`\int (\nabla\cdot\sigma)\cdot w + \mathrm{sym}\nabla v : \tau`."""
    v, sigma = fields(U)
    w, tau = fields(W)
    return (ufl.dot(ufl.div(sigma), w) + ufl.inner(ufl.sym(ufl.grad(v)), tau)) * dx


def facet_flux(s_star, v_star, v, sigma, w, tau, n):
    r"""Flux correction on one side of a facet with outward normal n:
    :math:`(s^* - \sigma n)\cdot w + (v^* - v)\cdot(\tau n)`."""
    return ufl.dot(s_star - sigma * n, w) + ufl.dot(v_star - v, tau * n)


def bonded_riemann(vp, vm, sp, sm, n, Zp, Zm):
    r"""Bonded Riemann solution (model.md §2, eq. 5) in Cartesian components.

    ``n`` points from side + to side -; ``Zp = (Z_d+, Z_s+)``, ``Zm`` likewise.
    Per component i (1 = normal, 2 = tangential):

    .. math:: \breve v = \frac{Z^+v^+ + Z^-v^- + s^- - s^+}{Z^+ + Z^-},\quad
              \breve s = \frac{Z^-s^+ + Z^+s^-}{Z^+ + Z^-} + \frac{Z^+Z^-}{Z^+ + Z^-}(v^- - v^+)
    """
    t = tangent(n)
    s_loc, v_loc = [], []
    for e, zp, zm in ((n, Zp[0], Zm[0]), (t, Zp[1], Zm[1])):
        a_vp, a_vm, a_sp, a_sm = ufl.dot(vp, e), ufl.dot(vm, e), ufl.dot(sp, e), ufl.dot(sm, e)
        zsum = zp + zm
        v_loc.append((zp * a_vp + zm * a_vm + a_sm - a_sp) / zsum)
        s_loc.append((zm * a_sp + zp * a_sm) / zsum + zp * zm / zsum * (a_vm - a_vp))
    return s_loc[0] * n + s_loc[1] * t, v_loc[0] * n + v_loc[1] * t


def interior_flux(U, W, rho, lam, mu, dS):
    """Upwind flux on interior facets = bonded Riemann solution with each side's impedances.

    Side '+' has outward normal n('+') (from + to -); side '-' sees -n and traction -s*.
    """
    v, sigma = fields(U)
    w, tau = fields(W)
    n = ufl.FacetNormal(U.ufl_function_space().mesh)("+")
    Zd, Zs = impedances(rho, lam, mu)
    Zp, Zm = (Zd("+"), Zs("+")), (Zd("-"), Zs("-"))
    s_star, v_star = bonded_riemann(v("+"), v("-"), sigma("+") * n, sigma("-") * n, n, Zp, Zm)
    flux_p = facet_flux(s_star, v_star, v("+"), sigma("+"), w("+"), tau("+"), n)
    flux_m = facet_flux(-s_star, v_star, v("-"), sigma("-"), w("-"), tau("-"), -n)
    return (flux_p + flux_m) * dS


def interior_dissipation(U, W, rho, lam, mu, dS):
    r"""Symmetric bilinear form of the energy dissipated per unit time by the upwind
    flux on interior facets; with W = U it is
    :math:`\sum_i \frac{Z_i^+Z_i^-}{Z_i^++Z_i^-}[\![v_i]\!]^2 + \frac{[\![s_i]\!]^2}{Z_i^++Z_i^-}`."""
    n = ufl.FacetNormal(U.ufl_function_space().mesh)("+")
    t = tangent(n)
    Zd, Zs = impedances(rho, lam, mu)
    jumps = []
    for X in (U, W):
        v, sigma = fields(X)
        jumps.append((v("+") - v("-"), sigma("+") * n - sigma("-") * n))
    (dvU, dsU), (dvW, dsW) = jumps
    out = 0
    for e, Z in ((n, Zd), (t, Zs)):
        zp, zm = Z("+"), Z("-")
        out += zp * zm / (zp + zm) * ufl.dot(dvU, e) * ufl.dot(dvW, e) + ufl.dot(dsU, e) * ufl.dot(dsW, e) / (zp + zm)
    return out * dS


# ------------------------------------------------------------------------------------
# Boundary fluxes: a Riemann problem between the interior trace and an outer state.
# Each (normal, tangential) component is one of
#   ("traction", S_i):        s = S_i,                     v = v_i + (S_i - s_i)/Z_i
#   ("velocity", V_i):        v = V_i,                     s = s_i + Z_i (V_i - v_i)
#   ("state", (V_i, S_i)):    bonded with an outer medium of the same impedance (absorbing
#                             when the outer state is the initial state)
# ------------------------------------------------------------------------------------
def outer_riemann_component(kind, vi, si, Z, data):
    """Target (s_i, v_i) of one component for a boundary Riemann problem."""
    if kind == "traction":
        S = data
        return S, vi + (S - si) / Z
    if kind == "velocity":
        V = data
        return si + Z * (V - vi), V
    if kind == "state":
        Ve, Se = data
        return (si + Se) / 2 + Z / 2 * (Ve - vi), (vi + Ve) / 2 + (Se - si) / (2 * Z)
    raise ValueError(f"unknown boundary component kind {kind!r}")


def boundary_targets(v, sigma, n, Zd, Zs, kinds, data):
    """Cartesian (s*, v*) on an exterior facet.

    ``kinds = (normal_kind, tangential_kind)``; ``data`` = per-component data in the
    same order (scalars, or (V, S) pairs for "state").
    """
    t = tangent(n)
    s_loc, v_loc = [], []
    for e, Z, kind, d in ((n, Zd, kinds[0], data[0]), (t, Zs, kinds[1], data[1])):
        s_i, v_i = outer_riemann_component(kind, ufl.dot(v, e), ufl.dot(sigma * n, e), Z, d)
        s_loc.append(s_i)
        v_loc.append(v_i)
    return s_loc[0] * n + s_loc[1] * t, v_loc[0] * n + v_loc[1] * t


def boundary_flux(U, W, rho, lam, mu, n, kinds, data, ds):
    """Boundary flux correction for one boundary condition (see :func:`boundary_targets`)."""
    v, sigma = fields(U)
    w, tau = fields(W)
    Zd, Zs = impedances(rho, lam, mu)
    s_star, v_star = boundary_targets(v, sigma, n, Zd, Zs, kinds, data)
    return facet_flux(s_star, v_star, v, sigma, w, tau, n) * ds


def boundary_dissipation(U, rho, lam, mu, n, kinds, data, ds):
    r"""Energy dissipated per unit time by the upwind flux on exterior facets:
    :math:`\int (s^* - \sigma n)\cdot(v^* - v) = \int \sum_i Z_i (v^*_i - v_i)^2 \ge 0`
    (every boundary Riemann target has :math:`s^*_i - s_i = Z_i (v^*_i - v_i)`).

    Tested against the discrete energy identity: with the cell terms summed, a boundary
    facet contributes :math:`(s^* - \sigma_0 n)\cdot v^* - (s^* - \sigma n)\cdot(v^* - v)`
    to dE/dt, the power of :func:`boundary_power` minus this dissipation."""
    v, sigma = fields(U)
    Zd, Zs = impedances(rho, lam, mu)
    s_star, v_star = boundary_targets(v, sigma, n, Zd, Zs, kinds, data)
    return ufl.dot(s_star - sigma * n, v_star - v) * ds


def boundary_power(U, rho, lam, mu, n, kinds, data, sigma0, ds):
    r"""Power delivered to the body through the boundary, relative to the uniform
    initial stress sigma0: :math:`\int (s^* - \sigma_0 n)\cdot v^*`."""
    v, sigma = fields(U)
    Zd, Zs = impedances(rho, lam, mu)
    s_star, v_star = boundary_targets(v, sigma, n, Zd, Zs, kinds, data)
    return ufl.dot(s_star - sigma0 * n, v_star) * ds
