"""The bulk DG solver against known answers (docs/verification.md, cases 1-5).

1. plane P and S waves: convergence slopes of the L2 errors of v and sigma;
2. welded bimaterial at normal incidence: reflection and transmission coefficients;
3. absorbing boundary: energy left behind by a pulse that leaves the domain;
4. energy: never increases without loads; balances the work in with a load;
5. CFL: stable at the documented constant, stopped with a clear message at 1.5 times it.

All tests run on any number of MPI ranks (meshes on COMM_WORLD, reductions over it).
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

import exact
from exact import BOTTOM, LEFT, RIGHT, TOP, PlaneWave
from hydrofrac import CONFINEMENT, ROCK, Material
from hydrofrac.boundary import Absorbing, OuterState, PiecewiseLinear, Slider, Symmetry, Traction
from hydrofrac.run import RunOptions, run
from hydrofrac.solver import CFL_DEFAULT, BlowUpError, Solver, default_cfl

#: Medium 2 of verification case 2.
MEDIUM2 = Material(E=40e9, nu=0.25, rho=2700.0, name="medium 2")

SIGMA0 = ((-CONFINEMENT, 0.0), (0.0, -CONFINEMENT))


def run_to(solver, t_end):
    """Step to exactly t_end (the step shortened evenly, never lengthened)."""
    n = int(math.ceil(t_end / solver.dt - 1e-9))
    solver.dt = t_end / n
    for _ in range(n):
        solver.step()
    return n


# --------------------------------------------------------------------------- case 1
#: Meshes N x N of the unit square ("right" diagonals) per degree; the pulse has width 0.3
#: (1.2 to 7 cells per width) and travels at 0.7 rad, oblique to every mesh line.  Measured
#: slopes (v, sigma): p = 1: 2.00, 2.00 (P), 2.01, 2.00 (S); p = 2: 3.20, 3.07 / 3.23, 2.89;
#: p = 3: 3.97, 3.93 / 3.97, 3.92.  At these sizes the stress error of p = 3 is still
#: pre-asymptotic in some directions: at 0.3 rad the S wave's sigma slope is 3.74 over
#: N = 4, 8, 16 (pairwise 3.67, 3.82, then 3.86 from 12 to 24), at -0.4 rad the P wave's
#: 3.80; v converges at >= 3.9 in every direction tried.
PLANE_WAVE_MESHES = {1: (6, 12, 24), 2: (4, 8, 16), 3: (4, 8, 16)}
PLANE_WAVE_ANGLE = 0.7
PLANE_WAVE_WIDTH = 0.3


@pytest.mark.parametrize("kind", ["P", "S"])
@pytest.mark.parametrize("p", [1, 2, 3])
def test_plane_wave_convergence(p, kind):
    """Case 1: a Gaussian plane pulse crosses 0.3 of the unit square; the exact solution
    is the initial state and the outer state of the boundary Riemann flux.  The fitted
    slope of the relative L2 errors of v and of sigma over three meshes is >= p + 0.8."""
    d = np.array([np.cos(PLANE_WAVE_ANGLE), np.sin(PLANE_WAVE_ANGLE)])
    wave = PlaneWave(ROCK, kind, PLANE_WAVE_ANGLE, PLANE_WAVE_WIDTH, x0=np.array([0.5, 0.5]) - 0.15 * d)
    Ns = PLANE_WAVE_MESHES[p]
    errors = []
    for N in Ns:
        mesh, _ = exact.unit_square(N)
        solver = Solver(mesh, p, ROCK, facet_tags=exact.exterior_tags(mesh), bcs=[OuterState(1, wave)])
        solver.set_initial_state(lambda x: wave(x, 0.0))
        run_to(solver, 0.3 / wave.speed)
        errors.append(exact.relative_l2_errors(solver, wave, solver.t))
    h = 1.0 / np.array(Ns)
    slopes = {key: exact.fitted_slope(h, [e[key] for e in errors]) for key in ("v", "sigma")}
    report = ", ".join(f"N = {N}: v {e['v']:.3e}, sigma {e['sigma']:.3e}" for N, e in zip(Ns, errors))
    for key, slope in slopes.items():
        assert slope >= p + 0.8, (f"{kind} wave, p = {p}: L2 error of {key} converges at {slope:.2f} < {p + 0.8} "
                                  f"({report})")
    assert errors[-1]["v"] < 0.02 and errors[-1]["sigma"] < 0.02, report


@pytest.mark.parametrize("p", [1, 2, 3])
def test_plane_wave_convergence_ader(p):
    """Case 1 under the ADER step (one cell-local Taylor predictor and one corrector per
    step, :data:`hydrofrac.solver.ADER`), at its documented CFL constant: the P wave's
    errors converge at >= p + 0.8 and stay within 10 % of rk4's on the finest mesh (both
    schemes have the same spatial error; a predictor truncated to first order in time
    converges at 1)."""
    d = np.array([np.cos(PLANE_WAVE_ANGLE), np.sin(PLANE_WAVE_ANGLE)])
    wave = PlaneWave(ROCK, "P", PLANE_WAVE_ANGLE, PLANE_WAVE_WIDTH, x0=np.array([0.5, 0.5]) - 0.15 * d)
    Ns = PLANE_WAVE_MESHES[p]
    errors = {}
    for scheme in ("ader", "rk4"):
        errors[scheme] = []
        for N in Ns if scheme == "ader" else Ns[-1:]:
            mesh, _ = exact.unit_square(N)
            solver = Solver(mesh, p, ROCK, facet_tags=exact.exterior_tags(mesh), bcs=[OuterState(1, wave)],
                            scheme=scheme)
            solver.set_initial_state(lambda x: wave(x, 0.0))
            run_to(solver, 0.3 / wave.speed)
            errors[scheme].append(exact.relative_l2_errors(solver, wave, solver.t))
    h = 1.0 / np.array(Ns)
    report = ", ".join(f"N = {N}: v {e['v']:.3e}, sigma {e['sigma']:.3e}" for N, e in zip(Ns, errors["ader"]))
    for key in ("v", "sigma"):
        slope = exact.fitted_slope(h, [e[key] for e in errors["ader"]])
        assert slope >= p + 0.8, f"ADER, p = {p}: L2 error of {key} converges at {slope:.2f} < {p + 0.8} ({report})"
        fine, ref = errors["ader"][-1][key], errors["rk4"][-1][key]
        assert abs(fine - ref) <= 0.1 * ref, f"ADER {key} error {fine:.4e} against rk4's {ref:.4e} on N = {Ns[-1]}"


# --------------------------------------------------------------------------- case 2
def bimaterial_peaks(kind, p=3, cells_per_width=2):
    """Normal incidence of a Gaussian pulse (width w) from rock (x < 0) onto medium 2 (x > 0)
    in a strip whose sides carry the mirror condition of the wave (Symmetry for P, Slider
    for SV), absorbing ends.  Returns (numerical, exact) coefficients R, T, R_sigma, T_sigma
    from the signed peaks of velocity and stress once both pulses have left the interface."""
    w = 0.1
    h = w / cells_per_width
    mesh, ft, ct = exact.strip(-7 * w, 10 * w, 17 * cells_per_width, 2 * h, 2)  # x = 0 is a grid line
    side = Symmetry if kind == "P" else Slider
    solver = Solver(mesh, p, {1: ROCK, 2: MEDIUM2}, cell_tags=ct, facet_tags=ft,
                    bcs=[Absorbing(LEFT), Absorbing(RIGHT), side(BOTTOM), side(TOP)])
    wave = PlaneWave(ROCK, kind, 0.0, w, x0=(-3.5 * w, 0.0))
    solver.set_initial_state(lambda x: wave(x, 0.0) * (x[0] < 0))
    # the reflected pulse is back at x = -3.5 w, the transmitted one at 3.5 w c2/c1 <= 5 w
    run_to(solver, 7 * w / wave.speed)
    pts, vals = exact.sample(solver)
    iv, isg = (0, 2) if kind == "P" else (1, 4)
    left, right = pts[:, 0] < 0, pts[:, 0] > 0
    s_inc = wave.S[0, 0] if kind == "P" else wave.S[0, 1]  # incident stress amplitude (v amplitude 1)
    peak = lambda mask, i: exact.signed_peak(solver.comm, vals[mask, i])  # noqa: E731
    num = {"R": peak(left, iv), "T": peak(right, iv), "R_sigma": peak(left, isg) / s_inc,
           "T_sigma": peak(right, isg) / s_inc}
    Z1, Z2 = (ROCK.Zd, MEDIUM2.Zd) if kind == "P" else (ROCK.Zs, MEDIUM2.Zs)
    ref = {"R": (Z1 - Z2) / (Z1 + Z2), "T": 2 * Z1 / (Z1 + Z2), "R_sigma": (Z2 - Z1) / (Z1 + Z2),
           "T_sigma": 2 * Z2 / (Z1 + Z2)}
    return num, ref


@pytest.mark.parametrize("kind, abs_R", [("P", 0.20866), ("S", 0.18033)])
def test_welded_bimaterial_normal_incidence(kind, abs_R):
    """Case 2: peak amplitudes of the reflected and transmitted pulses within 1 % of
    R = (Z1 - Z2)/(Z1 + Z2), T = 2 Z1/(Z1 + Z2), R_sigma = -R, T_sigma = 2 Z2/(Z1 + Z2)."""
    num, ref = bimaterial_peaks(kind)
    assert abs(ref["R"]) == pytest.approx(abs_R, abs=5e-6)  # the numbers of verification.md
    if kind == "P":
        assert ref["T"] == pytest.approx(0.79134, abs=5e-6)
    for key in ref:
        rel = abs(num[key] - ref[key]) / abs(ref[key])
        assert rel < 0.01, f"{kind}: {key} = {num[key]:.5f}, expected {ref[key]:.5f} (error {100 * rel:.2f} %)"


# --------------------------------------------------------------------------- case 3
@pytest.mark.parametrize("kind", ["P", "S"])
def test_absorbing_boundary_normal_incidence(kind):
    """Case 3: a stress pulse at rest splits into two halves that leave through the absorbing
    ends of a strip at normal incidence; less than 1 % of the energy stays behind."""
    w, p, cells_per_width = 0.1, 2, 3
    h = w / cells_per_width
    mesh, ft, _ = exact.strip(-4 * w, 4 * w, 8 * cells_per_width, 2 * h, 2)
    side = Symmetry if kind == "P" else Slider
    solver = Solver(mesh, p, ROCK, facet_tags=ft, bcs=[Absorbing(LEFT), Absorbing(RIGHT), side(BOTTOM), side(TOP)])
    wave = PlaneWave(ROCK, kind, 0.0, w)

    def stress_pulse(x):
        u = wave(x, 0.0)
        u[:2] = 0.0
        return u
    solver.set_initial_state(stress_pulse)
    e0 = solver.energy.initial
    n = int(math.ceil(8 * w / wave.speed / solver.dt))  # each half travels 8 w: 4 w past the end
    for _ in range(n):
        solver.step()
        solver.update_energy()
    left = solver.energy.total / e0
    assert left < 0.01, f"{kind}: {100 * left:.3f} % of the energy is left after the pulse has gone"
    # where it went: out through the ends, and a little into upwind dissipation
    assert abs(solver.energy.balance_error) < 1e-3 * e0


# --------------------------------------------------------------------------- case 4
@pytest.mark.parametrize("scheme", ["rk4", "ssprk3", "lsrk54", "lsrk144", "ader"])
@pytest.mark.parametrize("boundary", ["traction-free", "absorbing"])
@pytest.mark.parametrize("data", ["smooth", "rough"])
def test_energy_never_increases(boundary, scheme, data):
    """Case 4: with traction-free or absorbing boundaries and no load, the discrete total
    energy never increases from one step to the next (to round-off), for smooth data and
    for data that excite every mode of the mesh."""
    mesh, _ = exact.unit_square(6)
    bcs = [] if boundary == "traction-free" else [Absorbing(1)]
    solver = Solver(mesh, 2, ROCK, facet_tags=exact.exterior_tags(mesh), bcs=bcs, scheme=scheme)
    initial = exact.gaussian_bump(ROCK, (0.4, 0.55), 0.2) if data == "smooth" else exact.rough_state(ROCK)
    solver.set_initial_state(initial)
    energies = [solver.energy.total]
    for _ in range(120):
        solver.step()
        solver.update_energy()
        energies.append(solver.energy.total)
    energies = np.array(energies)
    growth = np.diff(energies) / energies[0]
    assert growth.max() <= 1e-12, (f"energy grew by {growth.max():.2e} of the initial energy at step "
                                   f"{growth.argmax() + 1}")
    assert energies[-1] < energies[0]
    if boundary == "traction-free":
        assert solver.energy.radiated == 0.0 and solver.energy.work_in == 0.0


def loaded_block(dt_factor, scheme="rk4", N=6):
    """Confined block (sigma0 = -p0 I): a pressure ramp on the left side, absorbing right side,
    the initial stress as traction on top and bottom.  Returns the energy budget after the
    wave has crossed the block once."""
    mesh, ft = exact.unit_square(N)
    history = PiecewiseLinear((0.0, 50e-6, 1.0), (0.0, 1e6, 1e6))  # ramp to 1 MPa in 50 us, held
    bcs = [Traction(LEFT, stress=SIGMA0, pressure=history), Absorbing(RIGHT, stress=SIGMA0),
           Traction(BOTTOM, stress=SIGMA0), Traction(TOP, stress=SIGMA0)]
    solver = Solver(mesh, 2, ROCK, facet_tags=ft, bcs=bcs, sigma0=SIGMA0, scheme=scheme)
    solver.dt *= dt_factor
    t_end = 1.5 / ROCK.cd
    n = int(math.ceil(t_end / solver.dt))
    solver.update_energy()
    for _ in range(n):
        solver.step()
        solver.update_energy()
    return solver.energy


def test_energy_balance_with_load():
    """Case 4 with a load: total = initial + work in - radiated - dissipated to the
    time-integration error.  The budget integrates the boundary power and the upwind
    dissipation rate with the trapezoidal rule per step, an O(dt^2) quadrature (the RK4
    fields themselves are O(dt^4)), so the test asks for (a) a balance error below 1e-3 of
    the work in at the default time step and (b) second order: halving dt divides it by
    more than 3 (4 in the limit).  A missing or wrong term (a load, the radiation, the
    dissipation, the initial stress) would leave an O(1) error that does not shrink."""
    e1 = loaded_block(1.0)
    e2 = loaded_block(0.5)
    assert e1.work_in > 0 and e1.radiated > 0 and e1.dissipated_flux > 0
    rel1, rel2 = abs(e1.balance_error) / e1.work_in, abs(e2.balance_error) / e2.work_in
    assert rel1 < 1e-3, f"balance error {e1.balance_error:.3e} J/m = {rel1:.2e} of the work in {e1.work_in:.4e} J/m"
    assert rel2 < rel1 / 3, f"balance error does not converge at second order in dt: {rel1:.2e} -> {rel2:.2e}"
    assert e2.work_in == pytest.approx(e1.work_in, rel=1e-2)


def test_ader_reuses_its_predictor_only_for_the_state_it_was_made_from():
    """The ADER corrector's pass also computes the next step's predictor; a state written
    between steps (here a new initial state) or a new dt must not step with the stale one:
    the run then equals a fresh solver's bit for bit."""
    mesh, _ = exact.unit_square(4)
    bump = exact.gaussian_bump(ROCK, (0.4, 0.55), 0.2)
    other = exact.gaussian_bump(ROCK, (0.6, 0.4), 0.15)
    a = Solver(mesh, 2, ROCK, scheme="ader")
    a.set_initial_state(bump)
    for _ in range(3):
        a.step()
    a.set_initial_state(other)
    a.dt *= 0.5
    b = Solver(mesh, 2, ROCK, scheme="ader")
    b.set_initial_state(other)
    b.dt *= 0.5
    for _ in range(4):
        a.step()
        b.step()
    assert np.array_equal(a.x.array_r, b.x.array_r)


