"""The one builder of the wellbore problems (crack intersection, re-fracturing, new ones).

A :class:`Wellbore` describes the problem: a wellbore with perforations, natural fractures
and pre-meshed potential paths in confined rock; the wellbore wall and the perforations
carry the fluid pressure p_h(t), the outer boundary is absorbing relative to the
confinement.  :func:`setup` builds its :class:`~hydrofrac.problem.Problem` and, for free
growth, the :class:`~hydrofrac.growth.GrowthDriver` that rebuilds it after every extension.
"""
from __future__ import annotations

import math

from dataclasses import dataclass, field, replace
from typing import Optional, Sequence, Tuple

import numpy as np
from mpi4py import MPI

from .adapt import Adapt
from .boundary import Absorbing, PiecewiseLinear, Traction
from .hydraulics import HydraulicParams
from .growth import BRANCH_SPEED
from .interface import ContactParams, Crack, DamageParams, Interface, crack_facet_indices
from .material import CONFINEMENT, ROCK, Material
from .meshes.fractures import (NATURAL, OUTER, PATH, PERFORATION, WELLBORE, Domain, Fracture, Perforation,
                               check_geometry, fracture_mesh, fracture_points, perforation_points)
from .network import CrackLine, CrackNetwork
from .problem import Problem
from .solver import SCHEMES, Solver


def radial_paths(domain: Domain, perforations: Sequence[Perforation], lengths: Sequence[float]):
    """Straight potential paths continuing each perforation outward by ``lengths``."""
    out = []
    for pf, L in zip(perforations, lengths):
        d = np.array([np.cos(np.radians(pf.angle)), np.sin(np.radians(pf.angle))])
        start = (domain.wellbore_radius + pf.length) * d
        out.append(np.array([start, start + L * d]))
    return out


@dataclass(frozen=True)
class Growth:
    """Free growth (the options of :func:`hydrofrac.cli.add_growth_arguments`, lengths in
    crack-facet sizes h): from the perforation tips and, with ``natural_tips``, from both ends
    of every natural fracture, each by the same criterion once its onset is met.

    The scenario scripts choose which network events are on (``cli.add_growth_arguments``);
    this record's defaults are the plain growth of the perforation tips.  Natural-fracture tips
    need the pressure factor through connected apertures (``Wellbore.connected``): with the
    factor at each vertex alone, a branch grown from a natural fracture's tip (the rock's tau~,
    a 30x smaller aperture scale) takes the full load ahead of the front still crossing the
    fracture (docs/studies/scenarios.md)."""

    r: float = 4.0
    beta: float = 0.0
    direction: str = "cod"
    cod_window: Optional[float] = None
    cod_relax: float = 0.5
    da: float = 2.0
    max_radius: Optional[float] = None
    natural_tips: bool = False
    max_speed: Optional[float] = None
    nucleation_cap: int = 0
    branch_speed: float = float("inf")
    remesh: str = "full"
    patch_radius: float = 6.0

    @classmethod
    def from_args(cls, args) -> Optional["Growth"]:
        if not args.growth:
            return None
        return cls(r=args.growth_r, beta=args.growth_beta, direction=args.growth_direction,
                   cod_window=args.growth_cod_window, cod_relax=args.growth_cod_relax, da=args.growth_da,
                   max_radius=args.growth_max_radius, natural_tips=args.growth_natural_tips,
                   max_speed=None if math.isinf(args.growth_max_speed) else args.growth_max_speed,
                   nucleation_cap=args.growth_nucleation_cap,
                   branch_speed=args.growth_branch_speed, remesh=args.growth_remesh,
                   patch_radius=args.growth_patch_radius)


