"""Matrix-free bulk DG operator: cell-local compiled kernels for the volume terms, the
upwind (bonded Riemann) flux on interior facets and the closed-form inverse mass (numba here;
the volume, facet, ADER and cell energy loops also in C, :mod:`hydrofrac.native`, the default).

``MatrixFreeOperator.apply(x, out)`` computes ``out = M^{-1} (K_vol + K_int) x`` on the
owned cells, for the same weak form as :mod:`hydrofrac.forms.elastodynamics` (the tests
check it against the assembled forms to round-off).  Boundary facets keep their
assembled (sparse, boundary cells only) operator in the solver; crack facets are left
out here as in the assembled bulk flux (:mod:`hydrofrac.interface` handles them).

Per cell (affine triangles): the volume terms use the reference derivative matrices
``S_r[i, j] = int phi_i d_r phi_j`` and the cell's inverse Jacobian; each interior facet
solves the bonded Riemann problem (:func:`hydrofrac.riemann.bonded_jump_pt`) at its p+1 nodes
(one node list per ordered pair of reference vertices) and integrates the flux
corrections into the owned sides with the facet mass matrix, which equals Gauss
quadrature because the bonded solution is linear with facet-constant coefficients.
The kernels are compiled per element size (:func:`_kernels`) so that the small loops
unroll.
Facets between an owned and a ghost cell are computed on both ranks, each keeping its own
side, so no reverse scatter is needed; ghost values must be current (forward scatter).
"""
from __future__ import annotations

import functools
from typing import Dict, NamedTuple

import numpy as np
from mpi4py import MPI

from . import compat, native
from ._jit import HAVE_NUMBA, njit
from .element import line_quadrature, triangle_quadrature
from .riemann import bonded_jump_pt, boundary_pt

_REF_VERTICES = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])


@njit
def _node_jumps(X, b, e, nx, ny):
    """Jumps [u] = u- - u+ between the values at X[b:b+5] (side +) and X[e:e+5] (side -) in
    the facet frame (n, t = (-ny, nx)): ([v_n], [v_t], [s_n], [s_t]), s = sigma n."""
    j0 = X[e] - X[b]
    j1 = X[e + 1] - X[b + 1]
    j2 = X[e + 2] - X[b + 2]
    j3 = X[e + 3] - X[b + 3]
    j4 = X[e + 4] - X[b + 4]
    tx, ty = j2 * nx + j4 * ny, j4 * nx + j3 * ny
    return j0 * nx + j1 * ny, -j0 * ny + j1 * nx, tx * nx + ty * ny, -tx * ny + ty * nx


@njit
def _boundary_node(X, i, nx, ny, kn, kt, Zn, Zt, G, f, k):
    """The interior trace at the dof block X[i:i+5] in the facet frame (v_n, v_t, s_n, s_t)
    and the corrections (s* - s, v* - v) of both components against boundary facet f's
    outer data at its node k (:func:`hydrofrac.riemann.boundary_pt`)."""
    vx, vy = X[i], X[i + 1]
    tx, ty = X[i + 2] * nx + X[i + 4] * ny, X[i + 4] * nx + X[i + 3] * ny
    vn, vt, sn, st = vx * nx + vy * ny, -vx * ny + vy * nx, tx * nx + ty * ny, -tx * ny + ty * nx
    dsn, dvn = boundary_pt(kn, vn, sn, Zn, G[f, k, 0], G[f, k, 2])
    dst, dvt = boundary_pt(kt, vt, st, Zt, G[f, k, 1], G[f, k, 3])
    return vn, vt, sn, st, dsn, dvn, dst, dvt


def _pack_blocks(B):
    """(cells, 11) rows of the C kernels' per-material tables from (cells, 5, 5) material blocks
    diag(b_v, b_v) + a 3x3 stress block: b_v twice, then the stress block row by row."""
    return np.concatenate([B[:, 0, 0:1], B[:, 1, 1:2], B[:, 2:, 2:].reshape(-1, 9)], axis=1)


@njit
def _add_blocks(Q, X, src, dofs, coef):
    """Q[blocks] = X[blocks] + coef * src[blocks] over the dof blocks ``dofs`` (cells, nb)."""
    for c in range(dofs.shape[0]):
        for j in range(dofs.shape[1]):
            b = 5 * dofs[c, j]
            for k in range(5):
                Q[b + k] = X[b + k] + coef * src[b + k]


