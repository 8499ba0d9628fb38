# # Two cracks, one loaded: a new scenario in a few lines
#
# A wellbore with one perforation carries the fluid pressure p_h (2.425 → 19.4 MPa in 1 µs);
# the crack grows freely from the perforation tip (Gmsh remeshing) towards an *unloaded*
# natural fracture (closed, frictional, D = 1).  Nothing here wires solver, interface,
# hydraulics or growth together: the description is data, `wellbore.setup` builds the
# problem (with its growth driver), and `hydrofrac.run.run` updates the hydraulic network
# and remeshes as the crack grows.
#
#     mpirun -n 2 python scenarios/two_cracks.py [--quick] [--out DIR]
from __future__ import annotations

from pathlib import Path

from hydrofrac import CONFINEMENT, cli, wellbore
from hydrofrac.boundary import PiecewiseLinear
from hydrofrac.meshes.fractures import Domain, Fracture, Perforation
from hydrofrac.run import run


# ## The problem as data
def description(quick=False, degree=2, growth=wellbore.Growth(), h=None):
    h = h or (0.06 if quick else 0.03)
    return wellbore.Wellbore(
        domain=Domain(half_width=1.5, half_height=1.5, wellbore_radius=0.1, h_crack=h, h_far=0.5, grading=1.0),
        perforations=[Perforation(angle=0.0, length=0.2)],                   # loaded (hydraulic source)
        fractures=[Fracture((0.8, 0.0), angle=90.0, length=0.8, tau=1e-3)],  # unloaded until connected
        pressure=PiecewiseLinear([0.0, 1e-6], [CONFINEMENT, 19.4e6]),
        degree=degree, growth=growth)


def setup(quick=False, degree=2, record=None):
    return wellbore.setup(description(quick, degree), record=record)[0]


# ## Run: the summary counts the network's cracks, junctions and tips
def main(argv=None):
    parser = cli.scenario_parser("Two cracks, one hydraulically loaded, with free growth")
    args = cli.parse(parser, argv, name="two_cracks", degree=2, t_end=(6e-4, 3e-4), frames=20)
    problem = setup(args.quick, args.degree, record=Path(args.out) / "growth.json")
    return run(problem, cli.run_options(args), name="two_cracks")


if __name__ == "__main__":
    main()
