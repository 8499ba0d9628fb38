"""Rock box with a wellbore, oriented perforations, natural fractures and potential
crack paths, all embedded as facet polylines of a graded triangle mesh.

Every crack is a straight segment (or a polyline) whose facets carry its own
facet tag; the interface model (:mod:`hydrofrac.interface`) turns the tag into
a crack with its friction, initial damage and opening:

* perforations start on the wellbore wall and are hydraulic sources,
* natural fractures are pre-existing (D = 1) cracks in contact,
* potential paths are bonded interfaces (D = 0) that can debond.

Mesh size: ``h_crack`` along the cracks (finer, ``h_tip``, within ``tip_radius``
of crack tips), growing to ``h_far`` over ``grading`` metres (Gmsh Distance +
Threshold size fields).  Each :class:`Refinement` (points, a size and a radius; the adaptive
meshes of :mod:`hydrofrac.adapt`) adds a field: its size within its radius of the points,
growing to ``h_far`` over the same ``grading``; the mesh takes the smallest of the fields.  The outer boundary is one facet tag (``OUTER``),
absorbing in the scenarios; the wellbore wall is ``WELLBORE``.

Tags (module constants): cells ``ROCK`` = 1; facets ``WELLBORE`` = 1,
``OUTER`` = 2, perforation i -> ``PERFORATION + i``, natural fracture j ->
``NATURAL + j``, potential path k -> ``PATH + k``.
"""
from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import List, Optional, Sequence, Tuple

import numpy as np
from mpi4py import MPI

from .gmsh_util import gmsh_session, mesh_arrays

ROCK = 1
WELLBORE = 1
OUTER = 2
PERFORATION = 100
NATURAL = 200
PATH = 300


@dataclass(frozen=True)
class Perforation:
    """A perforation leaving the wellbore wall at ``angle`` [deg], ``length`` [m] long,
    with hydraulic aperture ``width`` [m] (its initial opening)."""

    angle: float
    length: float
    width: float = 1e-4


@dataclass(frozen=True)
class Fracture:
    """A straight natural fracture through ``center`` at ``angle`` [deg] (0 = along x),
    with Coulomb friction and its own relaxation time ``tau`` [s] (None = the scenario's
    damage tau~; see :class:`hydrofrac.interface.Crack`)."""

    center: Tuple[float, float]
    angle: float
    length: float
    friction: float = 0.6
    tau: Optional[float] = None


@dataclass(frozen=True)
class Domain:
    """Box [-half_width, half_width] x [-half_height, half_height] with an optional wellbore
    of ``wellbore_radius`` at the origin; mesh sizes as in the module docstring."""

    half_width: float = 4.0
    half_height: float = 4.0
    wellbore_radius: float = 0.1
    h_crack: float = 0.05
    h_tip: Optional[float] = None
    tip_radius: float = 0.2
    h_far: float = 0.8
    grading: float = 2.0


@dataclass(frozen=True)
class Refinement:
    """Where the mesh must be finer than the crack law: ``h`` [m] within ``radius`` [m] of
    ``points`` (k, 2), graded to the domain's ``h_far`` over its ``grading`` (Gmsh Distance +
    Threshold, as for the cracks)."""

    points: Tuple[Tuple[float, float], ...]
    h: float
    radius: float

    def __post_init__(self):
        if not (self.h > 0 and self.radius >= 0):
            raise ValueError(f"a refinement needs h > 0 and radius >= 0 m; got h = {self.h}, radius = {self.radius}")
        object.__setattr__(self, "points", tuple((float(x), float(y)) for x, y in self.points))


