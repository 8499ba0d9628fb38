"""Explicit Runge-Kutta DG solver for velocity-stress elastodynamics.

The semi-discrete system is ``M dU/dt = K U + b(t) + r_interface(U, z, t)``.
Everything linear is assembled once per mesh from the UFL forms in
:mod:`hydrofrac.forms.elastodynamics`:

* ``A = M^{-1} K`` (bulk operator; the mass matrix is block-diagonal and is
  inverted cell by cell in closed form),
* ``c_k = M^{-1} b_k`` for each load that is constant or scaled by a history g_k(t),
* ``M^{-1} B_j`` for boundaries with a prescribed outer state (e.g. exact solutions),

so a stage costs one sparse mat-vec plus a few vector updates.  Crack
interfaces (:mod:`hydrofrac.interface`) add their nonlinear facet terms through
the ``extensions`` hook and integrate their state ``z`` with the same stages.
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from typing import Dict, Optional, Sequence, Union

import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from . import compat
from ._jit import njit
from .boundary import (Absorbing, BoundaryCondition, OuterState, Traction, Velocity, boundary_tags, check_boundary_tags,
                       ufl_data)
from .element import CellGeometry, reference_element
from .forms import elastodynamics as ef
from .energy import BlowUpError, EnergyAccount, EnergyBudget  # noqa: F401  (BlowUpError: raised here)
from .material import Material, plane_strain_kappa

#: Documented CFL constant C per scheme: dt = C h_min / ((2p + 1) c_d), h_min = smallest
#: inscribed-circle diameter over the cells (with each cell's c_d).
#:
#: Calibration (tests/cfl_calibration.py): the largest stable C_max is the largest dt
#: with |R(dt lambda)| <= 1 for every eigenvalue lambda of A = M^-1 K (R: the scheme's
#: stability polynomial), in units of h_min/((2p + 1) c_d).  On an infinite structured
#: mesh (von Neumann symbol of A on a periodic cell of the mesh), rock (nu = 0.2):
#:
#:   ======================  =====  =====  =====  =====
#:   C_max                   p = 1  p = 2  p = 3  p = 4
#:   ======================  =====  =====  =====  =====
#:   rk4, "right" diagonals  1.160  1.088  1.047  0.935
#:   rk4, "crossed"          1.263  1.188  1.129  1.016
#:   ssprk3, "right"         1.047  0.981  0.944  0.844
#:   ssprk3, "crossed"       1.139  1.071  1.018  0.916
#:   ======================  =====  =====  =====  =====
#:
#: Finite meshes allow more (16 x 16 "right", rk4: 1.177, 1.103, 1.058, 0.947; a Gmsh
#: mesh: 1.52, 1.41, 1.35, 1.20; perturbed structured meshes, where h_min is set by the
#: worst cell: >= 1.57).  The constants below are stable with a margin of 10 % (rk4) / 9 %
#: (ssprk3) at p = 4 and >= 23 % / 22 % at p <= 3 for rock; over nu in [-0.5, 0.45] the
#: p = 4 limit stays >= 0.888 (rk4) and >= 0.801 (ssprk3), 4 % above C.  1.5 C exceeds C_max of
#: the structured meshes for p <= 3 (rk4: 1.275, ssprk3: 1.155), so a run at 1.5 C
#: blows up and is stopped by :meth:`Solver.check_stability`
#: (tests/test_bulk.py::test_cfl_*).
#: The low-storage schemes (tests/cfl_calibration.py, infinite meshes): C_max "right" p = 1..4:
#: lsrk54 1.845, 1.787, 1.671, 1.531; lsrk144 5.000, 4.687, 4.509, 4.030 ("crossed" higher).
#: Per operator application (C_max / stages) both beat rk4 (0.234-0.290): lsrk54 by 1.27-1.31x,
#: lsrk144 by 1.23x.  Their constants keep rk4's ratio to the p = 4 "right" limit (0.909).
CFL_DEFAULT = {"rk4": 0.85, "ssprk3": 0.77, "lsrk54": 1.39, "lsrk144": 3.66}

#: Butcher tableaux (a, b, c) of the explicit schemes.
TABLEAUX = {
    "rk4": ([[], [0.5], [0.0, 0.5], [0.0, 0.0, 1.0]], [1 / 6, 1 / 3, 1 / 3, 1 / 6], [0.0, 0.5, 0.5, 1.0]),
    "ssprk3": ([[], [1.0], [0.25, 0.25]], [1 / 6, 1 / 6, 2 / 3], [0.0, 1.0, 0.5]),
}

#: Low-storage (2N) schemes (Williamson form): per stage s, dQ <- A_s dQ + dt f(Q, t + C_s dt),
#: Q <- Q + B_s dQ, with two registers whatever the stage count.
#: lsrk54: Carpenter & Kennedy (1994), NASA TM-109112, the (5,4) 2N solution 3;
#: lsrk144: Niegemann, Diehl & Busch (2012), J. Comput. Phys. 231, 364, the 14-stage 4th-order
#: scheme with a stability region optimised for DG wave propagation.
LOW_STORAGE = {
    "lsrk54": (
        (0.0, -567301805773 / 1357537059087, -2404267990393 / 2016746695238, -3550918686646 / 2091501179385,
         -1275806237668 / 842570457699),
        (1432997174477 / 9575080441755, 5161836677717 / 13612068292357, 1720146321549 / 2090206949498,
         3134564353537 / 4481467310338, 2277821191437 / 14882151754819),
        (0.0, 1432997174477 / 9575080441755, 2526269341429 / 6820363962896, 2006345519317 / 3224310063776,
         2802321613138 / 2924317926251)),
    "lsrk144": (
        (0.0, -0.7188012108672410, -0.7785331173421570, -0.0053282796654044, -0.8552979934029281,
         -3.9564138245774565, -1.5780575380587385, -2.0837094552574054, -0.7483334182761610,
         -0.7032861106563359, 0.0013917096117681, -0.0932075369637460, -0.9514200470875948,
         -7.1151571693922548),
        (0.0367762454319673, 0.3136296607553959, 0.1531848691869027, 0.0030097086818182, 0.3326293790646110,
         0.2440251405350864, 0.3718879239592277, 0.6204126221582444, 0.1524043173028741, 0.0760894927419266,
         0.0077604214040978, 0.0024647284755382, 0.0780348340049386, 5.5059777270269628),
        (0.0, 0.0367762454319673, 0.1249685262725025, 0.2446177702277698, 0.2476149531070420,
         0.2969311120382472, 0.3978149645802642, 0.5270854589440328, 0.6981269994175695, 0.8190890835352128,
         0.8527059887098624, 0.8604711817462826, 0.8627060376969976, 0.8734213127600976)),
}


#: ADER (arbitrary high-order derivatives) one-step scheme, as SeisSol
#: uses for linear elastodynamics (Dumbser & Käser 2006, Geophys. J. Int. 167, 319): per
#: step, a cell-local Taylor predictor from p applications of the local strong-form
#: operator D (Cauchy-Kovalevskaya; D^(p+1) = 0 on P_p, so the local series is exact), its
#: time integral I = sum_k dt^(k+1)/(k+1)! D^k x, and one corrector x += L(I) with the
#: boundary data integrated over the step (Gauss-Legendre).  Order p + 1 in space and time.
#: C_max from the spectral radius of the amplification symbol I + C A(theta) P(C D),
#: P(z) = sum_k z^k/(k+1)!, on infinite structured meshes (tests/cfl_calibration.py), rock:
#: "right" p = 1..4: 0.813, 0.762, 0.707, 0.624; "crossed" p = 1..3: 0.895, 0.828, 0.766.
#: Per application (C_max/(p + 1), the local derivatives counted as full ones) that is
#: 0.41, 0.25, 0.18, 0.12, but a local derivative costs about half a full application.  The
#: constants are 0.90 of the "right" limit (rk4's margin at p = 4); 1.5 C blows up and is
#: stopped (tests/test_bulk.py::test_cfl_*).  Crack interfaces (nonlinear, with their own
#: state) take their flux at the stages of a Runge-Kutta scheme of ADER's order, from the
#: cells' predictor, as SeisSol's dynamic rupture takes its friction law at time points of the
#: step (:meth:`hydrofrac.interface.Interface.ader_step`).
ADER = "ader"
ADER_CFL = {1: 0.73, 2: 0.69, 3: 0.64, 4: 0.56}


#: every time scheme the solver has
SCHEMES = tuple(TABLEAUX) + tuple(LOW_STORAGE) + (ADER,)


def default_cfl(scheme: str, degree: int) -> float:
    """The documented stable CFL constant of ``scheme`` at degree p (:data:`CFL_DEFAULT`,
    :data:`ADER_CFL`)."""
    return ADER_CFL[degree] if scheme == ADER else CFL_DEFAULT[scheme]


def num_stages(scheme: str, degree: Optional[int] = None) -> int:
    """Operator applications per step of ``scheme`` (ADER: p local derivatives and one
    full application, counted alike)."""
    if scheme == ADER:
        if degree is None:
            raise ValueError("the ADER step's work depends on the degree: pass degree")
        return degree + 1
    return len(LOW_STORAGE[scheme][1]) if scheme in LOW_STORAGE else len(TABLEAUX[scheme][1])


def _combination(terms):
    """sum c k over the Runge-Kutta ``terms`` [(c, k)], or None for none."""
    if not terms:
        return None
    out = terms[0][0] * terms[0][1]
    for c, k in terms[1:]:
        out += c * k
    return out


BULK_FACET = 1
MAX_DEGREE = 4
class Timers:
    """Wall-time split of a run, in seconds per named part."""

    def __init__(self):
        self.t: Dict[str, float] = {}

    def add(self, name, dt):
        self.t[name] = self.t.get(name, 0.0) + dt


@njit
def _axpy_into(y, x, c, k):
    """y = x + c k (one pass over three vectors; PETSc needs a copy and an axpy)."""
    for i in range(y.size):
        y[i] = x[i] + c * k[i]


def _to_baij(A, bs):
    """Re-pack an AIJ matrix with bs x bs block structure as BAIJ (one column index per
    block: ~3x faster mat-vec than AIJ here; PETSc's MatConvert is far slower than this)."""
    indptr, cols, vals = A.getValuesCSR()
    nrows = indptr.size - 1
    rows = np.repeat(np.arange(nrows), np.diff(indptr))
    brow, bcol = rows // bs, cols // bs
    ncb = A.getSize()[1] // bs + 1
    key = brow.astype(np.int64) * ncb + bcol
    ukey, inv = np.unique(key, return_inverse=True)
    bvals = np.zeros((ukey.size, bs, bs))
    bvals[inv, rows % bs, cols % bs] = vals
    ub_row = ukey // ncb
    ub_col = (ukey % ncb).astype(PETSc.IntType)
    bindptr = np.searchsorted(ub_row, np.arange(nrows // bs + 1)).astype(PETSc.IntType)
    B = PETSc.Mat().createBAIJ(size=A.getSizes(), bsize=bs, csr=(bindptr, ub_col, bvals.reshape(-1)),
                               comm=A.getComm())
    B.assemble()
    A.destroy()
    return B


def set_outer_state(bc, uext, where, t):
    """The outer state of ``bc`` at time t into ``uext`` at the dof blocks ``where`` (the
    boundary cells'; the other entries stay zero and are not read)."""
    blocks, X = where
    compat.function_array(uext).reshape(-1, 5)[blocks] = np.asarray(bc.state(X, t)).T


def _nonzeros(vec):
    """(indices, values) of the nonzero owned entries of a PETSc vector."""
    a = vec.array_r
    idx = np.flatnonzero(a)
    return idx, a[idx].copy()


class Solver:
    """DG P_p velocity-stress solver on an affine triangle mesh.

    Parameters
    ----------
    mesh : DOLFINx mesh (triangles, ghost mode shared_facet)
    degree : polynomial degree p, 1..4
    materials : a :class:`Material`, or ``{cell_tag: Material}`` with ``cell_tags``
    bcs : boundary conditions (:mod:`hydrofrac.boundary`); untagged exterior
        facets are traction-free
    sigma0 : initial (and reference) stress, symmetric 2x2 [Pa]
    cfl : CFL constant (default :func:`default_cfl`)
    dt : fixed time step; must not exceed the stability limit
    scheme : "rk4" (default), "ssprk3", a low-storage scheme "lsrk54" / "lsrk144"
        (:data:`LOW_STORAGE`), or "ader" (:data:`ADER`: matrix-free)
    crack_facets : local facet indices excluded from the bulk upwind flux (crack
        interfaces carry their own flux, :mod:`hydrofrac.interface`)
    relaxation : dynamic-relaxation damping c [1/s] (rho dv/dt = div sigma - c rho v),
        0 for physical dynamics; only to reach static states quickly (e.g. the
        Sneddon verification).  Its dissipation is reported separately.
    allow_unstable : accept a ``cfl`` above :data:`CFL_DEFAULT` (stability studies only: the
        run may blow up, and :meth:`check_stability` stops it)
    operator : "matfree" (default: cell-local compiled kernels for the volume terms, the
        interior upwind flux and the boundary fluxes, :mod:`hydrofrac.matfree`; nothing is
        assembled) or "assembled" (the whole A = M^{-1} K as one PETSc BAIJ matrix,
        assembled from the UFL forms).  Both give the same results to round-off.
    """

    def __init__(self, mesh, degree: int, materials: Union[Material, Dict[int, Material]],
                 cell_tags=None, facet_tags=None, bcs: Sequence[BoundaryCondition] = (),
                 sigma0=((0.0, 0.0), (0.0, 0.0)), cfl: Optional[float] = None, dt: Optional[float] = None,
                 scheme: str = "rk4", crack_facets: Optional[np.ndarray] = None, relaxation: float = 0.0,
                 operator: str = "matfree", allow_unstable: bool = False):
        t_setup = time.perf_counter()
        self.mesh = mesh
        self.comm = mesh.comm
        if not isinstance(degree, (int, np.integer)) or not 1 <= degree <= MAX_DEGREE:
            raise ValueError(f"degree p must be an integer in 1..{MAX_DEGREE}; got {degree!r}")
        if operator not in ("matfree", "assembled"):
            raise ValueError(f"operator must be 'matfree' or 'assembled'; got {operator!r}")
        if operator == "matfree":
            from .matfree import IMPLEMENTED_FORMS, implements_forms
            if not implements_forms():
                operator = "assembled"
                if self.comm.rank == 0:
                    print("[hydrofrac] the bulk forms in forms/elastodynamics.py differ from the ones the matrix-free "
                          f"kernels implement ({', '.join(IMPLEMENTED_FORMS)}): using the operator assembled from "
                          "the edited forms", flush=True)
        self.operator = operator
        if scheme not in SCHEMES:
            raise ValueError(f"scheme must be one of {list(SCHEMES)}; got {scheme!r}")
        if scheme == ADER and operator != "matfree":
            raise ValueError("scheme 'ader' needs the matrix-free operator (its predictor is the cell-local volume "
                             "kernel): use operator='matfree' with the forms the kernels implement, or a Runge-Kutta "
                             "scheme")
        if scheme == ADER and relaxation:
            raise ValueError("scheme 'ader' has no dynamic relaxation: use relaxation=0, or a Runge-Kutta scheme")
        self.degree = int(degree)
        self.scheme = scheme
        self.sigma0 = np.asarray(sigma0, dtype=float)
        if self.sigma0.shape != (2, 2) or not np.allclose(self.sigma0, self.sigma0.T):
            raise ValueError(f"sigma0 must be a symmetric 2x2 stress; got {sigma0!r}")
        self.facet_tags = facet_tags
        self.bcs = list(bcs)
        check_boundary_tags(self.comm, facet_tags, self.bcs)
        self.timers = Timers()

        self.geometry = CellGeometry(mesh)
        self.V = compat.dg_space(mesh, self.degree, ef.NCOMP)
        self.ref = reference_element(self.V, self.geometry)
        self._setup_materials(materials, cell_tags)

        # CFL
        h_over_c = self.geometry.inradius * 2.0 / self.cd_cell
        nloc = compat.num_cells_local(mesh)
        local_min = h_over_c[:nloc].min() if nloc else np.inf
        self.h_over_c_min = self.comm.allreduce(local_min, op=MPI.MIN)
        c_def = default_cfl(scheme, self.degree)
        self.cfl = c_def if cfl is None else float(cfl)
        if not self.cfl > 0:
            raise ValueError(f"cfl must be > 0; got {cfl}")
        if self.cfl > c_def * (1 + 1e-12) and not allow_unstable:
            raise ValueError(f"cfl = {self.cfl:g} is above the documented stable value {c_def} of "
                             f"{scheme} (CFL_DEFAULT / ADER_CFL, calibrated in docs/verification.md); use cfl <= "
                             f"{c_def}, or allow_unstable=True for a stability study")
        self.dt_stable = c_def * self.h_over_c_min / (2 * self.degree + 1)
        if dt is None:
            self.dt = self.cfl * self.h_over_c_min / (2 * self.degree + 1)
        else:
            if not dt > 0:
                raise ValueError(f"dt must be > 0; got {dt}")
            if dt > self.dt_stable * (1 + 1e-12):
                raise ValueError(
                    f"dt = {dt:.4g} s is above the stability limit {self.dt_stable:.4g} s of this mesh "
                    f"(CFL {c_def} * h_min/((2p+1) c_d) with h_min/c_d = {self.h_over_c_min:.4g} s); "
                    f"use dt <= {self.dt_stable:.4g} or leave dt unset")
            self.dt = float(dt)

        if not relaxation >= 0:
            raise ValueError(f"relaxation (damping rate) must be >= 0 1/s; got {relaxation}")
        self.relaxation = float(relaxation)
        self.crack_facets = np.zeros(0, dtype=np.int32) if crack_facets is None else np.asarray(crack_facets, np.int32)
        self._build_operators()
        self.extensions = []
        self._ader_next = None  # (x's state, dt) for which the ADER predictor in _work[0] holds
        self._x_ghosts = None  # x's PETSc state when its ghosts were last updated (update_ghosts)
        self.t = 0.0
        self.step_count = 0
        self.energy = EnergyBudget()
        self.x = compat.create_vector(self.V)
        self.set_initial_state()
        self.timers.add("setup", time.perf_counter() - t_setup)

    # ------------------------------------------------------------------ set-up
    def _setup_materials(self, materials, cell_tags):
        ncells = compat.num_cells_with_ghosts(self.mesh)
        if isinstance(materials, Material):
            cell_mat = np.zeros(ncells, dtype=np.int32)
            order = [materials]
        else:
            if cell_tags is None:
                raise ValueError("materials given per cell tag need cell_tags")
            order = list(materials.values())
            tag_index = {tag: i for i, tag in enumerate(materials)}
            cell_mat = np.full(ncells, -1, dtype=np.int32)
            for tag, i in tag_index.items():
                cell_mat[cell_tags.indices[cell_tags.values == tag]] = i
            compat.require_tags(self.comm, cell_tags, materials, "material cell", "the mesh's cell tags",
                                "give a Material for the cell tags of the mesh")
            nloc = compat.num_cells_local(self.mesh)
            if np.any(cell_mat[:nloc] < 0):
                raise ValueError("some cells have a tag without a material; give a Material for every cell tag")
        self.materials = order
        self.cell_material = cell_mat
        self._coefficients = None  # (rho, lambda, mu) as DG0 Functions, made when a form needs them
        self.cd_cell = np.array([m.cd for m in order])[np.maximum(cell_mat, 0)]
        self.rho_cell = np.array([m.rho for m in order])[np.maximum(cell_mat, 0)]
        self.lam_cell = np.array([m.lam for m in order])[np.maximum(cell_mat, 0)]
        self.mu_cell = np.array([m.mu for m in order])[np.maximum(cell_mat, 0)]

    @property
    def rho(self):
        """The density as a DG0 Function (for UFL forms; the kernels use ``rho_cell``)."""
        return self._material_functions()[0]

    @property
    def lam(self):
        """Lame's lambda as a DG0 Function (for UFL forms; the kernels use ``lam_cell``)."""
        return self._material_functions()[1]

    @property
    def mu(self):
        """The shear modulus as a DG0 Function (for UFL forms; the kernels use ``mu_cell``)."""
        return self._material_functions()[2]

    def _material_functions(self):
        """(rho, lambda, mu) per cell as DG0 Functions, made on first use: the assembled operator,
        its energy forms and forms a user writes need them; the matrix-free kernels do not, so a
        remesh with them builds no DG0 space (collective: every rank asks at the same point)."""
        if self._coefficients is None:
            Q0 = compat.dg_space(self.mesh, 0)
            fs = tuple(compat.function(Q0, n) for n in ("rho", "lambda", "mu"))
            q0dofs = compat.cell_dofs(Q0)[:, 0]
            for f, vals in zip(fs, (self.rho_cell, self.lam_cell, self.mu_cell)):
                compat.function_array(f)[q0dofs] = vals
                compat.scatter_forward(f)
            self._coefficients = fs
        return self._coefficients

    def _bulk_facets(self):
        """Local indices of the interior facets that carry the bulk upwind flux."""
        nf = compat.num_facets_with_ghosts(self.mesh)
        interior = np.ones(nf, dtype=bool)
        interior[compat.exterior_facet_indices(self.mesh)] = False
        interior[self.crack_facets] = False
        return np.flatnonzero(interior)

    def _interior_facet_tags(self):
        tdim = self.mesh.topology.dim
        idx = self._bulk_facets()
        return compat.meshtags(self.mesh, tdim - 1, idx, np.full(idx.size, BULK_FACET))

    def _build_operators(self):
        mesh, V = self.mesh, self.V
        U, W = ufl.TrialFunction(V), ufl.TestFunction(V)
        Z5 = ufl.as_vector([0.0] * ef.NCOMP)
        dx = compat.measure("dx", mesh)
        dS = compat.measure("dS", mesh, self._interior_facet_tags())
        btags, free_tag = boundary_tags(mesh, facet_tags=self.facet_tags, bcs=self.bcs)
        ds = compat.measure("ds", mesh, btags)
        n = ufl.FacetNormal(mesh)

        self._mass_factors()
        self._M = None
        self.A = self.B = self.matfree = None
        self.c0, self.c_hist, self.outer, self._loads = None, [], [], []
        if self.operator == "matfree":
            # the boundary facets in the kernel too: nothing is assembled (docs/benchmarks.md)
            from .matfree import MatrixFreeOperator
            self.matfree = MatrixFreeOperator(self, self._bulk_facets())
            facets, bc_of = self._boundary_facets(btags)
            self.matfree.set_boundary(facets, bc_of, self.bcs)
            self._work = [self.x_like() for _ in range(self._registers())]
            self.account = EnergyAccount(self, ds, free_tag, n)
            return

        rho, lam, mu = self.rho, self.lam, self.mu
        a_bulk = ef.volume(U, W, dx) + ef.interior_flux(U, W, rho, lam, mu, dS(BULK_FACET))
        a_bdry = None
        homog = {"traction": 0.0, "velocity": 0.0, "state": (0.0, 0.0)}
        for bc in self.bcs:
            hd = tuple(homog[k] for k in bc.kinds)
            term = ef.boundary_flux(U, W, rho, lam, mu, n, bc.kinds, hd, ds(bc.tag))
            a_bdry = term if a_bdry is None else a_bdry + term
        # traction-free on untagged exterior facets
        if free_tag is not None:
            term = ef.boundary_flux(U, W, rho, lam, mu, n, ("traction", "traction"), (0.0, 0.0), ds(free_tag))
            a_bdry = term if a_bdry is None else a_bdry + term

        self.Minv = self._inverse_mass()
        K = compat.assemble_matrix(compat.form(a_bulk if a_bdry is None else a_bulk + a_bdry))
        self.A = _to_baij(self.Minv.matMult(K), ef.NCOMP)
        K.destroy()

        # loads: constant part, history-scaled parts (history, vector), outer states (bc,
        # Function uext, M^{-1} B, points)
        Lconst = None
        for bc in self.bcs:
            if isinstance(bc, (Traction, Velocity, Absorbing)):
                data = ufl_data(bc, n)
                if isinstance(bc, Traction):
                    L = ef.boundary_flux(Z5, W, rho, lam, mu, n, bc.kinds, data, ds(bc.tag))
                    Lconst = L if Lconst is None else Lconst + L
                    Lp = ef.boundary_flux(Z5, W, rho, lam, mu, n, bc.kinds, ufl_data(bc, n, unit=True), ds(bc.tag))
                    self.c_hist.append((bc.pressure, self._minv_vector(Lp)))
                elif isinstance(bc, Velocity) and bc.history is not None:
                    Lv = ef.boundary_flux(Z5, W, rho, lam, mu, n, bc.kinds, data, ds(bc.tag))
                    self.c_hist.append((bc.history, self._minv_vector(Lv)))
                else:
                    L = ef.boundary_flux(Z5, W, rho, lam, mu, n, bc.kinds, data, ds(bc.tag))
                    Lconst = L if Lconst is None else Lconst + L
            elif isinstance(bc, OuterState):
                uext = compat.function(V, f"outer_{bc.tag}")
                Uext = ufl.TrialFunction(V)
                Bf = ef.boundary_flux(Z5, W, rho, lam, mu, n, bc.kinds, ufl_data(bc, n, uext=Uext), ds(bc.tag))
                B = compat.assemble_matrix(compat.form(Bf))
                MB = self.Minv.matMult(B)
                B.destroy()
                self.outer.append((bc, uext, MB, self._outer_points(bc.tag)))
        if Lconst is not None:
            self.c0 = self._minv_vector(Lconst)
        # the load vectors are zero outside the cells on loaded boundaries: added by their
        # nonzero entries (full-length axpys cost ~3 % of the intersection scenario's rhs)
        self._loads = ([] if self.c0 is None else [(None, _nonzeros(self.c0))]) + [
            (hist, _nonzeros(c)) for hist, c in self.c_hist]

        self._work = [self.x_like() for _ in range(self._registers())]
        self.account = EnergyAccount(self, ds, free_tag, n)

    def _registers(self):
        """Work vectors of the scheme: 2 (low-storage, ADER: the integral and its rate), or
        the stages and the stage input, and with the assembled operator one more (its energy
        forms use the last two: :meth:`EnergyAccount.energies`)."""
        if self.scheme in LOW_STORAGE or self.scheme == ADER:
            return 2
        return num_stages(self.scheme) + (1 if self.matfree is not None else 2)

    def _boundary_facets(self, btags):
        """The exterior facets of the owned cells, and the boundary condition of each (None:
        traction-free, as on facets without a condition's tag)."""
        nloc = compat.num_cells_local(self.mesh)
        facets = compat.exterior_facet_indices(self.mesh)
        facets = facets[compat.facet_cells(self.mesh, facets) < nloc]
        by_tag = {bc.tag: bc for bc in self.bcs}
        tag_of = np.full(compat.num_facets_with_ghosts(self.mesh), -1, dtype=np.int64)
        if btags is not None:
            tag_of[btags.indices] = btags.values
        return facets, [by_tag.get(int(tag)) for tag in tag_of[facets]]

    def _mass_factors(self):
        """The per-cell factors of the block-diagonal mass matrix: M_c = |det J| M_ref kron B_c.

        B_c is the 5x5 material block: rho for v, the plane-strain compliance for
        (s_xx, s_yy, s_xy) with the factor 2 of the shear term in C^{-1} sigma : tau.
        """
        nloc = compat.num_cells_local(self.mesh)
        # one block per material, then per cell (the same values as cell by cell)
        rho, lam, mu = (np.array([getattr(m, k) for m in self.materials], dtype=float) for k in ("rho", "lam", "mu"))
        kappa = plane_strain_kappa(lam, mu)
        B = np.zeros((len(self.materials), 5, 5))
        B[:, 0, 0] = B[:, 1, 1] = rho
        c = 1.0 / (2 * mu)
        B[:, 2, 2] = B[:, 3, 3] = c * (1 - kappa)
        B[:, 2, 3] = B[:, 3, 2] = -c * kappa
        B[:, 4, 4] = 2 * c
        which = np.maximum(self.cell_material, 0)
        self.material_blocks = np.ascontiguousarray(B[which])  # per cell: rho for v, compliance for sigma
        self.material_blocks_inv = np.ascontiguousarray(np.linalg.inv(B)[which])
        from .matfree import reference_data  # (the element's data, computed once per element)
        self.Mref_inv = reference_data(self.ref).Mref_inv
        absdet = np.abs(self.geometry.detJ)
        self._absdet_own = absdet[:nloc].copy()  # for M (built on first use)
        # M_c^{-1} = Mref_inv kron Binv_scaled[c] (all cells incl. ghosts), for cell-local kernels
        self.Binv_scaled = np.ascontiguousarray(self.material_blocks_inv / absdet[:, None, None])

    def _inverse_mass(self):
        """Block-diagonal M^{-1} in closed form: per owned cell (M_ref^{-1} kron B_c^{-1}) / |det J|."""
        nloc = self._absdet_own.size
        nd = self.Mref_inv.shape[0] * 5
        return self._block_diag_matrix(np.einsum("ij,cab->ciajb", self.Mref_inv,
                                                 self.Binv_scaled[:nloc]).reshape(-1, nd, nd))

    @property
    def M(self):
        """The mass matrix (BAIJ), built on first use: the matrix-free operator and its energy
        kernel do not need it, and it was 40 % of a remesh's set-up at the --quick sizes."""
        if self._M is None:
            nloc = self._absdet_own.size
            nd = self.Mref_inv.shape[0] * 5
            blocks = (np.einsum("ij,cab->ciajb", self.ref.mass(), self.material_blocks[:nloc])
                      * self._absdet_own[:, None, None, None, None]).reshape(-1, nd, nd)
            self._M = _to_baij(self._block_diag_matrix(blocks), ef.NCOMP)
        return self._M

    def _block_diag_matrix(self, blocks):
        """PETSc AIJ matrix with the per-owned-cell dense blocks on the diagonal."""
        nloc = blocks.shape[0]
        nd = blocks.shape[1]
        dofs = compat.cell_dofs(self.V)[:nloc]
        own, _, bs, _ = compat.dof_counts(self.V)
        rstart = compat.index_offset(self.V) * bs
        rows = (dofs[:, :, None] * bs + np.arange(bs)).reshape(nloc, nd)  # local dof index per cell
        n = own * bs
        if n == nloc * nd and np.array_equal(rows.reshape(-1), np.arange(n)):
            # DOLFINx numbers DG dofs cell by cell, in order: the blocks are the CSR rows as
            # they are (no sorting; 0.25 -> 0.03 s on a 3300-cell mesh at p = 2)
            cols = rows[np.repeat(np.arange(nloc), nd)] + rstart
            vals = np.ascontiguousarray(blocks).reshape(-1)
            return self._aij(n, nd, cols, vals)
        order = np.argsort(rows, axis=None)
        flat_rows = rows.reshape(-1)[order]
        # each row's nonzeros are the block row of its cell
        cell_of = np.repeat(np.arange(nloc), nd)[order]
        pos_of = np.tile(np.arange(nd), nloc)[order]
        vals = blocks[cell_of, pos_of, :]
        cols = rows[cell_of] + rstart
        colorder = np.argsort(cols, axis=1)
        vals = np.take_along_axis(vals, colorder, axis=1)
        cols = np.take_along_axis(cols, colorder, axis=1)
        assert np.array_equal(flat_rows, np.arange(n))
        return self._aij(n, nd, cols, vals)

    def _aij(self, n, nd, cols, vals):
        """A PETSc AIJ matrix of n owned rows with nd sorted nonzeros each."""
        indptr = np.arange(0, n * nd + 1, nd, dtype=PETSc.IntType)
        Mat = PETSc.Mat().createAIJ(size=((n, PETSc.DECIDE), (n, PETSc.DECIDE)), bsize=ef.NCOMP,
                                   csr=(indptr, np.ascontiguousarray(cols.reshape(-1), dtype=PETSc.IntType),
                                        np.ascontiguousarray(vals.reshape(-1))), comm=self.comm)
        Mat.assemble()
        return Mat

    def _minv_vector(self, L):
        out = self.x_like()
        if not L.arguments():  # UFL simplified the load to zero (e.g. a zero outer stress)
            out.set(0.0)
            return out
        b = compat.assemble_vector(compat.form(L))
        self.Minv.mult(b, out)
        b.destroy()
        return out

    def _outer_points(self, tag):
        """(dof blocks, coordinates (3, m)) of the cells on the facets tagged ``tag``: the only
        values of an outer state the boundary flux reads (its columns of M^{-1} B)."""
        facets = self.facet_tags.indices[self.facet_tags.values == tag]
        cells = np.unique(compat.facet_cells(self.mesh, facets))
        blocks = np.unique(compat.cell_dofs(self.V)[cells].reshape(-1))
        return blocks, compat.dof_coordinates(self.V)[blocks].T

    def x_like(self):
        return compat.create_vector(self.V)

    def release(self):
        """Free this solver's PETSc objects: the state x, the scheme's work vectors, the crack
        interfaces' residual vectors and, with the assembled operator, its matrices, load
        vectors and the outer states' vectors (:func:`hydrofrac.compat.destroy`: petsc4py frees
        none of them when Python drops the solver).  Collective.  The solver is not used
        afterwards: it is the old solver of a remesh, once the new one holds its fields
        (:func:`hydrofrac.run.run`).  Returns the number of objects freed."""
        objs = [self.x, getattr(self, "x0", None), *getattr(self, "_work", ()), self.A, self._M,
                getattr(self, "Minv", None), self.c0, *(c for _, c in self.c_hist),
                *(o[2] for o in self.outer), *(compat.function_vector_made(o[1]) for o in self.outer),
                getattr(getattr(self, "account", None), "Qd", None)]
        return compat.destroy(*objs, *(getattr(ext, "_r", None) for ext in self.extensions))

    def attach(self, extension):
        """Make ``extension`` (a crack :class:`~hydrofrac.interface.Interface`) part of the
        right-hand side and of the RK stages."""
        if extension in self.extensions:
            raise ValueError("this extension is already attached to the solver")
        if self.scheme == ADER and not hasattr(extension, "ader_step"):
            raise ValueError(f"scheme 'ader' needs extensions with an ADER step; {type(extension).__name__} has "
                             f"none: use a Runge-Kutta scheme (scheme='rk4' or 'lsrk54')")
        self.extensions.append(extension)

    # ------------------------------------------------------------------ state
    @property
    def num_dofs(self):
        return compat.dof_counts(self.V)[3] * ef.NCOMP

    @property
    def num_cells(self):
        return compat.num_cells_global(self.mesh)

    @property
    def num_stages(self):
        return num_stages(self.scheme, self.degree)

    @property
    def state0(self):
        """The uniform initial state (v = 0, sigma0) of a node, (5,)."""
        s = self.sigma0
        return np.array([0.0, 0.0, s[0, 0], s[1, 1], s[0, 1]])

    def state0_array(self):
        """Nodal array (ndofs_local_with_ghosts, 5) of the initial uniform state (v=0, sigma0)."""
        own, ghosts = compat.dof_counts(self.V)[:2]
        return np.tile(self.state0, (own + ghosts, 1))

    def set_initial_state(self, func=None, by_cell=False):
        """Set U from ``func(x (3,m)) -> (5,m)`` (nodal interpolation), default the
        uniform initial stress sigma0 at rest.

        by_cell=True evaluates ``func`` at each cell's centroid and makes the state
        constant per cell: use it for data that jump across a crack or a material
        interface, where a node on the facet belongs to both sides.
        """
        arr = s0 = self.state0_array()
        if func is not None:
            X = compat.dof_coordinates(self.V).T
            if by_cell:
                dofs = compat.cell_dofs(self.V)
                cent = self.geometry.centroid
                X = X.copy()
                X[:2, dofs.reshape(-1)] = np.repeat(cent, dofs.shape[1], axis=0).T
            arr = np.asarray(func(X), dtype=float).T.copy()
        with self.x.localForm() as xl:
            xl.array[:] = arr.reshape(-1)
        if self.matfree is None:  # (the matrix-free energy kernel subtracts state0 itself)
            self.x0 = self.x_like()
            with self.x0.localForm() as xl:
                xl.array[:] = s0.reshape(-1)
        # the energies are those of x - x0: exactly 0 at the uniform initial state (no pass, no
        # reduction; a remesh starts every new solver there before the transfer)
        kin, strain = self.energies() if func is not None else (0.0, 0.0)
        self.energy = EnergyBudget(kinetic=kin, strain=strain, initial=kin + strain)
        self.account.last_rates = None

    def smallest_cell(self):
        """(2 x inradius [m], centroid (x, y)) of the cell that sets the time step, the smallest
        h/c_d over the owned cells of all ranks (collective; the summary's diagnostic)."""
        nloc = compat.num_cells_local(self.mesh)
        h_over_c = self.geometry.inradius[:nloc] * 2.0 / self.cd_cell[:nloc]
        i = int(np.argmin(h_over_c)) if nloc else -1
        _, rank = self.comm.allreduce((float(h_over_c[i]) if nloc else np.inf, self.comm.rank), op=MPI.MINLOC)
        mine = (2.0 * float(self.geometry.inradius[i]), self.geometry.centroid[i, :2].tolist()) if nloc else None
        return self.comm.bcast(mine, root=rank)

    def local_array(self, vec=None):
        """(owned nodes, 5) view of a state vector."""
        vec = self.x if vec is None else vec
        own = compat.dof_counts(self.V)[0]
        return vec.array_r.reshape(own, ef.NCOMP)

    def update_ghosts(self, vec):
        """Forward ghost update of ``vec`` (several ranks); of the state x only if it was written
        since its last update (its PETSc state counter, which every write through ``x.array``,
        a local form or a Vec operation raises, and so does the ghost update itself; the counter
        after the update is kept): the end of a step, the energy budget and the next step's
        first stage read the same x.  Timed as "halo exchange" (waiting for the neighbours
        included); returns those seconds, which a caller that times its own part leaves out."""
        if self.comm.size == 1:
            return 0.0
        if vec is self.x and self._x_ghosts == vec.stateGet():
            return 0.0
        t0 = time.perf_counter()
        before = vec.stateGet()
        self._forward(vec)
        if vec is self.x:
            self._x_ghosts = vec.stateGet()
            self._unchanged(before)
        spent = time.perf_counter() - t0
        self.timers.add("halo exchange", spent)
        return spent

    @staticmethod
    def _forward(vec):
        """The forward ghost update itself (waiting for the neighbours included)."""
        vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def _unchanged(self, before):
        """x's state counter rose from ``before`` without a change of its owned values (a ghost
        update, a read of its local form): ADER's predictor holds, and so do the ghosts if they
        were current."""
        after = self.x.stateGet()
        if self._ader_next is not None and self._ader_next[0] == before:
            self._ader_next = (after, self._ader_next[1])
        if self._x_ghosts == before:
            self._x_ghosts = after

    @contextmanager
    def read_local(self, vec):
        """The local values of ``vec`` with its ghosts, to read (its local form).  On several
        ranks the local form's restore raises the PETSc state counter; for x, a read then keeps
        ADER's predictor and the ghost update valid (:meth:`update_ghosts`)."""
        before = vec.stateGet()
        with vec.localForm() as vl:
            yield vl.array_r
        if vec is self.x:
            self._unchanged(before)

    # ------------------------------------------------------------------ operator
    def rhs(self, y, t, out):
        """out = M^{-1}(K y + b(t)) + interface terms; returns the aux-state rates."""
        t0 = time.perf_counter()
        rates = None
        if self.matfree is not None:
            if self.comm.size > 1:  # (the neighbours' values of y: timed as "halo exchange")
                self.update_ghosts(y)
                t0 = time.perf_counter()
            mf = self.matfree
            with self.read_local(y) as X:
                mf.begin(X, t)
                self.timers.add("bulk operator", time.perf_counter() - t0)
                # crack interfaces add their owned cells' flux before the inverse mass
                rates = [ext.stage_cells(X, t, mf.R) for ext in self.extensions]
                for ext in self.extensions:  # their ghost cells' share travels during the volume pass
                    ext.start_finish()
                t0 = time.perf_counter()
                mf.finish(X, out.array)
        else:
            self.A.mult(y, out)
            if self._loads:
                o = out.array
                for hist, (idx, vals) in self._loads:
                    o[idx] += vals if hist is None else hist(t) * vals
            for bc, uext, MB, where in self.outer:
                set_outer_state(bc, uext, where, t)
                MB.multAdd(compat.function_vector(uext), out, out)
        if self.relaxation:
            yv, ov = y.array_r.reshape(-1, ef.NCOMP), out.array.reshape(-1, ef.NCOMP)
            ov[:, :2] -= self.relaxation * yv[:, :2]
        self.timers.add("bulk operator", time.perf_counter() - t0)
        if rates is not None:
            for ext in self.extensions:
                ext.finish_stage(out)
            return rates
        return [ext.rhs(y, t, out) for ext in self.extensions]

    # ------------------------------------------------------------------ stepping
    def step(self):
        """Advance one time step with the explicit RK scheme (fields and extension states)."""
        if self.scheme in LOW_STORAGE:
            return self._step_2n()
        if self.scheme == ADER:
            return self._step_ader()
        a, b, c = TABLEAUX[self.scheme]
        dt, t, x = self.dt, self.t, self.x
        ks = self._work[: len(b)]
        y = self._work[len(b)]
        zs = [ext.state for ext in self.extensions]
        zk = [[] for _ in self.extensions]
        for i in range(len(b)):
            t0 = time.perf_counter()
            terms = [(dt * aij, ks[j]) for j, aij in enumerate(a[i]) if aij]
            yi = y
            if not terms:  # the first stage reads x itself (the operator only reads its input)
                yi = x
            elif len(terms) == 1:  # y = x + c k in one pass (RK4's other stages)
                _axpy_into(y.array, x.array_r, terms[0][0], terms[0][1].array_r)
            else:
                x.copy(y)
                y.maxpy([c for c, _ in terms], [k for _, k in terms])
            for e, ext in enumerate(self.extensions):
                ext.stage_state = ext.advance(zs[e], _combination([(dt * aij, zk[e][j])
                                                                   for j, aij in enumerate(a[i]) if aij]))
            if self.extensions and self.matfree is None:  # (the matrix-free rhs updates them itself)
                yi.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
            self.timers.add("rk update", time.perf_counter() - t0)
            rates = self.rhs(yi, t + c[i] * dt, ks[i])
            for e in range(len(self.extensions)):
                zk[e].append(rates[e])
        t0 = time.perf_counter()
        x.maxpy([dt * bi for bi in b], ks)
        for e, ext in enumerate(self.extensions):
            ext.state = ext.advance(zs[e], _combination([(dt * bi, k) for bi, k in zip(b, zk[e]) if bi]))
        self.timers.add("rk update", time.perf_counter() - t0)
        for ext in self.extensions:  # (timed as "state update")
            ext.end_step(x, self.t + dt, dt)
        self.t += dt
        self.step_count += 1

    def _step_2n(self):
        """One step of a low-storage scheme (:data:`LOW_STORAGE`): the fields in place with one
        extra register; each extension's state from its step-start value and the accumulated
        increment (``advance``), so that it stays admissible at every stage."""
        A, B, C = LOW_STORAGE[self.scheme]
        dt, t, x = self.dt, self.t, self.x
        dQ, k = self._work[0], self._work[1]
        zs = [ext.state for ext in self.extensions]
        zd = [None] * len(self.extensions)  # the extensions' dQ registers
        inc = [None] * len(self.extensions)  # their accumulated increments Q_s - Q_n
        for s_ in range(len(B)):
            t0 = time.perf_counter()
            if self.extensions and self.matfree is None:
                x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
            self.timers.add("rk update", time.perf_counter() - t0)
            rates = self.rhs(x, t + C[s_] * dt, k)
            t0 = time.perf_counter()
            if s_ == 0:  # (A_1 = 0)
                k.copy(dQ)
                dQ.scale(dt)
            else:
                dQ.axpby(dt, A[s_], k)  # dQ = A_s dQ + dt k
            x.axpy(B[s_], dQ)
            for e, ext in enumerate(self.extensions):
                zd[e] = dt * rates[e] if s_ == 0 else A[s_] * zd[e] + dt * rates[e]
                inc[e] = B[s_] * zd[e] if s_ == 0 else inc[e] + B[s_] * zd[e]
                ext.stage_state = ext.advance(zs[e], inc[e])
            self.timers.add("rk update", time.perf_counter() - t0)
        for ext in self.extensions:  # (timed as "state update")
            ext.state = ext.stage_state
            ext.end_step(x, self.t + dt, dt)
        self.t += dt
        self.step_count += 1

    def _step_ader(self):
        """One ADER step (:data:`ADER`): the predictor's time integral I over the step from p
        cell-local derivatives, one ghost update of I, the facet fluxes of I with the boundary
        data integrated over the step, and x += M^{-1}(K I + those data).  The corrector's
        pass also computes the next step's I; it is reused while x and dt are unchanged
        (x's PETSc state counter: any write through ``x.array`` or a local form invalidates it;
        :meth:`read_local` reads keep it).  Crack interfaces first add their flux integrated over
        the step to the corrector's residual (:meth:`~hydrofrac.interface.Interface.ader_step`),
        and take their new state after it."""
        t0 = time.perf_counter()
        mf, dt, x = self.matfree, self.dt, self.x
        I, _ = self._work
        if self._ader_next != (x.stateGet(), dt):
            mf.ader_predictor(x.array, I.array, dt, self.degree)
        mf.integrate_boundary_data(self.t, dt, (self.degree + 2) // 2)
        self.timers.add("rk update", time.perf_counter() - t0)
        states = []
        if self.extensions:  # crack interfaces: their flux integrals into R before the facets'
            # (R is clear after the last corrector, so begin() below adds to their share)
            self.update_ghosts(x)

            def taylor(X, Q, cells, taus):
                mf.taylor_values(X, Q, cells, taus, self.degree)

            with self.read_local(x) as X:
                states = [ext.ader_step(X, self.t, dt, mf.R, taylor) for ext in self.extensions]
            for ext in self.extensions:
                ext.fold_received(mf.R)
        if self.comm.size > 1:
            t0 = time.perf_counter()
            I.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
            self.timers.add("halo exchange", time.perf_counter() - t0)
        t0 = time.perf_counter()
        with I.localForm() as il:
            mf.begin(il.array_r, self.t, data=False)
        mf.ader_correct(x.array, I.array, dt, self.degree)
        self._ader_next = (x.stateGet(), dt)
        self.timers.add("bulk operator", time.perf_counter() - t0)
        for ext, z in zip(self.extensions, states):  # (timed as "state update")
            ext.state = z
            ext.end_step(x, self.t + dt, dt)
        self.t += dt
        self.step_count += 1

    # ------------------------------------------------------------------ energy
    def energies(self):
        """(kinetic, strain) energy relative to the initial stress state [J/m]."""
        return self.account.energies()

    def update_energy(self):
        """Advance the energy budget over the last step (:class:`hydrofrac.energy.EnergyAccount`)."""
        return self.account.update()

    def check_stability(self):
        """Raise :class:`BlowUpError` if the run became unstable (:meth:`EnergyAccount.check`)."""
        self.account.check()

    # ------------------------------------------------------------------ info
    def summary(self):
        return {
            "cells": self.num_cells,
            "dofs": self.num_dofs,
            "degree": self.degree,
            "ranks": self.comm.size,
            "scheme": self.scheme,
            "stages_per_step": self.num_stages,
            "dt": self.dt,
            "cfl": self.dt / (self.h_over_c_min / (2 * self.degree + 1)),
            "steps": self.step_count,
            "simulated_time": self.t,
        }
