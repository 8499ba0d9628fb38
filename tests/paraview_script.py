"""pvpython script used by tests/test_paraview.py: open a hydrofrac ``.pvd`` in ParaView.

    xvfb-run -a pvpython tests/paraview_script.py OUT/borehole.pvd OUT/summary.json shot.png

Checks that the last frame has the hydrofrac fields and as many cells as
``summary.json`` says, saves a screenshot, and exits non-zero on a mismatch.
"""
import json
import sys

from paraview.simple import ColorBy, GetActiveViewOrCreate, OpenDataFile, ResetCamera, SaveScreenshot, Show

FIELDS = ("velocity", "stress", "strain_energy_density", "kinetic_energy_density")

pvd, summary_path, png = sys.argv[1:4]
reader = OpenDataFile(pvd)
if reader is None:
    sys.exit(f"ParaView could not open {pvd}")
times = reader.TimestepValues
times = list(times) if hasattr(times, "__len__") else [times]
reader.UpdatePipeline(time=times[-1])
cells = reader.GetDataInformation().GetNumberOfCells()
arrays = list(reader.PointData.keys())
expected = json.load(open(summary_path))["cells"]
print(json.dumps({"frames": len(times), "last_time": times[-1], "cells": cells, "arrays": arrays}))
missing = [f for f in FIELDS if f not in arrays]
if missing:
    sys.exit(f"fields {missing} missing from {pvd}; ParaView sees {arrays}")
if cells != expected:
    sys.exit(f"{cells} cells at the last time in ParaView, summary.json says {expected}")

display = Show(reader)
ColorBy(display, ("POINTS", "strain_energy_density"))
display.RescaleTransferFunctionToDataRange(True)
view = GetActiveViewOrCreate("RenderView")
view.ViewSize = [400, 300]
ResetCamera()
SaveScreenshot(png, view)
print("paraview check passed")
