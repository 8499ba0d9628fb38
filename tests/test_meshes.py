"""Gmsh mesh generators: physical groups land on the right facets, bad parameters
and broken geometries fail with messages that say what to change.

Rank-agnostic: the ``mpi``-marked copy runs the same checks on 2 ranks.
"""
import math

import numpy as np
import pytest
import ufl
from mpi4py import MPI

from hydrofrac import compat
from hydrofrac.meshes import borehole as bh
from hydrofrac.meshes.gmsh_util import build_mesh

A, R = 0.1, 1.0


def _owned_count(mesh, facets):
    owned = compat.facet_owned_mask(mesh)
    return mesh.comm.allreduce(int(owned[facets].sum()), op=MPI.SUM)


def _area(mesh):
    return compat.assemble_scalar(compat.form(compat.constant(mesh, 1.0) * ufl.dx(domain=mesh)), mesh.comm)


def check_borehole_tags(quarter, shape):
    comm = MPI.COMM_WORLD
    mesh, cell_tags, facet_tags = bh.borehole_mesh(comm, a=A, R=R, h_hole=A / 3, quarter=quarter, shape=shape)
    assert set(np.unique(cell_tags.values)) <= {bh.ROCK}
    nloc = compat.num_cells_local(mesh)
    tagged_owned = np.unique(cell_tags.indices[cell_tags.indices < nloc])
    assert comm.allreduce(tagged_owned.size, op=MPI.SUM) == compat.num_cells_global(mesh)
    tol = 1e-8
    markers = {
        bh.BOREHOLE: lambda x: np.hypot(x[0], x[1]) < A + tol,
        bh.SYMMETRY_X: lambda x: np.abs(x[0]) < tol,
        bh.SYMMETRY_Y: lambda x: np.abs(x[1]) < tol,
    }
    if shape == "square":
        markers[bh.OUTER] = lambda x: np.maximum(np.abs(x[0]), np.abs(x[1])) > R - tol
    else:
        markers[bh.OUTER] = lambda x: np.hypot(x[0], x[1]) > R * (1 - 0.02)  # chords of the outer circle
    expected = {bh.BOREHOLE, bh.OUTER} | ({bh.SYMMETRY_X, bh.SYMMETRY_Y} if quarter else set())
    present = set().union(*comm.allgather(set(np.unique(facet_tags.values).tolist())))
    assert present == expected  # the same on every rank
    owned = compat.facet_owned_mask(mesh)
    for tag in expected:
        tagged = facet_tags.indices[facet_tags.values == tag]
        tagged = tagged[owned[tagged]]
        located = compat.locate_boundary_facets(mesh, markers[tag])
        located = located[owned[located]]
        # assert collectively, so a failure on one rank cannot leave the other in a collective call
        assert comm.allreduce(bool(np.array_equal(np.sort(tagged), np.sort(located))), op=MPI.LAND), \
            f"owned facets tagged {tag} differ from the facets on that boundary"
        assert comm.allreduce(tagged.size, op=MPI.SUM) > 0
    # every exterior facet carries a tag
    exterior = compat.exterior_facet_indices(mesh)
    assert _owned_count(mesh, exterior) == _owned_count(mesh, facet_tags.indices)
    # area of the (polygonal) domain
    full = (2 * R) ** 2 if shape == "square" else math.pi * R ** 2
    area = (full - math.pi * A ** 2) / (4 if quarter else 1)
    assert _area(mesh) == pytest.approx(area, rel=5e-3)


@pytest.mark.parametrize("quarter", [True, False])
@pytest.mark.parametrize("shape", ["square", "circle"])
def test_borehole_tags(quarter, shape):
    check_borehole_tags(quarter, shape)


@pytest.mark.mpi
@pytest.mark.parametrize("quarter", [True, False])
def test_borehole_tags_mpi(quarter):
    check_borehole_tags(quarter, "square")


def test_borehole_mesh_grades_outward():
    mesh, _, _ = bh.borehole_mesh(MPI.COMM_SELF, a=A, R=R, quarter=True)
    xc = compat.cell_vertex_coords(mesh)
    r = np.hypot(*xc.mean(axis=1).T)
    edge = np.linalg.norm(xc[:, [1, 2, 0]] - xc, axis=2).mean(axis=1)
    assert edge[r < 1.5 * A].mean() < 0.5 * A  # ~a/4 at the hole
    assert edge[r > 0.8 * R].mean() > 2 * edge[r < 1.5 * A].mean()