@dataclass(frozen=True)
class Wellbore:
    """Declarative description of a wellbore problem.

    domain, perforations, fractures : the geometry (:mod:`hydrofrac.meshes.fractures`)
    paths : pre-meshed potential paths (polylines), bonded interfaces (D = 0)
    pressure : p_h(t), the fluid pressure table (required)
    regularized : aperture-based pressure factor (eq. 15) or f_p = 1 at connection
    connected : the pressure factor through connected apertures (default) or at each vertex alone
        (:class:`~hydrofrac.hydraulics.HydraulicParams`)
    degree, material, p0 (confinement [Pa]), damage, contact, delta_bar (δ̄'), path_friction
    growth : free growth from the perforation tips (:class:`Growth`), or None
    volume : V(t), the fluid in the network (:class:`~hydrofrac.hydraulics.HydraulicParams`),
        or None: an unlimited supply at p_h (the paper)
    scheme : the explicit time scheme (:data:`hydrofrac.solver.SCHEMES`; ADER's crack interfaces:
        docs/benchmarks.md, "ADER with crack interfaces")
    cfl : the solver's CFL constant (None: its documented stable value; studies of dt take less)
    """

    domain: Domain
    perforations: Tuple[Perforation, ...]
    pressure: PiecewiseLinear
    fractures: Tuple[Fracture, ...] = ()
    paths: Tuple[np.ndarray, ...] = ()
    regularized: bool = True
    connected: bool = True
    degree: int = 2
    material: Material = ROCK
    p0: float = CONFINEMENT
    damage: DamageParams = field(default_factory=DamageParams)
    contact: ContactParams = field(default_factory=ContactParams)
    delta_bar: float = 0.1
    path_friction: float = 0.6
    growth: Optional[Growth] = None
    volume: Optional[PiecewiseLinear] = None
    scheme: str = "rk4"
    cfl: Optional[float] = None
    adapt: Optional[Adapt] = None

    def __post_init__(self):
        if not isinstance(self.pressure, PiecewiseLinear):
            raise ValueError("wellbore: pressure must be a PiecewiseLinear table of (time [s], p_h [Pa]); "
                             f"got {self.pressure!r}")
        if not self.perforations:
            raise ValueError("wellbore: give at least one perforation (the hydraulic source)")
        if self.scheme not in SCHEMES:
            raise ValueError(f"wellbore: scheme must be one of {', '.join(SCHEMES)}; got {self.scheme!r}")
        if self.contact.delta0 is None and self.contact.closing_speed is None:
            # a contact band resolved in time (delta0 = None) spans its steps at the fastest
            # closing the load can drive: faces unloaded from the peak fluid pressure close at
            # the jump 2 p_max / Z_d
            object.__setattr__(self, "contact", replace(self.contact, closing_speed=closing_speed(self)))
        object.__setattr__(self, "perforations", tuple(self.perforations))
        object.__setattr__(self, "fractures", tuple(self.fractures))
        object.__setattr__(self, "paths", tuple(np.asarray(p, float) for p in self.paths))
        check_geometry(self.domain, self.perforations, self.fractures, self.paths)
        if self.adapt is not None and self.growth is not None and self.growth.remesh == "patch":
            raise ValueError("adaptive meshes change the size field everywhere, so they remesh the whole domain: "
                             "use growth remesh 'full' (--growth-remesh full) with adapt")


#: adaptive meshes (docs/benchmarks.md, "Adaptive meshes"): bulk jumps above this share of the
#: peak load ask for refinement; the far size and the distance it is reached within (0.75 m:
#: within 0.5 m, Gmsh made small cells at the crack ends, and the time step fell by 21 %;
#: docs/benchmarks.md, "Adaptive meshes: the cracks at the fine size")
ADAPT_TOL, ADAPT_H_FAR, ADAPT_GRADING = 0.2, 1.0, 0.75


def adaptive(desc: Wellbore, h_fine: float, tol: float = ADAPT_TOL, h_crack=None, h_far=None) -> Wellbore:
    """``desc`` on adaptive meshes (:mod:`hydrofrac.adapt`) with the fine size ``h_fine`` [m]:
    the cracks at ``h_crack`` (default h_fine), ``h_far`` (default 1 m) reached within 0.75 m;
    bulk jumps relative to the peak load; growing tips keep h_fine within 4 h_fine, where the
    criterion samples the stress.  The cracks stay at h_fine because the pressure front
    advances one crack vertex per update: cracks at 2 h_fine cost the intersection time more
    than the bulk saves (docs/benchmarks.md, "Adaptive meshes: the cracks at the fine size")."""
    dom = replace(desc.domain, h_crack=h_crack or h_fine, h_far=h_far or ADAPT_H_FAR, grading=ADAPT_GRADING)
    if desc.growth is not None:
        dom = replace(dom, h_tip=h_fine, tip_radius=4 * h_fine)
    peak = max(max(desc.pressure.values), desc.p0)
    return replace(desc, domain=dom, adapt=Adapt(h_fine=h_fine, radius=2 * h_fine, stress_scale=peak, tol=tol))


def closing_speed(desc: Wellbore) -> float:
    """The largest closing velocity jump [m/s] the load of ``desc`` can drive: crack faces
    unloaded from the peak fluid pressure (or from the confinement, if larger) by 2 p / Z_d, the
    jump a traction change p makes across an interface of equal rock (docs/model.md §4)."""
    return 2 * max(max(desc.pressure.values), desc.p0) / desc.material.Zd


