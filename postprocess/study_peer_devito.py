"""Study: the DG bulk against an external peer, Devito's staggered-grid velocity-stress scheme.

The plane P wave of ``study_work_precision`` (a Gaussian pulse of width 0.12 m crossing the
unit square for 0.2 m of travel) on both codes, one core each, float64, the same final time:

* DG: P_p, p = 1-3, RK4, the low-storage lsrk54 (p = 2, 3) and ADER (p = 1-4), each at its default CFL, the
  matrix-free operator, the exact solution as the boundary's outer state (compiled); error:
  the relative energy norm over the unit square;
* Devito 4.8 (``postprocess/peer_devito.py``, run in Devito's own environment as a child
  process): space orders 2, 4 and 8, leapfrog at Courant number 0.5, the unit square padded
  by a ring that keeps its edges out of the square until the final time; error: the same
  energy norm over the unit square, each field on its own staggered points and times.

Wall times are the time loops only, the minimum of 3 repeats (Devito: its own timer of the
compiled loop, without the Python call of ``Operator.apply``).  Each run's flops are counted
too: DG's from its kernels' flop model (``postprocess/roofline.py``), Devito's by Devito itself
for the operator it generated.  At each target error the study gives the wall-time ratio, the
ratio of the fewest flops each code needs, and the flop rate (and fraction of one core's
multiply-add peak, measured in the same run) the DG step would need for DG/Devito = 30.
Writes ``peer_devito.csv``, ``peer_devito_ratios.csv`` and ``peer_devito.png`` (``--out``)
and prints the frontier ratios at 10 %, 1 % and 0.1 %.
Devito is optional: ``make devito-env`` installs it into ``.venv-devito``
(``--devito-python`` or ``HYDROFRAC_DEVITO_PYTHON`` point elsewhere); without it only the DG
half runs, and the study says so.

    python -m hydrofrac.postprocess.study_peer_devito [--quick] [--out DIR]
"""
from __future__ import annotations

import json
import os
import subprocess
import tempfile
from pathlib import Path

from mpi4py import MPI

from hydrofrac.postprocess.roofline import peak_flops
from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.study_common import log_axes, save_figure, study_parser, wall_at
from hydrofrac.postprocess.study_work_precision import DIRECTION, MAT, TRAVEL, WIDTH, run_dg

ROOT = Path(__file__).resolve().parents[1]
DG = {1: (8, 16, 32, 64), 2: (8, 16, 32), 3: (4, 8, 16, 32)}
#: the low-storage scheme the time-scheme study measured fastest (docs/benchmarks.md, "Time schemes")
DG_LSRK = {"lsrk54": {2: (8, 16, 32), 3: (4, 8, 16, 32)},
           "ader": {1: (8, 16, 32, 64), 2: (8, 16, 32), 3: (4, 8, 16, 32), 4: (4, 6, 8, 12)}}
QUICK_DG_LSRK = {"lsrk54": {3: (4, 8)}, "ader": {3: (4, 8)}}
DEVITO = {2: (16, 32, 64, 128, 256), 4: (16, 32, 64, 128), 8: (16, 32, 64)}
QUICK_DG = {1: (8, 16), 3: (4, 8)}
QUICK_DEVITO = {2: (16, 32), 4: (16, 32)}
TARGETS = (0.1, 0.01, 0.001)
GOAL = 30.0  #: the DG/Devito ratio asked for (docs/studies/peer_devito.md)


def dg_rows(sizes, repeats=3, scheme="rk4"):
    rows = []
    for p, Ns in sizes.items():
        for N in Ns:
            runs = [run_dg(MPI.COMM_SELF, p, N, scheme) for _ in range(repeats)]
            best = min(runs, key=lambda r: r["wall_s"])
            rows.append({**best, "unknowns_unit_square": best["dofs"], "apply_wall_s": best["wall_s"]})
    return rows


def devito_python(arg=None):
    """The Python of Devito's environment, or None where it is absent."""
    cand = arg or os.environ.get("HYDROFRAC_DEVITO_PYTHON") or str(ROOT / ".venv-devito" / "bin" / "python")
    if not Path(cand).exists():
        return None
    ok = subprocess.run([cand, "-c", "import devito"], capture_output=True).returncode == 0
    return cand if ok else None


def devito_rows(python, sizes, repeats=3):
    prm = {"direction": list(map(float, DIRECTION)), "width": WIDTH, "travel": TRAVEL, "rho": MAT.rho,
           "lam": MAT.lam, "mu": MAT.mu, "repeats": repeats,
           "cases": [[so, N] for so, Ns in sizes.items() for N in Ns]}
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "in.json", Path(tmp) / "out.json"
        src.write_text(json.dumps(prm))
        env = {**os.environ, "OMP_NUM_THREADS": "1", "DEVITO_LANGUAGE": "C", "DEVITO_LOGGING": "WARNING"}
        subprocess.run([python, str(ROOT / "postprocess" / "peer_devito.py"), str(src), str(dst)], check=True,
                       env=env)
        return json.loads(dst.read_text())


