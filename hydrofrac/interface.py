"""Crack interfaces: the interfacial damage / contact model on crack facets.

On crack facets the bulk upwind flux is replaced by the combined Riemann target
values ``s*``, ``v*+``, ``v*-`` of model.md §3 (eqs. 6-7).  This module

* finds the crack facets of the mesh (Gmsh physical groups -> facet tags),
* evaluates both sides' traces at Gauss points of every crack facet,
* calls :mod:`hydrofrac.riemann` (the one implementation of the formulas),
* integrates the flux corrections ``(s* - s).w + (v* - v).(tau n)`` and adds
  ``M^{-1}`` times them to the right-hand side (:meth:`Interface.rhs`),
* carries the interface state per Gauss point (damage D, normal opening delta,
  tangential slip), integrated with the same Runge-Kutta stages as the fields.

Facets are counted once: each rank handles the crack facets it owns, and
contributions to ghost cells are sent to their owners by a reverse scatter.
"""
from __future__ import annotations

import time
from collections import namedtuple
from dataclasses import dataclass, replace
from typing import Callable, Dict, Optional, Sequence

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from . import compat
from . import kernels
from . import riemann as rm
from .element import line_quadrature
from .energy import DISSIPATION_TERMS

#: integer codes of the dominant contact mode, for output
MODE_BONDED, MODE_STICK, MODE_SLIP, MODE_SEPARATED = 0, 1, 2, 3


@dataclass(frozen=True)
class DamageParams:
    """Rate-dependent damage law (model.md §3, eqs. 8-10).

    s_bar : fracture strength s̄ [Pa] (paper: 2 MPa)
    s_onset : damage onset s_ [Pa], < s_bar  [our choice: 0.5 s̄]
    tau : relaxation time τ̃ [s] (paper's extraction: 30 "ms"; its problems last 1-10 ms,
        so a scenario parameter; default 30 µs [our choice])
    a : rate-shape exponent of H(x) = exp(-a x)  [our choice: 5]
    beta : shear factor of the effective stress  [our choice: 1]
    """

    s_bar: float = 2.0e6
    s_onset: float = 1.0e6
    tau: float = 30e-6
    a: float = 5.0
    beta: float = 1.0

    def __post_init__(self):
        if not self.s_bar > 0:
            raise ValueError(f"damage s_bar (strength) must be > 0 Pa; got {self.s_bar}")
        if not 0 <= self.s_onset < self.s_bar:
            raise ValueError(f"damage s_onset must be in [0, s_bar = {self.s_bar}); got {self.s_onset}")
        if not self.tau > 0:
            raise ValueError(f"damage tau (relaxation time) must be > 0 s; got {self.tau}")
        if not self.a > 0:
            raise ValueError(f"damage a (rate shape) must be > 0; got {self.a}")
        if not self.beta >= 0:
            raise ValueError(f"damage beta (shear factor) must be >= 0; got {self.beta}")


@dataclass(frozen=True)
class ContactParams:
    """Regularised contact fraction eta (model.md §4).

    delta0 : maximum normalised penetration δ'₀ < 0 (penetration never beyond |δ'₀| δ̃)
        [our choice: −0.01, 80 nm at τ̃ = 30 µs], or None: resolved in time by the interface
        from its time step, so that the band |δ'₀| δ̃ of the smallest δ̃ spans ``band_steps``
        steps at ``closing_speed``: δ'₀ = −band_steps · closing_speed · dt / min δ̃
        (docs/model.md §4, "The band must be resolved in time"; the measured choice between
        the two is in docs/studies/contact_regularisation.md)
    local_flow : integrate a closing opening by the exact flow through the band (admissible
        at any step, so the clip never acts; :meth:`Interface.advance`); False: the plain
        Runge-Kutta sum, held by the clip (the comparison of the study)
    band_steps : steps the band spans at the closing speed when δ'₀ is resolved [our choice: 3]
    closing_speed : the largest closing velocity jump ⟦v⟧ [m/s] expected of the scene (a
        traction change Δs closes a crack at Δs / Z̃), or None: the fracture velocity scale
        ṽ = s̄ / Z̃ (a traction of the strength).  Scenes with larger loads give theirs.
    w0 : normalised separation-velocity width w'₀ > 0 of the contact -> separation ramp
        [our choice: 0.01, i.e. a bonded-traction excess of 0.005 s̄]
    regularized : False gives the exact (discontinuous) map of fig. 3, for comparison
    penalty : None (default: the Riemann contact model above), or a penalty stiffness
        kappa [Pa/m] for the *penalty baseline* of the stability study: debonded facets are
        always in the separation mode (eta = 0) with the normal traction
        S^1 += -kappa <-delta> (contact by interpenetration, frictionless), as a penalty
        method would impose; penetration ~ p/kappa and an explicit step limit ~ Z~/kappa.
    clip : hold the opening at the permitted penetration delta'_0 delta~ after every stage (a
        safety net: every activation is counted and reported in the summary); False lets the
        dynamics alone keep it (the tests and studies of the regularisation)
    """

    delta0: Optional[float] = -0.01
    w0: float = 0.01
    regularized: bool = True
    penalty: Optional[float] = None
    clip: bool = True
    band_steps: float = 3.0
    closing_speed: Optional[float] = None
    local_flow: bool = True

    def __post_init__(self):
        if self.penalty is not None and not self.penalty > 0:
            raise ValueError(f"contact penalty stiffness kappa must be > 0 Pa/m (or None); got {self.penalty}")
        if self.delta0 is not None and not self.delta0 < 0:
            raise ValueError(f"contact delta0 (maximum penetration delta'_0) must be < 0 (or None: resolved "
                             f"in time); got {self.delta0}")
        if not self.w0 > 0:
            raise ValueError(f"contact w0 (velocity width w'_0) must be > 0; got {self.w0}")
        if not self.band_steps > 0:
            raise ValueError(f"contact band_steps (steps the band spans) must be > 0; got {self.band_steps}")
        if self.closing_speed is not None and not self.closing_speed > 0:
            raise ValueError(f"contact closing_speed must be > 0 m/s (or None: the fracture velocity scale); "
                             f"got {self.closing_speed}")

    def resolved(self, dt: float, delta_scale: float, v_scale: float) -> "ContactParams":
        """These parameters with δ'₀ set (if None) so that the band |δ'₀| ``delta_scale``
        spans ``band_steps`` steps of ``dt`` at the closing speed (``v_scale``, the fracture
        velocity scale, if no closing speed is given)."""
        if self.delta0 is not None:
            return self
        v = v_scale if self.closing_speed is None else self.closing_speed
        return replace(self, delta0=-self.band_steps * v * dt / delta_scale)

    def band_span(self, dt: float, delta_scale: float, v_scale: float) -> float:
        """Steps of ``dt`` in which the band |δ'₀| ``delta_scale`` is crossed at the closing speed."""
        v = v_scale if self.closing_speed is None else self.closing_speed
        return abs(self.delta0) * delta_scale / (v * dt)


