"""Local remeshing: a new mesh that is the old one outside a patch around the changed crack
tips, and a fresh Gmsh mesh of the patch with its boundary fixed (docs/benchmarks.md,
"Remeshing: local patches").

A full mesh is Gmsh's, as arrays on rank 0 (:class:`MeshArrays`, :func:`capture`,
:func:`distribute`).  A local remesh (:func:`patch_local`) works on the distributed mesh:
each rank sends rank 0 only its cells near the new crack segments (the region), rank 0 takes
the triangles whose centroid lies within ``radius`` of an end of a new segment (and the
too-coarse ones next to them), keeps the boundary of their union as it is (its nodes and
edges are not moved, so the triangles outside are the old ones, node for node), meshes the
union again with the new segments embedded and the same size law as the full mesh
(:class:`SizeLaw`, :func:`_patch`), and each rank then drops its cells in the patch and takes
the new ones nearest to them (:class:`LocalArrays`: no rank holds the whole mesh).  Where a
patch cannot be made, it says why and the caller meshes the whole domain: a patch boundary
that touches itself at a vertex, a new segment outside the patch, or Gmsh failing on the
patch.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, Optional, Sequence, Tuple

import numpy as np
from mpi4py import MPI

from hydrofrac import _jit  # noqa: F401  (numba's cache keyed by the sources, before the functions below)
from hydrofrac import compat

try:
    import numba
except ImportError:  # pragma: no cover
    numba = None

#: Gmsh element types
_LINE, _TRIANGLE = 1, 2


@dataclass
class MeshArrays:
    """A triangle mesh as arrays (rank 0): ``nodes`` (n, 2), ``tris`` (t, 3) node indices,
    ``lines`` facet tag -> (e, 2) node indices, and the crack polylines it was made for."""

    nodes: np.ndarray
    tris: np.ndarray
    lines: Dict[int, np.ndarray]
    polylines: Dict[int, np.ndarray] = field(default_factory=dict)


def _nearest_sq(x, y, pts):
    """Squared distance from (x, y) to the nearest of ``pts`` (m, 2); inf for none."""
    best = np.inf
    for i in range(pts.shape[0]):
        dx, dy = pts[i, 0] - x, pts[i, 1] - y
        d = dx * dx + dy * dy
        if d < best:
            best = d
    return best


def _nearest_sq_grid(x, y, pts, offs, gx, gy, c, nx, ny):
    """:func:`_nearest_sq` over ``pts`` sorted into a grid of square cells ``c`` wide from
    (gx, gy), ``nx`` by ``ny`` (cell iy nx + ix holds the rows ``offs[k]:offs[k + 1]``, whole
    numbers stored as floats, as the callback's data holds them): the
    cells in rings outward from the query's, until no cell left can hold a nearer point.  The
    minimum is taken over a subset that holds the nearest point, by the same arithmetic: the
    brute-force pass's value, bit for bit (a patch's ~1000 queries over ~1200 samples took
    2.3 ms that way)."""
    if pts.shape[0] == 0:
        return np.inf
    qx = math.floor((x - gx) / c)
    qy = math.floor((y - gy) / c)
    r0 = max(0, -qx, qx - (nx - 1), -qy, qy - (ny - 1))  # the first ring that meets the grid
    r1 = max(qx, nx - 1 - qx, qy, ny - 1 - qy)  # the ring that covers all of it
    best = np.inf
    for r in range(r0, r1 + 1):
        # a point r cells away (Chebyshev) is more than (r - 1) c away; a hair less for round-off
        reach = max(r - 1, 0) * c * (1.0 - 1e-6)
        if reach * reach > best:
            break
        for iy in range(max(qy - r, 0), min(qy + r, ny - 1) + 1):
            if iy == qy - r or iy == qy + r:  # the ring's top and bottom rows: every cell
                cols = range(max(qx - r, 0), min(qx + r, nx - 1) + 1)
            else:  # the rows between: the ring's two columns
                cols = range(qx - r, qx + r + 1, 2 * r)
            for ix in cols:
                if 0 <= ix < nx:
                    k = iy * nx + ix
                    for i in range(int(offs[k]), int(offs[k + 1])):
                        dx, dy = pts[i, 0] - x, pts[i, 1] - y
                        d = dx * dx + dy * dy
                        if d < best:
                            best = d
    return best


def _size_at(x, y, pts, offs, grid, tips, wellbore_radius, h_crack, h_far, span, h_tip, tip_radius, grading):
    """:class:`SizeLaw`'s ``sizes`` at one point (the nearest crack sample through the grid
    ``grid`` = (gx, gy, c, nx, ny) of :func:`_nearest_sq_grid`, the nearest tip by brute force:
    the same distances as the trees', sqrt of the smallest squared distance)."""
    d = math.sqrt(_nearest_sq_grid(x, y, pts, offs, grid[0], grid[1], grid[2], int(grid[3]), int(grid[4])))
    if wellbore_radius > 0:
        d = min(d, abs(math.hypot(x, y) - wellbore_radius))
    h = h_crack + (h_far - h_crack) * min(max((d - h_crack) / span, 0.0), 1.0) if d < math.inf else h_far
    if tips.shape[0]:
        dt = math.sqrt(_nearest_sq(x, y, tips))
        h = min(h, h_tip + (h_far - h_tip) * min(max((dt - tip_radius) / grading, 0.0), 1.0))
    return h


def _grid(pts, c):
    """(pts sorted by cell, offsets, (gx, gy, c, nx, ny)) of :func:`_nearest_sq_grid`: cells
    ``c`` wide over the points' box, or wider where the box would hold more than about 4 cells
    per point."""
    if not len(pts):
        return pts, np.zeros(2), np.array([0.0, 0.0, 1.0, 1.0, 1.0])
    g0 = pts.min(axis=0)
    span = pts.max(axis=0) - g0
    c = max(c, math.sqrt(float(span[0] * span[1]) / (4.0 * len(pts))))
    nx, ny = (np.floor(span / c).astype(np.int64) + 1).tolist()
    ix = np.minimum(np.floor((pts[:, 0] - g0[0]) / c).astype(np.int64), nx - 1)
    iy = np.minimum(np.floor((pts[:, 1] - g0[1]) / c).astype(np.int64), ny - 1)
    k = iy * nx + ix
    order = np.argsort(k, kind="stable")
    offs = np.r_[0, np.cumsum(np.bincount(k, minlength=nx * ny))].astype(float)
    return np.ascontiguousarray(pts[order]), offs, np.array([g0[0], g0[1], c, nx, ny], dtype=float)


