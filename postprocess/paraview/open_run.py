"""Open a hydrofrac run in ParaView: the bulk and the cracks of one ``.pvd`` series
together, with the colours of the paper's pictures.  Works for every scenario.

    xvfb-run -a pvpython postprocess/paraview/open_run.py results/intersection_regularized
    pvpython postprocess/paraview/open_run.py RUN --time 7.6e-4 --cracks mode --warp --png shot.png
    paraview --state=RUN/figures/<name>.pvsm          # the state this script saves, in the GUI
    HYDROFRAC_RUN=RUN paraview --script=postprocess/paraview/open_run.py

* bulk: coloured by the strain-energy density (Turbo, logarithmic over three
  decades below the largest value at the shown time); ``--warp`` lifts it by the
  kinetic-energy density like figs. 7, 8 and 11 of the paper;
* cracks: every interface facet as a thin grey line (potential paths that are
  still bonded stay grey), the debonded ones (D >= 0.5) thick and coloured by the
  pressure factor f_p from blue (0) to red (1), like figs. 9 and 12
  (``--cracks mode`` colours them by contact mode 0 bonded, 1 stick, 2 slip,
  3 separated; runs without hydraulics fall back to the damage D);
* a time label.

It saves a screenshot (default ``RUN/figures/<name>_paraview.png``) and a ParaView
state file (default ``RUN/figures/<name>.pvsm``, paths absolute) that the
ParaView GUI opens with every time step.  Exit status 0 and a last line
``open_run: ok`` when all went well.
"""
import argparse
import glob
import json
import os
import sys

from paraview import servermanager
from paraview.simple import (ColorBy, ExtractBlock, GetActiveViewOrCreate, GetAnimationScene, GetColorTransferFunction,
                             GetScalarBar, MergeBlocks, ProgrammableFilter, PVDReader, Render, ResampleWithDataset,
                             ResetCamera, SaveScreenshot, SaveState, Show, Text, Transform, WarpByScalar)

CRACK_DAMAGE = 0.5
#: quantile of the strain-energy density that tops the colour bar (crack tips are singular)
CLIM_QUANTILE = 0.995
HEIGHT_SHARE = 0.15

#: the crack lines whose two ends are both debonded (D >= CRACK_DAMAGE), or the others: a
#: ProgrammableFilter, saved with the state.  ParaView 5.11's Threshold reads out of bounds on these
#: line meshes now and then (a segfault in vtkExtractCells on some machines, about 1 run in 12 here)
SPLIT_SCRIPT = """
import numpy as np
from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy
from vtkmodules.util.vtkConstants import VTK_ID_TYPE, VTK_LINE
from vtkmodules.vtkCommonDataModel import vtkCellArray
inp, out = self.GetInputDataObject(0, 0), self.GetOutputDataObject(0)
out.SetPoints(inp.GetPoints())
out.GetPointData().ShallowCopy(inp.GetPointData())
n = inp.GetNumberOfCells()
lines = vtk_to_numpy(inp.GetCells().GetConnectivityArray()).reshape(n, 2) if n else np.zeros((0, 2), int)
damage = vtk_to_numpy(inp.GetPointData().GetArray("D")) if n else np.zeros(0)
keep = np.all(damage[lines] >= {threshold!r}, axis=1) if n else np.zeros(0, bool)
if {bonded!r}:
    keep = ~keep
conn = np.ascontiguousarray(lines[keep].ravel(), dtype=np.int64)
cells = vtkCellArray()
cells.SetData(numpy_to_vtk(np.arange(0, conn.size + 1, 2, dtype=np.int64), deep=1, array_type=VTK_ID_TYPE),
              numpy_to_vtk(conn, deep=1, array_type=VTK_ID_TYPE))
out.SetCells(VTK_LINE, cells)
cd = inp.GetCellData()
for i in range(cd.GetNumberOfArrays()):
    a = numpy_to_vtk(np.ascontiguousarray(vtk_to_numpy(cd.GetArray(i))[keep]), deep=1)
    a.SetName(cd.GetArrayName(i))
    out.GetCellData().AddArray(a)
"""



def style_bar(bar, title, fmt, position, length):
    """A vertical colour legend in black at ``position`` (view fractions)."""
    bar.Title = title
    bar.ComponentTitle = ""
    bar.RangeLabelFormat = fmt
    bar.TitleColor = bar.LabelColor = [0.0, 0.0, 0.0]
    bar.WindowLocation = "Any Location"
    bar.Orientation = "Vertical"
    bar.Position = position
    bar.ScalarBarLength = length


