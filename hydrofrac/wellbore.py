"""Set-up shared by the wellbore problems (crack intersection, re-fracturing).

A wellbore with perforations, natural fractures and potential crack paths in
confined rock; the wellbore wall and the perforations carry the fluid pressure
p_h(t), the outer boundary is absorbing relative to the confinement.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from mpi4py import MPI

from .boundary import Absorbing, PiecewiseLinear, Traction
from .hydraulics import HydraulicParams, Hydraulics
from .interface import ContactParams, Crack, DamageParams, Interface, crack_facet_indices
from .material import CONFINEMENT, ROCK
from .meshes.fractures import OUTER, WELLBORE, Domain, Fracture, Perforation, fracture_mesh
from .solver import Solver


def radial_paths(domain: Domain, perforations: Sequence[Perforation], lengths: Sequence[float]):
    """Straight potential paths continuing each perforation outward by ``lengths``."""
    out = []
    for pf, L in zip(perforations, lengths):
        d = np.array([np.cos(np.radians(pf.angle)), np.sin(np.radians(pf.angle))])
        start = (domain.wellbore_radius + pf.length) * d
        out.append(np.array([start, start + L * d]))
    return out


def build(comm=MPI.COMM_WORLD, domain: Domain = Domain(), perforations: Sequence[Perforation] = (),
          fractures: Sequence[Fracture] = (), paths=(), pressure: PiecewiseLinear = None, regularized=True,
          degree=2, damage: DamageParams = DamageParams(), contact: ContactParams = ContactParams(),
          delta_bar=0.1, path_friction=0.6, p0=CONFINEMENT, material=ROCK, out=None, path_tags=None):
    """Mesh, solver, interface and hydraulics of a wellbore problem.

    Perforations are open (opening = width) hydraulic sources, natural fractures
    are closed pre-existing cracks (D = 1) and paths are intact interfaces (D = 0).
    """
    fm = fracture_mesh(comm, domain, perforations=perforations, fractures=fractures, paths=paths, out=out,
                       path_tags=path_tags)
    sigma0 = -p0 * np.eye(2)
    cracks = ([Crack(t, friction=0.0, damage=1.0, opening=p.width) for t, p in zip(fm.perforations, perforations)]
              + [Crack(t, friction=f.friction, damage=1.0, tau=f.tau) for t, f in zip(fm.naturals, fractures)]
              + [Crack(t, friction=path_friction, damage=0.0) for t in fm.paths])
    solver = Solver(fm.mesh, degree, material, facet_tags=fm.facet_tags, sigma0=sigma0,
                    bcs=[Traction(WELLBORE, pressure=pressure), Absorbing(OUTER, stress=sigma0)],
                    crack_facets=crack_facet_indices(fm.mesh, fm.facet_tags, cracks))
    iface = Interface(solver, fm.facet_tags, cracks, damage=damage, contact=contact)
    hyd = Hydraulics(iface, HydraulicParams(pressure=pressure, sources=fm.perforations, delta_bar=delta_bar,
                                            regularized=regularized))
    return solver, iface, hyd, fm