def test_energy_balance_with_load_ader():
    """Case 4 with a load under the ADER step.  ADER is a space-time discretisation: its
    predictor sees each cell alone, so at a fixed mesh it tends to the semi-discrete solution
    only at first order in dt (an O(dt h^p) defect per unit time from the facet jumps), and
    the budget is checked under joint refinement of h and dt at the CFL constant: a balance
    error below 1e-3 of the work in at N = 12, and at least 3x smaller at N = 24 (measured:
    2.7e-4, then 4.7x smaller).  A missing load, radiation, dissipation or data integration
    leaves an O(1) error."""
    e1 = loaded_block(1.0, "ader", N=12)
    e2 = loaded_block(1.0, "ader", N=24)
    assert e1.work_in > 0 and e1.radiated > 0 and e1.dissipated_flux > 0
    rel1, rel2 = abs(e1.balance_error) / e1.work_in, abs(e2.balance_error) / e2.work_in
    assert rel1 < 1e-3, f"balance error {e1.balance_error:.3e} J/m = {rel1:.2e} of the work in {e1.work_in:.4e} J/m"
    assert rel2 < rel1 / 3, f"the ADER balance error does not converge under refinement: {rel1:.2e} -> {rel2:.2e}"
    assert e2.work_in == pytest.approx(e1.work_in, rel=1e-2)