@dataclass(frozen=True)
class Crack:
    """A crack (or potential crack path) = a facet tag of interior facets.

    tag : facet tag (Gmsh physical group) of its facets
    friction : Coulomb coefficient k >= 0
    damage : initial damage, 1 for a pre-existing crack, 0 for an intact interface
    opening : initial normal opening delta [m]; None = closed: delta'_0 * delta~
        (in contact, eta = 1) for D > 0, 0 for intact interfaces
    tau : this crack's relaxation time tau~ [s]; None = the interface's
        ``DamageParams.tau``.  It sets the crack's damage rate and its fracture
        scale delta~ = tau~ s_bar / Z~ (eq. 13), hence its maximum penetration
        |delta'_0| delta~ and pressure-factor aperture delta_bar' delta~ (eq. 15).
        A pre-existing fracture (D = 1) no longer damages, so there tau~ only sets
        these length scales.
    """

    tag: int
    friction: float = 0.6
    damage: float = 1.0
    opening: Optional[float] = None
    tau: Optional[float] = None

    def __post_init__(self):
        if self.tau is not None and not self.tau > 0:
            raise ValueError(f"crack {self.tag}: tau (relaxation time) must be > 0 s; got {self.tau}")
        if not self.friction >= 0:
            raise ValueError(f"crack {self.tag}: friction k must be >= 0; got {self.friction}")
        if not 0 <= self.damage <= 1:
            raise ValueError(f"crack {self.tag}: initial damage must be in [0, 1]; got {self.damage}")


def crack_facet_indices(mesh, facet_tags, cracks: Sequence[Crack]):
    """Local indices of the facets of ``cracks`` (owned and ghost), checked to be
    interior facets; raises a clear error for a missing tag."""
    comm = mesh.comm
    tags = [c.tag for c in cracks]
    if len(set(tags)) != len(tags):
        raise ValueError(f"crack tags must be distinct; got {tags}")
    compat.require_tags(comm, facet_tags, tags, "crack", "the mesh's facet tags",
                        "give the crack's Gmsh physical group tag")
    if not tags:
        return np.zeros(0, dtype=np.int32)
    idx = facet_tags.indices[np.isin(facet_tags.values, tags)]
    ext = compat.exterior_facet_indices(mesh)
    bad = comm.allreduce(int(np.isin(idx, ext).sum()), op=MPI.SUM)
    if bad:
        raise ValueError(f"{bad} crack facet(s) lie on the domain boundary; crack polylines must be interior "
                         "(end them inside the domain)")
    return np.unique(idx).astype(np.int32)


#: what ADER's interface step keeps while dt does not change (:meth:`Interface.ader_step`): the
#: crack cells, the facet records with each stage's weights, the stage times with c > 0, their
#: Taylor values (rows of Q), each stage's row of Q (-1: the state itself) and the scheme (A, b)
AderData = namedtuple("AderData", "dt cells PW times Q rows A b")


