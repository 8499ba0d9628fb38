"""An animation of a run (GIF) in the style of the paper's pictures, small enough
to attach to a report.

    python -m hydrofrac.postprocess.animate results/intersection_regularized
    python -m hydrofrac.postprocess.animate RUN --kind mesh --max-frames 40 --size 480 360 --fps 6

Every frame is drawn like :mod:`hydrofrac.postprocess.figures` draws one picture
(``energy``: strain-energy colour, kinetic-energy height; ``mesh``: mesh with
cracks coloured by f_p), with one colour range and height scale for the whole
animation.  At most ``--max-frames`` frames of the series are used (evenly
spread, first and last kept).  The GIF is written with Pillow (no imageio or
ffmpeg needed); colours are reduced to one 256-colour palette, which keeps a
60-frame, 560x420 animation at about 1-3 MB.  The frames are drawn by up to 4 processes at
once (``--workers``, default: the cores), into the same GIF as one process draws.
Output: ``RUN/figures/<name>_<kind>.gif``.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Optional

from . import figures
from .rundata import load_run, subsample, tool_main


def animate(source, kind: str = "energy", out=None, max_frames: int = 60, size=(560, 420), fps: float = 8.0,
            crop="auto", log_decades: Optional[float] = figures.LOG_DECADES, workers: Optional[int] = None) -> Path:
    """Write the GIF of a run folder; returns its path.  ``workers``: processes that draw the
    frames (default :func:`default_workers`); the GIF is the same for any number."""
    from PIL import Image
    if kind not in ("energy", "mesh"):
        raise ValueError(f"unknown kind of animation '{kind}': use 'energy' or 'mesh'")
    if max_frames < 2:
        raise ValueError(f"an animation needs at least 2 frames; got --max-frames {max_frames}")
    if workers is not None and (not isinstance(workers, int) or workers < 1):
        raise ValueError(f"--workers must be an integer >= 1; got {workers!r}")
    run = load_run(source)
    frames = subsample(run.frames, max_frames)
    out = Path(out) if out is not None else run.dir / "figures" / f"{run.name}_{kind}.gif"
    out.parent.mkdir(parents=True, exist_ok=True)
    bounds = figures.crop_bounds(run, crop)
    scale = figures.EnergyScale.of(run, frames, bounds, log_decades) if kind == "energy" else None
    field = figures.crack_colour_field(run) if kind == "mesh" else None
    job = (str(run.dir), kind, size, scale, bounds, field)
    # the frames are independent pictures: drawn by several processes at once (each takes every
    # n-th frame); the images are the same as one process draws
    n = min(default_workers() if workers is None else workers, len(frames))
    arrays = None
    if n > 1:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor
        from concurrent.futures.process import BrokenProcessPool
        try:
            with ProcessPoolExecutor(n, mp_context=mp.get_context("spawn")) as pool:
                parts = list(pool.map(_draw, [(job, frames[i::n]) for i in range(n)]))
            arrays = [None] * len(frames)
            for i, part in enumerate(parts):
                arrays[i::n] = part
        except BrokenProcessPool as err:  # e.g. a main module that a new process cannot import
            print(f"[animate] drawing in {n} processes failed ({err}); drawing in this one", flush=True)
    if arrays is None:
        arrays = _draw((job, frames))
    images = [Image.fromarray(a).convert("RGB") for a in arrays]
    # one palette for all frames (taken from a strip of samples of them): no flicker, small file
    strip = Image.new("RGB", (size[0], size[1] * min(len(images), 6)))
    for i, img in enumerate(subsample(images, 6)):
        strip.paste(img, (0, i * size[1]))
    palette = strip.quantize(colors=255, method=Image.MEDIANCUT)
    frames_p = [img.quantize(palette=palette, dither=Image.NONE) for img in images]
    duration = int(round(1000 / fps))
    frames_p[0].save(out, save_all=True, append_images=frames_p[1:], duration=[duration] * (len(frames_p) - 1)
                     + [4 * duration], loop=0, optimize=True)
    return out


#: the most processes that draw an animation's frames
MAX_WORKERS = 4


def default_workers() -> int:
    """Processes for the frames: the cores this process may use, at most :data:`MAX_WORKERS`."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # (not on Linux)
        cores = os.cpu_count() or 1
    return max(1, min(cores, MAX_WORKERS))


def _draw(task):
    """Screenshots (arrays) of the listed frames: one worker's share."""
    (source, kind, size, scale, bounds, field), frames = task
    run = load_run(source)
    out = []
    for frame in frames:
        plotter = figures.new_plotter(size)
        if kind == "energy":
            figures.draw_energy(plotter, run, frame, scale, bounds, font_scale=0.75)
        else:
            figures.draw_mesh(plotter, run, frame, bounds, field=field, font_scale=0.75)
        out.append(plotter.screenshot(None, return_img=True))
        plotter.close()
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hydrofrac.postprocess.animate",
                                     description="GIF animation of a run (strain/kinetic energy or mesh + f_p).")
    parser.add_argument("source", help="output folder of a run (or its .pvd file)")
    parser.add_argument("--kind", choices=("energy", "mesh"), default="energy", help="what to draw (default energy)")
    parser.add_argument("--max-frames", type=int, default=60, help="at most this many frames (default 60)")
    parser.add_argument("--size", type=int, nargs=2, default=(560, 420), metavar=("W", "H"),
                        help="frame size in pixels (default 560 420)")
    parser.add_argument("--fps", type=float, default=8.0, help="frames per second (default 8)")
    parser.add_argument("--crop", nargs="+", default=["auto"],
                        help="'auto' (around the cracks, default), 'full' or x0 x1 y0 y1 [m]")
    parser.add_argument("--log", type=float, default=figures.LOG_DECADES, metavar="DECADES",
                        help="logarithmic strain-energy colours over the top DECADES decades")
    parser.add_argument("--linear", action="store_true", help="linear strain-energy colours from 0")
    parser.add_argument("--out", default=None, help="GIF file (default RUN/figures/<name>_<kind>.gif)")
    parser.add_argument("--workers", type=int, default=None,
                        help=f"processes that draw the frames (default: the cores, at most {MAX_WORKERS})")
    args = parser.parse_args(argv)
    crop = args.crop[0] if len(args.crop) == 1 else [float(c) for c in args.crop]
    return tool_main("animate", lambda: animate(args.source, kind=args.kind, out=args.out, max_frames=args.max_frames,
                                                size=tuple(args.size), fps=args.fps, crop=crop,
                                                log_decades=None if args.linear else args.log,
                                                workers=args.workers))


if __name__ == "__main__":
    sys.exit(main())
