"""Meshes that follow the solution: refined where it changes, coarsened where it has settled.

The indicator and the rule are in docs/model.md, "Adaptive meshes".  In short, every
``check_every`` steps :class:`AdaptDriver` flags

* the bulk cells whose DG inter-element jump of (sigma, Z v), relative to ``stress_scale``,
  exceeds ``tol`` (:func:`jump_indicator`; crack facets, where a jump is the physics, are left
  out).  Each gets the size that equidistributes the indicator (:func:`size_levels`), rounded
  to a level h_fine 2^k;
* the crack points in a process zone, where the contact mode or the load changes: damage or
  pressure factor strictly between ``band`` and 1 - ``band`` (:func:`crack_process_points`).
  They are level 0 (h_fine within ``radius``), and stay so: a crack keeps its fine facets
  where it has been a process zone, because its state is history.

The levels are Gmsh size fields beside the scene's own law
(:class:`hydrofrac.meshes.fractures.Refinement`).  The driver remeshes the whole domain when a
crack process point lies in a coarse cell or more than ``refine_fraction`` of the cells are
coarser than ``refine_ratio`` times their target (refinement), or when more than
``coarsen_fraction`` of the cells a bulk level made fine would now be twice as large
(coarsening), and transfers fields and interface state as a crack extension does
(:mod:`hydrofrac.transfer`).  It is a ``remesh`` hook of :func:`hydrofrac.run.run`, with
checkpoints: the levels and the crack history are its state, and a restart meshes them again.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
import ufl
from mpi4py import MPI

from . import compat


@dataclass(frozen=True)
class Adapt:
    """Parameters of adaptive meshes (docs/model.md, "Adaptive meshes").

    h_fine : size where the indicator flags [m]
    radius : the fine zone around each flagged point [m]
    stress_scale : the scene's stress scale [Pa] (e.g. its peak load): jumps are relative to it
    tol : the indicator's threshold (relative jump)
    band : crack points with D or f_p in (band, 1 - band) are a process zone
    check_every : steps between checks (of rk4 at its documented CFL constant, in time)
    refine_ratio : a cell coarser than this times its target is under-resolved
    refine_fraction : a remesh when more than this share of the cells is under-resolved (any
        cell at a crack process point is enough)
    coarsen_fraction : a remesh when more than this share of the cells the refinement made
        fine would now be at least twice as large
    """

    h_fine: float
    radius: float
    stress_scale: float
    tol: float = 0.02
    band: float = 0.02
    check_every: int = 20
    refine_ratio: float = 1.6
    refine_fraction: float = 0.01
    coarsen_fraction: float = 0.3

    def __post_init__(self):
        for name in ("h_fine", "radius", "stress_scale", "tol"):
            if not getattr(self, name) > 0:
                raise ValueError(f"adapt: {name} must be > 0; got {getattr(self, name)}")
        if not 0 < self.band < 0.5:
            raise ValueError(f"adapt: band must be in (0, 0.5); got {self.band}")
        if int(self.check_every) < 1:
            raise ValueError(f"adapt: check_every must be >= 1 step; got {self.check_every}")
        if not self.refine_ratio > 1:
            raise ValueError(f"adapt: refine_ratio must be > 1; got {self.refine_ratio}")
        if not 0 <= self.refine_fraction < 1:
            raise ValueError(f"adapt: refine_fraction must be in [0, 1); got {self.refine_fraction}")
        if not 0 < self.coarsen_fraction < 1:
            raise ValueError(f"adapt: coarsen_fraction must be in (0, 1); got {self.coarsen_fraction}")


class _JumpForm:
    """The compiled indicator forms of one solver (FFCx; the JIT cache keeps the code)."""

    def __init__(self, solver):
        from .forms import elastodynamics as ef
        mesh = solver.mesh
        tdim = mesh.topology.dim
        nfac = compat.num_facets_with_ghosts(mesh)
        off, _ = compat.connectivity(mesh, tdim - 1, tdim)
        interior = np.diff(off)[:nfac] == 2
        interior[np.asarray(solver.crack_facets, dtype=np.int64)] = False
        facets = np.flatnonzero(interior).astype(np.int32)
        self.tags = compat.meshtags(mesh, tdim - 1, facets, np.ones(facets.size, dtype=np.int32))
        self.Q = compat.dg_space(mesh, 0)
        self.u = compat.function(solver.V)
        self.scale = compat.constant(mesh, 1.0)  # Z_ref / sigma_ref, set per call
        self.inv_s = compat.constant(mesh, 1.0)  # 1 / sigma_ref
        q = ufl.TestFunction(self.Q)
        v, sig = ef.fields(self.u)
        dS = compat.measure("dS", mesh, subdomain_data=self.tags)
        js = ufl.jump(sig) * self.inv_s
        jv = ufl.jump(v) * self.scale
        self.num = compat.form(ufl.avg(q) * (ufl.inner(js, js) + ufl.inner(jv, jv)) * dS(1))
        self.den = compat.form(ufl.avg(q) * dS(1))
        self.nloc = compat.num_cells_local(mesh)


def jump_indicator(solver, stress_scale: float, cache: Optional[dict] = None) -> np.ndarray:
    """Per owned cell: the root mean square, over its interior non-crack facets, of the
    inter-element jump of (sigma, Z v), divided by ``stress_scale`` (Z = the largest rho c_d
    of the solver's materials).  Zero for a field continuous across the facets."""
    key = id(solver)
    jf = None if cache is None else cache.get(key)
    if jf is None:
        jf = _JumpForm(solver)
        if cache is not None:
            cache.clear()
            cache[key] = jf
    z_ref = float(np.max(solver.rho_cell * solver.cd_cell)) if solver.rho_cell.size else 0.0
    z_ref = solver.comm.allreduce(z_ref, op=MPI.MAX)
    jf.inv_s.value = 1.0 / stress_scale
    jf.scale.value = z_ref / stress_scale
    arr = compat.function_array(jf.u)
    arr[:] = compat.function_array_of_vec(solver.x)
    num = compat.assemble_vector(jf.num)
    den = compat.assemble_vector(jf.den)
    with num.localForm() as a, den.localForm() as b:
        n, d = a.array_r[:jf.nloc].copy(), b.array_r[:jf.nloc].copy()
    num.destroy()
    den.destroy()
    out = np.zeros(jf.nloc)
    ok = d > 0
    out[ok] = np.sqrt(np.maximum(n[ok], 0.0) / d[ok])
    return out


def crack_process_points(problem, band: float) -> np.ndarray:
    """(k, 2) crack Gauss points (of the owned crack facets) whose damage D or pressure factor f_p lies strictly
    inside (band, 1 - band): a contact mode or the hydraulic load is changing there."""
    iface = problem.interface
    if iface is None or iface.facets.size == 0:
        return np.zeros((0, 2))
    D = iface.state[0]
    active = (D > band) & (D < 1 - band)
    hyd = problem.hydraulics
    if hyd is not None:
        fp = hyd.fp_q
        active |= (fp > band) & (fp < 1 - band)
    return iface.points[active].reshape(-1, 2)


def cell_sizes(solver) -> np.ndarray:
    """Per owned cell: the edge of the equilateral triangle of the same area [m]."""
    g = solver.geometry
    nloc = compat.num_cells_local(solver.mesh)
    area = 0.5 * np.abs(np.linalg.det(g.J[:nloc]))
    return np.sqrt(4 * area / np.sqrt(3))


def thin(points: np.ndarray, spacing: float) -> np.ndarray:
    """The centres of the squares of side ``spacing`` that hold a point, sorted: the size field
    needs the flagged region, not every Gauss point, and the centres do not depend on the
    points' order (so not on the partition)."""
    if points.shape[0] == 0:
        return points.reshape(0, 2)
    keys = np.unique(np.floor(points / spacing).astype(np.int64), axis=0)
    return (keys + 0.5) * spacing


def size_levels(h_fine: float, h_cell: np.ndarray, eta: np.ndarray, tol: float, degree: int) -> np.ndarray:
    """Per flagged cell (eta > tol): the level k of its target size h_fine 2^k.  The target
    equidistributes the indicator, h_K (tol / eta_K)^(1/(p+1)) (a DG jump falls as h^(p+1) on
    a smooth field), rounded down to a power of two times h_fine, and never below h_fine."""
    target = h_cell * (tol / eta) ** (1.0 / (degree + 1))
    return np.maximum(np.floor(np.log2(np.maximum(target, h_fine) / h_fine) + 1e-12), 0).astype(int)


class Adaptivity:
    """The indicator, the size levels and the remesh rule of adaptive meshes (module docstring),
    without a mesh builder: :class:`AdaptDriver` remeshes a fixed geometry with it, and
    :class:`hydrofrac.growth.GrowthDriver` a growing one.

    The levels: level 0 (h_fine, ``radius``) holds the crack process points and the bulk cells
    that need h_fine; level k (h_fine 2^k, radius h_fine 2^k) the bulk cells whose target size
    is that.
    """

    def __init__(self, params: Adapt):
        self.params = params
        self.levels = {}
        self.crack_history = np.zeros((0, 2))  # every crack process point seen so far
        self._zone = np.zeros((0, 2))  # the crack process points of the last check
        self.refines = self.coarsens = self.checks = 0
        self.indicator_s = 0.0
        self._cache = {}
        self._before = self.levels  # the levels before the last check that changed them (undo)

    def _size(self, k):
        return self.params.h_fine * 2.0 ** k

    def _radius(self, k):
        return self.params.radius if k == 0 else self._size(k)

    def refinements(self, levels=None):
        """The levels as :class:`hydrofrac.meshes.fractures.Refinement` size fields."""
        from .meshes.fractures import Refinement
        levels = self.levels if levels is None else levels
        return [Refinement(tuple(map(tuple, pts)), self._size(k), self._radius(k))
                for k, pts in sorted(levels.items()) if pts.shape[0]]

    def flagged(self, problem) -> dict:
        """{level: points (k, 2)}, the same on every rank (docstring of the class)."""
        solver, p = problem.solver, self.params
        eta = jump_indicator(solver, p.stress_scale, self._cache)
        g = solver.geometry
        nloc = eta.size
        centroids = g.x0[:nloc] + g.J[:nloc] @ np.array([1 / 3, 1 / 3])
        on = eta > p.tol
        lev = size_levels(p.h_fine, cell_sizes(solver)[on], eta[on], p.tol, solver.degree)
        zone = crack_process_points(problem, p.band)
        self._zone = thin(np.vstack(solver.comm.allgather(thin(zone, 0.5 * p.h_fine))), 0.5 * p.h_fine)
        # a crack stays fine where it has been a process zone: its damage and opening are
        # history, and a coarser facet would average them (a path's mean D below the network's
        # threshold disconnected a loaded natural fracture in the study; docs/model.md)
        self.crack_history = thin(np.vstack([self.crack_history, self._zone]), 0.5 * p.h_fine)
        local = {0: self.crack_history if solver.comm.rank == 0 else np.zeros((0, 2))}
        for k in np.unique(lev):
            pts = centroids[on][lev == k]
            local[int(k)] = pts if int(k) not in local else np.vstack([local[int(k)], pts])
        keys = sorted(set(k for d in solver.comm.allgather(sorted(local)) for k in d))
        out = {}
        for k in keys:
            mine = thin(local.get(k, np.zeros((0, 2))), 0.5 * self._size(k))
            pts = thin(np.vstack(solver.comm.allgather(mine)), 0.5 * self._size(k))
            if pts.shape[0]:
                out[k] = pts
        return out

    def target(self, levels, x) -> np.ndarray:
        """The refinement's size at points ``x`` (n, 2): the smallest level size whose points
        lie within its radius (where Gmsh's Threshold gives that size); inf where no level
        reaches (the scene's law)."""
        from scipy.spatial import cKDTree
        out = np.full(x.shape[0], np.inf)
        for k, pts in levels.items():
            if pts.shape[0] and x.shape[0]:
                d = cKDTree(pts).query(x)[0]
                near = d <= self._radius(k)
                out[near] = np.minimum(out[near], self._size(k))
        return out

    def decide(self, problem, levels):
        """("refine" | "coarsen" | None) for the flagged ``levels`` (collective): refine when a
        crack process point lies in a cell coarser than ``refine_ratio`` h_fine, or more than
        ``refine_fraction`` of the cells are coarser than ``refine_ratio`` times their new
        target; coarsen when more than ``coarsen_fraction`` of the cells the current
        refinement made fine would now be at least twice as large."""
        solver, p = problem.solver, self.params
        g = solver.geometry
        nloc = compat.num_cells_local(solver.mesh)
        centroids = g.x0[:nloc] + g.J[:nloc] @ np.array([1 / 3, 1 / 3])
        h = cell_sizes(solver)
        new = self.target(levels, centroids)
        old = self.target(self.levels, centroids)
        coarse = int(np.sum(h > p.refine_ratio * new))
        zone = self.target({0: self._zone}, centroids) if self._zone.shape[0] else np.full(nloc, np.inf)
        zone_coarse = int(np.sum(h > p.refine_ratio * zone))
        made = np.isfinite(old)
        idle = int(np.sum(made & (new >= 2 * old)))
        coarse, zone_coarse, idle, n_made, n = solver.comm.allreduce(
            np.array([coarse, zone_coarse, idle, int(made.sum()), nloc]), op=MPI.SUM)
        if zone_coarse > 0 or coarse > p.refine_fraction * n:
            return "refine"
        if n_made and idle > p.coarsen_fraction * n_made:
            return "coarsen"
        return None

    def due(self, solver) -> bool:
        """A check every ``check_every`` steps of rk4 at its documented constant, in time
        (:func:`check_interval`: the same interval whatever the scheme)."""
        return solver.step_count % check_interval(solver, int(self.params.check_every)) == 0

    def check(self, problem):
        """Evaluate the indicators (collective); when the mesh no longer fits them, take the new
        levels and return why ("refine" or "coarsen"), else None.  Times itself as "adapt
        indicator"; returns (why, seconds)."""
        t0 = time.perf_counter()
        levels = self.flagged(problem)
        why = self.decide(problem, levels)
        self.checks += 1
        spent = time.perf_counter() - t0
        self.indicator_s += spent
        problem.solver.timers.add("adapt indicator", spent)
        if why is not None:
            self._before = self.levels
            self.levels = levels
            if why == "refine":
                self.refines += 1
            else:
                self.coarsens += 1
        return why, spent

    def undo(self, why):
        """Back to the levels before the last :meth:`check` that asked for a remesh (its build failed)."""
        self.levels = self._before
        if why == "refine":
            self.refines -= 1
        else:
            self.coarsens -= 1

    def state(self) -> dict:
        return {"levels": {str(k): v.tolist() for k, v in self.levels.items()},
                "crack_history": self.crack_history.tolist(), "refines": self.refines,
                "coarsens": self.coarsens, "checks": self.checks}

    def restore(self, st: dict):
        self.levels = {int(k): np.asarray(v, float).reshape(-1, 2) for k, v in st["levels"].items()}
        self.crack_history = np.asarray(st["crack_history"], float).reshape(-1, 2)
        self.refines, self.coarsens, self.checks = st["refines"], st["coarsens"], st["checks"]

    def report(self) -> dict:
        return {"adaptive_refines": self.refines, "adaptive_coarsens": self.coarsens, "adapt_checks": self.checks}


def _check_period(solver, check_every):
    """``check_every`` steps of rk4 at its documented CFL constant on this mesh [s]."""
    from .solver import CFL_DEFAULT
    return check_every * CFL_DEFAULT["rk4"] * solver.h_over_c_min / (2 * solver.degree + 1)


def check_interval(solver, check_every):
    """Steps between criterion checks: ``check_every`` steps of the rk4 step at its documented
    CFL constant on this mesh, so that the check interval is the same time whatever the scheme
    and CFL constant (its steps are then fewer or more); exactly ``check_every`` for the
    default rk4 run.  The tip speeds and the growth events depend on this interval."""
    key = (solver.dt, check_every, solver.h_over_c_min, solver.degree)  # (asked for at every step)
    kept = solver.__dict__.get("_check_interval")
    if kept is None or kept[0] != key:
        kept = solver._check_interval = (key, max(1, int(round(_check_period(solver, check_every) / solver.dt))))
    return kept[1]


def fit_step_to_checks(solver, check_every):
    """Shorten the step, where needed, to a whole number of steps per check interval
    (:func:`check_interval`), so that the checks fall at the same times whatever the scheme.
    Rounding the interval to steps instead moved the grown network (docs/benchmarks.md, "The
    scheme of a crack run").  A step that already divides the interval (rk4 at its documented
    constant) is left untouched, bit for bit."""
    period = _check_period(solver, check_every)
    ratio = period / solver.dt
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        solver.dt = period / np.ceil(ratio)


class RemeshDriver:
    """What every ``remesh`` hook of :func:`hydrofrac.run.run` that builds new problems shares
    (:class:`AdaptDriver`, :class:`hydrofrac.growth.GrowthDriver`): ``build(what) -> Problem``
    with what :meth:`_mesh_args` gives, the log of meshes, and the adoption of a new problem
    (fields and state carried over, the first mesh kept).

    The first mesh lives as long as the driver: the run's writers and collectives use its
    communicator.  The others go with their problems: the NumPy arrays and the DOLFINx objects
    when Python drops the problem, its PETSc objects before that (:func:`hydrofrac.run.run`,
    :meth:`hydrofrac.problem.Problem.release`), since petsc4py frees none that Python drops.
    Until stop 57 every old mesh was kept: freeing one had corrupted memory (a later numpy write
    crashed).  The commit that kept them also removed a PETSc wrapper of a Function's array
    that outlived its Function, and until stop 57 no PETSc vector was freed before its mesh's
    communicator.  With both gone, freeing the meshes leaves the demo's and the full
    re-fracture's records the same bytes (docs/benchmarks.md, "A remesh freed none of the old
    solver's vectors")."""

    def _mesh_args(self):
        raise NotImplementedError

    #: steps (of rk4, in time) between the driver's checks: every mesh's step fits them
    def _check_every(self):
        raise NotImplementedError

    def _build(self, **kw):
        problem = self.build(self._mesh_args(), **kw)
        problem.growth = self  # run() remeshes a problem through its driver
        if getattr(problem, "solver", None) is not None:  # (the tests' stand-in problems have none)
            fit_step_to_checks(problem.solver, self._check_every())
        return problem

    def _log_mesh(self):
        """Record the current mesh: the time it starts at, its cells and its time step (a step
        that falls tells which remesh made small cells)."""
        s = getattr(self.problem, "solver", None)
        if s is not None:
            self.meshes.append((float(s.t), int(s.num_cells), float(s.dt)))

    @property
    def solver(self):
        return self.problem.solver

    @property
    def iface(self):
        return self.problem.interface

    def _adaptive_build(self, problem):
        """The adaptive check of the current geometry (``self.adapt``, an :class:`Adaptivity`):
        (the problem built on the new mesh, or None where the indicators ask for none, the
        check's seconds).  A build that fails undoes the check's new levels."""
        why, spent = self.adapt.check(problem)
        if why is None:
            return None, spent
        try:
            return self._build(), spent
        except Exception:
            self.adapt.undo(why)
            raise

    def _keep_first_mesh(self, problem):
        """Keep the mesh of the run's first problem alive (see the class)."""
        if not self._first_mesh:
            self._first_mesh.append(problem.solver.mesh)

    def _adopt(self, problem, new):
        """Make ``new`` (built on the new mesh) the current problem: fields and interface state
        carried over from ``problem``, the first mesh kept alive, the mesh logged."""
        self._keep_first_mesh(problem)
        carry_over(problem, new)
        self.problem = new
        self._log_mesh()
        return new


class AdaptDriver(RemeshDriver):
    """Adaptive remeshing of a fixed geometry as a ``remesh`` hook of :func:`hydrofrac.run.run`.

    ``build(refinements) -> Problem`` meshes the scene with the given
    :class:`hydrofrac.meshes.fractures.Refinement` objects (none: the scene's own mesh) and
    builds its problem.
    """

    def __init__(self, build: Callable, params: Adapt):
        self.build, self.params = build, params
        self.adapt = Adaptivity(params)
        self.count = 0
        self.meshes = []  # (t, cells, dt)
        self._first_mesh = []  # the first mesh (RemeshDriver)
        self.last_criterion_s = 0.0
        self.problem = self._build()
        self._log_mesh()

    @property
    def levels(self):
        return self.adapt.levels

    @property
    def refines(self):
        return self.adapt.refines

    @property
    def coarsens(self):
        return self.adapt.coarsens

    def _mesh_args(self):
        return self.adapt.refinements()

    def _check_every(self):
        return self.adapt.params.check_every

    def __call__(self, problem):
        solver = problem.solver
        self.last_criterion_s = 0.0
        if not self.adapt.due(solver):
            return None
        new, self.last_criterion_s = self._adaptive_build(problem)
        if new is None:
            return None
        self.count += 1
        return self._adopt(problem, new)

    # ------------------------------------------------------------ checkpoints and report
    def checkpoint_state(self):
        return json.dumps({"adapt": self.adapt.state(), "count": self.count, "meshes": self.meshes})

    def restart(self, text):
        st = json.loads(text)
        self.adapt.restore(st["adapt"])
        self.count = st["count"]
        self.meshes = [tuple(m) for m in st["meshes"]]
        self._keep_first_mesh(self.problem)
        self.problem = self._build()
        return self.problem

    def report(self):
        cells = [m[1] for m in self.meshes]
        return {"adaptive_remeshes": self.count, **self.adapt.report(), "cells_min": min(cells),
                "cells_max": max(cells)}


def carry_over(old, new):
    """Fields, interface state and the derived hydraulic state from problem ``old`` to ``new``
    (a remesh: :mod:`hydrofrac.transfer`)."""
    from .transfer import continue_run, transfer_fields, transfer_interface
    t0 = time.perf_counter()
    transfer_fields(old.solver, new.solver)
    continue_run(old.solver, new.solver)
    if old.interface is not None and new.interface is not None:
        transfer_interface(old.interface, new.interface)
    new.after_restore()
    # the remesh's time split (summary.py), summed over the remeshes: the new mesh's parts
    # (meshes.fractures.fracture_mesh) and this transfer
    split = new.solver.remesh_split_s
    fm = getattr(new, "fracture_mesh", None)
    for part, s in (("meshing", getattr(fm, "meshing_s", 0.0)), ("distribution", getattr(fm, "distribution_s", 0.0)),
                    ("transfer", time.perf_counter() - t0)):
        split[part] = split.get(part, 0.0) + s