@pytest.mark.parametrize("kwargs, match", [
    ({"a": 0.0}, "a .borehole radius. must be a positive length"),
    ({"a": -1.0}, "positive length"),
    ({"R": 0.25}, "must exceed 3 a"),
    ({"h_hole": 0.2}, "h_hole = 0.2 m is larger than the radius"),
    ({"h_outer": 0.01, "h_hole": 0.02}, "h_outer = 0.01 m must be >= h_hole"),
    ({"h_outer": 1.5}, "must be <= R/2"),
    ({"growth": 0.0}, "growth"),
    ({"shape": "hexagon"}, "shape must be one of"),
    ({"R": float("nan")}, "positive length"),
])
def test_borehole_parameters_rejected(kwargs, match):
    args = {"a": A, "R": R, **kwargs}
    with pytest.raises(ValueError, match=match):
        bh.borehole_mesh(MPI.COMM_WORLD, **args)


def test_gmsh_failure_is_reported(tmp_path):
    def broken(model):
        model.occ.addRectangle(0, 0, 0, 1, 1)
        model.occ.synchronize()
        raise ValueError("deliberately broken geometry")

    with pytest.raises(RuntimeError, match="deliberately broken geometry.*failed_geometry") as info:
        build_mesh(MPI.COMM_WORLD, broken, name="broken", out=tmp_path)
    assert "Fix the geometry callback" in str(info.value)
    if MPI.COMM_WORLD.rank == 0:
        saved = list(tmp_path.glob("failed_geometry.*"))
        assert saved and saved[0].stat().st_size > 0


def test_gmsh_needs_physical_cells(tmp_path):
    def untagged(model):
        model.occ.addRectangle(0, 0, 0, 1, 1)
        model.occ.synchronize()

    with pytest.raises(RuntimeError, match="no physical group of dimension 2"):
        build_mesh(MPI.COMM_WORLD, untagged, name="untagged", out=tmp_path)


def _reference_destinations(graph, owner):
    """Each cell's ranks, written out: its owner, then its neighbours' other owners in order."""
    offsets, nbr = np.asarray(graph.offsets), np.asarray(graph.array)
    dest = [[int(owner[i])] + sorted(set(owner[nbr[offsets[i]:offsets[i + 1]]].tolist()) - {int(owner[i])})
            for i in range(len(offsets) - 1)]
    return np.concatenate(dest), np.r_[0, np.cumsum([len(d) for d in dest])]


@pytest.mark.parametrize("nparts", [2, 3, 7])
def test_ordered_partition_ghost_destinations(nparts):
    """The vectorised partition sends every cell to its owner first and then to each other rank
    that owns one of its facet neighbours, once, in increasing order, as the loop over cells it
    replaced did (the owners: reverse Cuthill-McKee slabs)."""
    from dolfinx.cpp.graph import AdjacencyList_int32
    rng = np.random.default_rng(nparts)
    n = 500
    pairs = {tuple(sorted(p)) for p in rng.integers(0, n, (3 * n, 2)).tolist() if p[0] != p[1]}
    nbrs = [[] for _ in range(n)]
    for a, b in pairs:
        nbrs[a].append(b)
        nbrs[b].append(a)
    graph = AdjacencyList_int32(np.concatenate([sorted(x) for x in nbrs]).astype(np.int32),
                                np.r_[0, np.cumsum([len(x) for x in nbrs])].astype(np.int32))
    part = compat._ordered_partition(MPI.COMM_SELF, nparts, graph, True)
    arr, off = np.asarray(part.array), np.asarray(part.offsets)
    owner = arr[off[:-1]]
    assert np.bincount(owner, minlength=nparts).max() - np.bincount(owner, minlength=nparts).min() <= 1
    ref_arr, ref_off = _reference_destinations(graph, owner)
    assert np.array_equal(arr, ref_arr) and np.array_equal(off, ref_off)


