"""What a user gets from a run: the output folder, ``summary.json``, a series that
ParaView opens, and the PNG snapshot.

The borehole scenario runs once at its ``--quick`` size (serially, in a
subprocess with the test interpreter); the tests inspect its output.
"""
import json
import random
import shutil
import subprocess
import sys

import pytest
from PIL import Image

SUMMARY_KEYS = ("cells", "dofs", "degree", "ranks", "steps", "dt", "simulated_time", "wall_time_s",
                "dof_stages_per_s", "energy")
ENERGY_KEYS = ("kinetic", "strain", "work_in", "radiated")


@pytest.fixture(scope="module")
def borehole_quick(tmp_path_factory, run_python, repo_root):
    out = tmp_path_factory.mktemp("borehole_quick")
    stdout = run_python([repo_root / "scenarios" / "borehole.py", "--quick", "--out", out], timeout=600)
    return out, stdout


def test_output_folder(borehole_quick):
    out, stdout = borehole_quick
    assert (out / "borehole.pvd").is_file()
    assert list((out / "vtk").glob("borehole_bulk_*.pvtu"))
    assert (out / "history.csv").is_file()
    assert list((out / "checkpoint").glob("state_r*.npz"))
    png = out / "borehole.png"
    assert png.is_file() and png.stat().st_size > 0
    assert f"picture: {png}" in stdout


def test_summary_keys(borehole_quick):
    out, _ = borehole_quick
    summary = json.loads((out / "summary.json").read_text())
    missing = [k for k in SUMMARY_KEYS if k not in summary]
    assert not missing, f"summary.json lacks {missing}"
    missing = [k for k in ENERGY_KEYS if k not in summary["energy"]]
    assert not missing, f"summary.json energy lacks {missing}"
    p = summary["degree"]
    assert summary["ranks"] == 1
    assert summary["dofs"] == summary["cells"] * 5 * (p + 1) * (p + 2) // 2
    assert summary["steps"] > 0 and summary["dt"] > 0
    # the last step lands on t_end: it is at most one step
    assert (summary["steps"] - 1) * summary["dt"] < summary["simulated_time"] <= summary["steps"] * summary["dt"]
    assert summary["wall_time_s"] > 0 and summary["dof_stages_per_s"] > 0
    assert summary["energy"]["work_in"] > 0  # the borehole pressure did work


@pytest.mark.paraview
@pytest.mark.skipif(shutil.which("pvpython") is None or shutil.which("xvfb-run") is None,
                    reason="needs pvpython and xvfb-run (Debian packages paraview and xvfb; `make setup` "
                           "installs them)")
def test_paraview_opens_series(borehole_quick, repo_root, tmp_path):
    out, _ = borehole_quick
    png = tmp_path / "paraview.png"
    cmd = [str(c) for c in (repo_root / "tests" / "paraview_script.py", out / "borehole.pvd",
                            out / "summary.json", png)]
    # `xvfb-run -a` starts looking for a free display at :99; concurrent runs on a shared
    # machine can race for it, so start elsewhere and try another display if the X server
    # was not usable: no connection, or the render window could not be created (a fresh-clone
    # CI run once aborted in vtkXOpenGLRenderWindow::CreateAWindow after the data checks had
    # passed). Any other failure is reported at once.
    for attempt in range(3):
        display = str(random.randint(100, 30000))
        res = subprocess.run(["xvfb-run", "-a", "-n", display, "pvpython", *cmd], capture_output=True, text=True,
                             timeout=300)
        x_failed = "bad X server connection" in res.stderr or "vtkXOpenGLRenderWindow::CreateAWindow" in res.stderr
        if res.returncode == 0 or not x_failed:
            break
    assert res.returncode == 0, f"pvpython failed ({res.returncode}):\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}"
    assert "paraview check passed" in res.stdout
    assert png.is_file() and png.stat().st_size > 0


def test_snapshot_png(borehole_quick, run_python, tmp_path):
    out, _ = borehole_quick
    png = tmp_path / "snapshot.png"
    stdout = run_python(["-m", "hydrofrac.postprocess.snapshot", out, "--field", "strain_energy_density",
                         "--time", "last", "--png", png, "--size", "320", "240"], timeout=300)
    assert str(png) in stdout
    with Image.open(png) as img:
        assert img.size == (320, 240)
        colours = img.convert("RGB").getcolors(maxcolors=320 * 240)
    assert len(colours) > 10


def test_snapshot_frames_and_errors(borehole_quick, tmp_path):
    # only the .pvd parsing runs in this process: VTK (pyvista) and DOLFINx do not share one process
    from hydrofrac.postprocess import snapshot
    out, _ = borehole_quick
    with pytest.raises(FileNotFoundError, match="pvd"):
        snapshot.find_pvd(tmp_path)
    frames = snapshot.read_frames(snapshot.find_pvd(out))
    assert len(frames) >= 2 and all("bulk" in parts for _, parts in frames)
    assert snapshot.pick_frame(frames, "last") == frames[-1]
    assert snapshot.pick_frame(frames, 0.0) == frames[0]
    res = subprocess.run([sys.executable, "-m", "hydrofrac.postprocess.snapshot", str(out), "--field", "no_such_field",
                          "--png", str(tmp_path / "x.png")], capture_output=True, text=True, timeout=300)
    assert res.returncode == 2
    assert "no_such_field" in res.stderr and "strain_energy_density" in res.stderr
