"""Baseline for the crack work–precision studies: continuous-Galerkin elastodynamics with
doubled crack nodes.

What a user without an interface model would do for the two crack verification problems:
take the same mesh, **double the nodes along the crack** (:func:`split_mesh`), and solve
displacement-form elastodynamics with continuous P_k elements (k = 1, 2), an HRZ-lumped mass
and explicit central differences (as :mod:`hydrofrac.cg_baseline`),

    M (u⁺ − 2u + u⁻)/dt² + C (u⁺ − u⁻)/(2 dt) + K u = f(t),

with a diagonal C from Lysmer dashpots on absorbing facets (ρ c_p along n, ρ c_s along t,
row-sum lumped) and an optional mass-proportional damping c M (dynamic relaxation).  The crack
faces are then ordinary boundary facets:

* a **pressurised crack** (Sneddon) carries the traction −p(t) n on both faces;
* **contact** between faces (two-bar impact) is enforced node to node by forward-increment
  Lagrange multipliers (Carpenter, Taylor & Katona 1991), the usual explicit-dynamics contact
  algorithm: after the predictor step every penetrating pair is moved back to zero gap with a
  compressive multiplier λ ≥ 0 that conserves momentum.  No penalty parameter; stable at the
  step of the bulk.

One process only (the node pairs and the crack sampling are local): it is a baseline for
the studies, not a production solver.
"""
from __future__ import annotations

import math

import numpy as np
import ufl
from mpi4py import MPI

from hydrofrac import compat
from .cg_baseline import elastic_operators


def split_mesh(mesh, crack_facets, side):
    """Copy of ``mesh`` (one process) with the nodes of the crack facets doubled: the cells
    whose centroid satisfies ``side(centroid (m, 2)) -> bool`` take the copies.  A crack node
    is doubled if it joins two crack facets or lies on the outer boundary (a crack tip inside
    the domain stays shared).  Straight-sided (affine) triangles."""
    if mesh.comm.size > 1:
        raise ValueError("split_mesh: the CG crack baseline runs on one process")
    x, cells = compat.mesh_arrays(mesh)
    fn = compat.facet_nodes(mesh, crack_facets)
    count = np.bincount(fn.reshape(-1), minlength=len(x))
    ext = np.setdiff1d(compat.exterior_facet_indices(mesh), crack_facets)
    on_boundary = np.zeros(len(x), bool)
    on_boundary[compat.facet_nodes(mesh, ext).reshape(-1)] = True
    double = (count >= 2) | ((count >= 1) & on_boundary)
    copy = np.full(len(x), -1)
    nodes = np.flatnonzero(double)
    copy[nodes] = len(x) + np.arange(nodes.size)
    cells = cells.copy()
    moved = side(x[cells].mean(axis=1))
    sub = cells[moved]
    sub = np.where(copy[sub] >= 0, copy[sub], sub)
    cells[moved] = sub
    return compat.create_mesh(MPI.COMM_SELF, cells, np.vstack([x, x[nodes]]))


def boundary_facets_on(mesh, marker):
    """Exterior facets whose midpoint satisfies ``marker(x (3, m)) -> bool``."""
    return compat.locate_boundary_facets(mesh, marker)