@functools.lru_cache(maxsize=None)
def _kernels(nb, nk, contig=False):
    """The (volume + inverse mass, interior facet flux, facet dissipation, cell energies)
    kernels for ``nb`` basis functions per cell and ``nk`` on a facet, compiled with both as
    constants: LLVM then unrolls the small loops (2-3x faster than with run-time sizes at
    p = 1-3; numba caches each set).  At P1 (nb = 3) the gradients of the basis are
    constant, so the rows of S_r = int phi_i d_r phi_j (and of D_r = M^-1 S_r) are equal:
    the kernels compute one row (``rows`` = 1; checked in :class:`MatrixFreeOperator`)."""
    rows = 1 if nb == 3 else nb

    @njit
    def volume_and_inverse(out, R, X, dofs, ncells, S0, S1, Jinv, invdet, Minv_ref, mat, Btab):
        """out[cell dofs] = M_c^{-1} (R[c] + volume terms of c), for the owned cells (R[c] is zeroed);
        M_c^{-1} = Minv_ref kron B^{-1} / |det J_c|, with B^{-1} = diag(1/rho, 1/rho) + a 3x3
        stiffness block, stored once per material: ``Btab[mat[c]]`` = (1/rho, 1/rho, the 3x3 block
        row by row).  Written out, as the ADER corrector is: numba's inlining of helpers costs
        10x the compile time, and LLVM alone does not unroll them (0.6x the speed).  So the
        volume loops exist twice; both paths are checked (tests/test_matfree.py against the
        assembled forms, tests/test_bulk.py::test_plane_wave_convergence_ader)."""
        u = np.empty((nb, 5))
        g0 = np.empty((nb, 5))
        g1 = np.empty((nb, 5))
        r = np.empty((nb, 5))
        tmp = np.empty((nb, 5))
        vol = np.empty((rows, 5))
        for c in range(ncells):
            for j in range(nb):
                base = 5 * (nb * c + j) if contig else 5 * dofs[c, j]
                for k in range(5):
                    u[j, k] = X[base + k]
            for i in range(rows):
                for k in range(5):
                    s0 = 0.0
                    s1 = 0.0
                    for j in range(nb):
                        s0 += S0[i, j] * u[j, k]
                        s1 += S1[i, j] * u[j, k]
                    g0[i, k] = s0
                    g1[i, k] = s1
            j00, j01, j10, j11 = Jinv[c, 0, 0], Jinv[c, 0, 1], Jinv[c, 1, 0], Jinv[c, 1, 1]
            for i in range(rows):
                # d/dx = Jinv[0,0] d/dX0 + Jinv[1,0] d/dX1 ; d/dy = Jinv[0,1] d/dX0 + Jinv[1,1] d/dX1
                dx_vx = j00 * g0[i, 0] + j10 * g1[i, 0]
                dy_vx = j01 * g0[i, 0] + j11 * g1[i, 0]
                dx_vy = j00 * g0[i, 1] + j10 * g1[i, 1]
                dy_vy = j01 * g0[i, 1] + j11 * g1[i, 1]
                dx_sxx = j00 * g0[i, 2] + j10 * g1[i, 2]
                dy_syy = j01 * g0[i, 3] + j11 * g1[i, 3]
                dx_sxy = j00 * g0[i, 4] + j10 * g1[i, 4]
                dy_sxy = j01 * g0[i, 4] + j11 * g1[i, 4]
                vol[i, 0] = dx_sxx + dy_sxy
                vol[i, 1] = dx_sxy + dy_syy
                vol[i, 2] = dx_vx
                vol[i, 3] = dy_vy
                vol[i, 4] = dy_vx + dx_vy
            e = invdet[c]  # (R + |det J| vol) / |det J|
            for i in range(nb):
                iv = i if rows == nb else 0
                for k in range(5):
                    r[i, k] = e * R[c, i, k] + vol[iv, k]
                    R[c, i, k] = 0.0  # cleared for the next stage (saves a separate pass)
            for a in range(nb):
                for k in range(5):
                    acc = 0.0
                    for b in range(nb):
                        acc += Minv_ref[a, b] * r[b, k]
                    tmp[a, k] = acc
            B = Btab[mat[c]]
            b00, b11 = B[0], B[1]
            c22, c23, c24, c32, c33, c34 = B[2], B[3], B[4], B[5], B[6], B[7]
            c42, c43, c44 = B[8], B[9], B[10]
            for a in range(nb):
                base = 5 * (nb * c + a) if contig else 5 * dofs[c, a]
                t2, t3, t4 = tmp[a, 2], tmp[a, 3], tmp[a, 4]
                out[base] = b00 * tmp[a, 0]
                out[base + 1] = b11 * tmp[a, 1]
                out[base + 2] = c22 * t2 + c23 * t3 + c24 * t4
                out[base + 3] = c32 * t2 + c33 * t3 + c34 * t4
                out[base + 4] = c42 * t2 + c43 * t3 + c44 * t4

    @njit
    def ader_corrector(x, I, R, dofs, ncells, S0, S1, Jinv, invdet, Minv_ref, mat, Btab, D0, D1, dt, order):
        """Per owned cell: x += M_c^{-1} (R[c] + volume terms of I) (ADER's corrector, R[c]
        holding the facet fluxes of I; R[c] is zeroed), then I = the predictor's time integral
        from the new x, sum_{k=0..order} dt^(k+1)/(k+1)! D^k x with D the cell-local
        strong-form operator (the volume terms and the inverse mass, no facet flux;
        ``D_r = Minv_ref S_r``, the nodal derivative matrices), for the next step: one pass
        for what would be the volume kernel, the update and the next predictor."""
        # Written out in one loop over the passes m = 0..order (m = 0: the corrector's volume
        # terms of I with S_r; m >= 1: the Taylor terms with D_r), not from inlined helpers:
        # numba's inlining made this kernel take 140-160 s to compile per degree.
        u = np.empty((nb, 5))
        g0 = np.empty((rows, 5))
        g1 = np.empty((rows, 5))
        r = np.empty((nb, 5))
        w = np.empty((nb, 5))
        acc = np.empty((nb, 5))
        for c in range(ncells):
            B = Btab[mat[c]]
            b00, b11 = B[0], B[1]
            c22, c23, c24, c32, c33, c34 = B[2], B[3], B[4], B[5], B[6], B[7]
            c42, c43, c44 = B[8], B[9], B[10]
            j00, j01, j10, j11 = Jinv[c, 0, 0], Jinv[c, 0, 1], Jinv[c, 1, 0], Jinv[c, 1, 1]
            for j in range(nb):
                base = 5 * (nb * c + j) if contig else 5 * dofs[c, j]
                for k in range(5):
                    u[j, k] = I[base + k]
            coef = dt
            for m in range(order + 1):
                A0 = S0 if m == 0 else D0
                A1 = S1 if m == 0 else D1
                # r = the strong-form volume terms of u (row 0 copied where the rows are equal)
                for i in range(rows):
                    for k in range(5):
                        s0 = 0.0
                        s1 = 0.0
                        for j in range(nb):
                            s0 += A0[i, j] * u[j, k]
                            s1 += A1[i, j] * u[j, k]
                        g0[i, k] = s0
                        g1[i, k] = s1
                for i in range(nb):
                    iv = i if rows == nb else 0
                    r[i, 0] = j00 * g0[iv, 2] + j10 * g1[iv, 2] + j01 * g0[iv, 4] + j11 * g1[iv, 4]
                    r[i, 1] = j00 * g0[iv, 4] + j10 * g1[iv, 4] + j01 * g0[iv, 3] + j11 * g1[iv, 3]
                    r[i, 2] = j00 * g0[iv, 0] + j10 * g1[iv, 0]
                    r[i, 3] = j01 * g0[iv, 1] + j11 * g1[iv, 1]
                    r[i, 4] = j01 * g0[iv, 0] + j11 * g1[iv, 0] + j00 * g0[iv, 1] + j10 * g1[iv, 1]
                if m == 0:  # w = M_c^-1 (R[c] + volume terms): first Minv_ref, into u
                    e = invdet[c]
                    for i in range(nb):
                        for k in range(5):
                            r[i, k] += e * R[c, i, k]
                            R[c, i, k] = 0.0
                    for a in range(nb):
                        for k in range(5):
                            t = 0.0
                            for b in range(nb):
                                t += Minv_ref[a, b] * r[b, k]
                            u[a, k] = t
                    src = u
                else:  # D_r already holds Minv_ref
                    src = r
                for a in range(nb):  # w = B^-1 src, node by node
                    t2, t3, t4 = src[a, 2], src[a, 3], src[a, 4]
                    w[a, 0] = b00 * src[a, 0]
                    w[a, 1] = b11 * src[a, 1]
                    w[a, 2] = c22 * t2 + c23 * t3 + c24 * t4
                    w[a, 3] = c32 * t2 + c33 * t3 + c34 * t4
                    w[a, 4] = c42 * t2 + c43 * t3 + c44 * t4
                if m == 0:  # the corrector: x += w; the predictor starts from the new x
                    for j in range(nb):
                        base = 5 * (nb * c + j) if contig else 5 * dofs[c, j]
                        for k in range(5):
                            v = x[base + k] + w[j, k]
                            x[base + k] = v
                            u[j, k] = v
                            acc[j, k] = dt * v
                else:  # the Taylor term dt^(m+1)/(m+1)! D^m x
                    coef *= dt / (m + 1)
                    for j in range(nb):
                        for k in range(5):
                            u[j, k] = w[j, k]
                            acc[j, k] += coef * w[j, k]
            for a in range(nb):
                base = 5 * (nb * c + a) if contig else 5 * dofs[c, a]
                for k in range(5):
                    I[base + k] = acc[a, k]

    @njit
    def facet_fluxes(R, X, dofs, fcells, fcodes, normal, length, fnodes, Mf, Zd, Zs, nowned):
        """R[c] += upwind flux corrections of every listed interior facet, on its owned sides.

        Nodal form: the bonded Riemann solution is linear in the traces with coefficients
        constant on the facet, so the flux correction is solved at the facet's nk nodes
        (both sides' nodal values, no interpolation) and integrated with the facet mass
        matrix ``length * Mf`` -- exactly the Gauss-point result (degree-2p integrand), at
        (p+1)/nb of the trace and scatter work.  The corrections depend on the jumps
        [u] = u- - u+ only (:func:`hydrofrac.riemann.bonded_jump_pt`)."""
        Fp = np.empty((nk, 5))
        Fm = np.empty((nk, 5))
        for f in range(fcells.shape[0]):
            cp, cm = fcells[f, 0], fcells[f, 1]
            kp, km = fcodes[f, 0], fcodes[f, 1]
            nx, ny = normal[f, 0], normal[f, 1]
            Zpn, Zpt, Zmn, Zmt = Zd[cp], Zs[cp], Zd[cm], Zs[cm]
            for k in range(nk):
                if contig:
                    ip, im = 5 * (nb * cp + fnodes[kp, k]), 5 * (nb * cm + fnodes[km, k])
                else:
                    ip, im = 5 * dofs[cp, fnodes[kp, k]], 5 * dofs[cm, fnodes[km, k]]
                jvn, jvt, jsn, jst = _node_jumps(X, ip, im, nx, ny)
                dspn, dvpn, dsmn, dvmn = bonded_jump_pt(jvn, jsn, Zpn, Zmn)
                dspt, dvpt, dsmt, dvmt = bonded_jump_pt(jvt, jst, Zpt, Zmt)
                # side +: outward normal n
                dsx, dsy = dspn * nx - dspt * ny, dspn * ny + dspt * nx
                dvx, dvy = dvpn * nx - dvpt * ny, dvpn * ny + dvpt * nx
                Fp[k, 0], Fp[k, 1] = dsx, dsy
                Fp[k, 2], Fp[k, 3], Fp[k, 4] = dvx * nx, dvy * ny, dvx * ny + dvy * nx
                # side -: outward normal -n and traction -s*, so both terms change sign
                dsx, dsy = -(dsmn * nx - dsmt * ny), -(dsmn * ny + dsmt * nx)
                dvx, dvy = -(dvmn * nx - dvmt * ny), -(dvmn * ny + dvmt * nx)
                Fm[k, 0], Fm[k, 1] = dsx, dsy
                Fm[k, 2], Fm[k, 3], Fm[k, 4] = dvx * nx, dvy * ny, dvx * ny + dvy * nx
            # the two sides written out on purpose: a helper taking the arrays was not inlined
            # (3x slower), and a loop over the sides with one (2, nk, 5) array measured 15-20 %
            # slower at p = 1-2
            L = length[f]
            if cp < nowned:
                for i in range(nk):
                    j = fnodes[kp, i]
                    for m in range(5):
                        acc = 0.0
                        for k in range(nk):
                            acc += Mf[i, k] * Fp[k, m]
                        R[cp, j, m] += L * acc
            if cm < nowned:
                for i in range(nk):
                    j = fnodes[km, i]
                    for m in range(5):
                        acc = 0.0
                        for k in range(nk):
                            acc += Mf[i, k] * Fm[k, m]
                        R[cm, j, m] += L * acc

    @njit
    def boundary_fluxes(R, X, dofs, bcells, bcodes, normal, length, kinds, G, fnodes, Mf, Zd, Zs):
        """R[c] += boundary flux corrections of every listed exterior facet (owned cell c):
        per component, the Riemann problem of the interior trace against the outer
        condition (:func:`hydrofrac.riemann.boundary_pt`; ``kinds[f]`` = (normal, tangential)
        kind, ``G[f, k]`` = the outer (V_n, V_t, S_n, S_t) at facet node k), solved at the
        facet nodes and integrated with the facet mass matrix -- exact as for interior
        facets, since the corrections are linear in the trace and the data are nodal."""
        F = np.empty((nk, 5))
        for f in range(bcells.shape[0]):
            c, kc = bcells[f], bcodes[f]
            nx, ny = normal[f, 0], normal[f, 1]
            Zn, Zt = Zd[c], Zs[c]
            kn, kt = kinds[f, 0], kinds[f, 1]
            for k in range(nk):
                i = 5 * (nb * c + fnodes[kc, k]) if contig else 5 * dofs[c, fnodes[kc, k]]
                _, _, _, _, dsn, dvn, dst, dvt = _boundary_node(X, i, nx, ny, kn, kt, Zn, Zt, G, f, k)
                dvx, dvy = dvn * nx - dvt * ny, dvn * ny + dvt * nx
                F[k, 0], F[k, 1] = dsn * nx - dst * ny, dsn * ny + dst * nx
                F[k, 2], F[k, 3], F[k, 4] = dvx * nx, dvy * ny, dvx * ny + dvy * nx
            L = length[f]
            for i in range(nk):
                j = fnodes[kc, i]
                for m in range(5):
                    acc = 0.0
                    for k in range(nk):
                        acc += Mf[i, k] * F[k, m]
                    R[c, j, m] += L * acc

    @njit
    def boundary_energy(X, dofs, bcells, bcodes, normal, length, kinds, G, radiating, fnodes, Mf, Zd, Zs, s0xx,
                        s0yy, s0xy):
        """(power in, power out through radiating facets, upwind dissipation) of the listed
        exterior facets: int (s* - sigma0 n).v* and int (s* - s).(v* - v) (the quadratic forms
        of :func:`hydrofrac.forms.elastodynamics.boundary_power` and ``boundary_dissipation``),
        from the node values of the corrections (:func:`hydrofrac.riemann.boundary_pt`) and
        the facet mass matrix: exact, the integrands being products of two degree-p traces."""
        A = np.empty((nk, 2))  # s* - sigma0 n (n, t)
        V = np.empty((nk, 2))  # v*
        dS_ = np.empty((nk, 2))
        dV = np.empty((nk, 2))
        p_in = 0.0
        p_out = 0.0
        diss = 0.0
        for f in range(bcells.shape[0]):
            c, kc = bcells[f], bcodes[f]
            nx, ny = normal[f, 0], normal[f, 1]
            Zn, Zt = Zd[c], Zs[c]
            kn, kt = kinds[f, 0], kinds[f, 1]
            t0x, t0y = s0xx * nx + s0xy * ny, s0xy * nx + s0yy * ny
            s0n, s0t = t0x * nx + t0y * ny, -t0x * ny + t0y * nx
            for k in range(nk):
                i = 5 * (nb * c + fnodes[kc, k]) if contig else 5 * dofs[c, fnodes[kc, k]]
                vn, vt, sn, st, dsn, dvn, dst, dvt = _boundary_node(X, i, nx, ny, kn, kt, Zn, Zt, G, f, k)
                A[k, 0], A[k, 1] = sn + dsn - s0n, st + dst - s0t
                V[k, 0], V[k, 1] = vn + dvn, vt + dvt
                dS_[k, 0], dS_[k, 1] = dsn, dst
                dV[k, 0], dV[k, 1] = dvn, dvt
            pw = 0.0
            dd = 0.0
            for k in range(nk):
                for m in range(nk):
                    pw += Mf[k, m] * (A[k, 0] * V[m, 0] + A[k, 1] * V[m, 1])
                    dd += Mf[k, m] * (dS_[k, 0] * dV[m, 0] + dS_[k, 1] * dV[m, 1])
            L = length[f]
            if radiating[f]:
                p_out -= L * pw
            else:
                p_in += L * pw
            diss += L * dd
        return p_in, p_out, diss

    @njit
    def facet_dissipation(X, dofs, fcells, fcodes, fown, normal, length, fnodes, Mf, Zd, Zs):
        """Rate of energy dissipated by the upwind flux on the owned listed facets:
        int sum_i Z_i+ Z_i- / (Z_i+ + Z_i-) [[v_i]]^2 + [[s_i]]^2 / (Z_i+ + Z_i-), i = n, t
        (the quadratic form of :func:`hydrofrac.forms.elastodynamics.interior_dissipation`),
        from the jumps at the facet nodes and the facet mass matrix (exact, as the flux)."""
        J = np.empty((nk, 4))
        total = 0.0
        for f in range(fcells.shape[0]):
            if not fown[f]:
                continue
            cp, cm = fcells[f, 0], fcells[f, 1]
            kp, km = fcodes[f, 0], fcodes[f, 1]
            nx, ny = normal[f, 0], normal[f, 1]
            Zpn, Zpt, Zmn, Zmt = Zd[cp], Zs[cp], Zd[cm], Zs[cm]
            for k in range(nk):
                J[k, 0], J[k, 1], J[k, 2], J[k, 3] = _node_jumps(X, 5 * dofs[cp, fnodes[kp, k]],
                                                                 5 * dofs[cm, fnodes[km, k]], nx, ny)
            an, at = Zpn * Zmn / (Zpn + Zmn), Zpt * Zmt / (Zpt + Zmt)
            cn, ct = 1.0 / (Zpn + Zmn), 1.0 / (Zpt + Zmt)
            acc = 0.0
            for k in range(nk):
                for m in range(nk):
                    acc += Mf[k, m] * (an * J[k, 0] * J[m, 0] + at * J[k, 1] * J[m, 1]
                                       + cn * J[k, 2] * J[m, 2] + ct * J[k, 3] * J[m, 3])
            total += acc * length[f]
        return total

    @njit
    def cell_energies(X, X0, dofs, ncells, Mref, absdet, Bmat):
        """(kinetic, strain) energy of X - X0 on the owned cells, X0 (5,) the uniform initial
        state at every node: 1/2 u^T M_c u with M_c = |det J| Mref kron B_c (B_c: rho for v,
        the compliance for sigma)."""
        u = np.empty((nb, 5))
        kin = 0.0
        strain = 0.0
        for c in range(ncells):
            for j in range(nb):
                base = 5 * dofs[c, j]
                for k in range(5):
                    u[j, k] = X[base + k] - X0[k]
            B = Bmat[c]
            ek = 0.0
            es = 0.0
            for a in range(nb):
                # w = B u[a] (sigma block), then u[b] . (Mref[a, b] w) summed over b
                w2 = B[2, 2] * u[a, 2] + B[2, 3] * u[a, 3] + B[2, 4] * u[a, 4]
                w3 = B[3, 2] * u[a, 2] + B[3, 3] * u[a, 3] + B[3, 4] * u[a, 4]
                w4 = B[4, 2] * u[a, 2] + B[4, 3] * u[a, 3] + B[4, 4] * u[a, 4]
                wk0, wk1 = B[0, 0] * u[a, 0], B[1, 1] * u[a, 1]
                for b in range(nb):
                    m = Mref[a, b]
                    ek += m * (wk0 * u[b, 0] + wk1 * u[b, 1])
                    es += m * (w2 * u[b, 2] + w3 * u[b, 3] + w4 * u[b, 4])
            kin += absdet[c] * ek
            strain += absdet[c] * es
        return 0.5 * kin, 0.5 * strain

    return (volume_and_inverse, facet_fluxes, facet_dissipation, cell_energies, boundary_fluxes, boundary_energy,
            ader_corrector)