# --------------------------------------------------------------------------- case 5
@pytest.mark.parametrize("scheme", ["rk4", "ssprk3", "lsrk54", "lsrk144", "ader"])
@pytest.mark.parametrize("p", [1, 2, 3, 4])
@pytest.mark.parametrize("mesh_kind", ["structured", "perturbed"])
def test_cfl_stable_at_documented_constant(mesh_kind, p, scheme):
    """Case 5: at the documented CFL constant a run from data that excite every mode stays
    stable (no blow-up detected, energy decays), on a structured mesh (the most restrictive
    for the h_min-based limit, see CFL_DEFAULT) and on a perturbed one."""
    mesh, _ = exact.unit_square(6)
    if mesh_kind == "perturbed":
        exact.perturb_interior(mesh, 0.2, 1.0 / 6)
    solver = Solver(mesh, p, ROCK, scheme=scheme)
    assert solver.dt == pytest.approx(default_cfl(scheme, p) * solver.h_over_c_min / (2 * p + 1))
    solver.set_initial_state(exact.rough_state(ROCK))
    for _ in range(200):
        solver.step()
        solver.update_energy()
        solver.check_stability()
    assert solver.energy.total < solver.energy.initial


@pytest.mark.parametrize("scheme", ["rk4", "ssprk3", "lsrk54", "lsrk144", "ader"])
@pytest.mark.parametrize("p", [1, 2, 3])
def test_cfl_unstable_at_one_and_a_half(p, scheme):
    """Case 5: at 1.5 times the documented constant the run blows up; check_stability stops
    it within a few hundred steps, before any NaN, with a message that names the cause and
    the remedy.  (lsrk144: at 2 times.  Its documented constant keeps |R| <= 1 strictly on
    the infinite mesh's spectrum, which its stability region leaves only by a thin margin up
    to beyond 1.5 C: there the energy still decays over 1500 steps; at 2 C it blows up within
    4 steps.)"""
    mesh, _ = exact.unit_square(12)
    factor = 2.0 if scheme == "lsrk144" else 1.5
    solver = Solver(mesh, p, ROCK, scheme=scheme, cfl=factor * default_cfl(scheme, p), allow_unstable=True)
    solver.set_initial_state(exact.rough_state(ROCK))
    with pytest.raises(BlowUpError, match=r"unstable at step \d+.*too large.*CFL constant <= ") as err:
        for _ in range(300):
            solver.step()
            solver.update_energy()
            solver.check_stability()
    assert math.isfinite(solver.energy.total), "the blow-up was detected only after the fields overflowed"
    assert str(default_cfl(scheme, p)) in str(err.value)


