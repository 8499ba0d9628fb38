"""Compiled (numba) kernels of the crack interface: one loop over crack facets and
their Gauss points per Runge-Kutta stage.

* :func:`interface_stage` (one Runge-Kutta stage): per Gauss point, both sides' traces,
  the bonded solution, the separation traction, eta and the combined targets via
  :func:`hydrofrac.riemann.combine_point` (the one implementation of the formulas);
  the flux corrections ``(s* - s).w + (v* - v).(tau n)`` of both sides integrated into a
  residual vector; the state rates (damage, opening, slip);
* :func:`interface_targets`: the same targets stored per point (output, energy terms);
* :func:`apply_block_inverse` multiplies the residual of the touched cells by their
  closed-form inverse mass blocks.

Layouts: the field vector holds 5 values (v_x, v_y, s_xx, s_yy, s_xy) per dof block;
``dofs`` (nf, nb) are block indices of a facet's cell on one side, ``phi`` (nf, nq, nb)
that cell's basis at the facet's Gauss points.  Local components: 0 = normal, 1 = tangent
``t = (-n_y, n_x)``.
"""
from __future__ import annotations

import numpy as np

from ._jit import njit
from .riemann import (bonded_pt, combine_point, damage_rate_pt, effective_stress_pt, eta_exact_pt,
                      eta_regularized_pt, macaulay_pt, target_damage_pt)


@njit
def _trace(X, dofs, phi, f, q, nx, ny):
    """(v_n, v_t, s_n, s_t) of one side at Gauss point q of facet f."""
    u0 = u1 = u2 = u3 = u4 = 0.0
    for j in range(phi.shape[2]):
        a = phi[f, q, j]
        b = 5 * dofs[f, j]
        u0 += a * X[b]
        u1 += a * X[b + 1]
        u2 += a * X[b + 2]
        u3 += a * X[b + 3]
        u4 += a * X[b + 4]
    sx = u2 * nx + u4 * ny
    sy = u4 * nx + u3 * ny
    return u0 * nx + u1 * ny, -u0 * ny + u1 * nx, sx * nx + sy * ny, -sx * ny + sy * nx


@njit
def _point(X, dofs_p, dofs_m, phi_p, phi_m, f, q, nx, ny, Zp, Zm, Zt, k, delta_scale, v_scale, D, delta, S0, cS,
           S_scale, regularized, delta0, w0, kappa):
    """Traces, bonded solution, separation traction, eta and combined targets at Gauss
    point q of facet f.  Returns (vpn, vpt, vmn, vmt, spn, spt, smn, smt, sBn, sBt, Sn, St,
    s*n, s*t, v*+n, v*+t, v*-n, v*-t, gamma, eta, w')."""
    vpn, vpt, spn, spt = _trace(X, dofs_p, phi_p, f, q, nx, ny)
    vmn, vmt, smn, smt = _trace(X, dofs_m, phi_m, f, q, nx, ny)
    sBn, vBn = bonded_pt(vpn, vmn, spn, smn, Zp[f, 0], Zm[f, 0])
    sBt, vBt = bonded_pt(vpt, vmt, spt, smt, Zp[f, 1], Zm[f, 1])
    Sn = S_scale * S0[f, q, 0] + cS[f, q] * macaulay_pt(-sBn)
    St = S_scale * S0[f, q, 1]
    if kappa > 0.0:
        Sn -= kappa * macaulay_pt(-delta[f, q])
    w = 2.0 / Zt[f, 0] * (sBn - Sn) / v_scale[f]  # [[v_S^1]] / v~ (eqs. 11-12)
    dn = delta[f, q] / delta_scale[f]
    if kappa > 0.0:
        e = 0.0
    elif regularized:
        e = eta_regularized_pt(dn, w, delta0, w0)
    else:
        e = eta_exact_pt(dn, w)
    r = combine_point(vpn, vpt, vmn, vmt, spn, spt, smn, smt, Zp[f, 0], Zp[f, 1], Zm[f, 0], Zm[f, 1],
                      k[f], D[f, q], e, Sn, St, sBn, vBn, sBt, vBt)
    return (vpn, vpt, vmn, vmt, spn, spt, smn, smt, sBn, sBt, Sn, St, r[0], r[1], r[2], r[3], r[4], r[5], r[6],
            e, w)


