"""Study: crossing or arrest of a crack at a natural fracture, against friction and angle.

The ``crossing`` scenario (a debonded crack ending on a closed natural fracture under remote
tension 0.7 MPa normal to the crack and compression 1 MPa along it) for fracture friction
coefficients μ and angles between fracture and crack, plus the bonded fracture (D = 0) at
each angle.  Each run goes to 0.9 ms or to the crossing.  The outcome comes from the far-side
criterion in the stress the fracture's interface transmits (docs/model.md §6); no rule on μ
is involved.  Reported per case: crossed or arrested, the crossing time and angle, and the
wall time.  For the fracture normal to the crack, Renshaw & Pollard's (1995) criterion,
-σ_n / (T0 - σ_p) > (0.35 + 0.35/μ)/1.06 with σ_n = -1 MPa, σ_p = 0.7 MPa and T0 = s_ = 1 MPa,
gives the smallest friction for crossing, μ_c = 0.11 (marked on the chart).

    python -m hydrofrac.postprocess.study_crossing [--quick] [--out DIR]

Writes ``crossing.csv`` and ``crossing.png`` in ``--out`` (default postprocess/results).
"""
from __future__ import annotations

import time
from pathlib import Path

from mpi4py import MPI

from hydrofrac.growth import renshaw_pollard_friction
from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.study_common import save_figure, scenario, study_parser

T_END = 9e-4


def case(angle, friction, damage):
    sc = scenario("crossing")
    problem = sc.setup(angle=angle, friction=friction, damage=damage)
    t0 = time.perf_counter()
    while problem.solver.t < T_END * (1 - 1e-12):
        problem.solver.step()
        new = problem.growth(problem)
        problem = new if new is not None else problem
        if sc.outcome(problem.growth)[0] == "crossed":
            break
    what, t = sc.outcome(problem.growth)
    ev = [e for e in problem.growth.tree if e["event"] == "crossing"]
    return {"angle_deg": angle, "friction": friction, "damage": damage, "outcome": what,
            "t_cross_us": (t * 1e6) if t is not None else float("nan"),
            "cross_angle_deg": ev[0]["angle_deg"] if ev else float("nan"),
            "wall_s": MPI.COMM_WORLD.allreduce(time.perf_counter() - t0, op=MPI.MAX)}


def chart(rows, png):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4.5))
    angles = sorted({r["angle_deg"] for r in rows})
    mus = sorted({r["friction"] for r in rows if r["damage"] == 1.0})
    xs = [str(m) for m in mus] + ["bonded"]
    for r in rows:
        x = xs.index("bonded") if r["damage"] == 0.0 else mus.index(r["friction"])
        y = angles.index(r["angle_deg"])
        crossed = r["outcome"] == "crossed"
        ax.scatter(x, y, s=300, marker="o" if crossed else "x", color="tab:green" if crossed else "tab:red")
        if crossed:
            ax.annotate(f"{r['t_cross_us']:.0f} µs", (x, y), textcoords="offset points", xytext=(0, 12),
                        ha="center", fontsize=7)
    mu_c = renshaw_pollard_friction(-1.0e6, 0.7e6, 1.0e6)
    k = sum(m < mu_c for m in mus)  # between the columns either side of mu_c
    if 0 < k < len(mus) and 90.0 in angles:
        x = k - 1 + (mu_c - mus[k - 1]) / (mus[k] - mus[k - 1])
        y = angles.index(90.0)
        ax.plot([x, x], [y - 0.4, y + 0.4], "k--", lw=1)
        ax.annotate(f"Renshaw-Pollard μ_c = {mu_c:.2f}", (x, y - 0.45), ha="center", fontsize=7)
    ax.set_xticks(range(len(xs)), xs)
    ax.set_yticks(range(len(angles)), [f"{a:g}°" for a in angles])
    ax.set_xlabel("fracture friction coefficient μ (debonded, closed) / bonded")
    ax.set_ylabel("angle between fracture and crack")
    ax.set_title("crossing (o, with its time) or arrest (x) at a natural fracture", fontsize=10)
    ax.set_xlim(-0.5, len(xs) - 0.5)
    ax.set_ylim(-0.6, len(angles) - 0.4)
    ax.grid(True, alpha=0.3)
    save_figure(fig, png)


def main(argv=None):
    args = study_parser(__doc__).parse_args(argv)
    angles = (90.0, 60.0) if args.quick else (90.0, 75.0, 60.0, 45.0)
    mus = (0.0, 0.3) if args.quick else (0.0, 0.05, 0.1, 0.12, 0.15, 0.2, 0.3, 0.6, 1.0)
    rows = []
    for a in angles:
        for mu in mus:
            rows.append(case(a, mu, 1.0))
        rows.append(case(a, 0.0, 0.0))
    if MPI.COMM_WORLD.rank == 0:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_csv(out / "crossing.csv", rows)
        chart(rows, out / "crossing.png")
        print(f"[study] Renshaw-Pollard smallest friction for crossing at 90 deg: {renshaw_pollard_friction(-1.0e6, 0.7e6, 1.0e6):.3f}")
        for r in rows:
            print(f"[study] angle {r['angle_deg']:4.0f} mu {r['friction']:4.2f} D {r['damage']:.0f}: "
                  f"{r['outcome']:8s} t {r['t_cross_us']:6.0f} us, angle {r['cross_angle_deg']:6.1f} deg, "
                  f"{r['wall_s']:.1f} s", flush=True)
    return rows


if __name__ == "__main__":
    main()