#: the length of :func:`_size_callback`'s data header: the counts of crack samples, tips and
#: grid offsets, the law's 7 numbers and the grid's 5
_HEADER = 15


if numba is not None:  # (no fast-math: the distances round as the tree's do)
    _nearest_sq = numba.njit(cache=True)(_nearest_sq)
    _nearest_sq_grid = numba.njit(cache=True)(_nearest_sq_grid)
    _size_at = numba.njit(cache=True)(_size_at)

    @numba.cfunc(numba.types.float64(numba.types.int32, numba.types.int32, numba.types.float64, numba.types.float64,
                                     numba.types.float64, numba.types.CPointer(numba.types.float64)), cache=True)
    def _size_callback(dim, tag, x, y, z, data):
        """:func:`_size_at` as Gmsh's compiled size callback (:func:`hydrofrac.compat.gmsh_compiled_size_callback`):
        ``data`` is ``SizeLaw.sampler(...).scalar_near(...).packed`` (the counts, the law's numbers,
        the grid's, then the crack samples, the tips and the grid's offsets)."""
        head = numba.carray(data, _HEADER)
        nps, nts, nof = int(head[0]), int(head[1]), int(head[2])
        buf = numba.carray(data, _HEADER + 2 * (nps + nts) + nof)
        ps = buf[_HEADER:_HEADER + 2 * nps].reshape((nps, 2))
        ts = buf[_HEADER + 2 * nps:_HEADER + 2 * (nps + nts)].reshape((nts, 2))
        offs = buf[_HEADER + 2 * (nps + nts):]
        return _size_at(x, y, ps, offs, head[10:15], ts, head[3], head[4], head[5], head[6], head[7], head[8],
                        head[9])
else:  # pragma: no cover
    _size_callback = None


def _samples(polylines: Dict[int, np.ndarray], step: float) -> np.ndarray:
    """Points along every segment of ``polylines``, at most ``step`` apart: each segment's two
    ends and ceil(length / step) - 1 points evenly between them, in one vectorised pass (the
    values of ``np.linspace(0, 1, n + 1)`` per segment, bit for bit)."""
    segs = [np.asarray(line, dtype=float) for line in polylines.values() if len(line) > 1]
    if not segs:
        return np.zeros((0, 2))
    a = np.concatenate([s[:-1] for s in segs])
    d = np.concatenate([s[1:] for s in segs]) - a
    n = np.maximum(np.ceil(np.sqrt((d * d).sum(axis=1)) / step).astype(np.int64), 1)
    seg = np.repeat(np.arange(n.size), n + 1)
    j = np.arange(seg.size) - np.repeat(np.cumsum(n + 1) - (n + 1), n + 1)
    t = j * (1.0 / n[seg])
    t[j == n[seg]] = 1.0  # (linspace's last point is its end exactly)
    return a[seg] + t[:, None] * d[seg]


@dataclass(frozen=True)
class SizeLaw:
    """The target size of the full mesh (meshes/fractures.py's Gmsh fields, evaluated here):
    ``h_crack`` within ``h_crack`` of a crack or the wellbore wall, growing linearly to
    ``h_far`` at ``grading``; with ``h_tip``, also ``h_tip`` within ``tip_radius`` of a tip,
    growing to ``h_far`` over ``grading``."""

    h_crack: float
    h_far: float
    grading: float
    wellbore_radius: float = 0.0
    h_tip: Optional[float] = None
    tip_radius: float = 0.0

    @property
    def smallest(self) -> float:
        """The smallest size the law gives anywhere: h_crack, or h_tip if smaller."""
        return min(self.h_crack, self.h_far, self.h_crack if self.h_tip is None else self.h_tip)

    def sampler(self, polylines: Dict[int, np.ndarray], tips: Sequence[Tuple[float, float]] = ()):
        """sizes(points (m, 2)) for the given crack lines (a tree of points sampled along them)."""
        from scipy.spatial import cKDTree
        pts = _samples(polylines, self.h_crack / 8)
        tree = cKDTree(pts) if pts.size else None
        tip_tree = cKDTree(np.asarray(tips, dtype=float)) if len(tips) and self.h_tip is not None else None

        span = max(self.grading - self.h_crack, 1e-300)

        def sizes(xy):
            """Target sizes at points (m, 2)."""
            xy = np.atleast_2d(np.asarray(xy, dtype=float))
            d = tree.query(xy)[0] if tree is not None else np.full(len(xy), np.inf)
            if self.wellbore_radius > 0:
                d = np.minimum(d, np.abs(np.hypot(xy[:, 0], xy[:, 1]) - self.wellbore_radius))
            h = np.where(np.isfinite(d), self.h_crack + (self.h_far - self.h_crack)
                         * np.clip((d - self.h_crack) / span, 0.0, 1.0), self.h_far)
            if tip_tree is not None:
                dt = tip_tree.query(xy)[0]
                h = np.minimum(h, self.h_tip + (self.h_far - self.h_tip)
                               * np.clip((dt - self.tip_radius) / self.grading, 0.0, 1.0))
            return h

        tip_pts = np.asarray(tips, dtype=float).reshape(-1, 2) if tip_tree is not None else np.zeros((0, 2))
        law = (float(self.wellbore_radius), float(self.h_crack), float(self.h_far), float(span),
               float(self.h_tip or 0.0), float(self.tip_radius), float(self.grading))

        def scalar_near(lo, hi):
            """The law at one point (x, y) in the box lo..hi, compiled (a tree query costs 20 us a
            call): with the samples that can be nearest there, those within the grading's reach
            (farther ones give h_far, as no sample does)."""
            def near(p, reach):
                keep = np.all((p >= np.asarray(lo) - reach) & (p <= np.asarray(hi) + reach), axis=1)
                return np.ascontiguousarray(p[keep])
            ps, ts = near(pts, span + self.h_crack), near(tip_pts, self.tip_radius + self.grading)
            ps, offs, grid = _grid(ps, 0.5 * self.h_crack)  # (about 4 samples a cell along a crack)
            f = lambda x, y: _size_at(x, y, ps, offs, grid, ts, *law)  # noqa: E731
            # the same as one array, for the compiled callback (_size_callback)
            f.packed = np.concatenate([[ps.shape[0], ts.shape[0], offs.size], law, grid, ps.reshape(-1),
                                       ts.reshape(-1), offs])
            return f

        sizes.scalar_near = scalar_near
        return sizes


