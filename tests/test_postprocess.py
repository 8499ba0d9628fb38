"""The pictures of a run: paper-style figures, charts, animation, ParaView script.

The regularised intersection scenario runs once at its ``--quick`` size, cut to
420 µs and 6 frames (the cracks grow twice, with two remeshes, so the frames live on
three meshes; nothing intersects yet: about 25 s); every
entry point of ``hydrofrac.postprocess`` then runs on it in a subprocess (VTK
and DOLFINx do not share one process) and must write a picture of the size
asked for that is not blank (more than a handful of colours).  The choice of
frames and the reading of the history are checked on made-up runs.
"""
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import assert_dynamics_hold_penetration
from PIL import Image

from hydrofrac.postprocess import rundata

NAME = "intersection_regularized"


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory, run_python, repo_root):
    out = tmp_path_factory.mktemp("postprocess_run")
    run_python([repo_root / "scenarios" / f"{NAME}.py", "--quick", "--t-end", "4.2e-4", "--frames", "6", "--ramp", "1e-6",
                "--out", out], timeout=600)
    return out


def colours(png, size=None):
    """Number of distinct colours of a PNG (after checking its size)."""
    with Image.open(png) as img:
        if size is not None:
            assert img.size == tuple(size), f"{png} is {img.size}, expected {size}"
        rgb = img.convert("RGB")
        return len(rgb.getcolors(maxcolors=rgb.width * rgb.height))


def printed_paths(stdout):
    return [Path(line) for line in stdout.splitlines() if line.strip().endswith((".png", ".gif"))]


def test_figures_energy_and_mesh(quick_run, run_python, tmp_path):
    stdout = run_python(["-m", "hydrofrac.postprocess.figures", quick_run, "--frames", "2", "--size", "320", "240",
                         "--out", tmp_path], timeout=300)
    pngs = printed_paths(stdout)
    singles = [p for p in pngs if not p.name.endswith("_sequence.png")]
    assert sorted(p.name.split("_")[0] for p in singles) == ["energy", "energy", "mesh", "mesh"]
    for png in singles:
        assert png.is_file() and png.stat().st_size > 0
        assert colours(png, (320, 240)) > 10, f"{png} looks blank"
    for kind in ("energy", "mesh"):
        sheet = tmp_path / f"{kind}_sequence.png"
        assert sheet in pngs and colours(sheet, (640, 240)) > 10


def test_figures_at_given_times(quick_run, run_python, tmp_path):
    stdout = run_python(["-m", "hydrofrac.postprocess.figures", quick_run, "--kind", "mesh", "--times", "140us",
                         "2.8e-4", "--size", "300", "200", "--crop", "full", "--no-sheet", "--out", tmp_path],
                        timeout=300)
    pngs = printed_paths(stdout)
    assert len(pngs) == 2 and all(p.name.startswith("mesh_") for p in pngs)
    times = sorted(float(p.stem.split("_")[1].replace("p", ".").rstrip("us")) for p in pngs)
    assert times[0] == pytest.approx(140, abs=15) and times[1] == pytest.approx(280, abs=15)
    assert all(colours(p, (300, 200)) > 10 for p in pngs)