@functools.lru_cache(maxsize=None)
def _gauss_legendre(n):
    return np.polynomial.legendre.leggauss(n)


def facet_nodes(ref, tables, qw):
    """Per ordered pair of reference vertices (code 3 i + j), the local nodes on that edge
    in order from vertex i to j, (9, p+1), and the reference facet mass matrix (p+1, p+1)
    (the same for every code).  Checks that the other basis functions vanish on the edge."""
    X = ref.nodes
    nk = ref.degree + 1
    fnodes = np.zeros((9, nk), dtype=np.int64)
    Mf = None
    for i in range(3):
        for j in range(3):
            if i == j:
                continue
            d = _REF_VERTICES[j] - _REF_VERTICES[i]
            rel = X - _REF_VERTICES[i]
            s = rel @ d / (d @ d)
            on = np.where((np.abs(rel[:, 0] * d[1] - rel[:, 1] * d[0]) < 1e-10) & (s > -1e-10) & (s < 1 + 1e-10))[0]
            on = on[np.argsort(s[on])]
            code = 3 * i + j
            rest = np.setdiff1d(np.arange(X.shape[0]), on)
            if on.size != nk or (rest.size and np.abs(tables[code][:, rest]).max() > 1e-12):
                raise RuntimeError(f"the element is not nodal on its edges ({on.size} nodes on edge {i}-{j}, "
                                   f"expected {nk}); the matrix-free facet kernel needs a Lagrange element")
            fnodes[code] = on
            psi = tables[code][:, on]
            M = np.einsum("q,qk,ql->kl", qw, psi, psi)
            if Mf is None:
                Mf = M
            elif not np.allclose(M, Mf, rtol=0.0, atol=1e-13):
                raise RuntimeError("edge mass matrices differ between reference edges")
    return fnodes, np.ascontiguousarray(Mf)


