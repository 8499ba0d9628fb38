"""Local remeshing (hydrofrac.meshes.patch; docs/benchmarks.md, "Remeshing: local patches").

* A remesh of an unchanged geometry is the same mesh: the fields move bit for bit and the
  energy changes by exactly 0.
* After an extension only the patch changes: every other triangle is an old one, its fields
  are copied bit for bit, the mesh is conforming and covers the domain, the crack facets are
  mesh edges and the grown crack has the facets of its new length.
* A run with local remeshing on 2 ranks stopped half way and restarted ends where the straight
  run ends (the checkpoint keeps the mesh, which a full remesh of the same geometry would not
  give; rank 0 holds it, the other ranks write their part too).
"""
import ctypes
import json

import numpy as np
import pytest
from mpi4py import MPI

from hydrofrac import ROCK, compat
from hydrofrac.boundary import Absorbing
from hydrofrac.interface import Crack, Interface, crack_facet_indices
from hydrofrac.meshes.fractures import NATURAL, OUTER, PATH, Domain, Fracture, fracture_mesh
from hydrofrac.meshes.patch import SizeLaw, _edge_key, _edges, _in_polygon, _member, _size_callback, gathered
from hydrofrac.network import CrackLine, CrackNetwork
from hydrofrac.solver import Solver
from hydrofrac.transfer import continue_run, transfer_fields

DOM = Domain(half_width=2.0, half_height=2.0, wellbore_radius=0.0, h_crack=0.05, h_far=0.4, grading=1.0)
S0 = np.array([[0.0, 0.0], [0.0, 1e6]])
NF = np.array([[-0.5, 0.0], [0.5, 0.0]])


def network(path):
    cracks = [CrackLine(NATURAL, "natural", NF), CrackLine(PATH, "path", np.asarray(path, float))]
    return CrackNetwork.from_cracks(cracks, 0.0, growing=[PATH])


def solver_on(fm):
    cracks = [Crack(NATURAL, friction=0.0, damage=1.0), Crack(PATH, friction=0.0, damage=0.0)]
    s = Solver(fm.mesh, 2, ROCK, facet_tags=fm.facet_tags, sigma0=S0, bcs=[Absorbing(OUTER, stress=S0)],
               crack_facets=crack_facet_indices(fm.mesh, fm.facet_tags, cracks))
    s.attach(Interface(s, fm.facet_tags, cracks))
    return s


def smooth(x):
    return np.vstack([np.sin(3 * x[0]) * np.cos(2 * x[1]), x[0] * x[1], np.exp(-x[0] ** 2), x[1] ** 3, x[0] + 0 * x[1]])


def check_arrays(a, area):
    """A conforming triangulation of the domain whose tagged lines are mesh edges."""
    x = a.nodes[a.tris]
    det = (x[:, 1, 0] - x[:, 0, 0]) * (x[:, 2, 1] - x[:, 0, 1]) - (x[:, 1, 1] - x[:, 0, 1]) * (x[:, 2, 0] - x[:, 0, 0])
    assert np.all(np.abs(det) > 0)
    assert 0.5 * np.abs(det).sum() == pytest.approx(area, rel=1e-12)
    e = _edges(a.tris)
    _, counts = np.unique(_edge_key(e), return_counts=True)
    assert counts.max() == 2  # no edge in three triangles: conforming
    keys = _edge_key(e)
    for tag, edges in a.lines.items():
        assert np.isin(_edge_key(edges), keys).all(), tag


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial: rank 0's arrays")
def test_unchanged_geometry_is_the_same_mesh_and_moves_the_fields_bit_for_bit():
    comm = MPI.COMM_WORLD
    path = [[0.5, 0.0], [0.6, 0.0]]
    full = fracture_mesh(comm, DOM, network=network(path))
    again = fracture_mesh(comm, DOM, network=network(path), previous=full, patch_radius=0.3)
    assert again.remesh == "patch" and again.patch_cells == 0
    old, new = solver_on(full), solver_on(again)
    old.set_initial_state(smooth)
    transfer_fields(old, new)
    assert np.array_equal(new.local_array(), old.local_array())
    e_old, e_new = continue_run(old, new)
    assert e_new - e_old == 0.0


