"""The paper's pictures of a run, rendered off screen with pyvista.

    python -m hydrofrac.postprocess.figures results/intersection_regularized
    python -m hydrofrac.postprocess.figures RUN --kind energy --times 560us 720us 920us
    python -m hydrofrac.postprocess.figures RUN --kind mesh --frames 6 --size 640 480 --out pics

Two kinds of picture, one PNG per chosen frame plus a sequence sheet of all of them:

* ``energy`` (figs. 7, 8 and 11 of the paper): the strain-energy density as colour
  on the bulk, lifted by the kinetic-energy density as height (oblique view),
  cracks drawn on top (black).  The colours are logarithmic over three decades
  below the 99.5 % quantile (crack tips are singular; ``--log DECADES``,
  ``--linear``), which shows the wave fronts as well as the process zones;
* ``mesh`` (figs. 9 and 12): the space mesh, with the crack facets coloured by the
  pressure factor f_p from blue (0) to red (1); potential paths that are still
  bonded are thin grey lines.  A run without hydraulics colours the cracks by
  the damage D instead.

Every frame carries its time (and p_h, if the history has it); colour range and
height scale are shared by all frames of one call, so the panels compare.  The
frames are chosen by ``--times``, ``--frames N`` (evenly spread), or by default
from the run itself (:func:`hydrofrac.postprocess.rundata.key_times`).  The view
is cropped around the cracks (``--crop full`` shows the whole domain).
Output: ``RUN/figures/<kind>_<time>.png`` and ``RUN/figures/<kind>_sequence.png``.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Sequence, Tuple, Union

import numpy as np

from . import rundata
from .rundata import CRACK_DAMAGE, Run, load_run, select_frames
from .snapshot import _offscreen_environment

#: colour map of the energy pictures and of f_p (blue 0 -> red 1)
ENERGY_CMAP = "turbo"
FP_CMAP = "coolwarm"
#: quantile of the strain-energy density that tops the colour bar (crack tips are singular)
CLIM_QUANTILE = 0.995
#: height of the peak kinetic-energy density, as a share of the picture's width
HEIGHT_SHARE = 0.15
#: decades of strain-energy density shown by the (logarithmic) colours by default
LOG_DECADES = 3.0


def energy_unit(vmax: float) -> Tuple[float, str]:
    """(scale, unit) that puts an energy density of size vmax [J/m³] in 0.1 .. 1000."""
    for scale, unit in ((1e9, "GJ/m³"), (1e6, "MJ/m³"), (1e3, "kJ/m³")):
        if vmax >= 0.5 * scale:
            return scale, unit
    return 1.0, "J/m³"


def time_label(run: Run, t: float) -> str:
    """``t = 563.2 µs`` (µs for runs under 2 ms, else ms) and the hydraulic pressure
    at that time where the history has it."""
    scale, unit = rundata.time_unit(run.t_end)
    text = f"t = {t / scale:.4g} {unit}"
    p_h = run.history_at("p_h", t)
    if p_h is not None:
        text += f"    p_h = {p_h / 1e6:.3g} MPa"
    return text


# ---------------------------------------------------------------------------- geometry
def bulk_surface(path):
    """The bulk part as linear triangles (quadratic and higher DG cells subdivided),
    with all point fields; DG points stay separate, so jumps between cells remain."""
    import pyvista as pv
    grid = pv.read(path)
    level = 1 if grid.celltypes.size and grid.celltypes.max() > 5 else 0
    try:
        surf = grid.extract_surface(nonlinear_subdivision=level, algorithm="dataset_surface")
    except TypeError:  # pyvista without the 'algorithm' keyword
        surf = grid.extract_surface(nonlinear_subdivision=level)
    return surf.triangulate()


def mesh_edges(path):
    """The space mesh: the straight-sided triangles of the bulk cells (corner nodes)."""
    import pyvista as pv
    grid = pv.read(path)
    offsets = np.asarray(grid.cell_offsets if hasattr(grid, "cell_offsets") else grid.offset)[:-1]
    conn = grid.cell_connectivity
    tri = np.stack([conn[offsets], conn[offsets + 1], conn[offsets + 2]], axis=1)
    faces = np.hstack([np.full((tri.shape[0], 1), 3), tri]).ravel()
    return pv.PolyData(np.asarray(grid.points), faces)


def crack_lines(path, min_damage: float = CRACK_DAMAGE):
    """(cracks, bonded): the segments of the cracks part whose mean damage is at
    least ``min_damage``, and the rest (potential paths still bonded)."""
    import pyvista as pv
    grid = pv.read(path)
    D = rundata.segment_values(grid, "D")
    cracked = D >= min_damage
    ids = np.arange(grid.n_cells)
    pick = (lambda sel: grid.extract_cells(ids[sel]) if sel.any() else pv.UnstructuredGrid())
    return pick(cracked), pick(~cracked)


def crop_bounds(run: Run, crop: Union[str, Sequence[float]] = "auto", pad: float = 0.25) -> Tuple[float, ...]:
    """(x0, x1, y0, y1) of the view: 'full' domain, 'auto' (the cracks' bounding box
    grown by ``pad`` of its size on each side, within the domain; the full domain
    where the cracks span most of it or only a small part) or four numbers."""
    import pyvista as pv
    t, parts = run.frames[-1]
    b = pv.read(parts["bulk"]).bounds
    full = (b[0], b[1], b[2], b[3])
    if not isinstance(crop, str):
        if len(crop) != 4:
            raise ValueError(f"--crop takes 'auto', 'full' or four numbers x0 x1 y0 y1; got {crop}")
        return tuple(float(c) for c in crop)
    if crop == "full" or "cracks" not in parts:
        return full
    if crop != "auto":
        raise ValueError(f"--crop takes 'auto', 'full' or four numbers x0 x1 y0 y1; got '{crop}'")
    c = pv.read(parts["cracks"]).bounds
    w, h = c[1] - c[0], c[3] - c[2]
    size = max(w, h)
    domain = max(full[1] - full[0], full[3] - full[2])
    if not 0.1 * domain < size < 0.8 * domain:  # cracks across the domain, or a speck in it: show it all
        return full
    cx, cy = 0.5 * (c[0] + c[1]), 0.5 * (c[2] + c[3])
    half = 0.5 * size + pad * size
    return (max(full[0], cx - half), min(full[1], cx + half), max(full[2], cy - half), min(full[3], cy + half))


def _clip(mesh, bounds):
    x0, x1, y0, y1 = bounds
    b = mesh.bounds
    if b[0] >= x0 - 1e-12 and b[1] <= x1 + 1e-12 and b[2] >= y0 - 1e-12 and b[3] <= y1 + 1e-12:
        return mesh
    return mesh.clip_box((x0, x1, y0, y1, -1e30, 1e30), invert=False, crinkle=False)


# ---------------------------------------------------------------------------- energy pictures
@dataclass
class EnergyScale:
    """Colour range and height scale shared by a sequence of energy pictures."""

    clim: Tuple[float, float]       # strain-energy density [J/m³]
    k_max: float                    # largest kinetic-energy density [J/m³]
    height: float                   # height of k_max [m]
    log: bool = False               # logarithmic colours from clim[0] > 0

    @classmethod
    def of(cls, run: Run, frames, bounds, log_decades: Optional[float] = LOG_DECADES) -> "EnergyScale":
        import pyvista as pv
        w_top, k_max = 0.0, 0.0
        for _, parts in frames:
            g = _clip(pv.read(parts["bulk"]), bounds)
            if g.n_points == 0:
                continue
            w_top = max(w_top, float(np.quantile(g["strain_energy_density"], CLIM_QUANTILE)))
            k_max = max(k_max, float(np.max(g["kinetic_energy_density"])))
        size = max(bounds[1] - bounds[0], bounds[3] - bounds[2])
        w_top = w_top if w_top > 0 else 1.0
        low = w_top * 10.0 ** -log_decades if log_decades else 0.0
        return cls(clim=(low, w_top), k_max=k_max, height=HEIGHT_SHARE * size, log=bool(log_decades))

    def z(self, k):
        return np.asarray(k) * (self.height / self.k_max if self.k_max > 0 else 0.0)


def _lift_cracks(cracks, surf, scale: EnergyScale, eps: float):
    """Crack points raised to the higher of the two faces' kinetic-energy heights."""
    pts = np.asarray(cracks.points).copy()
    sp = np.asarray(surf.points)[:, :2]
    k = np.asarray(surf["kinetic_energy_density"])
    try:
        from scipy.spatial import cKDTree
        _, idx = cKDTree(sp).query(pts[:, :2], k=min(8, sp.shape[0]))
        near = k[idx].max(axis=1)
    except ImportError:
        near = np.array([k[np.argsort(((sp - p[:2]) ** 2).sum(1))[:8]].max() for p in pts])
    pts[:, 2] = scale.z(near) + eps
    out = cracks.copy()
    out.points = pts
    return out


