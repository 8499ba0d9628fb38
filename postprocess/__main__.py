"""Every picture of a run in one go: figures, charts, animation and the ParaView view.

    python -m hydrofrac.postprocess results/intersection_regularized
    python -m hydrofrac.postprocess RUN --out pics --no-animation --no-paraview

Runs :mod:`~hydrofrac.postprocess.figures` (energy and mesh pictures at the run's
key times, and their sequence sheets), :mod:`~hydrofrac.postprocess.charts`,
:mod:`~hydrofrac.postprocess.animate` (energy GIF) and, where ParaView is
installed, ``postprocess/paraview/open_run.py`` under ``pvpython`` (through
``xvfb-run`` without a display), which saves a screenshot and a ``.pvsm`` state.
Everything goes to ``RUN/figures`` unless ``--out`` says otherwise; the last
lines printed say where each kind of output is.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path

from . import animate, charts, figures
from .rundata import load_run

OPEN_RUN = Path(__file__).resolve().parent / "paraview" / "open_run.py"


def paraview_command(run_dir: Path, out: Path, name: str):
    """The pvpython command line of open_run.py, or None without ParaView."""
    if shutil.which("pvpython") is None:
        return None
    cmd = ["pvpython", str(OPEN_RUN), str(run_dir), "--png", str(out / f"{name}_paraview.png"),
           "--state", str(out / f"{name}.pvsm")]
    if not os.environ.get("DISPLAY"):
        if shutil.which("xvfb-run") is None:
            return None
        cmd = ["xvfb-run", "-a"] + cmd
    return cmd


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hydrofrac.postprocess",
                                     description="Figures, charts, animation and ParaView state of a run.")
    parser.add_argument("source", help="output folder of a run (or its .pvd file)")
    parser.add_argument("--out", default=None, help="output folder (default RUN/figures)")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help="N frames evenly spread for the figures (default: the run's key times)")
    parser.add_argument("--size", type=int, nargs=2, default=(900, 700), metavar=("W", "H"),
                        help="size of each figure in pixels (default 900 700)")
    parser.add_argument("--no-animation", action="store_true", help="skip the GIF")
    parser.add_argument("--no-paraview", action="store_true", help="skip the ParaView screenshot and state")
    args = parser.parse_args(argv)
    try:
        run = load_run(args.source)
    except (FileNotFoundError, ValueError) as err:
        print(f"postprocess: {err}", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else run.dir / "figures"
    out.mkdir(parents=True, exist_ok=True)
    # ParaView runs as its own process beside the figures, charts and animation (it reads the
    # run's files and writes only its own two): on 2 cores the two halves overlap
    paraview, cmd = None, None
    if not args.no_paraview:
        cmd = paraview_command(run.dir, out, run.pvd.stem)
        if cmd is None:
            print("[postprocess] ParaView (pvpython, and xvfb-run without a display) not found: "
                  "no ParaView screenshot/state")
        else:
            paraview = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        pngs = figures.make_figures(run.dir, out=out, count=args.frames, size=tuple(args.size))
        chart_pngs = charts.make_charts(run.dir, out=out) if run.history else []
        gif = None if args.no_animation else animate.animate(run.dir, out=out / f"{run.name}_energy.gif")
    except BaseException:
        if paraview is not None:
            paraview.kill()
            paraview.communicate()
        raise
    pv_files = []
    if paraview is not None:
        try:
            stdout, stderr = paraview.communicate(timeout=600)
        except subprocess.TimeoutExpired:
            paraview.kill()
            stdout, stderr = paraview.communicate()
        if paraview.returncode == 0 and "open_run: ok" in stdout:
            pv_files = [out / f"{run.pvd.stem}.pvsm", out / f"{run.pvd.stem}_paraview.png"]
        else:
            print(f"[postprocess] {' '.join(cmd)} failed (exit {paraview.returncode}):\n{stderr[-2000:]}")
    sheets = [p for p in pngs if p.name.endswith("_sequence.png")]
    print(f"[postprocess] figures:   {len(pngs) - len(sheets)} PNGs in {out} "
          f"(sequences: {', '.join(p.name for p in sheets) or '-'})")
    if chart_pngs:
        print(f"[postprocess] charts:    {chart_pngs[-1]} (one page) and "
              f"{', '.join(p.name for p in chart_pngs[:-1])}")
    if gif is not None:
        print(f"[postprocess] animation: {gif} ({gif.stat().st_size / 1e6:.1f} MB)")
    print(f"[postprocess] ParaView:  paraview {run.pvd}" + (f"   or   paraview --state={pv_files[0]}"
                                                          if pv_files else ""))
    if pv_files:
        print(f"[postprocess] ParaView screenshot: {pv_files[1]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