def extension_changes_only_the_patch(comm):
    before = [[0.5, 0.0], [0.6, 0.0]]
    after = [[0.5, 0.0], [0.6, 0.0], [0.7, 0.02]]
    full = fracture_mesh(comm, DOM, network=network(before))
    patched = fracture_mesh(comm, DOM, network=network(after), previous=full, patch_radius=0.3)
    assert patched.remesh == "patch" and patched.fallback is None and patched.patch_cells > 0
    a0, a1 = gathered(comm, full.arrays), gathered(comm, patched.arrays)
    ref = fracture_mesh(comm, DOM, network=network(after))
    kept = None
    if comm.rank == 0:
        check_arrays(a1, 16.0)
        # every triangle but the patch's is an old one, vertex for vertex (Gmsh may also make a
        # few of the patch's triangles again as they were)
        k0 = {tuple(sorted(map(tuple, a0.nodes[t]))) for t in a0.tris}
        k1 = [tuple(sorted(map(tuple, a1.nodes[t]))) for t in a1.tris]
        kept = sum(k in k0 for k in k1)
        assert len(a0.tris) - patched.patch_cells <= kept < len(a0.tris)
        # the grown crack: its facets cover its new length, as in a full remesh of the new geometry
        for a in (a1, ref.arrays):
            e = a.lines[PATH]
            length = np.linalg.norm(a.nodes[e[:, 0]] - a.nodes[e[:, 1]], axis=1).sum()
            assert length == pytest.approx(0.1 + np.hypot(0.1, 0.02), rel=1e-12)
    kept = comm.bcast(kept, root=0)
    # the fields outside the patch are copied bit for bit: on the same rank, or (where the remesh
    # spread the cells over the ranks again) on another
    old, new = solver_on(full), solver_on(patched)
    old.set_initial_state(smooth)
    transfer_fields(old, new)
    same = 0
    dofs_old, dofs_new = compat.cell_dofs(old.V), compat.cell_dofs(new.V)
    U0, U1 = old.local_array().reshape(-1, 5), new.local_array().reshape(-1, 5)
    n0, n1 = compat.num_cells_local(full.mesh), compat.num_cells_local(patched.mesh)
    mine = [(tuple(sorted(map(tuple, v))), U0[dofs_old[c]]) for c, v in enumerate(old.geometry.vertices[:n0])]
    where = dict(mine) if not patched.rebalanced else {k: u for part in comm.allgather(mine) for k, u in part}
    for c, v in enumerate(new.geometry.vertices[:n1]):
        u = where.get(tuple(sorted(map(tuple, v))))
        if u is not None:
            assert sorted(map(tuple, U1[dofs_new[c]])) == sorted(map(tuple, u))
            same += 1
    assert comm.allreduce(same) == kept
    return patched


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial")
def test_an_extension_changes_only_the_patch():
    extension_changes_only_the_patch(MPI.COMM_WORLD)


@pytest.mark.mpi
def test_an_extension_changes_only_the_patch_on_2_ranks(monkeypatch):
    """... and the transfer moves only the patch's surroundings: the kept cells are copied from
    the rank's own old cells, so each rank holds fewer old cells than it owned (before, it held
    every old cell near the box of all its new cells: here more than it owned)."""
    from hydrofrac import transfer
    from hydrofrac.meshes import patch
    monkeypatch.setattr(patch, "REBALANCE_TOLERANCE", np.inf)  # every kept cell stays on its rank
    held = []
    exchange = transfer._exchange_near

    def counted(comm, old_cells, old_vertices, new_vertices):
        got = exchange(comm, old_cells, old_vertices, new_vertices)
        held.append((len(got[0]), len(old_vertices)))
        return got
    monkeypatch.setattr(transfer, "_exchange_near", counted)
    assert not extension_changes_only_the_patch(MPI.COMM_WORLD).rebalanced
    (got, owned), = held
    assert got < owned


