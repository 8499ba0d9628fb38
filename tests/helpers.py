"""Helpers shared by the tests: meshes, states and checks used by more than one test module.

(Tests import these, never another test module.)"""
from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from hydrofrac import ROCK, compat
from hydrofrac.interface import Crack, Interface, crack_facet_indices
from hydrofrac.loader import scenario as load_scenario  # noqa: F401
from hydrofrac.solver import Solver

CRACK, SIDES, LEFT, RIGHT = 10, 1, 2, 3


# --------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------
def strip(comm, L, nx):
    """Strip [-L, L] x [0, 2L/nx] of right-angled triangles (one cell row): the crack is the
    column of facets at x = 0; tags SIDES (top and bottom), LEFT and RIGHT (the ends)."""
    h = 2 * L / nx
    mesh = compat.create_rectangle(comm, (-L, 0.0), (L, h), nx, 1)
    crack = compat.locate_facets(mesh, lambda x: np.isclose(x[0], 0.0))
    sides = np.r_[compat.locate_boundary_facets(mesh, lambda x: np.isclose(x[1], 0.0)),
                  compat.locate_boundary_facets(mesh, lambda x: np.isclose(x[1], h))]
    left = compat.locate_boundary_facets(mesh, lambda x: np.isclose(x[0], -L))
    right = compat.locate_boundary_facets(mesh, lambda x: np.isclose(x[0], L))
    idx = np.r_[crack, sides, left, right]
    val = np.r_[np.full(crack.size, CRACK), np.full(sides.size, SIDES), np.full(left.size, LEFT),
                np.full(right.size, RIGHT)]
    idx, first = np.unique(idx, return_index=True)  # an end facet touches a side: keep one tag
    return mesh, compat.meshtags(mesh, 1, idx, val[first])


def facet_midpoints(mesh):
    """(num facets incl. ghosts, 2) midpoints of the facets."""
    off, arr = compat.connectivity(mesh, 1, 0)
    v2g = compat.vertex_to_geometry(mesh)
    x = mesh.geometry.x[:, :2]
    return 0.5 * (x[v2g[arr[off[:-1]]]] + x[v2g[arr[off[:-1] + 1]]])


def kinked_crack_mesh(comm, nx=16, ny=8):
    """A distorted rectangle mesh [0, 2] x [0, 1] with a crack polyline of several facets
    and two kinks: a horizontal run at y = 0.5, a diagonal run, then a vertical run (on the
    structured mesh), after which every vertex is moved by a smooth field, so that the crack
    facets point in many directions and the cells are no longer right-angled."""
    mesh = compat.create_rectangle(comm, (0.0, 0.0), (2.0, 1.0), nx, ny)
    h = 1.0 / ny
    mid = facet_midpoints(mesh)
    mx, my = mid[:, 0], mid[:, 1]
    horizontal = np.isclose(my, 0.5) & (mx > 0.3) & (mx < 1.0)
    # the diagonals of the "right" pattern run along x - y = const
    diagonal = np.isclose(mx - my, 0.5) & (mx > 1.0) & (mx < 1.25)
    vertical = np.isclose(mx, 1.25) & (my > 0.75) & (my < 0.9)
    crack = np.flatnonzero(horizontal | diagonal | vertical)
    n_global = comm.allreduce(int(compat.facet_owned_mask(mesh)[crack].sum()), op=MPI.SUM)
    tags = compat.meshtags(mesh, 1, crack, np.full(crack.size, CRACK))
    x = mesh.geometry.x
    X, Y = x[:, 0].copy(), x[:, 1].copy()
    x[:, 0] += 0.18 * h * np.sin(5.3 * X + 3.1 * Y + 0.4)
    x[:, 1] += 0.18 * h * np.cos(4.1 * X - 6.7 * Y + 1.3)
    return mesh, tags, n_global