def capture(gmsh, polylines) -> MeshArrays:
    """The current Gmsh model's mesh as :class:`MeshArrays` (its physical groups: triangles of
    dimension 2, tagged lines of dimension 1)."""
    model = gmsh.model
    tags, coords, _ = model.mesh.getNodes()
    order = np.argsort(tags)
    stags = tags[order]
    nodes = coords.reshape(-1, 3)[order, :2].copy()

    def index(node_tags):
        return np.searchsorted(stags, node_tags).astype(np.int64)

    tris, lines = [], {}
    for dim, ptag in model.getPhysicalGroups():
        for ent in model.getEntitiesForPhysicalGroup(dim, ptag):
            types, _, ntags = model.mesh.getElements(dim, ent)
            for t, nt in zip(types, ntags):
                if dim == 2 and t == _TRIANGLE:
                    tris.append(index(nt).reshape(-1, 3))
                elif dim == 1 and t == _LINE:
                    lines.setdefault(int(ptag), []).append(index(nt).reshape(-1, 2))
    return MeshArrays(nodes, np.concatenate(tris), {k: np.concatenate(v) for k, v in lines.items()},
                      {int(k): np.asarray(v, dtype=float) for k, v in polylines.items()})


@dataclass
class LocalArrays:
    """This rank's part of a mesh as the inputs it is made from
    (:func:`hydrofrac.compat.mesh_from_local_arrays`, every cell staying on the rank that holds
    it): ``x`` (n, 2) this rank's block of nodes (global index: the row plus the rows of the
    ranks before), ``cells`` (c, 3) global node indices of the cells it owns, ``facets`` (k, 2)
    global node pairs tagged ``values`` (k,), and the crack polylines (the same on every rank).
    ``owners`` (c,): the rank each cell goes to, where a local remesh spreads the cells evenly
    again (:func:`balanced_owners`); None: every cell stays on this rank.  A local remesh makes
    the next one from the mesh (:func:`patch_local`); no rank holds the whole mesh."""

    x: np.ndarray
    cells: np.ndarray
    facets: np.ndarray
    values: np.ndarray
    polylines: Dict[int, np.ndarray] = field(default_factory=dict)
    owners: Optional[np.ndarray] = None


def build(comm, arrays, cell_tag: int):
    """(mesh, cell_tags, facet_tags) of the arrays a mesh was made from: :class:`LocalArrays`
    on every rank, or :class:`MeshArrays` on rank 0 (None elsewhere, :func:`distribute`)."""
    if isinstance(arrays, LocalArrays):
        return compat.mesh_from_local_arrays(comm, arrays.x, arrays.cells, cell_tag, arrays.facets, arrays.values,
                                             owners=arrays.owners)
    return distribute(comm, arrays, cell_tag)


def gathered(comm, arrays) -> Optional[MeshArrays]:
    """The whole mesh as :class:`MeshArrays` on rank 0 (None elsewhere), from either kind of
    arrays: for checks and tests only (a run never gathers a :class:`LocalArrays` mesh)."""
    if not isinstance(arrays, LocalArrays):
        return arrays
    parts = comm.gather((arrays.x, arrays.cells, arrays.facets, arrays.values), root=0)
    if comm.rank != 0:
        return None
    values = np.concatenate([p[3] for p in parts])
    facets = np.concatenate([p[2] for p in parts]).reshape(-1, 2)
    lines = {int(t): np.unique(np.sort(facets[values == t], axis=1), axis=0) for t in np.unique(values)}
    return MeshArrays(np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]), lines,
                      dict(arrays.polylines))


def arrays_state(arrays):
    """JSON-able state of this rank's arrays (a checkpoint's, :func:`arrays_from_state`)."""
    if arrays is None:
        return None
    poly = {str(k): np.asarray(v).tolist() for k, v in arrays.polylines.items()}
    if isinstance(arrays, LocalArrays):
        return {"layout": "local", "x": arrays.x.tolist(), "cells": arrays.cells.tolist(),
                "facets": arrays.facets.tolist(), "values": arrays.values.tolist(), "polylines": poly,
                "owners": None if arrays.owners is None else arrays.owners.tolist()}
    return {"layout": "root", "nodes": arrays.nodes.tolist(), "tris": arrays.tris.tolist(),
            "lines": {str(k): v.tolist() for k, v in arrays.lines.items()}, "polylines": poly}


def arrays_from_state(a):
    """The arrays of :func:`arrays_state`."""
    if a is None:
        return None
    poly = {int(k): np.asarray(v, float) for k, v in a["polylines"].items()}
    if a.get("layout") == "local":
        owners = a.get("owners")
        return LocalArrays(np.asarray(a["x"], float).reshape(-1, 2), np.asarray(a["cells"], np.int64).reshape(-1, 3),
                           np.asarray(a["facets"], np.int64).reshape(-1, 2), np.asarray(a["values"], np.int32), poly,
                           None if owners is None else np.asarray(owners, np.int32))
    return MeshArrays(np.asarray(a["nodes"], float), np.asarray(a["tris"], np.int64),
                      {int(k): np.asarray(v, np.int64).reshape(-1, 2) for k, v in a["lines"].items()}, poly)


def distribute(comm, arrays: MeshArrays, cell_tag: int):
    """(mesh, cell_tags, facet_tags) of ``arrays`` (held on rank 0, None elsewhere), distributed
    over ``comm``: every triangle tagged ``cell_tag``, each line's edges their tag."""
    if comm.rank == 0:
        items = sorted(arrays.lines.items())
        facets = np.concatenate([e for _, e in items]) if items else np.zeros((0, 2), np.int64)
        values = np.concatenate([np.full(len(e), t, np.int32) for t, e in items]) if items else np.zeros(0, np.int32)
        return compat.mesh_from_arrays(comm, arrays.nodes, arrays.tris, cell_tag, facets, values)
    return compat.mesh_from_arrays(comm, None, None, cell_tag, None, None)


def _segments(polylines):
    """{(tag, a, b)}: each polyline's segments, their ends rounded to 12 digits (each line rounded
    in one pass: the whole network's segments at every remesh)."""
    out = set()
    for tag, line in polylines.items():
        pts = [tuple(p) for p in np.round(np.asarray(line, dtype=float), 12).tolist()]
        out.update((tag, a, b) for a, b in zip(pts[:-1], pts[1:]))
    return out


def new_segments(old: Dict[int, np.ndarray], new: Dict[int, np.ndarray]):
    """The segments (tag, a, b) of the ``new`` polylines that are not segments of the ``old``
    ones, and whether an old segment is gone (then the patch cannot follow the change)."""
    o, n = _segments(old), _segments(new)
    added = sorted(n - o)
    return [(t, np.array(a), np.array(b)) for t, a, b in added], bool(o - n)