def test_figures_errors(tmp_path):
    res = subprocess.run([sys.executable, "-m", "hydrofrac.postprocess.figures", str(tmp_path)],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and ".pvd" in res.stderr


def test_charts(quick_run, run_python, tmp_path):
    stdout = run_python(["-m", "hydrofrac.postprocess.charts", quick_run, "--out", tmp_path], timeout=300)
    names = {p.name for p in printed_paths(stdout)}
    assert names == {"pressure.png", "energy_budget.png", "crack_length.png", "contact_modes.png", "opening.png",
                     "wall_time.png", "charts.png"}
    for name in names:
        png = tmp_path / name
        assert png.stat().st_size > 0 and colours(png) > 10, f"{name} looks blank"


def test_wall_time_parts_add_up_to_the_wall_time():
    """The wall-time chart's parts: the time split without the set-up, a remesh's parts in place
    of "remesh" (per remesh times the remeshes), and the untimed rest, adding up to the wall time."""
    summary = {"wall_time_s": 10.0, "time_split_s": {"setup": 2.0, "bulk operator": 4.0, "remesh": 3.0, "output": 1.0},
               "remeshing": {"remeshes": 10, "split_per_remesh_s": {"meshing": 0.2, "transfer": 0.05, "rest": 0.05}}}
    parts = dict(rundata.wall_time_parts(summary))
    assert parts == pytest.approx({"bulk operator": 4.0, "remesh: meshing": 2.0, "remesh: transfer": 0.5,
                                   "remesh: rest": 0.5, "output": 1.0, "not timed": 2.0})
    assert [k for k, _ in rundata.wall_time_parts(summary)][:2] == ["bulk operator", "remesh: meshing"]
    del summary["remeshing"]  # (a run without remeshes, or an older summary): "remesh" as it is
    assert dict(rundata.wall_time_parts(summary))["remesh"] == 3.0


def test_crack_statistics(quick_run, run_python):
    """Lengths and mode fractions integrated from the crack frames add up."""
    code = ("import json, sys; from hydrofrac.postprocess import rundata as r; run = r.load_run(sys.argv[1]); "
            "s = r.crack_statistics(run); "
            "print(json.dumps({'stats': {k: v.tolist() for k, v in s.items()}}))")
    out = json.loads(run_python(["-c", code, quick_run], timeout=120).splitlines()[-1])
    s = {k: np.array(v) for k, v in out["stats"].items()}
    assert len(s["t"]) == len(rundata.load_run(quick_run).frames)  # every frame has cracks
    total = sum(s[f"fraction_{m}"] for m in rundata.MODES)
    assert np.allclose(total, 1.0, atol=1e-12)
    assert np.all(s["loaded_length"] <= s["network_length"] + 1e-12)
    assert np.all(s["network_length"] <= s["interface_length"] + 1e-12)
    assert s["damaged_length"][-1] > s["damaged_length"][0]  # the grown segments debond
    # perforations and natural fracture; then two extensions of 2h = 0.12 m at each of the 4 tips
    assert s["interface_length"][0] == pytest.approx(0.3 * 4 + 1.6, rel=1e-6)
    assert s["interface_length"][-1] == pytest.approx(0.3 * 4 + 1.6 + 4 * 2 * 0.12, rel=1e-6)
    # the natural fracture starts pressed to the permitted penetration (ratio 1), never beyond;
    # the permitted value comes from the model parameters, not from the data
    assert s["penetration_ratio_max"][0] == pytest.approx(1.0, rel=1e-9)
    assert np.all(s["penetration_ratio_max"] <= 1 + 1e-9)
    # ... by the dynamics: the opening clip never acted in the run
    assert_dynamics_hold_penetration(json.loads((quick_run / "summary.json").read_text()))


def test_animation(quick_run, run_python, tmp_path):
    gif = tmp_path / "run.gif"
    stdout = run_python(["-m", "hydrofrac.postprocess.animate", quick_run, "--max-frames", "5", "--size", "240",
                         "180", "--out", gif], timeout=300)
    assert str(gif) in stdout
    assert 0 < gif.stat().st_size < 3e6
    with Image.open(gif) as img:
        assert img.size == (240, 180) and img.n_frames == 5
    # the frames drawn by 2 processes (the default where there are 2 cores) and by 1: the same GIF
    counts = {}
    for n in (1, 2):
        other = tmp_path / f"run_{n}.gif"
        stdout = run_python(["-m", "hydrofrac.postprocess.animate", quick_run, "--max-frames", "5", "--size", "240",
                             "180", "--out", other, "--workers", str(n)], timeout=300)
        assert "failed" not in stdout
        counts[n] = other.read_bytes()
    assert counts[1] == counts[2]
    with pytest.raises(ValueError, match="--workers must be an integer >= 1"):
        from hydrofrac.postprocess import animate
        animate.animate(quick_run, out=tmp_path / "x.gif", workers=0)


def test_everything_in_one_go(quick_run, run_python, tmp_path):
    stdout = run_python(["-m", "hydrofrac.postprocess", quick_run, "--out", tmp_path, "--frames", "2", "--size", "320",
                         "240", "--no-animation", "--no-paraview"], timeout=300)
    assert f"charts:    {tmp_path / 'charts.png'}" in stdout
    assert (tmp_path / "energy_sequence.png").is_file() and (tmp_path / "mesh_sequence.png").is_file()


def pvpython(args, cwd):
    """Run a pvpython script headless; its stdout."""
    # xvfb-run -a can lose a race for a display number with a parallel job: one retry
    for attempt in range(2):
        res = subprocess.run(["xvfb-run", "-a", "pvpython", *map(str, args)], capture_output=True, text=True,
                             timeout=300, cwd=cwd)
        if res.returncode == 0:
            return res.stdout
    pytest.fail(f"pvpython {args} exited with {res.returncode}\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}")


@pytest.mark.paraview
@pytest.mark.skipif(shutil.which("pvpython") is None or shutil.which("xvfb-run") is None,
                    reason="needs pvpython and xvfb-run (Debian packages paraview and xvfb; `make setup` "
                           "installs them)")
def test_paraview_script_and_state(quick_run, repo_root, tmp_path):
    png, state = tmp_path / "shot.png", tmp_path / "run.pvsm"
    stdout = pvpython([repo_root / "postprocess" / "paraview" / "open_run.py", quick_run, "--warp", "--size", "400",
                       "300", "--png", png, "--state", state], repo_root)
    assert stdout.splitlines()[-1] == "open_run: ok"
    info = json.loads(stdout.splitlines()[-2])
    assert info["frames"] == len(rundata.load_run(quick_run).frames) and info["crack_colour"] == "f_p"
    assert info["bulk_cells"] == json.loads((quick_run / "summary.json").read_text())["cells"]
    assert colours(png, (400, 300)) > 10
    # the saved state opens again in ParaView
    loader = tmp_path / "load_state.py"
    loader.write_text("import sys\nfrom paraview.simple import GetActiveViewOrCreate, LoadState, SaveScreenshot\n"
                      "LoadState(sys.argv[1])\n"
                      "SaveScreenshot(sys.argv[2], GetActiveViewOrCreate('RenderView'), ImageResolution=[320, 240])\n"
                      "print('state loaded')\n")
    shot = tmp_path / "from_state.png"
    assert "state loaded" in pvpython([loader, state, shot], repo_root)
    assert colours(shot, (320, 240)) > 10


@pytest.mark.paraview
@pytest.mark.skipif(shutil.which("pvpython") is None or shutil.which("xvfb-run") is None,
                    reason="needs pvpython and xvfb-run (Debian packages paraview and xvfb; `make setup` "
                           "installs them)")
def test_paraview_script_with_crack_points_outside_the_bulk(quick_run, repo_root, tmp_path):
    """Crack points the bulk probe misses (a point on the wellbore boundary lost to round-off) stay
    in the lifted view: no line is blanked, and the bonded and debonded lines together are all the
    lines of the frame shown, each once (ParaView 5.11's Threshold segfaulted on such input)."""
    import meshio

    from hydrofrac.io import VTK_LINE, write_vtu
    run = tmp_path / "run"
    shutil.copytree(quick_run, run)
    n_cells = {}
    for piece in sorted((run / "vtk").glob("*_cracks_*_r0.vtu")):
        m = meshio.read(piece)
        points = m.points.copy()
        points[:, 0] += 0.013  # the perforation points next to the wellbore now lie in it
        write_vtu(piece, points, m.cells_dict["line"], VTK_LINE, dict(m.point_data),
                  {k: v[0] for k, v in m.cell_data.items()})
        n_cells[piece] = len(m.cells_dict["line"])
    state = tmp_path / "run.pvsm"
    stdout = pvpython([repo_root / "postprocess" / "paraview" / "open_run.py", run, "--warp", "--size", "320", "240",
                       "--png", tmp_path / "shot.png", "--state", state], repo_root)
    assert stdout.splitlines()[-1] == "open_run: ok"
    # the saved pipeline: the two thresholds together hold every crack cell of the shown frame, unblanked
    check = tmp_path / "check.py"
    check.write_text("import sys, json\nfrom paraview.simple import FindSource, LoadState\nfrom paraview import servermanager\n"
                     "LoadState(sys.argv[1])\nout = {}\nt = float(sys.argv[2])\n"
                     "for name in ('bonded', 'debonded'):\n"
                     "    FindSource(name).UpdatePipeline(t)\n"
                     "    d = servermanager.Fetch(FindSource(name))\n"
                     "    out[name] = [d.GetNumberOfCells(), int(d.GetPointData().GetArray('vtkGhostType') is not None)]\n"
                     "print(json.dumps(out))\n")
    shown_time = json.loads(stdout.splitlines()[-2])["time"]
    out = json.loads(pvpython([check, state, repr(shown_time)], repo_root).splitlines()[-1])
    assert out["bonded"][1] == out["debonded"][1] == 0
    assert out["bonded"][0] + out["debonded"][0] == n_cells[max(n_cells)]


# ---------------------------------------------------------------------------- frame choice, history (no VTK)
def made_up_run(t_frames, history=None, summary=None):
    frames = [(t, {"bulk": Path(f"b{i}.pvtu")}) for i, t in enumerate(t_frames)]
    return rundata.Run(dir=Path("."), pvd=Path("x.pvd"), frames=frames, history=history or {},
                       summary=summary or {})


def test_parse_time():
    assert rundata.parse_time("560us") == pytest.approx(5.6e-4)
    assert rundata.parse_time("560µs") == pytest.approx(5.6e-4)
    assert rundata.parse_time("0.9ms") == pytest.approx(9e-4)
    assert rundata.parse_time("1e-3") == pytest.approx(1e-3)
    with pytest.raises(ValueError, match="560us"):
        rundata.parse_time("soon")


def test_key_times_intersection():
    t = np.linspace(0, 1e-3, 201)
    loaded = np.clip((t - 7.4e-4) / 4e-5, 0, 1) * 1.6
    run = made_up_run(np.linspace(0, 1e-3, 41), history={"t": t, "nf_loaded_length": loaded},
                      summary={"accuracy": {"intersection_time": 7.4e-4, "nf_length": 1.6}})
    times = rundata.key_times(run)
    assert times[0] < 7.4e-4 < times[1] < 7.5e-4 and times[-1] == 1e-3
    assert any(7.5e-4 <= x <= 7.65e-4 for x in times)  # half of the natural fracture loaded
    picked = [f[0] for f in rundata.select_frames(run)]
    assert picked == sorted(set(picked)) and picked[-1] == 1e-3


def test_key_times_refracture():
    t = np.linspace(0, 1.8e-3, 361)
    p = np.interp(t, [0, 1e-6, 3e-4, 4e-4, 1.5e-3, 1.51e-3, 1.8e-3], [2.4e6, 19.4e6, 19.4e6, 0, 0, 19.4e6, 19.4e6])
    run = made_up_run(np.linspace(0, 1.8e-3, 51), history={"t": t, "p_h": p})
    t_hold, t_off, t_on = rundata.load_breakpoints(run)
    assert t_hold == pytest.approx(3e-4, abs=6e-6) and t_off == pytest.approx(4e-4, abs=6e-6)
    assert t_on == pytest.approx(1.5e-3, abs=6e-6)
    times = rundata.key_times(run)
    assert len(times) == 6 and t_hold < times[0] < t_off and times[3] < t_on < times[4]
    # with the separated share of the network: frames while the cracks close and re-open
    sep = np.where(t < 8e-4, 1.0, np.where(t < 1.5e-3, np.clip(1 - (t - 8e-4) / 1e-4, 0.2, 1), 1.0))
    sep[(t > 1.5e-3) & (t < 1.52e-3)] = 0.7
    run.history["separated_fraction"] = sep
    times = rundata.key_times(run)
    assert len(times) == 6 and t_hold < times[0] < t_off
    assert times[1] == pytest.approx(8.1e-4, abs=6e-6) and times[2] == pytest.approx(8.6e-4, abs=6e-6)
    assert times[3] < t_on < times[4] < 1.52e-3 and times[5] == 1.8e-3


def test_select_frames_by_count_and_times():
    run = made_up_run(np.linspace(0, 1e-3, 11))
    assert [f[0] for f in rundata.select_frames(run, count=2)] == pytest.approx([5e-4, 1e-3])
    assert [f[0] for f in rundata.select_frames(run, count=1)] == pytest.approx([1e-3])
    assert [f[0] for f in rundata.select_frames(run, times=["0.31ms", "290us"])] == pytest.approx([3e-4])
    assert len(rundata.subsample(run.frames, 4)) == 4 and rundata.subsample(run.frames, 4)[-1] == run.frames[-1]


def test_history_after_restart(tmp_path):
    """A restarted run appends rows from its checkpoint on: the later rows win."""
    csv = tmp_path / "history.csv"
    csv.write_text("step,t,kinetic\n0,0,0\n5,1,1\n10,2,2\n5,1,1.5\n10,2,2.5\n15,3,3\n")
    h = rundata.read_history(csv)
    assert h["step"].tolist() == [0, 5, 10, 15]
    assert h["kinetic"].tolist() == [0, 1.5, 2.5, 3]


def test_local_time_stepping_gain():
    """The LTS study's work model: cells at 1, 1, 2, 4 and 3 times the global step; ideal
    per-cell steps do (1 + 1 + 1/2 + 1/4 + 1/3)/5 of the work, 2^k levels (3 -> 2)
    (1 + 1 + 1/2 + 1/4 + 1/2)/5, or with one level all of it."""
    from hydrofrac.postprocess.cost_model import lts_gain
    dt = np.array([1.0, 1.0, 2.0, 4.0, 3.0]) * 1e-6
    g = lts_gain(dt, 1e-6, levels=6)
    assert g["work_ideal"] == pytest.approx((1 + 1 + 0.5 + 0.25 + 1 / 3) / 5, rel=1e-12)
    assert g["work_levels"] == pytest.approx((1 + 1 + 0.5 + 0.25 + 0.5) / 5, rel=1e-12)
    assert g["finest_level_share"] == pytest.approx(0.4) and g["levels_used"] == 3
    assert lts_gain(dt, 1e-6, levels=1)["work_levels"] == pytest.approx(1.0)


def test_sequence_sheet_has_no_empty_panel_and_pictures_a_length_scale(tmp_path):
    """Five pictures on three columns: the short last row is centred, so no panel slot stays
    empty at its left; the length scale is a round number of at most a quarter of the view."""
    from hydrofrac.postprocess.figures import nice_length, sequence_sheet
    pngs = []
    for i in range(5):
        p = tmp_path / f"p{i}.png"
        Image.new("RGB", (60, 40), (200, 30 * i, 0)).save(p)
        pngs.append(p)
    sheet = Image.open(sequence_sheet(pngs, tmp_path / "sheet.png", columns=3, width=10_000)).convert("RGB")
    assert sheet.size == (180, 80)
    # last row: two pictures centred (30 px of white on each side), none left empty in the middle
    assert sheet.getpixel((10, 60)) == (255, 255, 255) and sheet.getpixel((170, 60)) == (255, 255, 255)
    assert sheet.getpixel((45, 60)) != (255, 255, 255) and sheet.getpixel((135, 60)) != (255, 255, 255)
    assert [nice_length(s) for s in (6.0, 1.0, 0.33, 3.2)] == [1.0, 0.2, 0.05, 0.5]


def test_time_scheme_study_quick(tmp_path):
    """``study_time_schemes --quick`` runs every scheme, ADER included, and writes its CSV and
    chart.  At each scheme's documented CFL constant the time error is far below the spatial
    one (docs/benchmarks.md, "Time schemes"), so on each mesh every scheme's error is rk4's
    within 10 % (ADER's fixed-mesh defect included); each halving of h divides every
    scheme's error by more than 2^(p + 0.8)."""
    from hydrofrac.postprocess import study_time_schemes as st
    rows = st.main(["--quick", "--out", str(tmp_path)])
    assert (tmp_path / "time_schemes.csv").exists() and (tmp_path / "time_schemes.png").exists()
    main = [r for r in rows if not r["dt_series"]]
    assert {r["scheme"] for r in main} == set(st.SCHEMES)
    for p, Ns in st.QUICK.items():
        for N in Ns:
            ref = next(r["rel_error"] for r in main if r["scheme"] == "rk4" and r["degree"] == p and r["N"] == N)
            for r in main:
                if r["degree"] == p and r["N"] == N:
                    assert abs(r["rel_error"] - ref) <= 0.1 * ref, (r["method"], N, r["rel_error"], ref)
        for scheme in st.SCHEMES:
            e = [r["rel_error"] for r in sorted(main, key=lambda r: r["N"]) if r["scheme"] == scheme and r["degree"] == p]
            assert e[0] / e[1] > 2 ** (p + 0.8), (scheme, p, e)


def test_mesh_grading_work_for_the_same_error_follows_a_power_law():
    """The mesh-grading study's equal-error work: on errors that fall as 1/work it recovers the
    work of any error exactly, between the static meshes and beyond either end, and a work
    ratio is the static work over the adaptive one; errors that do not fall give no ratio.  An
    ensemble's ratio is that of its mean |error| at its mean work, and neighbours are not
    static meshes of their own."""
    from hydrofrac.postprocess.study_mesh_grading import ensemble_means, equal_error_work, work_ratios
    static = [{"dof_steps": w, "e": s * 1e6 / w} for w, s in ((1e6, 1), (1e7, -1), (1e8, 1))]
    for err, work in ((0.05, 2e7), (-0.3, 10 ** 6.5 / 0.3 * 10 ** -0.5), (1e-3, 1e9), (10.0, 1e5)):
        assert equal_error_work(static, "e", err) == pytest.approx(work, rel=1e-12)
    assert np.isnan(equal_error_work([{"dof_steps": 1e6, "e": 1.0}, {"dof_steps": 1e7, "e": 2.0}], "e", 1.5))
    keys = ("intersection_time_error", "loaded_length_error", "open_area_error")
    rows = [{"case": "ref", "h_fine": None, "h_far": 0.5, "h_crack": 0.02, "dof_steps": 1e9,
             **dict.fromkeys(keys, 0.0)}]
    rows += [{"case": f"static {w:g}", "h_fine": None, "h_far": 0.5, "h_crack": 0.03, "dof_steps": w,
              **dict.fromkeys(keys, 1e6 / w)} for w in (1e6, 1e7, 1e8)]
    rows.append({"case": "adaptive", "h_fine": 0.03, "h_far": 1.0, "h_crack": 0.06, "dof_steps": 1e7,
                 **dict.fromkeys(keys, 0.01)})
    work_ratios(rows)
    assert rows[-1]["work_ratio_open_area"] == pytest.approx(10.0, rel=1e-12)
    assert rows[1]["work_ratio_intersection_time"] == ""
    # an ensemble: the adaptive mesh and two neighbours at the same work err by 0.01, 0.005 and
    # -0.03 (mean |error| 0.015), so the means' ratio is that of 0.015; a neighbour of a static
    # mesh (an error of 1 at 1e7) is not a static mesh of its own
    rows += [{**rows[4], "case": f"n{e}", "group": "adaptive", **dict.fromkeys(keys, e)} for e in (0.005, -0.03)]
    rows.append({**rows[2], "case": "stray", "group": rows[2]["case"], **dict.fromkeys(keys, 1.0)})
    work_ratios(rows)
    assert rows[4]["work_ratio_open_area"] == pytest.approx(10.0, rel=1e-12)
    means = ensemble_means(rows)
    assert [m["case"] for m in means] == ["ref", "static 1e+06", "mean of 2: static 1e+07", "static 1e+08",
                                          "mean of 3: adaptive"]
    assert means[2]["dof_steps"] == 1e7 and means[2]["loaded_length_error"] == pytest.approx(0.55)
    # between the static means (1e7, 0.55) and (1e8, 0.01), log-linear
    assert means[-1]["work_ratio_loaded_length"] == pytest.approx(10 ** (np.log(0.015 / 0.55) / np.log(0.01 / 0.55)),
                                                                  rel=1e-12)


def test_peer_study_ratios_by_time_and_by_work():
    """``study_peer_devito``'s ratio table: each code's fewest flops at a target error are
    interpolated in log-log as its wall times are (exact for a power law), the flop ratio is
    theirs, and the rate DG would need for DG/Devito = 30 is its flops over 30 times Devito's
    time, as a fraction of the peak.  A Devito run already below the target counts with its
    own (upper-bound) time and flops."""
    from hydrofrac.postprocess.study_peer_devito import GOAL, ratios
    dg = [{"method": "DG P3 ader", "family": "DG", "dofs": d, "rel_error": e, "wall_s": w, "flops": f}
          for d, e, w, f in ((1600, 1e-1, 1e-3, 1e6), (25600, 1e-3, 1e-1, 1e8))]
    devito = [{"method": "Devito SO4", "family": "Devito", "dofs": 3125, "rel_error": 5e-3, "wall_s": 2e-5,
               "flops": 2e5}]
    peak = 5e10
    row = next(r for r in ratios(dg + devito, peak) if r["error"] == 0.01)
    assert row["dg_wall_s"] == pytest.approx(1e-2, rel=1e-12) and row["dg_flops"] == pytest.approx(1e7, rel=1e-12)
    assert row["ratio"] == pytest.approx(500, rel=1e-12) and row["flop_ratio"] == pytest.approx(50, rel=1e-12)
    assert row["devito_gflops"] == pytest.approx(10.0, rel=1e-12)
    assert row["dg_gflops_for_goal"] == pytest.approx(1e7 / (GOAL * 2e-5) / 1e9, rel=1e-12)
    assert row["dg_fraction_of_peak_for_goal"] == pytest.approx(1e7 / (GOAL * 2e-5) / peak, rel=1e-12)
    assert row["ratio_at_peak"] == pytest.approx(1e7 / peak / 2e-5, rel=1e-12)
