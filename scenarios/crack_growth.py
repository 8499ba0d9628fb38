# # Free crack growth with remeshing: a crack in tension
#
# A traction-free crack of length 2a, inclined at `--angle` to the x axis, in rock
# under remote uniaxial tension σ along y (the initial stress, held by the absorbing
# outer boundary).  At t = 0 the crack faces lose their traction, the crack opens,
# and dynamic relaxation brings the plate towards its static state.
#
# Both tips grow in the direction that maximises the effective stress s̆ (model.md §6,
# `hydrofrac.growth`): every 10 steps, at each tip whose last segment has debonded,
# s̆(θ) is sampled at r = 4h ahead of the tip; where it reaches the damage onset s_ the
# tip advances by Δa = 2h as a bonded segment (D = 0), which the damage law then
# debonds.  Gmsh remeshes with the new segments embedded (fine at the cracks, coarse
# far away), and the fields and interface state are transferred (`hydrofrac.transfer`).
# Tips stop 2h before the boundary.
#
# A mode-I crack (`--angle 0`) grows straight; an inclined one kinks towards the plane
# normal to the tension, by the angle the criterion predicts (for 30°: −28.9° at
# r = 0.2a on the exact field; −43.2° from the singular field alone).
#
#     mpirun -n 2 python scenarios/crack_growth.py [--angle 30] [--quick] [--out DIR]
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

A, SIGMA = 1.0, 1.0e6
DAMAGE = DamageParams()  # s_ = 1 MPa, s̄ = 2 MPa, τ̃ = 30 µs


def make_builder(comm, angle, h, half, degree):
    """build((paths, tags)) -> Problem for this scene."""
    dom = Domain(half_width=half, half_height=half, wellbore_radius=0.0, h_crack=h, h_far=1.5, grading=2.0)
    return block_builder(comm, dom, [Fracture((0.0, 0.0), angle, 2 * A, friction=0.0)],
                         [Crack(0, friction=0.0, damage=1.0)], sigma0=[[0.0, 0.0], [0.0, SIGMA]],
                         degree=degree, damage=DAMAGE, relaxation=1500.0)


def setup(comm=MPI.COMM_WORLD, angle=30.0, quick=False, degree=2, record=None) -> Problem:
    """The first problem; ``problem.growth`` is the driver that grows both tips."""
    h, half = (0.1, 4.0) if quick else (0.05, 8.0)
    a = math.radians(angle)
    d = np.array([math.cos(a), math.sin(a)])
    tips = [Tip(A * d, d.copy()), Tip(-A * d, -d.copy())]
    margin = half - 2 * h
    driver = GrowthDriver(make_builder(comm, angle, h, half, degree), tips,
                          GrowthParams(r=4 * h), da=2 * h, threshold=DAMAGE.s_onset, tags=[PATH, PATH + 1],
                          inside=lambda p: abs(p[0]) < margin and abs(p[1]) < margin, domain_size=2 * half,
                          record=record)
    return driver.problem


class KinkMonitor(Monitor):
    """The grown length in the history; the first kink angle and grown length per tip."""

    def history(self, problem):
        g = problem.growth
        return {"grown_length": g.report()["grown_length"], "remeshes": g.count}

    def accuracy(self, problem):
        g, out = problem.growth, {}
        for i in range(2):
            ang = [e[2] for e in g.events if e[1] == i]
            if ang:
                out[f"tip{i}_first_kink_deg"] = ang[0]
                p = np.array(g.paths[i])
                out[f"tip{i}_grown_m"] = float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())
        return out

    def report(self, acc):
        return (f"[crack_growth] {acc['extensions']} extensions in {acc['remeshes']} remeshes; first kink "
                f"{acc.get('tip0_first_kink_deg', float('nan')):.1f}° / "
                f"{acc.get('tip1_first_kink_deg', float('nan')):.1f}°")


def run(problem, options: RunOptions):
    """Run with the kink measurements."""
    return run_problem(problem, options, name="crack_growth", monitors=[KinkMonitor()])


def main(argv=None):
    parser = cli.scenario_parser("Free crack growth with remeshing: an inclined crack in tension")
    parser.add_argument("--angle", type=float, default=30.0, help="crack inclination to the x axis [deg]")
    args = cli.parse(parser, argv, name="crack_growth", degree=2, t_end=(3.0e-3, 1.5e-3), frames=30)
    problem = setup(angle=args.angle, quick=args.quick, degree=args.degree, record=Path(args.out) / "growth.json")
    return run(problem, options=cli.run_options(args))


if __name__ == "__main__":
    main()
