"""Runs that never hang, restarts that never lie, no silent defaults (docs/verification.md,
"Reliability").  The multi-rank tests start ``mpirun -n 2`` with a wall-clock limit: a hang
fails the test instead of the suite."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import MPI_ENV, ROOT

SC = ROOT / "scenarios"
#: summary entries that are measurements of the machine, not of the run
TIMING = {"wall_time_s", "setup_time_s", "compiling_in_wall_s", "dof_stages_per_s", "dof_stages_per_s_per_rank",
          "time_split_s", "cost_us", "output"}


def _mpi(n):
    return ["mpirun", "--oversubscribe", "-n", str(n), sys.executable]


def _run(cmd, timeout=300, check=True):
    res = subprocess.run([str(c) for c in cmd], cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                         env={**os.environ, **MPI_ENV})
    if check and res.returncode != 0:
        pytest.fail(f"{' '.join(map(str, cmd))} exited {res.returncode}\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}")
    return res


def _comparable(summary):
    s = {k: v for k, v in summary.items() if k not in TIMING}
    if "remeshing" in s:
        s["remeshing"] = {"remeshes": s["remeshing"]["remeshes"]}
    return s


def _last_frame(out: Path, name: str):
    """Bytes of every piece of the last frame (the pvd's last time step)."""
    import re
    pvd = (out / f"{name}.pvd").read_text()
    steps = re.findall(r'timestep="([^"]+)"[^>]*file="([^"]+)"', pvd)
    last_t = steps[-1][0]
    files = sorted(f for t, f in steps if t == last_t)
    pieces = {}
    for f in files:
        pv = (out / f).read_text()
        for piece in re.findall(r'Source="([^"]+)"', pv):
            pieces[piece] = (out / Path(f).parent / piece).read_bytes()
    return last_t, pieces


def _kill_after_checkpoint(cmd, ckpt: Path, ranks=2, timeout=300):
    """Start ``cmd``, wait for its first complete checkpoint, kill -9 the whole process group."""
    proc = subprocess.Popen([str(c) for c in cmd], cwd=ROOT, env={**os.environ, **MPI_ENV},
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    t0 = time.time()
    try:
        while time.time() - t0 < timeout:
            current = [f for f in ckpt.glob("state_r*.npz") if ".prev" not in f.name] if ckpt.exists() else []
            if len(current) >= ranks and proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                return
            if proc.poll() is not None:
                pytest.fail("the run ended before it wrote a checkpoint; make the checkpoint interval shorter")
            time.sleep(0.05)
        pytest.fail("no checkpoint within the time limit")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


@pytest.mark.parametrize("script, name, extra", [
    ("two_bars.py", "two_bars", []),
    ("two_cracks.py", "two_cracks", ["--t-end", "6e-4"]),
    ("crossing.py", "crossing", ["--friction", "0.3"]),   # an arrest, then a crossing after the restart
    ("branching.py", "branching", []),                    # a branch after the restart
    # microcracks; to 5e-4 s (244 steps): to 2.5e-4 s the run sometimes reached its end between its
    # first checkpoint and the kill (CI met it once, and 2 of 6 runs here); 8 of 8 passed since
    ("refracture.py", "refracture", ["--growth", "--growth-nucleation-cap", "2", "--t-end", "5e-4"]),
    ("borehole.py", "borehole", ["--scheme", "ader", "--t-end", "1e-2"]),  # ADER: its predictor from the restored state
    # lsrk54: every mesh's step fitted to the growth checks, the restored one too
    ("refracture.py", "refracture", ["--growth", "--scheme", "lsrk54", "--t-end", "4e-4"]),
    # ADER with cracks: the interface's stages from the restored state and predictor
    ("refracture.py", "refracture", ["--growth", "--scheme", "ader", "--t-end", "4e-4"]),
])
def test_kill_and_restart_on_two_ranks_ends_as_a_straight_run(tmp_path, script, name, extra):
    """Checkpoints every second (on rank 0's clock, broadcast: a per-rank decision hung here
    before) and every 20 steps; a run killed -9 after its first checkpoint and restarted ends
    with the straight run's summary (but timings) and the same last frame, bit for bit, and
    no duplicated history rows.  ``two_cracks`` remeshes as its crack grows."""
    base = [*_mpi(2), SC / script, "--quick", "--checkpoint-every", "1", "--checkpoint-steps", "20", *extra]
    straight, killed = tmp_path / "straight", tmp_path / "killed"
    _run([*base, "--out", straight], timeout=600)
    _kill_after_checkpoint([*base, "--out", killed], killed / "checkpoint")
    assert not (killed / "summary.json").exists()
    res = _run([*base, "--out", killed, "--restart"], timeout=600)
    assert "restarted from" in res.stdout
    a = json.loads((straight / "summary.json").read_text())
    b = json.loads((killed / "summary.json").read_text())
    assert _comparable(a) == _comparable(b)
    ta, fa = _last_frame(straight, name)
    tb, fb = _last_frame(killed, name)
    assert ta == tb and fa.keys() == fb.keys() and all(fa[k] == fb[k] for k in fa)
    steps = [int(float(r.split(",")[0])) for r in (killed / "history.csv").read_text().splitlines()[1:]]
    assert steps == sorted(set(steps))
    if name in ("two_cracks", "crossing", "branching", "refracture"):
        ga = json.loads((straight / "growth.json").read_text())
        gb = json.loads((killed / "growth.json").read_text())
        assert ga == gb and ga["remeshes"] >= 1
        events = {e["event"] for e in ga["tree"]}
        assert events >= {"crossing": {"arrest", "crossing"}, "branching": {"branch"},
                          "refracture": {"nucleation"}}.get(name, set()), events


@pytest.mark.parametrize("moment", ["between_the_ranks", "between_the_renames"])
def test_restart_after_a_save_interrupted_between_the_ranks(tmp_path, moment):
    """Killed while the ranks replace their checkpoint files: rank 0 has the new step and rank 1
    still the previous one, or both have moved their file to the previous generation and not
    yet put the new one in place.  The restart takes the newest step both ranks hold, says so,
    and ends as the straight run does."""
    cmd = [*_mpi(2), SC / "two_bars.py", "--quick", "--frames", "3", "--checkpoint-steps", "20"]
    straight, cut = tmp_path / "straight", tmp_path / "cut"
    _run([*cmd, "--t-end", "2e-4", "--out", straight], timeout=300)
    _run([*cmd, "--t-end", "1e-4", "--out", cut], timeout=300)
    ck = cut / "checkpoint"
    for p in (ck / "state_r0.npz", ck / "state_r0.prev.npz", ck / "state_r1.prev.npz"):
        assert p.exists()
    if moment == "between_the_ranks":
        (ck / "state_r1.prev.npz").replace(ck / "state_r1.npz")  # rank 1: the older step only
    else:
        for r in (0, 1):
            (ck / f"state_r{r}.npz").replace(ck / f"state_r{r}.prev.npz")  # no rank has a current file
    res = _run([*cmd, "--t-end", "2e-4", "--out", cut, "--restart"], timeout=300)
    assert "save was interrupted" in res.stdout and "restarted from" in res.stdout
    a = json.loads((straight / "summary.json").read_text())
    b = json.loads((cut / "summary.json").read_text())
    assert _comparable(a) == _comparable(b)
    ta, fa = _last_frame(straight, "two_bars")
    tb, fb = _last_frame(cut, "two_bars")
    assert ta == tb and all(fa[k] == fb[k] for k in fa)


def test_restart_of_a_finished_run_touches_nothing(tmp_path):
    """A requeued job (the same command with --restart) says the run has finished and leaves
    its summary, history and frames as they were."""
    out = tmp_path / "run"
    cmd = [sys.executable, SC / "two_bars.py", "--quick", "--frames", "2", "--out", out]
    _run(cmd)
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    res = _run([*cmd, "--restart"])
    assert "already finished" in res.stdout
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before


def test_restart_refuses_other_physics_and_other_rank_counts(tmp_path):
    """A restart with changed physics (--delta0) is refused, naming the parameter; a 1-rank
    checkpoint restarted on 2 ranks is refused, naming the rank count; --t-end may grow, and
    the last step lands on it."""
    out = tmp_path / "run"
    cmd = [sys.executable, SC / "two_bars.py", "--quick", "--frames", "2", "--t-end", "1e-4", "--out", out]
    _run(cmd)
    res = _run([*cmd, "--restart", "--delta0", "-0.1"], check=False)
    assert res.returncode != 0 and "delta0" in res.stderr and "other parameters" in res.stderr
    res = _run([*_mpi(2), *cmd[1:], "--restart"], check=False, timeout=120)
    assert res.returncode != 0 and "written by 1 rank" in (res.stderr + res.stdout)
    _run([sys.executable, SC / "two_bars.py", "--quick", "--frames", "2", "--t-end", "1.5e-4", "--out", out,
          "--restart"])
    s = json.loads((out / "summary.json").read_text())
    assert s["simulated_time"] == 1.5e-4


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_damaged_checkpoint_is_a_clear_error_on_every_rank(tmp_path, damage):
    """Rank 1's checkpoint file truncated or overwritten: the restart stops on both ranks with
    the file named and what to do (before: rank 1 raised BadZipFile, rank 0 waited forever)."""
    out = tmp_path / "run"
    cmd = [*_mpi(2), SC / "two_bars.py", "--quick", "--frames", "2", "--t-end", "1e-4", "--out", out]
    _run(cmd)
    f = out / "checkpoint" / "state_r1.npz"
    data = f.read_bytes()
    f.write_bytes(data[: len(data) // 2] if damage == "truncate" else b"not a checkpoint" * 100)
    res = _run([*cmd, "--t-end", "2e-4", "--restart"], check=False, timeout=120)
    text = res.stdout + res.stderr
    assert res.returncode != 0
    assert "state_r1.npz" in text and "Remove the folder" in text
    assert "BadZipFile" not in text.replace("(BadZipFile", "") or "cannot be read" in text


_FAILING_WRITE = """
import importlib, runpy, sys
from mpi4py import MPI
# argv: module:attribute (the writer to break), the rank it fails on, from its n-th call, script, args
target, rank, nth = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
module, _, path = target.partition(":")
owner = importlib.import_module(module)
*parents, name = path.split(".")
for p in parents:
    owner = getattr(owner, p)
real, calls = getattr(owner, name), [0]
def failing(*args, **kw):  # that rank's disk fills up
    calls[0] += 1
    if MPI.COMM_WORLD.rank == rank and calls[0] >= nth:
        raise OSError(28, "No space left on device")
    return real(*args, **kw)
setattr(owner, name, failing)
sys.argv = sys.argv[4:]
runpy.run_path(sys.argv[0], run_name="__main__")
"""


@pytest.mark.parametrize("target, rank, nth, error", [
    ("numpy:savez", 1, 2, "CheckpointError"),  # rank 1's second checkpoint
    ("hydrofrac.io:write_vtu", 1, 5, "OutputError"),  # rank 1's third frame (two parts a frame)
    ("csv:DictWriter.writerow", 0, 4, "OutputError"),  # rank 0's fourth history row
])
def test_output_that_fails_on_one_rank_stops_every_rank(tmp_path, target, rank, nth, error):
    """One rank cannot write its checkpoint file, frame piece or history row (disk full): both
    ranks stop with the same error naming that rank and its cause, instead of the other one
    waiting forever in the next collective.  A failed checkpoint keeps the previous one whole
    (both files of one step, no temporaries); the output so far is kept."""
    out = tmp_path / "run"
    script = tmp_path / "failing_write.py"
    script.write_text(_FAILING_WRITE)
    res = _run([*_mpi(2), script, target, rank, nth, SC / "two_bars.py", "--quick", "--frames", "4",
                "--t-end", "1e-4", "--checkpoint-steps", "5", "--out", out],
               check=False, timeout=180)
    text = res.stdout + res.stderr
    assert res.returncode != 0
    assert text.count(error) >= 2, text[-3000:]  # raised on both ranks
    assert f"rank {rank}: OSError" in text and "No space left on device" in text and "writable --out" in text
    assert (out / "history.csv").read_text().count("\n") >= 2
    if error == "CheckpointError":
        ckpt = out / "checkpoint"
        steps = []
        for r in (0, 1):
            with np.load(ckpt / f"state_r{r}.npz") as d:
                steps.append(int(d["step"]))
        assert steps[0] == steps[1] == 5, steps
        assert not list(ckpt.glob(".tmp_r*")), "a temporary file was left behind"


@pytest.mark.parametrize("args, word", [
    (["--degree", "0"], "--degree"),
    (["--t-end", "0"], "--t-end"),
    (["--frames", "0"], "--frames"),
    (["--out", ""], "--out"),
    (["--checkpoint-every", "0"], "--checkpoint-every"),
])
def test_options_are_honoured_or_rejected(args, word, tmp_path):
    """A value the user gave is never replaced by a default (``x or default``): 0 and '' are
    errors (exit 2) with the option named, before any set-up."""
    res = _run([sys.executable, SC / "two_bars.py", "--quick", *(["--out", tmp_path / "r"] if word != "--out" else []),
                *args], check=False, timeout=60)
    assert res.returncode == 2 and word in res.stderr


def test_out_must_be_a_writable_folder(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    res = _run([sys.executable, SC / "two_bars.py", "--quick", "--out", f], check=False, timeout=60)
    assert res.returncode == 2 and "is a file" in res.stderr


def test_unregularized_flag_of_the_regularized_script_is_an_error(tmp_path):
    res = _run([sys.executable, SC / "intersection_regularized.py", "--quick", "--unregularized", "--out",
                tmp_path / "r"], check=False, timeout=60)
    assert res.returncode == 2 and "intersection.py --unregularized" in res.stderr
    assert not (tmp_path / "r").exists()


def test_crossing_cracks_rejected_before_meshing(tmp_path):
    """--x-nf 0.3 puts the natural fracture across the 0° perforation: a clear error, not
    "crack tag(s) [101] not in facet tags" after Gmsh."""
    res = _run([sys.executable, SC / "intersection.py", "--quick", "--x-nf", "0.3", "--premeshed", "--out",
                tmp_path / "r"], check=False, timeout=60)
    assert res.returncode == 2 and "cross" in res.stderr


def test_wellbore_description_checks():
    from hydrofrac.boundary import PiecewiseLinear
    from hydrofrac.meshes.fractures import Domain, Perforation
    from hydrofrac.wellbore import Wellbore
    dom = Domain(half_width=1.0, half_height=1.0, wellbore_radius=0.1, h_crack=0.05, h_far=0.3, grading=0.5)
    p = PiecewiseLinear([0.0, 1e-6], [0.0, 1e6])
    with pytest.raises(ValueError, match="pressure must be a PiecewiseLinear"):
        Wellbore(dom, [Perforation(0.0, 0.2)], None)
    with pytest.raises(ValueError, match="overlap"):
        Wellbore(dom, [Perforation(0.0, 0.2), Perforation(0.0, 0.3)], p)


def test_cfl_above_the_stable_value_rejected():
    from mpi4py import MPI

    from hydrofrac import ROCK, compat
    from hydrofrac.solver import CFL_DEFAULT, Solver
    mesh = compat.create_rectangle(MPI.COMM_WORLD, (0.0, 0.0), (1.0, 1.0), 4, 4)
    with pytest.raises(ValueError, match=f"stable value {CFL_DEFAULT['rk4']}"):
        Solver(mesh, 1, ROCK, cfl=3.0)
    assert Solver(mesh, 1, ROCK, cfl=3.0, allow_unstable=True).cfl == 3.0  # the stability studies' escape


def test_material_accepts_any_real_number_type():
    from hydrofrac.material import Material
    m = Material(E=np.float32(2e10), nu=np.float64(0.2), rho=np.int64(2700))
    assert m.E == pytest.approx(2e10) and isinstance(m.lam, float)
    with pytest.raises(ValueError, match="finite number"):
        Material(E=float("nan"), nu=0.2, rho=2700.0)


def test_run_prints_its_estimate(tmp_path):
    res = _run([sys.executable, SC / "two_bars.py", "--quick", "--frames", "1", "--out", tmp_path / "r"])
    assert "steps to t = " in res.stdout and "estimated wall time" in res.stdout


def test_frames_evenly_spaced_in_time_across_remeshes(tmp_path):
    """The frames of a remeshing run are the requested count, evenly spaced in time (before:
    83 frames for 80, 1.3-27.9 µs apart)."""
    import re
    out = tmp_path / "r"
    _run([sys.executable, SC / "two_cracks.py", "--quick", "--frames", "12", "--out", out], timeout=600)
    times = sorted({float(t) for t in re.findall(r'timestep="([^"]+)"', (out / "two_cracks.pvd").read_text())})
    assert len(times) == 13
    dt = json.loads((out / "summary.json").read_text())["dt"]
    assert np.allclose(np.diff(times), 3e-4 / 12, atol=1.01 * dt)


@pytest.mark.parametrize("script", ["two_bars", "shear_fracture", "sneddon", "borehole", "crack_growth",
                                    "intersection_regularized", "intersection_unregularized", "refracture",
                                    "two_cracks"])
def test_every_dissipation_term_is_non_negative(script, tmp_path):
    """Each scenario at --quick: every dissipation of the energy budget is >= 0 (before:
    crack_growth reported -113.8 J/m of friction on frictionless cracks, the work of the
    initial shear traction on the slip counted as friction)."""
    out = tmp_path / "r"
    _run([sys.executable, SC / f"{script}.py", "--quick", "--frames", "1", "--out", out], timeout=900)
    e = json.loads((out / "summary.json").read_text())["energy"]
    for key in ("radiated", "dissipated_flux", "dissipated_friction", "dissipated_damage", "dissipated_relaxation"):
        assert e[key] >= -1e-9 * max(1.0, abs(e["initial"]) + abs(e["work_in"])), (key, e[key])


def test_a_run_that_compiles_the_kernels_ends_as_one_that_loads_them(tmp_path):
    """A fresh install's first run compiles numba's kernels; the next ones load them from its
    cache.  Both must give the same numbers, bit for bit: with the fast-math flags on the
    interface kernels (hydrofrac/kernels.py) they differed in the last digit from step 55 of
    this run on (docs/benchmarks.md, "Runs that compile the interface kernels")."""
    env = {**os.environ, **MPI_ENV, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    for name in ("compiles", "loads"):
        res = subprocess.run([sys.executable, "scenarios/refracture.py", "--quick", "--t-end", "2e-4",
                              "--out", str(tmp_path / name)], cwd=ROOT, env=env, capture_output=True, text=True,
                             timeout=600)
        assert res.returncode == 0, res.stderr[-3000:]
    first, second = ((tmp_path / n / "history.csv").read_bytes() for n in ("compiles", "loads"))
    assert len(first.splitlines()) > 15
    assert first == second


def _keyed_modules(tmp_path, files):
    """Write the modules ``files`` (name -> source) into a folder keyed as ``hydrofrac/`` is
    (``hydrofrac._jit.use_keyed_cache``); returns (the folder, g(x) as text: ``high.g`` run in a
    fresh interpreter, with numba's cache in ``tmp_path``)."""
    mods = tmp_path / "mods"
    mods.mkdir(exist_ok=True)
    for name, text in files.items():
        (mods / name).write_text(text)
    code = ("import sys; sys.path.insert(0, sys.argv[1]); from hydrofrac._jit import use_keyed_cache; "
            "use_keyed_cache(sys.argv[1]); import high; print(high.g(float(sys.argv[2])))")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}

    def g(x):
        return subprocess.run([sys.executable, "-c", code, str(mods), str(x)], env=env, capture_output=True,
                              text=True, check=True, timeout=300).stdout.strip()
    return mods, g


def test_a_kernel_is_compiled_again_when_a_function_it_calls_changes(tmp_path):
    """numba inlines the functions a kernel calls, but its cache checks only the kernel's own
    file: a kernel cached before an edit of a point function it calls (``hydrofrac/riemann.py``
    for the interface kernels) kept running the old code.  ``hydrofrac._jit.use_keyed_cache``
    keys the cache by the sources of every module, so the edit compiles it again."""
    mods, g = _keyed_modules(tmp_path, {
        "low.py": "from hydrofrac._jit import njit\n\n\n@njit\ndef f(x):\n    return x + 1.0\n",
        "high.py": "from hydrofrac._jit import njit\nfrom low import f\n\n\n@njit\ndef g(x):\n    return 2.0 * f(x)\n"})
    assert g(1.0) == "4.0"
    assert g(1.0) == "4.0"  # (the second run loads g from the cache)
    (mods / "low.py").write_text("from hydrofrac._jit import njit\n\n\n@njit\ndef f(x):\n    return x + 2.0\n")
    assert g(1.0) == "6.0"


def test_a_kernel_is_compiled_again_when_a_constant_it_reads_changes(tmp_path):
    """numba freezes the value of a global a kernel reads (a material constant) into its code:
    an edit of the module that defines it, which compiles nothing itself, compiles the kernel
    again too (the key hashes every module of ``hydrofrac/``)."""
    mods, g = _keyed_modules(tmp_path, {
        "const.py": "K = 1.0\n",
        "high.py": "from hydrofrac._jit import njit\nfrom const import K\n\n\n@njit\ndef g(x):\n    return K * x\n"})
    assert g(2.0) == "2.0"
    assert g(2.0) == "2.0"  # (from the cache)
    (mods / "const.py").write_text("K = 3.0\n")
    assert g(2.0) == "6.0"


def test_the_mesh_modules_compile_into_the_keyed_cache(tmp_path):
    """``meshes/patch.py`` (``hydrofrac.meshes.patch``) compiles with numba too: its compiled
    functions go to the keyed cache, whatever was imported first (imported alone, it used to
    cache beside its source, in ``meshes/__pycache__``, which a read-only install lacks)."""
    code = ("from hydrofrac.meshes.patch import SizeLaw; import numpy as np; "
            "law = SizeLaw(0.05, 1.0, 2.0).sampler({1: np.array([[0.0, 0.0], [1.0, 0.0]])}); "
            "print(law.scalar_near((0, 0), (1, 1))(0.5, 0.5))")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["HYDROFRAC_CACHE"] = str(tmp_path)
    subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True, timeout=300)
    cached = [p.name for p in tmp_path.glob("numba-*/**/*.nbi")]
    assert any(n.startswith("patch._size_at") for n in cached), cached


def test_compiled_caches_fall_back_to_the_temp_dir_where_the_home_cannot_be_written(monkeypatch, tmp_path):
    """A compute node may mount the home read-only: the caches then go to a per-user folder
    in the temp dir (before, importing hydrofrac failed there).  A cache folder the user set
    and that cannot be written is an error naming it."""
    from hydrofrac import _jit
    home = tmp_path / "home" / ".cache" / "hydrofrac"
    monkeypatch.delenv("HYDROFRAC_CACHE", raising=False)
    monkeypatch.setattr(_jit.Path, "home", lambda: tmp_path / "home")
    monkeypatch.setattr(_jit.tempfile, "tempdir", str(tmp_path / "tmp"))
    assert _jit.cache_root() == home
    real = _jit.writable
    monkeypatch.setattr(_jit, "writable", lambda p: p != home and real(p))
    assert _jit.cache_root() == tmp_path / "tmp" / f"hydrofrac-{os.getuid()}"
    monkeypatch.setenv("HYDROFRAC_CACHE", str(home))
    with pytest.raises(OSError, match="HYDROFRAC_CACHE="):
        _jit.cache_root()
