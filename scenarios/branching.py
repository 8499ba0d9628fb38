# # A fast crack that branches
#
# A traction-free crack (0.5 m, debonded) in a block under a tension `--tension` T normal to
# it runs straight ahead (docs/model.md §6).  The block's absorbing sides hold an outer state
# with an extra compression of 4 MPa along the crack: it enters from the sides as a plane
# wave and reaches the running tip after ~400 µs.  The crack-parallel compression gives the
# criterion s̆(θ) (β = 1) two maxima, near ±45°.
#
# Branching (docs/model.md §6, "Branching"): a tip running at `--branch-speed` or faster
# (default 0.5 c_R) with two separated maxima above the onset splits into two tips, one along
# each.  Under T = 0.8 MPa the tip runs at ~1000 m/s when the compression arrives and
# branches; under T = 0.7 MPa it runs at ~600 m/s and turns along one maximum only.
#
#     mpirun -n 2 python scenarios/branching.py [--tension 0.8e6] [--quick] [--out DIR]
from __future__ import annotations

from pathlib import Path

import numpy as np
from mpi4py import MPI

from hydrofrac import cli
from hydrofrac.block import block_builder
from hydrofrac.growth import BRANCH_SPEED, GrowthDriver, GrowthParams, Tip
from hydrofrac.interface import Crack, DamageParams
from hydrofrac.meshes.fractures import PATH, Domain, Fracture
from hydrofrac.problem import Problem
from hydrofrac.run import Monitor, RunOptions
from hydrofrac.run import run as run_problem

COMPRESSION = 4.0e6              # the outer state's extra compression along the crack [Pa]
HALF_WIDTH, HALF_HEIGHT, H = 1.5, 1.0, 0.025
DAMAGE = DamageParams()          # s_ = 1 MPa, s̄ = 2 MPa, τ̃ = 30 µs


def make_builder(comm, tension, degree):
    dom = Domain(half_width=HALF_WIDTH, half_height=HALF_HEIGHT, wellbore_radius=0.0, h_crack=H, h_far=0.2,
                 grading=0.5)
    return block_builder(comm, dom, [Fracture((-0.25, 0.0), 0.0, 0.5, friction=0.0)],
                         [Crack(0, friction=0.0, damage=1.0)], sigma0=[[0.0, 0.0], [0.0, tension]],
                         outer_stress=[[-COMPRESSION, 0.0], [0.0, tension]], degree=degree, damage=DAMAGE)


def setup(comm=MPI.COMM_WORLD, tension=0.8e6, branch_speed=BRANCH_SPEED, degree=1, record=None) -> Problem:
    """The first problem; ``problem.growth`` is the driver of the one tip at the origin."""
    if not 0 < tension < DAMAGE.s_onset:
        raise ValueError(f"branching: --tension must be in (0, s_ = {DAMAGE.s_onset:g}) Pa; got {tension}")
    mx, my = HALF_WIDTH - 0.3, HALF_HEIGHT - 0.3
    driver = GrowthDriver(make_builder(comm, tension, degree), [Tip(np.array([0.0, 0.0]), np.array([1.0, 0.0]))],
                          GrowthParams(r=4 * H, branch_speed=branch_speed), da=2 * H, threshold=DAMAGE.s_onset,
                          tags=[PATH], check_every=2, inside=lambda p: abs(p[0]) < mx and abs(p[1]) < my,
                          record=record)
    return driver.problem


class BranchMonitor(Monitor):
    """The branch events in the summary and a closing line."""

    def accuracy(self, problem):
        br = [e for e in problem.growth.tree if e["event"] == "branch"]
        return {"branch_t": br[0]["t"] if br else None, "branch_angles_deg": br[0]["angle_deg"] if br else None,
                "branch_speed": br[0]["speed"] if br else None}

    def report(self, acc):
        if acc["branch_t"] is None:
            return f"[branching] no branch; fastest extension {acc['tip_speed_max']:.0f} m/s"
        a, b = acc["branch_angles_deg"]
        return (f"[branching] branched at {acc['branch_t'] * 1e6:.0f} µs, {acc['branch_speed']:.0f} m/s, "
                f"into {a:.1f}° and {b:.1f}°")


def run(problem, options: RunOptions):
    return run_problem(problem, options, name="branching", monitors=[BranchMonitor()])


def main(argv=None):
    parser = cli.scenario_parser("A fast crack that branches")
    parser.add_argument("--tension", type=float, default=0.8e6, help="remote tension normal to the crack [Pa]")
    parser.add_argument("--branch-speed", type=float, default=BRANCH_SPEED,
                        help=f"speed a tip needs to branch [m/s] (default 0.5 c_R = {BRANCH_SPEED:.0f})")
    args = cli.parse(parser, argv, name="branching", degree=1, t_end=(7e-4, 5.2e-4), frames=20)
    if not args.branch_speed > 0:
        parser.error(f"--branch-speed must be > 0 m/s; got {args.branch_speed}")
    problem = setup(tension=args.tension, branch_speed=args.branch_speed, degree=args.degree,
                    record=Path(args.out) / "growth.json")
    return run(problem, options=cli.run_options(args))


if __name__ == "__main__":
    main()
