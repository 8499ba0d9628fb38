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

from hydrofrac import ROCK
from hydrofrac.boundary import Absorbing
from hydrofrac.growth import GrowthDriver, GrowthParams, Tip
from hydrofrac.interface import Crack, DamageParams, Interface, crack_facet_indices
from hydrofrac.meshes.fractures import NATURAL, OUTER, PATH, Domain, Fracture, fracture_mesh
from hydrofrac.run import RunOptions, log, run, scenario_parser
from hydrofrac.solver import Solver

A, SIGMA = 1.0, 1.0e6
DAMAGE = DamageParams()  # s_ = 1 MPa, s̄ = 2 MPa, τ̃ = 30 µs


def make_builder(comm, angle, h, half, degree):
    """build(paths, tags) -> (solver, interface) for this scene."""
    s0 = np.array([[0.0, 0.0], [0.0, SIGMA]])
    dom = Domain(half_width=half, half_height=half, wellbore_radius=0.0, h_crack=h, h_far=1.5, grading=2.0)

    def build(polylines):
        paths, tags = polylines
        fm = fracture_mesh(comm, dom, fractures=[Fracture((0.0, 0.0), angle, 2 * A, friction=0.0)],
                           paths=paths, path_tags=tags)
        cracks = [Crack(NATURAL, friction=0.0, damage=1.0)] + [Crack(t, friction=0.0, damage=0.0) for t in fm.paths]
        solver = Solver(fm.mesh, degree, ROCK, facet_tags=fm.facet_tags, sigma0=s0,
                        bcs=[Absorbing(OUTER, stress=s0)],
                        crack_facets=crack_facet_indices(fm.mesh, fm.facet_tags, cracks), relaxation=1500.0)
        return solver, Interface(solver, fm.facet_tags, cracks, damage=DAMAGE)
    return build


def main(argv=None):
    parser = scenario_parser("Free crack growth with remeshing: an inclined crack in tension")
    parser.add_argument("--angle", type=float, default=30.0, help="crack inclination to the x axis [deg]")
    args = parser.parse_args(argv)
    comm = MPI.COMM_WORLD
    h, half = (0.1, 4.0) if args.quick else (0.05, 8.0)
    a = math.radians(args.angle)
    d = np.array([math.cos(a), math.sin(a)])
    tips = [Tip(A * d, d.copy()), Tip(-A * d, -d.copy())]
    margin = half - 2 * h
    driver = GrowthDriver(make_builder(comm, args.angle, h, half, args.degree or 2), tips,
                          GrowthParams(r=4 * h), da=2 * h, threshold=DAMAGE.s_onset, tags=[PATH, PATH + 1],
                          inside=lambda p: abs(p[0]) < margin and abs(p[1]) < margin, domain_size=2 * half)

    def history():
        length = sum(float(np.linalg.norm(np.diff(np.array(p), axis=0), axis=1).sum()) for p in driver.paths)
        return {"grown_length": length, "remeshes": driver.count}

    def accuracy(solver):
        out = {"remeshes": driver.count, "extensions": len(driver.events)}
        for i in range(2):
            ang = [e[2] for e in driver.events if e[1] == i]
            if ang:
                out[f"tip{i}_first_kink_deg"] = ang[0]
                p = np.array(driver.paths[i])
                out[f"tip{i}_grown_m"] = float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())
        return out

    opts = RunOptions(t_end=args.t_end or (1.5e-3 if args.quick else 3.0e-3), out=args.out or "results/crack_growth",
                      frames=args.frames or 30, restart=args.restart)
    driver.record = Path(opts.out) / "growth.json"  # the grown paths, written as they grow
    summary = run(driver.solver, opts, name="crack_growth", extra_parts=lambda: driver.iface.part(),
                  history_extra=history, accuracy=accuracy, remesh=driver)
    acc = summary["accuracy"]
    log(comm, f"[crack_growth] {acc['extensions']} extensions in {acc['remeshes']} remeshes; first kink "
              f"{acc.get('tip0_first_kink_deg', float('nan')):.1f}° / {acc.get('tip1_first_kink_deg', float('nan')):.1f}°")
    return summary


if __name__ == "__main__":
    main()
