"""Crack interfaces on 2 MPI ranks (verification.md cases 6, 8, 9 in parallel).

Run with ``mpirun -n 2 python -m pytest -m mpi tests/test_interface_mpi.py`` (``make
test-mpi``).  The tests also pass on one rank, where they check nothing parallel.
"""
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from hydrofrac import ROCK
from hydrofrac.interface import Crack, DamageParams, Interface, crack_facet_indices
from hydrofrac.solver import Solver

from helpers import (CRACK, check_shear_fracture, check_two_bars, kinked_crack_mesh, load_scenario, norm,
                     rhs_parts, step_problem, strip)

pytestmark = pytest.mark.mpi


def crosses_partition(iface):
    """True if some crack facet has its two cells on different ranks (a ghost cell)."""
    return iface.solver.comm.allreduce(bool(iface._ghosted_cells_with_flux), op=MPI.LOR)


@pytest.fixture
def shared_tmp():
    """A temporary folder that every rank sees (created on rank 0)."""
    comm = MPI.COMM_WORLD
    path = comm.bcast(tempfile.mkdtemp(prefix="hydrofrac_mpi_") if comm.rank == 0 else None, root=0)
    yield Path(path)
    comm.barrier()
    if comm.rank == 0:
        shutil.rmtree(path, ignore_errors=True)


@pytest.mark.parametrize("degree", [1, 3])
def test_kernel_equals_ufl_flux_parallel(degree):
    """Case 8 on the ranks of COMM_WORLD, with the crack polyline crossing the partition
    boundary: the D = 0 interface kernel equals the bulk UFL upwind flux (relative 1e-12 of
    the crack facets' contribution)."""
    comm = MPI.COMM_WORLD
    mesh, tags, n_crack = kinked_crack_mesh(comm, nx=24, ny=12)
    (a, b, c), iface = rhs_parts(mesh, tags, degree, seed=10 + degree)
    if comm.size > 1:
        owners = comm.allgather(iface.facets.size)
        assert sum(o > 0 for o in owners) >= 2, f"crack facets per rank {owners}: the crack must be split"
        assert crosses_partition(iface), "no crack facet has its cells on two ranks"
    assert comm.allreduce(iface.facets.size, op=MPI.SUM) == n_crack  # each facet counted once
    flux = norm(b - c, comm)
    err = norm(a - b, comm)
    assert flux > 0 and err <= 1e-12 * flux, f"kernel vs UFL: relative difference {err / flux:.3g}"


def test_two_bars_parallel(shared_tmp):
    """Case 9 on the ranks of COMM_WORLD (the scenario's main, in this process)."""
    tb = load_scenario("two_bars")
    summary = tb.main(["--quick", "--out", str(shared_tmp), "--frames", "2"])
    check_two_bars(summary["accuracy"])
    assert summary["ranks"] == MPI.COMM_WORLD.size


def test_shear_fracture_parallel(shared_tmp):
    """The shear-fracture demo on the ranks of COMM_WORLD at its --quick size."""
    sf = load_scenario("shear_fracture")
    summary = sf.main(["--quick", "--out", str(shared_tmp), "--frames", "2"])
    check_shear_fracture(summary["accuracy"])
    assert (shared_tmp / "vtk").is_dir() or any(shared_tmp.glob("*.pvd"))


def pulled_apart(comm, steps=10, scheme="rk4"):
    """Two-bar-like run with a bonded interface: the bars start moving apart (normal v0 =
    0.5 m/s, bonded traction Z_d v0 = 3.7 MPa > s_bar) and sliding (tangential 0.5 v0), on a
    traction-free strip, so that damage, opening, slip and all modes evolve.  Returns the
    Gauss points (m, 2) and the interface state and targets (m, k) gathered on rank 0."""
    mesh, tags = strip(comm, 1.0, 20)
    cracks = [Crack(CRACK, friction=0.6, damage=0.0)]
    solver = Solver(mesh, 2, ROCK, facet_tags=tags, crack_facets=crack_facet_indices(mesh, tags, cracks),
                    scheme=scheme)
    v0 = 0.5
    solver.set_initial_state(lambda x: np.vstack([np.where(x[0] < 0, -v0, v0), np.where(x[0] < 0, 0.5 * v0, -0.5 * v0)]
                                                 + [0 * x[0]] * 3), by_cell=True)
    iface = Interface(solver, tags, cracks, damage=DamageParams(tau=30e-6))
    solver.attach(iface)
    for _ in range(steps):
        solver.step()
    T = iface.last
    nfq = iface.facets.size * iface.nq
    data = np.column_stack([iface.state.reshape(3, -1).T, T["s_star"], T["vp_star"], T["vm_star"],
                            T["eta"], T["gamma"]]) if nfq else np.zeros((0, 11))
    pts = iface.points.reshape(-1, 2)
    parts = comm.gather((pts, data), root=0)
    crossing = crosses_partition(iface)
    if comm.rank != 0:
        return None, None, crossing
    pts = np.concatenate([p for p, _ in parts])
    data = np.concatenate([d for _, d in parts])
    order = np.lexsort(np.round(pts / 1e-9).T[::-1])
    return pts[order], data[order], crossing


