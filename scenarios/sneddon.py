# # Sneddon's pressurised crack (verification.md, case 11)
#
# A straight crack of half-length a in confined rock (σ₀ = −p₀ I) is loaded by a
# fluid pressure p_h that ramps slowly from p₀ to p₀ + Δp and is then held.  In
# the static limit the crack opens as (plane strain)
#
#     w(x) = 4 (1 − ν²) Δp / E · √(a² − x²),      w(0) = 0.192 mm for a = 1 m, Δp = 1 MPa.
#
# The crack is a hydraulic source (f_p = 1), so its separation traction is
# S¹ = −p_h (model.md eq. 16); the opening is the interface state δ, integrated
# from the Riemann target velocities.  The ramp is long compared with a/c_s and
# the outer boundary absorbs the waves; a dynamic-relaxation damping (ρ v̇ = ∇·σ − c ρ v,
# `--relaxation c`, reported separately in the energy budget) removes the slow
# ringing of the box, so the run settles to the static state within a few ms.
#
#     mpirun -n 2 python scenarios/sneddon.py [--quick] [--out DIR]
from __future__ import annotations

import numpy as np
from mpi4py import MPI

from hydrofrac import CONFINEMENT, ROCK, cli
from hydrofrac.boundary import Absorbing, PiecewiseLinear
from hydrofrac.hydraulics import HydraulicParams
from hydrofrac.interface import Crack, Interface, crack_facet_indices
from hydrofrac.meshes.fractures import NATURAL, OUTER, Domain, Fracture, fracture_mesh
from hydrofrac.network import CrackLine, CrackNetwork
from hydrofrac.problem import Problem
from hydrofrac.run import Monitor, RunOptions
from hydrofrac.run import run as run_problem
from hydrofrac.solver import Solver


def exact_opening(x, a, dp, mat=ROCK):
    return 4 * (1 - mat.nu ** 2) * dp / mat.E * np.sqrt(np.maximum(a * a - x * x, 0.0))


# ## Set-up
# The crack lies on the x axis; the box is R = `size` a wide on each side.
def make_mesh(comm, a=1.0, size=6.0, h_crack=0.05, h_far=1.0):
    dom = Domain(half_width=size * a, half_height=size * a, wellbore_radius=0.0, h_crack=h_crack * a,
                 h_far=h_far * a, grading=2.0 * a)
    return fracture_mesh(comm, dom, fractures=[Fracture((0.0, 0.0), 0.0, 2 * a)])


def pressure_ramp(p0, dp, t_ramp):
    """p0 -> p0 + dp along a smoothstep sampled at 41 points: no kink that rings the crack."""
    xi = np.linspace(0.0, 1.0, 41)
    return PiecewiseLinear(t_ramp * xi, p0 + dp * xi * xi * (3 - 2 * xi))


def setup(comm=MPI.COMM_WORLD, degree=2, a=1.0, dp=1.0e6, p0=CONFINEMENT, size=6.0, h_crack=0.05,
          h_far=1.0, t_ramp=1.0e-3, relaxation=0.0) -> Problem:
    fm = make_mesh(comm, a, size, h_crack, h_far)
    sigma0 = -p0 * np.eye(2)
    cracks = [Crack(NATURAL, friction=0.0, damage=1.0)]
    solver = Solver(fm.mesh, degree, ROCK, facet_tags=fm.facet_tags, sigma0=sigma0,
                    bcs=[Absorbing(OUTER, stress=sigma0)],
                    crack_facets=crack_facet_indices(fm.mesh, fm.facet_tags, cracks), relaxation=relaxation)
    iface = Interface(solver, fm.facet_tags, cracks)
    hyd = HydraulicParams(pressure=pressure_ramp(p0, dp, t_ramp), sources=[NATURAL], regularized=False)
    network = CrackNetwork.from_cracks([CrackLine(NATURAL, "natural", fm.lines[NATURAL])])
    return Problem(solver, iface, hyd, network=network, facet_tags=fm.facet_tags)


# ## Accuracy: L2 error of the opening away from the tips (|x| < 0.9 a)
def opening_error(solver, iface, a, dp):
    pts = iface.points.reshape(-1, 2)
    w = iface.weights.reshape(-1)
    delta = iface.state[1].reshape(-1) - (iface.contact.delta0 * np.repeat(iface.delta_scale, iface.nq))
    sel = np.abs(pts[:, 0]) < 0.9 * a
    ex = exact_opening(pts[sel, 0], a, dp)
    comm = solver.comm
    num = comm.allreduce(float((w[sel] * (delta[sel] - ex) ** 2).sum()), op=MPI.SUM)
    den = comm.allreduce(float((w[sel] * ex ** 2).sum()), op=MPI.SUM)
    centre = np.abs(pts[:, 0]) < 0.05 * a
    c_num = comm.allreduce(float(delta[centre].sum()), op=MPI.SUM)
    c_n = comm.allreduce(int(centre.sum()), op=MPI.SUM)
    return {"opening_L2_rel_error": float(np.sqrt(num / den)),
            "opening_centre": c_num / max(c_n, 1), "opening_centre_exact": float(exact_opening(0.0, a, dp))}


class OpeningMonitor(Monitor):
    """The opening against Sneddon's in the history and the summary."""

    def __init__(self, a, dp):
        self.a, self.dp = a, dp

    def history(self, problem):
        e = opening_error(problem.solver, problem.interface, self.a, self.dp)
        return {"p_h": problem.hydraulics.params.pressure(problem.t), "opening_centre": e["opening_centre"],
                "opening_L2_rel_error": e["opening_L2_rel_error"]}

    def accuracy(self, problem):
        return opening_error(problem.solver, problem.interface, self.a, self.dp)

    def report(self, acc):
        return (f"[sneddon] opening at the centre {acc['opening_centre'] * 1e3:.4f} mm (exact "
                f"{acc['opening_centre_exact'] * 1e3:.4f} mm), L2 error {acc['opening_L2_rel_error']:.3%}")


def run(problem, options: RunOptions, a=1.0, dp=1.0e6):
    """Run with the opening measurements."""
    return run_problem(problem, options, name="sneddon", monitors=[OpeningMonitor(a, dp)])


def main(argv=None):
    parser = cli.scenario_parser("Sneddon's pressurised crack under confinement")
    parser.add_argument("--dp", type=float, default=1.0e6, help="net pressure p_h - p0 [Pa]")
    parser.add_argument("--p0", type=float, default=CONFINEMENT, help="confinement p0 [Pa] (0: unconfined)")
    parser.add_argument("--relaxation", type=float, default=1500.0,
                        help="dynamic-relaxation damping c [1/s] that brings the run to the static state "
                             "(0 = undamped dynamics)")
    args = cli.parse(parser, argv, name="sneddon", degree=2, t_end=3.0e-3, frames=10)
    if not args.dp > 0:
        parser.error(f"--dp (net pressure) must be > 0 Pa; got {args.dp}")
    a = 1.0
    size, h_crack = (8.0, 0.1) if args.quick else (10.0, 0.05)
    problem = setup(degree=args.degree, a=a, dp=args.dp, p0=args.p0, size=size, h_crack=h_crack, h_far=1.5,
                    t_ramp=1.0e-3, relaxation=args.relaxation)
    return run(problem, a=a, dp=args.dp, options=cli.run_options(args, history_every=10))


if __name__ == "__main__":
    main()
