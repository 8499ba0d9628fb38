"""Case 6 (docs/verification.md): the same problem on COMM_WORLD and on COMM_SELF gives the
same fields and energy budget (relative difference < 1e-10).

Run on 2 ranks: ``mpirun -n 2 .venv/bin/python -m pytest -m mpi tests/test_parallel.py``
(on 1 rank the test passes trivially).  Every rank also runs the problem serially on its
own copy of the mesh; the parallel fields are matched to the serial ones cell by cell
(cell centroid) and node by node (DG node coordinates, unique within a cell).
"""
from __future__ import annotations

import numpy as np
import pytest
from mpi4py import MPI

import exact
from exact import BOTTOM, LEFT, RIGHT, TOP
from hydrofrac import CONFINEMENT, ROCK, Material, compat
from hydrofrac.boundary import Absorbing, PiecewiseLinear, Slider, Symmetry, Traction
from hydrofrac.solver import Solver

SIGMA0 = ((-CONFINEMENT, 0.0), (0.0, -CONFINEMENT))
MEDIUM2 = Material(E=40e9, nu=0.25, rho=2700.0, name="medium 2")
RTOL = 1e-10


def two_material_square(comm, N=8):
    """Unit square, rock for x < 1/2 and medium 2 for x > 1/2 (cell tags 1, 2), side tags."""
    mesh, ft = exact.unit_square(N, comm=comm)
    centroid = compat.cell_vertex_coords(mesh).mean(axis=1)
    ct = compat.meshtags(mesh, mesh.topology.dim, np.arange(centroid.shape[0]), np.where(centroid[:, 0] < 0.5, 1, 2))
    return mesh, ft, ct


def run_problem(comm, p=2, steps=30, scheme="rk4"):
    """Confined two-material block: pressure ramp on the left, absorbing right side, mirror
    top and bottom, a smooth disturbance in the initial state; ``steps`` steps of ``scheme``
    with the energy budget."""
    mesh, ft, ct = two_material_square(comm)
    history = PiecewiseLinear((0.0, 20e-6, 1.0), (0.0, 2e6, 2e6))
    bcs = [Traction(LEFT, stress=SIGMA0, pressure=history), Absorbing(RIGHT, stress=SIGMA0),
           Symmetry(BOTTOM), Slider(TOP)]
    solver = Solver(mesh, p, {1: ROCK, 2: MEDIUM2}, cell_tags=ct, facet_tags=ft, bcs=bcs, sigma0=SIGMA0,
                    scheme=scheme)
    solver.set_initial_state(exact.gaussian_bump(ROCK, (0.3, 0.6), 0.15, sigma0=SIGMA0))
    solver.update_energy()
    for _ in range(steps):
        solver.step()
        solver.update_energy()
    return solver


def owned_nodal_fields(solver):
    """{(centroid, node) rounded coordinates: (5,) values} over this rank's owned cells."""
    nloc = compat.num_cells_local(solver.mesh)
    dofs = compat.cell_dofs(solver.V)[:nloc]
    X = compat.dof_coordinates(solver.V)[:, :2]
    U = compat.function_array_of_vec(solver.x).reshape(-1, 5)
    centroid = solver.geometry.vertices[:nloc].mean(axis=1)
    out = {}
    for c in range(nloc):
        for d in dofs[c]:
            out[tuple(np.round(np.r_[centroid[c], X[d]], 9))] = U[d]
    return out


@pytest.mark.mpi
@pytest.mark.parametrize("scheme", ["rk4", "ader"])
def test_world_equals_self(scheme):
    comm = MPI.COMM_WORLD
    par = run_problem(comm, scheme=scheme)
    ser = run_problem(MPI.COMM_SELF, scheme=scheme)
    assert par.num_dofs == ser.num_dofs and par.dt == ser.dt
    fp, fs = owned_nodal_fields(par), owned_nodal_fields(ser)
    assert comm.allreduce(len(fp), op=MPI.SUM) == len(fs), "the ranks' owned cells do not cover the mesh"
    missing = [k for k in fp if k not in fs]
    assert not missing, f"rank {comm.rank}: {len(missing)} nodes without a serial counterpart, e.g. {missing[0]}"
    keys = list(fp)
    diff = np.array([fp[k] - fs[k] for k in keys]).reshape(-1, 5)
    s0 = np.array([0.0, 0.0, SIGMA0[0][0], SIGMA0[1][1], SIGMA0[0][1]])
    ref = np.abs(np.array(list(fs.values())) - s0)
    for name, cols in (("velocity", slice(0, 2)), ("stress", slice(2, 5))):
        scale = ref[:, cols].max()
        err = comm.allreduce(np.abs(diff[:, cols]).max(initial=0.0), op=MPI.MAX)
        assert scale > 0 and err <= RTOL * scale, f"{name}: max difference {err:.3e} vs field scale {scale:.3e}"
    ep, es = par.energy.as_dict(), ser.energy.as_dict()
    scale = abs(es["initial"]) + abs(es["work_in"])
    for key in ("kinetic", "strain", "work_in", "radiated", "dissipated_flux", "balance_error"):
        assert abs(ep[key] - es[key]) <= RTOL * scale, f"energy {key}: {ep[key]!r} on {comm.size} ranks vs {es[key]!r}"
