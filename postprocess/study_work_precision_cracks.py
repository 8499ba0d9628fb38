"""Study: work–precision of the DG solver on the two crack verification problems (issue 7,
study 1, continued; the plane wave with the CG baseline is
:mod:`hydrofrac.postprocess.study_work_precision`).

* **Two-bar impact** (verification case 9, ``scenarios/two_bars.py``): p = 1-4 on strips of
  20, 40 and 80 cells along 2 m; errors of the contact stress (plateau against -Z_d v0) and
  of the contact duration (against 2L/c_d, in µs).
* **Sneddon** (case 11, ``scenarios/sneddon.py``, quick domain 8a, dynamic relaxation to the
  static state by 3 ms): p = 1-3 (p = 4 on the two coarser meshes) at crack sizes 0.2a, 0.1a,
  0.05a; L2 error of the opening for |x| < 0.9a.

No CG curve: the baseline has no crack interface (contact or a pressurised crack would need
a contact algorithm or doubled nodes, which it does not have).  Writes
``work_precision_bars.csv``, ``work_precision_sneddon.csv`` and one PNG with both charts into
``postprocess/results`` (``--out``).

    python -m hydrofrac.postprocess.study_work_precision_cracks [--quick] [--out DIR]
"""
from __future__ import annotations

from pathlib import Path

from mpi4py import MPI

from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.study_common import scenario, study_parser, timed_run


BARS = {1: (20, 40, 80), 2: (20, 40, 80), 3: (20, 40, 80), 4: (20, 40, 80)}
SNEDDON = {1: (0.2, 0.1, 0.05), 2: (0.2, 0.1, 0.05), 3: (0.2, 0.1, 0.05), 4: (0.2, 0.1)}
QUICK_BARS = {1: (20, 40), 2: (20, 40)}
QUICK_SNEDDON = {1: (0.2,), 2: (0.2,)}


def bars_case(p, nx):
    tb = scenario("two_bars")
    solver, iface = tb.setup(degree=p, nx=nx)
    rec = tb.Recorder(iface)
    wall = timed_run(solver, 0.75e-3, rec)
    acc = tb.accuracy(solver, iface, rec, 1.0, 1.0)
    return {"p": p, "size": nx, "dofs": solver.num_dofs, "steps": solver.step_count, "wall_s": wall,
            "stress_rel_error": acc["contact_stress_rel_error"],
            "duration_error_us": abs(acc["duration"] - acc["duration_exact"]) * 1e6}


def sneddon_case(p, h):
    sn = scenario("sneddon")
    solver, iface, hyd = sn.setup(degree=p, a=1.0, dp=1.0e6, size=8.0, h_crack=h, h_far=1.5, t_ramp=1.0e-3,
                                  relaxation=1500.0)
    wall = timed_run(solver, 3.0e-3, hyd.on_step)
    acc = sn.opening_error(solver, iface, 1.0, 1.0e6)
    return {"p": p, "size": h, "dofs": solver.num_dofs, "steps": solver.step_count, "wall_s": wall,
            "opening_rel_error": acc["opening_L2_rel_error"]}


def plot(bars, sned, png):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(14, 4), dpi=80)
    for ax, rows, key, label in ((axes[0], bars, "stress_rel_error", "contact stress, relative error"),
                                 (axes[1], bars, "duration_error_us", "contact duration error [µs]"),
                                 (axes[2], sned, "opening_rel_error", "Sneddon opening, L2 relative error")):
        for p in sorted({r["p"] for r in rows}):
            rs = sorted([r for r in rows if r["p"] == p], key=lambda r: r["wall_s"])
            ax.loglog([r["wall_s"] for r in rs], [max(r[key], 1e-16) for r in rs], "o-", label=f"DG P{p}")
        ax.set_xlabel("wall time of the run [s]")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_title("two-bar impact (case 9)", fontsize=10)
    axes[1].set_title("two-bar impact (case 9)", fontsize=10)
    axes[2].set_title("Sneddon crack (case 11)", fontsize=10)
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)


def main(argv=None):
    args = study_parser(__doc__).parse_args(argv)
    comm = MPI.COMM_WORLD
    bars, sned = [], []
    for p, sizes in (QUICK_BARS if args.quick else BARS).items():
        for nx in sizes:
            bars.append(bars_case(p, nx))
            r = bars[-1]
            if comm.rank == 0:
                print(f"[study] bars p={p} nx={nx}: {r['dofs']} DOFs, wall {r['wall_s']:.2f} s, stress error "
                      f"{r['stress_rel_error']:.2e}, duration error {r['duration_error_us']:.2f} µs", flush=True)
    for p, sizes in (QUICK_SNEDDON if args.quick else SNEDDON).items():
        for h in sizes:
            sned.append(sneddon_case(p, h))
            r = sned[-1]
            if comm.rank == 0:
                print(f"[study] sneddon p={p} h={h}: {r['dofs']} DOFs, wall {r['wall_s']:.2f} s, opening error "
                      f"{r['opening_rel_error']:.3%}", flush=True)
    if comm.rank == 0:
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
