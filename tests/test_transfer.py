"""Moving a run onto a new mesh (hydrofrac.transfer; issue 5's transfer checks).

* A polynomial field of degree p is moved exactly (round-off) between two different meshes
  of the same geometry: the interpolation evaluates the old cell's own polynomial.
* A remesh of an unchanged geometry (a different mesh: crack size 0.05a -> 0.04a) of the
  static cracked plate of ``test_growth`` (tension normal to the crack, p = 2, singular
  tips) changes the total energy by less than 0.5 %.
* Interface state that is piecewise constant per old facet is preserved exactly at matching
  arc length (new Gauss points on old facets get that facet's value).
"""
import gc

import numpy as np
import pytest
from mpi4py import MPI

from hydrofrac import ROCK, compat
from hydrofrac.adapt import carry_over
from hydrofrac.boundary import Absorbing
from hydrofrac.interface import Crack, Interface, crack_facet_indices
from hydrofrac.meshes.fractures import NATURAL, OUTER, Domain, Fracture, fracture_mesh
from hydrofrac.problem import Problem
from hydrofrac.run import RunOptions, run
from hydrofrac.solver import Solver
from hydrofrac.transfer import continue_run, transfer_fields, transfer_interface

A, SIGMA = 1.0, 1.0e6
S0 = np.array([[0.0, 0.0], [0.0, SIGMA]])


def cracked_plate(h, comm=MPI.COMM_WORLD, p=2, fm=None, attach=True):
    dom = Domain(half_width=8.0, half_height=8.0, wellbore_radius=0.0, h_crack=h, h_far=1.5, grading=2.0)
    fm = fm or fracture_mesh(comm, dom, fractures=[Fracture((0.0, 0.0), 0.0, 2 * A, friction=0.0)])
    cracks = [Crack(NATURAL, friction=0.0, damage=1.0)]
    solver = Solver(fm.mesh, p, ROCK, facet_tags=fm.facet_tags, sigma0=S0, bcs=[Absorbing(OUTER, stress=S0)],
                    crack_facets=crack_facet_indices(fm.mesh, fm.facet_tags, cracks), relaxation=1500.0)
    iface = Interface(solver, fm.facet_tags, cracks)
    if attach:
        solver.attach(iface)
    return solver, iface


@pytest.mark.parametrize("method", ["projection", "interpolation"])
def test_polynomial_field_moves_exactly(method):
    old, _ = cracked_plate(0.2, p=2)
    new, _ = cracked_plate(0.15, p=2)
    poly = lambda x: np.vstack([1 + x[0] * x[1], x[0] ** 2 - 2 * x[1], 3 * x[1] ** 2, x[0] - x[1], 0.5 * x[0] * x[0]])  # noqa: E731
    old.set_initial_state(poly)
    miss = transfer_fields(old, new, method=method)
    assert miss < 1e-9
    X = compat.dof_coordinates(new.V)[:, :2].T
    own = compat.dof_counts(new.V)[0]
    exact = poly(np.vstack([X, 0 * X[0]]))[:, :own].T
    err = np.abs(new.local_array() - exact).max() / np.abs(exact).max()  # values up to ~100 on the +-8 m box
    assert MPI.COMM_WORLD.allreduce(err, op=MPI.MAX) < 1e-12