def _camera_3d(plotter, bounds, elevation=38.0):
    """Oblique view from the south, looking at the middle of the crop window."""
    x0, x1, y0, y1 = bounds
    plotter.view_xy()
    plotter.camera.focal_point = (0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.0)
    plotter.camera.Elevation(-(90.0 - elevation))
    plotter.reset_camera()
    plotter.camera.zoom(1.4)
    # move the view down a little: the picture sits above the horizontal colour bar
    cam = plotter.camera
    up = np.asarray(cam.up, dtype=float)
    shift = -0.07 * max(x1 - x0, y1 - y0) * up / np.linalg.norm(up)
    cam.position = tuple(np.asarray(cam.position) + shift)
    cam.focal_point = tuple(np.asarray(cam.focal_point) + shift)


def _scalar_bar(title, n_labels=5, font_scale=1.0):
    return {"title": title, "color": "black", "vertical": False, "n_labels": n_labels, "fmt": "%.3g",
            "position_x": 0.2, "position_y": 0.03, "width": 0.6, "height": 0.09,
            "title_font_size": round(15 * font_scale), "label_font_size": round(13 * font_scale),
            "font_family": "arial"}


def nice_length(span: float) -> float:
    """A round length (1, 2 or 5 x 10^k) of at most a quarter of ``span``."""
    target = 0.25 * span
    k = np.floor(np.log10(target))
    for m in (5.0, 2.0, 1.0):
        if m * 10 ** k <= target:
            return float(m * 10 ** k)
    return float(10 ** k)


