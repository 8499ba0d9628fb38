"""The borehole scenario: runs on 1 and 2 ranks with the same result, and its
accuracy report measures what it says (errors against the Lamé solution)."""
import json
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from hydrofrac import CONFINEMENT
from hydrofrac.loader import scenario as load_scenario

ROOT = Path(__file__).resolve().parents[1]


def test_borehole_same_on_two_ranks(tmp_path, run_command, mpirun):
    script = ROOT / "scenarios" / "borehole.py"
    summaries = {}
    for n in (1, 2):
        out = tmp_path / f"n{n}"
        run_command([*mpirun(n), script, "--quick", "--out", out], timeout=600)
        summaries[n] = json.loads((out / "summary.json").read_text())
    s1, s2 = summaries[1], summaries[2]
    assert s2["ranks"] == 2
    for key in ("cells", "dofs", "steps"):
        assert s1[key] == s2[key]
    for key in ("kinetic", "strain", "work_in", "dissipated_flux"):
        assert s2["energy"][key] == pytest.approx(s1["energy"][key], rel=1e-9)


def lame_state(a, p, p0):
    """Nodal (v, σ) of the static Lamé solution, as a ``set_initial_state`` function."""
    bh = load_scenario("borehole")

    def state(x):
        r = np.hypot(x[0], x[1])
        c, s = x[0] / r, x[1] / r
        srr, stt = bh.lame_polar(r, a, p, p0)
        return np.vstack([0 * r, 0 * r, srr * c * c + stt * s * s, srr * s * s + stt * c * c, (srr - stt) * c * s])
    return state


def check_ring_errors():
    bh = load_scenario("borehole")
    solver = bh.setup(MPI.COMM_WORLD, "quick", degree=2).solver
    p = bh.pressure_history()(1.0)
    solver.set_initial_state(lame_state(bh.A, p, CONFINEMENT))
    err_rr, err_tt = bh.ring_errors(solver, bh.A, p, CONFINEMENT, 2 * bh.A)
    assert err_rr < 0.01 and err_tt < 0.01  # interpolation error only (0.6% at p = 2)
    solver.set_initial_state()  # σ0 everywhere: the error is the whole Lamé change
    err_rr, err_tt = bh.ring_errors(solver, bh.A, p, CONFINEMENT, 2 * bh.A)
    assert err_rr == pytest.approx(1.0, rel=1e-9) and err_tt == pytest.approx(1.0, rel=1e-9)


def test_borehole_lame_ring_error():
    check_ring_errors()


@pytest.mark.mpi
def test_borehole_lame_ring_error_mpi():
    check_ring_errors()


def test_borehole_accuracy_report_skips_short_runs():
    bh = load_scenario("borehole")
    problem = bh.setup(MPI.COMM_WORLD, "quick")
    report = bh.LameReport(bh.A, bh.pressure_history()).accuracy(problem)
    assert "not compared" in report["lame_ring"]
    assert "energy_balance_relative_error" in report


def test_borehole_settles_to_lame_under_ader():
    """The default borehole run (p = 2, to 10 a/c_s, one rank) under ADER and under rk4: the
    near field settles to the same Lamé errors (the time scheme's error is far below the
    spatial one: equal within 1 % of themselves), both below 3 % (measured 2.1 % and 1.7 %,
    the transient not fully gone and the p = 2 mesh); ADER takes its own, shorter steps."""
    bh = load_scenario("borehole")
    errors, steps = {}, {}
    for scheme in ("rk4", "ader"):
        solver = bh.setup(MPI.COMM_SELF, "default", scheme=scheme).solver
        t_end = bh.SIZES["default"][3]
        n = int(np.ceil(t_end / solver.dt - 1e-9))
        solver.dt = t_end / n
        for _ in range(n):
            solver.step()
        steps[scheme] = n
        errors[scheme] = bh.ring_errors(solver, bh.A, bh.pressure_history()(t_end), CONFINEMENT, 2 * bh.A)
    assert steps["ader"] > steps["rk4"]  # (its CFL constant is 0.69 at p = 2, rk4's 0.85)
    for k in range(2):
        assert errors["rk4"][k] < 0.03 and errors["ader"][k] < 0.03, errors
        assert errors["ader"][k] == pytest.approx(errors["rk4"][k], rel=0.01), errors
