# # Two bars closing: contact by Riemann solutions, no penalty
#
# Two identical rock bars, each of length L, touch at x = 0 with zero stress and
# close at ±v₀.  The interface between them is a fully debonded crack (D = 1)
# with the regularised contact fraction η of model.md §4.  The exact answer
# (verification.md, case 9):
#
# * contact stress σ = −Z_d v₀ (compression) while in contact,
# * contact duration 2L/c_d (the release waves from the free ends come back),
# * after separation the bars fly apart with exactly reversed velocities,
# * no energy is lost, and the penetration never exceeds |δ'₀| δ̃.
#
# Rock, L = 1 m, v₀ = 1 m/s: σ = −7.454 MPa, duration 0.6708 ms.
#
# The strip is in plane strain with roller (symmetry) sides, so the solution is
# one-dimensional.  Run it with
#
#     mpirun -n 2 python scenarios/two_bars.py [--quick] [--out DIR] [--delta0 D]
from __future__ import annotations

import numpy as np
from mpi4py import MPI

from hydrofrac import ROCK, cli, compat
from hydrofrac.boundary import Symmetry
from hydrofrac.interface import ContactParams, Crack, Interface, crack_facet_indices
from hydrofrac.network import CrackLine, CrackNetwork
from hydrofrac.problem import Problem
from hydrofrac.run import Monitor, RunOptions
from hydrofrac.run import run as run_problem
from hydrofrac.solver import Solver

CRACK, SIDES, ENDS = 10, 1, 2


# ## Geometry
# A strip [−L, L] × [0, H] of right-angled triangles; the crack is the column of
# facets at x = 0, the top and bottom are symmetry planes, the ends are free.
def make_mesh(comm, L, nx, ends=False):
    """The strip; ``ends`` also tags the two ends x = ±L (ENDS), for a strip held at its ends."""
    h = 2 * L / nx
    mesh = compat.create_rectangle(comm, (-L, 0.0), (L, h), nx, 1)
    crack = compat.locate_facets(mesh, lambda x: np.isclose(x[0], 0.0))
    # (one marker per side: a marker sees single vertices, and an end facet has one on each side)
    sides = np.r_[compat.locate_boundary_facets(mesh, lambda x: np.isclose(x[1], 0.0)),
                  compat.locate_boundary_facets(mesh, lambda x: np.isclose(x[1], h))]
    idx, val = np.r_[crack, sides], np.r_[np.full(crack.size, CRACK), np.full(sides.size, SIDES)]
    if ends:
        e = compat.locate_boundary_facets(mesh, lambda x: np.isclose(np.abs(x[0]), L))
        e = np.setdiff1d(e, sides)
        idx, val = np.r_[idx, e], np.r_[val, np.full(e.size, ENDS)]
    return mesh, compat.meshtags(mesh, 1, idx, val)


# ## Model
# The bars start at rest-stress with velocity +v₀ (left) and −v₀ (right).  The
# crack starts closed with zero opening (δ = 0): touching, not pressed.
#
# A variant (`gap_steps`) starts the bars apart, by the distance they close in that many CFL
# steps: with a half-integer the gap shuts in the middle of a step (the contact studies and
# tests); `contact` sets the contact map (exact or regularised, δ'₀, the opening clip).  The
# bars close at the velocity jump 2v₀: with `delta0=None` δ'₀ is resolved so that the band
# spans 3 steps at that speed (docs/model.md §4).
def setup(comm=MPI.COMM_WORLD, degree=3, nx=80, L=1.0, v0=1.0, delta0=-0.01, material=ROCK, gap_steps=0.0,
          contact=None, cfl=None, scheme="rk4") -> Problem:
    mesh, tags = make_mesh(comm, L, nx)
    gap = 0.0
    if gap_steps:
        gap = gap_steps * 2 * v0 * Solver(mesh, degree, material, facet_tags=tags, bcs=[Symmetry(SIDES)]).dt
    cracks = [Crack(CRACK, friction=0.0, damage=1.0, opening=gap)]
    solver = Solver(mesh, degree, material, facet_tags=tags, bcs=[Symmetry(SIDES)], cfl=cfl, scheme=scheme,
                    crack_facets=crack_facet_indices(mesh, tags, cracks))
    solver.set_initial_state(lambda x: np.vstack([np.where(x[0] < 0, v0, -v0)] + [0 * x[0]] * 4), by_cell=True)
    h = 2 * L / nx
    network = CrackNetwork.from_cracks([CrackLine(CRACK, "natural", [(0.0, 0.0), (0.0, h)])])
    contact = ContactParams(delta0=delta0, closing_speed=2 * v0) if contact is None else contact
    return Problem(solver, Interface(solver, tags, cracks, contact=contact), network=network, facet_tags=tags)