@dataclass
class FractureMesh:
    """What the generator returns: the DOLFINx mesh with tags and the crack lines."""

    mesh: object
    cell_tags: object
    facet_tags: object
    perforations: List[int] = field(default_factory=list)   # facet tags
    naturals: List[int] = field(default_factory=list)
    paths: List[int] = field(default_factory=list)
    lines: dict = field(default_factory=dict)  # tag -> (points (k, 2))
    #: the arrays the mesh was made from (meshes/patch.py): a full mesh's on rank 0 (None
    #: elsewhere), a local remesh's on every rank (each its own part); a restart makes the mesh
    #: again from them
    arrays: object = None
    #: how it was made: "full" (Gmsh over the whole domain) or "patch" (meshes/patch.py), the
    #: patch's old triangles, and why a local remesh that was asked for fell back to "full"
    remesh: str = "full"
    patch_cells: int = 0
    fallback: Optional[str] = None
    #: a local remesh: the old cells rank 0 received to make the patch (the region around it)
    region_cells: int = 0
    #: a local remesh made a second time with a larger radius (its first patch had a smaller cell)
    retried: bool = False
    #: a local remesh that spread the cells over the ranks again (meshes/patch.py, REBALANCE_TOLERANCE)
    rebalanced: bool = False
    #: this rank's seconds: making the arrays (Gmsh on rank 0; the others wait there), and
    #: making the DOLFINx mesh from them (:func:`fracture_mesh`)
    meshing_s: float = 0.0
    distribution_s: float = 0.0


def perforation_points(domain: Domain, perf: Perforation):
    a = math.radians(perf.angle)
    d = np.array([math.cos(a), math.sin(a)])
    p0 = domain.wellbore_radius * d
    return np.array([p0, p0 + perf.length * d])


def fracture_points(frac: Fracture):
    a = math.radians(frac.angle)
    d = 0.5 * frac.length * np.array([math.cos(a), math.sin(a)])
    c = np.asarray(frac.center, dtype=float)
    return np.array([c - d, c + d])


def _orient_all(a, b, c, tol):
    """Orientation (-1, 0, 1) of the points c against the lines ab, broadcasting; 0 within
    ``tol`` [m] of the line."""
    cross = (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])
    return np.where(np.abs(cross) <= tol * np.hypot(b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]), 0.0,
                    np.sign(cross))


def _cross_table(a, b, tol=1e-9):
    """(crossings, overlaps): (m, n) tables of the segments of polylines ``a`` (m + 1 points) and
    ``b`` (n + 1 points).  A crossing is proper: shared end points do not count, nor an end
    point within ``tol`` [m] of the other segment's line (a crack that ends on another, or on
    itself, at a point rounded to 1 nm, e.g. a growth tip that joins it).  An overlap is a
    collinear stretch shared by both segments (see :func:`check_no_crossings`)."""
    return _cross_segments(a[:-1], a[1:], b[:-1], b[1:], tol)


def _cross_segments(a0, a1, b0, b1, tol=1e-9):
    """:func:`_cross_table` of the segments a0[i]-a1[i] against b0[j]-b1[j]."""
    p, q = a0[:, None, :], a1[:, None, :]
    r, s_ = b0[None, :, :], b1[None, :, :]
    cross = ((_orient_all(p, q, r, tol) * _orient_all(p, q, s_, tol) < 0)
             & (_orient_all(r, s_, p, tol) * _orient_all(r, s_, q, tol) < 0))
    d, e = q - p, s_ - r
    cr = lambda u, v: u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]  # noqa: E731
    dot = lambda u, v: u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1]  # noqa: E731
    ld, le = np.linalg.norm(d, axis=-1), np.linalg.norm(e, axis=-1)
    overlap = ((np.abs(cr(d, e)) <= 1e-12 * ld * le) & (np.abs(cr(d, r - p)) <= 1e-9 * ld)
               & (np.maximum(dot(r - p, d), dot(s_ - p, d)) > 1e-12)
               & (np.maximum(dot(r - q, -d), dot(s_ - q, -d)) > 1e-12))
    return cross, overlap