def network_of(desc: Wellbore, paths=None, path_tags=None) -> CrackNetwork:
    """The crack network of ``desc`` (with ``paths``/``path_tags`` in place of its paths): the
    perforations, natural fractures and paths as polylines with their tags; the perforations'
    outer ends and the paths' last ends are the active tips of a growing problem."""
    paths = desc.paths if paths is None else paths
    lines = check_geometry(desc.domain, desc.perforations, desc.fractures, paths, path_tags)
    kind = {PERFORATION: "perforation", NATURAL: "natural", PATH: "path"}
    cracks = [CrackLine(t, kind[PATH if t >= PATH else NATURAL if t >= NATURAL else PERFORATION], pts)
              for t, pts in lines.items()]
    kinds = ("path", "perforation", "natural") if desc.growth is not None and desc.growth.natural_tips else \
        ("path", "perforation")
    growing = [c.tag for c in cracks if c.kind in kinds] if desc.growth is not None else ()
    return CrackNetwork.from_cracks(cracks, desc.domain.wellbore_radius, growing=growing)


def build(desc: Wellbore, comm=MPI.COMM_WORLD, paths=None, path_tags=None, out=None, previous=None,
          patch_radius=None, refine=()) -> Problem:
    """Mesh, solver, interface, hydraulics and network of ``desc`` (with ``paths``/``path_tags``
    in place of the description's paths: the grown ones).  The network is made first; the
    hydraulic sources are its perforations.  ``previous`` (the last problem's
    ``problem.fracture_mesh``) and ``patch_radius`` [m]: remesh only a patch around the new
    segments (:func:`hydrofrac.meshes.fractures.fracture_mesh`); ``refine``:
    :class:`~hydrofrac.meshes.fractures.Refinement` objects (adaptive meshes)."""
    network = network_of(desc, paths, path_tags)
    # Gmsh meshes the network's lines (or a patch of the previous mesh around the new ones)
    fm = fracture_mesh(comm, desc.domain, network=network, out=out, previous=previous, patch_radius=patch_radius,
                       refine=refine)
    sigma0 = -desc.p0 * np.eye(2)
    cracks = ([Crack(t, friction=0.0, damage=1.0, opening=p.width) for t, p in zip(fm.perforations, desc.perforations)]
              + [Crack(t, friction=f.friction, damage=1.0, tau=f.tau) for t, f in zip(fm.naturals, desc.fractures)]
              + [Crack(t, friction=desc.path_friction, damage=0.0) for t in fm.paths])
    solver = Solver(fm.mesh, desc.degree, desc.material, facet_tags=fm.facet_tags, sigma0=sigma0, cfl=desc.cfl,
                    scheme=desc.scheme,
                    bcs=[Traction(WELLBORE, pressure=desc.pressure), Absorbing(OUTER, stress=sigma0)],
                    crack_facets=crack_facet_indices(fm.mesh, fm.facet_tags, cracks))
    iface = Interface(solver, fm.facet_tags, cracks, damage=desc.damage, contact=desc.contact)
    hyd = HydraulicParams(pressure=desc.pressure, delta_bar=desc.delta_bar, regularized=desc.regularized,
                          connected=desc.connected, sources=[c.tag for c in network.cracks if c.kind == "perforation"],
                          volume=desc.volume)
    problem = Problem(solver, iface, hyd, network=network, facet_tags=fm.facet_tags)
    problem.fracture_mesh = fm
    return problem


def setup(desc: Wellbore, comm=MPI.COMM_WORLD, record=None):
    """(problem, growth driver or None) of ``desc``.  With ``desc.growth`` the cracks grow
    freely from the perforation tips: the driver builds the first problem (no paths yet)
    and every later one; ``record`` is its ``growth.json``."""
    if desc.adapt is not None and desc.growth is None:
        from .adapt import AdaptDriver
        driver = AdaptDriver(lambda refine: build(desc, comm, refine=refine), desc.adapt)
        return driver.problem, driver
    if desc.growth is None:
        return build(desc, comm), None
    driver = growth_driver(desc, comm)
    driver.record = record
    return driver.problem, driver