def test_point_location_by_cell_finds_the_containing_cells():
    """The projection's point location (one tree query per new cell, then a compiled pass over
    its candidates) returns, for every quadrature point of the new mesh, an old cell that
    contains it (barycentric minimum >= -1e-12): the per-point search's cell wherever that
    one contains the point strictly, and a containing cell where the per-point search's 16
    nearest centroids miss it."""
    from scipy.spatial import cKDTree

    from hydrofrac.element import triangle_quadrature
    from hydrofrac.transfer import _locate, _locate_by_cell, _owned_cells
    if MPI.COMM_WORLD.size > 1:
        pytest.skip("serial: the candidate search of one rank")
    old, _ = cracked_plate(0.2, p=2)
    new, _ = cracked_plate(0.15, p=2)
    x0, Jinv, cent, _, _ = _owned_cells(old)
    x0, Jinv = np.ascontiguousarray(x0), np.ascontiguousarray(Jinv)
    tree = cKDTree(cent)
    g, n = new.geometry, compat.num_cells_local(new.mesh)
    Xq, wq = triangle_quadrature(2 * new.degree + 4)
    pts = (g.x0[:n, None, :] + np.einsum("cij,qj->cqi", g.J[:n], Xq)).reshape(-1, 2)
    cell, Xref, miss = _locate_by_cell(tree, x0, Jinv, pts, g.vertices[:n].mean(axis=1), wq.size, 16)
    ref_cell, _, _ = _locate(tree, x0, Jinv, pts, 16)
    inside = np.minimum(1 - Xref.sum(axis=1), Xref.min(axis=1))  # barycentric minimum in the chosen cell
    assert miss == 0.0 and inside.min() >= -1e-12, inside.min()
    r = np.einsum("nij,nj->ni", Jinv[ref_cell], pts - x0[ref_cell])
    strict = np.minimum(1 - r.sum(axis=1), r.min(axis=1)) > 1e-10
    assert np.array_equal(cell[strict], ref_cell[strict])


def test_point_location_finds_a_big_cell_beside_many_small_ones():
    """A point inside a big cell whose 16 nearest centroids are all small cells' (a graded
    mesh; the re-fracture's patches met this) lies in the big cell: the search goes on past the
    first 16 candidates until no cell left can hold the point.  With the first 16 only, the
    point took the nearest small cell's polynomial, extrapolated, and the answer depended on
    which old cells a rank held (a 1-vs-2-rank difference of 1 % in one cell)."""
    from scipy.spatial import cKDTree

    from hydrofrac.transfer import _locate
    big = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    small = []  # 40 cells of 0.02 beyond the big cell's long edge, near the point
    for i in range(40):
        c = np.array([0.5, 0.5]) + 0.03 * np.array([np.cos(i * 0.157) + 1.0, np.sin(i * 0.157) + 1.0])
        small.append(np.array([c, c + [0.02, 0.0], c + [0.0, 0.02]]))
    verts = np.array([big] + small)
    x0 = verts[:, 0]
    J = np.stack([verts[:, 1] - verts[:, 0], verts[:, 2] - verts[:, 0]], axis=2)
    Jinv = np.linalg.inv(J)
    cent = verts.mean(axis=1)
    pts = np.array([[0.49, 0.49], [0.2, 0.7], [0.1, 0.1]])
    _, near16 = cKDTree(cent).query(pts[:1], k=16)
    assert 0 not in near16  # (the case: the big cell is not among the first candidates)
    cell, Xref, miss = _locate(cKDTree(cent), x0, Jinv, pts, 16)
    assert miss == 0.0 and np.all(cell == 0), (cell, miss)
    np.testing.assert_allclose(Xref, pts, rtol=0, atol=1e-14)  # (the big cell's map is the identity)


def test_remesh_of_unchanged_geometry_keeps_energy():
    old, _ = cracked_plate(0.05)
    while old.t < 3e-3:
        old.step()
    old.update_energy()
    new, _ = cracked_plate(0.04)
    transfer_fields(old, new)
    before, after = continue_run(old, new)
    assert before > 0
    change = abs(after / before - 1)
    print(f"total energy before {before:.6g} J/m, after the transfer {after:.6g} J/m (change {change:.3%})")
    assert change < 5e-3