def located_sets_carried_over(comm, monkeypatch):
    """Point sets located on the old mesh (the growth criterion's circles around the tips) and
    asked for again on the new one: the sets outside the patch are taken from the old location
    without a query, those in it are located again, and every set's location is the one a
    query on the new mesh gives, array for array."""
    from hydrofrac import probes
    before = [[0.5, 0.0], [0.6, 0.0]]
    full = fracture_mesh(comm, DOM, network=network(before))
    patched = fracture_mesh(comm, DOM, network=network(before + [[0.7, 0.02]]), previous=full, patch_radius=0.3)
    a = gathered(comm, full.arrays)
    corner = None
    if comm.rank == 0:  # an old vertex far from the patch and the middle of one of its edges
        x = a.nodes[:, :2]
        v = int(np.argmin(np.linalg.norm(x - [-1.2, 0.9], axis=1)))
        t = a.tris[np.flatnonzero((a.tris == v).any(axis=1))[0]]
        corner = np.array([x[v], 0.5 * (x[t[0]] + x[t[1]])])
    corner = comm.bcast(corner, root=0)
    angles = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    circle = np.column_stack([np.cos(angles), np.sin(angles)])
    sets = [[-1.0, -1.0] + 0.1 * circle, [0.6, 0.0] + 0.05 * circle, corner, [1.5, 1.2] + 0.2 * circle]
    old, new = solver_on(full), solver_on(patched)
    old.set_initial_state(smooth)
    probes.fields_at(old, sets)
    transfer_fields(old, new)
    queries = []
    real = probes.compat.cells_containing
    monkeypatch.setattr(probes.compat, "cells_containing", lambda m, X, c=None: queries.append(len(X)) or real(m, X, c))
    got = probes.fields_at(new, sets)
    assert queries == [24]  # the circle around the grown tip only
    monkeypatch.setattr(probes.compat, "cells_containing", real)
    carried = probes._located(new, [np.ascontiguousarray(X, dtype=float) for X in sets])
    fresh = probes._locate(new, [np.ascontiguousarray(X, dtype=float) for X in sets])
    for c, f in zip(carried, fresh):
        for x, y in zip(c, f):
            assert x.dtype == y.dtype and np.array_equal(x, y)
    assert comm.allreduce(sum(len(f[0]) for f in fresh)) > 24 * 3 + 2  # (the corner's points on several cells)
    assert all(np.isfinite(g).all() for g in got)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial")
def test_point_sets_outside_the_patch_stay_located(monkeypatch):
    located_sets_carried_over(MPI.COMM_WORLD, monkeypatch)


@pytest.mark.mpi
def test_point_sets_outside_the_patch_stay_located_on_2_ranks(monkeypatch):
    from hydrofrac.meshes import patch
    monkeypatch.setattr(patch, "REBALANCE_TOLERANCE", np.inf)  # every kept cell stays on its rank
    located_sets_carried_over(MPI.COMM_WORLD, monkeypatch)


@pytest.mark.mpi
def test_a_local_remesh_spreads_the_cells_again(monkeypatch):
    """Patch cells go to the ranks whose cells they replace, so the parts drift apart as cracks
    grow on some ranks; past REBALANCE_TOLERANCE a local remesh spreads the cells again
    (:func:`balanced_owners`): every rank then carries the same weight (cells, and
    CRACK_FACET_WEIGHT per crack facet of a cell) within one cell's, the mesh is the one the
    patch makes (cell for cell), and the kept cells' fields still move bit for bit, some to
    another rank (:func:`extension_changes_only_the_patch`)."""
    from hydrofrac.meshes import patch
    comm = MPI.COMM_WORLD
    monkeypatch.setattr(patch, "REBALANCE_TOLERANCE", -1.0)  # any remesh spreads them
    fm = extension_changes_only_the_patch(comm)
    assert fm.rebalanced and fm.arrays.owners is not None
    # what every rank owns now: the cells the owners sent it
    n = compat.num_cells_local(fm.mesh)
    sent = np.zeros(comm.size, np.int64)
    comm.Allreduce(np.bincount(fm.arrays.owners, minlength=comm.size).astype(np.int64), sent)
    assert n == sent[comm.rank]
    # the weights of the owned cells, from the mesh itself
    a = fm.arrays
    cells = comm.allgather((a.cells, a.owners, a.facets[np.isin(a.values, [NATURAL, PATH])]))
    crack = _edge_key(np.concatenate([c[2] for c in cells]))
    allc = np.concatenate([c[0] for c in cells])
    owner = np.concatenate([c[1] for c in cells])
    e = _edges(allc)
    w = 1 + patch.CRACK_FACET_WEIGHT * np.isin(_edge_key(e), crack).reshape(3, -1).sum(axis=0)
    load = np.bincount(owner, weights=w, minlength=comm.size)
    assert load.max() - load.min() <= w.max()
    assert comm.allreduce(n) == len(allc)
    # a checkpoint keeps the owners: the mesh made again from it has every cell on the same rank
    from hydrofrac.meshes.fractures import ROCK as rock
    again = patch.arrays_from_state(json.loads(json.dumps(patch.arrays_state(fm.arrays))))
    mesh, _, _ = patch.build(comm, again, rock)

    def owned(m):
        v = compat.cell_vertex_coords(m)[:compat.num_cells_local(m)]
        return sorted(tuple(sorted(map(tuple, c))) for c in v)
    assert owned(mesh) == owned(fm.mesh)