def random_state(solver, seed=0):
    """A random state vector (v ~ 1 m/s, sigma ~ 10 MPa) with current ghosts."""
    rng = np.random.default_rng(seed + 1000 * solver.comm.rank)
    y = solver.x_like()
    own = compat.dof_counts(solver.V)[0]
    vals = rng.normal(size=(own, 5))
    vals[:, 2:] *= 1e7
    y.array[:] = vals.reshape(-1)
    y.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
    return y


def rhs_parts(mesh, tags, degree, seed):
    """Right-hand sides at a random state of (a) the solver with the crack facets carried by
    the interface kernel with D = 0, (b) the solver without cracks (bulk UFL upwind flux on
    those facets), (c) the solver with the crack facets carrying no flux at all.
    Returns the owned arrays (a, b, c) and the interface."""
    cracks = [Crack(CRACK, damage=0.0)]
    crack_idx = crack_facet_indices(mesh, tags, cracks)
    with_iface = Solver(mesh, degree, ROCK, facet_tags=tags, crack_facets=crack_idx)
    iface = Interface(with_iface, tags, cracks)
    with_iface.attach(iface)
    no_crack = Solver(mesh, degree, ROCK, facet_tags=tags)
    no_flux = Solver(mesh, degree, ROCK, facet_tags=tags, crack_facets=crack_idx)
    out = []
    for s in (with_iface, no_crack, no_flux):
        y = random_state(s, seed)
        r = s.x_like()
        if s is with_iface:
            iface.stage_state = iface.state.copy()
        s.rhs(y, 0.0, r)
        out.append(r.array_r.copy())
    return out, iface


def norm(a, comm):
    return np.sqrt(comm.allreduce(float(a @ a), op=MPI.SUM))


def step_problem(problem, steps):
    """``steps`` steps of a :class:`~hydrofrac.problem.Problem`: the step, the energy budget and
    the problem's own updates, the reads of the state a run makes between steps."""
    solver = problem.solver
    for _ in range(steps):
        solver.step()
        solver.update_energy()
        problem.after_step()


def check_two_bars(acc):
    assert acc["contact_stress_rel_error"] < 0.01
    assert abs(acc["contact_stress"] / -ROCK.Zd - 1) < 0.01  # against the exact -Z_d v0, v0 = 1
    assert abs(acc["duration_error_steps"]) <= 2
    assert abs(acc["duration_exact"] - 2 * 1.0 / ROCK.cd) < 1e-12
    assert acc["velocity_rel_error"] < 0.005
    assert abs(acc["energy_rel_change"]) < 0.01
    assert acc["penetration_max"] <= acc["penetration_allowed"] * (1 + 1e-9)


def assert_dynamics_hold_penetration(summary):
    """The contact band is resolved in time: the opening clip (a counted safety net) never
    acted, so the penetration bound checked beside this call is the dynamics' (docs/model.md §4)."""
    c = summary["contact"]
    assert c["clip_activations"] == 0, c
    assert c["max_penetration"] <= c["permitted_penetration_max"] * (1 + 1e-9), c


def check_shear_fracture(acc):
    assert acc["coulomb_ratio_max"] <= 1 + 1e-9
    assert acc["slipped"] and acc["slip_max"] > 0
    assert acc["friction_dissipation"] > 0
    assert abs(acc["energy_balance_error_relative"]) < 1e-2


def malloc_in_use_mb():
    """This process's heap memory in use [MB] (glibc's mallinfo2: what malloc handed out and
    was not freed, PETSc's, DOLFINx's and NumPy's alike; the resident size would keep freed
    pages), or None where the C library has no mallinfo2."""
    import ctypes

    class Info(ctypes.Structure):
        _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                   "fsmblks", "uordblks", "fordblks", "keepcost")]
    try:
        fn = ctypes.CDLL("libc.so.6").mallinfo2
    except (OSError, AttributeError):
        return None
    fn.restype = Info
    m = fn()
    return (m.uordblks + m.hblkhd) / 2**20
