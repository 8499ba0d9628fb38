"""Matrix-free bulk DG operator: cell-local numba kernels for the volume terms, the
upwind (bonded Riemann) flux on interior facets and the closed-form inverse mass.

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

import numpy as np

from . import compat
from ._jit import njit
from .element import line_quadrature, triangle_quadrature
from .riemann import bonded_jump_pt

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


@functools.lru_cache(maxsize=None)
def _kernels(nb, nk, contig=False):
    """The (volume + inverse mass, interior facet flux, facet dissipation, cell energies)
    kernels for ``nb`` basis functions per cell and ``nk`` on a facet, compiled with both as
    constants: LLVM then unrolls the small loops (2-3x faster than with run-time sizes at
    p = 1-3; numba caches each set)."""

    @njit
    def volume_and_inverse(out, R, X, dofs, ncells, S0, S1, Jinv, invdet, Minv_ref, mat, Btab):
        """out[cell dofs] = M_c^{-1} (R[c] + volume terms of c), for the owned cells (R[c] is zeroed);
        M_c^{-1} = Minv_ref kron B^{-1} / |det J_c|, with B^{-1} = diag(1/rho, 1/rho) + a 3x3
        stiffness block, stored once per material: ``Btab[mat[c]]`` = (1/rho, 1/rho, the 3x3 block
        row by row)."""
        u = np.empty((nb, 5))
        g0 = np.empty((nb, 5))
        g1 = np.empty((nb, 5))
        r = np.empty((nb, 5))
        tmp = np.empty((nb, 5))
        for c in range(ncells):
            for j in range(nb):
                base = 5 * (nb * c + j) if contig else 5 * dofs[c, j]
                for k in range(5):
                    u[j, k] = X[base + k]
            for i in range(nb):
                for k in range(5):
                    s0 = 0.0
                    s1 = 0.0
                    for j in range(nb):
                        s0 += S0[i, j] * u[j, k]
                        s1 += S1[i, j] * u[j, k]
                    g0[i, k] = s0
                    g1[i, k] = s1
            j00, j01, j10, j11 = Jinv[c, 0, 0], Jinv[c, 0, 1], Jinv[c, 1, 0], Jinv[c, 1, 1]
            e = invdet[c]  # (R + |det J| vol) / |det J|
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
                r[i, 0] = e * R[c, i, 0] + (dx_sxx + dy_sxy)
                r[i, 1] = e * R[c, i, 1] + (dx_sxy + dy_syy)
                r[i, 2] = e * R[c, i, 2] + dx_vx
                r[i, 3] = e * R[c, i, 3] + dy_vy
                r[i, 4] = e * R[c, i, 4] + (dy_vx + dx_vy)
                for k in range(5):
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
        """(kinetic, strain) energy of X - X0 on the owned cells: 1/2 u^T M_c u with
        M_c = |det J| Mref kron B_c (B_c: rho for v, the compliance for sigma)."""
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

    return volume_and_inverse, facet_fluxes, facet_dissipation, cell_energies


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


#: The forms of :mod:`hydrofrac.forms.elastodynamics` these kernels implement by hand, and the
#: SHA-256 of their source as the kernels were written for them (:func:`implements_forms`).
IMPLEMENTED_FORMS = ("fields", "compliance", "impedances", "tangent", "volume", "facet_flux", "bonded_riemann",
                     "interior_flux", "interior_dissipation")
IMPLEMENTED_SIGNATURE = "8f66d813fc80021fc1e1a85da386cedec626a14fc08b9cc082747967e9916004"


def forms_signature() -> str:
    """SHA-256 of the source of the forms in :data:`IMPLEMENTED_FORMS`, as they are now."""
    import hashlib
    import inspect

    from .forms import elastodynamics as ef
    text = "\n".join(inspect.getsource(getattr(ef, name)) for name in IMPLEMENTED_FORMS)
    return hashlib.sha256(text.encode()).hexdigest()


def implements_forms() -> bool:
    """Do the kernels implement the forms the solver is given?  False after an edit of any of
    :data:`IMPLEMENTED_FORMS` (the solver then assembles the operator from the edited forms)."""
    return forms_signature() == IMPLEMENTED_SIGNATURE


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
        self.invdet = 1.0 / self.absdet
        B = np.linalg.inv(solver.material_blocks)  # per cell, unscaled
        if np.any(B[:, :2, 2:]) or np.any(B[:, 2:, :2]) or np.any(B[:, 0, 1]) or np.any(B[:, 1, 0]):
            raise RuntimeError("the matrix-free kernel expects a material block diag(1/rho, 1/rho) + stiffness "
                               "(isotropic density); use operator='assembled' for other materials")
        # one row per distinct material: 1/rho (twice) and the 3x3 stiffness block
        packed = np.concatenate([B[:, 0, 0:1], B[:, 1, 1:2], B[:, 2:, 2:].reshape(-1, 9)], axis=1)
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
        self.fnodes, self.Mf = facet_nodes(ref, tables, self.qw)
        self._volume, self._facets, self._dissipation, self._energies = _kernels(nb, self.fnodes.shape[1],
                                                                                 self.contiguous)
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
        # visit the facets in cell order, so that both sides' blocks are mostly still in cache
        order = np.lexsort((c2.max(axis=1), c2.min(axis=1)))
        facets, c2 = facets[order], c2[order]
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
        self._R_clear = True
        self.Mref = np.ascontiguousarray(ref.mass())
        self.Bmat = solver.material_blocks

    def dissipation_rate(self, xloc):
        """This rank's share of the interior upwind dissipation rate [W/m] (ghosts current)."""
        return self._dissipation(xloc, self.dofs, self.fcells, self.fcodes, self.fown, self.normal, self.length,
                                 self.fnodes, self.Mf, self.Zd, self.Zs)

    def energies(self, xloc, x0loc):
        """This rank's (kinetic, strain) energy of x - x0 [J/m]."""
        return self._energies(xloc, x0loc, self.dofs, self.nowned, self.Mref, self.absdet, self.Bmat)

    def apply(self, xloc, out):
        """out (owned values) = M^{-1}(K_vol + K_int) x; ``xloc``: local form incl. ghosts."""
        self.begin(xloc)
        self.finish(xloc, out)

    def begin(self, xloc):
        """Clear the cell residual ``R`` and add the interior facet fluxes; other facet terms
        (crack interfaces) may be added to ``R[c, j, :]`` (owned cell c, local basis j)
        before :meth:`finish`."""
        R = self.R
        if not self._R_clear:  # finish() clears R as it reads it; after an interrupted stage, here
            R[:] = 0.0
        self._R_clear = False
        self._facets(R, xloc, self.dofs, self.fcells, self.fcodes, self.normal, self.length, self.fnodes, self.Mf,
                     self.Zd, self.Zs, self.nowned)

    def finish(self, xloc, out):
        """out (owned values) = M^{-1} (R + volume terms)."""
        self._volume(out, self.R, xloc, self.dofs, self.nowned, self.S0, self.S1, self.Jinv, self.invdet,
                     self.Minv_ref, self.mat, self.Btab)
        self._R_clear = True