def test_run_blowup_keeps_last_good_state(tmp_path):
    """Case 5 through the run driver: a blow-up stops the run with the message, and the last
    good state (finite) is in the solver, in a last output frame and in the checkpoint."""
    comm = MPI.COMM_WORLD
    out = Path(comm.bcast(str(tmp_path), root=0)) / "blowup"
    mesh, _ = exact.unit_square(12)
    solver = Solver(mesh, 1, ROCK, cfl=1.5 * CFL_DEFAULT["rk4"], allow_unstable=True)
    solver.set_initial_state(exact.rough_state(ROCK))
    with pytest.raises(BlowUpError, match=r"(?s)unstable at step \d+.*last good state") as err:
        run(solver, RunOptions(t_end=400 * solver.dt, out=str(out), frames=4, progress_wall=1e9))
    bad_step = int(re.search(r"unstable at step (\d+)", str(err.value)).group(1))
    assert solver.step_count == bad_step - 1 and solver.t == pytest.approx(solver.dt * (bad_step - 1))
    x = solver.x.array_r
    assert np.all(np.isfinite(x))
    kin, strain = solver.energies()
    assert kin + strain <= 1.5 * solver.energy.initial
    ckpt = np.load(out / "checkpoint" / f"state_r{comm.rank}.npz")
    assert int(ckpt["step"]) == bad_step - 1 and np.array_equal(ckpt["x"], x)
    pvd = (out / "solution.pvd").read_text()
    assert f'timestep="{solver.t:.9e}"' in pvd


