"""PNG picture of one frame of a hydrofrac ``.pvd`` series, rendered off screen.

    python -m hydrofrac.postprocess.snapshot results/borehole
    python -m hydrofrac.postprocess.snapshot results/borehole/borehole.pvd --field stress:xy --time 2e-4 --png s.png

The bulk part (``.pvtu``) of the chosen frame is read with pyvista and drawn in
the x-y plane with a colour bar (field name and unit) and the simulated time.
Vector and tensor fields are shown as their magnitude unless a component is
given after a colon (``velocity:x``, ``stress:yy``).  Rendering needs no X
server: without ``DISPLAY``, VTK is pointed at EGL when the system has it.
"""
from __future__ import annotations

import argparse
import ctypes.util
import os
import sys
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Dict, List, Optional, Tuple, Union

#: units of the fields written by :func:`hydrofrac.io.bulk_part`
UNITS = {"strain_energy_density": "J/m^3", "kinetic_energy_density": "J/m^3", "velocity": "m/s", "stress": "Pa",
         "material": "-", "rank": "-"}
#: component labels of vector and (VTK symmetric) tensor fields
COMPONENTS = {3: ("x", "y", "z"), 6: ("xx", "yy", "zz", "xy", "yz", "xz")}


def _offscreen_environment():
    """Without an X display, ask VTK for an EGL (headless) render window if EGL is installed."""
    if os.environ.get("DISPLAY") or "VTK_DEFAULT_OPENGL_WINDOW" in os.environ:
        return
    if ctypes.util.find_library("EGL"):
        os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = "vtkEGLRenderWindow"


def find_pvd(source: Union[str, Path]) -> Path:
    """The ``.pvd`` file itself, or the only one in an output folder."""
    source = Path(source)
    if source.is_dir():
        found = sorted(source.glob("*.pvd"))
        if len(found) != 1:
            raise FileNotFoundError(f"expected one .pvd file in {source}, found {[f.name for f in found]}; "
                                    "give the .pvd file itself")
        return found[0]
    if source.suffix != ".pvd" or not source.exists():
        raise FileNotFoundError(f"{source} is not an existing .pvd file or output folder")
    return source


def read_frames(pvd: Path) -> List[Tuple[float, Dict[str, Path]]]:
    """[(t, {part name: .pvtu path})] in time order."""
    frames: Dict[float, Dict[str, Path]] = {}
    for ds in ET.parse(pvd).getroot().iter("DataSet"):
        t = float(ds.get("timestep"))
        frames.setdefault(t, {})[ds.get("name") or ds.get("part")] = pvd.parent / ds.get("file")
    if not frames:
        raise ValueError(f"{pvd} lists no data sets")
    return sorted(frames.items())


def pick_frame(frames, time: Union[str, float] = "last"):
    """'last', 'first', or the frame nearest to a time in seconds."""
    if time == "last":
        return frames[-1]
    if time == "first":
        return frames[0]
    t = float(time)
    return min(frames, key=lambda f: abs(f[0] - t))


def format_time(t: float) -> str:
    for scale, unit in ((1.0, "s"), (1e-3, "ms"), (1e-6, "µs")):
        if abs(t) >= scale or unit == "µs":
            return f"t = {t / scale:.4g} {unit}"
    return f"t = {t:g} s"


def field_values(grid, field: str):
    """(values at points or cells, colour-bar title) of ``name`` or ``name:component``."""
    import numpy as np
    name, _, comp = field.partition(":")
    if name in grid.point_data:
        arr = np.asarray(grid.point_data[name])
    elif name in grid.cell_data:
        arr = np.asarray(grid.cell_data[name])
    else:
        raise KeyError(f"field '{name}' is not in the data; available: "
                       f"{sorted(set(grid.point_data.keys()) | set(grid.cell_data.keys()))}")
    unit = UNITS.get(name, "?")
    label = name.replace("_", " ")
    if arr.ndim == 1:
        return arr, f"{label}\n[{unit}]"
    labels = COMPONENTS.get(arr.shape[1], tuple(str(i) for i in range(arr.shape[1])))
    if comp in ("", "magnitude"):
        if arr.shape[1] == 6:  # symmetric tensor: Frobenius norm counts off-diagonals twice
            mag = np.sqrt((arr[:, :3] ** 2).sum(axis=1) + 2 * (arr[:, 3:] ** 2).sum(axis=1))
        else:
            mag = np.linalg.norm(arr, axis=1)
        return mag, f"|{label}|\n[{unit}]"
    if comp not in labels:
        raise KeyError(f"component '{comp}' of {name}: use one of {labels} or 'magnitude'")
    return arr[:, labels.index(comp)], f"{label} {comp}\n[{unit}]"