@njit
def _rows_mult_add(out, y, rows, indptr, cols, vals):
    """out[rows[i]] += sum_k vals[k] y[cols[k]] over the stored rows i (CSR)."""
    for i in range(rows.size):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            acc += vals[k] * y[cols[k]]
        out[rows[i]] += acc


class SparseRows:
    """``out += A y`` for an operator whose few nonzero rows couple only owned values,
    such as the boundary-facet operator (each boundary cell with itself): the nonzero
    rows in CSR with local column indices, so a mat-vec touches the boundary cells only
    instead of every row of the vector (PETSc's MatMultAdd reads and writes all of
    ``out``).  ``A``: an assembled PETSc AIJ matrix; :meth:`from_petsc` returns None if a
    nonzero column is not owned by this rank (then keep PETSc's mat-vec)."""

    def __init__(self, rows, indptr, cols, vals):
        self.rows, self.indptr, self.cols, self.vals = rows, indptr, cols, vals

    @classmethod
    def from_petsc(cls, A):
        indptr, cols, vals = A.getValuesCSR()
        r0, r1 = A.getOwnershipRange()
        counts = np.diff(indptr)
        rows = np.nonzero(counts)[0]
        keep = np.repeat(counts > 0, counts)
        cols = cols[keep].astype(np.int64)
        if cols.size and (cols.min() < r0 or cols.max() >= r1):
            return None
        return cls(rows.astype(np.int64), np.concatenate([[0], np.cumsum(counts[rows])]).astype(np.int64),
                   cols - r0, np.ascontiguousarray(vals[keep]))

    def mult_add(self, y, out):
        """out += A y on this rank's owned values (arrays)."""
        _rows_mult_add(out, y, self.rows, self.indptr, self.cols, self.vals)
