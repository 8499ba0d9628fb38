"""Reference-element data of the DG space, derived from DOLFINx's own dof layout.

The nodes of the discontinuous Lagrange element are read off the DOF
coordinates of the mesh, so whatever Lagrange variant the form compiler picks,
the nodal basis here is the same as DOLFINx's: ``phi_j(X_i) = delta_ij``.  It
evaluates traces at arbitrary points (crack and boundary kernels, output) and
gives the per-cell affine geometry.
"""
from __future__ import annotations

import numpy as np

from . import compat


def _monomials(p):
    return [(i, j) for i in range(p + 1) for j in range(p + 1 - i)]


def dimension(k: int) -> int:
    """dim P_k on the triangle: the nodes of a degree-k cell."""
    return (k + 1) * (k + 2) // 2


class ReferenceElement:
    """Nodal P_p basis on the reference triangle (0,0), (1,0), (0,1)."""

    def __init__(self, nodes: np.ndarray, degree: int):
        self.degree = degree
        self.nodes = np.asarray(nodes, dtype=float)
        self._mono = _monomials(degree)
        if len(self._mono) != len(self.nodes):
            raise RuntimeError("node count does not match the P_p dimension")
        self._Vinv = np.linalg.inv(self._vandermonde(self.nodes))

    def _vandermonde(self, X):
        return np.stack([X[:, 0] ** i * X[:, 1] ** j for i, j in self._mono], axis=1)

    def tabulate(self, X):
        """Basis values at reference points X (m, 2) -> (m, n)."""
        return self._vandermonde(np.atleast_2d(X)) @ self._Vinv

    def tabulate_grad(self, X):
        """Reference gradients at X (m, 2) -> (m, n, 2)."""
        X = np.atleast_2d(X)
        dx = np.stack([i * X[:, 0] ** max(i - 1, 0) * X[:, 1] ** j for i, j in self._mono], axis=1)
        dy = np.stack([j * X[:, 0] ** i * X[:, 1] ** max(j - 1, 0) for i, j in self._mono], axis=1)
        return np.stack([dx @ self._Vinv, dy @ self._Vinv], axis=-1)

    def mass(self):
        """Reference mass matrix (exact Gauss quadrature of degree 2p)."""
        X, w = triangle_quadrature(2 * self.degree)
        phi = self.tabulate(X)
        return (phi * w[:, None]).T @ phi


def triangle_quadrature(degree):
    """Gauss-Jacobi points/weights on the reference triangle, exact to ``degree``."""
    import basix
    X, w = basix.make_quadrature(basix.CellType.triangle, max(degree, 1))
    return np.asarray(X), np.asarray(w)


def line_quadrature(degree):
    """Gauss points/weights on [0, 1], exact to ``degree``."""
    x, w = np.polynomial.legendre.leggauss(max(degree // 2 + 1, 1))
    return 0.5 * (x + 1), 0.5 * w


def inradius(xc):
    """Inradius 2 A / perimeter of triangles with vertices ``xc`` (n, 3, 2): the h of the
    explicit time step's CFL bound."""
    J = np.stack([xc[:, 1] - xc[:, 0], xc[:, 2] - xc[:, 0]], axis=2)
    area = 0.5 * np.abs(J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0])
    return 2.0 * area / np.linalg.norm(xc[:, [1, 2, 0]] - xc, axis=2).sum(axis=1)


class CellGeometry:
    """Affine geometry of every local cell (owned + ghosts): x = x0 + J X."""

    def __init__(self, mesh):
        self.nodes = compat.cell_geometry_nodes(mesh)  # (nc, 3) geometry node indices, reference order
        xc = mesh.geometry.x[self.nodes, :2]
        self.vertices = xc
        self.x0 = xc[:, 0, :]
        self.J = np.stack([xc[:, 1] - xc[:, 0], xc[:, 2] - xc[:, 0]], axis=2)  # (nc, 2, 2), columns
        self.detJ = self.J[:, 0, 0] * self.J[:, 1, 1] - self.J[:, 0, 1] * self.J[:, 1, 0]
        self.area = 0.5 * np.abs(self.detJ)
        self.inradius = inradius(xc)
        self.Jinv = np.linalg.inv(self.J)

    @property
    def centroid(self):
        """(nc, 2) each cell's vertex mean, computed once (the operators, the interface and the
        transfer all ask for it at a remesh)."""
        if getattr(self, "_centroid", None) is None:
            self._centroid = self.vertices.mean(axis=1)
        return self._centroid

    def to_reference(self, cells, x):
        """Physical points x (m, 2) in cells (m,) -> reference coordinates (m, 2)."""
        return np.einsum("mij,mj->mi", self.Jinv[cells], x - self.x0[cells])

    def to_physical(self, cells, X):
        return self.x0[cells] + np.einsum("mij,mj->mi", self.J[cells], X)


def reference_element(V, geometry: CellGeometry) -> ReferenceElement:
    """Read the nodal points of V off cell 0 and check every local cell agrees."""
    dofs = compat.cell_dofs(V)
    xd = compat.dof_coordinates(V)[:, :2]
    degree = V.ufl_element().degree()
    if dofs.shape[0] == 0:
        raise RuntimeError("a rank holds no cells; use fewer MPI ranks for this mesh")
    X = geometry.to_reference(np.zeros(dofs.shape[1], dtype=np.int64), xd[dofs[0]])
    X = np.round(X, 12)
    ref = ReferenceElement(X, degree)
    # every cell must map the same reference nodes to its dof coordinates
    xphys = geometry.x0[:, None, :] + np.matmul(geometry.J, X.T).transpose(0, 2, 1)  # (einsum's, 2x faster)
    err = np.abs(xphys - xd[dofs]).max()
    scale = np.abs(geometry.J).max()
    if err > 1e-9 * max(scale, 1.0):
        raise RuntimeError(f"DG dof layout differs between cells (mismatch {err:.2e}); "
                           "hydrofrac needs an affine triangle mesh")
    return ref
