"""Study: the time scheme by measured work–precision (docs/benchmarks.md, "Time schemes").

The plane P wave of :mod:`hydrofrac.postprocess.study_work_precision` (the unit square, the
exact solution as the outer state, the relative energy-norm error at the final time), run
with each explicit scheme of the solver at its documented CFL constant
(:func:`hydrofrac.solver.default_cfl`, calibrated by ``tests/cfl_calibration.py``):

* ``rk4``: the classical 4-stage scheme (the default);
* ``lsrk54``: Carpenter & Kennedy's 5-stage 4th-order 2N scheme;
* ``lsrk144``: Niegemann, Diehl & Busch's 14-stage 4th-order 2N scheme, whose stability
  region is optimised for upwind DG spectra;
* ``ader``: the one-step ADER scheme (:data:`hydrofrac.solver.ADER`): a cell-local Taylor
  predictor (p local derivatives in one compiled pass) and one corrector per step, order
  p + 1 in space and time.  Its "applications" count the p local derivatives like full ones.

For each: the error, the operator applications (steps x stages), the wall time of the time
loop and the throughput (DOF·stages/s), side by side in one run; and the error at a fixed
mesh as dt shrinks (the time error's share).  Writes ``time_schemes.csv`` and
``time_schemes.png`` in ``--out`` and prints, per degree, each scheme's wall time at 1 % and
0.1 % error relative to rk4's.

    python -m hydrofrac.postprocess.study_time_schemes [--quick] [--out DIR]
"""
from __future__ import annotations

import math

from mpi4py import MPI

from hydrofrac.postprocess.baselines.cg_baseline import timed_steps
from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.study_common import (cases, log_axes, plane_wave_solver, results_dir, save_figure, say,
                                                study_parser, wall_at)
from hydrofrac.postprocess.study_work_precision import MAT, TRAVEL, dg_error, state, state_pt
from hydrofrac.solver import default_cfl

SCHEMES = ("rk4", "lsrk54", "lsrk144", "ader")
SIZES = {1: (16, 32, 64), 2: (8, 16, 32), 3: (4, 8, 16, 32)}
QUICK = {2: (8, 16), 3: (4, 8)}


def run(comm, scheme, p, N, cfl_factor=1.0):
    def build():
        return plane_wave_solver(comm, p, N, MAT, state, TRAVEL, point=state_pt, scheme=scheme,
                                 cfl=default_cfl(scheme, p) * cfl_factor)
    wall = min(timed_steps(*build()) for _ in range(2))  # (the minimum of repeats: absolute times are noisy)
    solver, steps = build()
    timed_steps(solver, steps)
    err = dg_error(solver)
    applications = steps * solver.num_stages
    return {"scheme": scheme, "method": f"{scheme} P{p}", "degree": p, "N": N, "cfl_factor": cfl_factor,
            "dofs": solver.num_dofs, "steps": steps, "stages": solver.num_stages,
            "applications": applications, "wall_s": wall, "rel_error": err,
            "dof_stages_per_s": solver.num_dofs * applications / wall}


def plot(rows, png):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a1, a2, a3) = plt.subplots(1, 3, figsize=(16, 4.8))
    for p, ls in ((1, ":"), (2, "-"), (3, "--")):
        for scheme, m in zip(SCHEMES, "osd^"):
            rs = sorted([r for r in rows if r["scheme"] == scheme and r["degree"] == p and r["cfl_factor"] == 1.0],
                        key=lambda r: r["dofs"])
            if rs:
                a1.loglog([r["wall_s"] for r in rs], [r["rel_error"] for r in rs], m + ls, label=f"{scheme} P{p}")
                a2.loglog([r["applications"] * r["dofs"] for r in rs], [r["rel_error"] for r in rs], m + ls,
                          label=f"{scheme} P{p}")
    for scheme, m in zip(SCHEMES, "osd^"):
        rs = sorted([r for r in rows if r["scheme"] == scheme and r.get("dt_series")], key=lambda r: -r["cfl_factor"])
        if rs:
            a3.loglog([default_cfl(scheme, r["degree"]) * r["cfl_factor"] / r["stages"] for r in rs],
                      [r["rel_error"] for r in rs], m + "-", label=scheme)
    a1.set_xlabel("wall time of the time loop [s]")
    a2.set_xlabel("DOF x operator applications")
    a3.set_xlabel("CFL per stage (C / stages)")
    for a in (a1, a2, a3):
        a.set_ylabel("relative energy-norm error")
    a1.set_title("work-precision (wall)")
    a2.set_title("work-precision (operator applications)")
    a3.set_title("error at one mesh (P3) as dt shrinks")
    log_axes(a1, a2, a3)
    fig.suptitle("time schemes on the plane P wave, each at its documented CFL constant")
    save_figure(fig, png)


def main(argv=None):
    args = study_parser(__doc__).parse_args(argv)
    comm = MPI.COMM_WORLD
    rows = []
    for p, N in cases(args, QUICK, SIZES):
        for scheme in SCHEMES:
            r = run(comm, scheme, p, N)
            rows.append(r)
            say(comm, f"{r['method']:12s} N={N:3d} {r['dofs']:7d} DOFs: error {r['rel_error']:.4e}, "
                      f"{r['applications']:5d} applications, wall {r['wall_s']:.3f} s, "
                      f"{r['dof_stages_per_s']:.3g} DOF*stages/s")
    # the time error's share: one mesh, dt from the CFL constant down
    p, N = 3, (8 if args.quick else 16)
    for scheme in SCHEMES:
        for f in (1.0, 0.5, 0.25):
            r = run(comm, scheme, p, N, f)
            r["dt_series"] = True
            rows.append(r)
            say(comm, f"{scheme:8s} P{p} N={N} dt x {f:4.2f}: error {r['rel_error']:.5e}")
    out = results_dir(comm, args, rows)
    if out is None:
        return rows
    for r in rows:
        r.setdefault("dt_series", False)
    write_csv(out / "time_schemes.csv", rows)
    plot(rows, out / "time_schemes.png")
    for p in (QUICK if args.quick else SIZES):
        front = {s: [r for r in rows if r["scheme"] == s and r["degree"] == p and not r["dt_series"]] for s in SCHEMES}
        for target in (1e-2, 1e-3):
            w = {s: wall_at(front[s], target, "rel_error") for s in SCHEMES}
            if not all(math.isfinite(v) for v in w.values()):
                print(f"[study] P{p}: {target:.0e} error not reached by every scheme at these sizes", flush=True)
                continue
            print(f"[study] P{p} at {target:.0e} error: " + ", ".join(
                f"{s} {w[s]:.3g} s ({w['rk4'] / w[s]:.2f}x rk4's speed)" for s in SCHEMES), flush=True)
    print(f"[study] wrote {out}/time_schemes.csv and time_schemes.png", flush=True)
    return rows


if __name__ == "__main__":
    main()