def _length_scale(plotter, bounds, font_scale=1.0):
    """A scale bar with its length in metres, lying in the plane z = 0 at the lower left, so
    that every picture (flat or tilted) carries its length scale."""
    import pyvista as pv
    x0, x1, y0, y1 = bounds
    L = nice_length(x1 - x0)
    a = np.array([x0 + 0.05 * (x1 - x0), y0 + 0.06 * (y1 - y0), 0.0])
    b = a + [L, 0.0, 0.0]
    plotter.add_mesh(pv.Line(a, b), color="black", line_width=4)
    for end in (a, b):
        plotter.add_mesh(pv.Line(end - [0, 0.012 * (y1 - y0), 0], end + [0, 0.012 * (y1 - y0), 0]), color="black",
                         line_width=3)
    label = f"{L * 100:g} cm" if L < 1 else f"{L:g} m"
    plotter.add_point_labels([0.5 * (a + b) + [0, 0.03 * (y1 - y0), 0]], [label], font_size=round(12 * font_scale),
                             text_color="black", shape=None, show_points=False, always_visible=True)


def draw_energy(plotter, run: Run, frame, scale: EnergyScale, bounds, labels: bool = True,
                font_scale: float = 1.0):
    """Add the energy picture of one frame to ``plotter``."""
    import pyvista as pv
    t, parts = frame
    surf = _clip(bulk_surface(parts["bulk"]), bounds)
    w_scale, w_unit = energy_unit(scale.clim[1])
    colour = np.asarray(surf["strain_energy_density"]) / w_scale
    clim = (scale.clim[0] / w_scale, scale.clim[1] / w_scale)
    if scale.log:
        colour = np.maximum(colour, clim[0])
    flat = surf.copy()
    flat.points[:, 2] = 0.0
    lifted = surf.copy()
    lifted.points[:, 2] = scale.z(surf["kinetic_energy_density"])
    common = dict(cmap=ENERGY_CMAP, clim=clim, log_scale=scale.log, smooth_shading=False, show_scalar_bar=False)
    # the flat copy underneath fills the slits that open between lifted DG cells
    plotter.add_mesh(flat, scalars=colour.copy(), **common)
    n_labels = int(round(np.log10(clim[1] / clim[0]))) + 1 if scale.log else 5
    plotter.add_mesh(lifted, scalars=colour, ambient=0.25, diffuse=0.8, specular=0.1,
                     scalar_bar_args=_scalar_bar(f"strain energy density [{w_unit}]", n_labels, font_scale),
                     **{**common, "show_scalar_bar": labels})
    if "cracks" in parts:
        cracks, _ = crack_lines(parts["cracks"])
        if cracks.n_cells:
            cracks = _clip(cracks, bounds)
            lines = _lift_cracks(cracks, surf, scale, eps=0.004 * scale.height / HEIGHT_SHARE)
            plotter.add_mesh(lines, color="black", line_width=3, render_lines_as_tubes=False)
    if labels:
        k_scale, k_unit = energy_unit(scale.k_max)
        plotter.add_text(time_label(run, t), position="upper_left", font_size=round(13 * font_scale),
                         color="black")
        # under the time label, left (a second line: no clash with it in narrow pictures)
        height = plotter.window_size[1]
        plotter.add_text(f"height: kinetic energy density, peak {scale.k_max / k_scale:.3g} {k_unit}",
                         position=(6, height - round(52 * font_scale)), font_size=max(6, round(9 * font_scale)),
                         color="black")
    _length_scale(plotter, bounds, font_scale)
    _camera_3d(plotter, bounds)