def _facet_frames(mesh, g, facets, cells):
    """Each facet's end points (va, vb), unit normal n, length, whether n points out of
    ``cells`` (one adjacent cell per facet), and the end points' geometry nodes (ga, gb)."""
    f_off, f_arr = compat.connectivity(mesh, mesh.topology.dim - 1, 0)
    x = mesh.geometry.x[:, :2]
    v2g = compat.vertex_to_geometry(mesh)
    ga = v2g[f_arr[f_off[facets]]]
    gb = v2g[f_arr[f_off[facets] + 1]]
    va, vb = x[ga], x[gb]
    tang = vb - va
    length = np.linalg.norm(tang, axis=1)
    n = np.stack([tang[:, 1], -tang[:, 0]], axis=1) / np.maximum(length, 1e-300)[:, None]
    out = np.einsum("fi,fi->f", g.centroid[cells] - 0.5 * (va + vb), n) < 0
    return va, vb, n, length, out, ga, gb


def _facet_codes(g, cells, ga, gb):
    """Code 3 i + j of the reference edge from vertex i to j that the facet with end nodes
    (ga -> gb) is in each of ``cells``: i and j are the places of those geometry nodes among
    the cell's (:class:`~hydrofrac.element.CellGeometry`'s reference order), found by index,
    not by mapping the points back (a third of a remesh's operator set-up)."""
    cn = g.nodes[cells]
    at_a, at_b = cn == ga[:, None], cn == gb[:, None]
    if len(cells) and not (at_a.any(axis=1) & at_b.any(axis=1) & (ga != gb)).all():
        raise RuntimeError("a facet's end vertices are not two vertices of its cell (the mesh's facet-cell "
                           "connectivity is broken)")
    return 3 * at_a.argmax(axis=1) + at_b.argmax(axis=1)