def frees_the_vectors_of_every_replaced_problem(tmp_path, comm):
    """A run whose remesh hook rebuilds the cracked plate's solver and crack on the same mesh
    at every step (the fields and crack state carried over): ``run`` frees the PETSc vectors of
    every problem it replaced, which petsc4py does not when Python drops them
    (:func:`hydrofrac.compat.destroy`), and memory in use stays flat."""
    from helpers import malloc_in_use_mb
    dom = Domain(half_width=8.0, half_height=8.0, wellbore_radius=0.0, h_crack=0.2, h_far=1.5, grading=2.0)
    fm = fracture_mesh(comm, dom, fractures=[Fracture((0.0, 0.0), 0.0, 2 * A, friction=0.0)])

    def problem():
        return Problem(*cracked_plate(0.2, comm, fm=fm, attach=False))
    vectors, in_use = [], []  # (the vectors of each replaced problem, not the problem: it must go)

    def remesh(old):
        new = problem()
        carry_over(old, new)
        vectors.append([old.solver.x, *old.solver._work, old.interface._r])
        gc.collect()
        in_use.append(malloc_in_use_mb())
        return new
    first = problem()
    dt, steps = first.solver.dt, 24
    run(first, RunOptions(t_end=steps * dt, out=str(tmp_path / "run"), frames=1, progress_wall=1e9), remesh=remesh)
    assert len(vectors) == steps
    assert all(v.handle == 0 for vs in vectors for v in vs), "a replaced problem's vector is still allocated"
    # memory in use over the last 16 remeshes (the first ones fill the caches): a problem's
    # vectors are x, 5 registers and the crack's residual; x alone is 0.1 MB on 1 rank here
    x_mb = first.solver.num_dofs * 8 / 2**20 / comm.size
    if in_use[0] is not None:
        growth = (in_use[-1] - in_use[-17]) / 16
        print(f"memory in use: {growth:.3f} MB a remesh; one state vector {x_mb:.3f} MB")
        assert growth < 0.5 * x_mb


def test_a_run_frees_the_vectors_of_every_replaced_problem(tmp_path):
    frees_the_vectors_of_every_replaced_problem(tmp_path, MPI.COMM_WORLD)


@pytest.mark.mpi
def test_a_run_frees_the_vectors_of_every_replaced_problem_on_2_ranks(tmp_path):
    from pathlib import Path
    frees_the_vectors_of_every_replaced_problem(Path(MPI.COMM_WORLD.bcast(str(tmp_path), root=0)), MPI.COMM_WORLD)


def frees_the_meshes_of_every_replaced_problem(tmp_path, comm):
    """A remesh driver (:class:`hydrofrac.adapt.RemeshDriver`) whose every remesh makes a new
    mesh of the cracked plate: the run keeps the first mesh (its writers use that mesh's
    communicator) and lets every later replaced mesh go."""
    import weakref

    from hydrofrac.adapt import RemeshDriver

    def problem():
        return Problem(*cracked_plate(0.2, comm, attach=False))

    class EveryStep(RemeshDriver):
        def __init__(self):
            self.meshes, self._first_mesh, self.count = [], [], 0
            self.problem = problem()

        def __call__(self, old):
            replaced.append(weakref.ref(old.solver.mesh))
            self.count += 1
            return self._adopt(old, problem())
    replaced = []
    driver = EveryStep()
    steps = 6
    run(driver.problem, RunOptions(t_end=steps * driver.problem.solver.dt, out=str(tmp_path / "run"), frames=1,
                                   progress_wall=1e9), remesh=driver)
    gc.collect()
    assert len(replaced) == steps
    assert replaced[0]() is not None, "the first mesh must stay: the run's writers use its communicator"
    assert all(m() is None for m in replaced[1:]), "a replaced mesh is still alive"


def test_a_run_frees_the_meshes_of_every_replaced_problem(tmp_path):
    frees_the_meshes_of_every_replaced_problem(tmp_path, MPI.COMM_WORLD)


@pytest.mark.mpi
def test_a_run_frees_the_meshes_of_every_replaced_problem_on_2_ranks(tmp_path):
    from pathlib import Path
    frees_the_meshes_of_every_replaced_problem(Path(MPI.COMM_WORLD.bcast(str(tmp_path), root=0)), MPI.COMM_WORLD)