def check_mesh_from_arrays_is_gmshio():
    """A fracture mesh distributed from its arrays is the mesh (nodes, cells, cell and facet tags)
    that DOLFINx's gmshio makes of the same triangles and lines in a Gmsh model."""
    from hydrofrac.meshes import fractures as fr
    from hydrofrac.meshes.gmsh_util import gmsh_session
    comm = MPI.COMM_WORLD
    dom = fr.Domain(half_width=1.0, half_height=1.0, h_crack=0.1, h_far=0.4, grading=0.5)
    fm = fr.fracture_mesh(comm, dom, perforations=[fr.Perforation(0.0, 0.3)],
                          fractures=[fr.Fracture((0.6, 0.0), 90.0, 0.6)])
    arrays = comm.bcast(fm.arrays, root=0)
    with gmsh_session(comm) as gmsh:
        if comm.rank == 0:
            gmsh.option.setNumber("General.Terminal", 0)
            model = gmsh.model
            model.add("discrete")
            xyz = np.zeros((arrays.nodes.shape[0], 3))
            xyz[:, :2] = arrays.nodes
            model.addDiscreteEntity(2, 1)
            model.mesh.addNodes(2, 1, np.arange(1, xyz.shape[0] + 1), xyz.reshape(-1))
            model.mesh.addElementsByType(1, 2, [], (arrays.tris + 1).reshape(-1))
            model.addPhysicalGroup(2, [1], fr.ROCK)
            for k, (tag, edges) in enumerate(sorted(arrays.lines.items())):
                model.addDiscreteEntity(1, k + 1)
                model.mesh.addElementsByType(k + 1, 1, [], (edges + 1).reshape(-1))
                model.addPhysicalGroup(1, [k + 1], tag)
        mesh, ct, ft = compat.gmsh_model_to_mesh(gmsh.model, comm, rank=0, gdim=2)
        if comm.rank == 0:
            gmsh.model.remove()
    assert np.array_equal(fm.mesh.geometry.x, mesh.geometry.x)
    assert np.array_equal(fm.mesh.geometry.dofmap.array, mesh.geometry.dofmap.array)
    for a, b in ((fm.cell_tags, ct), (fm.facet_tags, ft)):
        assert np.array_equal(a.indices, b.indices) and np.array_equal(a.values, b.values)
    tags = set().union(*comm.allgather(set(np.unique(fm.facet_tags.values).tolist())))
    assert tags == {fr.OUTER, fr.WELLBORE, fr.PERFORATION, fr.NATURAL}


def test_mesh_from_arrays_is_gmshio():
    check_mesh_from_arrays_is_gmshio()


@pytest.mark.mpi
def test_mesh_from_arrays_is_gmshio_mpi():
    check_mesh_from_arrays_is_gmshio()


def test_a_growing_network_is_checked_against_its_old_lines():
    """check_no_crossings skips only the pairs of lines that its last clean call checked,
    unchanged: a new line, or an old line that grew, is checked against every other line."""
    from hydrofrac.meshes import fractures as fr
    compared = []
    cross_segments = fr._cross_segments

    def counting(a0, a1, b0, b1, tol=1e-9):
        compared.append(a0.shape[0] * b0.shape[0])
        return cross_segments(a0, a1, b0, b1, tol)

    lines = {fr.PATH + k: np.array([[x, -1.0], [x, 0.0], [x, 1.0]]) for k, x in enumerate((-0.5, 0.0, 0.5))}
    fr._CLEAN_LINES.clear()
    try:
        fr._cross_segments = counting
        fr.check_no_crossings(lines)
        first = sum(compared)
        compared.clear()
        # one line more, crossing none: only its pairs are compared
        grown = {**lines, fr.PATH + 3: np.array([[0.7, -1.0], [0.9, 1.0]])}
        fr.check_no_crossings(grown)
        assert sum(compared) == 3 * 2 * 1 < first
        # a new line across the old ones, and an old line grown across another, are caught
        with pytest.raises(ValueError, match=r"path 0 \(tag \d+\) and path 4 \(tag \d+\) cross"):
            fr.check_no_crossings({**grown, fr.PATH + 4: np.array([[-1.0, 0.5], [1.0, 0.5]])})
        bent = dict(grown)
        bent[fr.PATH + 1] = np.array([[0.0, -1.0], [0.0, 0.0], [0.0, 1.0], [0.6, 0.8]])
        with pytest.raises(ValueError, match=r"path 1 \(tag \d+\) and path 2 \(tag \d+\) cross"):
            fr.check_no_crossings(bent)
    finally:
        fr._cross_segments = cross_segments
        fr._CLEAN_LINES.clear()


def test_a_polyline_passed_in_one_domain_is_checked_again_in_another():
    """check_polyline keeps the polylines it passed, with the domain and the wellbore flag they
    passed in: the same points in a smaller box are refused."""
    from hydrofrac.meshes import fractures as fr
    pts = np.array([[0.0, 0.0], [0.97, 0.0]])
    big = fr.Domain(half_width=2.0, half_height=2.0, wellbore_radius=0.0, h_crack=0.05, h_far=0.5, grading=0.5)
    small = fr.Domain(half_width=1.0, half_height=1.0, wellbore_radius=0.0, h_crack=0.05, h_far=0.5, grading=0.5)
    fr.check_polyline("path 0", pts, big)
    assert (big, False, pts.shape, pts.tobytes()) in fr._VALID_POLYLINES
    with pytest.raises(ValueError, match="lie outside the domain"):
        fr.check_polyline("path 0", pts, small)