def test_balanced_owners_split_the_curve_evenly_whoever_holds_the_cells():
    """Distinct centroids: the owners are a function of the cells alone (not of the rank that
    holds them), each part carries the same weight within the largest cell's, and the parts
    follow the Z-order curve (each part's cells are a run of it)."""
    from hydrofrac.meshes.patch import _morton, balanced_owners
    comm = MPI.COMM_SELF
    rng = np.random.default_rng(3)
    c = rng.uniform(-2, 3, size=(1000, 2))
    w = rng.integers(1, 6, size=1000)
    own = balanced_owners(comm, c, 4, weights=w)
    perm = rng.permutation(1000)
    assert np.array_equal(balanced_owners(comm, c[perm], 4, weights=w[perm]), own[perm])
    load = np.bincount(own, weights=w, minlength=4)
    assert load.max() - load.min() <= 2 * w.max()
    key = _morton(np.floor((c - c.min(axis=0)) / (c.max(axis=0) - c.min(axis=0)).max() * 65535))
    assert np.all(np.diff(own[np.argsort(key)]) >= 0)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial: rank 0's arrays")
def test_a_patch_may_not_shorten_the_time_step(monkeypatch):
    """A patch keeps every cell outside it, so a small cell it makes (the smallest inradius sets
    dt) stays for the rest of the run.  A patch whose smallest cell is more than
    CELL_FLOOR_TOLERANCE (2 %) below the old mesh's is made again with PATCH_RETRY_RADIUS
    times the radius; if that one still is, it is checked against a full remesh of the same
    geometry: if the full mesh's smallest cell is 2 % larger, the full mesh is taken and the
    fallback says why; if not, the smaller cell is the new geometry's (a kink) and the patch
    stays."""
    from hydrofrac.meshes import patch
    from hydrofrac.meshes.patch import CELL_FLOOR_TOLERANCE as TOL, smallest_inradius as hmin
    comm = MPI.COMM_WORLD
    before = [[0.5, 0.0], [0.6, 0.0]]
    full = fracture_mesh(comm, DOM, network=network(before))
    h0 = hmin(full.arrays.nodes, full.arrays.tris)
    # a kink at the tip needs smaller cells, a full remesh's too: the patch stays
    kink = before + [[0.7, 0.02]]
    ok = fracture_mesh(comm, DOM, network=network(kink), previous=full, patch_radius=0.3)
    ref = fracture_mesh(comm, DOM, network=network(kink))
    assert ok.remesh == "patch" and ok.fallback is None
    a = gathered(comm, ok.arrays)
    assert hmin(a.nodes, a.tris) < (1 - TOL) * h0
    assert hmin(ref.arrays.nodes, ref.arrays.tris) <= (1 + TOL) * hmin(a.nodes, a.tris)
    # here the patch of radius 0.6 makes cells smaller than the geometry needs; the one of
    # twice the radius does not, and is taken
    bend = before + [[0.7, -0.05]]
    fm = fracture_mesh(comm, DOM, network=network(bend), previous=full, patch_radius=0.6)
    ref = fracture_mesh(comm, DOM, network=network(bend))
    assert fm.remesh == "patch" and fm.retried and fm.fallback is None
    a = gathered(comm, fm.arrays)
    assert hmin(a.nodes, a.tris) >= (1 - TOL) * h0
    # without the second patch the full mesh is taken
    monkeypatch.setattr(patch, "PATCH_RETRY_RADIUS", 1.0)
    fm = fracture_mesh(comm, DOM, network=network(bend), previous=full, patch_radius=0.6)
    assert fm.remesh == "full" and "smaller cell than a full remesh" in fm.fallback
    assert hmin(fm.arrays.nodes, fm.arrays.tris) == hmin(ref.arrays.nodes, ref.arrays.tris)
    # the first patch alone (radius 0.6) is the one whose cell is smaller
    monkeypatch.setattr(patch, "CELL_FLOOR_TOLERANCE", 1.0)
    first = fracture_mesh(comm, DOM, network=network(bend), previous=full, patch_radius=0.6)
    assert not first.retried
    a = gathered(comm, first.arrays)
    assert hmin(a.nodes, a.tris) < (1 - TOL) * h0