def _edges(tris):
    """The three edges (0-1, 1-2, 2-0) of every triangle of ``tris`` (m, 3), edge by edge:
    (3 m, 2), the m first edges first."""
    return np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])


def _edge_key(e):
    e = np.sort(e, axis=1)
    return e[:, 0] * (1 << 31) + e[:, 1]


def _loops(bedges):
    """Closed loops of boundary edges (each vertex on exactly two); None if a vertex is on more."""
    from collections import defaultdict
    nbr = defaultdict(list)
    for a, b in bedges:
        nbr[a].append(b)
        nbr[b].append(a)
    if any(len(v) != 2 for v in nbr.values()):
        return None
    seen, loops = set(), []
    for start in nbr:
        if start in seen:
            continue
        loop, prev, cur = [start], None, start
        seen.add(start)
        for _ in range(len(bedges) + 1):  # a loop has at most every boundary edge once
            a, b = nbr[cur]
            nxt = a if a != prev else b
            if nxt == start:
                break
            loop.append(nxt)
            seen.add(nxt)
            prev, cur = cur, nxt
        else:
            return None
        loops.append(loop)
    return loops


def _straight_pieces(edges, nodes, tol=1e-9):
    """(tag, (start, end)) straight pieces covering the crack ``edges`` [(tag, (a, b))]: each
    tag's edges are walked in chains between nodes not on exactly two of them, and a chain is
    cut where it turns (collinear nodes dropped)."""
    from collections import defaultdict
    by_tag = defaultdict(set)
    for tag, (a, b) in edges:
        if a != b:  # (an edge listed twice, or in both directions, is one edge)
            by_tag[tag].add((min(int(a), int(b)), max(int(a), int(b))))
    out = []
    for tag, es in by_tag.items():
        nbr = defaultdict(list)
        for a, b in sorted(es):  # (in index order: a set of tuples iterates in the order of their hashes)
            nbr[a].append(b)
            nbr[b].append(a)
        done = set()
        starts = [v for v, n in nbr.items() if len(n) != 2] or [next(iter(nbr))]
        for v0 in starts:
            for w in nbr[v0]:
                if (v0, w) in done:
                    continue
                chain, prev, cur = [v0], v0, w
                done.update({(v0, w), (w, v0)})
                for _ in range(len(es) + 1):  # a chain has at most every edge once
                    chain.append(cur)
                    if len(nbr[cur]) != 2 or cur == v0:
                        break
                    nxt = nbr[cur][0] if nbr[cur][0] != prev else nbr[cur][1]
                    done.update({(cur, nxt), (nxt, cur)})
                    prev, cur = cur, nxt
                else:
                    return None
                keep = [chain[0]]
                for i in range(1, len(chain) - 1):
                    a, b, c = nodes[keep[-1]], nodes[chain[i]], nodes[chain[i + 1]]
                    u, v = b - a, c - b
                    if abs(u[0] * v[1] - u[1] * v[0]) > tol * np.linalg.norm(u) * np.linalg.norm(v):
                        keep.append(chain[i])
                keep.append(chain[-1])
                out += [(tag, (p, q)) for p, q in zip(keep[:-1], keep[1:])]
    return out


def _area(xy):
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _in_polygon(points, poly):
    """Whether each point (m, 2) lies inside the closed polygon ``poly`` (k, 2) (even-odd
    rule; the points here are triangle centroids, never on a polygon's edge, which is made of
    triangle edges)."""
    m, k = points.shape[0], poly.shape[0]
    out = np.zeros(m, dtype=np.bool_)
    for i in range(m):
        x, y = points[i, 0], points[i, 1]
        c = False
        for j in range(k):
            ax, ay = poly[j - 1, 0], poly[j - 1, 1]
            bx, by = poly[j, 0], poly[j, 1]
            if (ay > y) != (by > y) and x < ax + (y - ay) * (bx - ax) / (by - ay):
                c = not c
        out[i] = c
    return out


if numba is not None:
    _in_polygon = numba.njit(cache=True)(_in_polygon)


def _inside(points, nodes, tris):
    """Whether each point lies in one of the triangles (closed)."""
    a, b, c = nodes[tris[:, 0]], nodes[tris[:, 1]], nodes[tris[:, 2]]
    out = np.zeros(len(points), dtype=bool)
    for i, p in enumerate(points):
        d = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
        l1 = ((b - p)[:, 0] * (c - p)[:, 1] - (b - p)[:, 1] * (c - p)[:, 0]) / d
        l2 = ((c - p)[:, 0] * (a - p)[:, 1] - (c - p)[:, 1] * (a - p)[:, 0]) / d
        out[i] = bool(np.any((l1 >= -1e-9) & (l2 >= -1e-9) & (1 - l1 - l2 >= -1e-9)))
    return out


#: a patch keeps every cell outside it, so a smallest cell it makes (its inradius sets the
#: explicit time step) stays for the rest of the run: a patch whose smallest cell is more than
#: this fraction below the old mesh's is checked against a full remesh of the same geometry,
#: and the full mesh is taken if its smallest cell is this fraction larger than the patch's
#: (docs/benchmarks.md, "A patch may not shorten the time step")
CELL_FLOOR_TOLERANCE = 0.02

#: a patch that cannot be made, or makes a cell smaller than the old mesh's smallest, is made
#: again with this many times the radius before a full remesh decides (meshes/fractures.py,
#: ``fracture_mesh``)
PATCH_RETRY_RADIUS = 2.0


def smallest_inradius(nodes, tris):
    """The smallest inradius [m] of the triangles ``tris`` (t, 3) of ``nodes`` (n, 2): the
    h of the solver's CFL bound (:func:`hydrofrac.element.inradius`)."""
    from hydrofrac.element import inradius
    return float(inradius(nodes[tris]).min()) if len(tris) else math.inf


