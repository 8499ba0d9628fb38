"""Known answers and small helpers shared by the bulk-solver tests.

* :class:`PlaneWave`: a Gaussian P or S pulse travelling in any direction, as nodal
  values (initial condition, outer state of the boundary Riemann flux) and as UFL
  expressions (L2 errors with quadrature);
* meshes: the unit square and a thin strip along x, with side tags
  (:data:`LEFT`, :data:`RIGHT`, :data:`BOTTOM`, :data:`TOP`);
* measuring: relative L2 errors, the DG fields sampled on a fine lattice of every owned
  cell (peak amplitudes), fitted convergence slopes.

Everything works on any number of MPI ranks (reductions over ``mesh.comm``).
"""
from __future__ import annotations

import numpy as np
import ufl
from mpi4py import MPI

from hydrofrac import compat
from hydrofrac.element import triangle_quadrature
from hydrofrac.material import Material

LEFT, RIGHT, BOTTOM, TOP = 1, 2, 3, 4


class PlaneWave:
    """Gaussian plane pulse ``g(xi) = A exp(-(xi/w)^2)``, ``xi = d.(x - x0) - c t``.

    kind "P": v = d g, speed c_d, sigma = -(lam I + 2 mu d d^T) g / c_d;
    kind "S": v = d_perp g, speed c_s, sigma = -mu (d_perp d^T + d d_perp^T) g / c_s,
    both exact solutions of rho dv/dt = div sigma, dsigma/dt = C : sym grad v.
    ``angle`` is the direction of travel d from the x axis [rad]; ``x0`` the pulse
    centre at t = 0; ``sigma0`` a uniform stress added to the wave's stress.
    """

    def __init__(self, material: Material, kind: str, angle: float, width: float, x0=(0.0, 0.0),
                 amplitude: float = 1.0, sigma0=((0.0, 0.0), (0.0, 0.0))):
        if kind not in ("P", "S"):
            raise ValueError(f"kind must be 'P' or 'S'; got {kind!r}")
        m = material
        self.kind = kind
        self.d = np.array([np.cos(angle), np.sin(angle)])
        dperp = np.array([-self.d[1], self.d[0]])
        if kind == "P":
            self.speed = m.cd
            self.polarization = self.d
            self.S = -(m.lam * np.eye(2) + 2 * m.mu * np.outer(self.d, self.d)) / m.cd
        else:
            self.speed = m.cs
            self.polarization = dperp
            self.S = -m.mu * (np.outer(dperp, self.d) + np.outer(self.d, dperp)) / m.cs
        self.width = width
        self.x0 = np.asarray(x0, dtype=float)
        self.amplitude = amplitude
        self.sigma0 = np.asarray(sigma0, dtype=float)

    def _g(self, xi, exp):
        return self.amplitude * exp(-(xi / self.width) ** 2)

    def __call__(self, x, t):
        """Nodal state (5, m) at points x (3 or 2, m): (v_x, v_y, s_xx, s_yy, s_xy)."""
        xi = self.d[0] * (x[0] - self.x0[0]) + self.d[1] * (x[1] - self.x0[1]) - self.speed * t
        g = self._g(xi, np.exp)
        out = np.empty((5, x.shape[1]))
        out[0], out[1] = self.polarization[0] * g, self.polarization[1] * g
        out[2] = self.S[0, 0] * g + self.sigma0[0, 0]
        out[3] = self.S[1, 1] * g + self.sigma0[1, 1]
        out[4] = self.S[0, 1] * g + self.sigma0[0, 1]
        return out

    def ufl(self, x, t):
        """(v, sigma) as UFL expressions of the spatial coordinate x at time t (float or Constant)."""
        xi = self.d[0] * (x[0] - self.x0[0]) + self.d[1] * (x[1] - self.x0[1]) - self.speed * t
        g = self._g(xi, ufl.exp)
        v = ufl.as_vector(self.polarization.tolist()) * g
        sigma = ufl.as_matrix(self.S.tolist()) * g + ufl.as_matrix(self.sigma0.tolist())
        return v, sigma


