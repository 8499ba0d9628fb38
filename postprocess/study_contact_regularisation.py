"""Study: the regularised contact map against the exact one, closing across a gap.

Two bars (the two_bars scenario's strip, p = 2, 40 cells) close at ±v0 across a small initial
gap that shuts in the middle of a time step, stay in contact for 2L/c_d and fly apart.  For
the exact map (fig. 3) and the regularised one (fig. 4) at several maximum penetrations δ'₀,
and at three time steps (the CFL step, 1/2 and 1/4 of it), with the opening clip disabled
(``ContactParams(clip=False)``: the dynamics alone) and, separately, enabled (its activations):

* chatter: contact-mode flips (η crossing 1/2) per Gauss point and millisecond;
* smoothness: the total variation of the mean normal traction history, relative to that of
  the exact answer (a plateau −Z_d v0 switched on and off: 2 Z_d v0), and its largest
  overshoot beyond −Z_d v0;
* convergence in dt: the L1 difference of the traction history from the next finer dt,
  and its rate;
* the energy balance error and the rebound-velocity error;
* the largest penetration relative to the permitted |δ'₀| δ̃.

    python -m hydrofrac.postprocess.study_contact_regularisation [--quick] [--out DIR]

Writes ``contact_regularisation.csv`` and ``.png`` in ``--out`` (default postprocess/results).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from mpi4py import MPI

from hydrofrac import ROCK
from hydrofrac.interface import ContactParams
from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.study_common import log_axes, save_figure, scenario, study_parser
from hydrofrac.solver import CFL_DEFAULT

V0, L, GAP_STEPS, T_END = 1.0, 1.0, 10.5, 0.85e-3


def closing_bars(regularized, delta0, dt_factor, clip, nx=40, degree=2):
    """The two_bars scenario with a gap that closes after GAP_STEPS CFL steps (mid-step), at
    CFL x dt_factor."""
    tb = scenario("two_bars")
    contact = ContactParams(delta0=delta0, regularized=regularized, clip=clip)
    return tb.setup(degree=degree, nx=nx, L=L, v0=V0, gap_steps=GAP_STEPS, contact=contact,
                    cfl=CFL_DEFAULT["rk4"] * dt_factor), tb


def measure(regularized, delta0, dt_factor, clip):
    problem, tb = closing_bars(regularized, delta0, dt_factor, clip)
    solver, iface, comm = problem.solver, problem.interface, problem.comm
    rec = tb.Recorder(L, V0)
    solver.update_energy()
    flips = 0
    last = None
    while solver.t < T_END * (1 - 1e-12):
        solver.step()
        solver.update_energy()
        problem.after_step()
        rec(problem)
        on = iface.last["eta"] > 0.5
        if last is not None:
            flips += int(np.count_nonzero(on != last))
        last = on
    flips = comm.allreduce(flips, op=MPI.SUM)
    points = comm.allreduce(iface.last["eta"].size, op=MPI.SUM)
    acc = rec.accuracy(problem)
    sn = np.asarray(rec.sn)
    exact = -ROCK.Zd * V0
    rep = iface.contact_report()
    permitted = abs(delta0) * comm.allreduce(float(iface.delta_scale.max()) if iface.facets.size else 0.0,
                                             op=MPI.MAX)
    return {
        "map": "regularised" if regularized else "exact", "delta0": delta0, "dt_factor": dt_factor,
        "dt": solver.dt, "clip": clip,
        "flips_per_point_per_ms": flips / points / (T_END * 1e3),
        "traction_tv_rel": float(np.abs(np.diff(np.r_[0.0, sn, 0.0])).sum() / (2 * abs(exact))),
        "overshoot_rel": float(max(0.0, (-sn).max() / abs(exact) - 1)),
        "balance_error_rel": solver.energy.as_dict()["balance_error_relative"],
        "velocity_rel_error": acc.get("velocity_rel_error", float("nan")),
        "penetration_rel": rep["max_penetration"] / permitted,
        "clip_activations": rep["clip_activations"],
        "_t": np.asarray(rec.t), "_sn": sn,
    }


def convergence(rows):
    """L1 difference of each run's traction history from the next finer dt's, and its rate."""
    for r in rows:
        finer = [q for q in rows if q["map"] == r["map"] and q["delta0"] == r["delta0"] and q["clip"] == r["clip"]
                 and math.isclose(q["dt_factor"], r["dt_factor"] / 2)]
        r["l1_to_finer"] = float("nan")
        if finer:
            q = finer[0]
            diff = np.abs(np.interp(r["_t"], q["_t"], q["_sn"]) - r["_sn"])
            r["l1_to_finer"] = float(np.sum(diff) * r["dt"] / (ROCK.Zd * V0 * T_END))
    for r in rows:
        finer = [q for q in rows if q["map"] == r["map"] and q["delta0"] == r["delta0"] and q["clip"] == r["clip"]
                 and math.isclose(q["dt_factor"], r["dt_factor"] / 2)]
        r["rate"] = (math.log2(r["l1_to_finer"] / finer[0]["l1_to_finer"])
                     if finer and finer[0]["l1_to_finer"] > 0 and np.isfinite(finer[0]["l1_to_finer"])
                     else float("nan"))


def chart(rows, png):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    free = [r for r in rows if not r["clip"]]
    for f, marker in zip(sorted({r["dt_factor"] for r in free}, reverse=True), "osd"):
        reg = sorted([r for r in free if r["map"] == "regularised" and r["dt_factor"] == f], key=lambda r: -r["delta0"])
        ex = [r for r in free if r["map"] == "exact" and r["dt_factor"] == f]
        d0 = [abs(r["delta0"]) for r in reg]
        for ax, key in zip(axes, ("traction_tv_rel", "flips_per_point_per_ms", "penetration_rel")):
            ax.plot(d0, [r[key] for r in reg], marker + "-", label=f"regularised, dt x {f:g}")
            if ex:
                ax.axhline(ex[0][key], ls="--", lw=1, color=ax.lines[-1].get_color(),
                           label=f"exact map, dt x {f:g}")
    for ax, title in zip(axes, ("traction total variation / exact", "mode flips per point per ms",
                                "max penetration / permitted (clip off)")):
        ax.set_xscale("log")
        ax.set_xlabel("|δ'₀|")
        ax.set_title(title, fontsize=11)
        log_axes(ax)
    axes[2].axhline(1.0, color="k", lw=1)
    axes[2].set_yscale("log")
    fig.suptitle("two bars closing across a gap: regularised contact map against the exact one")
    save_figure(fig, png)


def main(argv=None):
    args = study_parser(__doc__).parse_args(argv)
    deltas = (-0.01, -0.3) if args.quick else (-0.01, -0.03, -0.1, -0.3, -1.0)
    factors = (1.0, 0.5) if args.quick else (1.0, 0.5, 0.25)
    rows = []
    for f in factors:
        rows.append(measure(False, -0.01, f, clip=False))
        for d0 in deltas:
            for clip in (False, True):
                rows.append(measure(True, d0, f, clip))
    convergence(rows)
    comm = MPI.COMM_WORLD
    if comm.rank == 0:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        table = [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]
        write_csv(out / "contact_regularisation.csv", table)
        chart(rows, out / "contact_regularisation.png")
        for r in table:
            print(f"[study] {r['map']:11s} d0 {r['delta0']:6.2f} dt x {r['dt_factor']:4.2f} clip {r['clip']!s:5s} "
                  f"TV {r['traction_tv_rel']:.4f} overshoot {r['overshoot_rel']:.4f} flips {r['flips_per_point_per_ms']:.2f} "
                  f"pen/permitted {r['penetration_rel']:.3g} clips {r['clip_activations']} "
                  f"L1 {r['l1_to_finer']:.3g} rate {r['rate']:.2f} vel err {r['velocity_rel_error']:.4f} "
                  f"balance {r['balance_error_rel']:.2e}", flush=True)
    return rows


if __name__ == "__main__":
    main()