def _patch(gmsh, old: MeshArrays, polylines: Dict[int, np.ndarray], added, radius: float, size: SizeLaw,
           tips=(), crack_tags=None, scale=None):
    """The patch of ``old`` (a whole mesh, or the part of one around the new segments
    ``added``): (near, nodes, new_t, lines, None) or (None, ..., why not).  ``near``: the old
    triangles replaced; ``nodes``: the old nodes, then the patch's new ones; ``new_t``: the
    patch's triangles in those; ``lines``: tag -> edges of every tagged line after the patch
    (the old ones but the crack edges inside the patch, then the patch's).  ``scale``: the
    domain's size (nodes closer than 1e-12 of it are one)."""
    none = (None, None, None, None)
    ends = np.array([p for _, a, b in added for p in (a, b)])
    cent = old.nodes[old.tris].mean(axis=1)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree
    dist = cKDTree(ends).query(cent)[0]
    e = _edges(old.tris)
    keys = _edge_key(e)
    nt = old.tris.shape[0]
    tri_of = np.tile(np.arange(nt), 3)
    # the patch: the triangles within radius of a new segment's end, and, connected to them
    # through edges, those within the size law's grading that are too coarse for the new
    # cracks (longest edge above 1.5 times the new target): the size changes there
    fn = size.sampler(polylines, tips)
    edge_len = np.linalg.norm(old.nodes[e[:, 0]] - old.nodes[e[:, 1]], axis=1).reshape(3, nt).max(axis=0)
    core = dist < radius
    cand = core.copy()
    # (a cell no longer than 1.5 times the smallest size the law gives is never too coarse)
    reach = np.flatnonzero(~core & (dist < size.grading) & (edge_len > 1.5 * size.smallest))
    if reach.size:
        target = fn(cent[reach])
        cand[reach] = edge_len[reach] > 1.5 * target
    order = np.argsort(keys, kind="stable")
    ks = keys[order]
    pair = np.flatnonzero(ks[1:] == ks[:-1])  # interior edges: the two triangles sharing one
    ta, tb = tri_of[order[pair]], tri_of[order[pair + 1]]
    both = cand[ta] & cand[tb]
    G = coo_matrix((np.ones(both.sum()), (ta[both], tb[both])), shape=(nt, nt))
    _, comp = connected_components(G, directed=False)
    near = cand & np.isin(comp, np.unique(comp[core]))
    ptris = old.tris[near]
    # the new segments must lie in the patch (ends and midpoints)
    probe = np.concatenate([ends, np.array([0.5 * (a + b) for _, a, b in added])])
    if not np.all(_inside(probe, old.nodes, ptris)):
        return (*none, "a new crack segment leaves the patch")
    for _ in range(4):  # the triangles at a vertex where the boundary touches itself, and islands
        # of old triangles inside the patch, join it (a patch with no pinch and no hole)
        pe = _edges(ptris)
        uk, first, counts = np.unique(_edge_key(pe), return_index=True, return_counts=True)
        bedges = pe[first[counts == 1]]
        loops = _loops(bedges)
        if loops is None:
            deg = np.bincount(bedges.reshape(-1), minlength=old.nodes.shape[0])
            near |= np.isin(old.tris, np.flatnonzero(deg > 2)).any(axis=1)
            ptris = old.tris[near]
            continue
        if len(loops) == 1:
            break
        areas = [abs(_area(old.nodes[lp])) for lp in loops]
        outer = int(np.argmax(areas))
        inside = np.zeros(nt, dtype=bool)
        for k, lp in enumerate(loops):
            if k != outer:
                inside |= _in_polygon(cent, np.ascontiguousarray(old.nodes[lp]))
        if not (inside & ~near).any():
            break  # several pieces, no island
        near |= inside
        ptris = old.tris[near]
    pe = _edges(ptris)
    uk, first, counts = np.unique(_edge_key(pe), return_index=True, return_counts=True)
    loops = _loops(pe[first[counts == 1]])
    if loops is None:
        return (*none, "the patch boundary touches itself at a vertex")
    # each connected piece of the patch is one surface: its outer loop and its holes
    # (the pieces again: an island filled in joins the piece around it)
    sel = np.flatnonzero(near)
    pos = np.full(nt, -1)
    pos[sel] = np.arange(sel.size)
    inner = near[ta] & near[tb]
    _, pcomp = connected_components(coo_matrix((np.ones(inner.sum()), (pos[ta[inner]], pos[tb[inner]])),
                                               shape=(sel.size, sel.size)), directed=False)
    # (a node of a loop is in one piece only: pieces that touched at a vertex failed _loops)
    piece_of_node = np.full(old.nodes.shape[0], -1, dtype=np.int64)
    piece_of_node[ptris] = pcomp[:, None]
    interior_keys = uk[counts == 2]
    crack_tags = set(old.lines) if crack_tags is None else set(crack_tags)
    inner_cracks = []  # (tag, (2,) node indices) old crack edges inside the patch
    kept_lines = {}
    for tag, edges in old.lines.items():
        inside = np.isin(_edge_key(edges), interior_keys) if tag in crack_tags else np.zeros(len(edges), bool)
        kept_lines[tag] = edges[~inside]
        inner_cracks += [(tag, ed) for ed in edges[inside]]

    model = gmsh.model
    model.add("patch")
    # the loops come from a conforming mesh's boundary: OpenCASCADE's fixing of wire and face
    # orientation changed none of the demo's and the re-fracture's patches, and took 60 % of
    # addPlaneSurface (docs/benchmarks.md, "Cheaper remeshes with the same results"); a face it
    # would have fixed fails the checks below, and the caller remeshes
    gmsh.option.setNumber("Geometry.OCCAutoFix", 0)
    occ = model.occ
    point_of = {}

    def pt(i):
        if i not in point_of:
            x, y = old.nodes[i]
            point_of[i] = occ.addPoint(float(x), float(y), 0.0)
        return point_of[i]

    # a hole's loop turns the way its piece's outer loop does: the walk of _loops along the
    # triangles' edges gives either way, and with the two opposed Gmsh builds a face that
    # OpenCASCADE's fragment does not cut with the crack lines (docs/benchmarks.md, "A patch
    # with a hole"); the outer loops stay as walked, so a patch without a hole is unchanged
    signed = [_area(old.nodes[loop]) for loop in loops]
    piece = [int(piece_of_node[loop[0]]) for loop in loops]
    outer_sign = {}
    for k in sorted(range(len(loops)), key=lambda k: abs(signed[k])):
        outer_sign[piece[k]] = signed[k] > 0  # (the largest loop of each piece comes last)
    pieces = {}
    for k, loop in enumerate(loops):
        if (signed[k] > 0) != outer_sign[piece[k]]:
            loop = loop[::-1]
        ids = [occ.addLine(pt(a), pt(b)) for a, b in zip(loop, loop[1:] + loop[:1])]
        pieces.setdefault(piece[k], []).append((abs(signed[k]), occ.addCurveLoop(ids)))
    surfs = []
    for loops_of_piece in pieces.values():
        loops_of_piece.sort(key=lambda al: -al[0])  # the outer loop first, then the holes
        surfs.append((2, occ.addPlaneSurface([lid for _, lid in loops_of_piece])))
    # the old crack edges inside the patch, as straight pieces between their chains' ends and
    # corners (Gmsh meshes them again, so a new segment that ends on one makes no sliver edge),
    # and the new segments
    pieces_of_cracks = _straight_pieces(inner_cracks, old.nodes)
    if pieces_of_cracks is None:
        model.remove()
        return (*none, "a crack inside the patch is not a chain of edges")
    lines = ([(1, occ.addLine(pt(p), pt(q))) for _, (p, q) in pieces_of_cracks]
             + [(1, occ.addLine(occ.addPoint(*a, 0.0), occ.addPoint(*b, 0.0))) for _, a, b in added])
    owner = [tag for tag, _ in pieces_of_cracks] + [tag for tag, _, _ in added]
    out_map = occ.fragment(surfs, lines)[1]
    occ.synchronize()
    crack_curves = {}
    for tag, bits in zip(owner, out_map[len(surfs):]):
        crack_curves.setdefault(tag, set()).update(c for d, c in bits if d == 1)
    all_crack = set().union(*crack_curves.values()) if crack_curves else set()
    surfaces = model.getEntities(2)
    model.addPhysicalGroup(2, [s for _, s in surfaces], 1)
    for tag, cs in crack_curves.items():
        model.addPhysicalGroup(1, sorted(cs), tag)
    # the patch boundary keeps its nodes: one element per boundary curve
    for _, c in model.getBoundary(surfaces, combined=True, oriented=False):
        if abs(c) not in all_crack:
            model.mesh.setTransfiniteCurve(abs(c), 2)
    # (Gmsh 4.8 passes (dim, tag, x, y, z), later versions also the size it would take)
    box = model.getBoundingBox(-1, -1)
    scalar = fn.scalar_near(box[:2], box[3:5])
    # compiled: Gmsh asks for ~1400 sizes a patch, 7 us each through Python
    if _size_callback is None or not compat.gmsh_compiled_size_callback(gmsh, _size_callback.address, scalar.packed):
        model.mesh.setSizeCallback(lambda dim, tag, x, y, z, *lc: scalar(x, y))
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.Algorithm", 6)
    try:
        model.mesh.generate(2)
        patch = capture(gmsh, {})
    except Exception as err:  # noqa: BLE001 - the caller meshes the whole domain instead
        return (*none, f"Gmsh failed on the patch: {err}")
    finally:
        if hasattr(model.mesh, "removeSizeCallback"):
            model.mesh.removeSizeCallback()
        model.remove()
    lost = sorted(set(owner) - {t for t, e in patch.lines.items() if len(e)})
    if lost:
        return (*none, f"crack(s) {lost} have no facet in the patch mesh")
    # every crack facet of the patch must be an edge of its triangles (embedded in the surface)
    pk = _edge_key(_edges(patch.tris))
    if any(not np.isin(_edge_key(e), pk).all() for e in patch.lines.values()):
        return (*none, "a crack is not embedded in the patch mesh")

    # merge: the old nodes keep their indices; patch nodes at an old node's place are that node
    pnodes = np.unique(ptris)
    tree = cKDTree(old.nodes[pnodes])
    d, j = tree.query(patch.nodes)
    scale = float(np.ptp(old.nodes, axis=0).max()) if scale is None else scale
    same = d <= 1e-12 * scale
    fresh = np.flatnonzero(~same)
    index = np.empty(patch.nodes.shape[0], dtype=np.int64)
    index[same] = pnodes[j[same]]
    index[fresh] = old.nodes.shape[0] + np.arange(fresh.size)
    nodes = np.concatenate([old.nodes, patch.nodes[fresh]])
    # the patch must meet the kept mesh edge for edge: its boundary is the old patch boundary
    new_t = index[patch.tris]
    ne = _edges(new_t)
    nk, nc = np.unique(_edge_key(ne), return_counts=True)
    if not np.array_equal(np.sort(nk[nc == 1]), np.sort(uk[counts == 1])):
        return (*none, "the patch mesh does not meet the kept mesh edge for edge")
    for tag, edges in patch.lines.items():
        kept_lines[tag] = np.concatenate([kept_lines.get(tag, np.zeros((0, 2), np.int64)), index[edges]])
    # (an edge on the patch boundary may come both from the kept lines and from the patch)
    lines = {t: np.unique(np.sort(e, axis=1), axis=0) for t, e in kept_lines.items() if len(e)}
    return near, nodes, new_t, lines, None