@njit
def interface_targets(X, dofs_p, dofs_m, phi_p, phi_m, normal, Zp, Zm, Zt, k, delta_scale, v_scale,
                      D, delta, S0, cS, S_scale, regularized, delta0, w0, kappa,
                      vp, vm, sp, sm, sB, S, s_star, vp_star, vm_star, eta, gamma, wn):
    """Targets at every Gauss point; outputs (last 12 arguments) are (nf*nq, 2) or (nf*nq,).

    The separation traction is ``S = S_scale S0 + cS <-s_B^1> e_n`` (the hydraulic law, eq. 16,
    is of this form; S0 = cS = 0 for traction-free cracks).  ``kappa`` > 0 switches to the
    penalty baseline: eta = 0 and S^1 += -kappa <-delta>."""
    nf, nq = phi_p.shape[0], phi_p.shape[1]
    for f in range(nf):
        nx, ny = normal[f, 0], normal[f, 1]
        for q in range(nq):
            i = f * nq + q
            o = _point(X, dofs_p, dofs_m, phi_p, phi_m, f, q, nx, ny, Zp, Zm, Zt, k, delta_scale, v_scale, D, delta,
                       S0, cS, S_scale, regularized, delta0, w0, kappa)
            vp[i, 0], vp[i, 1], vm[i, 0], vm[i, 1] = o[0], o[1], o[2], o[3]
            sp[i, 0], sp[i, 1], sm[i, 0], sm[i, 1] = o[4], o[5], o[6], o[7]
            sB[i, 0], sB[i, 1], S[i, 0], S[i, 1] = o[8], o[9], o[10], o[11]
            s_star[i, 0], s_star[i, 1] = o[12], o[13]
            vp_star[i, 0], vp_star[i, 1] = o[14], o[15]
            vm_star[i, 0], vm_star[i, 1] = o[16], o[17]
            gamma[i] = o[18]
            eta[i] = o[19]
            wn[i] = o[20]


@njit
def interface_stage(X, Rc, r, nowned, rates, dofs_p, dofs_m, phi_p, phi_m, cells_p, cells_m, normal, weights, Zp, Zm,
                    Zt, k, delta_scale, v_scale, D, delta, S0, cS, S_scale, regularized, delta0, w0, kappa, beta,
                    s_onset, s_bar, tau, a):
    """One Runge-Kutta stage on the crack facets in one pass: the targets at every Gauss
    point (as :func:`interface_targets`), their flux corrections added to the residuals
    (cell-major Rc for cells below ``nowned``, dof vector r otherwise; :func:`_scatter`),
    and the state rates (3, nf, nq): damage (eqs. 8-10), normal opening and slip from the
    target velocity jump [[v*]] = v*- - v*+."""
    nf, nq = phi_p.shape[0], phi_p.shape[1]
    for f in range(nf):
        nx, ny = normal[f, 0], normal[f, 1]
        for q in range(nq):
            o = _point(X, dofs_p, dofs_m, phi_p, phi_m, f, q, nx, ny, Zp, Zm, Zt, k, delta_scale, v_scale, D, delta,
                       S0, cS, S_scale, regularized, delta0, w0, kappa)
            _flux(Rc, r, dofs_p, dofs_m, phi_p, phi_m, cells_p, cells_m, nowned, f, q, nx, ny, weights[f, q],
                  o[0], o[1], o[2], o[3], o[4], o[5], o[6], o[7], o[12], o[13], o[14], o[15], o[16], o[17])
            Dt = target_damage_pt(effective_stress_pt(o[8], o[9], beta), s_onset, s_bar)
            rates[0, f, q] = damage_rate_pt(D[f, q], Dt, tau[f], a)
            rates[1, f, q] = o[16] - o[14]
            rates[2, f, q] = o[17] - o[15]


