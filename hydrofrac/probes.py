"""Probes (receivers): the fields at physical points and the crack state at arc-length positions.

* :func:`field_at` gives (v_x, v_y, s_xx, s_yy, s_xy) at points from the state vector: the
  cells are found by DOLFINx's bounding-box tree (compiled), the basis is tabulated for all
  points at once.  A point on a facet takes the mean of the owned cells that contain it, so
  the value does not depend on the partition; NaN where no cell contains the point.
* :func:`crack_at` gives opening, slip, tractions, D, η and f_p at positions along a crack
  (tag, arc length from its first point), from the nearest Gauss point on that crack.
* :class:`ProbeWriter` writes ``probes.csv`` as a run goes (``--probes x,y;x,y``).
"""
from __future__ import annotations

from typing import Dict, Sequence, Tuple

import numpy as np
from mpi4py import MPI

from . import compat
from ._jit import njit

FIELDS = ("v_x", "v_y", "s_xx", "s_yy", "s_xy")
CRACK_FIELDS = ("opening", "slip", "traction_n", "traction_t", "D", "eta", "f_p")


#: point sets whose location (owned cells, basis values, dof rows) each solver keeps: the
#: growth criterion samples the same points around a tip at every check until it moves
LOCATION_CACHE = 64


def _locate(solver, sets):
    """Locate the point sets ``sets`` (each (m_i, 2)) together: one bounding-box query and one
    reduction of the counts for all (collective); returns each set's (points, their owned
    cells' dof rows, basis values, the number of owned cells that contain each point over all
    ranks, and the owned cells themselves), this rank's part of all but the fourth."""
    X = np.concatenate(sets) if sets else np.zeros((0, 2))
    nloc = compat.num_cells_local(solver.mesh)
    g = solver.geometry
    # the owned cells whose bounding box meets a set's: a tree of these only (a set is often a
    # circle of samples around one crack tip; the tree of all cells costs more than the query)
    box = g.__dict__.get("_cell_boxes")
    if box is None:  # (x_lo, y_lo, x_hi, y_hi) of each owned cell, once per mesh
        v = g.vertices[:nloc]
        box = g._cell_boxes = np.vstack([np.minimum(np.minimum(v[:, 0], v[:, 1]), v[:, 2]).T,
                                         np.maximum(np.maximum(v[:, 0], v[:, 1]), v[:, 2]).T])
    sb = np.array([[*S.min(axis=0), *S.max(axis=0)] for S in sets if S.shape[0]]).reshape(-1, 4)
    near = ((box[0] <= sb[:, 2:3]) & (box[2] >= sb[:, 0:1]) & (box[1] <= sb[:, 3:4])
            & (box[3] >= sb[:, 1:2])).any(axis=0)
    pts, cells = compat.cells_containing(solver.mesh, X, np.flatnonzero(near))
    order = np.lexsort((cells, pts))  # (by point, then cell: the sums do not depend on the tree)
    pts, cells = pts[order], cells[order]
    ref = np.einsum("cij,cj->ci", g.Jinv[cells], X[pts] - g.x0[cells])
    phi = solver.ref.tabulate(ref) if cells.size else np.zeros((0, compat.cell_dofs(solver.V).shape[1]))
    cnt = np.bincount(pts, minlength=X.shape[0]).astype(float)
    solver.comm.Allreduce(MPI.IN_PLACE, cnt, op=MPI.SUM)
    rows = compat.cell_dofs(solver.V)[cells]
    out, start = [], 0
    for S in sets:
        k = (pts >= start) & (pts < start + S.shape[0])
        out.append((pts[k] - start, rows[k], phi[k], cnt[start:start + S.shape[0]], cells[k]))
        start += S.shape[0]
    return out