@pytest.mark.mpi
def test_a_patch_checked_against_a_full_remesh_on_2_ranks(monkeypatch):
    """The check of :func:`test_a_patch_may_not_shorten_the_time_step` is collective: the full
    mesh's arrays live on rank 0 only, and every rank takes the same mesh.  The second patch
    is taken on every rank too."""
    from hydrofrac.meshes import patch
    comm = MPI.COMM_WORLD
    before = [[0.5, 0.0], [0.6, 0.0]]
    full = fracture_mesh(comm, DOM, network=network(before))
    bend = network(before + [[0.7, -0.05]])
    fm = fracture_mesh(comm, DOM, network=bend, previous=full, patch_radius=0.6)
    assert all(r == ("patch", True, None) for r in comm.allgather((fm.remesh, fm.retried, fm.fallback)))
    monkeypatch.setattr(patch, "PATCH_RETRY_RADIUS", 1.0)
    fm = fracture_mesh(comm, DOM, network=bend, previous=full, patch_radius=0.6)
    assert all(r == ("full", True) for r in comm.allgather((fm.remesh, "smaller cell" in (fm.fallback or ""))))
    cells = comm.allreduce(compat.num_cells_local(fm.mesh), op=MPI.SUM)
    assert comm.rank != 0 or cells == len(fm.arrays.tris)


def test_local_remeshing_restarts_where_the_straight_run_ends(tmp_path, run_command, mpirun):
    script = "scenarios/intersection_regularized.py"
    args = ["--quick", "--growth-remesh", "patch", "--frames", "2", "--t-end", "1.1e-3"]
    straight, split = tmp_path / "straight", tmp_path / "split"
    run_command([*mpirun(2), script, *args, "--out", straight], timeout=600)
    s = json.loads((straight / "summary.json").read_text())
    assert s["accuracy"]["local_remeshes"] == s["accuracy"]["remeshes"] > 0
    run_command([*mpirun(2), script, *args[:-1], "9.8e-4", "--out", split], timeout=600)
    half = json.loads((split / "summary.json").read_text())["accuracy"]["remeshes"]
    assert 0 < half < s["accuracy"]["remeshes"]
    run_command([*mpirun(2), script, *args, "--out", split, "--restart"], timeout=600)
    r = json.loads((split / "summary.json").read_text())
    assert r["steps"] == s["steps"] and r["cells"] == s["cells"]
    for key in ("remeshes", "local_remeshes", "full_remesh_fallbacks", "grown_length"):
        assert r["accuracy"][key] == s["accuracy"][key], key
    # the restarted run's time per remesh is over the remeshes it timed itself, not the run's
    assert r["remeshing"]["remeshes_timed"] == s["accuracy"]["remeshes"] - half
    assert r["remeshing"]["per_remesh_s"] == pytest.approx(r["remeshing"]["wall_s"] / (s["accuracy"]["remeshes"] - half))
    for key in ("kinetic", "strain", "work_in", "balance_error"):
        assert r["energy"][key] == pytest.approx(s["energy"][key], rel=1e-12, abs=1e-12), key