def growth_driver(desc: Wellbore, comm=MPI.COMM_WORLD):
    """A :class:`~hydrofrac.growth.GrowthDriver` that grows a crack from every active tip of the
    network (r, Δa in facet sizes ``domain.h_crack``).  The onset is the damage law's s_; tips stop 2h
    before the outer boundary (and at ``growth.max_radius`` from the centre, if given) and join
    the natural fractures or another crack they reach."""
    from .growth import GrowthDriver, GrowthParams, Tip
    g, dom, perfs = desc.growth, desc.domain, desc.perforations
    # the growing tips are the network's active ends: the perforations' outer ends and, with
    # growth.natural_tips, both ends of every natural fracture
    start = network_of(replace(desc, paths=()))
    tips = [Tip(t.point.copy(), t.direction.copy()) for t in start.tips if t.active]
    # the growth's length unit: the crack facet size, or with adaptive meshes the fine size
    # (the cracks there are coarser away from their process zones and tips)
    h = dom.h_crack if desc.adapt is None else desc.adapt.h_fine
    mx, my = dom.half_width - 2 * h, dom.half_height - 2 * h
    rmax = np.inf if g.max_radius is None else g.max_radius
    if not rmax > dom.wellbore_radius + max(pf.length for pf in perfs):
        raise ValueError(f"growth max_radius {rmax} m does not reach beyond the perforation tips; make it larger")
    params = GrowthParams(r=g.r * h, beta=g.beta, direction=g.direction,
                          cod_window=(g.cod_window * h if g.cod_window else None), cod_relax=g.cod_relax,
                          branch_speed=None if np.isinf(g.branch_speed) else g.branch_speed)
    premeshed = replace(desc, paths=())

    last = {}  # the last problem's mesh, for a local remesh
    adapt = None
    if desc.adapt is not None:
        from .adapt import Adaptivity
        adapt = Adaptivity(desc.adapt)

    def rebuild(polylines, count=True):
        paths, tags = polylines
        local = g.remesh == "patch" and "fm" in last
        problem = build(premeshed, comm, paths=paths, path_tags=tags, previous=last["fm"] if local else None,
                        patch_radius=g.patch_radius * h if local else None,
                        refine=adapt.refinements() if adapt is not None else ())
        last["fm"] = problem.fracture_mesh
        if local and count:
            fm = problem.fracture_mesh
            rebuild.kinds["patch" if fm.remesh == "patch" else "full_fallback"] += 1
            rebuild.kinds["retried"] = rebuild.kinds.get("retried", 0) + int(fm.retried)
            rebuild.kinds["rebalanced"] = rebuild.kinds.get("rebalanced", 0) + int(fm.rebalanced)
            if fm.fallback:
                rebuild.fallbacks[fm.fallback] = rebuild.fallbacks.get(fm.fallback, 0) + 1
        return problem

    def mesh_state():
        """What a restart needs to make the same mesh again: the arrays it was made from (a
        local remesh's on every rank, a full mesh's on rank 0) and the counts; None unless the
        remesh is local."""
        if g.remesh != "patch":
            return None
        from .meshes.patch import arrays_state
        a = getattr(last.get("fm"), "arrays", None)
        if "listed" not in last or last["listed"][0] is not a:  # (asked at every checkpoint: once per mesh)
            last["listed"] = (a, arrays_state(a))
        return {"arrays": last["listed"][1], "kinds": dict(rebuild.kinds), "fallbacks": dict(rebuild.fallbacks)}

    def restore_mesh(state):
        """Before a restart's build: the checkpoint's mesh is the previous one, with no new
        segment, so the build makes it again from the same arrays (meshes/fractures.py)."""
        from types import SimpleNamespace

        from .meshes.patch import arrays_from_state
        last["fm"] = SimpleNamespace(arrays=arrays_from_state(state["arrays"]), mesh=None)
        rebuild.kinds.update(state["kinds"])
        rebuild.fallbacks.update(state["fallbacks"])

    rebuild.kinds = {"patch": 0, "full_fallback": 0, "retried": 0, "rebalanced": 0}
    rebuild.fallbacks = {}
    rebuild.mesh_state, rebuild.restore_mesh = mesh_state, restore_mesh
    rebuild.local = g.remesh == "patch"

    from .growth import NucleationParams
    # microcracks (nucleation_cap > 0): where the bulk reaches the strength, a crack of Δa, at
    # least 4h from other cracks and tips, and inside the same margin as the tips
    nucleation = (NucleationParams(s_bar=desc.damage.s_bar, length=g.da * h, beta=desc.damage.beta,
                                   exclusion=g.r * h, cap=g.nucleation_cap) if g.nucleation_cap else None)
    return GrowthDriver(rebuild, tips, params, da=g.da * h, threshold=desc.damage.s_onset, nucleation=nucleation,
                        tags=[PATH + k for k in range(len(tips))],
                        domain_size=2 * min(dom.half_width, dom.half_height),
                        # tips stop before the outer boundary, at max_radius, and one Δa from the
                        # wellbore (a segment ending farther than its length from the wall cannot enter it)
                        inside=lambda p: (abs(p[0]) < mx and abs(p[1]) < my
                                          and dom.wellbore_radius + g.da * h < np.hypot(p[0], p[1]) < rmax),
                        obstacles=([fracture_points(nf) for nf in desc.fractures]
                                   + [perforation_points(dom, pf) for pf in perfs]), max_speed=g.max_speed,
                        adapt=adapt)