class CrackCG:
    """Explicit central-difference CG P_k (lumped mass) on a split mesh.

    * ``rollers``: list of (facets, component): that displacement component is zero there;
    * ``pressure``: (facets, p(t)): traction −p n on those (crack-face) facets;
    * ``absorbing``: facets with Lysmer dashpots;
    * ``damping``: c [1/s], the mass-proportional damping of dynamic relaxation;
    * ``contact``: (facets_a, facets_b, n): node-to-node contact of matching nodes, n the
      unit normal pointing from side a to side b; the gap n·(u_b − u_a) stays ≥ 0.
    """

    def __init__(self, mesh, degree, material, rollers=(), pressure=None, absorbing=None, damping=0.0,
                 contact=None, cfl=0.9):
        if mesh.comm.size > 1:
            raise ValueError("CrackCG runs on one process (a baseline for the studies)")
        if degree not in (1, 2):
            raise ValueError(f"CG baseline degree must be 1 or 2; got {degree}")
        if damping < 0:
            raise ValueError(f"damping must be >= 0; got {damping}")
        self.mesh, self.comm, self.degree, self.mat = mesh, mesh.comm, degree, material
        V = compat.cg_vector_space(mesh, degree)
        self.V = V
        self.K, M, self.m = elastic_operators(V, material)  # HRZ-lumped mass m
        M.destroy()
        rho = material.rho
        u, w = ufl.TrialFunction(V), ufl.TestFunction(V)
        # tags: 1 pressure, 2 absorbing
        groups = [(np.asarray(pressure[0]) if pressure else np.empty(0, np.int32), 1),
                  (np.asarray(absorbing) if absorbing is not None else np.empty(0, np.int32), 2)]
        ents = np.concatenate([g for g, _ in groups]).astype(np.int32)
        vals = np.concatenate([np.full(g.size, k) for g, k in groups]).astype(np.int32)
        tags = compat.meshtags(mesh, 1, ents, vals)
        ds = compat.measure("ds", mesh, subdomain_data=tags)
        n = ufl.FacetNormal(mesh)
        self.c = damping * self.m
        if absorbing is not None and len(absorbing):
            t = ufl.as_vector((-n[1], n[0]))
            a = rho * (material.cd * ufl.dot(u, n) * ufl.dot(w, n) + material.cs * ufl.dot(u, t) * ufl.dot(w, t)) * ds(2)
            C = compat.assemble_matrix(compat.form(a))
            ones = C.createVecRight()
            ones.set(1.0)
            row = C.createVecLeft()
            C.mult(ones, row)
            self.c = self.c + row.array_r
            C.destroy()
        self.pressure = None
        if pressure is not None:
            self.pressure = pressure[1]
            self.b = compat.assemble_vector(compat.form(-ufl.dot(n, w) * ds(1))).array_r.copy()
        self.fixed = np.concatenate([2 * compat.boundary_dofs(V, f) + comp for f, comp in rollers]) \
            if rollers else np.empty(0, np.int64)
        X = compat.dof_coordinates(V)[:, :2]
        self.X = X
        # each dof's coordinates moved 1e-6 of the way to the centroid of a cell that holds it:
        # initial data defined by side at doubled crack nodes
        cd = compat.cell_dofs(V)
        cent = np.repeat(compat.cell_vertex_coords(mesh).mean(axis=1), cd.shape[1], axis=0)
        toward = np.empty_like(X)
        toward[cd.reshape(-1)] = cent
        self.X_inside = X + 1e-6 * (toward - X)
        self.pairs = None
        if contact is not None:
            fa, fb, nrm = contact
            self.n = np.asarray(nrm, float) / np.linalg.norm(nrm)
            self.pairs = _match(X, compat.boundary_dofs(V, fa), compat.boundary_dofs(V, fb))
            self.contact_length = _facet_length(mesh, fa)
        self.u = [np.zeros(self.m.size) for _ in range(2)]  # u^{n-1}, u^n
        self.work = compat.create_vector(V)
        self.Ku = compat.create_vector(V)
        self.num_dofs = self.m.size
        self.dt = cfl * 2.0 / math.sqrt(self._lambda_max())
        self.t = 0.0
        self.step_count = 0
        self.contact_force = 0.0  # sum of the multipliers of the last step [N/m]

    def _lambda_max(self, iters=60):
        y = np.random.default_rng(0).random(self.m.size)
        y /= np.linalg.norm(y)
        lam = 0.0
        for _ in range(iters):
            z = self._K(y) / self.m
            z[self.fixed] = 0.0
            lam = float(np.linalg.norm(z))
            y = z / lam
        return 1.02 * lam

    def _K(self, u):
        self.work.array[:] = u
        self.K.mult(self.work, self.Ku)
        return self.Ku.array_r

    def set_velocity(self, v):
        """Start at rest displacement with velocity v(X (m, 2)) -> (m, 2) (u^{-1} = -dt v),
        evaluated just inside a cell next to each node (so that doubled crack nodes take
        their own side's value)."""
        vel = np.asarray(v(self.X_inside), float).reshape(-1)
        vel[self.fixed] = 0.0
        self.u = [-self.dt * vel, np.zeros_like(vel)]

    def step(self):
        um, u = self.u
        dt = self.dt
        f = -self._K(u)
        if self.pressure is not None:
            f = f + self.pressure(self.t) * self.b
        meff = self.m + 0.5 * dt * self.c
        up = (dt * dt * f + self.m * (2 * u - um) + 0.5 * dt * self.c * um) / meff
        up[self.fixed] = 0.0
        self.contact_force = 0.0
        if self.pairs is not None:
            ia, ib = self.pairs
            n = self.n
            ua, ub = up.reshape(-1, 2)[ia], up.reshape(-1, 2)[ib]
            gap = (ub - ua) @ n
            ma, mb = meff[2 * ia], meff[2 * ib]
            lam = np.maximum(-gap / (dt * dt * (1 / ma + 1 / mb)), 0.0)
            U = up.reshape(-1, 2)
            U[ia] -= (lam * dt * dt / ma)[:, None] * n
            U[ib] += (lam * dt * dt / mb)[:, None] * n
            self.contact_force = float(lam.sum())
        self.u = [u, up]
        self.t += dt
        self.step_count += 1

    def mean_velocity(self, nodes):
        """Momentum / mass (2,) of the dof blocks selected by the boolean array ``nodes``."""
        v, m = self.velocity().reshape(-1, 2)[nodes], self.m.reshape(-1, 2)[nodes]
        return (m * v).sum(axis=0) / m.sum(axis=0)

    def displacement(self):
        fu = compat.function(self.V)
        compat.function_array(fu)[:] = self.u[1]
        return fu

    def velocity(self):
        """(u^n − u^{n−1}) / dt (backward difference, no extra step)."""
        return (self.u[1] - self.u[0]) / self.dt