def _inradii(xy):
    from hydrofrac.element import inradius
    return inradius(xy) if len(xy) else np.zeros(0)


def patch_local(comm, gmsh, mesh, facet_tags, added, polylines, radius: float, size: SizeLaw, tips=(),
                crack_tags=None, scale=None):
    """A local remesh of the distributed ``mesh`` for the new crack lines ``polylines``, whose
    segments ``added`` (:func:`new_segments`, at least one) the mesh lacks, on every rank:
    (:class:`LocalArrays`, patch triangles, why not, stats).

    Each rank sends rank 0 only its cells that the patch can take, and a margin (the region,
    :func:`_region`), and its tagged facets there.  Rank 0 meshes the
    patch of that region (:func:`_patch`, with Gmsh; ``gmsh`` is None on the other ranks) and
    sends each rank the old cells it drops and the patch cells it takes (those nearest to its
    dropped cells).  Every rank keeps its other cells, nodes and facets as they are; the new
    nodes join the last rank's block.  ``stats``: the cells rank 0 received, and the smallest
    inradius of the new and of the old mesh (for the time-step check)."""
    polylines = {int(k): np.asarray(v, dtype=float) for k, v in polylines.items()}
    x, cells, cxy, facets, values = compat.mesh_inputs(mesh, facet_tags)
    r_old = _inradii(cxy)
    old_min = comm.allreduce(float(r_old.min()) if r_old.size else math.inf, op=MPI.MIN)
    sel, fsel = _region(comm, cells, cxy, facets, added, polylines, radius, size, tips)
    n_nodes = comm.allreduce(x.shape[0])
    parts = comm.gather((cells[sel], cxy[sel], sel, facets[fsel], values[fsel]), root=0)
    plan = None
    if comm.rank == 0:
        plan = _plan_patch(gmsh, parts, comm.size, n_nodes, polylines, added, radius, size, tips,
                           crack_tags, scale)
    why, region, drop, patch_min, n_patch, unused = comm.bcast(None if plan is None else plan["common"], root=0)
    if why is not None:
        return None, 0, why, {"region_cells": region}
    mine = comm.scatter(None if plan is None else plan["per_rank"], root=0)
    dropped_cells, new_cells, new_centroids, fresh = mine
    keep = np.ones(len(cells), dtype=bool)
    keep[dropped_cells] = False
    kept_min = float(r_old[keep].min()) if keep.any() else math.inf
    new_min = min(comm.allreduce(kept_min, op=MPI.MIN), patch_min)
    fkeep = ~_rows_in(np.column_stack([values, np.sort(facets, axis=1)]), np.asarray(drop, np.int64).reshape(-1, 3))
    add_f, add_v = plan["add"] if plan is not None else (np.zeros((0, 2), np.int64), np.zeros(0, np.int32))
    # the nodes no cell uses leave this rank's block, and every global index after them moves down
    start = comm.exscan(x.shape[0])
    start = start if comm.rank else 0  # (exscan leaves rank 0's undefined)
    rows = np.ones(x.shape[0], dtype=bool)
    rows[unused[(unused >= start) & (unused < start + x.shape[0])] - start] = False

    def renumber(g):
        return g - np.searchsorted(unused, g)
    local = LocalArrays(np.concatenate([x[rows], fresh]), renumber(np.concatenate([cells[keep], new_cells])),
                        renumber(np.concatenate([facets[fkeep], add_f])), np.concatenate([values[fkeep], add_v]),
                        polylines)
    # patch cells go to the ranks whose cells they replace, so the parts drift apart as cracks
    # grow on some ranks more than on others: past REBALANCE_TOLERANCE they are spread again.
    # A cell next to a crack facet weighs more: the facet's interface work.
    crack = np.isin(local.values, list(crack_tags or ()))
    edges = _edges(local.cells)
    weights = 1 + CRACK_FACET_WEIGHT * np.isin(_edge_key(edges), _edge_key(local.facets[crack])).reshape(3, -1).sum(0)
    loads = np.array(comm.allgather(int(weights.sum())))
    rebalanced = bool(loads.max() > (1 + REBALANCE_TOLERANCE) * loads.mean())
    if rebalanced:
        local.owners = balanced_owners(comm, np.concatenate([cxy[keep].mean(axis=1), new_centroids]), comm.size,
                                       weights=weights)
    return local, n_patch, None, {"region_cells": region, "inradius": new_min, "old_inradius": old_min,
                                  "rebalanced": rebalanced}