def check_polyline(name, pts, domain: Domain, on_wellbore_start=False):
    """Raise ValueError (what to change) if a crack polyline leaves the domain, enters the
    wellbore, has a zero-length segment or crosses itself."""
    pts = np.asarray(pts, dtype=float)
    key = (domain, bool(on_wellbore_start), pts.shape, pts.tobytes())
    if key in _VALID_POLYLINES:  # (a network's unchanged lines, at every remesh)
        return pts
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 2 or not np.all(np.isfinite(pts)):
        raise ValueError(f"{name}: needs at least two finite (x, y) points; got {pts.tolist()}")
    seg = np.diff(pts, axis=0)
    if np.any(np.linalg.norm(seg, axis=1) <= 1e-12):
        raise ValueError(f"{name}: has a zero-length segment; remove repeated points")
    margin = domain.h_crack
    out = (np.abs(pts[:, 0]) > domain.half_width - margin) | (np.abs(pts[:, 1]) > domain.half_height - margin)
    if np.any(out):
        raise ValueError(f"{name}: point(s) {pts[out].tolist()} lie outside the domain "
                         f"[-{domain.half_width}, {domain.half_width}] x [-{domain.half_height}, {domain.half_height}] "
                         f"(less one crack mesh size {margin} m from the edge); shorten or move the crack, "
                         "or enlarge the domain")
    if domain.wellbore_radius > 0:
        # distance from the wellbore centre to every segment
        a, b = pts[:-1], pts[1:]
        t = np.clip(np.einsum("ij,ij->i", -a, b - a) / np.einsum("ij,ij->i", b - a, b - a), 0.0, 1.0)
        dist = np.linalg.norm(a + t[:, None] * (b - a), axis=1)
        if np.any(dist < domain.wellbore_radius * (1 - 1e-9)):
            raise ValueError(f"{name}: enters the wellbore (radius {domain.wellbore_radius} m); move it out")
        if not on_wellbore_start and np.any(np.linalg.norm(pts, axis=1) <= domain.wellbore_radius * (1 + 1e-9)):
            raise ValueError(f"{name}: touches the wellbore wall; only perforations start there")
    cross, _ = _cross_table(pts, pts)
    i, j = np.nonzero(np.triu(cross, k=2))  # (a segment and its neighbours share an end)
    if i.size:
        raise ValueError(f"{name}: crosses itself (segments {i[0]} and {j[0]}); give a simple polyline")
    if len(_VALID_POLYLINES) >= 4096:
        _VALID_POLYLINES.clear()
    _VALID_POLYLINES.add(key)
    return pts


#: (domain, on_wellbore_start, shape, bytes) of the polylines :func:`check_polyline` passed
_VALID_POLYLINES: set = set()


def _line_name(tag):
    for base, name in ((PATH, "path"), (NATURAL, "natural fracture"), (PERFORATION, "perforation")):
        if tag >= base:
            return f"{name} {tag - base} (tag {tag})"
    return f"crack tag {tag}"


def check_no_crossings(lines):
    """Raise ValueError (naming both) if two crack lines cross or overlap: a crack may end
    on another (a junction), but Gmsh would split a crossed line and lose its tag."""
    items = [(t, np.asarray(pts, dtype=float)) for t, pts in lines.items()]
    if len(items) < 2:
        return
    # pairs of lines that the last clean call checked already, unchanged, are skipped (a growing
    # network adds a segment or two per remesh; its other lines were checked against each other)
    keys = [(t, a.shape, a.tobytes()) for t, a in items]
    known = np.array([k in _CLEAN_LINES for k in keys])
    # each line's segments against the segments of all later lines in one table (the pairs'
    # arithmetic is the one of a table per pair of lines; memory: one line's rows at a time)
    a0 = np.concatenate([a[:-1] for _, a in items])
    a1 = np.concatenate([a[1:] for _, a in items])
    line = np.repeat(np.arange(len(items)), [len(a) - 1 for _, a in items])
    start = np.r_[0, np.cumsum([len(a) - 1 for _, a in items])]
    for ia in range(len(items) - 1):
        rows, rest = slice(start[ia], start[ia + 1]), np.arange(start[ia + 1], a0.shape[0])
        if known[ia]:
            rest = rest[~known[line[rest]]]
            if not rest.size:
                continue
        cross, overlap = _cross_segments(a0[rows], a1[rows], a0[rest], a1[rest])
        i, j = np.nonzero(cross | overlap)
        if i.size:  # named by the first later line it meets, and the first bad pair of segments
            k = np.lexsort((j, i, line[rest][j]))[0]
            tb = items[line[rest][j[k]]][0]
            raise ValueError(f"{_line_name(items[ia][0])} and {_line_name(tb)} "
                             f"{'overlap' if overlap[i[k], j[k]] else 'cross'}; move one of them (cracks may "
                             "end on each other, not cross)")
    _CLEAN_LINES.clear()
    _CLEAN_LINES.update(keys)