def chart(rows, png):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    for m in sorted({r["method"] for r in rows}):
        rs = sorted([r for r in rows if r["method"] == m], key=lambda r: r["dofs"])
        style = "o-" if "DG" in m else "s--"
        for ax, key in zip(axes, ("wall_s", "flops")):
            ax.loglog([r[key] for r in rs], [r["rel_error"] for r in rs], style, label=m)
    axes[0].set_xlabel("wall time of the time loop [s] (one core, min of 3)")
    axes[1].set_xlabel("flops of the run (DG: its kernels' model; Devito: its own count)")
    for ax in axes:
        ax.set_ylabel("relative energy-norm error")
    axes[0].set_title("plane P wave: DG (this code) against Devito's staggered grid")
    axes[1].set_title("the same runs by the work they do")
    log_axes(*axes)
    save_figure(fig, png)


def ratios(rows, peak):
    """At each target error: the wall times and fewest flops of each code's frontier, their
    ratios, Devito's flop rate there, and the flop rate (and fraction of the multiply-add peak
    ``peak`` [flop/s]) that DG's fewest-flop frontier would need for DG/Devito = GOAL."""
    dg = [r for r in rows if r["family"] == "DG"]
    dv = [r for r in rows if r["family"] == "Devito"]
    out = []
    for e in TARGETS:
        a, b = wall_at(dg, e, "rel_error"), wall_at(dv, e, "rel_error")
        fa, fb = wall_at(dg, e, "rel_error", "flops"), wall_at(dv, e, "rel_error", "flops")
        need = fa / (GOAL * b) if b else float("nan")
        out.append({"error": e, "dg_wall_s": a, "devito_wall_s": b, "ratio": a / b if b else float("nan"),
                    "dg_flops": fa, "devito_flops": fb, "flop_ratio": fa / fb if fb else float("nan"),
                    "devito_gflops": fb / b / 1e9 if b else float("nan"), "dg_gflops_for_goal": need / 1e9,
                    "dg_fraction_of_peak_for_goal": need / peak, "peak_gflops": peak / 1e9,
                    "ratio_at_peak": fa / peak / b if b else float("nan")})
    return out


def main(argv=None):
    parser = study_parser(__doc__)
    parser.add_argument("--devito-python", default=None, help="the Python of an environment with Devito")
    args = parser.parse_args(argv)
    rows = dg_rows(QUICK_DG if args.quick else DG)
    for scheme, sizes in (QUICK_DG_LSRK if args.quick else DG_LSRK).items():
        rows += dg_rows(sizes, scheme=scheme)
    py = devito_python(args.devito_python)
    if py is None:
        print("[study] Devito is not installed (make devito-env): only the DG half ran", flush=True)
    else:
        rows += devito_rows(py, QUICK_DEVITO if args.quick else DEVITO)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "peer_devito.csv", rows)
    chart(rows, out / "peer_devito.png")
    for r in rows:
        print(f"[study] {r['method']:10s} N {r['N']:4d} unknowns {r['dofs']:8d} steps {r['steps']:5d} "
              f"wall {r['wall_s'] * 1e3:9.3f} ms  error {r['rel_error']:.3e}", flush=True)
    if py is not None:
        peak = peak_flops()
        table = ratios(rows, peak)
        write_csv(out / "peer_devito_ratios.csv", table)
        print(f"[study] one core's multiply-add peak {peak / 1e9:.1f} GFlop/s", flush=True)
        for r in table:
            print(f"[study] error {r['error']:.0e}: DG {r['dg_wall_s'] * 1e3:.3g} ms, Devito "
                  f"{r['devito_wall_s'] * 1e3:.3g} ms, DG/Devito {r['ratio']:.3g}; fewest flops DG "
                  f"{r['dg_flops']:.3g}, Devito {r['devito_flops']:.3g} ({r['flop_ratio']:.3g}x; Devito at "
                  f"{r['devito_gflops']:.3g} GFlop/s); DG/Devito = {GOAL:.0f} needs DG at "
                  f"{r['dg_gflops_for_goal']:.3g} GFlop/s, {r['dg_fraction_of_peak_for_goal']:.2f} of the peak "
                  f"(at the peak DG/Devito would be {r['ratio_at_peak']:.3g})", flush=True)
    return rows


if __name__ == "__main__":
    main()