# ------------------------------------------------------------------------------ meshes
def side_tags(mesh, x0, x1):
    """Facet tags LEFT/RIGHT/BOTTOM/TOP of the box [x0, x1] (corner facets go to the first match)."""
    tol = 1e-10 * max(x1[0] - x0[0], x1[1] - x0[1])
    idx, val = [], []
    seen = set()
    for tag, marker in ((LEFT, lambda x: np.isclose(x[0], x0[0], atol=tol)),
                        (RIGHT, lambda x: np.isclose(x[0], x1[0], atol=tol)),
                        (BOTTOM, lambda x: np.isclose(x[1], x0[1], atol=tol)),
                        (TOP, lambda x: np.isclose(x[1], x1[1], atol=tol))):
        f = [i for i in compat.locate_boundary_facets(mesh, marker) if i not in seen]
        seen.update(f)
        idx += f
        val += [tag] * len(f)
    return compat.meshtags(mesh, mesh.topology.dim - 1, idx, val)


def exterior_tags(mesh, tag=1):
    """Facet tags with every exterior facet tagged ``tag``."""
    fac = compat.exterior_facet_indices(mesh)
    return compat.meshtags(mesh, mesh.topology.dim - 1, fac, np.full(fac.size, tag))


def unit_square(N, diagonal="right", comm=MPI.COMM_WORLD):
    """N x N structured triangles on [0, 1]^2 with side tags."""
    mesh = compat.create_rectangle(comm, (0.0, 0.0), (1.0, 1.0), N, N, diagonal=diagonal)
    return mesh, side_tags(mesh, (0.0, 0.0), (1.0, 1.0))


def strip(xl, xr, nx, height, ny, comm=MPI.COMM_WORLD):
    """Structured strip [xl, xr] x [0, height] with side tags and cell tags 1 (x < 0), 2 (x > 0).

    The vertical grid lines are xl + i (xr - xl)/nx; choose nx so that x = 0 is one of them
    when the strip holds a material interface there."""
    mesh = compat.create_rectangle(comm, (xl, 0.0), (xr, height), nx, ny)
    ft = side_tags(mesh, (xl, 0.0), (xr, height))
    mid = compat.cell_vertex_coords(mesh).mean(axis=1)
    ncells = compat.num_cells_with_ghosts(mesh)
    ct = compat.meshtags(mesh, mesh.topology.dim, np.arange(ncells), np.where(mid[:, 0] < 0, 1, 2))
    return mesh, ft, ct


def perturb_interior(mesh, amplitude, h):
    """Move interior vertices of a box mesh by up to ``amplitude * h`` (a smooth, rank-independent
    function of the position, so shared vertices move alike): an unstructured-ish mesh."""
    x = mesh.geometry.x
    lo = np.minimum.reduce(mesh.comm.allgather(x[:, :2].min(axis=0)))
    hi = np.maximum.reduce(mesh.comm.allgather(x[:, :2].max(axis=0)))
    tol = 1e-9 * (hi - lo).max()
    inner = np.all((x[:, :2] > lo + tol) & (x[:, :2] < hi - tol), axis=1)
    dx = np.sin(12.9898 * x[:, 0] / h + 78.233 * x[:, 1] / h) * np.cos(3.7719 * x[:, 0] * x[:, 1] / h ** 2 + 4.1)
    dy = np.sin(9.3989 * x[:, 0] / h + 7.233 * x[:, 1] / h + 1.3)
    x[inner, 0] += amplitude * h * dx[inner]
    x[inner, 1] += amplitude * h * dy[inner]


# ------------------------------------------------------------------------------ states
def rough_state(material: Material, sigma0=((0.0, 0.0), (0.0, 0.0))):
    """Nodal state func(x) -> (5, m) of pseudo-random values in [-1/2, 1/2) (velocity) and
    [-Z_d/2, Z_d/2) + sigma0 (stress), a hash of the node coordinates: every mode of the mesh
    is excited, and the same node gets the same value on any number of ranks."""
    s0 = np.asarray(sigma0, dtype=float)

    def func(x):
        out = np.empty((5, x.shape[1]))
        for k in range(5):
            h = np.sin(12.9898 * x[0] + 78.233 * x[1] + 37.719 * (k + 1)) * 43758.5453
            out[k] = h - np.floor(h) - 0.5
        out[2:] *= material.Zd
        out[2] += s0[0, 0]
        out[3] += s0[1, 1]
        out[4] += s0[0, 1]
        return out
    return func


def gaussian_bump(material: Material, centre, width, sigma0=((0.0, 0.0), (0.0, 0.0))):
    """Nodal state func(x) -> (5, m): a smooth bump in every component (not a travelling wave)."""
    s0 = np.asarray(sigma0, dtype=float)
    c = np.asarray(centre, dtype=float)

    def func(x):
        g = np.exp(-((x[0] - c[0]) ** 2 + (x[1] - c[1]) ** 2) / width ** 2)
        z = material.Zd
        return np.array([g, -0.5 * g, z * g + s0[0, 0], -z * g + s0[1, 1], 0.5 * z * g + s0[0, 1]])
    return func