def test_size_law_point_query_equals_the_vectorised_law():
    """The compiled one-point size query Gmsh calls inside a patch gives the vectorised law's
    sizes bit for bit (near cracks, near tips, at the wellbore, and beyond the grading, where
    the samples it drops would not be nearest)."""
    law = SizeLaw(h_crack=0.05, h_far=1.0, grading=2.0, wellbore_radius=0.1, h_tip=0.02, tip_radius=0.1)
    rng = np.random.default_rng(1)
    lines = {1: np.cumsum(rng.normal(size=(30, 2)), axis=0), 2: np.cumsum(rng.normal(size=(20, 2)), axis=0)}
    sizes = law.sampler(lines, tips=[(0.3, 0.4), (2.0, -1.0)])
    got = {}
    for lo, hi in [((-5.0, -5.0), (5.0, 5.0)), ((0.0, 0.0), (0.5, 0.5)), ((-20.0, -20.0), (-19.0, -19.0))]:
        xy = rng.uniform(lo, hi, size=(500, 2))
        one = sizes.scalar_near(lo, hi)
        got[lo] = np.array([one(x, y) for x, y in xy])
        assert np.array_equal(got[lo], sizes(xy))
        # the compiled callback Gmsh calls, on the same data packed into one array
        data = one.packed.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        assert np.array_equal([_size_callback.ctypes(2, 1, x, y, 0.0, data) for x, y in xy], got[lo])
    assert got[(-5.0, -5.0)].min() < 0.1 and got[(-5.0, -5.0)].max() == law.h_far  # graded, and far away
    assert np.all(got[(-20.0, -20.0)] == law.h_far)


def test_points_in_a_polygon_as_matplotlib_finds_them():
    """The compiled even-odd test that finds the islands inside a patch classifies points as
    matplotlib's Path does, for a polygon with concave corners."""
    from matplotlib.path import Path
    t = np.linspace(0.0, 2 * np.pi, 41)[:-1]
    r = 1.0 + 0.4 * np.sin(5 * t)  # a star: concave corners
    poly = np.stack([r * np.cos(t), r * np.sin(t)], axis=1)
    pts = np.random.default_rng(3).uniform(-1.5, 1.5, size=(4000, 2))
    inside = _in_polygon(pts, poly)
    assert 0.2 < inside.mean() < 0.8
    assert np.array_equal(inside, Path(poly).contains_points(pts))


@pytest.mark.parametrize("default, argv, expected", [
    ("patch", [], "patch"),  # the growth scenarios (intersection, re-fracture)
    ("patch", ["--adapt", "0.03"], "full"),  # adaptive meshes change the size field everywhere
    ("patch", ["--growth-remesh", "full"], "full"),
    ("full", [], "full"),  # a scenario that chooses full remeshes
    ("full", ["--growth-remesh", "patch"], "patch"),
])
def test_remesh_default_is_the_scenarios_and_full_with_adapt(default, argv, expected):
    """The growth options take the scenario's remesh default; with --adapt and no explicit
    choice it is the full remesh (a patch would be refused), and an explicit one is kept."""
    from hydrofrac import cli
    from hydrofrac.wellbore import Growth
    parser = cli.scenario_parser("test")
    cli.add_growth_arguments(parser, remesh=default)
    cli.add_adapt_arguments(parser)
    args = parser.parse_args(argv)
    cli.check_growth_arguments(parser, args)
    assert Growth.from_args(args).remesh == expected
    with pytest.raises(ValueError, match="'full' or 'patch'"):
        cli.add_growth_arguments(cli.scenario_parser("test"), remesh="local")


