# # A frictional natural fracture under shear-wave loading
#
# A pre-existing fracture (fully debonded, D = 1) lies in a block of the paper's rock
# (``hydrofrac.ROCK``) confined by the in-situ stress $\sigma_0 = -p_0 I$,
# $p_0 = 2.425$ MPa (``hydrofrac.CONFINEMENT``).  It starts closed, in contact at the
# penetration floor (the default opening of a :class:`~hydrofrac.interface.Crack`).  A
# shear (SV) pulse enters through the left side, a boundary that moves up and down with
# the velocity $V g(t)$, $g = \sin^2(\pi t/T)$, and runs across the block towards the
# fracture.  The other sides absorb outgoing waves relative to $\sigma_0$.
#
# The fracture is inclined, so the pulse changes both its normal and its shear traction.
# With Coulomb friction k = 0.6 the fracture sticks while $|s_2| \le k\langle -s_1\rangle$
# and slips once the shear traction reaches that bound (model.md §2-3): the slip mode's
# traction is exactly $k\langle -\breve s^1_B\rangle$, so the friction bound is honoured
# point by point, and the friction work is dissipated, never gained.  The run reports
#
# * the largest ratio $|s^*_2| / (k\langle -s^*_1\rangle)$ over the fracture and the run
#   (must not exceed 1: with no fluid in the fracture the separation traction is zero, and
#   every mode fraction respects the bound),
# * the slip accumulated along the fracture,
# * the friction dissipation (≥ 0) and the smallest instantaneous friction power,
# * the energy balance error (kinetic + strain = initial + work in − radiated − dissipated).
#
# Run it with
#
# ```
# mpirun -n 2 python scenarios/shear_fracture.py               # about a minute on 2 cores
# python scenarios/shear_fracture.py --quick --out /tmp/shear  # a few seconds
# ```
#
# and open ``results/shear_fracture/shear_fracture.pvd`` in ParaView: the bulk fields and,
# as a second block, the fracture with its damage, contact fraction, slip, tractions and
# mode per Gauss point.

# +
from __future__ import annotations

import math

import numpy as np
from mpi4py import MPI

from hydrofrac import CONFINEMENT, ROCK, cli
from hydrofrac.boundary import Absorbing, PiecewiseLinear, Velocity
from hydrofrac.interface import Crack, Interface, crack_facet_indices
from hydrofrac.meshes.blocks import square_with_segment
from hydrofrac.network import CrackLine, CrackNetwork
from hydrofrac.problem import Problem
from hydrofrac.run import Monitor, RunOptions
from hydrofrac.run import run as run_problem
from hydrofrac.solver import Solver
# -

# ## Problem data
#
# The block is $[-R, R]^2$, the fracture a segment of half-length $a$ through the centre
# at angle θ to the x axis.  For a plane SV wave with shear stress τ travelling along x,
# the traction on a plane with normal $n = (-\sin θ, \cos θ)$ has the normal part
# $-τ \sin 2θ$ and the shear part $τ \cos 2θ$: at θ = 75° most of the pulse loads the
# fracture in shear, and a part modulates its normal stress.  The pulse's peak shear
# stress $Z_s V$ is 1.5 times the static friction strength $k p_0$, so the fracture slips.

R = 1.0                          # half-size of the block [m]
A = 0.4                          # half-length of the fracture [m]
THETA = math.radians(75.0)       # fracture angle to the x axis
FRICTION = 0.6                   # Coulomb coefficient k
T_PULSE = 2e-4                   # pulse duration T [s] (wavelength c_s T = 0.37 m)
V_PEAK = 1.5 * FRICTION * CONFINEMENT / ROCK.Zs  # peak boundary velocity [m/s]

CRACK, LEFT, OTHER, BLOCK = 10, 1, 2, 1

SIZES = {  # name: (mesh size h, degree)
    "default": (0.1, 3),
    "quick": (0.15, 2),
}

#: the pulse has crossed the fracture (the fracture's far end is reached after
#: (R + A |cos θ|)/c_s, the pulse lasts T) and the waves it scattered have travelled a bit
T_END = (R + A * abs(math.cos(THETA))) / ROCK.cs + T_PULSE + 0.2 * R / ROCK.cs


# ## Mesh
#
# Gmsh meshes the square with the fracture embedded as a line, so that the fracture is
# a polyline of interior facets, tagged as a physical group.  Gmsh runs on rank 0 and
# DOLFINx distributes the mesh with the facet ghosts DG needs.

def fracture_mesh(comm, h: float):
    """Square [-R, R]^2 with the fracture segment embedded; returns (mesh, facet tags)."""
    dx, dy = A * math.cos(THETA), A * math.sin(THETA)
    return square_with_segment(comm, R, (-dx, -dy), (dx, dy), h, BLOCK, CRACK, LEFT, OTHER)


# ## Model
#
# The solver works with the total stress: the initial state is σ0 at rest.  The left
# side prescribes the velocity $(0, V g(t))$: no normal motion (so it holds the
# confinement) and the vertical shaking that sends the SV pulse.  The fracture is a
# :class:`~hydrofrac.interface.Crack` with D = 1 whose opening starts at the
# penetration floor, in contact; its separation traction is zero (no fluid).