def test_piecewise_constant_interface_state_is_preserved():
    old_s, old = cracked_plate(0.2)
    new_s, new = cracked_plate(0.13)
    rng = np.random.default_rng(1)
    # piecewise constant per old facet: one value per facet, a function of its midpoint
    mid = 0.5 * (old.va + old.vb)
    val = np.sin(7.0 * mid[:, 0]) + 2.0
    old.state[0] = 0.3 + 0.1 * val[:, None]   # damage
    old.state[1] = 1e-6 * val[:, None]        # opening
    old.state[2] = -2e-6 * val[:, None]       # slip
    old.min_opening = old.state[1].copy()
    del rng
    found = transfer_interface(old, new)
    total = MPI.COMM_WORLD.allreduce(new.facets.size * new.nq, op=MPI.SUM)
    assert found == total  # every new Gauss point lies on an old facet (same crack line)
    # expected: the value of the old facet containing each new Gauss point
    fn = lambda x: np.sin(7.0 * x) + 2.0  # noqa: E731
    parts = MPI.COMM_WORLD.allgather((old.va, old.vb))
    va = np.concatenate([p[0] for p in parts]).reshape(-1, 2)
    vb = np.concatenate([p[1] for p in parts]).reshape(-1, 2)
    lo, hi = np.minimum(va[:, 0], vb[:, 0]), np.maximum(va[:, 0], vb[:, 0])
    for f in range(new.facets.size):
        for q in range(new.nq):
            x = new.points[f, q, 0]
            g = np.flatnonzero((lo <= x + 1e-12) & (x <= hi + 1e-12))[0]
            v = fn(0.5 * (va[g, 0] + vb[g, 0]))
            assert new.state[0, f, q] == 0.3 + 0.1 * v
            assert new.state[1, f, q] == 1e-6 * v
            assert new.state[2, f, q] == -2e-6 * v


@pytest.mark.mpi
def test_transfer_parallel():
    """The same checks on 2 ranks (old cells gathered, every rank fills its own new cells)."""
    test_polynomial_field_moves_exactly("projection")
    test_piecewise_constant_interface_state_is_preserved()


@pytest.mark.mpi
def test_each_rank_receives_only_the_old_cells_near_its_new_cells():
    """On 2 ranks the transfer sends each rank the old cells near its own new cells, not the
    whole old mesh: fewer than all on each rank here, yet every new quadrature point still lies
    in a received old cell (the polynomial field moves exactly, as with the whole old mesh)."""
    from hydrofrac.element import triangle_quadrature
    from hydrofrac.transfer import _exchange_near, _inside_candidates, _owned_cells
    comm = MPI.COMM_WORLD
    old, _ = cracked_plate(0.2, p=2)
    new, _ = cracked_plate(0.15, p=2)
    n_old, n_new = compat.num_cells_local(old.mesh), compat.num_cells_local(new.mesh)
    x0, Jinv, cent, U, _ = _exchange_near(comm, _owned_cells(old), old.geometry.vertices[:n_old],
                                       new.geometry.vertices[:n_new])
    total = comm.allreduce(n_old, op=MPI.SUM)
    if comm.size > 1:
        assert x0.shape[0] < total
    # every quadrature point of this rank's new cells lies in a received old cell
    from scipy.spatial import cKDTree

    from hydrofrac.transfer import _locate
    Xq, _ = triangle_quadrature(2 * new.degree + 4)
    g = new.geometry
    pts = (g.x0[:n_new, None, :] + np.einsum("cij,qj->cqi", g.J[:n_new], Xq)).reshape(-1, 2)
    _, _, miss = _locate(cKDTree(cent), x0, Jinv, pts, 16)
    assert miss < 1e-9
    test_polynomial_field_moves_exactly("projection")