# ---------------------------------------------------------------------------- mesh pictures
def crack_colour_field(run: Run) -> Tuple[str, str]:
    """(field, colour-bar title) of the crack colours: f_p where the run has hydraulics."""
    for _, parts in run.frames:
        if "cracks" in parts:
            import pyvista as pv
            names = pv.read(parts["cracks"]).point_data.keys()
            return ("f_p", "pressure factor f_p") if "f_p" in names else ("D", "damage D")
    return "f_p", "pressure factor f_p"


def draw_mesh(plotter, run: Run, frame, bounds, labels: bool = True, field: Optional[Tuple[str, str]] = None,
              font_scale: float = 1.0):
    """Add the space-mesh picture of one frame to ``plotter``."""
    t, parts = frame
    name, title = field or crack_colour_field(run)
    edges = _clip(mesh_edges(parts["bulk"]), bounds)
    plotter.add_mesh(edges, style="wireframe", color="#6f6f6f", line_width=0.6)
    if "cracks" in parts:
        cracks, bonded = crack_lines(parts["cracks"])
        if bonded.n_cells:
            plotter.add_mesh(bonded, color="#b9b9b9", line_width=1.5)
        if cracks.n_cells:
            lifted = cracks.copy()
            lifted.points[:, 2] = 1e-3 * (bounds[1] - bounds[0])
            plotter.add_mesh(lifted, scalars=name, cmap=FP_CMAP, clim=(0.0, 1.0), line_width=5,
                             show_scalar_bar=labels, scalar_bar_args=_scalar_bar(title, 3, font_scale))
    if labels:
        plotter.add_text(time_label(run, t), position="upper_left", font_size=round(13 * font_scale),
                         color="black")
    _length_scale(plotter, bounds, font_scale)
    x0, x1, y0, y1 = bounds
    plotter.view_xy()
    plotter.camera.focal_point = (0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.0)
    plotter.reset_camera(bounds=(x0, x1, y0, y1, 0.0, 0.0))
    plotter.camera.zoom(1.1)


# ---------------------------------------------------------------------------- output
def new_plotter(size):
    _offscreen_environment()
    import pyvista as pv
    p = pv.Plotter(off_screen=True, window_size=list(size))
    p.set_background("white")
    return p


def time_tag(t: float) -> str:
    return f"{t * 1e6:08.1f}us".replace(".", "p")


def render_frames(run: Run, kind: str, frames, out: Path, size=(900, 700), crop="auto",
                  log_decades: Optional[float] = LOG_DECADES) -> List[Path]:
    """One PNG per frame of ``kind`` ('energy' or 'mesh'); returns their paths."""
    if kind not in ("energy", "mesh"):
        raise ValueError(f"unknown kind of figure '{kind}': use 'energy' or 'mesh'")
    out.mkdir(parents=True, exist_ok=True)
    bounds = crop_bounds(run, crop)
    scale = EnergyScale.of(run, frames, bounds, log_decades) if kind == "energy" else None
    field = crack_colour_field(run) if kind == "mesh" else None
    pngs = []
    for frame in frames:
        p = new_plotter(size)
        if kind == "energy":
            draw_energy(p, run, frame, scale, bounds)
        else:
            draw_mesh(p, run, frame, bounds, field=field)
        png = out / f"{kind}_{time_tag(frame[0])}.png"
        p.screenshot(str(png))
        p.close()
        pngs.append(png)
    return pngs


