"""The README gallery: small PNGs of the paper's problems, made from their full-size runs.

    mpirun -n 2 python scenarios/intersection_regularized.py --frames 120 --out /tmp/g/reg
    mpirun -n 2 python scenarios/intersection_unregularized.py --frames 120 --out /tmp/g/unreg
    mpirun -n 2 python scenarios/refracture.py --frames 120 --out /tmp/g/refrac
    python -m hydrofrac.postprocess.gallery --regularized /tmp/g/reg --unregularized /tmp/g/unreg \\
        --refracture /tmp/g/refrac --out postprocess/gallery

(``make gallery`` does all of it.)  Writes, each under 300 KB (256 colours):

* ``intersection_regularized_energy.png`` and ``..._mesh.png``: six frames at the
  key times of the regularised run (before, at, half and all of the natural
  fracture loaded, later, end);
* ``intersection_unregularized_mesh.png``: the same times without regularisation;
* ``refracture_energy.png`` and ``refracture_mesh.png``: removal, closing,
  closed, re-loading, end;
* ``intersection_regularized_charts.png`` and ``refracture_charts.png``.

Many frames (``--frames 120``) let the key times fall close to the events.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import List

from . import charts, figures
from .rundata import load_run, select_frames

PANEL = (640, 500)
WIDTH = 1200


def _quantised(src: Path, dst: Path) -> Path:
    from PIL import Image
    with Image.open(src) as img:
        img.convert("RGB").quantize(colors=256, method=Image.FASTOCTREE, dither=Image.FLOYDSTEINBERG) \
            .save(dst, optimize=True)
    return dst


def sheets(source, out: Path, name: str, kinds, times=None, tmp: Path = None) -> List[Path]:
    """Sequence sheets of ``kinds`` of one run (at ``times``, default its key times)."""
    run = load_run(source)
    frames = select_frames(run, times=times)
    written = []
    for kind in kinds:
        pngs = figures.render_frames(run, kind, frames, tmp / f"{name}_{kind}", size=PANEL)
        written.append(figures.sequence_sheet(pngs, out / f"{name}_{kind}.png", width=WIDTH, palette=True))
    return written


def make_gallery(regularized, unregularized, refracture, out) -> List[Path]:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        reg_times = [t for t, _ in select_frames(load_run(regularized))]
        written += sheets(regularized, out, "intersection_regularized", ("energy", "mesh"), tmp=tmp)
        written += sheets(unregularized, out, "intersection_unregularized", ("mesh",), times=reg_times, tmp=tmp)
        written += sheets(refracture, out, "refracture", ("energy", "mesh"), tmp=tmp)
        for name, run in (("intersection_regularized", regularized), ("refracture", refracture)):
            page = charts.make_charts(run, out=tmp / f"{name}_charts")[-1]
            written.append(_quantised(page, out / f"{name}_charts.png"))
    return written


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hydrofrac.postprocess.gallery",
                                     description="README gallery PNGs from --quick runs of the paper's problems.")
    parser.add_argument("--regularized", required=True, help="output folder of intersection_regularized")
    parser.add_argument("--unregularized", required=True, help="output folder of intersection_unregularized")
    parser.add_argument("--refracture", required=True, help="output folder of refracture")
    parser.add_argument("--out", default="postprocess/gallery", help="folder of the PNGs")
    args = parser.parse_args(argv)
    try:
        pngs = make_gallery(args.regularized, args.unregularized, args.refracture, args.out)
    except (FileNotFoundError, KeyError, ValueError) as err:
        print(f"gallery: {err}", file=sys.stderr)
        return 2
    for p in pngs:
        print(f"{p}  ({p.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