def _located(solver, sets):
    """:func:`_locate` of ``sets``, cached per solver (a new mesh has a new solver) and point
    set: the sets not in the cache are taken from the previous mesh's cache where
    :func:`carry_locations` allows, the rest located together (collective: every rank asks for
    the same sets, so every rank misses the same ones)."""
    cache = solver.__dict__.setdefault("_probe_locations", {})
    keys = [X.tobytes() for X in sets]
    found = [cache.get(k) for k in keys]
    miss = [i for i, f in enumerate(found) if f is None]
    if miss:
        carried = _carried(solver, [keys[i] for i in miss])
        for i, hit in zip(miss, carried):
            found[i] = hit
        miss = [i for i in miss if found[i] is None]
        for i, hit in zip(miss, _locate(solver, [sets[i] for i in miss]) if miss else ()):
            found[i] = hit
        for i, k in enumerate(keys):
            if k not in cache:
                if len(cache) >= LOCATION_CACHE:
                    cache.pop(next(iter(cache)))
                cache[k] = found[i]
    return found


def carry_locations(old, new, kept):
    """After a remesh from solver ``old`` to ``new``: keep ``old``'s located point sets for
    ``new``, to be taken (:func:`_carried`) where every owned cell that contained a point is
    kept.  ``kept`` = (new index, old index) of the new owned cells that are this rank's old
    owned cells, the same vertices in the same order (the transfer's exact copies outside a
    local remesh's patch)."""
    cache = old.__dict__.get("_probe_locations")
    if not cache:
        return
    new_of = np.full(compat.num_cells_local(old.mesh), -1, dtype=np.int64)
    new_of[kept[1]] = kept[0]
    new.__dict__["_probe_carry"] = (dict(cache), new_of)


def _carried(solver, keys):
    """The located sets of :func:`carry_locations` for ``keys`` (None where not carried;
    collective, one reduction when the previous mesh located any of them).

    A set is carried when, over all ranks, each of its (point, owned cell) pairs has its cell
    kept on the same rank.  A point that lies only in kept cells lies in no other cell of the
    new mesh (both meshes are conforming, and the cells around it are the same triangles), so
    the new mesh's location would find the same pairs: they are taken in its order (by point,
    then new cell) with the new dof rows, and the basis values are the old ones (the same
    vertices in the same order give the same reference coordinates, bit for bit)."""
    carry = solver.__dict__.get("_probe_carry")
    out = [None] * len(keys)
    if carry is None:
        return out
    old_cache, new_of = carry
    ask = [k for k, key in enumerate(keys) if key in old_cache]
    if not ask:
        return out
    mapped = [new_of[old_cache[keys[k]][4]] for k in ask]
    got = np.array([np.count_nonzero(c >= 0) for c in mapped], dtype=float)
    solver.comm.Allreduce(MPI.IN_PLACE, got, op=MPI.SUM)
    rows_of = compat.cell_dofs(solver.V)
    for k, c, n in zip(ask, mapped, got):
        pts, _, phi, cnt, _ = old_cache[keys[k]]
        if n == cnt.sum():  # (cnt: each point's cells over all ranks)
            order = np.lexsort((c, pts))
            out[k] = (pts[order], rows_of[c[order]], phi[order], cnt, c[order])
    return out


@njit(exact=True)
def _add_values(pts, rows, phi, U, out):
    """out[pts[k]] += the fields at located pair k (its basis values ``phi[k]`` on the dof rows
    ``rows[k]`` of ``U``), pair by pair in order: NumPy's ``einsum("kn,knc->kc")`` and ``bincount``
    of the pairs, operation for operation."""
    for k in range(pts.size):
        for c in range(U.shape[1]):
            v = 0.0
            for n in range(phi.shape[1]):
                v += phi[k, n] * U[rows[k, n], c]
            out[pts[k], c] += v


def field_at(solver, points) -> np.ndarray:
    """(m, 5): v and σ at ``points`` (m, 2), the same on every rank (collective)."""
    return fields_at(solver, [points])[0]