def sequence_sheet(pngs: Sequence[Path], out: Path, columns: Optional[int] = None, width: int = 1500,
                   palette: bool = False) -> Path:
    """The pictures side by side, (a), (b), ... in the corner, a short last row centred (no
    empty panel), at most ``width`` pixels wide
    (``palette``: reduced to 256 colours, about a third of the file size, for galleries)."""
    from PIL import Image, ImageDraw, ImageFont
    images = [Image.open(p).convert("RGB") for p in pngs]
    n = len(images)
    columns = columns or (n if n <= 3 else (2 if n == 4 else 3))
    rows = -(-n // columns)
    w, h = images[0].size
    sheet = Image.new("RGB", (columns * w, rows * h), "white")
    draw = ImageDraw.Draw(sheet)
    try:
        font = ImageFont.truetype("DejaVuSans.ttf", max(14, h // 22))
    except OSError:
        font = ImageFont.load_default()
    last_row = n - (rows - 1) * columns  # pictures in the last row: centred, no empty panel
    for i, img in enumerate(images):
        r, c = i // columns, i % columns
        x = c * w + (((columns - last_row) * w) // 2 if r == rows - 1 else 0)
        y = r * h
        sheet.paste(img, (x, y))
        draw.text((x + 8, y + h - max(14, h // 22) - 12), f"({chr(ord('a') + i)})", fill="black", font=font)
    if sheet.width > width:
        sheet = sheet.resize((width, round(sheet.height * width / sheet.width)), Image.LANCZOS)
    if palette:
        sheet = sheet.quantize(colors=256, method=Image.FASTOCTREE, dither=Image.FLOYDSTEINBERG)
    sheet.save(out, optimize=True)
    return out


def make_figures(source, kinds=("energy", "mesh"), times=None, count=None, out=None, size=(900, 700),
                 crop="auto", sheet=True, log_decades: Optional[float] = LOG_DECADES, sheet_width: int = 1500,
                 palette: bool = False, columns: Optional[int] = None) -> List[Path]:
    """Figures of a run folder; returns the PNG paths (the sequence sheets last)."""
    run = load_run(source)
    frames = select_frames(run, times=times, count=count)
    out = Path(out) if out is not None else run.dir / "figures"
    written, sheets = [], []
    for kind in kinds:
        pngs = render_frames(run, kind, frames, out, size=size, crop=crop, log_decades=log_decades)
        written += pngs
        if sheet and len(pngs) > 1:
            sheets.append(sequence_sheet(pngs, out / f"{kind}_sequence.png", columns=columns, width=sheet_width,
                                         palette=palette))
    return written + sheets


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hydrofrac.postprocess.figures",
                                     description="The paper's pictures of a run: strain energy (colour) with "
                                                 "kinetic energy (height), and the mesh with cracks coloured by f_p.")
    parser.add_argument("source", help="output folder of a run (or its .pvd file)")
    parser.add_argument("--kind", nargs="+", choices=("energy", "mesh"), default=["energy", "mesh"],
                        help="which pictures (default both)")
    when = parser.add_mutually_exclusive_group()
    when.add_argument("--times", nargs="+", metavar="T",
                      help="times of the frames: seconds or with a unit (560us, 0.9ms); nearest frame")
    when.add_argument("--frames", type=int, metavar="N", help="N frames evenly spread over the run")
    parser.add_argument("--size", type=int, nargs=2, default=(900, 700), metavar=("W", "H"),
                        help="size of each picture in pixels (default 900 700)")
    parser.add_argument("--crop", nargs="+", default=["auto"],
                        help="'auto' (around the cracks, default), 'full' or x0 x1 y0 y1 [m]")
    parser.add_argument("--log", type=float, default=LOG_DECADES, metavar="DECADES",
                        help=f"logarithmic strain-energy colours over the top DECADES decades "
                             f"(default {LOG_DECADES:g})")
    parser.add_argument("--linear", action="store_true", help="linear strain-energy colours from 0")
    parser.add_argument("--out", default=None, help="folder of the PNGs (default RUN/figures)")
    parser.add_argument("--no-sheet", action="store_true", help="no sequence sheet of all frames")
    parser.add_argument("--sheet-width", type=int, default=1500, help="largest width of a sequence sheet [px]")
    parser.add_argument("--columns", type=int, default=None, help="panels per row of a sequence sheet")
    parser.add_argument("--palette", action="store_true",
                        help="sequence sheets with 256 colours (small files, e.g. for a gallery)")
    args = parser.parse_args(argv)
    crop = args.crop[0] if len(args.crop) == 1 else [float(c) for c in args.crop]
    return rundata.tool_main("figures", lambda: make_figures(
        args.source, kinds=args.kind, times=args.times, count=args.frames, out=args.out, size=tuple(args.size),
        crop=crop, sheet=not args.no_sheet, log_decades=None if args.linear else args.log,
        sheet_width=args.sheet_width, palette=args.palette, columns=args.columns))


if __name__ == "__main__":
    sys.exit(main())
