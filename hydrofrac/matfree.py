"""Matrix-free bulk DG operator: cell-local numba kernels for the volume terms, the
upwind (bonded Riemann) flux on interior facets and the closed-form inverse mass.

``MatrixFreeOperator.apply(x, out)`` computes ``out = M^{-1} (K_vol + K_int) x`` on the
owned cells, for the same weak form as :mod:`hydrofrac.forms.elastodynamics` (the tests
check it against the assembled forms to round-off).  Boundary facets keep their
assembled (sparse, boundary cells only) operator in the solver; crack facets are left
out here as in the assembled bulk flux (:mod:`hydrofrac.interface` handles them).

Per cell (affine triangles): the volume terms use the reference derivative matrices
``S_r[i, j] = int phi_i d_r phi_j`` and the cell's inverse Jacobian; each interior facet
evaluates both traces at its Gauss points with shared reference tables (one per ordered
pair of reference vertices), solves the bonded Riemann problem with
:func:`hydrofrac.riemann.bonded_pt` and adds the flux corrections to the owned sides.
Facets between an owned and a ghost cell are computed on both ranks, each keeping its own
side, so no reverse scatter is needed; ghost values must be current (forward scatter).
"""
from __future__ import annotations

import numpy as np

from . import compat
from ._jit import njit
from .element import line_quadrature, triangle_quadrature
from .kernels import kron_inverse
from .riemann import bonded_pt

_REF_VERTICES = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])


@njit
def _volume_and_inverse(out, R, X, dofs, ncells, S0, S1, Jinv, absdet, Minv_ref, Binv):
    """out[cell dofs] = M_c^{-1} (R[c] + volume terms of c), for the owned cells."""
    nb = dofs.shape[1]
    u = np.empty((nb, 5))
    g0 = np.empty((nb, 5))
    g1 = np.empty((nb, 5))
    r = np.empty((nb, 5))
    tmp = np.empty((nb, 5))
    res = np.empty((nb, 5))
    for c in range(ncells):
        for j in range(nb):
            base = 5 * dofs[c, j]
            for k in range(5):
                u[j, k] = X[base + k]
        g0[:] = 0.0
        g1[:] = 0.0
        for i in range(nb):
            for j in range(nb):
                a0 = S0[i, j]
                a1 = S1[i, j]
                for k in range(5):
                    g0[i, k] += a0 * u[j, k]
                    g1[i, k] += a1 * u[j, k]
        j00, j01, j10, j11 = Jinv[c, 0, 0], Jinv[c, 0, 1], Jinv[c, 1, 0], Jinv[c, 1, 1]
        d = absdet[c]
        for i in range(nb):
            # d/dx = Jinv[0,0] d/dX0 + Jinv[1,0] d/dX1 ; d/dy = Jinv[0,1] d/dX0 + Jinv[1,1] d/dX1
            dx_vx = j00 * g0[i, 0] + j10 * g1[i, 0]
            dy_vx = j01 * g0[i, 0] + j11 * g1[i, 0]
            dx_vy = j00 * g0[i, 1] + j10 * g1[i, 1]
            dy_vy = j01 * g0[i, 1] + j11 * g1[i, 1]
            dx_sxx = j00 * g0[i, 2] + j10 * g1[i, 2]
            dy_syy = j01 * g0[i, 3] + j11 * g1[i, 3]
            dx_sxy = j00 * g0[i, 4] + j10 * g1[i, 4]
            dy_sxy = j01 * g0[i, 4] + j11 * g1[i, 4]
            r[i, 0] = R[c, i, 0] + d * (dx_sxx + dy_sxy)
            r[i, 1] = R[c, i, 1] + d * (dx_sxy + dy_syy)
            r[i, 2] = R[c, i, 2] + d * dx_vx
            r[i, 3] = R[c, i, 3] + d * dy_vy
            r[i, 4] = R[c, i, 4] + d * (dy_vx + dx_vy)
        kron_inverse(r, Minv_ref, Binv[c], tmp, res)  # M_c^{-1} = Minv_ref kron Binv[c]
        for a in range(nb):
            base = 5 * dofs[c, a]
            for k in range(5):
                out[base + k] = res[a, k]