#: a local remesh after which the largest rank's part weighs more than (1 + this) times the mean
#: (cells, and :data:`CRACK_FACET_WEIGHT` per crack facet of a cell) spreads the cells over the
#: ranks again (:func:`balanced_owners`)
REBALANCE_TOLERANCE = 0.1

#: the weight of a crack facet for each of its cells in that spread, against 1 for a cell: an
#: interface Gauss point pass, state update and hydraulics per crack facet cost about 4 cells'
#: bulk work (1 rank, re-fracture --quick: 0.24 against 0.078 us per facet and cell stage)
CRACK_FACET_WEIGHT = 2


def _morton(q):
    """Z-order keys of the integer points ``q`` (m, 2), each coordinate below 2**16."""
    def spread(v):
        v = v.astype(np.uint64) & np.uint64(0xFFFF)
        for shift, mask in ((8, 0x00FF00FF), (4, 0x0F0F0F0F), (2, 0x33333333), (1, 0x55555555)):
            v = (v | (v << np.uint64(shift))) & np.uint64(mask)
        return v
    return spread(q[:, 0]) | (spread(q[:, 1]) << np.uint64(1))


def balanced_owners(comm, centroids, nparts, weights=None, bins=1 << 16):
    """The rank (of ``nparts``) of each of this rank's cells (``centroids`` (m, 2), integer
    ``weights`` (m,), default 1) in an even split of all ranks' cells along the Z-order curve of
    their centroids: the cells in curve order (ties by rank, then by index), cut into ``nparts``
    parts of equal weight (a cell goes where the middle of its weight falls).  Each cell's place
    in that order comes from a histogram of the keys over ``bins`` bins reduced over the ranks,
    so no rank holds more than its own centroids and the histogram.  The result depends on the
    centroids, weights and their order on each rank only (collective)."""
    c = np.asarray(centroids, dtype=float).reshape(-1, 2)
    w = np.ones(len(c), np.int64) if weights is None else np.asarray(weights, np.int64).reshape(-1)
    box = np.r_[c.min(axis=0), -c.max(axis=0)] if len(c) else np.full(4, np.inf)
    comm.Allreduce(MPI.IN_PLACE, box, op=MPI.MIN)
    lo, span = box[:2], max(float((-box[2:] - box[:2]).max()), 1e-300)
    q = np.clip(np.floor((c - lo) / span * 65535.0), 0, 65535)
    key = _morton(q)
    b = (key >> np.uint64(32 - int(np.log2(bins)))).astype(np.int64)
    here = np.bincount(b, weights=w, minlength=bins).astype(np.int64)
    total = np.empty_like(here)
    comm.Allreduce(here, total, op=MPI.SUM)
    before = np.zeros_like(here)  # the weight of each bin on the ranks before this one
    comm.Exscan(here, before, op=MPI.SUM)
    if comm.rank == 0:
        before[:] = 0
    order = np.lexsort((np.arange(len(key)), key))
    sb, sw = b[order], w[order]
    run = np.cumsum(sw) - sw  # this rank's weight before each cell, in curve order
    within = np.empty(len(key), dtype=np.int64)  # ... and before it within its bin
    within[order] = run - run[np.searchsorted(sb, sb, side="left")]
    pos = (np.cumsum(total) - total)[b] + before[b] + within
    W = max(int(total.sum()), 1)
    return ((2 * pos + w) * nparts // (2 * W)).astype(np.int32)


#: the rings of cells around the patch's seeds that the region adds: the patch grows by a ring
#: at each of at most 4 passes that remove a pinch (:func:`_patch`), and one more holds the
#: cells next to it
REGION_RINGS = 5


def _region(comm, cells, cxy, facets, added, polylines, radius, size, tips):
    """(cells, tagged facets) of this rank that rank 0 needs to make the patch: the seeds (the
    cells within ``radius`` of an end of an ``added`` segment, and those within the size law's
    grading that are too coarse for the new cracks: every cell :func:`_patch` can select), and
    :data:`REGION_RINGS` rings of cells around them (node neighbours, across ranks).  The patch
    made from the region is the one the whole mesh gives, but for an island of old cells inside
    the patch wider than the rings, which then stays as it is (a hole in the patch)."""
    from scipy.spatial import cKDTree
    ends = np.array([p for _, a, b in added for p in (a, b)])
    seed = np.zeros(len(cells), dtype=bool)
    if len(cells):
        cent = cxy.mean(axis=1)
        dist = cKDTree(ends).query(cent)[0]
        seed = dist < radius
        reach = np.flatnonzero(~seed & (dist < size.grading))
        if reach.size:
            xy = cxy[reach]
            longest = np.sqrt(((xy - np.roll(xy, 1, axis=1)) ** 2).sum(axis=2)).max(axis=1)
            coarse = longest > 1.5 * size.smallest  # (only these can be too coarse: see _patch)
            reach, longest = reach[coarse], longest[coarse]
        if reach.size:
            seed[reach] = longest > 1.5 * size.sampler(polylines, tips)(cent[reach])
    nodes = np.unique(cells[seed])
    inside = seed
    for _ in range(REGION_RINGS):
        nodes = np.unique(np.concatenate(comm.allgather(nodes)))
        inside = _member(cells, nodes).any(axis=1)
        nodes = np.unique(cells[inside])
    nodes = np.unique(np.concatenate(comm.allgather(nodes)))
    return np.flatnonzero(inside), np.flatnonzero(_member(facets, nodes).all(axis=1))


def _member(a, nodes):
    """np.isin(a, nodes) for node indices (non-negative integers) by a mask over the indices:
    one pass, no sort (a region's rings test every cell of the rank five times)."""
    a = np.asarray(a)
    if not a.size:
        return np.zeros(a.shape, dtype=bool)
    mark = np.zeros(max(int(a.max()), int(nodes.max()) if nodes.size else 0) + 1, dtype=bool)
    mark[nodes] = True
    return mark[a]


def _rows_in(a, b):
    """Whether each row of the integer array ``a`` (m, k) is a row of ``b`` (n, k)."""
    if not len(a) or not len(b):
        return np.zeros(len(a), dtype=bool)
    view = np.dtype((np.void, a.shape[1] * 8))
    return np.isin(np.ascontiguousarray(a, np.int64).view(view).ravel(),
                   np.ascontiguousarray(b, np.int64).view(view).ravel())


def _plan_patch(gmsh, parts, nranks, n_nodes, polylines, added, radius, size, tips, crack_tags, scale):
    """Rank 0's part of :func:`patch_local`: the region's cells from every rank as one
    :class:`MeshArrays` (nodes by global index), its patch, and what each rank changes."""
    from scipy.spatial import cKDTree
    gc = np.concatenate([p[0] for p in parts]).reshape(-1, 3)
    gxy = np.concatenate([p[1] for p in parts]).reshape(-1, 3, 2)
    origin = np.concatenate([np.full(len(p[0]), r, np.int64) for r, p in enumerate(parts)])
    index = np.concatenate([p[2] for p in parts]).astype(np.int64)
    gf = np.concatenate([p[3] for p in parts]).reshape(-1, 2)
    gv = np.concatenate([p[4] for p in parts]).astype(np.int32)
    uniq, first, inv = np.unique(gc.reshape(-1), return_index=True, return_inverse=True)
    nodes = gxy.reshape(-1, 2)[first]
    # the region in an order of its geometry alone (nodes by coordinates, triangles and edges by
    # their nodes), not of the partition: any number of ranks makes the same patch
    by_xy = np.lexsort((nodes[:, 1], nodes[:, 0]))
    rank_of = np.empty_like(by_xy)
    rank_of[by_xy] = np.arange(by_xy.size)
    uniq, nodes = uniq[by_xy], nodes[by_xy]
    tris = rank_of[inv.reshape(-1, 3)].astype(np.int64)
    t_order = np.lexsort(np.sort(tris, axis=1).T[::-1])
    tris, origin, index = tris[t_order], origin[t_order], index[t_order]
    g_order = np.argsort(uniq)
    pos = g_order[np.clip(np.searchsorted(uniq[g_order], gf), 0, max(len(uniq) - 1, 0))]
    inside = (uniq[pos] == gf).all(axis=1) if len(uniq) else np.zeros(len(gf), bool)
    lines = {}
    for t in np.unique(gv[inside]):
        e = np.sort(pos[inside & (gv == t)], axis=1)
        lines[int(t)] = e[np.lexsort(e.T[::-1])]
    region = MeshArrays(nodes, tris, lines)
    near, all_nodes, new_t, new_lines, why = _patch(gmsh, region, polylines, added, radius, size, tips, crack_tags,
                                                   scale)
    if why is not None:
        return {"common": (why, len(tris), None, None, 0, None)}
    n_sub = len(uniq)
    gid = np.concatenate([uniq, n_nodes + np.arange(all_nodes.shape[0] - n_sub)])
    new_cells = gid[new_t]
    fresh = all_nodes[n_sub:]
    # each patch cell goes to the rank of the dropped cell nearest to it
    gone = np.flatnonzero(near)
    dest = origin[gone][cKDTree(nodes[tris[gone]].mean(axis=1)).query(all_nodes[new_t].mean(axis=1))[1]]
    per_rank = []
    centroids = all_nodes[new_t].mean(axis=1)
    for r in range(nranks):
        per_rank.append((index[gone[origin[gone] == r]], new_cells[dest == r], centroids[dest == r],
                         fresh if r == nranks - 1 else np.zeros((0, 2))))

    def keyed(lns, ids):
        return {(int(t), int(min(a, b)), int(max(a, b))) for t, e in lns.items() for a, b in ids[e]}
    before, after = keyed(lines, uniq), keyed(new_lines, gid)
    drop = sorted(before - after)
    add = sorted(after - before)
    add_f = np.array([[a, b] for _, a, b in add], dtype=np.int64).reshape(-1, 2)
    add_v = np.array([t for t, _, _ in add], dtype=np.int32)
    patch_min = float(_inradii(all_nodes[new_t]).min()) if len(new_t) else math.inf
    # the old nodes inside the patch that no cell uses any more (every cell at such a node is in
    # the region): DOLFINx wants the global node indices without gaps
    used = np.zeros(all_nodes.shape[0], dtype=bool)
    used[tris[~near].reshape(-1)] = used[new_t.reshape(-1)] = True
    unused = np.setdiff1d(np.unique(tris[near]), np.flatnonzero(used))
    return {"common": (None, len(tris), drop, patch_min, int(near.sum()), np.sort(uniq[unused])), "per_rank": per_rank,
            "add": (add_f, add_v)}
