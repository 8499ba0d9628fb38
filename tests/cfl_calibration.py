"""Calibration of :data:`hydrofrac.solver.CFL_DEFAULT` (a study, not a test).

The largest stable CFL constant C_max of a scheme on a mesh is the largest dt with
``|R(dt lambda)| <= 1`` for every eigenvalue lambda of the operator ``A = M^-1 K``
(``R``: the stability polynomial of the Runge-Kutta scheme), in units of
``h_min / ((2p + 1) c_d)``.

* ``infinite``: von Neumann analysis on an infinite structured mesh: the symbol
  ``A(theta) = sum_k A[0, k] exp(i theta . k)`` of the rows of one interior mesh square
  (2 cells "right", 4 cells "crossed") against its 3 x 3 neighbourhood, read off the
  assembled operator of a small mesh, eigenvalues over a grid of wave numbers theta;
* ``N x N``: the eigenvalues of A on the unit square (dense for small A, the 60 of
  largest modulus with ARPACK otherwise), traction-free boundary.

Run: ``.venv/bin/python tests/cfl_calibration.py`` (about 10 minutes on 2 cores;
``--quick``: infinite meshes with a coarse theta grid, about 2 minutes; ``--nu -0.5,0.2,0.45``:
the limits of every Runge-Kutta scheme on the infinite "right" mesh for those Poisson ratios,
p = 1..4, about 15 minutes for seven ratios).
"""
from __future__ import annotations

import argparse
import math

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from mpi4py import MPI

from hydrofrac import ROCK, compat
from hydrofrac.material import Material
from hydrofrac.solver import ADER, ADER_CFL, CFL_DEFAULT, LOW_STORAGE, Solver, num_stages

def low_storage_polynomial(scheme):
    """R(z) of a 2N scheme (:data:`hydrofrac.solver.LOW_STORAGE`): its stages applied to y' = z y."""
    A, B, _ = LOW_STORAGE[scheme]

    def R(z):
        q, dq = np.ones_like(z, dtype=complex), np.zeros_like(z, dtype=complex)
        for a, b in zip(A, B):
            dq = a * dq + z * q
            q = q + b * dq
        return q
    return R


STABILITY_POLYNOMIAL = {
    "rk4": lambda z: 1 + z + z ** 2 / 2 + z ** 3 / 6 + z ** 4 / 24,
    "ssprk3": lambda z: 1 + z + z ** 2 / 2 + z ** 3 / 6,
    **{name: low_storage_polynomial(name) for name in LOW_STORAGE},
}


def c_max(lam, scheme, samples=4000):
    """Largest s (to 1/samples of the range) with |R(s' lam)| <= 1 for all s' <= s."""
    R = STABILITY_POLYNOMIAL[scheme]
    lam = lam[np.abs(lam) > 1e-9 * np.abs(lam).max()]
    s = np.linspace(0, 12.0 / np.abs(lam).max(), samples + 1)[1:]
    for i, si in enumerate(s):
        if np.abs(R(si * lam)).max() > 1 + 1e-10:
            return s[i - 1] if i else 0.0
    return s[-1]


def scipy_operator(solver):
    A = solver.A.convert("aij")
    indptr, cols, vals = A.getValuesCSR()
    return sp.csr_matrix((vals, cols, indptr), shape=A.getSize())


def square_blocks(p, diagonal, material=ROCK):
    """The rows of A for the unknowns of one interior square of an infinite structured mesh,
    split by the neighbouring square they couple to: ({(di, dj): block}, rows, the matrix-free
    solver of the same mesh, the unit h_min/((2p + 1) c_d))."""
    N = 6
    mesh = compat.create_rectangle(MPI.COMM_SELF, (0, 0), (N, N), N, N, diagonal=diagonal)
    s = Solver(mesh, p, material, operator="assembled")
    A = scipy_operator(s)
    X = compat.dof_coordinates(s.V)[:, :2]
    dofs = compat.cell_dofs(s.V)
    centroid = s.geometry.vertices.mean(axis=1)

    def square_rows(i, j):
        """Indices of the unknowns of square (i, j), in an order that a translation keeps."""
        keys = []
        for c in np.flatnonzero((np.floor(centroid[:, 0]) == i) & (np.floor(centroid[:, 1]) == j)):
            for d in dofs[c]:
                key = tuple(np.round(np.r_[centroid[c] - (i, j), X[d] - (i, j)], 6))
                keys.append((key, d))
        keys.sort()
        return (np.array([d for _, d in keys])[:, None] * 5 + np.arange(5)).ravel()

    rows = square_rows(2, 2)
    Arows = A[rows]
    blocks = {(di, dj): Arows[:, square_rows(2 + di, 2 + dj)].toarray() for di in (-1, 0, 1) for dj in (-1, 0, 1)}
    coupled = sum(np.abs(b).sum() for b in blocks.values())
    assert abs(coupled - np.abs(Arows).sum()) <= 1e-9 * coupled, "rows couple beyond the neighbouring squares"
    return blocks, rows, Solver(mesh, p, material), s.h_over_c_min / (2 * p + 1)


def symbols(blocks, ntheta):
    theta = np.linspace(-np.pi, np.pi, ntheta, endpoint=False)
    return [sum(b * np.exp(1j * (t1 * k[0] + t2 * k[1])) for k, b in blocks.items()) for t1 in theta for t2 in theta]