def _small_run(out):
    """(the output folder ``out``, rank 0's path on every rank; a P1 solver on a 6x6 unit square
    from a rough state): a run of a few dozen steps for the loop's own tests."""
    out = Path(MPI.COMM_WORLD.bcast(str(out), root=0))
    mesh, _ = exact.unit_square(6)
    solver = Solver(mesh, 1, ROCK)
    solver.set_initial_state(exact.rough_state(ROCK))
    return out, solver


def test_a_checkpoint_by_wall_time_is_taken_at_a_clock_reading(tmp_path, monkeypatch):
    """With checkpoints by wall time only and a wall interval always passed, the loop saves at
    every reading of rank 0's clock: every CLOCK_EVERY steps, not at every step (each reading is
    a broadcast every rank waits for), then the one at the end."""
    from hydrofrac import run as run_module
    out, solver = _small_run(tmp_path / "clock")
    steps = 3 * run_module.CLOCK_EVERY + 4
    saved = []
    original = run_module.Checkpoint.save

    def counted(self, problem, *args, **kwargs):
        saved.append(problem.solver.step_count)
        return original(self, problem, *args, **kwargs)
    monkeypatch.setattr(run_module.Checkpoint, "save", counted)
    run(solver, RunOptions(t_end=steps * solver.dt, out=str(out), frames=1, progress_wall=1e9, checkpoint_wall=1e-9))
    readings = [k for k in range(1, steps) if k % run_module.CLOCK_EVERY == 0]
    assert saved == readings + [steps]  # (and the save at the end)