@njit
def _facet_fluxes(R, X, dofs, fcells, fcodes, normal, length, qw, tables, Zd, Zs, nowned):
    """R[c] += upwind flux corrections of every listed interior facet, on its owned sides."""
    nq = qw.shape[0]
    nb = dofs.shape[1]
    for f in range(fcells.shape[0]):
        cp, cm = fcells[f, 0], fcells[f, 1]
        Tp, Tm = tables[fcodes[f, 0]], tables[fcodes[f, 1]]
        nx, ny = normal[f, 0], normal[f, 1]
        Zpn, Zps, Zmn, Zms = Zd[cp], Zs[cp], Zd[cm], Zs[cm]
        for q in range(nq):
            # both traces in one loop, inline: calling kernels' per-row trace helper here
            # (row views of dofs and tables per point) halved this kernel's throughput
            up0 = up1 = up2 = up3 = up4 = 0.0
            um0 = um1 = um2 = um3 = um4 = 0.0
            for j in range(nb):
                a = Tp[q, j]
                b = 5 * dofs[cp, j]
                up0 += a * X[b]
                up1 += a * X[b + 1]
                up2 += a * X[b + 2]
                up3 += a * X[b + 3]
                up4 += a * X[b + 4]
                a = Tm[q, j]
                b = 5 * dofs[cm, j]
                um0 += a * X[b]
                um1 += a * X[b + 1]
                um2 += a * X[b + 2]
                um3 += a * X[b + 3]
                um4 += a * X[b + 4]
            # local (normal, tangential) components, t = (-ny, nx)
            vpn, vpt = up0 * nx + up1 * ny, -up0 * ny + up1 * nx
            vmn, vmt = um0 * nx + um1 * ny, -um0 * ny + um1 * nx
            sx, sy = up2 * nx + up4 * ny, up4 * nx + up3 * ny
            spn, spt = sx * nx + sy * ny, -sx * ny + sy * nx
            sx, sy = um2 * nx + um4 * ny, um4 * nx + um3 * ny
            smn, smt = sx * nx + sy * ny, -sx * ny + sy * nx
            sBn, vBn = bonded_pt(vpn, vmn, spn, smn, Zpn, Zmn)
            sBt, vBt = bonded_pt(vpt, vmt, spt, smt, Zps, Zms)
            w = qw[q] * length[f]
            for side in range(2):
                if side == 0:
                    c, T, sgn = cp, Tp, 1.0
                    dsn, dst, dvn, dvt = sBn - spn, sBt - spt, vBn - vpn, vBt - vpt
                else:
                    c, T, sgn = cm, Tm, -1.0
                    dsn, dst, dvn, dvt = sBn - smn, sBt - smt, vBn - vmn, vBt - vmt
                if c >= nowned:
                    continue
                dsx, dsy = dsn * nx - dst * ny, dsn * ny + dst * nx
                dvx, dvy = dvn * nx - dvt * ny, dvn * ny + dvt * nx
                mx, my = sgn * nx, sgn * ny
                F0, F1 = w * sgn * dsx, w * sgn * dsy
                F2, F3, F4 = w * dvx * mx, w * dvy * my, w * (dvx * my + dvy * mx)
                for j in range(nb):
                    a = T[q, j]
                    R[c, j, 0] += a * F0
                    R[c, j, 1] += a * F1
                    R[c, j, 2] += a * F2
                    R[c, j, 3] += a * F3
                    R[c, j, 4] += a * F4


