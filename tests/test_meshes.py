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