def test_the_time_split_holds_the_monitors(tmp_path):
    """A scenario's monitors run every step inside the wall time; the time split gives them
    their own part ("monitors"), so the split's parts account for them.  Here a monitor that
    sleeps 4 ms a step over 12 steps: the part holds at least those 48 ms, within the wall
    time."""
    import time as _time
    from hydrofrac.run import Monitor
    out, solver = _small_run(tmp_path / "monitors")

    class Sleepy(Monitor):
        def __call__(self, problem):
            _time.sleep(0.004)

    s = run(solver, RunOptions(t_end=12 * solver.dt, out=str(out), frames=1, progress_wall=1e9),
            monitors=[Sleepy()])
    split = s["time_split_s"]
    assert 12 * 0.004 <= split["monitors"] <= s["wall_time_s"], split


def test_the_summary_says_how_much_of_the_wall_time_compiled_kernels(tmp_path):
    """A kernel compiled at its first use inside the time loop (a first run after an edit, or on a
    fresh machine) counts in the wall time and in the part that called it; the summary gives those
    seconds ("compiling_in_wall_s").  Here a monitor calls a kernel of its own (not cached) at
    the first step: the summary holds at least 80 % of that first call's time, and a run whose
    kernels are all compiled reports less than that kernel's compile."""
    import time as _time
    import numba
    from hydrofrac.run import Monitor
    out, solver = _small_run(tmp_path / "compiling")
    solver.step()  # (the solver's own kernels: compiled or loaded before the runs below)
    first = []

    def sums(a):  # (a kernel whose compile takes a while: sorting, a reduction, a loop)
        b = np.sort(a)
        t = 0.0
        for i in range(b.size):
            t += np.sqrt(abs(b[i])) * np.sin(b[i])
        return t + np.linalg.norm(b)

    class Compiling(Monitor):
        def __init__(self):
            self.kernel = numba.njit(sums)

        def __call__(self, problem):
            t0 = _time.perf_counter()
            self.kernel(np.arange(4.0))
            first.append(_time.perf_counter() - t0)

    s = run(solver, RunOptions(t_end=solver.t + 3 * solver.dt, out=str(out), frames=1, progress_wall=1e9),
            monitors=[Compiling()])
    assert s["compiling_in_wall_s"] >= 0.8 * first[0], (s["compiling_in_wall_s"], first[0])
    again = run(solver, RunOptions(t_end=solver.t + 3 * solver.dt, out=str(out / "again"), frames=1,
                                   progress_wall=1e9))
    assert again["compiling_in_wall_s"] < 0.5 * first[0], (again["compiling_in_wall_s"], first[0])