def render(source: Union[str, Path], field: str = "strain_energy_density", time: Union[str, float] = "last",
           png: Optional[Union[str, Path]] = None, size: Tuple[int, int] = (640, 480), part: str = "bulk",
           cmap: str = "viridis", log_decades: Optional[float] = None) -> Path:
    """Render one frame of ``source`` (a ``.pvd`` or output folder) to a PNG; returns its path.

    The default PNG is ``<name>_<field>.png`` next to the ``.pvd``.  With
    ``log_decades = k`` the colours are logarithmic over the top k decades of the
    (positive) values.
    """
    _offscreen_environment()
    import pyvista as pv

    pvd = find_pvd(source)
    t, parts = pick_frame(read_frames(pvd), time)
    if part not in parts:
        raise KeyError(f"frame at t = {t:g} s of {pvd} has parts {sorted(parts)}, not '{part}'")
    grid = pv.read(parts[part])
    values, title = field_values(grid, field)
    png = Path(png) if png is not None else pvd.with_name(f"{pvd.stem}_{field.replace(':', '_')}.png")
    png.parent.mkdir(parents=True, exist_ok=True)

    plotter = pv.Plotter(off_screen=True, window_size=list(size))
    plotter.set_background("white")
    scale = {}
    if log_decades is not None:
        import numpy as np
        top = float(np.max(values))
        if not top > 0:
            raise ValueError(f"a logarithmic colour scale needs positive values; max of {field} is {top:g}")
        values = np.maximum(values, top * 10.0 ** -log_decades)
        scale = {"log_scale": True, "clim": (top * 10.0 ** -log_decades, top)}
    plotter.add_mesh(grid, scalars=values, cmap=cmap, show_edges=False, **scale,
                     scalar_bar_args={"title": title, "fmt": "%.3g", "color": "black", "vertical": True,
                                      "position_x": 0.84, "position_y": 0.08, "height": 0.75, "width": 0.06,
                                      "title_font_size": 14, "label_font_size": 12})
    plotter.add_text(format_time(t), position="upper_left", font_size=11, color="black")
    plotter.view_xy()
    plotter.reset_camera()
    plotter.camera.zoom(0.95)
    plotter.screenshot(str(png))
    plotter.close()
    return png


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hydrofrac.postprocess.snapshot",
                                     description="Save a PNG of one frame of a hydrofrac .pvd series.")
    parser.add_argument("source", help="output folder or .pvd file")
    parser.add_argument("--field", default="strain_energy_density",
                        help="point or cell field, optionally name:component (e.g. stress:xy, velocity:x)")
    parser.add_argument("--time", default="last", help="'last', 'first' or a time in seconds (nearest frame)")
    parser.add_argument("--png", default=None, help="output PNG (default <name>_<field>.png next to the .pvd)")
    parser.add_argument("--size", type=int, nargs=2, default=(640, 480), metavar=("W", "H"),
                        help="image size in pixels")
    parser.add_argument("--part", default="bulk", help="part of the frame (bulk, cracks, ...)")
    parser.add_argument("--log", type=float, default=None, metavar="DECADES",
                        help="logarithmic colours over the top DECADES decades of the values")
    args = parser.parse_args(argv)
    from .rundata import tool_main  # (rundata reads frames through this module)
    return tool_main("snapshot", lambda: render(args.source, field=args.field, time=args.time, png=args.png,
                                                size=tuple(args.size), part=args.part, log_decades=args.log))


if __name__ == "__main__":
    sys.exit(main())