def fields_at(solver, point_sets) -> list:
    """:func:`field_at` of several point sets (each located and cached on its own, e.g. one
    per crack tip) with one reduction for all (collective)."""
    sets = [np.ascontiguousarray(X, dtype=float).reshape(-1, 2) for X in point_sets]
    sizes = [X.shape[0] for X in sets]
    U = solver.x.array_r.reshape(-1, 5)
    located = _located(solver, sets)
    out = np.zeros((sum(sizes), 5))
    start = 0
    for (pts, rows, phi, _, _), n in zip(located, sizes):
        _add_values(pts, rows, phi, U, out[start:start + n])
        start += n
    solver.comm.Allreduce(MPI.IN_PLACE, out, op=MPI.SUM)
    cnt = np.concatenate([lo[3] for lo in located]) if sets else np.zeros(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        vals = out / cnt[:, None]
    return np.split(vals, np.cumsum(sizes)[:-1]) if sets else []


def _arc_length(points, line) -> Tuple[np.ndarray, np.ndarray]:
    """Arc length along the polyline ``line`` of the foot of each point, and the distance."""
    a, b = line[:-1], line[1:]
    e = b - a
    L = np.linalg.norm(e, axis=1)
    s0 = np.r_[0.0, np.cumsum(L)[:-1]]
    u = np.clip(np.einsum("pkj,kj->pk", points[:, None, :] - a[None], e) / np.maximum(L * L, 1e-300), 0, 1)
    foot = a[None] + u[..., None] * e[None]
    d = np.linalg.norm(points[:, None, :] - foot, axis=2)
    k = np.argmin(d, axis=1)
    i = np.arange(len(points))
    return s0[k] + u[i, k] * L[k], d[i, k]


def crack_at(problem, probes: Sequence[Tuple[int, float]]) -> np.ndarray:
    """(m, 7): :data:`CRACK_FIELDS` at (crack tag, arc length [m]) positions, from the nearest
    Gauss point of that crack (collective; NaN for a tag the problem has no facets of)."""
    iface, net = problem.interface, problem.network
    lines = {c.tag: c.points for c in net.cracks} if net is not None else {}
    fields = iface.fields()
    if problem.hydraulics is not None:
        fields.update(problem.hydraulics.fields())
    pts = iface.points.reshape(-1, 2)
    tags = np.repeat(iface.crack_tag, iface.nq)
    best = np.full(len(probes), np.inf)
    vals = np.full((len(probes), len(CRACK_FIELDS)), np.nan)
    for j, (tag, s) in enumerate(probes):
        if tag not in lines:
            raise ValueError(f"crack probe: no crack with tag {tag}; the cracks are {sorted(lines)}")
        on = np.flatnonzero(tags == tag)
        if not on.size:
            continue
        arc, _ = _arc_length(pts[on], lines[tag])
        k = np.argmin(np.abs(arc - s))
        best[j] = abs(arc[k] - s)
        vals[j] = [np.asarray(fields[f]).reshape(-1)[on[k]] if f in fields else np.nan for f in CRACK_FIELDS]
    comm = problem.comm
    allbest = np.array(comm.allgather(best))  # (ranks, m)
    owner = np.argmin(allbest, axis=0)
    mine = np.where(owner == comm.rank, 1.0, 0.0)[:, None]
    out = np.where(mine > 0, np.nan_to_num(vals), 0.0)
    comm.Allreduce(MPI.IN_PLACE, out, op=MPI.SUM)
    out[~np.isfinite(allbest.min(axis=0))] = np.nan
    return out


def parse_points(text: str) -> np.ndarray:
    """``"x,y;x,y"`` -> (m, 2); raises ValueError with the expected form."""
    try:
        pts = np.array([[float(v) for v in p.split(",")] for p in text.split(";") if p.strip()])
    except ValueError:
        pts = np.zeros((0, 3))
    if pts.ndim != 2 or pts.shape[1] != 2 or not len(pts) or not np.all(np.isfinite(pts)):
        raise ValueError(f"probes must be 'x,y;x,y;...' (metres); got {text!r}")
    return pts


class ProbeWriter:
    """``probes.csv``: step, t and :data:`FIELDS` at every probe point, one row per history row."""

    def __init__(self, points, path, comm, restart_step=None):
        from .output import History
        self.points = np.asarray(points, dtype=float).reshape(-1, 2)
        self.table = History(path, comm, restart_step=restart_step)

    def write(self, problem):
        f = field_at(problem.solver, self.points)
        row: Dict[str, float] = {"step": problem.solver.step_count, "t": problem.t}
        for i in range(len(self.points)):
            for k, name in enumerate(FIELDS):
                row[f"p{i}_{name}"] = float(f[i, k])
        self.table.write(row)

    def close(self):
        self.table.close()