#: the lines (tag, shape, bytes) of the last network that :func:`check_no_crossings` passed
_CLEAN_LINES: set = set()


def check_domain(d: Domain):
    for k in ("half_width", "half_height", "h_crack", "h_far", "grading", "tip_radius"):
        v = getattr(d, k)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"domain: {k} must be a positive length in metres; got {v!r}")
    if d.wellbore_radius < 0:
        raise ValueError(f"domain: wellbore_radius must be >= 0; got {d.wellbore_radius}")
    if d.h_crack > d.h_far:
        raise ValueError(f"domain: h_crack = {d.h_crack} must not exceed h_far = {d.h_far}")
    if d.wellbore_radius and d.wellbore_radius >= min(d.half_width, d.half_height) / 2:
        raise ValueError("domain: the wellbore must be smaller than half the box")


def check_geometry(domain: Domain, perforations: Sequence[Perforation] = (), fractures: Sequence[Fracture] = (),
                   paths: Sequence[np.ndarray] = (), path_tags: Optional[Sequence[int]] = None):
    """Validate a geometry before any meshing; returns its crack lines {tag: points}.
    Raises ValueError saying what to change."""
    path_tags = [PATH + k for k in range(len(paths))] if path_tags is None else [int(t) for t in path_tags]
    if len(path_tags) != len(paths) or len(set(path_tags)) != len(path_tags):
        raise ValueError(f"path_tags must be {len(paths)} distinct tags; got {path_tags}")
    check_domain(domain)
    lines = {}
    for i, pf in enumerate(perforations):
        if not (pf.length > 0 and pf.width > 0):
            raise ValueError(f"perforation {i}: length and width must be > 0; got {pf.length}, {pf.width}")
        if domain.wellbore_radius <= 0:
            raise ValueError("perforations need a wellbore (domain.wellbore_radius > 0)")
        lines[PERFORATION + i] = check_polyline(f"perforation {i}", perforation_points(domain, pf), domain, True)
    for j, fr in enumerate(fractures):
        if not fr.length > 0:
            raise ValueError(f"natural fracture {j}: length must be > 0; got {fr.length}")
        lines[NATURAL + j] = check_polyline(f"natural fracture {j}", fracture_points(fr), domain)
    for k, pth in enumerate(paths):
        pts = np.asarray(pth, dtype=float)
        lines[path_tags[k]] = check_polyline(f"potential path {k}", pts, domain,
                                         on_wellbore_start=np.linalg.norm(pts[0]) <= domain.wellbore_radius + 1e-9)
    check_no_crossings(lines)
    return lines