@njit
def _facet_dissipation(X, dofs, fcells, fcodes, fown, normal, length, qw, tables, Zd, Zs):
    """Rate of energy dissipated by the upwind flux on the owned listed facets:
    int sum_i Z_i+ Z_i- / (Z_i+ + Z_i-) [[v_i]]^2 + [[s_i]]^2 / (Z_i+ + Z_i-), i = n, t
    (the quadratic form of :func:`hydrofrac.forms.elastodynamics.interior_dissipation`)."""
    nq = qw.shape[0]
    nb = dofs.shape[1]
    total = 0.0
    for f in range(fcells.shape[0]):
        if not fown[f]:
            continue
        cp, cm = fcells[f, 0], fcells[f, 1]
        Tp, Tm = tables[fcodes[f, 0]], tables[fcodes[f, 1]]
        nx, ny = normal[f, 0], normal[f, 1]
        Zpn, Zps, Zmn, Zms = Zd[cp], Zs[cp], Zd[cm], Zs[cm]
        acc = 0.0
        for q in range(nq):
            d0 = d1 = d2 = d3 = d4 = 0.0  # jumps of the five fields, + minus -
            for j in range(nb):
                a = Tp[q, j]
                b = Tm[q, j]
                ip = 5 * dofs[cp, j]
                im = 5 * dofs[cm, j]
                d0 += a * X[ip] - b * X[im]
                d1 += a * X[ip + 1] - b * X[im + 1]
                d2 += a * X[ip + 2] - b * X[im + 2]
                d3 += a * X[ip + 3] - b * X[im + 3]
                d4 += a * X[ip + 4] - b * X[im + 4]
            dvn, dvt = d0 * nx + d1 * ny, -d0 * ny + d1 * nx
            sx, sy = d2 * nx + d4 * ny, d4 * nx + d3 * ny
            dsn, dst = sx * nx + sy * ny, -sx * ny + sy * nx
            acc += qw[q] * (Zpn * Zmn / (Zpn + Zmn) * dvn * dvn + dsn * dsn / (Zpn + Zmn)
                            + Zps * Zms / (Zps + Zms) * dvt * dvt + dst * dst / (Zps + Zms))
        total += acc * length[f]
    return total


@njit
def _cell_energies(X, X0, dofs, ncells, Mref, absdet, Bmat):
    """(kinetic, strain) energy of X - X0 on the owned cells: 1/2 u^T M_c u with
    M_c = |det J| Mref kron B_c (B_c: rho for v, the compliance for sigma)."""
    nb = dofs.shape[1]
    u = np.empty((nb, 5))
    kin = 0.0
    strain = 0.0
    for c in range(ncells):
        for j in range(nb):
            base = 5 * dofs[c, j]
            for k in range(5):
                u[j, k] = X[base + k] - X0[base + k]
        B = Bmat[c]
        ek = 0.0
        es = 0.0
        for a in range(nb):
            for b in range(nb):
                m = Mref[a, b]
                ek += m * (B[0, 0] * u[a, 0] * u[b, 0] + B[1, 1] * u[a, 1] * u[b, 1])
                s = 0.0
                for k in range(2, 5):
                    for l in range(2, 5):
                        s += B[k, l] * u[a, k] * u[b, l]
                es += m * s
        kin += absdet[c] * ek
        strain += absdet[c] * es
    return 0.5 * kin, 0.5 * strain