def parse(argv):
    p = argparse.ArgumentParser(description="Open a hydrofrac run folder in ParaView and save a screenshot/state.")
    p.add_argument("run", nargs="?", default=os.environ.get("HYDROFRAC_RUN"),
                   help="output folder of a run (or its .pvd); default $HYDROFRAC_RUN")
    p.add_argument("--time", default="last", help="'last', 'first' or a time in seconds (nearest frame)")
    p.add_argument("--cracks", choices=("f_p", "mode", "D"), default="f_p", help="crack colouring (default f_p)")
    p.add_argument("--warp", action="store_true", help="lift the bulk by the kinetic-energy density")
    p.add_argument("--png", default=None, help="screenshot (default RUN/figures/<name>_paraview.png)")
    p.add_argument("--state", default=None, help="state file (default RUN/figures/<name>.pvsm); 'none' for none")
    p.add_argument("--size", type=int, nargs=2, default=(1000, 800), metavar=("W", "H"))
    args = p.parse_args(argv)
    if not args.run:
        p.error("give the run folder (or set HYDROFRAC_RUN)")
    return args


def find_pvd(run):
    if os.path.isfile(run) and run.endswith(".pvd"):
        return os.path.abspath(run)
    found = sorted(glob.glob(os.path.join(run, "*.pvd")))
    if len(found) != 1:
        sys.exit(f"open_run: expected one .pvd file in {run}, found {found}")
    return os.path.abspath(found[0])


def pick_time(times, wanted):
    if wanted == "last":
        return times[-1]
    if wanted == "first":
        return times[0]
    return min(times, key=lambda t: abs(t - float(wanted)))


def time_text(t, t_end):
    scale, unit = (1e-6, "µs") if t_end < 2e-3 else (1e-3, "ms")
    return f"t = {t / scale:.4g} {unit}"


def array_range(source, name, t):
    source.UpdatePipeline(t)
    info = source.PointData.GetArray(name)
    return info.GetRange(0) if info is not None else (0.0, 1.0)


def array_quantile(source, name, t, q):
    """A quantile of a point array of a (multiblock) source at time t."""
    import numpy as np
    from vtk.numpy_interface import dataset_adapter as dsa
    source.UpdatePipeline(t)
    values = dsa.WrapDataObject(servermanager.Fetch(source)).PointData[name]
    arrays = values.Arrays if hasattr(values, "Arrays") else [values]
    data = np.concatenate([np.asarray(a).ravel() for a in arrays]) if arrays else np.zeros(1)
    return float(np.quantile(data, q))


