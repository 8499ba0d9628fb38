"""Study: work–precision of the DG solver against a continuous-Galerkin baseline (issue 7,
study 1; so far the plane-wave problem).

A Gaussian plane P wave (width 0.12 m, direction 0.3 rad) crosses the unit square for
0.2 m of travel, with the exact solution on the boundary (DG: as the outer state of the
Riemann flux; CG: as Dirichlet displacement).  Both solvers are run on the same structured
meshes, and the error is measured the same way for both: the relative energy norm
(rho |v - v_e|^2 + (sigma - sigma_e) : C^-1 (sigma - sigma_e), by quadrature of the exact
expressions) at the final time.  Wall time is the time loop only (set-up excluded for
both).

* DG: P_p, p = 1-4, RK4 at the default CFL, the matrix-free operator (this project);
* CG: P_1 and P_2 displacement, HRZ-lumped mass, explicit central differences at 0.9 of
  the measured stability limit (:mod:`hydrofrac.cg_baseline`); and P_2 with the consistent
  mass (a Jacobi-preconditioned CG solve per step), since lumping costs standard P_2
  triangles their accuracy.

Writes ``work_precision_cg.csv`` and ``work_precision_cg.png`` into ``postprocess/results``
(``--out``) and prints the speed-up of the DG frontier over the CG one at 1 % error (and
0.1 %), interpolated log-log on each method's points, measured in the same run.

    python -m hydrofrac.postprocess.study_work_precision [--quick] [--out DIR]
"""
from __future__ import annotations

import math

import numpy as np
import ufl
from mpi4py import MPI
from scipy.special import erfc

from hydrofrac import ROCK, compat
from hydrofrac._jit import njit
from hydrofrac.postprocess.baselines.cg_baseline import CentralDifferenceCG, energy_norm_error, timed_steps
from hydrofrac.forms import elastodynamics as ef
from hydrofrac.postprocess.roofline import flops_per_dof_step
from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.study_common import (cases, log_axes, plane_wave_solver, results_dir, save_figure, say,
                                                study_parser, wall_at)

DIRECTION = np.array([math.cos(0.3), math.sin(0.3)])
WIDTH = 0.12
TRAVEL = 0.2
MAT = ROCK

DG_SIZES = {1: (8, 16, 32, 64), 2: (8, 16, 32), 3: (4, 8, 16, 32), 4: (4, 8, 16)}
CG_SIZES = {(1, "lumped"): (16, 32, 64, 128, 256), (2, "lumped"): (8, 16, 32, 64, 128),
            (2, "consistent"): (8, 16, 32, 64, 128)}
QUICK_DG = {1: (8, 16), 2: (4, 8), 3: (4, 8)}
QUICK_CG = {(1, "lumped"): (8, 16, 32), (2, "lumped"): (4, 8, 16), (2, "consistent"): (4, 8)}


def xi(x, t):
    d = DIRECTION
    return d[0] * (x[0] - 0.5) + d[1] * (x[1] - 0.5) - MAT.cd * t


def state(x, t):
    """Exact (v_x, v_y, s_xx, s_yy, s_xy) at points x (3, m)."""
    g = np.exp(-(xi(x, t) / WIDTH) ** 2)
    d = DIRECTION
    S = -(MAT.lam * np.eye(2) + 2 * MAT.mu * np.outer(d, d)) / MAT.cd
    return np.vstack([d[0] * g, d[1] * g, S[0, 0] * g, S[1, 1] * g, S[0, 1] * g])


_S = -(MAT.lam * np.eye(2) + 2 * MAT.mu * np.outer(DIRECTION, DIRECTION)) / MAT.cd
_D0, _D1, _S00, _S11, _S01, _CD = (float(v) for v in (DIRECTION[0], DIRECTION[1], _S[0, 0], _S[1, 1], _S[0, 1], MAT.cd))


@njit
def state_pt(x, y, t):
    """:func:`state` at one point, compiled (the boundary's outer state inside the kernel)."""
    z = _D0 * (x - 0.5) + _D1 * (y - 0.5) - _CD * t
    g = math.exp(-(z / WIDTH) ** 2)
    return _D0 * g, _D1 * g, _S00 * g, _S11 * g, _S01 * g


def displacement(x, t):
    """Exact displacement: u = d (W sqrt(pi) / (2 c)) erfc(xi / W), so that du/dt = d g."""
    s = WIDTH * math.sqrt(math.pi) / (2 * MAT.cd) * erfc(xi(x, t) / WIDTH)
    return np.vstack([DIRECTION[0] * s, DIRECTION[1] * s])


