# # A crack that meets a natural fracture: crossing or arrest
#
# A traction-free crack (0.5 m, debonded) ends on a natural fracture (1 m long, at
# `--angle` to the crack, friction `--friction`, damage `--damage`: 1 debonded, 0 bonded).
# The rock is under a tension T = 0.7 MPa normal to the crack (below the damage onset
# s_ = 1 MPa) and a compression P = 1 MPa along it, which presses the fracture closed.  At
# t = 0 the crack faces lose their traction and the crack's tip field builds up against the
# fracture.
#
# The tip is arrested on the fracture (docs/model.md §6, "Crossing or arrest").  Every
# check, the growth criterion is sampled on the far side of the fracture only, in the stress
# that the fracture's interface transmits in its current mode (bonded, stick, slip or
# separation: the Riemann solutions).  Where it reaches the onset, a new crack starts there:
# the crack crosses.  A bonded fracture transmits the tip's stress; a frictionless one in
# contact transmits no shear and slips, and the far side stays at the remote stress, below
# the onset; friction decides in between, through the stick and slip solutions.
#
# The criterion here is the tensile one (β = 0): with β = 1 the shear planes of the remote
# stress, (P + T)/2 = 0.85 MPa, would compete with the tip's own field.
#
#     mpirun -n 2 python scenarios/crossing.py [--friction 0.3] [--angle 90] [--damage 1] [--quick]
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from mpi4py import MPI

from hydrofrac import cli
from hydrofrac.block import block_builder
from hydrofrac.growth import GrowthDriver, GrowthParams, Tip
from hydrofrac.interface import Crack, DamageParams
from hydrofrac.meshes.fractures import PATH, Domain, Fracture
from hydrofrac.problem import Problem
from hydrofrac.run import Monitor, RunOptions
from hydrofrac.run import run as run_problem

T_REMOTE, P_REMOTE = 0.7e6, 1.0e6   # tension normal to the crack, compression along it [Pa]
CRACK, FRACTURE = 0.5, 1.0          # lengths [m]
X_MEET = 0.06                       # where the crack ends on the fracture [m]
DAMAGE = DamageParams()             # s_ = 1 MPa, s̄ = 2 MPa, τ̃ = 30 µs


def make_builder(comm, angle, friction, damage, h, degree):
    """build((paths, tags)) -> Problem for this scene."""
    dom = Domain(half_width=1.5, half_height=1.0, wellbore_radius=0.0, h_crack=h, h_far=0.2, grading=0.5)
    fractures = [Fracture((X_MEET - CRACK / 2, 0.0), 0.0, CRACK, friction=0.0),
                 Fracture((X_MEET, 0.0), angle, FRACTURE, friction=friction)]
    return block_builder(comm, dom, fractures, [Crack(0, friction=0.0, damage=1.0),
                                                Crack(0, friction=friction, damage=damage)],
                         sigma0=[[-P_REMOTE, 0.0], [0.0, T_REMOTE]], degree=degree, damage=DAMAGE)


def setup(comm=MPI.COMM_WORLD, angle=90.0, friction=0.0, damage=1.0, quick=False, degree=1,
          record=None) -> Problem:
    """The first problem; ``problem.growth`` is the driver (its one tip starts arrested)."""
    if not 0.0 < angle < 180.0:
        raise ValueError(f"crossing: --angle must be in (0, 180) degrees; got {angle}")
    if not friction >= 0.0:
        raise ValueError(f"crossing: --friction must be >= 0; got {friction}")
    if damage not in (0.0, 1.0):
        raise ValueError(f"crossing: --damage must be 0 (bonded) or 1 (debonded); got {damage}")
    h = 0.025
    a = math.radians(angle)
    e = np.array([math.cos(a), math.sin(a)])
    meet = np.array([X_MEET, 0.0])
    fracture = np.array([meet - 0.5 * FRACTURE * e, meet + 0.5 * FRACTURE * e])
    driver = GrowthDriver(make_builder(comm, angle, friction, damage, h, degree),
                          [Tip(meet.copy(), np.array([1.0, 0.0]))],
                          GrowthParams(r=4 * h, beta=0.0), da=2 * h, threshold=DAMAGE.s_onset, tags=[PATH],
                          check_every=2, inside=lambda p: abs(p[0]) < 1.2 and abs(p[1]) < 0.7,
                          obstacles=[fracture], record=record)
    return driver.problem


def outcome(driver):
    """'crossed' (time of the crossing [s]) or 'arrested' (None)."""
    ev = [e for e in driver.tree if e["event"] == "crossing"]
    return ("crossed", ev[0]["t"]) if ev else ("arrested", None)


class CrossingMonitor(Monitor):
    """The outcome in the summary and a closing line."""

    def accuracy(self, problem):
        what, t = outcome(problem.growth)
        return {"outcome": what, "t_cross": t}

    def report(self, acc):
        return f"[crossing] {acc['outcome']}" + (f" at {acc['t_cross'] * 1e6:.0f} µs" if acc["t_cross"] else "")


def run(problem, options: RunOptions):
    return run_problem(problem, options, name="crossing", monitors=[CrossingMonitor()])


def main(argv=None):
    parser = cli.scenario_parser("A crack meets a natural fracture: crossing or arrest")
    parser.add_argument("--angle", type=float, default=90.0, help="fracture angle to the crack [deg]")
    parser.add_argument("--friction", type=float, default=0.0, help="fracture friction coefficient")
    parser.add_argument("--damage", type=float, default=1.0, help="fracture damage: 1 debonded, 0 bonded")
    args = cli.parse(parser, argv, name="crossing", degree=1, t_end=(9e-4, 5e-4), frames=20)
    problem = setup(angle=args.angle, friction=args.friction, damage=args.damage, degree=args.degree,
                    quick=args.quick, record=Path(args.out) / "growth.json")
    return run(problem, options=cli.run_options(args))


if __name__ == "__main__":
    main()