def main(argv=None):
    args = parse(sys.argv[1:] if argv is None else argv)
    pvd = find_pvd(args.run)
    run_dir = os.path.dirname(pvd)
    name = os.path.splitext(os.path.basename(pvd))[0]
    out_dir = os.path.join(run_dir, "figures")
    png = args.png or os.path.join(out_dir, f"{name}_paraview.png")
    state = None if args.state == "none" else (args.state or os.path.join(out_dir, f"{name}.pvsm"))
    for path in (png, state):
        if path:
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)

    reader = PVDReader(registrationName=name, FileName=pvd)
    times = list(reader.TimestepValues) if hasattr(reader.TimestepValues, "__len__") else [reader.TimestepValues]
    t = pick_time(times, args.time)
    scene = GetAnimationScene()
    scene.UpdateAnimationUsingDataTimeSteps()
    scene.AnimationTime = t
    view = GetActiveViewOrCreate("RenderView")
    view.ViewSize = list(args.size)
    view.ViewTime = t
    view.OrientationAxesVisibility = 0
    view.Background = [1.0, 1.0, 1.0]
    try:  # ParaView >= 5.10 uses a palette unless told not to
        view.UseColorPaletteForBackground = 0
    except AttributeError:
        pass

    # -- bulk: strain-energy density, optionally lifted by the kinetic-energy density
    bulk = ExtractBlock(registrationName="bulk", Input=reader, Selectors=["/Root/bulk"])
    bulk.UpdatePipeline(t)
    b = bulk.GetDataInformation().GetBounds()
    size = max(b[1] - b[0], b[3] - b[2])
    height = 0.0
    shown = [bulk]
    if args.warp:
        k_max = max(array_range(bulk, "kinetic_energy_density", t)[1], 1e-300)
        height = HEIGHT_SHARE * size / k_max
        warped = WarpByScalar(registrationName="kinetic height", Input=bulk,
                              Scalars=["POINTS", "kinetic_energy_density"])
        warped.ScaleFactor = height
        warped.Normal = [0.0, 0.0, 1.0]
        warped.UseNormal = 1
        shown.append(warped)  # the flat bulk stays underneath: it fills the slits between lifted DG cells
    w_lut = GetColorTransferFunction("strain_energy_density")
    for src in shown:
        bulk_display = Show(src, view)
        ColorBy(bulk_display, ("POINTS", "strain_energy_density"))
    try:
        w_lut.ApplyPreset("Turbo", True)
    except Exception:  # older ParaView: keep its default map
        pass
    w_max = max(array_quantile(bulk, "strain_energy_density", t, CLIM_QUANTILE), 1e-300)
    w_lut.RescaleTransferFunction(w_max * 1e-3, w_max)
    w_lut.UseLogScale = 1
    w_lut.AutomaticRescaleRangeMode = "Never"
    style_bar(GetScalarBar(w_lut, view), "strain energy density [J/m³]", "%-#6.3g", [0.82, 0.1], 0.4)
    bulk_display.SetScalarBarVisibility(view, True)

    # -- cracks: all facets thin grey, debonded ones thick and coloured
    crack_field = None
    cracks = ExtractBlock(registrationName="cracks", Input=reader, Selectors=["/Root/cracks"])
    cracks.UpdatePipeline(t)
    if cracks.GetDataInformation().GetNumberOfCells() > 0:  # the scenario has cracks
        names = cracks.PointData.keys()
        crack_field = args.cracks if args.cracks in names else ("D" if "D" in names else None)
        source = cracks
        if args.warp:  # on the lifted surface: the kinetic-energy density of the bulk at the crack points
            probe = ResampleWithDataset(registrationName="bulk at cracks", SourceDataArrays=bulk,
                                        DestinationMesh=cracks)
            try:
                probe.PassPointArrays = 1
            except AttributeError:
                pass
            # a crack point the probe misses (on the wellbore boundary by round-off, say) would be
            # blanked with a ghost array and its lines hidden: take 0 there instead (not lifted)
            try:
                probe.MarkBlankPointsAndCells = 0
            except AttributeError:
                pass
            source = WarpByScalar(registrationName="cracks lifted", Input=probe,
                                  Scalars=["POINTS", "kinetic_energy_density"])
            source.ScaleFactor = height
            source.Normal = [0.0, 0.0, 1.0]
            source.UseNormal = 1
        # a little above the bulk so that the lines are not hidden in it
        lift = Transform(registrationName="cracks above", Input=source)
        lift.Transform = "Transform"
        lift.Transform.Translate = [0.0, 0.0, (0.01 if args.warp else 0.002) * size]

        lines = MergeBlocks(registrationName="crack lines", Input=lift)

        def damaged(bonded):
            split = ProgrammableFilter(registrationName="bonded" if bonded else "debonded", Input=lines)
            split.OutputDataSetType = "vtkUnstructuredGrid"
            split.Script = SPLIT_SCRIPT.format(threshold=CRACK_DAMAGE, bonded=bonded)
            return split

        bonded_display = Show(damaged(True), view)
        bonded_display.ColorArrayName = ["POINTS", ""]
        bonded_display.AmbientColor = bonded_display.DiffuseColor = [0.6, 0.6, 0.6]
        bonded_display.LineWidth = 1.5
        crack_display = Show(damaged(False), view)
        crack_display.LineWidth = 5.0
        if crack_field:
            ColorBy(crack_display, ("POINTS", crack_field))
            c_lut = GetColorTransferFunction(crack_field)
            c_lut.ApplyPreset("Cool to Warm", True)
            c_lut.AutomaticRescaleRangeMode = "Never"
            c_lut.RescaleTransferFunction(0.0, 3.0 if crack_field == "mode" else 1.0)
            style_bar(GetScalarBar(c_lut, view), {"f_p": "pressure factor f_p", "D": "damage D",
                                                  "mode": "mode (0 bonded, 1 stick, 2 slip, 3 separated)"}[crack_field],
                      "%-#.2g", [0.82, 0.55], 0.35)
            crack_display.SetScalarBarVisibility(view, True)

    label = Text(registrationName="time label")
    label.Text = f"{name}   {time_text(t, times[-1])}"
    label_display = Show(label, view)
    label_display.Color = [0.0, 0.0, 0.0]
    label_display.FontSize = 14
    label_display.WindowLocation = "Upper Left Corner"

    view.InteractionMode = "3D" if args.warp else "2D"
    ResetCamera(view)
    if args.warp:
        cam = view.GetActiveCamera()
        cam.Elevation(-50.0)
        ResetCamera(view)
    Render(view)
    SaveScreenshot(png, view, ImageResolution=list(args.size))
    if state:
        SaveState(state)
    print(json.dumps({"pvd": pvd, "frames": len(times), "time": t, "bulk_cells": bulk.GetDataInformation()
                      .GetNumberOfCells(), "crack_colour": crack_field, "png": png, "state": state}))
    print("open_run: ok")


if __name__ == "__main__":
    main()