def _outer_frame(u, n):
    """Outer states u (5, m) as (V_n, V_t, S_n, S_t) (m, 4) in the frames of the normals n (m, 2)."""
    nx, ny = n[:, 0], n[:, 1]
    tx, ty = u[2] * nx + u[4] * ny, u[4] * nx + u[3] * ny
    return np.stack([u[0] * nx + u[1] * ny, -u[0] * ny + u[1] * nx, tx * nx + ty * ny, -tx * ny + ty * nx], axis=1)


@functools.lru_cache(maxsize=None)
def _outer_filler(point):
    """A compiled fill(G, rows, pts, n, t): the outer state ``point(x, y, t)`` at the facet
    nodes of the boundary facets ``rows``, in their frames (as :func:`_outer_frame`)."""
    def fill(G, rows, pts, n, t):
        nk = G.shape[1]
        for a in range(rows.size):
            for k in range(nk):
                q = a * nk + k
                vx, vy, sxx, syy, sxy = point(pts[0, q], pts[1, q], t)
                nx, ny = n[q, 0], n[q, 1]
                tx, ty = sxx * nx + sxy * ny, sxy * nx + syy * ny
                G[rows[a], k, 0] = vx * nx + vy * ny
                G[rows[a], k, 1] = -vx * ny + vy * nx
                G[rows[a], k, 2] = tx * nx + ty * ny
                G[rows[a], k, 3] = -tx * ny + ty * nx
    if not HAVE_NUMBA:  # pragma: no cover
        return fill
    import numba
    return numba.njit(error_model="numpy")(fill)  # (not cached: it calls the user's function)


