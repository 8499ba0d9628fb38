"""Moving a run onto a new mesh (after remeshing): the bulk fields and the crack-interface
state.

* **Bulk fields** (v, sigma): L2 projection per new cell (conservative, default) or
  interpolation at the new nodes; see :func:`transfer_fields`.  The old field is evaluated in
  the old cell that contains each point, with that cell's own polynomial.  A new cell that is
  one of the rank's own old cells (outside a local remesh's patch) is copied from it; for the
  others, each rank receives only the old cells whose bounding box meets the box around them
  (:func:`_exchange_near`), then fills its own new cells without further communication.
* **Interface state** (damage, opening, slip, smallest opening): by arc length along the
  crack polylines.  Each new Gauss point is located on the old facet of the same crack tag
  whose segment contains it, and takes the state of that facet's Gauss point nearest in arc
  length (exact for state that is piecewise constant per old facet).  Points on no old facet
  (new segments of a growing crack) keep the new interface's initial state.

:class:`hydrofrac.growth.GrowthDriver` calls these after every remesh; the tests also run
them on remeshes of a fixed geometry.
"""
from __future__ import annotations

import copy

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc
from scipy.spatial import cKDTree

from . import compat, probes
from ._jit import njit


def _owned_cells(solver):
    """(x0 (c, 2), Jinv (c, 2, 2), centroid (c, 2), U (c, nb, 5), vertices (c, 3, 2)) of the
    owned cells."""
    g = solver.geometry
    n = compat.num_cells_local(solver.mesh)
    U = solver.x.array_r.reshape(-1, 5)
    dofs = compat.cell_dofs(solver.V)[:n]
    return g.x0[:n], g.Jinv[:n], g.centroid[:n], U[dofs], g.vertices[:n]