def fracture_mesh(comm, domain: Domain = Domain(), perforations: Sequence[Perforation] = (),
                  fractures: Sequence[Fracture] = (), paths: Sequence[np.ndarray] = (),
                  out=None, verbose=False, path_tags: Optional[Sequence[int]] = None, network=None,
                  previous: Optional[FractureMesh] = None, patch_radius: Optional[float] = None,
                  refine: Sequence[Refinement] = ()) -> FractureMesh:
    """Mesh a box with a wellbore, perforations, natural fractures and potential paths.

    ``paths`` are polylines (k, 2); every line is validated before Gmsh runs.  ``path_tags``
    (default ``PATH + k``) fixes each path's facet tag, e.g. so that growing cracks keep
    their tags from one remesh to the next.  ``network`` (a
    :class:`hydrofrac.network.CrackNetwork`, validated already) gives the crack lines
    instead of the perforations, fractures and paths.

    ``previous`` (the mesh of the same domain made before, with ``patch_radius`` [m]): remesh
    only the triangles within ``patch_radius`` of the new crack segments' ends and keep the
    rest of ``previous`` as it is (:mod:`hydrofrac.meshes.patch`); where that cannot be done,
    mesh the whole domain and say why in ``fallback``.

    ``refine`` (:class:`Refinement` objects): finer still near their points (a full remesh only).

    The result's ``meshing_s`` and ``distribution_s`` are this rank's seconds for the arrays
    (Gmsh on rank 0, the patch's exchanges) and for the DOLFINx mesh made from them.
    """
    t0 = time.perf_counter()
    spent = [0.0]

    def made(make_mesh, *args):  # (mesh, cell tags, facet tags) from arrays, timed
        t = time.perf_counter()
        try:
            return make_mesh(*args)
        finally:
            spent[0] += time.perf_counter() - t
    fm = _fracture_mesh(comm, domain, perforations, fractures, paths, out, verbose, path_tags, network, previous,
                        patch_radius, refine, made)
    fm.distribution_s = spent[0]
    fm.meshing_s = time.perf_counter() - t0 - spent[0]
    return fm