def symbol_eigenvalues(p, diagonal, material=ROCK, ntheta=24):
    """Eigenvalues of the symbol of A on an infinite structured mesh, in units of 1/unit."""
    blocks, _, _, unit = square_blocks(p, diagonal, material)
    return np.concatenate([np.linalg.eigvals(S) for S in symbols(blocks, ntheta)]) * unit


def ader_c_max(p, diagonal, ntheta=24, tol=1e-4):
    """C_max of the ADER step (:data:`hydrofrac.solver.ADER`) on an infinite structured mesh:
    the largest C with spectral radius <= 1 + tol of its amplification symbol
    G(theta) = I + C A(theta) P, P = sum_k C^k D^k / (k + 1)! (A, D in units of 1/unit; D, the
    cell-local operator, read column by column off the matrix-free kernel).  ``tol``: the
    eigenvalue 1 of the uniform states is defective, and its round-off reaches 3e-6 at p = 4;
    past the limit the radius jumps by > 0.1 within 0.05 of C."""
    blocks, rows, mf_solver, unit = square_blocks(p, diagonal)
    n = mf_solver.x.array_r.size
    D = np.zeros((rows.size, rows.size))
    e, out = np.zeros(n), np.zeros(n)
    for jj, col in enumerate(rows):
        e[:] = 0.0
        e[col] = 1.0
        mf_solver.matfree.local_derivative(e, out)
        D[:, jj] = out[rows]
        assert abs(np.abs(out).sum() - np.abs(out[rows]).sum()) <= 1e-12 * np.abs(out).sum()  # cell-local
    syms = [S * unit for S in symbols(blocks, ntheta)]
    D *= unit
    eye = np.eye(D.shape[0])

    def radius(C):
        P, Dk = np.zeros_like(D), eye
        for k in range(p + 1):
            P = P + Dk * C ** k / math.factorial(k + 1)
            Dk = Dk @ D
        return max(np.abs(np.linalg.eigvals(eye + C * S @ P)).max() for S in syms)

    lo = 0.0
    while radius(lo + 0.1) <= 1 + tol:
        lo += 0.1
    hi = lo + 0.1
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if radius(mid) <= 1 + tol else (lo, mid)
    return lo


def mesh_eigenvalues(p, N, diagonal="right"):
    mesh = compat.create_rectangle(MPI.COMM_SELF, (0, 0), (1, 1), N, N, diagonal=diagonal)
    s = Solver(mesh, p, ROCK, operator="assembled")
    A = scipy_operator(s)
    if A.shape[0] <= 5000:
        lam = np.linalg.eigvals(A.toarray())
    else:
        lam = sla.eigs(A, k=60, which="LM", return_eigenvectors=False, tol=1e-8)
    return lam * s.h_over_c_min / (2 * p + 1)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="infinite meshes only, coarse wave-number grid")
    parser.add_argument("--nu", help="comma-separated Poisson ratios: the Runge-Kutta limits over them instead")
    args = parser.parse_args()
    if args.nu:
        try:
            nus = [float(v) for v in args.nu.split(",")]
        except ValueError:
            parser.error(f"--nu takes comma-separated numbers, e.g. -0.5,0.2,0.45; got {args.nu!r}")
        if not all(-1.0 < nu < 0.5 for nu in nus):
            parser.error(f"--nu: every Poisson ratio must be in (-1, 0.5); got {args.nu!r}")
        print(f"{'p':>2s} {'nu':>6s}  " + "  ".join(f"C_max {k:>7s}" for k in STABILITY_POLYNOMIAL))
        for p in (1, 2, 3, 4):
            for nu in nus:
                lam = symbol_eigenvalues(p, "right", Material(E=ROCK.E, nu=nu, rho=ROCK.rho, name=f"nu={nu}"))
                print(f"{p:2d} {nu:6.2f}  " + "  ".join(f"{c_max(lam, k, samples=16000):13.4f}"
                                                         for k in STABILITY_POLYNOMIAL), flush=True)
        return
    cases = [("infinite", "right"), ("infinite", "crossed")]
    if not args.quick:
        cases += [(8, "right"), (16, "right")]
    print(f"CFL_DEFAULT = {CFL_DEFAULT}; 1.5 x: { {k: 1.5 * v for k, v in CFL_DEFAULT.items()} }")
    schemes = list(STABILITY_POLYNOMIAL)
    print(f"{'mesh':>20s}  p  " + "  ".join(f"C_max {k:>7s}" for k in schemes) + "   (per stage: C_max / stages)")
    for size, diagonal in cases:
        for p in (1, 2, 3, 4):
            lam = (symbol_eigenvalues(p, diagonal, ntheta=12 if args.quick else 24) if size == "infinite"
                   else mesh_eigenvalues(p, size, diagonal))
            cm = {k: c_max(lam, k, samples=16000) for k in schemes}
            print(f"{str(size) + ' ' + diagonal:>20s}  {p}  " + "  ".join(f"{cm[k]:13.4f}" for k in schemes)
                  + "   (" + ", ".join(f"{k} {cm[k] / num_stages(k):.4f}" for k in schemes) + ")", flush=True)
    print(f"ADER (ADER_CFL = {ADER_CFL}): C_max on infinite meshes, and per application (C_max / (p + 1))")
    for diagonal in ("right",) if args.quick else ("right", "crossed"):
        for p in (1, 2, 3, 4):
            cm = ader_c_max(p, diagonal, ntheta=12 if args.quick else 24)
            print(f"{'infinite ' + diagonal:>20s}  {p}  ader {cm:.4f}  ({cm / num_stages(ADER, p):.4f})", flush=True)


if __name__ == "__main__":
    main()