def test_the_time_loop_writes_its_history_rows_without_a_collective_each(tmp_path, monkeypatch):
    """Rank 0 writes a history row every step; whether it could is read with its clock every
    CLOCK_EVERY steps (one broadcast), not gathered from every rank at every row. A row rank 0
    cannot write stops every rank at the next reading (tests/test_reliability.py, the disk full
    on rank 0's fourth row)."""
    from hydrofrac import output, run as run_module
    out, solver = _small_run(tmp_path / "rows")
    steps = 4 * run_module.CLOCK_EVERY
    gathered = []
    original = output.failures

    def counted(comm_, action):
        gathered.append(1)
        return original(comm_, action)
    monkeypatch.setattr(output, "failures", counted)
    run(solver, RunOptions(t_end=steps * solver.dt, out=str(out), frames=1, progress_wall=1e9))
    rows = (out / "history.csv").read_text().strip().splitlines() if MPI.COMM_WORLD.rank == 0 else []
    assert MPI.COMM_WORLD.rank != 0 or len(rows) == steps + 2  # the header, the initial row and one a step
    assert len(gathered) == 1  # the initial row's


def test_blowup_falls_back_to_a_state_close_to_the_stable_run_and_restarts(tmp_path):
    """At 1.5x the stable CFL the run stops as soon as the energy balance has grown in each of
    4 steps, by 2 % in all (before: when the energy passed 1.5x the inflow, 22-45 % above a
    stable run). The
    kept state (fields and budget) has at most 5 % more energy than the stable run at the same
    time, and a restart from it at the stable CFL ends within 5 % of the stable run's energy."""
    comm = MPI.COMM_WORLD
    out = Path(comm.bcast(str(tmp_path), root=0)) / "blowup"
    mesh, _ = exact.unit_square(12)
    bad = Solver(mesh, 1, ROCK, cfl=1.5 * CFL_DEFAULT["rk4"], allow_unstable=True)
    bad.set_initial_state(exact.rough_state(ROCK))
    t_end = 400 * bad.dt
    with pytest.raises(BlowUpError, match="energy-balance error"):
        run(bad, RunOptions(t_end=t_end, out=str(out), frames=2, progress_wall=1e9))
    t_good = bad.t
    kept = bad.energy.total
    assert bad.step_count < 15  # (the 1.5x bound alone trips at step 21 here)
    stable = Solver(mesh, 1, ROCK)
    stable.set_initial_state(exact.rough_state(ROCK))
    while stable.t < t_good - 1e-15:
        stable.step()
    assert kept <= 1.05 * stable.energies()[0] + 1.05 * stable.energies()[1]
    # restart from the kept state at the stable CFL, and a straight stable run, to t_end
    again = Solver(mesh, 1, ROCK)
    s_restart = run(again, RunOptions(t_end=t_end, out=str(out), frames=2, progress_wall=1e9, restart=True))
    straight = Solver(mesh, 1, ROCK)
    straight.set_initial_state(exact.rough_state(ROCK))
    s_straight = run(straight, RunOptions(t_end=t_end, out=str(out / "straight"), frames=2, progress_wall=1e9))
    e_r, e_s = s_restart["energy"], s_straight["energy"]
    assert abs(e_r["total"] / e_s["total"] - 1) < 0.05