# ------------------------------------------------------------------------------ measuring
def fields_function(solver):
    """A Function holding the solver's current state (ghosts updated)."""
    u = compat.function(solver.V)
    compat.function_array(u)[:] = compat.function_array_of_vec(solver.x)
    return u


def relative_l2_errors(solver, wave, t, extra_degree=6):
    """Relative L2 errors against the exact wave at time t, by quadrature of degree
    2p + extra_degree: ``{"v": ||v_h - v|| / ||v||, "sigma": ||sigma_h - sigma|| / ||sigma - sigma0||,
    "energy": ||U_h - U||_E / ||U - U0||_E}`` with the energy norm
    ``||U||_E^2 = int rho |v|^2 + sigma : C^-1 : sigma`` (the L2 norm the scheme is stable in)."""
    from hydrofrac.forms.elastodynamics import compliance, fields
    mesh = solver.mesh
    vh, sh = fields(fields_function(solver))
    v, s = wave.ufl(ufl.SpatialCoordinate(mesh), t)
    dx = compat.measure("dx", mesh, metadata={"quadrature_degree": 2 * solver.degree + extra_degree})
    s0 = ufl.as_matrix(wave.sigma0.tolist())
    rho, lam, mu = solver.rho, solver.lam, solver.mu
    ev, es, ds_ = vh - v, sh - s, s - s0
    integrands = (ufl.inner(ev, ev), ufl.inner(v, v), ufl.inner(es, es), ufl.inner(ds_, ds_),
                  rho * ufl.inner(ev, ev) + ufl.inner(compliance(es, lam, mu), es),
                  rho * ufl.inner(v, v) + ufl.inner(compliance(ds_, lam, mu), ds_))
    val = [compat.assemble_scalar(compat.form(f * dx), mesh.comm) for f in integrands]
    return {"v": np.sqrt(val[0] / val[1]), "sigma": np.sqrt(val[2] / val[3]), "energy": np.sqrt(val[4] / val[5])}


def sample(solver, order=12):
    """Points (m, 2) and values (m, 5) of the DG fields on the degree-``order`` equispaced
    lattice of every owned cell (this rank's part)."""
    k = np.arange(order + 1)
    X = np.array([(i, j) for i in k for j in k if i + j <= order], dtype=float) / order
    T = solver.ref.tabulate(X)
    nloc = compat.num_cells_local(solver.mesh)
    dofs = compat.cell_dofs(solver.V)[:nloc]
    U = compat.function_array_of_vec(solver.x).reshape(-1, 5)[dofs]
    vals = np.einsum("pn,cnk->cpk", T, U).reshape(-1, 5)
    g = solver.geometry
    pts = (g.x0[:nloc, None, :] + np.einsum("cij,pj->cpi", g.J[:nloc], X)).reshape(-1, 2)
    return pts, vals


def signed_peak(comm, values):
    """The value of largest magnitude over all ranks (with its sign)."""
    local = values[np.argmax(np.abs(values))] if values.size else 0.0
    allv = np.array(comm.allgather(local))
    return float(allv[np.argmax(np.abs(allv))])


def fitted_slope(h, err):
    """Least-squares slope of log(err) against log(h)."""
    return float(np.polyfit(np.log(h), np.log(err), 1)[0])


def westergaard_stress(x, y, a, s_n, tau, s_t):
    """Exact static stress (sxx, syy, sxy) around a traction-free crack on (-a, a) x {0} in an
    infinite plate under remote sxx = s_t, syy = s_n, sxy = tau (Westergaard's complex
    potentials Z = s z / sqrt(z^2 - a^2); the constant s_t - s_n restores the remote sxx)."""
    z = np.asarray(x) + 1j * np.asarray(y)
    w = np.sqrt(z - a) * np.sqrt(z + a)  # branch cut on the crack
    Z = z / w
    dZ = -a * a / w ** 3
    sxx = (s_n * Z).real - y * (s_n * dZ).imag + (s_t - s_n) + 2 * (tau * Z).imag + y * (tau * dZ).real
    syy = (s_n * Z).real + y * (s_n * dZ).imag - y * (tau * dZ).real
    sxy = -y * (s_n * dZ).real + (tau * Z).real - y * (tau * dZ).imag
    return sxx, syy, sxy