def _fracture_mesh(comm, domain, perforations, fractures, paths, out, verbose, path_tags, network, previous,
                   patch_radius, refine, made):
    """:func:`fracture_mesh`, with ``made(make_mesh, *args)`` making each DOLFINx mesh."""
    refine = [r for r in refine if len(r.points)]
    if refine and previous is not None:
        raise ValueError("a refinement changes the size field everywhere: mesh the whole domain "
                         "(previous = None), not a local patch")
    if network is not None:
        lines = {c.tag: c.points for c in network.cracks}
        kinds = {c.tag: c.kind for c in network.cracks}
        perf_tags = [t for t in lines if kinds[t] == "perforation"]
        nat_tags = [t for t in lines if kinds[t] == "natural"]
        path_tags = [t for t in lines if kinds[t] == "path"]
    else:
        path_tags = [PATH + k for k in range(len(paths))] if path_tags is None else [int(t) for t in path_tags]
        lines = check_geometry(domain, perforations, fractures, paths, path_tags)
        perf_tags = [PERFORATION + i for i in range(len(perforations))]
        nat_tags = [NATURAL + j for j in range(len(fractures))]
    tips = _tips(lines)

    def build(model):
        occ = model.occ
        box = occ.addRectangle(-domain.half_width, -domain.half_height, 0, 2 * domain.half_width,
                               2 * domain.half_height)
        surf = [(2, box)]
        if domain.wellbore_radius > 0:
            disk = occ.addDisk(0, 0, 0, domain.wellbore_radius, domain.wellbore_radius)
            surf, _ = occ.cut(surf, [(2, disk)])
        line_ids, owner = [], []
        for tag, pts in lines.items():
            pids = [occ.addPoint(x, y, 0) for x, y in pts]
            for a, b in zip(pids[:-1], pids[1:]):
                line_ids.append((1, occ.addLine(a, b)))
                owner.append(tag)
        # (a block without cracks yet, e.g. before a crack nucleates: nothing to fragment)
        out_map = occ.fragment(surf, line_ids)[1] if line_ids else [[x] for x in surf]
        occ.synchronize()
        surfaces = model.getEntities(2)
        model.addPhysicalGroup(2, [s[1] for s in surfaces], ROCK)
        crack_curves = {}
        for tag, pieces in zip(owner, out_map[len(surf):]):
            crack_curves.setdefault(tag, []).extend(p[1] for p in pieces if p[0] == 1)
        for tag, curves in crack_curves.items():
            model.addPhysicalGroup(1, sorted(set(curves)), tag)
        # outer and wellbore curves: the surface boundary minus crack curves
        all_crack = {c for cs in crack_curves.values() for c in cs}
        bnd = model.getBoundary(surfaces, combined=True, oriented=False)
        outer, well = [], []
        for _, c in bnd:
            if abs(c) in all_crack:
                continue
            xmin, ymin, _, xmax, ymax, _ = model.getBoundingBox(1, abs(c))
            cx, cy = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax)
            if math.hypot(cx, cy) < 2 * domain.wellbore_radius + 1e-9 and domain.wellbore_radius > 0:
                well.append(abs(c))
            else:
                outer.append(abs(c))
        model.addPhysicalGroup(1, outer, OUTER)
        if well:
            model.addPhysicalGroup(1, well, WELLBORE)
        # size field: fine at cracks, finer at tips, coarse far away
        mf = model.mesh.field
        if not all_crack and not well and not refine:  # no crack, wellbore or refinement: h_far everywhere
            import gmsh
            gmsh.option.setNumber("Mesh.MeshSizeMax", domain.h_far)
            gmsh.option.setNumber("Mesh.MeshSizeMin", domain.h_far)
            return
        fields = []
        if all_crack or well:
            dist = mf.add("Distance")
            mf.setNumbers(dist, "CurvesList", sorted(all_crack) + well)
            mf.setNumber(dist, "NumPointsPerCurve", 200)  # "Sampling" in Gmsh >= 4.11
            thr = mf.add("Threshold")
            mf.setNumber(thr, "InField", dist)
            mf.setNumber(thr, "SizeMin", domain.h_crack)
            mf.setNumber(thr, "SizeMax", domain.h_far)
            mf.setNumber(thr, "DistMin", domain.h_crack)
            mf.setNumber(thr, "DistMax", domain.grading)
            fields.append(thr)

        def near_points(points, h, radius):
            """h within radius of free points (not embedded: they only feed the Distance
            field), graded to h_far over ``grading``."""
            pts = [occ.addPoint(x, y, 0) for x, y in points]
            occ.synchronize()
            d = mf.add("Distance")
            mf.setNumbers(d, "PointsList", pts)
            t = mf.add("Threshold")
            mf.setNumber(t, "InField", d)
            mf.setNumber(t, "SizeMin", h)
            mf.setNumber(t, "SizeMax", domain.h_far)
            mf.setNumber(t, "DistMin", radius)
            mf.setNumber(t, "DistMax", radius + domain.grading)
            fields.append(t)

        for ref in refine:
            near_points(ref.points, ref.h, ref.radius)
        if domain.h_tip is not None and tips:
            near_points(tips, domain.h_tip, domain.tip_radius)
        mn = mf.add("Min")
        mf.setNumbers(mn, "FieldsList", fields)
        mf.setAsBackgroundMesh(mn)
        import gmsh
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.option.setNumber("Mesh.Algorithm", 6)

    tags = dict(perforations=perf_tags, naturals=nat_tags, paths=list(path_tags), lines=lines)
    fallback = None
    from .patch import capture, distribute
    if previous is not None:
        from . import patch
        if patch_radius is None or not patch_radius > 0:
            raise ValueError(f"a local remesh needs patch_radius > 0; got {patch_radius}")
        if getattr(previous, "mesh", None) is None:
            # a restart: the checkpoint's mesh, made again from the arrays it was made from
            a = previous.arrays
            local = comm.allreduce(isinstance(a, patch.LocalArrays), op=MPI.LOR)
            old_lines = a.polylines if local else comm.bcast(None if a is None else a.polylines, root=0)
            mesh, ct, ft = made(patch.build, comm, a, ROCK)
            previous = FractureMesh(mesh, ct, ft, lines=old_lines, arrays=a, remesh="patch" if local else "full")
        added, removed = patch.new_segments(previous.lines, lines)
        if not added and not removed:  # the same geometry: the same mesh, from the same arrays
            mesh, ct, ft = made(patch.build, comm, previous.arrays, ROCK)
            arrays = None if previous.arrays is None else replace(previous.arrays, polylines=dict(lines))
            return FractureMesh(mesh, ct, ft, **tags, arrays=arrays, remesh="patch", patch_cells=0)
        local, n_patch, why, stats = None, 0, "a crack segment of the old mesh is gone", {}
        retried = False

        def shrinks_(why, stats):
            return why is None and stats["inradius"] < (1 - patch.CELL_FLOOR_TOLERANCE) * stats["old_inradius"]
        if not removed:
            law = patch.SizeLaw(domain.h_crack, domain.h_far, domain.grading, domain.wellbore_radius,
                                domain.h_tip, domain.tip_radius)

            def make(radius):
                with gmsh_session(comm) as gmsh:
                    if comm.rank == 0:
                        gmsh.option.setNumber("General.Terminal", 0)
                    return patch.patch_local(comm, gmsh if comm.rank == 0 else None, previous.mesh,
                                             previous.facet_tags, added, lines, radius, law, tips,
                                             crack_tags=set(lines),
                                             scale=2 * max(domain.half_width, domain.half_height))
            local, n_patch, why, stats = make(patch_radius)
            # a patch that cannot be made, or whose smallest cell is smaller than the old mesh's,
            # is made once more with PATCH_RETRY_RADIUS times the radius (more room for Gmsh);
            # the second is taken if it can be made and its smallest cell is larger
            if (why is not None or shrinks_(why, stats)) and patch.PATCH_RETRY_RADIUS > 1:
                second = make(patch.PATCH_RETRY_RADIUS * patch_radius)
                if second[2] is None and (why is not None or second[3]["inradius"] > stats["inradius"]):
                    (local, n_patch, why, stats), retried = second, True
        shrinks = shrinks_(why, stats)
        full = None
        if shrinks:
            # is the smaller cell the new geometry's (a kink, a short segment) or the patch's?
            full = mesh_arrays(comm, build, lambda gmsh: capture(gmsh, lines), name="fractures", out=out,
                               verbose=verbose)
            better = None
            if comm.rank == 0:
                better = (patch.smallest_inradius(full.nodes, full.tris) > (1 + patch.CELL_FLOOR_TOLERANCE)
                          * stats["inradius"])
            if comm.bcast(better, root=0):
                why = "the patch made a smaller cell than a full remesh does (a shorter time step)"
        if why is None:
            mesh, ct, ft = made(patch.build, comm, local, ROCK)
            return FractureMesh(mesh, ct, ft, **tags, arrays=local, remesh="patch", patch_cells=n_patch,
                                region_cells=stats["region_cells"], retried=retried,
                                rebalanced=stats["rebalanced"])
        fallback = why
        if shrinks:  # (the full mesh is made already; its arrays live on rank 0)
            mesh, ct, ft = made(distribute, comm, full, ROCK)
            return FractureMesh(mesh, ct, ft, **tags, arrays=full, fallback=fallback)
    arrays = mesh_arrays(comm, build, lambda gmsh: capture(gmsh, lines), name="fractures", out=out, verbose=verbose)
    mesh, ct, ft = made(distribute, comm, arrays, ROCK)
    return FractureMesh(mesh, ct, ft, **tags, arrays=arrays, fallback=fallback)


def _tips(lines):
    """End points that belong to one line only (crack tips)."""
    rounded = [[tuple(p) for p in np.round(np.asarray(pts, dtype=float), 9).tolist()] for pts in lines.values()]
    count = Counter(p for pts in rounded for p in pts)
    return [e for pts in rounded for e in (pts[0], pts[-1]) if count[e] == 1]