# ## Measurements against the exact answer
# We record the mean interface traction and contact fraction after every step.
class Recorder(Monitor):
    checkpointed = ("t", "sn", "eta")

    def __init__(self, L=1.0, v0=1.0):
        self.L, self.v0 = L, v0
        self.t, self.sn, self.eta = [], [], []

    def __call__(self, problem):
        T, comm = problem.interface.last, problem.comm
        n = comm.allreduce(T["eta"].size, op=MPI.SUM)
        self.t.append(problem.t)
        self.sn.append(comm.allreduce(float(T["s_star"][:, 0].sum()), op=MPI.SUM) / n)
        self.eta.append(comm.allreduce(float(T["eta"].sum()), op=MPI.SUM) / n)

    def accuracy(self, problem):
        return accuracy(problem.solver, problem.interface, self, self.L, self.v0)

    def report(self, acc):
        return (f"[two_bars] contact stress {acc['contact_stress'] / 1e6:.4f} MPa "
                f"(exact {acc['contact_stress_exact'] / 1e6:.4f} MPa)")


def bar_velocity(solver, side):
    """Mean x-velocity (momentum / mass) of the left (side < 0) or right bar."""
    d = solver.x.copy()
    Md = d.duplicate()
    solver.M.mult(d, Md)
    own = Md.array_r.reshape(-1, 5)
    dofs = compat.cell_dofs(solver.V)[: compat.num_cells_local(solver.mesh)]
    cent = solver.geometry.vertices[: dofs.shape[0]].mean(axis=1)[:, 0]
    sel = np.zeros(own.shape[0], bool)
    sel[dofs[(cent < 0) if side < 0 else (cent > 0)].reshape(-1)] = True
    mom = solver.comm.allreduce(float(own[sel, 0].sum()), op=MPI.SUM)
    ones = d.duplicate()
    ones.array[:] = np.tile([1.0, 0, 0, 0, 0], own.shape[0])
    solver.M.mult(ones, Md)
    mass = solver.comm.allreduce(float(Md.array_r.reshape(-1, 5)[sel, 0].sum()), op=MPI.SUM)
    return mom / mass


def accuracy(solver, iface, rec, L, v0):
    mat = solver.materials[0]
    t, sn, eta = map(np.asarray, (rec.t, rec.sn, rec.eta))
    contact = eta > 0.5
    if not contact.any():
        return {"error": "no contact happened"}
    t_first, t_last = t[contact][0], t[contact][-1]
    duration = t_last - t_first + solver.dt  # steps in contact
    mid = contact & (t > t_first + 0.25 * duration) & (t < t_first + 0.75 * duration)
    plateau = float(sn[mid].mean())
    exact_s, exact_T = -mat.Zd * v0, 2 * L / mat.cd
    v_left, v_right = bar_velocity(solver, -1), bar_velocity(solver, +1)
    e = solver.energy
    local = float(iface.delta_scale.max()) if iface.delta_scale.size else 0.0
    pen_max = abs(iface.contact.delta0) * solver.comm.allreduce(local, op=MPI.MAX)
    return {
        "contact_stress": plateau, "contact_stress_exact": exact_s,
        "contact_stress_rel_error": abs(plateau / exact_s - 1),
        "duration": duration, "duration_exact": exact_T,
        "duration_error_steps": (duration - exact_T) / solver.dt,
        "velocity_left": v_left, "velocity_right": v_right,
        "velocity_rel_error": max(abs(v_left + v0), abs(v_right - v0)) / v0,
        "energy_rel_change": (e.total - e.initial) / e.initial,
        "penetration_max": iface.max_penetration(), "penetration_allowed": pen_max,
    }


def run(problem, options: RunOptions, L=1.0, v0=1.0):
    """Run with the contact measurements."""
    return run_problem(problem, options, name="two_bars", monitors=[Recorder(L, v0)])


def main(argv=None):
    parser = cli.scenario_parser("Two bars closing at ±v0: contact stress, duration, rebound")
    parser.add_argument("--delta0", type=cli.delta0_type, default=-0.01,
                        help="maximum normalised penetration δ'₀ < 0, or 'resolved': the band spans 3 steps at "
                             "the closing speed 2 v0 (docs/model.md §4)")
    # --quick: the coarsest size that meets the case-9 tolerances, run just past separation
    args = cli.parse(parser, argv, name="two_bars", degree=3, t_end=(1.0e-3, 0.75e-3), frames=20)
    L, v0 = 1.0, 1.0
    problem = setup(degree=args.degree, nx=80 if args.quick else 160, L=L, v0=v0, delta0=args.delta0)
    return run(problem, L=L, v0=v0, options=cli.run_options(args))


if __name__ == "__main__":
    main()
