"""Baseline for the work–precision study: continuous-Galerkin elastodynamics.

What a user would otherwise pick for the bulk wave problems: a displacement formulation
with continuous Lagrange P_k elements (k = 1, 2), a lumped mass matrix and explicit
central differences,

    M_L (u^{n+1} - 2 u^n + u^{n-1}) / dt^2 = -K u^n,

with the exact displacement prescribed on the boundary (Dirichlet).  The mass is lumped by
HRZ scaling of the consistent mass diagonal (positive for P2, where row sums give zero vertex
masses on triangles), or, with ``mass="consistent"``, kept consistent and solved every step
by conjugate gradients with a Jacobi preconditioner (relative tolerance 1e-10): standard P2
triangles lose accuracy when lumped (the measured energy-norm error then falls only like h).  The step is ``cfl * 2 / omega_max`` with omega_max^2 the largest
eigenvalue of M_L^{-1} K (power iteration).  Not a production solver: it exists so that
the DG solver's speed and accuracy are compared with the usual alternative in the same code,
on the same meshes, measured in the same run.
"""
from __future__ import annotations

import math
import time

import numpy as np
import ufl
from mpi4py import MPI

from hydrofrac import compat
from hydrofrac.forms import elastodynamics as ef


def elastic_operators(V, material):
    """(K, M, m) on the CG vector space V: stiffness and consistent mass (assembled PETSc
    matrices) and the HRZ-lumped mass diagonal (local array): the consistent diagonal scaled
    to the total mass (both components)."""
    mesh = V.mesh
    u, w = ufl.TrialFunction(V), ufl.TestFunction(V)
    lam, mu, rho = material.lam, material.mu, material.rho
    eps = lambda a: ufl.sym(ufl.grad(a))  # noqa: E731
    sig = lambda a: lam * ufl.tr(eps(a)) * ufl.Identity(2) + 2 * mu * eps(a)  # noqa: E731
    dx = compat.measure("dx", mesh)
    K = compat.assemble_matrix(compat.form(ufl.inner(sig(u), eps(w)) * dx))
    M = compat.assemble_matrix(compat.form(rho * ufl.inner(u, w) * dx))
    diag = M.getDiagonal()
    d = diag.array_r.copy()
    diag.destroy()
    area = compat.assemble_scalar(compat.form(1.0 * dx), mesh.comm)
    total = mesh.comm.allreduce(float(d.sum()), op=MPI.SUM)
    return K, M, d * (2 * rho * area / total)