def _match(X, da, db):
    """Pairs (ia, ib) of dof blocks of side a and b at the same coordinates."""
    ka = np.lexsort((X[da, 1], X[da, 0]))
    kb = np.lexsort((X[db, 1], X[db, 0]))
    da, db = da[ka], db[kb]
    if da.size != db.size or not np.allclose(X[da], X[db], atol=1e-9 * max(1.0, np.abs(X).max())):
        raise ValueError("contact faces do not have matching nodes")
    return da, db


def _facet_length(mesh, facets):
    xy = mesh.geometry.x[compat.facet_nodes(mesh, facets), :2]
    return float(np.linalg.norm(xy[:, 1] - xy[:, 0], axis=1).sum())


def crack_opening(solver, faces_plus, faces_minus, nq=4):
    """Opening u_y(+) − u_y(−) of a crack along x, sampled at ``nq`` Gauss points of each
    crack facet: returns (points (m, 2), weights (m,), opening (m,)).  ``faces_plus`` /
    ``faces_minus``: the exterior facets of the upper / lower face (matched by midpoint)."""
    mesh = solver.mesh
    xg = mesh.geometry.x[:, :2]
    cp, cm = compat.facet_nodes(mesh, faces_plus), compat.facet_nodes(mesh, faces_minus)
    mp, mm = xg[cp].mean(axis=1), xg[cm].mean(axis=1)
    kp, km = np.lexsort((mp[:, 1], mp[:, 0])), np.lexsort((mm[:, 1], mm[:, 0]))
    fp, fm = np.asarray(faces_plus)[kp], np.asarray(faces_minus)[km]
    ends = xg[cp[kp]]
    g, gw = np.polynomial.legendre.leggauss(nq)
    s = 0.5 * (g + 1)
    pts = (ends[:, None, 0, :] * (1 - s)[None, :, None] + ends[:, None, 1, :] * s[None, :, None]).reshape(-1, 2)
    length = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
    w = (0.5 * gw[None, :] * length[:, None]).reshape(-1)
    u = solver.displacement()
    up = compat.eval_function(u, pts, np.repeat(compat.facet_cells(mesh, fp), nq))[:, 1]
    um = compat.eval_function(u, pts, np.repeat(compat.facet_cells(mesh, fm), nq))[:, 1]
    return pts, w, up - um