@pytest.mark.mpi
def test_no_rank_holds_the_whole_mesh_in_a_local_remesh():
    """A local remesh on 2 ranks: rank 0 receives only the region around the new segments, not
    the old mesh, and each rank makes the new mesh from its own part (no rank passes the whole
    mesh to DOLFINx); the result is the mesh a serial patch makes, cell for cell."""
    comm = MPI.COMM_WORLD
    dom = Domain(half_width=6.0, half_height=6.0, wellbore_radius=0.0, h_crack=0.05, h_far=0.4, grading=1.0)
    before = [[0.5, 0.0], [0.6, 0.0]]
    full = fracture_mesh(comm, dom, network=network(before))
    fm = fracture_mesh(comm, dom, network=network(before + [[0.7, 0.02]]), previous=full, patch_radius=0.3)
    assert fm.remesh == "patch" and fm.patch_cells > 0
    total = comm.allreduce(compat.num_cells_local(fm.mesh))
    region = comm.bcast(fm.region_cells, root=0)
    assert region < 0.5 * comm.allreduce(compat.num_cells_local(full.mesh))
    assert max(comm.allgather(len(fm.arrays.cells))) < 0.75 * total
    assert comm.allreduce(len(fm.arrays.cells)) == total
    # the same triangles as the serial patch of the same mesh
    a = gathered(comm, fm.arrays)
    mine = None
    if comm.rank == 0:
        one = MPI.COMM_SELF
        f1 = fracture_mesh(one, dom, network=network(before))
        b = fracture_mesh(one, dom, network=network(before + [[0.7, 0.02]]), previous=f1, patch_radius=0.3).arrays
        mine = ({tuple(sorted(map(tuple, a.nodes[t]))) for t in a.tris}
                == {tuple(sorted(map(tuple, b.x[t]))) for t in b.cells})
    assert comm.bcast(mine, root=0)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial")
def test_the_region_makes_the_patch_the_whole_mesh_makes(monkeypatch):
    """Rank 0 receives only the region around the patch's seeds (patch._region); the patch made
    from it is the one made from the whole old mesh, triangle for triangle, also where old crack
    edges lie inside the patch."""
    from hydrofrac.meshes import patch
    comm = MPI.COMM_WORLD
    before = [[0.5, 0.0], [0.6, 0.0]]  # (the old path and the natural fracture's end are in the patch)
    after = before + [[0.7, 0.02], [0.78, 0.06]]
    full = fracture_mesh(comm, DOM, network=network(before))
    small = fracture_mesh(comm, DOM, network=network(after), previous=full, patch_radius=0.3)
    monkeypatch.setattr(patch, "_region", lambda comm, cells, cxy, facets, *a, **k: (np.arange(len(cells)),
                                                                                     np.arange(len(facets))))
    whole = fracture_mesh(comm, DOM, network=network(after), previous=full, patch_radius=0.3)
    assert small.remesh == whole.remesh == "patch" and small.patch_cells == whole.patch_cells > 0
    assert 0 < small.region_cells < whole.region_cells
    a, b = small.arrays, whole.arrays
    assert ({tuple(sorted(map(tuple, a.x[t]))) for t in a.cells} == {tuple(sorted(map(tuple, b.x[t]))) for t in b.cells})


def test_crack_samples_are_linspace_per_segment_bit_for_bit():
    """The size law's samples along the cracks (one vectorised pass) are each segment's
    ``np.linspace(0, 1, n + 1)`` points, bit for bit: the patches Gmsh makes do not move."""
    from hydrofrac.meshes.patch import _samples
    rng = np.random.default_rng(3)
    lines = {k: np.cumsum(rng.uniform(-0.07, 0.07, (int(rng.integers(2, 9)), 2)), axis=0) for k in range(6)}
    lines[9] = np.array([[0.0, 0.0], [1e-4, 0.0]])  # shorter than a step: its two ends
    step = 0.03 / 8
    expected = [a + np.linspace(0.0, 1.0, max(int(np.ceil(np.linalg.norm(b - a) / step)), 1) + 1)[:, None] * (b - a)
                for line in lines.values() for a, b in zip(line[:-1], line[1:])]
    assert np.array_equal(_samples(lines, step), np.concatenate(expected))
    assert _samples({}, step).shape == (0, 2)


def test_region_membership_is_isin():
    """The region's rings test membership of node indices with a mask (:func:`_member`): the
    same as ``np.isin`` for any shapes, node sets larger or smaller than the cells' indices,
    and empty inputs."""
    rng = np.random.default_rng(7)
    for _ in range(100):
        a = rng.integers(0, rng.integers(1, 5000), size=(rng.integers(0, 400), rng.integers(1, 4)))
        nodes = np.unique(rng.integers(0, 7000, size=rng.integers(0, 600)))
        assert np.array_equal(_member(a, nodes), np.isin(a, nodes))