class MatrixFreeOperator:
    """Bulk operator M^{-1}(K_vol + K_int) of a :class:`~hydrofrac.solver.Solver`, applied
    cell by cell (see the module docstring).  ``facets``: local indices of the interior
    facets that carry the bulk upwind flux."""

    def __init__(self, solver, facets):
        mesh = solver.mesh
        tdim = mesh.topology.dim
        ref, g = solver.ref, solver.geometry
        p = solver.degree
        self.nowned = compat.num_cells_local(mesh)
        # reference derivative matrices S_r[i, j] = int phi_i d_r phi_j
        Xq, wq = triangle_quadrature(2 * p)
        phi = ref.tabulate(Xq)
        dphi = ref.tabulate_grad(Xq)
        self.S0 = np.ascontiguousarray(np.einsum("q,qi,qj->ij", wq, phi, dphi[:, :, 0]))
        self.S1 = np.ascontiguousarray(np.einsum("q,qi,qj->ij", wq, phi, dphi[:, :, 1]))
        self.Jinv = np.ascontiguousarray(g.Jinv)
        self.absdet = np.ascontiguousarray(np.abs(g.detJ))
        self.Minv_ref = solver.Mref_inv
        self.Binv = solver.Binv_scaled
        self.dofs = np.ascontiguousarray(compat.cell_dofs(solver.V), dtype=np.int64)
        cs = np.sqrt(solver.mu_cell / solver.rho_cell)
        self.Zd = np.ascontiguousarray(solver.rho_cell * solver.cd_cell)
        self.Zs = np.ascontiguousarray(solver.rho_cell * cs)

        # facets: both cells, + side = the cell the normal points away from
        s, w = line_quadrature(2 * p + 1)
        self.qw = np.ascontiguousarray(w)
        # one table per ordered pair (i, j) of reference vertices: the facet from vertex i to j
        tables = np.zeros((9, s.size, ref.nodes.shape[0]))
        for i in range(3):
            for j in range(3):
                if i != j:
                    pts = _REF_VERTICES[i] + s[:, None] * (_REF_VERTICES[j] - _REF_VERTICES[i])
                    tables[3 * i + j] = ref.tabulate(pts)
        self.tables = tables
        f_off, f_arr = compat.connectivity(mesh, tdim - 1, 0)
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
        x = mesh.geometry.x[:, :2]
        v2g = compat.vertex_to_geometry(mesh)
        va = x[v2g[f_arr[f_off[facets]]]]
        vb = x[v2g[f_arr[f_off[facets] + 1]]]
        tang = vb - va
        length = np.linalg.norm(tang, axis=1)
        n = np.stack([tang[:, 1], -tang[:, 0]], axis=1) / np.maximum(length, 1e-300)[:, None]
        centroid = g.vertices.mean(axis=1)
        mid = 0.5 * (va + vb)
        first_is_plus = np.einsum("fi,fi->f", centroid[c2[:, 0]] - mid, n) < 0
        cells = np.where(first_is_plus[:, None], c2, c2[:, ::-1])
        codes = np.zeros_like(cells)
        for side in range(2):
            Xa = g.to_reference(cells[:, side], va)
            Xb = g.to_reference(cells[:, side], vb)
            ia = np.argmin(np.linalg.norm(Xa[:, None, :] - _REF_VERTICES[None], axis=2), axis=1)
            ib = np.argmin(np.linalg.norm(Xb[:, None, :] - _REF_VERTICES[None], axis=2), axis=1)
            if facets.size:
                err = max(np.abs(Xa - _REF_VERTICES[ia]).max(), np.abs(Xb - _REF_VERTICES[ib]).max())
                if err > 1e-8 or np.any(ia == ib):
                    raise RuntimeError(f"facet vertices do not map onto reference vertices (error {err:.2e})")
            codes[:, side] = 3 * ia + ib
        fmask = compat.facet_owned_mask(mesh)
        self.fown = np.ascontiguousarray(fmask[facets])  # count each facet once in global sums
        self.fcells = np.ascontiguousarray(cells, dtype=np.int64)
        self.fcodes = np.ascontiguousarray(codes, dtype=np.int64)
        self.normal = np.ascontiguousarray(n)
        self.length = np.ascontiguousarray(length)
        self.R = np.zeros((self.nowned, self.dofs.shape[1], 5))
        self.Mref = np.ascontiguousarray(ref.mass())
        self.Bmat = solver.material_blocks

    def dissipation_rate(self, xloc):
        """This rank's share of the interior upwind dissipation rate [W/m] (ghosts current)."""
        return _facet_dissipation(xloc, self.dofs, self.fcells, self.fcodes, self.fown, self.normal, self.length,
                                  self.qw, self.tables, self.Zd, self.Zs)

    def energies(self, xloc, x0loc):
        """This rank's (kinetic, strain) energy of x - x0 [J/m]."""
        return _cell_energies(xloc, x0loc, self.dofs, self.nowned, self.Mref, self.absdet, self.Bmat)

    def apply(self, xloc, out):
        """out (owned values) = M^{-1}(K_vol + K_int) x; ``xloc``: local form incl. ghosts."""
        self.begin(xloc)
        self.finish(xloc, out)

    def begin(self, xloc):
        """Clear the cell residual ``R`` and add the interior facet fluxes; other facet terms
        (crack interfaces) may be added to ``R[c, j, :]`` (owned cell c, local basis j)
        before :meth:`finish`."""
        R = self.R
        R[:] = 0.0
        _facet_fluxes(R, xloc, self.dofs, self.fcells, self.fcodes, self.normal, self.length, self.qw,
                      self.tables, self.Zd, self.Zs, self.nowned)

    def finish(self, xloc, out):
        """out (owned values) = M^{-1} (R + volume terms)."""
        _volume_and_inverse(out, self.R, xloc, self.dofs, self.nowned, self.S0, self.S1, self.Jinv, self.absdet,
                            self.Minv_ref, self.Binv)