def _cell_keys(vertices):
    """A key per triangle that two triangles share exactly when they have the same three
    vertices (bit for bit), in any order: the sorted vertex coordinates as one opaque value."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    order = np.lexsort((v[:, :, 1], v[:, :, 0]), axis=1)
    s = np.ascontiguousarray(np.take_along_axis(v, order[:, :, None], axis=1).reshape(len(v), 6))
    return s.view(np.dtype((np.void, 6 * 8))).ravel()


def _same_cells(old_vertices, new_vertices):
    """(new index, old index) of the new cells that are old cells (the same vertices)."""
    if not len(old_vertices) or not len(new_vertices):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    _, new_i, old_i = np.intersect1d(_cell_keys(new_vertices), _cell_keys(old_vertices), assume_unique=True,
                                     return_indices=True)
    return new_i.astype(np.int64), old_i.astype(np.int64)


def _exchange_near(comm, old_cells, old_vertices, new_vertices):
    """The old cells (``old_cells``: arrays of :func:`_owned_cells`, this rank's; their
    ``old_vertices``) that any point of the given new cells (``new_vertices``, this rank's) can
    lie in, from every rank: each rank sends to each other rank, and keeps of its own, only the
    old cells whose bounding box meets the box around that rank's new cells.  Every old cell a
    point can lie in is then here; the whole old mesh is not (docs/benchmarks.md,
    "Remeshing")."""
    if comm.size == 1:
        return list(old_cells)
    # a cell can hold a point of a box only if its own box meets it (widened by a hair for the
    # round-off of points on an edge, 1e-9 of the largest old cell)
    lo, hi = old_vertices.min(axis=1), old_vertices.max(axis=1)
    pad = 1e-9 * comm.allreduce(float((hi - lo).max()) if len(lo) else 0.0, op=MPI.MAX)
    box = ((new_vertices.reshape(-1, 2).min(axis=0), new_vertices.reshape(-1, 2).max(axis=0))
           if new_vertices.size else None)
    # one row of doubles per picked old cell (its arrays side by side), sent as raw buffers: no
    # pickling, and this rank's own rows are kept, not sent to itself
    shapes = [a.shape[1:] for a in old_cells]
    widths = [int(np.prod(sh)) for sh in shapes]
    width = sum(widths)

    def rows(idx):
        return np.concatenate([np.asarray(a[idx], dtype=np.float64).reshape(len(idx), w)
                               for a, w in zip(old_cells, widths)], axis=1)
    picks = []
    for b in comm.allgather(box):
        picks.append(np.zeros(0, np.int64) if b is None else
                     np.flatnonzero(np.all((hi >= b[0] - pad) & (lo <= b[1] + pad), axis=1)))
    me = comm.rank
    send_n = np.array([0 if r == me else p.size for r, p in enumerate(picks)], dtype=np.int64)
    recv_n = np.empty_like(send_n)
    comm.Alltoall(send_n, recv_n)
    sendbuf = np.concatenate([rows(p) for r, p in enumerate(picks) if r != me] + [np.zeros((0, width))])
    recvbuf = np.empty((int(recv_n.sum()), width))
    comm.Alltoallv([sendbuf, send_n * width, MPI.DOUBLE], [recvbuf, recv_n * width, MPI.DOUBLE])
    offsets = np.r_[0, np.cumsum(recv_n)]
    got = np.concatenate([rows(picks[me]) if r == me else recvbuf[offsets[r]:offsets[r + 1]]
                          for r in range(comm.size)])  # by source rank, as before
    cols = np.r_[0, np.cumsum(widths)]
    return [np.ascontiguousarray(got[:, cols[i]:cols[i + 1]]).reshape((-1,) + sh) for i, sh in enumerate(shapes)]


def _locate(tree, x0, Jinv, pts, k, hint=None):
    """Old cell containing each point (the nearest miss if none) and the point's reference
    coordinates in it; ``hint`` (points moved a hair into the wanted side) picks the cell,
    the reference coordinates are those of ``pts``.  Returns (cell, Xref, largest miss).

    The cells are tried nearest centroid first, ``k`` at a time and then 4 times more, until a
    cell holds the point or no cell left can: a cell holds only points within its largest
    centroid-to-vertex distance, so the search ends where the next centroid is farther than the
    largest of those.  A big cell beside small ones (a graded mesh) can hold a point whose 16
    nearest centroids are all small cells'; a fixed ``k`` then took the nearest miss, and the
    answer depended on which old cells a rank held (docs/benchmarks.md, "Point location in a
    graded mesh")."""
    search = pts if hint is None else hint
    n, m = search.shape[0], x0.shape[0]
    cell = np.zeros(n, dtype=np.int64)
    lam_best = np.full(n, -np.inf)
    todo = np.arange(n)
    kk = min(k, m)
    reach = None
    while todo.size:
        dist, cand = tree.query(search[todo], k=kk)
        cand, dist = cand.reshape(todo.size, kk), np.asarray(dist).reshape(todo.size, kk)
        ref = np.einsum("nkij,nkj->nki", Jinv[cand], search[todo, None, :] - x0[cand])
        lam = np.concatenate([1 - ref.sum(axis=2, keepdims=True), ref], axis=2).min(axis=2)
        best = np.argmax(lam, axis=1)  # inside (>= 0) if any; else the nearest miss
        rows = np.arange(todo.size)
        cell[todo], lam_best[todo] = cand[rows, best], lam[rows, best]
        if kk == m:
            break
        if reach is None:  # the largest centroid-to-vertex distance of the old cells
            J = np.linalg.inv(Jinv)
            corners = x0[:, None, :] + np.concatenate([np.zeros((m, 1, 2)), np.swapaxes(J, 1, 2)], axis=1)
            reach = float(np.sqrt(((corners - tree.data[:, None, :]) ** 2).sum(axis=2)).max())
        todo = todo[(lam_best[todo] < -1e-12) & (dist[:, -1] <= reach)]  # (-1e-12: a point on an edge)
        kk = min(4 * kk, m)
    miss = float(max(0.0, -lam_best.min())) if n else 0.0
    Xref = np.einsum("nij,nj->ni", Jinv[cell], pts - x0[cell])
    return cell, Xref, miss


@njit
def _inside_candidates(x0, Jinv, pts, cand, per):
    """Old cell strictly containing each point (barycentric minimum > 1e-10: the unique one),
    tried among the candidates ``cand[i // per]`` of its new cell in order, the first that
    contains it; -1 where none does."""
    cell = np.full(pts.shape[0], -1, dtype=np.int64)
    for i in range(pts.shape[0]):
        row = i // per
        for j in range(cand.shape[1]):
            o = cand[row, j]
            dx, dy = pts[i, 0] - x0[o, 0], pts[i, 1] - x0[o, 1]
            r0 = Jinv[o, 0, 0] * dx + Jinv[o, 0, 1] * dy
            r1 = Jinv[o, 1, 0] * dx + Jinv[o, 1, 1] * dy
            if min(1.0 - r0 - r1, min(r0, r1)) > 1e-10:
                cell[i] = o
                break
    return cell


def _locate_by_cell(tree, x0, Jinv, pts, centroids, per, k):
    """:func:`_locate` for ``per`` points of each new cell: the old cells nearest the new
    cell's centroid are tried first (one tree query per cell, a compiled pass with an early
    exit); the points none of them contains strictly, the per-point search decides."""
    kk = min(k, x0.shape[0])
    _, cand = tree.query(centroids, k=kk)
    cell = _inside_candidates(x0, Jinv, pts, np.ascontiguousarray(cand.reshape(centroids.shape[0], kk)), per)
    miss = 0.0
    rest = np.flatnonzero(cell < 0)
    if rest.size:
        cell[rest], _, miss = _locate(tree, x0, Jinv, pts[rest], k)
    Xref = np.einsum("nij,nj->ni", Jinv[cell], pts - x0[cell])
    return cell, Xref, miss


@njit
def _evaluate(T, U, cell):
    """The old fields at points: sum_j T[n, j] U[cell[n], j, :] (without gathering U[cell])."""
    out = np.zeros((T.shape[0], U.shape[2]))
    for n in range(T.shape[0]):
        c = cell[n]
        for j in range(T.shape[1]):
            t = T[n, j]
            for k in range(U.shape[2]):
                out[n, k] += t * U[c, j, k]
    return out


def _copied(new, old, x0, Jinv, U, V_old, same_old, same_new):
    """The values (c, nb, 5) of the new cells ``same_new`` that are the old cells ``same_old``
    of the arrays ``x0, Jinv, U, V_old`` (as :func:`_owned_cells` gives them): the old values as they are,
    their nodes matched by position where the vertices come in another order (a cell with its
    vertices in the old order has its nodes in the old order too)."""
    g = new.geometry
    copied = U[same_old].copy()
    turned = np.flatnonzero((g.vertices[same_new] != V_old[same_old]).any(axis=(1, 2)))
    if turned.size:
        sn, so = same_new[turned], same_old[turned]
        pn = g.x0[sn, None, :] + np.einsum("cij,nj->cni", g.J[sn], new.ref.nodes)
        po = x0[so, None, :] + np.einsum("cij,nj->cni", np.linalg.inv(Jinv[so]), old.ref.nodes)
        perm = np.argmin(((pn[:, :, None, :] - po[:, None, :, :]) ** 2).sum(axis=3), axis=2)
        copied[turned] = np.take_along_axis(U[so], perm[:, :, None], axis=1)
    return copied


def transfer_fields(old, new, method="projection", k=16):
    """Set ``new.x`` from ``old``'s DG fields; returns the largest barycentric miss (0 when
    every evaluation point lies in an old cell).

    method "projection" (default, conservative): per new cell, the L2 projection of the old
    fields onto the new cell's polynomials (quadrature of degree 2p + 4 on the new cell, the
    old field evaluated in the old cell containing each quadrature point); since the cells'
    mass matrices are |det J| M_ref kron B with B constant per cell, this is also the
    projection in the energy inner product, so it never adds energy.  method "interpolation":
    the old fields at the new nodes.  Both move a polynomial field of degree <= p exactly.  A new
    cell with the same vertices as an old one (outside a local remesh's patch) takes the old
    cell's values unchanged, bit for bit, and the point sets located on the old mesh stay
    located in it (:func:`hydrofrac.probes.carry_locations`)."""
    from .element import triangle_quadrature
    if method not in ("projection", "interpolation"):
        raise ValueError(f"transfer method must be 'projection' or 'interpolation'; got {method!r}")
    comm = new.comm
    n_old = compat.num_cells_local(old.mesh)
    n_new = compat.num_cells_local(new.mesh)
    dofs = compat.cell_dofs(new.V)[:n_new]
    g = new.geometry
    none = np.zeros(0, np.int64)
    # a new cell that is an old cell (a local remesh keeps the cells outside its patch) takes the
    # old cell's values as they are: first those this rank owned, then, from the old cells the
    # others send, the rest (cells a rebalance moved).  Only the cells not found here decide
    # what the others send: after a local remesh, the patch and its surroundings
    own = _owned_cells(old)
    same = old.degree == new.degree
    here_new, here_old = _same_cells(own[4], g.vertices[:n_new]) if same else (none, none)
    in_order = (g.vertices[here_new] == own[4][here_old]).all(axis=(1, 2))  # (the same vertex order too)
    probes.carry_locations(old, new, (here_new[in_order], here_old[in_order]))
    rest = np.setdiff1d(np.arange(n_new), here_new)
    x0, Jinv, cent, U, V_old = _exchange_near(comm, own, old.geometry.vertices[:n_old], g.vertices[rest])
    far_new, far_old = _same_cells(V_old, g.vertices[rest]) if same and comm.size > 1 else (none, none)
    copied = np.concatenate([_copied(new, old, own[0], own[1], own[3], own[4], here_old, here_new),
                             _copied(new, old, x0, Jinv, U, V_old, far_old, rest[far_new])])
    same_new = np.concatenate([here_new, rest[far_new]])
    todo = np.setdiff1d(rest, same_new)  # the cells the transfer computes
    tree = cKDTree(cent)
    miss = 0.0
    vals = np.zeros((0, 5))
    if todo.size and method == "interpolation":
        X = compat.dof_coordinates(new.V)[:, :2]
        pts = X[dofs[todo]].reshape(-1, 2)
        cc = np.repeat(g.vertices[todo].mean(axis=1), dofs.shape[1], axis=0)
        cell, Xref, miss = _locate(tree, x0, Jinv, pts, k, hint=pts + 1e-6 * (cc - pts))
        vals = _evaluate(old.ref.tabulate(Xref), np.ascontiguousarray(U), cell)
    elif todo.size:
        Xq, wq = triangle_quadrature(2 * new.degree + 4)
        nq = wq.size
        pts = (g.x0[todo, None, :] + np.einsum("cij,qj->cqi", g.J[todo], Xq)).reshape(-1, 2)
        cell, Xref, miss = _locate_by_cell(tree, np.ascontiguousarray(x0), np.ascontiguousarray(Jinv), pts,
                                           g.vertices[todo].mean(axis=1), nq, k)
        uq = _evaluate(old.ref.tabulate(Xref), np.ascontiguousarray(U), cell).reshape(todo.size, nq, 5)
        phi = new.ref.tabulate(Xq)  # (nq, nb): the |det J| of the new cell cancels
        b = np.matmul((wq[:, None] * phi).T, uq)  # (c, nb, 5)
        vals = np.matmul(new.Mref_inv, b).reshape(-1, 5)
    with new.x.localForm() as xl:
        arr = xl.array.reshape(-1, 5)
        arr[dofs[todo].reshape(-1)] = vals
        if same_new.size:
            arr[dofs[same_new].reshape(-1)] = copied.reshape(-1, 5)
    new.x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
    return comm.allreduce(miss, op=MPI.MAX)


def continue_run(old, new):
    """Carry time, step count and the energy budget of solver ``old`` over to ``new`` (after
    :func:`transfer_fields`); returns the total energy before and after the transfer [J/m]
    (the difference is the transfer's interpolation error)."""
    new.t, new.step_count = old.t, old.step_count
    # the remeshes' time split so far (hydrofrac.adapt.carry_over adds its parts), with the new
    # solver's own set-up
    new.remesh_split_s = dict(getattr(old, "remesh_split_s", {}))
    new.remesh_split_s["solver set-up"] = new.remesh_split_s.get("solver set-up", 0.0) + new.timers.t.get("setup", 0.0)
    new.timers = old.timers  # one wall-time split for the whole run
    before = old.energy.total
    new.energy = copy.deepcopy(old.energy)
    new.energy.kinetic, new.energy.strain = new.energies()
    new.energy.transfer_loss += before - new.energy.total  # reported, so the budget still closes
    new.account.last_rates = old.account.last_rates  # the trapezoid of the next step starts from the old rates
    new.account.recent_balance = list(old.account.recent_balance)
    return before, new.energy.total


@njit
def _match_on_old_facets(va, vb, tags_sorted, order, points, new_tag, s_old, tol):
    """For each new Gauss point ``points[f, q]``: the old facet of tag ``new_tag[f]`` whose
    segment holds it (distance <= tol times the longest old facet, arc parameter u in [0, 1]),
    the nearest if several (the lowest index on a tie), and the old Gauss point nearest in u.
    ``order`` sorts the old facets by tag (``tags_sorted``).  Returns (old facet, its Gauss
    point), -1 where the point lies on no old facet of its tag."""
    nf, nq = points.shape[0], points.shape[1]
    g_out = np.full((nf, nq), -1, dtype=np.int64)
    iq_out = np.zeros((nf, nq), dtype=np.int64)
    L2max = 0.0
    for i in range(va.shape[0]):
        L2max = max(L2max, (vb[i, 0] - va[i, 0]) ** 2 + (vb[i, 1] - va[i, 1]) ** 2)
    reach = tol * np.sqrt(L2max) + 1e-12
    for f in range(nf):
        lo = np.searchsorted(tags_sorted, new_tag[f], side="left")
        hi = np.searchsorted(tags_sorted, new_tag[f], side="right")
        for q in range(nq):
            px, py = points[f, q, 0], points[f, q, 1]
            best, best_d, best_u = -1, np.inf, 0.0
            for m in range(lo, hi):
                o = order[m]
                sx, sy = vb[o, 0] - va[o, 0], vb[o, 1] - va[o, 1]
                u = ((px - va[o, 0]) * sx + (py - va[o, 1]) * sy) / (sx * sx + sy * sy)
                if u < -1e-9 or u > 1 + 1e-9:
                    continue
                c = min(max(u, 0.0), 1.0)
                d = np.sqrt((px - va[o, 0] - c * sx) ** 2 + (py - va[o, 1] - c * sy) ** 2)
                if d <= reach and d < best_d:
                    best, best_d, best_u = o, d, u
            if best >= 0:
                g_out[f, q] = best
                k = 0
                for j in range(1, s_old.size):
                    if abs(s_old[j] - best_u) < abs(s_old[k] - best_u):
                        k = j
                iq_out[f, q] = k
    return g_out, iq_out


def transfer_interface(old, new, tol=1e-9):
    """Copy the interface state of ``old`` (an :class:`~hydrofrac.interface.Interface`) onto
    ``new``'s Gauss points by arc length along facets of the same crack tag (see the module
    docstring).  Returns the number of new Gauss points (all ranks) found on an old facet."""
    comm = new.solver.comm
    nq_old = old.nq
    parts = comm.allgather((old.va, old.vb, old.crack_tag, old.state, old.min_opening))
    va = np.concatenate([p[0] for p in parts]).reshape(-1, 2)
    vb = np.concatenate([p[1] for p in parts]).reshape(-1, 2)
    tag = np.concatenate([p[2] for p in parts])
    st = np.concatenate([p[3] for p in parts], axis=1).reshape(3, -1, nq_old)
    mo = np.concatenate([p[4] for p in parts]).reshape(-1, nq_old)
    s_old, _ = np.polynomial.legendre.leggauss(nq_old)
    s_old = 0.5 * (s_old + 1)
    state, min_open = new.state.copy(), new.min_opening.copy()
    found = 0
    if new.facets.size and va.shape[0]:
        order = np.argsort(tag, kind="stable")  # old facets grouped by tag, in index order within a tag
        g, iq = _match_on_old_facets(np.ascontiguousarray(va), np.ascontiguousarray(vb), tag[order], order,
                                     np.ascontiguousarray(new.points, dtype=np.float64),
                                     np.asarray(new.crack_tag, dtype=tag.dtype), s_old, tol)
        hit = g >= 0
        state[:, hit] = st[:, g[hit], iq[hit]]
        min_open[hit] = mo[g[hit], iq[hit]]
        found = int(hit.sum())
    if new.contact.delta0 != old.contact.delta0 and new.facets.size:
        # a band resolved in time on a mesh with another step: a penetration keeps its place
        # x = delta / (delta'_0 delta~) in the band (hence eta), not its length; a point at the
        # old floor (x = 1) is at the new one exactly
        ds = new.delta_scale[:, None]
        for a in (state[1], min_open):
            x = np.minimum(a / (old.contact.delta0 * ds), 1.0)
            a[...] = np.where(a < 0, x * (new.contact.delta0 * ds), a)
    new.state = state
    new.stage_state = state.copy()
    new._delta_prev = state[1].copy()
    new.min_opening = min_open
    new.clip_count, new.clip_depth = old.clip_count, old.clip_depth  # (summed over ranks when reported)
    new.closing_max = old.closing_max
    new.solver.x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
    new.evaluate(new.solver.x, new.solver.t, store=True)
    return comm.allreduce(found, op=MPI.SUM)