def setup(comm=MPI.COMM_WORLD, size="default", degree=None) -> Problem:
    h, p_default = SIZES[size]
    mesh, tags = fracture_mesh(comm, h)
    sigma0 = -CONFINEMENT * np.eye(2)
    tt = np.linspace(0.0, T_PULSE, 101)
    pulse = PiecewiseLinear(tt, np.sin(np.pi * tt / T_PULSE) ** 2)
    cracks = [Crack(CRACK, friction=FRICTION, damage=1.0)]
    bcs = [Velocity(LEFT, value=(0.0, V_PEAK), history=pulse), Absorbing(OTHER, stress=sigma0)]
    solver = Solver(mesh, p_default if degree is None else degree, ROCK, facet_tags=tags, bcs=bcs,
                    sigma0=sigma0, crack_facets=crack_facet_indices(mesh, tags, cracks))
    dx, dy = A * math.cos(THETA), A * math.sin(THETA)
    network = CrackNetwork.from_cracks([CrackLine(CRACK, "natural", [(-dx, -dy), (dx, dy)])])
    return Problem(solver, Interface(solver, tags, cracks), network=network, facet_tags=tags)


# ## Measurements
#
# After every step we record, over the fracture's Gauss points, the largest Coulomb
# ratio $|s^*_2| / (k\langle -s^*_1\rangle)$ (0/0 counts as 0; shear without compression
# counts as infinite), the largest slip and the friction power.

class Recorder(Monitor):
    """Per-step fracture measurements (the same numbers on every rank)."""

    checkpointed = ("ratio_max", "friction_power_min", "slipping_steps", "last")

    def __init__(self):
        self.ratio_max = 0.0
        self.friction_power_min = math.inf
        self.slipping_steps = 0
        self.last = {"coulomb_ratio": 0.0, "friction_power": 0.0, "slip_max": 0.0}  # history columns

    def __call__(self, problem):
        iface, comm = problem.interface, problem.comm
        T = iface.last
        ratio, slipping = 0.0, 0
        if iface.facets.size:
            sn, st = T["s_star"][:, 0], T["s_star"][:, 1]
            bound = FRICTION * np.maximum(-sn, 0.0)
            with np.errstate(divide="ignore", invalid="ignore"):
                r = np.where(np.abs(st) > 0, np.abs(st) / bound, 0.0)
            ratio = float(r.max())
            contact = T["D"] * T["eta"] > 0
            slipping = int(np.any(contact & (T["gamma"] == 0)))
        self.ratio_max = max(self.ratio_max, comm.allreduce(ratio, op=MPI.MAX))
        self.slipping_steps += comm.allreduce(slipping, op=MPI.MAX)
        power = iface.dissipation_rates()["friction"]
        self.friction_power_min = min(self.friction_power_min, power)
        self.last = {"coulomb_ratio": ratio, "friction_power": power, "slip_max": slip_max(iface)}

    def history(self, problem):
        return self.last

    def accuracy(self, problem):
        e = problem.solver.energy.as_dict()
        iface = problem.interface
        local = float(iface.delta_scale.max()) if iface.delta_scale.size else 0.0
        return {
            "coulomb_ratio_max": self.ratio_max,
            "slip_max": slip_max(iface),
            "slip_mean": slip_mean(iface),
            "slipped": slip_max(iface) > 0,
            "slipping_steps": self.slipping_steps,
            "friction_dissipation": e["dissipated_friction"],
            "friction_power_min": self.friction_power_min,
            "energy_balance_error_relative": e["balance_error_relative"],
            "penetration_max": iface.max_penetration(),
            "penetration_allowed": abs(iface.contact.delta0) * problem.comm.allreduce(local, op=MPI.MAX),
        }

    def report(self, acc):
        return (f"[shear_fracture] max |s_t|/(k|s_n|) = {acc['coulomb_ratio_max']:.6f} (bound 1), slip max "
                f"{acc['slip_max'] * 1e6:.3f} µm, friction dissipation {acc['friction_dissipation']:.4g} J/m")


def slip_max(iface):
    loc = float(np.abs(iface.state[2]).max()) if iface.facets.size else 0.0
    return iface.solver.comm.allreduce(loc, op=MPI.MAX)


def slip_mean(iface):
    """Length-weighted mean |slip| along the fracture [m]."""
    comm, w = iface.solver.comm, iface.weights
    num = comm.allreduce(float((np.abs(iface.state[2]) * w).sum()), op=MPI.SUM)
    den = comm.allreduce(float(w.sum()), op=MPI.SUM)
    return num / den


def run(problem, options: RunOptions):
    """Run with the fracture measurements."""
    return run_problem(problem, options, name="shear_fracture", monitors=[Recorder()])


def main(argv=None):
    parser = cli.scenario_parser("A frictional natural fracture under shear-wave loading (hydrofrac scenario)")
    args = cli.parse(parser, argv, name="shear_fracture", degree=(SIZES["default"][1], SIZES["quick"][1]),
                     t_end=T_END, frames=(40, 5))
    problem = setup(MPI.COMM_WORLD, "quick" if args.quick else "default", degree=args.degree)
    return run(problem, options=cli.run_options(args))


if __name__ == "__main__":
    main()
