"""A rectangular block with natural fractures and growing paths, held at a stress by absorbing
sides: the builder that the growth scenarios without a wellbore share (``crack_growth``,
``branching``, ``crossing``)."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .boundary import Absorbing
from .interface import Crack, DamageParams, Interface, crack_facet_indices
from .material import ROCK
from .meshes.fractures import OUTER, PATH, Domain, Fracture, fracture_mesh
from .network import CrackLine, CrackNetwork
from .problem import Problem
from .solver import Solver


def block_builder(comm, domain: Domain, fractures: Sequence[Fracture], cracks: Sequence[Crack], sigma0,
                  outer_stress=None, degree=2, damage: DamageParams = DamageParams(), relaxation=0.0,
                  patch_radius=None):
    """``build((paths, tags)) -> Problem``: Gmsh meshes ``domain`` with ``fractures`` (their
    interface data ``cracks``, in the same order; the tags are filled in from the mesh) and the
    growth ``paths`` (bonded, frictionless: D = 0, k = 0); the rock starts at ``sigma0`` and the
    absorbing sides hold ``outer_stress`` (default ``sigma0``).  With ``patch_radius`` [m], every
    mesh after the first is a local remesh of the one before (meshes/patch.py)."""
    s0 = np.asarray(sigma0, float)
    s_out = s0 if outer_stress is None else np.asarray(outer_stress, float)
    if len(cracks) != len(fractures):
        raise ValueError(f"give one Crack per fracture; got {len(cracks)} for {len(fractures)}")

    last = {}

    def build(polylines):
        paths, tags = polylines
        local = patch_radius is not None and "fm" in last
        fm = fracture_mesh(comm, domain, fractures=fractures, paths=paths, path_tags=tags,
                           previous=last["fm"] if local else None, patch_radius=patch_radius if local else None)
        last["fm"] = fm
        cr = ([Crack(t, friction=c.friction, damage=c.damage, opening=c.opening, tau=c.tau)
               for t, c in zip(fm.naturals, cracks)]
              + [Crack(t, friction=0.0, damage=0.0) for t in fm.paths])
        solver = Solver(fm.mesh, degree, ROCK, facet_tags=fm.facet_tags, sigma0=s0,
                        bcs=[Absorbing(OUTER, stress=s_out)],
                        crack_facets=crack_facet_indices(fm.mesh, fm.facet_tags, cr), relaxation=relaxation)
        lines = [CrackLine(t, "path" if t >= PATH else "natural", pts) for t, pts in fm.lines.items()]
        problem = Problem(solver, Interface(solver, fm.facet_tags, cr, damage=damage),
                          network=CrackNetwork.from_cracks(lines, growing=fm.paths), facet_tags=fm.facet_tags)
        problem.fracture_mesh = fm
        return problem
    return build
