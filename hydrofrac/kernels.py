"""Compiled (numba) kernels of the crack interface: one loop over crack facets and
their Gauss points per Runge-Kutta stage.

* :func:`interface_stage` (one Runge-Kutta stage): per Gauss point, both sides' traces,
  the bonded solution, the separation traction, eta and the combined targets via
  :func:`hydrofrac.riemann.combine_point` (the one implementation of the formulas);
  the flux corrections ``(s* - s).w + (v* - v).(tau n)`` of both sides integrated into a
  residual vector; the state rates (damage, opening, slip);
* :func:`ader_interface_step`: ADER's stages of one step, with the states between them, in one
  call (:meth:`hydrofrac.interface.Interface.ader_step`);
* :func:`interface_targets`: the same targets stored per point (output, energy terms);
* :func:`advance_state`: a stage's or step's state from its increment, admissible (the
  exact closing flow through the contact band, damage in [D_n, 1], the counted opening clip);
* :func:`apply_block_inverse` multiplies the residual of the touched cells by their
  closed-form inverse mass blocks.

The kernels are compiled without the fast-math flags (``njit(exact=True)``): with them, a run
that compiles these kernels and a run that loads them from numba's cache differed in the last
digit (the contraction of the inlined point functions into fused multiply-adds is not the
same in the two), and so a fresh install's first run differed from the next ones
(docs/benchmarks.md, "Runs that compile the interface kernels").  Without them the two agree,
and the kernels are as fast.

Layouts: the field vector holds 5 values (v_x, v_y, s_xx, s_yy, s_xy) per dof block; the
per-facet data (normal, impedances, scales, weights, both cells' basis at the Gauss points,
cells and dof blocks) are packed into two records per facet (:func:`pack_facets`).  Local components: 0 = normal, 1 = tangent
``t = (-n_y, n_x)``.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

from ._jit import njit, prefetch
from .riemann import (bonded_pt, closing_flow_pt, combine_point, damage_rate_pt, effective_stress_pt, eta_exact_pt,
                      eta_regularized_pt, macaulay_pt, mode_weights_pt, penalty_traction_pt, separation_jump_pt,
                      target_damage_pt)


# Packed per-facet records (built once by :func:`pack_facets`): the stage streams through
# two arrays instead of some twenty, which keeps the hardware prefetcher ahead when the
# interface pass runs right after the bulk pass has evicted its data from the caches.
#   P (nf, 11 + nq + 2 nq nb) float: n_x, n_y, Zp_n, Zp_t, Zm_n, Zm_t, Z~_n, k, delta~, v~, tau~,
#       quadrature weights (nq), phi_+ (nq, nb), phi_- (nq, nb)
#   I (nf, 2 + 2 nb) int: cell_+, cell_-, dofs_+ (nb), dofs_- (nb)
_NX, _NY, _ZPN, _ZPT, _ZMN, _ZMT, _ZT, _K, _DS, _VS, _TAU, _W = range(12)
WEIGHTS = _W  # the first of the nq quadrature weights' columns of the packed facet data (the flux's only use)

# The named records the kernels take and return (numba compiles their fields as constants of
# the record type, so a name costs nothing at run time):
#: the crack facets: the packed records and the number of Gauss points and basis functions
Facets = namedtuple("Facets", "P I nq nb")
#: the interface state of a stage: damage D and normal opening delta, (nf, nq) each
State = namedtuple("State", "D delta")
#: the separation law S = scale S0 + cS <-s_B^1> e_n: S0 (nf, nq, 2), cS (nf, nq)
Separation = namedtuple("Separation", "S0 cS scale")
#: the contact map (eta exact or regularised; kappa > 0: the penalty baseline) and the damage law
Laws = namedtuple("Laws", "regularized delta0 w0 kappa beta s_onset s_bar a")
#: one Gauss point: traces of both sides, bonded traction, separation traction, the targets
#: s*, v*+, v*- (local components _n, _t), the stick flag, eta and w' = [[v_S^1]] / v~
Point = namedtuple("Point", "vpn vpt vmn vmt spn spt smn smt sBn sBt Sn St ssn sst vpsn vpst vmsn vmst gamma eta w")
#: the per-point output arrays of :func:`interface_targets`: (nf*nq, 2) or (nf*nq,)
Targets = namedtuple("Targets", "vp vm sp sm s_B S s_star vp_star vm_star eta gamma w")


def pack_facets(normal, Zp, Zm, Zt, k, delta_scale, v_scale, tau, weights, phi_p, phi_m, cells_p, cells_m,
                dofs_p, dofs_m):
    """The (P, I) records of the crack facets (layout above)."""
    nf, nq, nb = phi_p.shape
    P = np.empty((nf, _W + nq + 2 * nq * nb))
    P[:, _NX], P[:, _NY] = normal[:, 0], normal[:, 1]
    P[:, _ZPN], P[:, _ZPT], P[:, _ZMN], P[:, _ZMT] = Zp[:, 0], Zp[:, 1], Zm[:, 0], Zm[:, 1]
    P[:, _ZT], P[:, _K], P[:, _DS], P[:, _VS], P[:, _TAU] = Zt[:, 0], k, delta_scale, v_scale, tau
    P[:, _W:_W + nq] = weights
    P[:, _W + nq:_W + nq + nq * nb] = phi_p.reshape(nf, nq * nb)
    P[:, _W + nq + nq * nb:] = phi_m.reshape(nf, nq * nb)
    I = np.empty((nf, 2 + 2 * nb), dtype=np.int64)
    I[:, 0], I[:, 1] = cells_p, cells_m
    I[:, 2:2 + nb], I[:, 2 + nb:] = dofs_p, dofs_m
    return P, I


@njit(exact=True)
def _traces(X, I, P, f, nq, nb, T):
    """T[side, q, :] = the 5 field values of side (0: +, 1: -) at every Gauss point q of facet f.
    The loop over the basis runs outside the one over the points, so each of a cell's values is
    read once for all nq points and the nq x 5 sums grow side by side; each sum still adds its
    terms in the basis' order, so the values are the same bits as one point at a time (2x faster
    at p = 2 and 3, docs/benchmarks.md, "The crack facets' pass, basis-major")."""
    for side in range(2):
        for q in range(nq):
            for k in range(5):
                T[side, q, k] = 0.0
        po = _W + nq + side * nq * nb
        do = 2 + side * nb
        for j in range(nb):
            b = 5 * I[f, do + j]
            x0, x1, x2, x3, x4 = X[b], X[b + 1], X[b + 2], X[b + 3], X[b + 4]
            for q in range(nq):
                a = P[f, po + q * nb + j]
                T[side, q, 0] += a * x0
                T[side, q, 1] += a * x1
                T[side, q, 2] += a * x2
                T[side, q, 3] += a * x3
                T[side, q, 4] += a * x4


@njit(exact=True)
def _local(T, side, q, nx, ny):
    """(v_n, v_t, s_n, s_t) of side (0: +, 1: -) at Gauss point q from its values :func:`_traces`."""
    u0, u1, u2, u3, u4 = T[side, q, 0], T[side, q, 1], T[side, q, 2], T[side, q, 3], T[side, q, 4]
    sx = u2 * nx + u4 * ny
    sy = u4 * nx + u3 * ny
    return u0 * nx + u1 * ny, -u0 * ny + u1 * nx, sx * nx + sy * ny, -sx * ny + sy * nx


@njit(exact=True)
def _point(T, P, f, q, D, delta, S0, cS, S_scale, regularized, delta0, w0, kappa):
    """Traces (from the facet's values ``T``, :func:`_traces`), bonded solution, separation
    traction, eta and combined targets at Gauss point q of facet f, as a :data:`Point`.  (The
    callers unpack their records into these arguments once per pass: with the records passed down to the point level the stage took
    0.56 instead of 0.40 us per crack facet, measured on the full-size intersection mesh.)"""
    nx, ny = P[f, _NX], P[f, _NY]
    Zpn, Zpt, Zmn, Zmt = P[f, _ZPN], P[f, _ZPT], P[f, _ZMN], P[f, _ZMT]
    vpn, vpt, spn, spt = _local(T, 0, q, nx, ny)
    vmn, vmt, smn, smt = _local(T, 1, q, nx, ny)
    sBn, vBn = bonded_pt(vpn, vmn, spn, smn, Zpn, Zmn)
    sBt, vBt = bonded_pt(vpt, vmt, spt, smt, Zpt, Zmt)
    Sn = S_scale * S0[f, q, 0] + cS[f, q] * macaulay_pt(-sBn)
    St = S_scale * S0[f, q, 1]
    if kappa > 0.0:
        Sn += penalty_traction_pt(kappa, delta[f, q])
    w = separation_jump_pt(sBn, Sn, P[f, _ZT]) / P[f, _VS]  # [[v_S^1]] / v~ (eqs. 11-12)
    dn = delta[f, q] / P[f, _DS]
    if kappa > 0.0:
        e = 0.0
    elif regularized:
        e = eta_regularized_pt(dn, w, delta0, w0)
    else:
        e = eta_exact_pt(dn, w)
    r = combine_point(vpn, vpt, vmn, vmt, spn, spt, smn, smt, Zpn, Zpt, Zmn, Zmt,
                      P[f, _K], D[f, q], e, Sn, St, sBn, vBn, sBt, vBt)
    return Point(vpn, vpt, vmn, vmt, spn, spt, smn, smt, sBn, sBt, Sn, St, r[0], r[1], r[2], r[3], r[4], r[5],
                 r[6], e, w)


@njit(exact=True)
def interface_targets(X, F, Z, Sep, L, T):
    """Targets at every Gauss point into the :data:`Targets` arrays ``T``.

    The separation traction is ``S = scale S0 + cS <-s_B^1> e_n`` (the hydraulic law, eq. 16,
    is of this form; S0 = cS = 0 for traction-free cracks).  ``L.kappa`` > 0 switches to the
    penalty baseline: eta = 0 and S^1 += -kappa <-delta>."""
    P, I, nq, nb, D, delta, S0, cS, scale = F.P, F.I, F.nq, F.nb, Z.D, Z.delta, Sep.S0, Sep.cS, Sep.scale
    reg, d0, w0, kappa = L.regularized, L.delta0, L.w0, L.kappa
    Tf = np.empty((2, nq, 5))
    for f in range(P.shape[0]):
        _traces(X, I, P, f, nq, nb, Tf)
        for q in range(nq):
            i = f * nq + q
            o = _point(Tf, P, f, q, D, delta, S0, cS, scale, reg, d0, w0, kappa)
            T.vp[i, 0], T.vp[i, 1], T.vm[i, 0], T.vm[i, 1] = o.vpn, o.vpt, o.vmn, o.vmt
            T.sp[i, 0], T.sp[i, 1], T.sm[i, 0], T.sm[i, 1] = o.spn, o.spt, o.smn, o.smt
            T.s_B[i, 0], T.s_B[i, 1], T.S[i, 0], T.S[i, 1] = o.sBn, o.sBt, o.Sn, o.St
            T.s_star[i, 0], T.s_star[i, 1] = o.ssn, o.sst
            T.vp_star[i, 0], T.vp_star[i, 1] = o.vpsn, o.vpst
            T.vm_star[i, 0], T.vm_star[i, 1] = o.vmsn, o.vmst
            T.gamma[i] = o.gamma
            T.eta[i] = o.eta
            T.w[i] = o.w


@njit(exact=True)
def interface_stage(X, Rc, r, nowned, rates, F, Z, Sep, L):
    """One Runge-Kutta stage on the crack facets in one pass: the targets at every Gauss
    point (as :func:`interface_targets`), their flux corrections added to the residuals
    (cell-major Rc for cells below ``nowned``, dof vector r otherwise; :func:`_scatter`),
    and the rates (4, nf, nq): damage (eqs. 8-10), normal opening and slip from the
    target velocity jump [[v*]] = v*- - v*+, and the free opening rate D [[v_S^1]] that the
    opening would have in the separation mode (eta = 0), which the exact closing flow
    integrates (:meth:`hydrofrac.interface.Interface.advance`)."""
    P, I, nq, nb, D, delta, S0, cS, scale = F.P, F.I, F.nq, F.nb, Z.D, Z.delta, Sep.S0, Sep.cS, Sep.scale
    reg, d0, w0, kappa, beta, s_onset, s_bar, a = L
    nf = P.shape[0]
    Tf = np.empty((2, nq, 5))  # the facet's values at its Gauss points (_traces)
    Ff = np.empty((2, nq, 5))  # and their flux corrections (_flux), scattered per facet
    for f in range(nf):
        if f + _AHEAD < nf:
            _prefetch_cells(X, Rc, I, f + _AHEAD, nb, nowned)
        nx, ny = P[f, _NX], P[f, _NY]
        _traces(X, I, P, f, nq, nb, Tf)
        for q in range(nq):
            o = _point(Tf, P, f, q, D, delta, S0, cS, scale, reg, d0, w0, kappa)
            _flux(Ff, q, nx, ny, P[f, _W + q], o.vpn, o.vpt, o.vmn, o.vmt,
                  o.spn, o.spt, o.smn, o.smt, o.ssn, o.sst, o.vpsn, o.vpst, o.vmsn, o.vmst)
            Dt = target_damage_pt(effective_stress_pt(o.sBn, o.sBt, beta), s_onset, s_bar)
            rates[0, f, q] = damage_rate_pt(D[f, q], Dt, P[f, _TAU], a)
            rates[1, f, q] = o.vmsn - o.vpsn
            rates[2, f, q] = o.vmst - o.vpst
            rates[3, f, q] = D[f, q] * o.w * P[f, _VS]  # the free opening rate D [[v_S^1]] (eta = 0)
        _scatter(Rc, r, P, I, nowned, f, nq, nb, Ff)


# Flat entry points: the driver passes the records' fields as separate arguments, because
# numba's dispatcher types a namedtuple argument in Python (tens of µs a call, measured in the
# demo's profile: ~1 ms a step), while arrays and scalars take its compiled fast path; the
# records are rebuilt inside the compiled code, where they cost nothing.
@njit(exact=True)
def interface_stage_flat(X, Rc, r, nowned, rates, P, I, nq, nb, D, delta, S0, cS, scale,
                         reg, d0, w0, kappa, beta, s_onset, s_bar, a):
    """:func:`interface_stage` with the fields of its records as arguments."""
    interface_stage(X, Rc, r, nowned, rates, Facets(P, I, nq, nb), State(D, delta), Separation(S0, cS, scale),
                    Laws(reg, d0, w0, kappa, beta, s_onset, s_bar, a))


@njit(exact=True)
def interface_targets_flat(X, P, I, nq, nb, D, delta, S0, cS, scale, reg, d0, w0, kappa, beta, s_onset, s_bar, a,
                           vp, vm, sp, sm, s_B, S, s_star, vp_star, vm_star, eta, gamma, w):
    """:func:`interface_targets` with the fields of its records as arguments."""
    interface_targets(X, Facets(P, I, nq, nb), State(D, delta), Separation(S0, cS, scale),
                      Laws(reg, d0, w0, kappa, beta, s_onset, s_bar, a),
                      Targets(vp, vm, sp, sm, s_B, S, s_star, vp_star, vm_star, eta, gamma, w))


@njit(exact=True)
def _combine(out, dt, coefs, rates, n):
    """out = sum_j (dt a_j) r_j over the first ``n`` rates with a nonzero coefficient a_j, in
    their order; zero if none.  One flat loop a term, in place (the array expressions
    ``out += c * rates[j]`` made a temporary a term and took 4-5x as long), with the same
    operations on every value, so the same bits."""
    o = out.reshape(-1)
    first = True
    for j in range(n):
        if coefs[j] == 0.0:
            continue
        c = dt * coefs[j]
        r = rates[j].reshape(-1)
        if first:
            for i in range(o.size):
                o[i] = c * r[i]
            first = False
        else:
            for i in range(o.size):
                o[i] += c * r[i]
    if first:
        o[:] = 0.0


@njit(exact=True)
def ader_interface_step(X, Q, rows, R, r, nowned, A, b, dt, PW, I, nq, nb, z0, S0, cS, scales, reg, d0, w0, kappa,
                        beta, s_onset, s_bar, a, D_n, delta_scale, delta0, flow, clip):
    """ADER's whole step on the crack facets in one call (:meth:`hydrofrac.interface.Interface.
    ader_step`): stage k (of the explicit scheme A, b) takes the traces of ``X`` (rows[k] < 0)
    or of the Taylor values ``Q[rows[k]]``, the state z0 + dt sum_j A_kj r_j made admissible
    (:func:`advance_state`), the facet records ``PW[k]`` (their weights times b_k dt) and the
    separation law (S0[k], cS[k] or the one pair for all, scales[k]); its flux goes into R and
    r (:func:`interface_stage`).  Returns the admissible state z0 + dt sum_k b_k r_k, the
    openings clipped over the step and the deepest clip: the operations of the stage-by-stage
    driver, one after the other, so the same bits without its per-stage calls."""
    ns = b.size
    nf = z0.shape[1]
    rates = np.empty((ns, 4, nf, nq))
    inc = np.empty((4, nf, nq))
    count = 0
    depth = 0.0
    L = Laws(reg, d0, w0, kappa, beta, s_onset, s_bar, a)
    for k in range(ns):
        z = z0
        if k:
            _combine(inc, dt, A[k], rates, k)
            z, n, d = advance_state(z0, inc, D_n, delta_scale, delta0, flow, clip)
            count += n
            depth = max(depth, d)
        m = k if S0.shape[0] > 1 else 0
        F, Z, Sep = Facets(PW[k], I, nq, nb), State(z[0], z[1]), Separation(S0[m], cS[m], scales[k])
        if rows[k] < 0:
            interface_stage(X, R, r, nowned, rates[k], F, Z, Sep, L)
        else:
            interface_stage(Q[rows[k]], R, r, nowned, rates[k], F, Z, Sep, L)
    _combine(inc, dt, b, rates, ns)
    z, n, d = advance_state(z0, inc, D_n, delta_scale, delta0, flow, clip)
    return z, count + n, max(depth, d)


#: facets ahead whose cells' field values and residual rows are prefetched: the interface
#: pass follows the bulk pass, which has pushed them out of the nearer caches
_AHEAD = 6


@njit(exact=True)
def _prefetch_cells(X, Rc, I, f, nb, nowned):
    for side in range(2):
        c = I[f, side]
        for j in range(nb):
            prefetch(X, 5 * I[f, 2 + side * nb + j])
        if c < nowned:
            for o in range(0, 5 * nb, 8):
                prefetch(Rc, c * 5 * nb + o)


@njit(exact=True)
def _scatter(Rc, r, P, I, nowned, f, nq, nb, Ff):
    """Add facet f's flux corrections ``Ff`` (side, Gauss point, 5) to its cells: into the
    cell-major residual Rc[c, j, :] of the matrix-free operator if the cell is one of its first
    ``nowned`` (owned) cells, else into the dof-vector residual r.  Each residual value is read
    once and gets its Gauss points' terms in their order, the same sums as one point at a time."""
    Rf = Rc.reshape(-1)  # (cell c's node j at 5 (nb c + j), as in the dof vector of a cell-contiguous space)
    for side in range(2):
        c = I[f, side]
        po = _W + nq + side * nq * nb
        do = 2 + side * nb
        owned = c < nowned
        out = Rf if owned else r
        for j in range(nb):
            b = 5 * (nb * c + j) if owned else 5 * I[f, do + j]
            r0, r1, r2, r3, r4 = out[b], out[b + 1], out[b + 2], out[b + 3], out[b + 4]
            for q in range(nq):
                a = P[f, po + q * nb + j]
                r0 += a * Ff[side, q, 0]
                r1 += a * Ff[side, q, 1]
                r2 += a * Ff[side, q, 2]
                r3 += a * Ff[side, q, 3]
                r4 += a * Ff[side, q, 4]
            out[b], out[b + 1], out[b + 2], out[b + 3], out[b + 4] = r0, r1, r2, r3, r4


@njit(exact=True)
def _flux(Ff, q, nx, ny, w, vpn, vpt, vmn, vmt, spn, spt, smn, smt, ssn, sst, vpsn, vpst, vmsn, vmst):
    """Flux corrections of both sides at Gauss point q (weight w) into ``Ff[side, q]`` (see
    :func:`_scatter`): momentum ``(s* - s) . w`` and kinematics ``(v* - v) . (tau n)`` with each
    side's outward normal (side +: n, side -: -n; the side - traction is -s*, so both terms change
    sign).  The values come as scalars (fields of a :data:`Point`), like the other point-level
    arguments (see :func:`_point`)."""
    for side in range(2):
        if side == 0:
            sgn, dsn, dst, dvn, dvt = 1.0, ssn - spn, sst - spt, vpsn - vpn, vpst - vpt
        else:
            sgn, dsn, dst, dvn, dvt = -1.0, ssn - smn, sst - smt, vmsn - vmn, vmst - vmt
        dsx, dsy = dsn * nx - dst * ny, dsn * ny + dst * nx  # to Cartesian
        dvx, dvy = dvn * nx - dvt * ny, dvn * ny + dvt * nx
        mx, my = sgn * nx, sgn * ny
        Ff[side, q, 0], Ff[side, q, 1] = w * sgn * dsx, w * sgn * dsy
        Ff[side, q, 2], Ff[side, q, 3], Ff[side, q, 4] = w * dvx * mx, w * dvy * my, w * (dvx * my + dvy * mx)


@njit(exact=True)
def interface_power(vp, vm, vp_star, vm_star, s_star, s_B, S, D, eta, gamma, Zp, Zm, Zt_n, normal, nq, s0, w):
    """This rank's four power terms of the crack facets at their Gauss points, in the order of
    :data:`hydrofrac.energy.DISSIPATION_TERMS` (:meth:`hydrofrac.interface.Interface.
    local_dissipation_rates` says what each is): friction s*_t [[v*]]_t; the normal power
    beyond the separation traction's work, (s*_n - (sigma0 n)_n) [[v*]]_n - (S_n - (sigma0 n)_n)
    a_S [[v_S]]_n; the characteristic dissipation of the traces, sum Z (v* - v)^2 over both
    sides and components; the initial shear traction's power beyond the separation work,
    (sigma0 n)_t [[v*]]_t - (S_n - (sigma0 n)_n) a_S [[v_S]]_n.  Point arrays in local
    components, (N, 2) or (N,); ``Zt_n`` (facets,) the reduced normal impedance; ``w`` (N,)
    the quadrature weights."""
    out = np.zeros(4)
    for i in range(D.shape[0]):
        f = i // nq
        nx, ny = normal[f, 0], normal[f, 1]
        tx, ty = s0[0, 0] * nx + s0[0, 1] * ny, s0[1, 0] * nx + s0[1, 1] * ny  # sigma0 n
        s0n, s0t = tx * nx + ty * ny, -tx * ny + ty * nx
        jn, jt = vm_star[i, 0] - vp_star[i, 0], vm_star[i, 1] - vp_star[i, 1]
        a_S = mode_weights_pt(D[i], eta[i], gamma[i])[2]
        p_sep = (S[i, 0] - s0n) * a_S * separation_jump_pt(s_B[i, 0], S[i, 0], Zt_n[f])
        flux = 0.0
        for k in range(2):
            dp, dm = vp_star[i, k] - vp[i, k], vm_star[i, k] - vm[i, k]
            flux += Zp[i, k] * dp * dp + Zm[i, k] * dm * dm
        out[0] += w[i] * s_star[i, 1] * jt
        out[1] += w[i] * ((s_star[i, 0] - s0n) * jn - p_sep)
        out[2] += w[i] * flux
        out[3] += w[i] * (s0t * jt - p_sep)
    return out


@njit(exact=True)
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


@njit(exact=True)
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


@njit(exact=True)
def advance_state(z0, inc, D_n, delta_scale, delta0, flow, clip):
    """The interface state z0 + inc (damage, opening, slip; (3, nf, nq)), admissible, in one
    pass (:meth:`hydrofrac.interface.Interface.advance`): where ``flow`` and the free opening
    closes (inc[3] < 0), the opening by the exact closing flow through the band
    |delta'_0| delta~ (:func:`hydrofrac.riemann.closing_flow_pt`); damage clipped to
    [D_n, 1]; with ``clip``, the opening held at the floor delta'_0 delta~.  Returns
    (z, openings clipped, the deepest clip relative to the floor)."""
    z = np.empty_like(z0)
    count = 0
    depth = 0.0
    for f in range(z0.shape[1]):
        band = abs(delta0) * delta_scale[f]
        floor = delta0 * delta_scale[f]
        for q in range(z0.shape[2]):
            z[0, f, q] = min(max(z0[0, f, q] + inc[0, f, q], D_n[f, q]), 1.0)
            z[2, f, q] = z0[2, f, q] + inc[2, f, q]
            op = z0[1, f, q] + inc[1, f, q]
            if flow and inc[3, f, q] < 0:
                op = closing_flow_pt(z0[1, f, q], inc[3, f, q], band)
            if clip and op < floor:
                count += 1
                depth = max(depth, (floor - op) / abs(floor))
                op = floor
            z[1, f, q] = op
    return z, count, depth