def ufl_exact(mesh, t):
    """(v_e, sigma_e) as UFL expressions of the spatial coordinate."""
    X = ufl.SpatialCoordinate(mesh)
    d = ufl.as_vector(DIRECTION.tolist())
    z = d[0] * (X[0] - 0.5) + d[1] * (X[1] - 0.5) - MAT.cd * t
    g = ufl.exp(-(z / WIDTH) ** 2)
    dd = ufl.outer(d, d)
    return g * d, -(g / MAT.cd) * (MAT.lam * ufl.Identity(2) + 2 * MAT.mu * dd)


def unit_square(comm, N):
    return compat.create_rectangle(comm, (0.0, 0.0), (1.0, 1.0), N, N)


def dg_error(solver):
    """Relative energy-norm error of a DG plane-wave run at its current time."""
    u = compat.function(solver.V)
    compat.function_vector(u).array[:] = solver.x.array_r
    compat.scatter_forward(u)
    v, sigma = ef.fields(u)
    ve, se = ufl_exact(solver.mesh, solver.t)
    return energy_norm_error(solver.mesh, MAT, v, sigma, ve, se, 2 * solver.degree + 4)


def run_dg(comm, p, N, scheme="rk4"):
    solver, steps = plane_wave_solver(comm, p, N, MAT, state, TRAVEL, point=state_pt, scheme=scheme)
    wall = timed_steps(solver, steps)
    err = dg_error(solver)
    per = flops_per_dof_step(solver)  # (the kernels' flop model: postprocess/roofline.py)
    return {"method": f"DG P{p}" + ("" if scheme == "rk4" else f" {scheme}"), "family": "DG", "degree": p,
            "scheme": scheme, "N": N, "dofs": solver.num_dofs, "steps": steps, "wall_s": wall, "rel_error": err,
            "flops_per_unknown_step": per, "flops": per * solver.num_dofs * steps}


def run_cg(comm, k, N, mass="lumped"):
    mesh = unit_square(comm, N)
    cg = CentralDifferenceCG(mesh, k, MAT, displacement, mass=mass)
    t_end = TRAVEL / MAT.cd
    steps = int(math.ceil(t_end / cg.dt - 1e-9))
    cg.start(dt=t_end / steps)
    wall = timed_steps(cg, steps)
    ve, se = ufl_exact(mesh, cg.t)
    err = cg.energy_error(ve, se)
    return {"method": f"CG P{k}" + (" consistent" if mass == "consistent" else ""), "family": "CG", "degree": k, "N": N, "dofs": cg.num_dofs, "steps": steps,
            "wall_s": wall, "rel_error": err}


def plot(rows, png):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=100)
    for m in sorted({r["method"] for r in rows}):
        rs = sorted([r for r in rows if r["method"] == m], key=lambda r: r["N"])
        style = "o-" if rs[0]["family"] == "DG" else "s--"
        ax.loglog([r["wall_s"] for r in rs], [r["rel_error"] for r in rs], style, label=m)
    ax.axhline(1e-2, color="k", lw=0.6, ls=":")
    ax.set_xlabel("wall time of the time loop [s]")
    ax.set_ylabel("relative error (energy norm)")
    ax.set_title("Plane P wave: DG (RK4, matrix-free) vs CG (central differences)", fontsize=9)
    log_axes(ax)
    save_figure(fig, png)


def main(argv=None):
    args = study_parser(__doc__).parse_args(argv)
    comm = MPI.COMM_WORLD
    rows = []
    runs = ([(N, lambda p=p, N=N: run_dg(comm, p, N)) for p, N in cases(args, QUICK_DG, DG_SIZES)]
            + [(N, lambda k=k, m=m, N=N: run_cg(comm, k, N, m)) for (k, m), N in cases(args, QUICK_CG, CG_SIZES)])
    for N, one in runs:
        r = one()
        rows.append(r)
        say(comm, f"{r['method']} N={N:3d} {r['dofs']:7d} DOFs: error {r['rel_error']:.3e}, wall {r['wall_s']:.3f} s")
    out = results_dir(comm, args, rows)
    if out is None:
        return rows
    write_csv(out / "work_precision_cg.csv", rows)
    plot(rows, out / "work_precision_cg.png")
    for target in (1e-2, 1e-3):
        dg = wall_at([r for r in rows if r["family"] == "DG"], target, "rel_error")
        cg = wall_at([r for r in rows if r["family"] == "CG"], target, "rel_error")
        print(f"[study] at {target:.0e} error: DG {dg:.3g} s, CG {cg:.3g} s, speed-up of DG {cg / dg:.3g}",
              flush=True)
    print(f"[study] wrote {out}/work_precision_cg.csv and work_precision_cg.png", flush=True)
    return rows


if __name__ == "__main__":
    main()