class CentralDifferenceCG:
    """Explicit central-difference CG P_k solver with a Dirichlet boundary from an exact
    displacement ``u_exact(x, t)`` (x: (3, m) -> (2, m))."""

    def __init__(self, mesh, degree, material, u_exact, cfl=0.9, mass="lumped"):
        if degree not in (1, 2):
            raise ValueError(f"CG baseline degree must be 1 or 2; got {degree}")
        if mass not in ("lumped", "consistent"):
            raise ValueError(f"CG baseline mass must be 'lumped' or 'consistent'; got {mass!r}")
        self.mass = mass
        self.mesh, self.comm, self.degree, self.mat = mesh, mesh.comm, degree, material
        self.u_exact = u_exact
        V = compat.cg_vector_space(mesh, degree)
        self.V = V
        self.K, M, self.m = elastic_operators(V, material)
        own = compat.dof_counts(V)[0] * 2
        self.ksp = None
        ext = compat.exterior_facet_indices(mesh)
        b = compat.boundary_dofs(V, ext)
        b = b[b < own // 2]
        self.bdofs = np.stack([2 * b, 2 * b + 1], axis=1).reshape(-1)  # same order as the values
        if mass == "consistent":
            from petsc4py import PETSc
            # Dirichlet rows and columns of M become identity rows, so that the boundary rows
            # of K u (which lack the boundary traction) do not pollute the interior
            rstart = compat.index_offset(V) * 2
            M.zeroRowsColumns((self.bdofs + rstart).astype(PETSc.IntType), diag=1.0)
            self.M = M
            self.ksp = PETSc.KSP().create(self.comm)
            self.ksp.setOperators(M)
            self.ksp.setType("cg")
            self.ksp.getPC().setType("jacobi")
            self.ksp.setTolerances(rtol=1e-10, atol=0.0)
            self.acc = compat.create_vector(V)
        else:
            M.destroy()
        X = compat.dof_coordinates(V)[: own // 2].T
        self.Xb = X[:, b]
        self.Xall = X
        self.nb = b.size
        self.x = [compat.create_vector(V) for _ in range(3)]  # u^{n-1}, u^n, scratch
        self.Ku = compat.create_vector(V)
        self.num_dofs = compat.dof_counts(V)[3] * 2
        self.dt = cfl * 2.0 / math.sqrt(self._lambda_max())
        self.t = 0.0

    def _lambda_max(self, iters=60):
        """Largest eigenvalue of M^{-1} K (lumped or consistent M) by power iteration, x1.02."""
        y = self.x[2]
        y0 = np.random.default_rng(self.comm.rank).random(y.array.size)
        y.array[:] = y0 / self.comm.allreduce(float(y0 @ y0), op=MPI.SUM) ** 0.5  # unit vector
        lam = 0.0
        for _ in range(iters):
            self.K.mult(y, self.Ku)
            if self.ksp is None:
                z = self.Ku.array_r / self.m
            else:
                self.Ku.array[self.bdofs] = 0.0
                self.ksp.solve(self.Ku, self.acc)
                z = self.acc.array_r.copy()
            lam = self.comm.allreduce(float(z @ z), op=MPI.SUM) ** 0.5  # |M^-1 K y| with |y| = 1
            y.array[:] = z / lam
        return 1.02 * lam

    def _exact_owned(self, t):
        return np.asarray(self.u_exact(self.Xall, t)).T.reshape(-1)

    def start(self, dt=None):
        """u^{-1}, u^0 from the exact solution."""
        if dt is not None:
            self.dt = dt
        self.x[0].array[:] = self._exact_owned(-self.dt)
        self.x[1].array[:] = self._exact_owned(0.0)
        self.t = 0.0

    def step(self):
        uold, u, unew = self.x
        self.K.mult(u, self.Ku)
        if self.ksp is None:
            unew.array[:] = 2 * u.array_r - uold.array_r - self.dt ** 2 * self.Ku.array_r / self.m
        else:
            self.Ku.array[self.bdofs] = 0.0
            self.ksp.solve(self.Ku, self.acc)  # M a = K u on the interior rows
            unew.array[:] = 2 * u.array_r - uold.array_r - self.dt ** 2 * self.acc.array_r
        self.t += self.dt
        ub = np.asarray(self.u_exact(self.Xb, self.t)).T.reshape(-1)
        unew.array[self.bdofs] = ub
        self.x = [u, unew, uold]

    def state_functions(self):
        """(u^n, v^n) as Functions: v^n = (u^{n+1} - u^{n-1}) / (2 dt) needs one extra step,
        taken on a copy."""
        uold, u, _ = self.x
        saved = (self.x[0].copy(), self.x[1].copy(), self.t)
        self.step()
        unew = self.x[1]
        fu, fv = compat.function(self.V), compat.function(self.V)
        own = compat.function_vector(fu).array.size
        compat.function_vector(fu).array[:] = saved[1].array_r[:own]
        compat.function_vector(fv).array[:] = (unew.array_r - saved[0].array_r)[:own] / (2 * self.dt)
        fu.x.scatter_forward()
        fv.x.scatter_forward()
        self.x[0], self.x[1], self.t = saved[0], saved[1], saved[2]
        return fu, fv

    def energy_error(self, v_exact, sigma_exact, qdeg=None):
        """Relative energy-norm error of (v, sigma) at the current time against UFL
        expressions of the exact fields."""
        fu, fv = self.state_functions()
        lam, mu = self.mat.lam, self.mat.mu
        eps = ufl.sym(ufl.grad(fu))
        sig = lam * ufl.tr(eps) * ufl.Identity(2) + 2 * mu * eps
        return energy_norm_error(self.mesh, self.mat, fv, sig, v_exact, sigma_exact, qdeg or 2 * self.degree + 4)


def energy_norm_error(mesh, mat, v, sigma, v_exact, sigma_exact, qdeg):
    """sqrt(int rho|v - ve|^2 + (s - se):C^-1(s - se)) / sqrt(int rho|ve|^2 + se:C^-1 se)."""
    dx = compat.measure("dx", mesh, metadata={"quadrature_degree": qdeg})
    dv, ds = v - v_exact, sigma - sigma_exact
    err = mat.rho * ufl.inner(dv, dv) + ufl.inner(ef.compliance(ds, mat.lam, mat.mu), ds)
    ref = mat.rho * ufl.inner(v_exact, v_exact) + ufl.inner(ef.compliance(sigma_exact, mat.lam, mat.mu), sigma_exact)
    e = compat.assemble_scalar(compat.form(err * dx), mesh.comm)
    r = compat.assemble_scalar(compat.form(ref * dx), mesh.comm)
    return math.sqrt(max(e, 0.0) / r)


def timed_steps(solver, steps):
    comm = solver.comm
    comm.barrier()
    t0 = time.perf_counter()
    for _ in range(steps):
        solver.step()
    comm.barrier()
    return comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)
