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


# ----------------------------------------------------------------------------- free growth
def add_growth_arguments(parser):
    """The free-growth options shared by the wellbore scenarios (intersection, re-fracture):
    ``--growth`` (the default) / ``--premeshed`` and the criterion's parameters, in
    crack-facet sizes h."""
    g = parser.add_mutually_exclusive_group()
    g.add_argument("--growth", dest="growth", action="store_true", default=True,
                   help="free crack growth from the perforation tips with Gmsh remeshing (default)")
    g.add_argument("--premeshed", dest="growth", action="store_false",
                   help="grow along pre-meshed radial potential paths instead (no remeshing)")
    parser.add_argument("--growth-r", type=float, default=4.0,
                        help="sampling distance of the growth criterion ahead of a tip, in crack facet sizes h "
                             "(default 4)")
    parser.add_argument("--growth-beta", type=float, default=0.0,
                        help="shear factor beta of the sampled growth criterion (default 0: the largest tensile "
                             "normal traction; 1 = the damage law's, which follows the shear of the compressive "
                             "pressure waves around the wellbore: see the README)")
    parser.add_argument("--growth-direction", choices=("sampled", "cod"), default="cod",
                        help="'cod' (default) takes the sampled onset and the angle of the singular near-tip "
                             "field, K_II/K_I from the crack's slip and opening within r of the tip; 'sampled' "
                             "grows towards the maximum of the sampled criterion (kinks: see the README)")
    parser.add_argument("--growth-cod-window", type=float, default=None,
                        help="with --growth-direction cod: distance behind the tip over which opening and slip "
                             "are correlated, in facet sizes h (default: the sampling distance r)")
    parser.add_argument("--growth-cod-relax", type=float, default=0.5,
                        help="with --growth-direction cod: fraction of the near-tip angle taken per extension "
                             "(default 0.5; 1 zigzags beyond ~1 m in the full-size intersection: see the README)")
    parser.add_argument("--growth-da", type=float, default=2.0,
                        help="length of a growth step, in crack facet sizes h (default 2)")
    parser.add_argument("--growth-max-radius", type=float, default=None,
                        help="tips stop at this distance from the wellbore centre [m] (default: only the outer "
                             "boundary stops them)")


def check_growth_arguments(parser, args):
    """Reject bad growth options before any meshing (argparse's error: exit 2, with the fix)."""
    if not args.growth_r > 0:
        parser.error(f"--growth-r must be > 0 (a distance in facet sizes); got {args.growth_r}")
    if not args.growth_da > 0:
        parser.error(f"--growth-da must be > 0 (a length in facet sizes); got {args.growth_da}")
    if not args.growth_beta >= 0:
        parser.error(f"--growth-beta must be >= 0; got {args.growth_beta}")
    if not 0 < args.growth_cod_relax <= 1:
        parser.error(f"--growth-cod-relax must be in (0, 1]; got {args.growth_cod_relax}")
    if args.growth_max_radius is not None and not args.growth_max_radius > 0:
        parser.error(f"--growth-max-radius must be > 0 m; got {args.growth_max_radius}")
    if args.growth_cod_window is not None and not args.growth_cod_window > 0:
        parser.error(f"--growth-cod-window must be > 0 (a distance in facet sizes); got {args.growth_cod_window}")


def growth_driver(build, domain: Domain, perforations: Sequence[Perforation], damage: DamageParams, args,
                  obstacles=()):
    """A :class:`~hydrofrac.growth.GrowthDriver` that grows a crack from every perforation tip,
    with the options of :func:`add_growth_arguments` (r, Δa in facet sizes ``domain.h_crack``).
    The onset is the damage law's s_; tips stop 2h before the outer boundary (and at
    ``args.growth_max_radius`` from the centre, if given) and join the
    ``obstacles`` (polylines) or another crack they reach.  ``build(polylines)`` makes the
    solver and interface of a geometry."""
    from .growth import GrowthDriver, GrowthParams, Tip
    from .meshes.fractures import PATH
    tips = []
    for pf in perforations:
        d = np.array([np.cos(np.radians(pf.angle)), np.sin(np.radians(pf.angle))])
        tips.append(Tip((domain.wellbore_radius + pf.length) * d, d))
    h = domain.h_crack
    mx, my = domain.half_width - 2 * h, domain.half_height - 2 * h
    rmax = np.inf if args.growth_max_radius is None else args.growth_max_radius
    if not rmax > domain.wellbore_radius + max((pf.length for pf in perforations), default=0.0):
        raise ValueError(f"--growth-max-radius {rmax} m does not reach beyond the perforation tips; make it larger")
    params = GrowthParams(r=args.growth_r * h, beta=args.growth_beta, direction=args.growth_direction,
                          cod_window=(args.growth_cod_window * h if args.growth_cod_window else None),
                          cod_relax=args.growth_cod_relax)
    return GrowthDriver(build, tips, params, da=args.growth_da * h, threshold=damage.s_onset,
                        tags=[PATH + k for k in range(len(tips))],
                        domain_size=2 * min(domain.half_width, domain.half_height),
                        inside=lambda p: abs(p[0]) < mx and abs(p[1]) < my and np.hypot(p[0], p[1]) < rmax,
                        obstacles=obstacles)