def _check_point_state(bc, fill, rows, pts, n, comm):
    """An OuterState's compiled ``point`` gives its ``state`` (at its facet nodes, t = 0)."""
    G = np.zeros((rows.size, pts.shape[1] // max(rows.size, 1), 4))
    try:
        fill(G, np.arange(rows.size), pts, n, 0.0)
    except Exception as exc:  # numba's typing errors name the line, not the boundary condition
        raise ValueError(f"OuterState(tag={bc.tag}): its point function could not be compiled or called as "
                         f"point(x, y, t) -> 5 floats ({type(exc).__name__}: {str(exc).splitlines()[0]})") from exc
    ref = _outer_frame(np.asarray(bc.state(pts, 0.0)), n).reshape(G.shape)
    err = float(np.abs(G - ref).max()) if G.size else 0.0
    scale = float(np.abs(ref).max()) if G.size else 0.0
    err, scale = comm.allreduce(err, op=MPI.MAX), comm.allreduce(scale, op=MPI.MAX)
    if err > 1e-10 * max(scale, 1e-300):
        raise ValueError(f"OuterState(tag={bc.tag}): point(x, y, t) and state(x, t) differ at the boundary nodes at "
                         f"t = 0 (largest difference {err:.3g}, values up to {scale:.3g}); give point the same state")


#: The forms of :mod:`hydrofrac.forms.elastodynamics` these kernels implement by hand, and the
#: SHA-256 of their source as the kernels were written for them (:func:`implements_forms`).
IMPLEMENTED_FORMS = ("fields", "compliance", "impedances", "tangent", "volume", "facet_flux", "bonded_riemann",
                     "interior_flux", "interior_dissipation", "outer_riemann_component", "boundary_targets",
                     "boundary_flux")
IMPLEMENTED_SIGNATURE = "fa0130871ab7a680dd6ef464917180e160ccf9b44889c6826f89a50b0aeea611"


_SIGNATURES: dict = {}


def forms_signature() -> str:
    """SHA-256 of the source of the forms in :data:`IMPLEMENTED_FORMS`, as they are now.  Read
    once per (form function objects, forms file version): a remesh builds a new solver, and
    reading the source costs ~5 ms; an edit of the file or a replaced function is a new key."""
    import hashlib
    import inspect
    import os

    from .forms import elastodynamics as ef
    fns = tuple(getattr(ef, name) for name in IMPLEMENTED_FORMS)
    files = tuple(inspect.getsourcefile(f) for f in fns)
    key = (tuple(map(id, fns)), tuple((f, os.stat(f).st_mtime_ns) for f in files))
    if key not in _SIGNATURES:
        text = "\n".join(inspect.getsource(f) for f in fns)
        _SIGNATURES[key] = (fns, hashlib.sha256(text.encode()).hexdigest())  # (fns kept: ids stay theirs)
    return _SIGNATURES[key][1]


def implements_forms() -> bool:
    """Do the kernels implement the forms the solver is given?  False after an edit of any of
    :data:`IMPLEMENTED_FORMS` (the solver then assembles the operator from the edited forms)."""
    return forms_signature() == IMPLEMENTED_SIGNATURE


class ReferenceData(NamedTuple):
    """What the kernels need of the reference element alone (no cell's geometry): the
    derivative matrices S_r[i, j] = int phi_i d_r phi_j, the facet quadrature weights ``qw``,
    the basis on each ordered reference edge (``tables``, code 3 i + j), its nodes ``fnodes``
    and the facet mass matrix ``Mf``, and the reference mass matrix ``Mref`` and its inverse.
    Every solver of the same element shares these arrays: nothing may write to them (they stay
    writeable, so that the compiled kernels see the array types they were compiled for)."""

    S0: np.ndarray
    S1: np.ndarray
    qw: np.ndarray
    tables: np.ndarray
    fnodes: np.ndarray
    Mf: np.ndarray
    Mref: np.ndarray
    Mref_inv: np.ndarray
    chain: np.ndarray


def _lattice(k):
    """The equispaced points of degree k on the reference triangle ((k+1)(k+2)/2, 2): a
    unisolvent set for P_k (the centroid at k = 0)."""
    if k == 0:
        return np.array([[1.0 / 3.0, 1.0 / 3.0]])
    return np.array([[i / k, j / k] for j in range(k + 1) for i in range(k + 1 - j)])


def taylor_chain(ref):
    """ADER's predictor in the degrees its terms have (the C ``ader_corrector``).  D lowers the
    degree by one, so D^m x lies in P_{p-m} and its values at the (p-m)-lattice
    (:func:`_lattice`) determine it.  Per m = 1..p, flattened in this order: the reference
    derivative matrices from the values D^{m-1} x is held by (m = 1: the P_p nodes; then the
    (p-m+1)-lattice) to the (p-m)-lattice, (n_{p-m}, n_{p-m+1}) each, and the interpolation
    of (p-m)-lattice values at the P_p nodes, (n_p, n_{p-m}).  The nodal derivative matrices
    ``Minv_ref S_r`` are the m = 1 matrices taken at the nodes instead, so each term is the
    nodal predictor's, to round-off, at n_{p-m}/n_p of its rows (docs/benchmarks.md, "ADER's
    predictor in the degrees it has")."""
    from .element import ReferenceElement
    p = ref.degree
    prev, parts = ref, []
    for m in range(1, p + 1):
        L = _lattice(p - m)
        g = prev.tabulate_grad(L)
        basis = ReferenceElement(L, p - m)
        parts += [g[:, :, 0], g[:, :, 1], basis.tabulate(ref.nodes)]
        prev = basis
    return np.ascontiguousarray(np.concatenate([a.ravel() for a in parts]) if parts else np.zeros(0))


#: :func:`reference_data` of each element met so far (degree, nodes): a remesh's new solver
#: reuses them (docs/benchmarks.md, "Reference data once per element")
_REFERENCE: Dict[tuple, ReferenceData] = {}


def reference_data(ref) -> ReferenceData:
    """:class:`ReferenceData` of the nodal element ``ref``, computed once per element."""
    key = (ref.degree, ref.nodes.shape, ref.nodes.tobytes())
    if key in _REFERENCE:
        return _REFERENCE[key]
    p = ref.degree
    Xq, wq = triangle_quadrature(2 * p)
    phi = ref.tabulate(Xq)
    dphi = ref.tabulate_grad(Xq)
    S0 = np.ascontiguousarray(np.einsum("q,qi,qj->ij", wq, phi, dphi[:, :, 0]))
    S1 = np.ascontiguousarray(np.einsum("q,qi,qj->ij", wq, phi, dphi[:, :, 1]))
    if ref.nodes.shape[0] == 3:  # P1: the kernels use row 0 of S_r for every row (_kernels)
        for S in (S0, S1):
            if not np.allclose(S, S[0], rtol=0.0, atol=1e-14 * np.abs(S).max()):
                raise RuntimeError("P1 basis with non-constant gradients: the kernels' one-row volume "
                                   "terms do not apply")
    s, w = line_quadrature(2 * p + 1)
    qw = np.ascontiguousarray(w)
    # one table per ordered pair (i, j) of reference vertices: the facet from vertex i to j
    tables = np.zeros((9, s.size, ref.nodes.shape[0]))
    for i in range(3):
        for j in range(3):
            if i != j:
                pts = _REF_VERTICES[i] + s[:, None] * (_REF_VERTICES[j] - _REF_VERTICES[i])
                tables[3 * i + j] = ref.tabulate(pts)
    fnodes, Mf = facet_nodes(ref, tables, qw)
    Mref = ref.mass()
    data = ReferenceData(S0, S1, qw, tables, fnodes, Mf, np.ascontiguousarray(Mref),
                         np.ascontiguousarray(np.linalg.inv(Mref)), taylor_chain(ref))
    _REFERENCE[key] = data
    return data


class MatrixFreeOperator:
    """Bulk operator M^{-1}(K_vol + K_int) of a :class:`~hydrofrac.solver.Solver`, applied
    cell by cell (see the module docstring).  ``facets``: local indices of the interior
    facets that carry the bulk upwind flux."""

    def __init__(self, solver, facets):
        mesh = solver.mesh
        tdim = mesh.topology.dim
        ref, g = solver.ref, solver.geometry
        self.mesh, self.geometry, self.comm = mesh, g, mesh.comm
        self.nowned = compat.num_cells_local(mesh)
        r = reference_data(ref)
        self.S0, self.S1, self.qw, self.tables, self.fnodes, self.Mf = r.S0, r.S1, r.qw, r.tables, r.fnodes, r.Mf
        self.chain = r.chain
        self.Jinv = np.ascontiguousarray(g.Jinv)
        self.absdet = np.ascontiguousarray(np.abs(g.detJ))
        self.Minv_ref = np.ascontiguousarray(solver.Mref_inv, dtype=float)
        self.invdet = 1.0 / self.absdet
        B = solver.material_blocks_inv  # per cell, unscaled
        if np.any(B[:, :2, 2:]) or np.any(B[:, 2:, :2]) or np.any(B[:, 0, 1]) or np.any(B[:, 1, 0]):
            raise RuntimeError("the matrix-free kernel expects a material block diag(1/rho, 1/rho) + stiffness "
                               "(isotropic density); use operator='assembled' for other materials")
        # one row per distinct material: 1/rho (twice) and the 3x3 stiffness block
        packed = _pack_blocks(B)
        if packed.shape[0] and (packed == packed[0]).all():  # one material: np.unique's answer, without its sort
            table, mat = packed[:1].copy(), np.zeros(packed.shape[0], dtype=np.int64)
        else:
            table, mat = np.unique(packed, axis=0, return_inverse=True)
        self.Btab = np.ascontiguousarray(table)
        self.mat = np.ascontiguousarray(mat.reshape(-1), dtype=np.int32)
        self.dofs = np.ascontiguousarray(compat.cell_dofs(solver.V), dtype=np.int64)
        nb = self.dofs.shape[1]
        # DOLFINx numbers a DG space cell by cell: then the kernels index blocks directly
        self.contiguous = bool(np.array_equal(self.dofs, np.arange(self.dofs.size).reshape(self.dofs.shape)))
        cs = np.sqrt(solver.mu_cell / solver.rho_cell)
        self.Zd = np.ascontiguousarray(solver.rho_cell * solver.cd_cell)
        self.Zs = np.ascontiguousarray(solver.rho_cell * cs)

        # facets: both cells, + side = the cell the normal points away from
        (self._volume, self._facets, self._dissipation, self._energies, self._boundary,
         self._boundary_energy, self._corrector) = _kernels(nb, self.fnodes.shape[1], self.contiguous)
        c_off, c_arr = compat.connectivity(mesh, tdim - 1, tdim)
        facets = np.asarray(facets, dtype=np.int64)
        # facets of the outer ghost layer see one cell here: a ghost, so nothing to add
        ncell = np.diff(c_off)[facets]
        one = facets[ncell == 1]
        if one.size and np.any(c_arr[c_off[one]] < self.nowned):
            raise RuntimeError("an interior facet of an owned cell has one cell on this rank "
                               "(the mesh needs ghost mode shared_facet)")
        facets = facets[ncell == 2]
        c2 = np.stack([c_arr[c_off[facets]], c_arr[c_off[facets] + 1]], axis=1) if facets.size \
            else np.zeros((0, 2), dtype=np.int64)
        keep = np.any(c2 < self.nowned, axis=1)  # facets of owned cells only
        facets, c2 = facets[keep], c2[keep]
        # visit the facets in cell order, so that both sides' blocks are mostly still in cache
        order = np.lexsort((c2.max(axis=1), c2.min(axis=1)))
        facets, c2 = facets[order], c2[order]
        va, vb, n, length, first_out, ga, gb = _facet_frames(mesh, g, facets, c2[:, 0])
        cells = np.where(first_out[:, None], c2, c2[:, ::-1])  # + side: the cell n points out of
        codes = np.stack([_facet_codes(g, cells[:, side], ga, gb) for side in range(2)], axis=1)
        fmask = compat.facet_owned_mask(mesh)
        self.fown = np.ascontiguousarray(fmask[facets])  # count each facet once in global sums
        self.fcells = np.ascontiguousarray(cells, dtype=np.int64)
        self.fcodes = np.ascontiguousarray(codes, dtype=np.int64)
        self.normal = np.ascontiguousarray(n)
        self.length = np.ascontiguousarray(length)
        self.dof_x = compat.dof_coordinates(solver.V)
        self.set_boundary(np.zeros(0, dtype=np.int64), [])  # (none until the solver sets them)
        self.R = np.zeros((self.nowned, self.dofs.shape[1], 5))
        self._Rzero = np.zeros_like(self.R)  # (the volume kernel leaves it zero)
        self._D = None  # the nodal derivative matrices (ADER's predictor), when first asked for
        self._taylor = None  # the cells of taylor_values, their data and work arrays
        self._R_clear = True
        self.Mref = r.Mref
        self.Bmat = solver.material_blocks
        # the volume, interior facet, ADER and cell energy kernels in C, in blocks of cells (hydrofrac/native.py)
        # for a cell-contiguous space; otherwise, or with HYDROFRAC_KERNELS=numba, the numba ones
        self.kernels = native.backend() if self.contiguous else "numba"
        self._cvolume = self._cfacets = self._cader = self._cenergy = self._cdiss = None  # (ADER's when first used)
        self._ctaylor = None  # (when first used)
        if self.kernels == "c":
            nk = self.fnodes.shape[1]
            self._cvolume = native.VolumeKernel(nb, nk, self.nowned, self.S0, self.S1, self.Jinv, self.invdet,
                                                self.Minv_ref, self.mat, self.Btab)
            cp, cm = self.fcells[:, 0], self.fcells[:, 1]
            coef, pair = native.bonded_coefficients(self.Zd[cp], self.Zd[cm], self.Zs[cp], self.Zs[cm],
                                                    bonded_jump_pt)
            self._cfacets = native.FacetKernel(nb, nk, self.dofs.shape[0], self.nowned, self.fcells, self.fcodes,
                                               self.normal, self.length, self.fnodes, self.Mf, coef, pair)
            # the energy budget's cell energies: the compliance per material, indexed as Btab
            ctab = np.zeros((self.Btab.shape[0], 11))
            ctab[self.mat[:self.nowned]] = _pack_blocks(self.Bmat[:self.nowned])
            self._cenergy = native.EnergyKernel(nb, nk, self.nowned, self.Mref, self.absdet, self.mat, ctab)
            self._cdiss = native.DissipationKernel(nb, nk, self.dofs.shape[0], self.fcells, self.fcodes, self.normal,
                                                   self.length, self.fnodes, self.Mf, self.fown, self.Zd[cp],
                                                   self.Zd[cm], self.Zs[cp], self.Zs[cm])

    def set_boundary(self, facets, bc_of, bcs=()):
        """The exterior facets of the owned cells, with the boundary condition of each
        (``bc_of[i]``, one of ``bcs``; None: traction-free), applied by :meth:`begin` with
        their data at the stage time (:func:`hydrofrac.boundary.point_data`; outer states
        evaluated at the facet nodes).  Collective (``bcs``: the same on every rank)."""
        from .boundary import RADIATING, OuterState, point_data
        from .riemann import BOUNDARY_KINDS
        facets = np.asarray(facets, dtype=np.int64)
        cells = compat.facet_cells(self.mesh, facets).astype(np.int64)
        g = self.geometry
        va, vb, n, length, out, ga, gb = _facet_frames(self.mesh, g, facets, cells)
        n = np.where(out[:, None], n, -n)
        codes = _facet_codes(g, cells, ga, gb)
        nk = self.fnodes.shape[1]
        self.bcells, self.bcodes = np.ascontiguousarray(cells), np.ascontiguousarray(codes, dtype=np.int64)
        self.bnormal, self.blength = np.ascontiguousarray(n), np.ascontiguousarray(length)
        self.bkinds = np.zeros((facets.size, 2), dtype=np.int64)  # traction-free: kind 0, data 0
        self.bradiating = np.zeros(facets.size, dtype=np.bool_)  # power counted as radiated (energy budget)
        G0 = np.zeros((facets.size, 4))
        self._bhist, self._bouter = [], []
        groups = {id(bc): (bc, []) for bc in bcs}  # every condition on every rank (collective checks)
        for i, bc in enumerate(bc_of):
            if bc is not None:
                groups[id(bc)][1].append(i)
        for bc, rows in groups.values():
            rows = np.asarray(rows, dtype=np.int64)
            self.bkinds[rows] = [BOUNDARY_KINDS[k] for k in bc.kinds]
            self.bradiating[rows] = isinstance(bc, RADIATING)
            if isinstance(bc, OuterState):
                nodes = self.dofs[cells[rows][:, None], self.fnodes[codes[rows]]]  # (m, nk) dof blocks
                pts = np.ascontiguousarray(self.dof_x[nodes.reshape(-1)].T)
                nrm = np.ascontiguousarray(np.repeat(n[rows], nk, axis=0))
                fill = None
                if bc.point is not None:
                    fill = _outer_filler(bc.point)
                    _check_point_state(bc, fill, rows, pts, nrm, self.comm)
                self._bouter.append((bc, rows, pts, nrm, fill))
                continue
            const, hist, unit = point_data(bc, n[rows])
            G0[rows] = const
            if hist is not None:
                self._bhist.append((hist, rows, unit[:, None, :]))
        self.G0 = np.ascontiguousarray(np.repeat(G0[:, None, :], nk, axis=1))
        self.G = self.G0.copy()
        self._bstatic = not (self._bhist or self._bouter)
        self._G_scaled = False
        self._G_acc = None

    def integrate_boundary_data(self, t, dt, npoints):
        """G = the integral of the outer data over [t, t + dt], by Gauss-Legendre quadrature
        with ``npoints`` points (the boundary flux is linear in the trace and the data, so
        the flux of a time-integrated trace uses the time-integrated data: ADER)."""
        if self._bstatic:
            np.multiply(self.G0, dt, out=self.G)
            self._G_scaled = True
            return
        xi, w = _gauss_legendre(npoints)
        if self._G_acc is None:
            self._G_acc = np.empty_like(self.G)
        acc = self._G_acc
        for q in range(npoints):
            self.boundary_data(t + 0.5 * dt * (1.0 + xi[q]))
            if q == 0:
                np.multiply(self.G, 0.5 * dt * w[q], out=acc)
            else:
                acc += (0.5 * dt * w[q]) * self.G
        self.G[:] = acc
        self._G_scaled = True

    def local_derivative(self, x, out):
        """out = D x, the cell-local strong-form operator (the volume terms without any facet
        flux: the time derivative of each cell's polynomial as if it stood alone, exact for
        P_p data); ``x``, ``out``: owned values."""
        self._apply_volume(out, self._Rzero, x)

    def ader_predictor(self, x, I, dt, order):
        """I = sum_{k=0..order} dt^(k+1)/(k+1)! D^k x (:meth:`local_derivative`), the time
        integral of the cell-local Taylor predictor over [t, t + dt] (ADER's
        Cauchy-Kovalevskaya step); ``x``, ``I``: owned values.  The corrector's kernel with no
        flux and I = 0 (x += 0 leaves it bit for bit): one kernel to compile, not two."""
        I[:] = 0.0
        if not self._R_clear:
            self.R[:] = 0.0
        self.ader_correct(x, I, dt, order)

    def ader_correct(self, x, I, dt, order):
        """x += M^{-1}(R + volume terms of I), ``R`` holding the facet fluxes of I from
        :meth:`begin` (the ADER corrector), then I = the predictor's integral from the new x
        over the next step of length dt (:meth:`ader_predictor`), in one compiled pass;
        ``x``, ``I``: owned values."""
        if self.kernels == "c":
            if self._cader is None:
                nb, nk = self.dofs.shape[1], self.fnodes.shape[1]
                self._cader = native.AderKernel(nb, nk, self.nowned, self.S0, self.S1, self.Jinv, self.invdet,
                                                self.Minv_ref, self.mat, self.Btab, self.chain)
            self._cader(x, I, self.R, dt, order)
        else:
            self._corrector(x, I, self.R, self.dofs, self.nowned, self.S0, self.S1, self.Jinv, self.invdet,
                            self.Minv_ref, self.mat, self.Btab, *self._derivatives(), float(dt), int(order))
        self._R_clear = True

    def taylor_values(self, x, Q, cells, taus, order):
        """Q[i] = the cell-local Taylor predictor from ``x`` at the time ``taus[i]`` into the
        step, sum_{m=0..order} tau^m/m! D^m x, on ``cells`` (owned or ghost; ``x``: the local
        array with ghosts, ``Q``: (len(taus), x.size), its other blocks left as they are): the
        traces ADER's crack interfaces see inside a step
        (:meth:`hydrofrac.interface.Interface.ader_step`).  D is :meth:`local_derivative`'s
        operator.  With the C kernels, one pass in blocks of cells
        (:class:`hydrofrac.native.TaylorKernel`, ADER's predictor on the listed cells); else the
        numba volume kernel on those cells' own data (gathered once per list of cells).  Each
        D^m x once for all the times."""
        if self.kernels == "c":
            if self._ctaylor is None:
                self._ctaylor = native.TaylorKernel(self.dofs.shape[1], self.fnodes.shape[1], self.dofs.shape[0],
                                                    self.Jinv, self.mat, self.Btab, self.chain)
            self._ctaylor(Q, x, cells, taus, order)
            return
        key = id(cells)
        if self._taylor is None or self._taylor[0] != key:
            vol = _kernels(self.dofs.shape[1], self.fnodes.shape[1], False)[0]  # (any dof numbering)
            d = np.ascontiguousarray(self.dofs[cells])
            self._taylor = (key, cells, vol, d, np.ascontiguousarray(self.Jinv[cells]),
                            np.ascontiguousarray(self.invdet[cells]), np.ascontiguousarray(self.mat[cells]),
                            np.zeros((cells.size, d.shape[1], 5)), np.zeros((2, x.size)))
        _, _, vol, d, Jinv, invdet, mat, Rzero, work = self._taylor
        out = work[0]
        vol(out, Rzero, x, d, d.shape[0], self.S0, self.S1, Jinv, invdet, self.Minv_ref, mat, self.Btab)
        coefs = [float(tau) for tau in taus]
        for Qi, coef in zip(Q, coefs):
            _add_blocks(Qi, x, out, d, coef)
        for m in range(2, order + 1):
            src, out = out, work[m % 2]
            vol(out, Rzero, src, d, d.shape[0], self.S0, self.S1, Jinv, invdet, self.Minv_ref, mat, self.Btab)
            for i, (Qi, tau) in enumerate(zip(Q, taus)):
                coefs[i] *= tau / m
                _add_blocks(Qi, Qi, out, d, coefs[i])

    def _derivatives(self):
        """The nodal derivative matrices D_r = Minv_ref S_r (computed when first asked for)."""
        if self._D is None:
            self._D = tuple(np.ascontiguousarray(self.Minv_ref @ S) for S in (self.S0, self.S1))
        return self._D

    def boundary_data(self, t):
        """The outer data G of the boundary facets at time t (histories and outer states)."""
        if self._bstatic and not self._G_scaled:
            return
        self._G_scaled = False
        G = self.G
        G[:] = self.G0
        for hist, rows, unit in self._bhist:
            G[rows] += hist(t) * unit
        for bc, rows, pts, n, fill in self._bouter:
            if fill is not None:
                fill(G, rows, pts, n, t)
            else:
                G[rows] = _outer_frame(np.asarray(bc.state(pts, t)), n).reshape(rows.size, -1, 4)

    def dissipation_rate(self, xloc):
        """This rank's share of the interior upwind dissipation rate [W/m] (ghosts current)."""
        if self._cdiss is not None:
            return self._cdiss(xloc)
        return self._dissipation(xloc, self.dofs, self.fcells, self.fcodes, self.fown, self.normal, self.length,
                                 self.fnodes, self.Mf, self.Zd, self.Zs)

    def boundary_rates(self, xloc, t, sigma0):
        """This rank's (power in, power radiated out, upwind dissipation) of the boundary
        facets at time t [W/m] (``xloc``: local form incl. ghosts)."""
        if not self.bcells.size:
            return 0.0, 0.0, 0.0
        self.boundary_data(t)
        return self._boundary_energy(xloc, self.dofs, self.bcells, self.bcodes, self.bnormal, self.blength,
                                     self.bkinds, self.G, self.bradiating, self.fnodes, self.Mf, self.Zd, self.Zs,
                                     float(sigma0[0, 0]), float(sigma0[1, 1]), float(sigma0[0, 1]))

    def energies(self, xloc, state0):
        """This rank's (kinetic, strain) energy of x less the uniform initial state ``state0``
        (5,) [J/m]."""
        if self._cenergy is not None:
            return self._cenergy(xloc, state0)
        return self._energies(xloc, state0, self.dofs, self.nowned, self.Mref, self.absdet, self.Bmat)

    def apply(self, xloc, out, t=0.0):
        """out (owned values) = M^{-1}(K_vol + K_int + K_bdry) x + the boundary data's term at
        time t; ``xloc``: local form incl. ghosts."""
        self.begin(xloc, t)
        self.finish(xloc, out)

    def begin(self, xloc, t=0.0, data=True):
        """Clear the cell residual ``R`` and add the interior and boundary facet fluxes (the
        boundary data at time t; ``data=False``: the data already in ``G``); other facet terms
        (crack interfaces) may be added to ``R[c, j, :]`` (owned cell c, local basis j) before
        :meth:`finish`."""
        R = self.R
        if not self._R_clear:  # finish() clears R as it reads it; after an interrupted stage, here
            R[:] = 0.0
        self._R_clear = False
        if self._cfacets is not None:
            self._cfacets(R, xloc)
        else:
            self._facets(R, xloc, self.dofs, self.fcells, self.fcodes, self.normal, self.length, self.fnodes,
                         self.Mf, self.Zd, self.Zs, self.nowned)
        if self.bcells.size:
            if data:
                self.boundary_data(t)
            self._boundary(R, xloc, self.dofs, self.bcells, self.bcodes, self.bnormal, self.blength, self.bkinds,
                           self.G, self.fnodes, self.Mf, self.Zd, self.Zs)

    def finish(self, xloc, out):
        """out (owned values) = M^{-1} (R + volume terms)."""
        self._apply_volume(out, self.R, xloc)
        self._R_clear = True

    def _apply_volume(self, out, R, X):
        """out = M^{-1}(R + volume terms of X) on the owned cells; R cleared."""
        if self._cvolume is not None:
            self._cvolume(out, R, X)
        else:
            self._volume(out, R, X, self.dofs, self.nowned, self.S0, self.S1, self.Jinv, self.invdet,
                         self.Minv_ref, self.mat, self.Btab)
