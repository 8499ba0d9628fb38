"""Study: the path of a single growing tip under mesh refinement.

The ``two_cracks`` scenario (one pressurised perforation, its crack grows freely towards an
unloaded natural fracture at x = 0.8 m; p = 2, Δa = 2h, r = 4h) at five crack-facet sizes h.
Reported per size: the join time (the tip meets the fracture), where it meets it (y), the
largest segment angle off the x axis, the number of extensions, and the largest distance of
the path from the finest one (its Hausdorff distance, in h of the finest).  The rate of the
join time's convergence comes from the three finest sizes.

    python -m hydrofrac.postprocess.study_path_convergence [--quick] [--out DIR]

Writes ``path_convergence.csv`` and ``path_convergence.png`` in ``--out``
(default postprocess/results).
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

from hydrofrac import wellbore
from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.study_common import save_figure, scenario, study_parser

T_END = 9e-4


def hausdorff(a, b, n=200):
    """Largest distance between two polylines, sampled at ``n`` points along each."""
    def sample(p):
        seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        t = np.linspace(0.0, s[-1], n)
        return np.stack([np.interp(t, s, p[:, 0]), np.interp(t, s, p[:, 1])], axis=1)

    def dist(x, p):  # from points x to polyline p
        a_, b_ = p[:-1], p[1:]
        e = b_ - a_
        u = np.clip(np.einsum("mij,ij->mi", x[:, None, :] - a_[None], e) / np.einsum("ij,ij->i", e, e), 0, 1)
        return np.linalg.norm(a_[None] + u[..., None] * e[None] - x[:, None, :], axis=2).min(axis=1)

    sa, sb = sample(a), sample(b)
    return float(max(dist(sa, b).max(), dist(sb, a).max()))


def case(h):
    sc = scenario("two_cracks")
    problem = wellbore.setup(sc.description(h=h))[0]
    t0 = time.perf_counter()
    while problem.solver.t < T_END * (1 - 1e-12):
        problem.solver.step()
        problem.after_step()
        new = problem.growth(problem)
        problem = new if new is not None else problem
        if problem.growth.joined:
            break
    g = problem.growth
    p = np.array(g.paths[0])
    seg = np.diff(p, axis=0)
    ang = np.degrees(np.arctan2(seg[:, 1], seg[:, 0]))
    return {"h": h, "join_t_us": g.joined[0][0] * 1e6 if g.joined else float("nan"),
            "join_y_m": float(g.joined[0][2][1]) if g.joined else float("nan"),
            "max_angle_deg": float(np.abs(ang).max()) if ang.size else float("nan"),
            "extensions": len(seg), "wall_s": MPI.COMM_WORLD.allreduce(time.perf_counter() - t0, op=MPI.MAX),
            "_path": p}


def chart(rows, png):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    for r in rows:
        p = r["_path"]
        a1.plot(p[:, 0], p[:, 1], "o-", ms=3, label=f"h = {r['h'] * 100:.2f} cm")
    a1.axvline(0.8, color="k", lw=1, label="natural fracture")
    a1.set_xlabel("x [m]")
    a1.set_ylabel("y [m]")
    a1.set_title("path of the tip", fontsize=10)
    a1.legend(fontsize=8)
    a1.grid(True, alpha=0.3)
    hs = [r["h"] for r in rows]
    a2.plot(hs, [r["join_t_us"] for r in rows], "o-")
    a2.set_xscale("log")
    a2.set_xlabel("h [m]")
    a2.set_ylabel("join time [µs]")
    a2.set_title("time the tip meets the natural fracture", fontsize=10)
    a2.grid(True, which="both", alpha=0.3)
    save_figure(fig, png)


def main(argv=None):
    args = study_parser(__doc__).parse_args(argv)
    sizes = (0.06, 0.042) if args.quick else (0.06, 0.042, 0.03, 0.021, 0.015)
    rows = [case(h) for h in sizes]
    finest = rows[-1]
    for r in rows:
        r["hausdorff_to_finest_h"] = hausdorff(r["_path"], finest["_path"]) / finest["h"]
    t = [r["join_t_us"] for r in rows[-3:]]
    rate = float("nan")
    if len(t) == 3 and (t[1] - t[2]) != 0 and (t[0] - t[1]) / (t[1] - t[2]) > 0:
        rate = math.log(abs((t[0] - t[1]) / (t[1] - t[2]))) / math.log(sizes[-3] / sizes[-2])
    if MPI.COMM_WORLD.rank == 0:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        table = [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]
        write_csv(out / "path_convergence.csv", table)
        chart(rows, out / "path_convergence.png")
        for r in table:
            print(f"[study] h {r['h'] * 100:5.2f} cm: join {r['join_t_us']:7.1f} us at y = {r['join_y_m']:+.4f} m, "
                  f"max angle {r['max_angle_deg']:5.2f} deg, {r['extensions']} extensions, "
                  f"distance to the finest {r['hausdorff_to_finest_h']:.2f} h, {r['wall_s']:.0f} s", flush=True)
        print(f"[study] join time: observed order {rate:.2f} from the three finest sizes", flush=True)
    return rows


if __name__ == "__main__":
    main()
