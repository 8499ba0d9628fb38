"""Study: work–precision of the DG solver on the two crack verification problems (issue 7,
study 1, continued; the plane wave with the CG baseline is
:mod:`hydrofrac.postprocess.study_work_precision`).

* **Two-bar impact** (verification case 9, ``scenarios/two_bars.py``): p = 1-4 on strips of
  20, 40 and 80 cells along 2 m, with rk4 and with ADER (the contact at the interface's
  stages from the cells' predictor); errors of the contact stress (plateau against -Z_d v0)
  and of the contact duration (against 2L/c_d, in µs).
* **Sneddon** (case 11, ``scenarios/sneddon.py``, quick domain 8a, dynamic relaxation to the
  static state by 3 ms): p = 1-3 (p = 4 on the two coarser meshes) at crack sizes 0.2a, 0.1a,
  0.05a; L2 error of the opening for |x| < 0.9a.

The CG baseline (:mod:`hydrofrac.cg_crack`) runs on the same meshes with the crack nodes
doubled: P1 and P2, HRZ-lumped mass, central differences; node-to-node contact by
forward-increment Lagrange multipliers for the bars (contact stress = sum of the multipliers
over the strip height), the pressure as a face traction for Sneddon (same ramp, dashpots and
relaxation damping; opening sampled at 4 Gauss points per crack facet).  Its wall time is the
bare stepping loop; the DG time includes the per-step energy budget and blow-up check.  The
CG baseline runs on one process, so the study does too.

Writes ``work_precision_bars.csv``, ``work_precision_sneddon.csv`` and one PNG with the
charts into ``postprocess/results`` (``--out``), and prints the speed-up of DG over CG at 1 %
error, and of DG's ADER over its rk4 (interpolated on each method's points, measured in the
same run).

    python -m hydrofrac.postprocess.study_work_precision_cracks [--quick] [--out DIR]
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

from hydrofrac import ROCK, compat
from hydrofrac.postprocess.baselines.cg_crack import CrackCG, boundary_facets_on, crack_opening, split_mesh
from hydrofrac.meshes.fractures import NATURAL
from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.study_common import log_axes, save_figure, scenario, study_parser, timed_run, wall_at


BARS = {1: (20, 40, 80), 2: (20, 40, 80), 3: (20, 40, 80), 4: (20, 40, 80)}
SNEDDON = {1: (0.2, 0.1, 0.05), 2: (0.2, 0.1, 0.05), 3: (0.2, 0.1, 0.05), 4: (0.2, 0.1)}
QUICK_BARS = {1: (20, 40), 2: (20, 40)}
ADER_BARS = BARS
QUICK_ADER_BARS = {2: (20, 40)}
QUICK_SNEDDON = {1: (0.2,), 2: (0.2,)}
CG_BARS = {1: (20, 40, 80, 160, 320), 2: (20, 40, 80, 160)}
CG_SNEDDON = {1: (0.2, 0.1, 0.05, 0.025), 2: (0.2, 0.1, 0.05)}
QUICK_CG_BARS = {1: (20, 40), 2: (20,)}
QUICK_CG_SNEDDON = {1: (0.2,), 2: (0.2,)}
SNEDDON_SIZE, SNEDDON_H_FAR, T_RAMP, RELAXATION, T_END = 8.0, 1.5, 1.0e-3, 1500.0, 3.0e-3


def bars_case(p, nx, scheme="rk4"):
    tb = scenario("two_bars")
    problem = tb.setup(degree=p, nx=nx, scheme=scheme)
    solver = problem.solver
    rec = tb.Recorder()
    wall = timed_run(problem, 0.75e-3, rec)
    acc = rec.accuracy(problem)
    method = f"DG P{p}" if scheme == "rk4" else f"DG P{p} {scheme}"
    return {"method": method, "family": "DG", "scheme": scheme, "p": p, "size": nx, "dofs": solver.num_dofs,
            "steps": solver.step_count, "wall_s": wall, "stress_rel_error": acc["contact_stress_rel_error"],
            "duration_error_us": abs(acc["duration"] - acc["duration_exact"]) * 1e6,
            "velocity_rel_error": acc["velocity_rel_error"]}


def cg_bars(k, nx, L=1.0, v0=1.0):
    """The two-bar impact with the CG baseline on the same strip as the DG, split at x = 0,
    closing at ±v0 (returns the solver)."""
    tb = scenario("two_bars")
    mesh, tags = tb.make_mesh(MPI.COMM_SELF, L, nx)
    sm = split_mesh(mesh, tags.indices[tags.values == tb.CRACK], lambda c: c[:, 0] > 0)
    h = 2 * L / nx
    faces = boundary_facets_on(sm, lambda x: np.isclose(x[0], 0.0))
    left = compat.cell_vertex_coords(sm)[compat.facet_cells(sm, faces)].mean(axis=1)[:, 0] < 0
    sides = boundary_facets_on(sm, lambda x: np.isclose(x[1], 0.0) | np.isclose(x[1], h))
    cg = CrackCG(sm, k, ROCK, rollers=[(sides, 1)], contact=(faces[left], faces[~left], (1.0, 0.0)))
    cg.set_velocity(lambda X: np.stack([np.where(X[:, 0] < 0, v0, -v0), 0 * X[:, 0]], axis=1))
    return cg


def cg_bar_velocities(cg):
    """Mean x-velocity (momentum / mass) of the left and the right bar."""
    left = cg.X_inside[:, 0] < 0
    return cg.mean_velocity(left)[0], cg.mean_velocity(~left)[0]


def cg_bars_case(k, nx, L=1.0, v0=1.0, t_end=0.75e-3):
    """Work and errors of :func:`cg_bars`, measured as :func:`bars_case` measures the DG."""
    cg = cg_bars(k, nx, L, v0)
    force, times = [], []
    t0 = time.perf_counter()
    while cg.t < t_end * (1 - 1e-12):
        cg.step()
        force.append(cg.contact_force)
        times.append(cg.t)
    wall = time.perf_counter() - t0
    force, times = np.asarray(force), np.asarray(times)
    on = force > 0
    if not on.any():
        raise RuntimeError("CG bars: no contact happened")
    t_first, t_last = times[on][0], times[on][-1]
    duration = t_last - t_first + cg.dt  # steps in contact, as scenarios/two_bars.py counts them
    mid = on & (times > t_first + 0.25 * duration) & (times < t_first + 0.75 * duration)
    stress = -force[mid].mean() / cg.contact_length
    vel = cg_bar_velocities(cg)
    return {"method": f"CG P{k}", "family": "CG", "p": k, "size": nx, "dofs": cg.num_dofs, "steps": cg.step_count,
            "wall_s": wall, "stress_rel_error": abs(stress / (-ROCK.Zd * v0) - 1),
            "duration_error_us": abs(duration - 2 * L / ROCK.cd) * 1e6,
            "velocity_rel_error": max(abs(vel[0] + v0), abs(vel[1] - v0)) / v0}


def sneddon_case(p, h):
    sn = scenario("sneddon")
    problem = sn.setup(degree=p, a=1.0, dp=1.0e6, size=SNEDDON_SIZE, h_crack=h, h_far=SNEDDON_H_FAR,
                       t_ramp=T_RAMP, relaxation=RELAXATION)
    solver = problem.solver
    wall = timed_run(problem, T_END)
    acc = sn.opening_error(solver, problem.interface, 1.0, 1.0e6)
    return {"method": f"DG P{p}", "family": "DG", "p": p, "size": h, "dofs": solver.num_dofs,
            "steps": solver.step_count, "wall_s": wall, "opening_rel_error": acc["opening_L2_rel_error"]}


def cg_sneddon_case(k, h, a=1.0, dp=1.0e6):
    """Sneddon with the CG baseline on the same mesh, split along the crack: the net
    pressure (same ramp) on both faces, dashpots on the box, the same relaxation damping."""
    sn = scenario("sneddon")
    fm = sn.make_mesh(MPI.COMM_SELF, a, SNEDDON_SIZE, h, SNEDDON_H_FAR)
    ft = fm.facet_tags
    sm = split_mesh(fm.mesh, ft.indices[ft.values == NATURAL], lambda c: c[:, 1] < 0)
    faces = boundary_facets_on(sm, lambda x: (np.abs(x[1]) < 1e-9 * a) & (np.abs(x[0]) < a * (1 + 1e-9)))
    upper = compat.cell_vertex_coords(sm)[compat.facet_cells(sm, faces)].mean(axis=1)[:, 1] > 0
    R = SNEDDON_SIZE * a
    outer = boundary_facets_on(sm, lambda x: np.isclose(np.abs(x[0]), R) | np.isclose(np.abs(x[1]), R))
    cg = CrackCG(sm, k, ROCK, pressure=(faces, sn.pressure_ramp(0.0, dp, T_RAMP)), absorbing=outer,
                 damping=RELAXATION)
    t0 = time.perf_counter()
    while cg.t < T_END * (1 - 1e-12):
        cg.step()
    wall = time.perf_counter() - t0
    pts, w, opening = crack_opening(cg, faces[upper], faces[~upper])
    sel = np.abs(pts[:, 0]) < 0.9 * a
    exact = sn.exact_opening(pts[sel, 0], a, dp)
    err = float(np.sqrt((w[sel] * (opening[sel] - exact) ** 2).sum() / (w[sel] * exact ** 2).sum()))
    return {"method": f"CG P{k}", "family": "CG", "p": k, "size": h, "dofs": cg.num_dofs, "steps": cg.step_count,
            "wall_s": wall, "opening_rel_error": err}


def plot(bars, sned, png):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 2, figsize=(11, 8), dpi=80)
    axes = axes.reshape(-1)
    for ax, rows, key, label in ((axes[0], bars, "stress_rel_error", "contact stress, relative error"),
                                 (axes[1], bars, "duration_error_us", "contact duration error [µs]"),
                                 (axes[2], bars, "velocity_rel_error", "rebound velocity, relative error"),
                                 (axes[3], sned, "opening_rel_error", "Sneddon opening, L2 relative error")):
        for m in sorted({r["method"] for r in rows}):
            rs = sorted([r for r in rows if r["method"] == m], key=lambda r: r["dofs"])
            style = ("^:" if rs[0].get("scheme") == "ader" else "o-") if rs[0]["family"] == "DG" else "s--"
            ax.loglog([r["wall_s"] for r in rs], [max(r[key], 1e-16) for r in rs], style, label=m)
        ax.set_xlabel("wall time of the run [s]")
        ax.set_ylabel(label)
        log_axes(ax)
    axes[0].set_title("two-bar impact (case 9)", fontsize=10)
    axes[1].set_title("two-bar impact (case 9)", fontsize=10)
    axes[2].set_title("two-bar impact (case 9)", fontsize=10)
    axes[3].set_title("Sneddon crack (case 11)", fontsize=10)
    save_figure(fig, png)


def main(argv=None):
    args = study_parser(__doc__).parse_args(argv)
    comm = MPI.COMM_WORLD
    bars, sned = [], []

    def bars_line(r):
        return (f"bars {r['method']} nx={r['size']}: {r['dofs']} DOFs, wall {r['wall_s']:.3f} s, stress error "
                f"{r['stress_rel_error']:.2e}, duration error {r['duration_error_us']:.2f} µs, rebound velocity "
                f"error {r['velocity_rel_error']:.2e}")

    def sneddon_line(r):
        return (f"sneddon {r['method']} h={r['size']}: {r['dofs']} DOFs, wall {r['wall_s']:.3f} s, opening error "
                f"{r['opening_rel_error']:.3%}")

    q = args.quick
    def ader_bars_case(p, nx):
        return bars_case(p, nx, scheme="ader")

    for rows, case, sizes, line in ((bars, bars_case, QUICK_BARS if q else BARS, bars_line),
                                    (bars, ader_bars_case, QUICK_ADER_BARS if q else ADER_BARS, bars_line),
                                    (bars, cg_bars_case, QUICK_CG_BARS if q else CG_BARS, bars_line),
                                    (sned, sneddon_case, QUICK_SNEDDON if q else SNEDDON, sneddon_line),
                                    (sned, cg_sneddon_case, QUICK_CG_SNEDDON if q else CG_SNEDDON, sneddon_line)):
        for p, cases in sizes.items():
            for size in cases:
                rows.append(case(p, size))
                if comm.rank == 0:
                    print("[study] " + line(rows[-1]), flush=True)
    if comm.rank == 0:
        for name, rows, key, target in (("bars, contact stress", bars, "stress_rel_error", 1e-2),
                                        ("bars, contact stress", bars, "stress_rel_error", 1e-4),
                                        ("bars, rebound velocity", bars, "velocity_rel_error", 1e-2),
                                        ("bars, rebound velocity", bars, "velocity_rel_error", 5e-3),
                                        ("Sneddon, opening", sned, "opening_rel_error", 1e-2),
                                        ("Sneddon, opening", sned, "opening_rel_error", 5e-2)):
            dg = wall_at([r for r in rows if r["family"] == "DG"], target, key)
            cg = wall_at([r for r in rows if r["family"] == "CG"], target, key)
            print(f"[study] {name} at {target:.0e} error: DG {dg:.3g} s, CG {cg:.3g} s, "
                  f"speed-up of DG {cg / dg:.3g}" if np.isfinite(dg) and np.isfinite(cg) else
                  f"[study] {name} at {target:.0e} error: DG {dg:.3g} s, CG {cg:.3g} s (inf: not reached)",
                  flush=True)
        for name, key, target in (("bars, contact stress", "stress_rel_error", 1e-4),
                                  ("bars, rebound velocity", "velocity_rel_error", 1e-2),
                                  ("bars, rebound velocity", "velocity_rel_error", 5e-3)):
            rk = wall_at([r for r in bars if r.get("scheme") == "rk4"], target, key)
            ad = wall_at([r for r in bars if r.get("scheme") == "ader"], target, key)
            print(f"[study] {name} at {target:.0e} error: DG rk4 {rk:.3g} s, DG ader {ad:.3g} s, "
                  f"speed-up of ader {rk / ad:.3g}" if np.isfinite(rk) and np.isfinite(ad) else
                  f"[study] {name} at {target:.0e} error: DG rk4 {rk:.3g} s, DG ader {ad:.3g} s (inf: not reached)",
                  flush=True)
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_csv(out / "work_precision_bars.csv", bars)
        write_csv(out / "work_precision_sneddon.csv", sned)
        plot(bars, sned, out / "work_precision_cracks.png")
        print(f"[study] wrote {out}/work_precision_bars.csv, work_precision_sneddon.csv, work_precision_cracks.png",
              flush=True)
    return bars, sned


if __name__ == "__main__":
    main()