@pytest.mark.parametrize("scheme", ["rk4", "ader"])
def test_interface_state_same_on_1_and_2_ranks(scheme):
    """Case 6 for the interface: the state (D, opening, slip) and the targets (s*, v*+-, eta,
    gamma) at every Gauss point are the same on COMM_WORLD and on one rank (relative
    difference < 1e-10 per quantity), matched by Gauss-point coordinates; under ADER too,
    whose flux into ghost cells travels to their owners before the corrector."""
    comm = MPI.COMM_WORLD
    pts_n, data_n, crossing = pulled_apart(comm, scheme=scheme)
    if comm.size > 1:
        assert crossing, "the crack must lie on the partition boundary for this test"
    ok, msg = True, ""
    if comm.rank == 0:
        pts_1, data_1, _ = pulled_apart(MPI.COMM_SELF, scheme=scheme)
        # mid-debonding: damage under way, opening and slip developed
        assert 0.2 < data_1[:, 0].min() and data_1[:, 0].max() < 0.99
        assert data_1[:, 1].min() > 0 and np.abs(data_1[:, 2]).min() > 0
        ok = pts_n.shape == pts_1.shape and np.abs(pts_n - pts_1).max() < 1e-12
        msg = "Gauss points differ"
        if ok:
            scale = np.maximum(np.abs(data_1).max(axis=0), 1e-300)
            rel = (np.abs(data_n - data_1) / scale).max(axis=0)
            ok = bool(np.all(rel < 1e-10))
            msg = f"relative differences per quantity {np.array2string(rel, precision=2)}"
    ok, msg = comm.bcast((ok, msg), root=0)
    assert ok, msg


def test_ader_predictor_kept_between_steps(monkeypatch):
    """ADER's corrector computes the next step's predictor.  Between steps the interface's
    targets and the energy budget read x's local form, which on several ranks raises x's PETSc
    state counter without changing x: the next step must still reuse that predictor (and x's
    ghosts), so a run of 20 steps computes it once, at its first step
    (:meth:`hydrofrac.solver.Solver.read_local`)."""
    from hydrofrac import matfree
    calls = []
    original = matfree.MatrixFreeOperator.ader_predictor

    def counted(self, *args):
        calls.append(1)
        return original(self, *args)

    monkeypatch.setattr(matfree.MatrixFreeOperator, "ader_predictor", counted)
    problem = load_scenario("two_bars").setup(degree=2, nx=20, scheme="ader")
    problem.solver.update_energy()
    step_problem(problem, 20)
    assert len(calls) == 1, f"the predictor was computed {len(calls)} times in 20 steps"


@pytest.mark.parametrize("scheme, cracks", [("rk4", True), ("ader", True), ("rk4", False)])
def test_time_split_keeps_the_halo_out_of_the_other_parts(scheme, cracks, monkeypatch):
    """Every ghost update of the state is timed as "halo exchange" and left out of the part
    around it: a stage's bulk operator, the end-of-step state update (with cracks) and the energy
    budget (without cracks, where it updates the ghosts itself).  Each update is slowed by 5 ms
    here, against stages of well under 1 ms: the halo exchange gets all of it, and the bulk
    operator's time stays positive and below it.  (A first version of this timing subtracted the
    exchange from the bulk operator before it had run, which made the bulk operator's time
    negative under rk4.)"""
    import time as _time
    from hydrofrac.boundary import Absorbing, Symmetry
    from hydrofrac.solver import Solver as _Solver
    from helpers import LEFT, RIGHT, SIDES
    comm = MPI.COMM_WORLD
    original = _Solver._forward
    slept = []

    def slow(vec):
        _time.sleep(0.005)
        slept.append(1)
        return original(vec)

    if cracks:
        problem = load_scenario("two_bars").setup(degree=2, nx=20, scheme=scheme)
        solver = problem.solver

        def steps(n):
            step_problem(problem, n)
    else:
        mesh, tags = strip(comm, 0.5, 40)
        solver = Solver(mesh, 2, ROCK, facet_tags=tags, scheme=scheme,
                        bcs=[Symmetry(SIDES), Absorbing(LEFT), Absorbing(RIGHT)])
        solver.set_initial_state(lambda x: np.vstack([np.exp(-(x[0] / 0.1) ** 2)] + [0 * x[0]] * 4))

        def steps(n):
            for _ in range(n):
                solver.step()
                solver.update_energy()
    solver.update_energy()
    steps(2)  # (the first steps may compile kernels)
    monkeypatch.setattr(_Solver, "_forward", staticmethod(slow))
    t = solver.timers.t
    t.clear()
    steps(10)
    if comm.size == 1:
        return
    assert len(slept) >= 10
    assert t["halo exchange"] >= 0.005 * len(slept), t
    assert 0 < t["bulk operator"] < 0.005 * len(slept), t
    # at least one slowed update a step falls at the end of the step (the state update with
    # cracks, the energy budget without): neither part holds half of those 10 x 5 ms
    assert t.get("state update", 0.0) < 0.025 and t.get("energy", 0.0) < 0.025, t