@njit
def _scatter(Rc, r, dofs, phi, cells, nowned, f, q, F0, F1, F2, F3, F4):
    """Add one Gauss point's flux to the facet's cell on one side: into the cell-major
    residual Rc[c, j, :] of the matrix-free operator if the cell is one of its first
    ``nowned`` (owned) cells, else into the dof-vector residual r."""
    c = cells[f]
    if c < nowned:
        for j in range(phi.shape[2]):
            a = phi[f, q, j]
            Rc[c, j, 0] += a * F0
            Rc[c, j, 1] += a * F1
            Rc[c, j, 2] += a * F2
            Rc[c, j, 3] += a * F3
            Rc[c, j, 4] += a * F4
    else:
        for j in range(phi.shape[2]):
            a = phi[f, q, j]
            b = 5 * dofs[f, j]
            r[b] += a * F0
            r[b + 1] += a * F1
            r[b + 2] += a * F2
            r[b + 3] += a * F3
            r[b + 4] += a * F4


@njit
def _flux(Rc, r, dofs_p, dofs_m, phi_p, phi_m, cells_p, cells_m, nowned, f, q, nx, ny, w, vpn, vpt, vmn, vmt,
          spn, spt, smn, smt, ssn, sst, vpsn, vpst, vmsn, vmst):
    """Flux corrections of both sides at one Gauss point (weight w) (see :func:`_scatter`): momentum
    ``(s* - s) . w`` and kinematics ``(v* - v) . (tau n)`` with each side's outward normal
    (side +: n, side -: -n; the side - traction is -s*, so both terms change sign)."""
    for side in range(2):
        if side == 0:
            sgn, dsn, dst, dvn, dvt = 1.0, ssn - spn, sst - spt, vpsn - vpn, vpst - vpt
        else:
            sgn, dsn, dst, dvn, dvt = -1.0, ssn - smn, sst - smt, vmsn - vmn, vmst - vmt
        dsx, dsy = dsn * nx - dst * ny, dsn * ny + dst * nx  # to Cartesian
        dvx, dvy = dvn * nx - dvt * ny, dvn * ny + dvt * nx
        mx, my = sgn * nx, sgn * ny
        F0, F1 = w * sgn * dsx, w * sgn * dsy
        F2, F3, F4 = w * dvx * mx, w * dvy * my, w * (dvx * my + dvy * mx)
        if side == 0:
            _scatter(Rc, r, dofs_p, phi_p, cells_p, nowned, f, q, F0, F1, F2, F3, F4)
        else:
            _scatter(Rc, r, dofs_m, phi_m, cells_m, nowned, f, q, F0, F1, F2, F3, F4)


@njit
def kron_inverse(loc, Mref_inv, B, tmp, res):
    """res = (Mref_inv kron B) applied to one cell's values ``loc`` (nb, 5): the closed-form
    inverse mass M_c^{-1} of an affine cell (5 nb^2 + 25 nb flops); ``tmp`` is scratch."""
    nb = loc.shape[0]
    tmp[:] = 0.0
    for a in range(nb):
        for b in range(nb):
            m = Mref_inv[a, b]
            for k in range(5):
                tmp[a, k] += m * loc[b, k]
    for a in range(nb):
        for k in range(5):
            acc = 0.0
            for l in range(5):
                acc += B[k, l] * tmp[a, l]
            res[a, k] = acc


@njit
def apply_block_inverse(out, r, cells, dofs, Mref_inv, Binv):
    """out[idx] += M_c^{-1} r[idx] for each cell c of ``cells`` (idx = its 5 nb values,
    block-major: 5 dofs[c, j] + component), M_c^{-1} = Mref_inv kron Binv[c]."""
    nb = dofs.shape[1]
    loc = np.empty((nb, 5))
    tmp = np.empty((nb, 5))
    res = np.empty((nb, 5))
    for c in cells:
        for b in range(nb):
            base = 5 * dofs[c, b]
            for k in range(5):
                loc[b, k] = r[base + k]
        kron_inverse(loc, Mref_inv, Binv[c], tmp, res)
        for a in range(nb):
            base = 5 * dofs[c, a]
            for k in range(5):
                out[base + k] += res[a, k]