def test_nearest_sample_through_the_grid_is_the_brute_force_one():
    """The size law's nearest crack sample is searched through a grid of cells
    (:func:`_grid`, :func:`_nearest_sq_grid`): the squared distance equals the brute-force
    pass's bit for bit, for samples along lines, in clusters, on one line of cells, a single
    sample and none, at points inside the samples' box, on its cell edges and far outside."""
    from hydrofrac.meshes.patch import _grid, _nearest_sq, _nearest_sq_grid
    rng = np.random.default_rng(11)
    clouds = [np.cumsum(rng.normal(scale=0.05, size=(400, 2)), axis=0),  # a crack-like walk
              rng.normal(size=(50, 2)) * [3.0, 0.01],  # nearly one row of cells
              np.array([[0.3, -0.2]]), np.zeros((0, 2)),
              np.repeat(rng.uniform(-1, 1, size=(30, 2)), 5, axis=0)]  # repeated points
    for pts in clouds:
        for c in (0.01, 0.05, 0.3):
            ps, offs, g = _grid(np.ascontiguousarray(pts), c)
            lo, hi = (pts.min(axis=0), pts.max(axis=0)) if len(pts) else (np.zeros(2), np.ones(2))
            q = np.concatenate([rng.uniform(lo - 0.2, hi + 0.2, size=(300, 2)), rng.uniform(-50, 50, size=(20, 2)),
                                g[:2] + g[2] * rng.integers(-3, 8, size=(20, 2))])  # on cell edges
            for x, y in q:
                assert _nearest_sq_grid(x, y, ps, offs, g[0], g[1], g[2], int(g[3]), int(g[4])) == \
                    _nearest_sq(x, y, np.ascontiguousarray(pts))


def test_a_patch_with_a_hole_is_meshed_around_it():
    """A patch can hold a hole: old cells inside it that its region does not hold (an island
    wider than the region's rings, :func:`_region`), or the wellbore.  Here a crack grows in a
    square region with a square hole: the patch covers the region but the hole, with the
    crack's facets edges of its triangles.  The hole's loop, walked along the triangles' edges,
    comes out turning against the outer loop; given to Gmsh so, it made a face that
    OpenCASCADE's fragment did not cut with the crack, and the patch failed ("a crack is not
    embedded in the patch mesh"): the remesh retried with a larger patch or remeshed the whole
    domain (docs/benchmarks.md, "A patch with a hole")."""
    import gmsh

    from hydrofrac.meshes.patch import MeshArrays, _edges, _patch
    n = 10
    xs = np.linspace(0.0, 1.0, n + 1)
    nodes = np.column_stack([c.ravel() for c in np.meshgrid(xs, xs)])
    tris = []
    for j in range(n):
        for i in range(n):
            if not (3 <= i < 7 and 3 <= j < 7):  # (the hole: 0.4 x 0.4)
                a, b, c, d = j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i, (j + 1) * (n + 1) + i + 1
                tris += [(a, b, d), (a, d, c)]
    seg = (PATH, np.array([0.15, 0.2]), np.array([0.15, 0.6]))
    law = SizeLaw(h_crack=0.05, h_far=0.2, grading=0.3)
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        near, xy, new_t, lines, why = _patch(gmsh, MeshArrays(nodes, np.array(tris), {}), {PATH: np.array(seg[1:])},
                                             [seg], 5.0, law, crack_tags={PATH})
    finally:
        gmsh.finalize()
    assert why is None, why
    assert near.all()  # every old cell of the region is replaced
    p, q, r = xy[new_t[:, 0]], xy[new_t[:, 1]], xy[new_t[:, 2]]
    area = 0.5 * ((q - p)[:, 0] * (r - p)[:, 1] - (q - p)[:, 1] * (r - p)[:, 0])
    assert np.all(area > 0) and area.sum() == pytest.approx(1.0 - 0.16, rel=1e-12)  # the hole stays empty
    assert np.isin(_edge_key(lines[PATH]), _edge_key(_edges(new_t))).all() and len(lines[PATH]) >= 8