class Interface:
    """Interfacial damage model on the crack facets of a :class:`~hydrofrac.solver.Solver`.

    Create the solver with ``crack_facets=crack_facet_indices(...)`` so that the bulk
    flux skips them; a :class:`~hydrofrac.problem.Problem` (or ``solver.attach``) makes the
    interface the solver's crack extension.

    The separation law (:meth:`set_separation_law`) ``law(t) -> (S0, cS[, scale])`` gives the
    target traction of the separation mode per Gauss point as ``S = scale S0 + cS <-s_B^1> e_n``
    (local components; S0 of shape (nf, nq, 2), cS of shape (nf, nq), either may be None = 0;
    scale defaults to 1).  The default is traction-free cracks (S = 0); a problem with a
    hydraulic load (:mod:`hydrofrac.hydraulics`, eq. 16) sets its law.
    """

    def __init__(self, solver, facet_tags, cracks: Sequence[Crack], damage: DamageParams = DamageParams(),
                 contact: ContactParams = ContactParams(), quadrature_degree: Optional[int] = None):
        t0 = time.perf_counter()
        self.solver = solver
        self.cracks = list(cracks)
        self.damage = damage
        self.contact = contact
        self.separation_traction: Optional[Callable] = None
        mesh, V = solver.mesh, solver.V
        tdim = mesh.topology.dim
        all_idx = crack_facet_indices(mesh, facet_tags, cracks)
        owned = compat.facet_owned_mask(mesh)
        facets = all_idx[owned[all_idx]]
        # crack id per facet (DOLFINx's meshtags keep their indices sorted)
        self.facets = facets
        at = np.minimum(np.searchsorted(facet_tags.indices, facets), max(facet_tags.indices.size - 1, 0))
        if facets.size and not np.array_equal(facet_tags.indices[at], facets):
            raise RuntimeError("the facet tags' indices are not sorted; make them with compat.meshtags")
        self.crack_tag = np.asarray(facet_tags.values[at], dtype=np.int32) if facets.size else np.zeros(0, np.int32)
        crack_by_tag = {c.tag: c for c in self.cracks}
        # each crack's own data, per facet (one lookup per crack, not per facet)
        tags, of_tag = np.unique(self.crack_tag, return_inverse=True)
        by_facet = [crack_by_tag[int(t)] for t in tags]

        def per_facet(value):
            return np.array([value(c) for c in by_facet], dtype=float)[of_tag] if facets.size else np.zeros(0)

        # geometry: vertices, normal, + and - cells
        f_off, f_arr = compat.connectivity(mesh, tdim - 1, 0)
        c_off, c_arr = compat.connectivity(mesh, tdim - 1, tdim)
        x = mesh.geometry.x[:, :2]
        # vertex -> geometry node (affine P1 mesh: same numbering via the cell maps)
        v2g = compat.vertex_to_geometry(mesh)
        nf = facets.size
        va = x[v2g[f_arr[f_off[facets]]]] if nf else np.zeros((0, 2))
        vb = x[v2g[f_arr[f_off[facets] + 1]]] if nf else np.zeros((0, 2))
        tang = vb - va
        length = np.linalg.norm(tang, axis=1)
        n = np.stack([tang[:, 1], -tang[:, 0]], axis=1) / np.maximum(length, 1e-300)[:, None]
        flip = (n[:, 0] < -1e-12) | ((np.abs(n[:, 0]) <= 1e-12) & (n[:, 1] < 0))
        n[flip] *= -1
        cells = np.zeros((nf, 2), dtype=np.int32)
        if nf:
            if np.any(np.diff(c_off)[facets] != 2):
                raise RuntimeError("a crack facet does not have two cells on this rank (ghost mode must be shared_facet)")
            c2 = np.stack([c_arr[c_off[facets]], c_arr[c_off[facets] + 1]], axis=1)
            g = solver.geometry
            centroid = g.centroid
            mid = 0.5 * (va + vb)
            first_is_plus = np.einsum("fi,fi->f", centroid[c2[:, 0]] - mid, n) < 0
            cells[:, 0] = np.where(first_is_plus, c2[:, 0], c2[:, 1])
            cells[:, 1] = np.where(first_is_plus, c2[:, 1], c2[:, 0])
        self.cells = cells
        self.n = n
        self.length = length
        self.va, self.vb = va, vb

        # Gauss points and traces
        p = solver.degree
        qdeg = 2 * p + 1 if quadrature_degree is None else quadrature_degree
        s, w = line_quadrature(qdeg)
        self.nq = s.size
        self.points = va[:, None, :] + s[None, :, None] * tang[:, None, :]  # (nf, nq, 2)
        self.weights = w[None, :] * length[:, None]  # (nf, nq)
        self._points_of_crack, self._on_segment, self._near = {}, {}, {}  # (points_on_segment, points_near)
        pts = self.points.reshape(-1, 2)
        ref = solver.ref
        g = solver.geometry
        self.phi = []
        for side in range(2):
            cc = np.repeat(cells[:, side], self.nq)
            X = g.to_reference(cc, pts) if nf else np.zeros((0, 2))
            phi = ref.tabulate(X)  # (nf * nq, n); explicit n: a rank may own no crack facet
            self.phi.append(phi.reshape(nf, self.nq, phi.shape[-1]))
        dofs = compat.cell_dofs(V)
        self.cell_dofs = [dofs[cells[:, side]] for side in range(2)]  # (nf, n) block indices
        # contiguous copies for the compiled kernels
        self._dofs = [np.ascontiguousarray(d, dtype=np.int64) for d in self.cell_dofs]
        self._phi = [np.ascontiguousarray(ph, dtype=float) for ph in self.phi]
        self._all_dofs = np.ascontiguousarray(dofs, dtype=np.int64)

        # materials and fracture scales per facet (component impedances (nf, 2))
        cd, rho = solver.cd_cell, solver.rho_cell
        cs = np.sqrt(solver.mu_cell / rho)
        self.Z = [np.stack([rho[cells[:, s_]] * cd[cells[:, s_]], rho[cells[:, s_]] * cs[cells[:, s_]]], axis=1)
                  for s_ in range(2)]
        self.Zt = rm.reduced_impedance(self.Z[0], self.Z[1])  # Z~ per component
        self._Zt_n = self._wq = None  # (the power terms' contiguous copies, when first asked for)
        self.tau = per_facet(lambda c: damage.tau if c.tau is None else c.tau)  # tau~ per facet
        self.delta_scale = self.tau * damage.s_bar / self.Zt[:, 0]  # delta~ (eq. 13)
        self.v_scale = damage.s_bar / self.Zt[:, 0]  # v~
        # delta'_0 resolved in time (ContactParams.delta0 = None), from the smallest delta~ and
        # the largest v~ of all ranks (collective: a rank without crack facets passes inf / 0)
        self._band_scales = (solver.comm.allreduce(float(self.delta_scale.min()) if nf else np.inf, op=MPI.MIN),
                             solver.comm.allreduce(float(self.v_scale.max()) if nf else 0.0, op=MPI.MAX))
        self._resolved = contact.delta0 is None
        if np.isfinite(self._band_scales[0]):
            contact = contact.resolved(solver.dt, *self._band_scales)
        elif contact.delta0 is None:  # no crack facet anywhere: the band has nothing to resolve
            contact = replace(contact, delta0=-1.0)
        self.contact = contact

        self._Zq = [np.repeat(Z_, self.nq, axis=0) for Z_ in self.Z]  # per Gauss point, for the energy terms
        self.friction = per_facet(lambda c: c.friction)
        D0 = per_facet(lambda c: c.damage)
        # the initial opening: a crack's own, else the floor delta'_0 delta~ where it is damaged
        opening = per_facet(lambda c: np.nan if c.opening is None else c.opening)
        delta0 = np.where(np.isnan(opening), np.where(D0 > 0, contact.delta0 * self.delta_scale, 0.0), opening)
        self.state = np.zeros((3, nf, self.nq))
        self.state[0] = D0[:, None]
        self.state[1] = delta0[:, None]
        self.stage_state = self.state.copy()
        self.min_opening = np.full((nf, self.nq), np.inf)
        self.clip_count = 0  # points x stages where the opening clip acted (constrain)
        self.clip_depth = 0.0  # the deepest overshoot it caught, in units of the permitted penetration
        self.closing_max = 0.0  # the fastest closing jump at entry into the contact band [m/s]
        self._delta_prev = self.state[1].copy()

        # M^{-1} blocks of the owned cells next to any crack facet: those next to a facet
        # owned by another rank receive its residual through the reverse scatter
        nloc = compat.num_cells_local(mesh)
        counts = np.diff(c_off)[all_idx]
        first = np.repeat(c_off[all_idx], counts)
        touched = c_arr[first + np.arange(first.size) - np.repeat(np.cumsum(counts) - counts, counts)]
        self.owned_cells = np.unique(touched[touched < nloc]).astype(np.int32)
        self._r = solver.x_like()
        self._ghosted_cells_with_flux = np.any(cells >= nloc)
        self._ghost_flux = solver.comm.allreduce(bool(self._ghosted_cells_with_flux), op=MPI.LOR)
        self.last = {}
        self._zero_law = None
        self._cells = [np.ascontiguousarray(cells[:, side], dtype=np.int64) for side in range(2)]
        self._no_cells = np.zeros((0, self._dofs[0].shape[1] if nf else len(ref.nodes), 5))
        # owned cells next to crack facets owned by another rank (they receive its residual)
        ghost_facets = np.setdiff1d(all_idx, facets)
        gcells = np.concatenate([c_arr[c_off[f]:c_off[f + 1]] for f in ghost_facets] + [np.zeros(0, np.int32)])
        self._recv_cells = np.unique(gcells[gcells < nloc]).astype(np.int32)
        # residual entries the interface writes: the cells on both sides of its facets
        # (owned or ghost) and the owned cells receiving other ranks' contributions
        touched_cells = np.unique(np.r_[cells.reshape(-1), self.owned_cells]).astype(np.int64)
        self._touched = (5 * self._all_dofs[touched_cells][:, :, None] + np.arange(5)).reshape(-1)
        self._P, self._I = kernels.pack_facets(self.n, self.Z[0], self.Z[1], self.Zt, self.friction,
                                               self.delta_scale, self.v_scale, self.tau, self.weights, self._phi[0],
                                               self._phi[1], self._cells[0], self._cells[1], self._dofs[0],
                                               self._dofs[1])
        self._nb = self._phi[0].shape[2]
        self._ader = None  # ADER's step, cells, weighted facet data and predictor values (ader_step)
        self._facets = kernels.Facets(self._P, self._I, self.nq, self._nb)
        c, d = contact, damage
        self._laws = kernels.Laws(bool(c.regularized), float(c.delta0), float(c.w0),
                                  0.0 if c.penalty is None else float(c.penalty), float(d.beta), float(d.s_onset),
                                  float(d.s_bar), float(d.a))
        self._warn_unresolved_band()
        self._compile_stage()
        solver.timers.add("setup", time.perf_counter() - t0)
        self.evaluate(solver.x, 0.0, store=True)

    # ------------------------------------------------------------------ kernels
    def _compile_stage(self):
        """Compile (or load from numba's cache) the stage kernel for the argument types of a
        run, on zero facets: the first stage's compile time is set-up, not interface time."""
        X = np.zeros(5)
        X.flags.writeable = False  # a local form's array_r
        z = np.zeros((3, 0, self.nq))
        Rc = np.zeros((0, self._nb, 5))
        empty = kernels.Facets(self._P[:0], self._I[:0], self.nq, self._nb)
        kernels.interface_stage_flat(X, Rc, np.zeros(5), 0, np.zeros((4, 0, self.nq)), *empty, z[0], z[1],
                                     np.zeros((0, self.nq, 2)), np.zeros((0, self.nq)), 1.0, *self._laws)
        if self._ghost_flux or self.solver.matfree is None:
            kernels.apply_block_inverse(np.zeros(5), np.zeros(5), self._recv_cells[:0], self._all_dofs,
                                        self.solver.Mref_inv, self.solver.Binv_scaled)

    def _warn_unresolved_band(self):
        """Warn (rank 0) when the regularised contact band |delta'_0| delta~ is crossed within
        fewer than 3 time steps at the closing speed (ContactParams.closing_speed, or the fracture
        velocity scale v~): eta then jumps within a step and the opening clip, not the
        regularisation, holds the penetration (docs/model.md §4).  Only without the exact
        closing flow (``ContactParams.local_flow``), which keeps any band admissible."""
        c = self.contact
        if not (c.regularized and c.penalty is None and not c.local_flow) or not np.isfinite(self._band_scales[0]):
            return
        steps = c.band_span(self.solver.dt, *self._band_scales)
        if steps < 3 * (1 - 1e-9) and self.solver.comm.rank == 0:
            import warnings
            v = self._band_scales[1] if c.closing_speed is None else c.closing_speed
            warnings.warn(f"the contact band |delta'_0| delta~ spans {steps:.2g} time steps at the closing speed "
                          f"{v:.3g} m/s (delta'_0 = {c.delta0:.3g}, smallest delta~ = {self._band_scales[0]:.3g} m, "
                          f"dt = {self.solver.dt:.3g} s); below 3 steps eta jumps within a step and the opening clip "
                          f"holds the penetration (counted in the summary). Leave delta0 unset (resolved in time) or "
                          f"take |delta'_0| >= {3 * v * self.solver.dt / self._band_scales[0]:.2g}", stacklevel=3)

    def set_separation_law(self, law: Optional[Callable]):
        """The target traction of the separation mode (see the class docstring); None:
        traction-free."""
        self.separation_traction = law
        self._zero_law = None

    def _separation(self, t):
        """(S0 (nf, nq, 2), cS (nf, nq), scale) of the separation law
        S = scale S0 + cS <-s_B^1> e_n."""
        nf, nq = self.facets.size, self.nq
        if self.separation_traction is None:
            if self._zero_law is None:
                self._zero_law = (np.zeros((nf, nq, 2)), np.zeros((nf, nq)), 0.0)
            return self._zero_law
        law = self.separation_traction(t)
        scale = float(law[2]) if len(law) > 2 else 1.0
        return self._full(law[0], (nf, nq, 2)), self._full(law[1], (nf, nq)), scale

    @staticmethod
    def _full(a, shape):
        if a is None:
            return np.zeros(shape)
        if isinstance(a, np.ndarray) and a.shape == shape and a.dtype == float and a.flags.c_contiguous:
            return a
        return np.ascontiguousarray(np.broadcast_to(np.asarray(a, dtype=float), shape))

    def _buffers(self):
        N = self.facets.size * self.nq
        return {key: np.empty((N, 2)) if key not in ("eta", "gamma", "w") else np.empty(N)
                for key in kernels.Targets._fields}

    def targets(self, xloc, z, t, T=None):
        """Riemann target values and mode fractions at every Gauss point (compiled kernel
        :func:`hydrofrac.kernels.interface_targets`).

        Returns a dict of (nf*nq, ...) arrays in local components: s_star, vp_star,
        vm_star, vp, vm, sp, sm, s_B, S, eta, gamma, D, w (normalised separation
        velocity jump), Zp, Zm.  ``T``: a dict from :meth:`_buffers` to fill (stages
        reuse one; stored states get their own).
        """
        T = self._buffers() if T is None else T
        D = np.ascontiguousarray(z[0])
        kernels.interface_targets_flat(xloc, *self._facets, D, np.ascontiguousarray(z[1]), *self._separation(t),
                                       *self._laws, *(T[k] for k in kernels.Targets._fields))
        T.update(D=D.reshape(-1), Zp=self._Zq[0], Zm=self._Zq[1])
        return T

    def evaluate(self, x, t, store=False, z=None, T=None):
        """Targets at state vector x (ghosts must be current)."""
        z = self.state if z is None else z
        # (views of a local form are used only inside its context: petsc4py releases the
        # array when the view is freed, which must not outlive the restored local form)
        with self.solver.read_local(x) as X:
            T = self.targets(X, z, t, T)
        if store:
            self.last = T
        return T

    def _stage(self, X, t, Rc, nowned, facets=None):
        """The compiled pass over the crack facets (``facets``: the packed facet data, by default
        this interface's own); returns the state rates."""
        z = self.stage_state
        rates = np.empty((4,) + z.shape[1:])  # (damage, opening, slip, free opening) rates
        with self._r.localForm() as rl:  # zero except between a stage and its finish
            kernels.interface_stage_flat(X, Rc, rl.array, nowned, rates, *(facets or self._facets), z[0], z[1],
                                         *self._separation(t), *self._laws)
        return rates

    def _finish(self, out, cells, started=False):
        """Reverse-scatter the dof-vector residual (contributions to ghost cells; ``started``:
        :meth:`start_finish` began it), apply the inverse mass of ``cells`` to it, add to
        ``out``, and clear it.  The exchange (waiting for the neighbours included) is timed as
        "halo exchange"; returns its seconds, which the caller's interface time leaves out."""
        halo = 0.0
        if self._ghost_flux:
            t0 = time.perf_counter()
            if started:
                self._r.ghostUpdateEnd(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            else:
                self._r.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            halo = time.perf_counter() - t0
            self.solver.timers.add("halo exchange", halo)
        with self._r.localForm() as rl:
            r = rl.array
            if cells.size:
                kernels.apply_block_inverse(out.array, r, cells, self._all_dofs, self.solver.Mref_inv,
                                            self.solver.Binv_scaled)
            r[self._touched] = 0.0
        return halo

    def stage_cells(self, X, t, Rc):
        """Matrix-free path (:class:`hydrofrac.matfree.MatrixFreeOperator`): add the flux
        corrections of the owned cells to its cell residual ``Rc`` before its inverse mass
        is applied; the rest (ghost cells) waits in the dof-vector residual for
        :meth:`finish_stage`.  Returns the state rates."""
        t0 = time.perf_counter()
        rates = self._stage(X, t, Rc, Rc.shape[0])
        self.solver.timers.add("interface kernel", time.perf_counter() - t0)
        return rates

    def start_finish(self):
        """Matrix-free path: begin sending the contributions to ghost cells (after
        :meth:`stage_cells`), so that the bulk's volume pass runs while they travel and
        :meth:`finish_stage` only completes the exchange."""
        if self._ghost_flux:
            self._r.ghostUpdateBegin(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)

    def finish_stage(self, out):
        """Matrix-free path: contributions that other ranks computed for owned cells (the
        exchange :meth:`start_finish` began)."""
        t0 = time.perf_counter()
        halo = self._finish(out, self._recv_cells, started=True) if self._ghost_flux else 0.0
        self.solver.timers.add("interface kernel", time.perf_counter() - t0 - halo)

    def rhs(self, y, t, out):
        """Add M^{-1} (interface flux terms) into ``out``; return the state rates (used with
        the assembled bulk operator; the matrix-free one calls :meth:`stage_cells`).

        One compiled pass over the crack facets (:func:`hydrofrac.kernels.interface_stage`)
        into a residual that is zero outside the cells next to cracks, then (in parallel)
        the reverse scatter of contributions to ghost cells, and the cells' inverse mass."""
        t0 = time.perf_counter()
        with y.localForm() as yl:
            rates = self._stage(yl.array_r, t, self._no_cells, 0)
        halo = self._finish(out, self.owned_cells)
        self.solver.timers.add("interface kernel", time.perf_counter() - t0 - halo)
        return rates

    #: ADER's stages for the crack interfaces, by the bulk's degree p (3 for p >= 3): an explicit
    #: Runge-Kutta scheme (c, A, b) of order min(p + 1, 4), ADER's own order in the bulk, with
    #: no negative coefficient.  The flux of stage k is taken from the cells' Taylor predictor
    #: at t + c_k dt and weighed by b_k dt; the state follows the scheme.  p = 1: Heun's
    #: second-order pair (the trapezoidal rule for the flux, exact for the P1 predictor, linear
    #: in time); p = 2: the strong-stability-preserving SSPRK(3,3) (Simpson's rule, exact for
    #: cubics); p >= 3: the classical fourth-order scheme (Simpson's rule).  Kutta's third-order
    #: scheme, whose third stage takes z_n + dt (2 r_1 - r_0), let an instability grow at a
    #: closing contact in the full-size re-fracture (docs/benchmarks.md, "ADER with crack
    #: interfaces").
    ADER_STAGES = {
        1: ((0.0, 1.0), ((), (1.0,)), (0.5, 0.5)),
        2: ((0.0, 1.0, 0.5), ((), (1.0,), (0.25, 0.25)), (1.0 / 6.0, 1.0 / 6.0, 2.0 / 3.0)),
        3: ((0.0, 0.5, 0.5, 1.0), ((), (0.5,), (0.0, 0.5), (0.0, 0.0, 1.0)),
            (1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0)),
    }

    def ader_step(self, X, t, dt, R, taylor):
        """ADER (the solver's scheme "ader"): add the time integral over [t, t + dt] of the crack
        facets' flux to the cell residual ``R`` of the owned cells, and to the dof-vector residual
        for ghost cells (:meth:`fold_received` completes it), and return the state at t + dt.
        The stages are :data:`ADER_STAGES`' for the solver's degree: stage k reads the cells'
        Taylor predictor at t + c_k dt (``taylor(X, Q, cells, taus)`` for all the stage times at once,
        :meth:`hydrofrac.matfree.MatrixFreeOperator.taylor_values`; ``X`` itself, the local
        values with ghosts, at c_k = 0) with the state z_n + dt sum_j A_kj r_j, and its
        quadrature weights carry b_k dt.  The new state z_n + dt sum_k b_k r_k is made
        admissible as by :meth:`advance`, as every stage's.  The stages run in one compiled call
        (:func:`hydrofrac.kernels.ader_interface_step`), after the Taylor values."""
        t0 = time.perf_counter()
        c, A, b = self.ADER_STAGES[min(self.solver.degree, 3)]
        if self._ader is None or self._ader.dt != dt:
            P = self._facets.P
            PW = np.empty((len(b),) + P.shape)
            for k, bk in enumerate(b):
                PW[k] = P
                PW[k, :, kernels.WEIGHTS:kernels.WEIGHTS + self.nq] *= dt * bk
            times = sorted({ck for ck in c if ck})
            Q = self._ader.Q if self._ader is not None else None
            if Q is None or Q.shape != (len(times), X.size):
                Q = np.zeros((len(times), X.size))  # (rows: the stage times' traces; other blocks unused)
            rows = np.array([times.index(ck) if ck else -1 for ck in c], dtype=np.int64)
            Am = np.zeros((len(b), len(b)))
            for k, Ak in enumerate(A):
                Am[k, :len(Ak)] = Ak
            self._ader = AderData(dt, np.unique(self.cells.reshape(-1)).astype(np.int64), PW, times, Q, rows, Am,
                                  np.array(b, dtype=float))
        _, cells, PW, times, Q, rows, Am, bv = self._ader
        taylor(X, Q, cells, [ck * dt for ck in times])  # (each stage time's traces)
        laws = [self._separation(t + ck * dt) for ck in c]
        if all(S0 is laws[0][0] and cS is laws[0][1] for S0, cS, _ in laws):  # (one law's arrays: no copy)
            S0s, cSs = laws[0][0][None], laws[0][1][None]
        else:
            S0s, cSs = np.stack([law[0] for law in laws]), np.stack([law[1] for law in laws])
        with self._r.localForm() as rl:  # (zero except between a stage and its finish)
            z, count, depth = kernels.ader_interface_step(
                X, Q, rows, R, rl.array, R.shape[0], Am, bv, dt, PW, self._facets.I, self.nq, self._nb,
                np.ascontiguousarray(self.state), S0s, cSs, np.array([law[2] for law in laws], dtype=float),
                *self._laws, *self._admissible())
        self._count_clips(count, depth)
        self.solver.timers.add("interface kernel", time.perf_counter() - t0)
        return z

    def fold_received(self, R):
        """ADER: the contributions to owned cells that other ranks computed (the reverse exchange
        of the dof-vector residual), added to the cell residual ``R``; the residual cleared."""
        if not self._ghost_flux:
            return
        t0 = time.perf_counter()
        self._r.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self.solver.timers.add("halo exchange", time.perf_counter() - t0)
        with self._r.localForm() as rl:
            r = rl.array
            cells = self._recv_cells
            if cells.size:
                R[cells] += r.reshape(-1, 5)[self._all_dofs[cells]]
            r[self._touched] = 0.0

    def advance(self, z0, inc):
        """The state z0 + inc, ``inc`` being a stage's or a step's Runge-Kutta combination of
        the rates (None: none), admissible: damage in [D_n, 1] (never decreases); the opening,
        where the free opening (the rates' last row, D [[v_S^1]]) closes, by the exact closing
        flow through the contact band (:func:`hydrofrac.riemann.closing_flow_pt`;
        ``ContactParams.local_flow``), which never passes the floor delta'_0 delta~ at any
        step; elsewhere by the Runge-Kutta sum.  The opening clip at the floor (the maximum
        penetration, where eta = 1 and d(delta)/dt = 0) stays as a counted safety net.  One
        compiled pass (:func:`hydrofrac.kernels.advance_state`)."""
        if inc is None:
            inc = np.zeros((4,) + z0.shape[1:])
        elif inc.shape[0] < 4:  # (no free-opening row: no closing flow)
            inc = np.concatenate([inc, np.zeros((4 - inc.shape[0],) + z0.shape[1:])])
        z, count, depth = kernels.advance_state(np.ascontiguousarray(z0), np.ascontiguousarray(inc),
                                                *self._admissible())
        self._count_clips(count, depth)
        return z

    def _admissible(self):
        """The arguments of :func:`hydrofrac.kernels.advance_state` after the state and its
        increment: the damage floor D_n, delta~, delta'_0, the closing flow on, the clip on."""
        c_ = self.contact
        free = c_.regularized and c_.penalty is None
        return (self.state[0], self.delta_scale, 0.0 if c_.delta0 is None else float(c_.delta0),
                bool(free and c_.local_flow), bool(free and c_.clip))

    def _count_clips(self, count, depth):
        if count:  # the dynamics overshot the permitted penetration: count it
            self.clip_count += int(count)
            self.clip_depth = max(self.clip_depth, float(depth))

    def end_step(self, x, t, dt):
        t0 = time.perf_counter()
        self._record_closing(dt)
        self.stage_state = self.state.copy()
        halo = self.solver.update_ghosts(x)
        self.evaluate(x, t, store=True)
        self.min_opening = np.minimum(self.min_opening, self.state[1])
        self.solver.timers.add("state update", time.perf_counter() - t0 - halo)

    def _record_closing(self, dt):
        """The fastest closing met: at points that entered the contact band this step (not
        penetrating before, delta < 0 now), the separation-mode closing jump -D [[v_S^1]] of the step's
        start.  The band must span steps at this speed (docs/model.md §4); the summary reports it."""
        prev = self._delta_prev
        self._delta_prev = self.state[1].copy()
        if prev.shape != self.state[1].shape or "w" not in self.last:
            return
        entered = (prev >= 0) & (self.state[1] < 0)
        if entered.any():
            w = self.last["w"].reshape(prev.shape) * self.v_scale[:, None]
            D = self.last["D"].reshape(prev.shape)
            self.closing_max = max(self.closing_max, float((-D * w)[entered].max()))

    # ------------------------------------------------------------------ energy
    def dissipation_rates(self):
        """Interface power terms at the last evaluated state [W/m]: dict with
        friction (tangential power s*_t [[v*]]_t: >= 0, each mode's tangential traction has
        the sign of its slip), damage (normal power beyond the separation-traction work:
        a_S (1 - a_S) 2 (s_B - S)^2 / Z~ >= 0), flux (characteristic dissipation of the
        traces), work_in (power into the body of the separation traction S relative to the
        initial stress, e.g. the net fluid pressure, and of the initial shear traction
        (sigma0 n)_t on the slip: the energy is measured relative to sigma0, so releasing
        that traction on a sliding crack is a source, not negative friction)."""
        tot = np.zeros(4)
        self.solver.comm.Allreduce(self.local_dissipation_rates(), tot, op=MPI.SUM)  # one reduction for the four
        return dict(zip(DISSIPATION_TERMS, tot.tolist()))

    def local_dissipation_rates(self):
        """This rank's part of :meth:`dissipation_rates`, as an array in the order of
        :data:`DISSIPATION_TERMS` (for a caller that reduces it with other sums at once)."""
        T = self.last
        if not T:
            return np.zeros(4)
        if self._Zt_n is None:
            self._Zt_n = np.ascontiguousarray(self.Zt[:, 0])
            self._wq = np.ascontiguousarray(self.weights.reshape(-1))
        # tractions relative to the initial stress (the energy is measured relative to it); one
        # compiled pass over the points (kernels.interface_power)
        return kernels.interface_power(T["vp"], T["vm"], T["vp_star"], T["vm_star"], T["s_star"], T["s_B"], T["S"],
                                       T["D"], T["eta"], T["gamma"], T["Zp"], T["Zm"], self._Zt_n,
                                       np.ascontiguousarray(self.n), self.nq, self.solver.sigma0, self._wq)

    # ------------------------------------------------------------------ output
    def fields(self):
        """Per Gauss point output fields (nf, nq) of the last evaluated state."""
        T = self.last
        nf, nq = self.facets.size, self.nq
        if not T:
            return {}
        eta, gamma = T["eta"], T["gamma"]
        return {
            "D": self.state[0], "eta": eta.reshape(nf, nq), "gamma": gamma.reshape(nf, nq),
            "opening": self.state[1], "slip": self.state[2],
            "traction_n": T["s_star"][:, 0].reshape(nf, nq), "traction_t": T["s_star"][:, 1].reshape(nf, nq),
            "mode": self.modes(),
            # the permitted penetration of each crack, from the model parameters (model §4)
            "penetration_limit": np.repeat(abs(self.contact.delta0) * self.delta_scale[:, None], nq, axis=1),
        }

    def modes(self):
        """The dominant contact mode (:data:`MODE_BONDED` ... :data:`MODE_SEPARATED`) at every Gauss
        point (nf, nq) of the last evaluated state: the largest of the four mode fractions (the
        first where they tie)."""
        T = self.last
        frac = rm.mode_fractions(T["D"], T["eta"], T["gamma"])
        return np.argmax(frac, axis=1).reshape(self.facets.size, self.nq).astype(np.int32)

    def separated(self):
        """Whether separation is the dominant mode at every Gauss point (nf, nq) of the last
        evaluated state: ``modes() == MODE_SEPARATED`` (its fraction D (1 - eta) above each of
        the other three, which win ties), without the four fractions' array and its argmax
        (a monitor asks every step)."""
        T = self.last
        D, eta, gamma = T["D"], T["eta"], T["gamma"]
        sep, De = D * (1 - eta), D * eta  # (the products of riemann.mode_fractions, in its order)
        return ((sep > 1 - D) & (sep > De * gamma) & (sep > De * (1 - gamma))).reshape(self.facets.size, self.nq)

    def part(self, extra: Optional[Dict[str, np.ndarray]] = None):
        """Line-mesh output part: per facet the points [a, q_1..q_nq, b] joined by
        segments, point data at the Gauss points (ends copy the nearest point)."""
        from .io import VTK_LINE, Part
        nf, nq = self.facets.size, self.nq
        pts = np.concatenate([self.va[:, None], self.points, self.vb[:, None]], axis=1).reshape(-1, 2)
        npf = nq + 2
        base = np.arange(nf)[:, None] * npf
        seg = np.arange(npf - 1)
        cells = np.stack([base + seg, base + seg + 1], axis=-1).reshape(-1, 2)
        flds = self.fields()
        if extra:
            flds.update(extra)
        pd = {}
        for k, v in flds.items():
            v = np.asarray(v).reshape(nf, nq)
            pd[k] = np.concatenate([v[:, :1], v, v[:, -1:]], axis=1).reshape(-1)
        cd = {"crack": np.repeat(self.crack_tag, npf - 1).astype(np.int32)}
        return {"cracks": Part(pts, cells, VTK_LINE, pd, cd)}

    def points_of_crack(self, tag):
        """Indices into the flattened Gauss points (and ``state[k].reshape(-1)``) of crack
        ``tag``'s points, in order (kept per crack: an interface lives on one mesh)."""
        if not self._points_of_crack:  # (every crack's at once: its points in order)
            tags = np.repeat(self.crack_tag, self.nq)
            order = np.argsort(tags, kind="stable")
            keys, first = np.unique(tags[order], return_index=True)
            self._points_of_crack = dict(zip(keys.tolist(), np.split(order.astype(np.int64), first[1:])))
        on = self._points_of_crack.get(int(tag))
        return on if on is not None else np.zeros(0, np.int64)

    def points_on_segment(self, tag, p0, p1):
        """Indices into the flattened Gauss points (and ``state[k].reshape(-1)``) of crack
        ``tag``'s points on the segment p0 -> p1 (within 1e-9 of its length, or of 1 m).  Kept
        for each segment met: an interface lives on one mesh, so its points do not move."""
        return self.points_on_segments([(tag, p0, p1)])[0]

    def points_on_segments(self, segments):
        """:meth:`points_on_segment` of each (tag, p0, p1) of ``segments``; those not met yet
        found in one pass."""
        keys = [(int(t), *np.asarray(a, float).tolist(), *np.asarray(b, float).tolist()) for t, a, b in segments]
        miss = list({key: None for key in keys if key not in self._on_segment})
        if miss:
            ons = [self.points_of_crack(key[0]) for key in miss]
            n = [o.size for o in ons]
            on = np.concatenate(ons)
            ends = np.array([key[1:] for key in miss], dtype=float).reshape(-1, 4)
            p0, seg = ends[:, :2], ends[:, 2:] - ends[:, :2]
            L2 = seg[:, 0] * seg[:, 0] + seg[:, 1] * seg[:, 1]
            tol = 1e-9 * np.maximum(1.0, np.sqrt(L2))
            p0, seg, L2, tol = (np.repeat(v, n, axis=0) for v in (p0, seg, L2, tol))
            q = self.points.reshape(-1, 2)[on] - p0
            u = (q[:, 0] * seg[:, 0] + q[:, 1] * seg[:, 1]) / L2
            r = q - u[:, None] * seg  # (the offset from the segment where 0 <= u <= 1)
            hit = (u >= 0) & (u <= 1) & (r[:, 0] * r[:, 0] + r[:, 1] * r[:, 1] <= tol * tol)
            for key, o, h in zip(miss, np.split(on, np.cumsum(n)[:-1]), np.split(hit, np.cumsum(n)[:-1])):
                self._on_segment[key] = o[h]
        return [self._on_segment[key] for key in keys]

    def points_near(self, tag, x, radius):
        """Indices into the flattened Gauss points of crack ``tag``'s points within ``radius``
        of the point ``x`` (kept for each point asked about, as :meth:`points_on_segment`)."""
        key = (int(tag), *np.asarray(x, float).tolist(), float(radius))
        idx = self._near.get(key)
        if idx is None:
            on = self.points_of_crack(tag)
            idx = self._near[key] = on[np.linalg.norm(self.points.reshape(-1, 2)[on] - np.asarray(x, float), axis=1)
                                       <= radius]
        return idx

    # ------------------------------------------------------------------ checkpoint
    def checkpoint_state(self):
        return {"state": self.state.copy(), "min_opening": self.min_opening.copy(),
                "clips": np.array([self.clip_count, self.clip_depth, self.closing_max]),
                "delta_prev": self._delta_prev.copy()}

    def restore_state(self, st):
        self.state = np.array(st["state"])
        self.stage_state = self.state.copy()
        self.min_opening = np.array(st["min_opening"])
        if "clips" in st:
            self.clip_count, self.clip_depth = int(st["clips"][0]), float(st["clips"][1])
            self.closing_max = float(st["clips"][2]) if len(st["clips"]) > 2 else 0.0
        if "delta_prev" in st:
            self._delta_prev = np.array(st["delta_prev"])

    def contact_report(self):
        """What the summary reports of the contact model (collective): the largest
        penetration and the permitted one [m], and the opening clip's activations (points x
        stages) and its deepest catch relative to the permitted penetration."""
        comm = self.solver.comm
        met = comm.allreduce(self.closing_max, op=MPI.MAX)
        permitted = abs(self.contact.delta0) * comm.allreduce(
            float(self.delta_scale.max()) if self.delta_scale.size else 0.0, op=MPI.MAX)
        return {"max_penetration": self.max_penetration(), "permitted_penetration_max": permitted,
                "clip_activations": comm.allreduce(self.clip_count, op=MPI.SUM),
                "clip_depth_max": comm.allreduce(self.clip_depth, op=MPI.MAX),
                "regularized": bool(self.contact.regularized), "clip": bool(self.contact.clip),
                "delta0": float(self.contact.delta0), "resolved": self._resolved,
                "local_flow": bool(self.contact.local_flow),
                # a resolved band: the steps it spans at its closing speed (ContactParams)
                "band_steps": (float(self.contact.band_span(self.solver.dt, *self._band_scales))
                               if np.isfinite(self._band_scales[0]) else None),
                "closing_speed": (self._band_scales[1] if self.contact.closing_speed is None
                                  else float(self.contact.closing_speed)),
                "closing_speed_met": met,
                "band_steps_met": (abs(self.contact.delta0) * self._band_scales[0] / (met * self.solver.dt)
                                   if met > 0 and np.isfinite(self._band_scales[0]) else None)}

    # ------------------------------------------------------------------ diagnostics
    def max_penetration(self):
        """Largest penetration -min(delta) seen so far, over all ranks [m]."""
        loc = float(-self.min_opening.min()) if self.min_opening.size else -np.inf
        return self.solver.comm.allreduce(loc, op=MPI.MAX)
