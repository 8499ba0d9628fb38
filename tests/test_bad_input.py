"""Bad input is refused before a run starts, with a ValueError that names the parameter
(and the value given), on any number of MPI ranks."""
from __future__ import annotations

import pytest

import exact
from hydrofrac import ROCK, Material
from hydrofrac.boundary import PiecewiseLinear, Traction
from hydrofrac.loader import scenario as _scenario
from hydrofrac.run import RunOptions
from hydrofrac.solver import Solver


@pytest.fixture(scope="module")
def square():
    return exact.unit_square(2)


@pytest.mark.parametrize("E", [0.0, -20e9])
def test_young_modulus_must_be_positive(E):
    with pytest.raises(ValueError, match=r"E must be > 0 \(Pa\); got "):
        Material(E=E, nu=0.2, rho=2500.0)


@pytest.mark.parametrize("nu", [-1.0, -1.5, 0.5, 0.7])
def test_poisson_ratio_must_be_in_range(nu):
    with pytest.raises(ValueError, match=rf"nu must be in \(-1, 0.5\); got {nu}"):
        Material(E=20e9, nu=nu, rho=2500.0)


@pytest.mark.parametrize("rho", [0.0, -2500.0])
def test_density_must_be_positive(rho):
    with pytest.raises(ValueError, match=r"rho must be > 0 \(kg/m\^3\); got "):
        Material(E=20e9, nu=0.2, rho=rho)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), "20e9"])
def test_material_constants_must_be_finite_numbers(value):
    with pytest.raises(ValueError, match=r"E must be a finite number"):
        Material(E=value, nu=0.2, rho=2500.0)


@pytest.mark.parametrize("degree", [0, 5, -1, 2.0, "2"])
def test_degree_must_be_1_to_4(square, degree):
    mesh, _ = square
    with pytest.raises(ValueError, match=r"degree p must be an integer in 1\.\.4; got "):
        Solver(mesh, degree, ROCK)


def test_time_step_above_stability_limit(square):
    mesh, _ = square
    limit = Solver(mesh, 1, ROCK).dt_stable
    assert Solver(mesh, 1, ROCK, dt=limit).dt == limit  # the limit itself is allowed
    with pytest.raises(ValueError, match=r"dt = .* s is above the stability limit .* use dt <= "):
        Solver(mesh, 1, ROCK, dt=1.01 * limit)


@pytest.mark.parametrize("dt", [0.0, -1e-6])
def test_time_step_must_be_positive(square, dt):
    mesh, _ = square
    with pytest.raises(ValueError, match=r"dt must be > 0; got "):
        Solver(mesh, 1, ROCK, dt=dt)


def test_cfl_must_be_positive(square):
    mesh, _ = square
    with pytest.raises(ValueError, match=r"cfl must be > 0; got "):
        Solver(mesh, 1, ROCK, cfl=0.0)


def test_unknown_scheme(square):
    mesh, _ = square
    with pytest.raises(ValueError, match=r"scheme must be one of .*'ader'.*; got 'rk5'"):
        Solver(mesh, 1, ROCK, scheme="rk5")


def test_ader_refuses_what_it_cannot_step(square):
    """ADER's predictor is the matrix-free volume kernel, and its step has no place for dynamic
    relaxation or for an extension without an ADER step: each is refused up front."""
    mesh, _ = square
    with pytest.raises(ValueError, match=r"scheme 'ader' needs the matrix-free operator.*operator='matfree'"):
        Solver(mesh, 1, ROCK, scheme="ader", operator="assembled")
    with pytest.raises(ValueError, match=r"scheme 'ader' has no dynamic relaxation: use relaxation=0"):
        Solver(mesh, 1, ROCK, scheme="ader", relaxation=1e3)
    solver = Solver(mesh, 1, ROCK, scheme="ader")
    with pytest.raises(ValueError, match=r"scheme 'ader' needs extensions with an ADER step; object has none.*"
                                         r"scheme='rk4' or 'lsrk54'"):
        solver.attach(object())


def test_boundary_tag_not_in_mesh(square):
    mesh, ft = square  # tags 1..4
    with pytest.raises(ValueError, match=r"boundary tag\(s\) \[7\] are not in the mesh's facet tags \[1, 2, 3, 4\]"):
        Solver(mesh, 1, ROCK, facet_tags=ft, bcs=[Traction(exact.LEFT), Traction(7)])


def test_boundary_condition_without_facet_tags(square):
    mesh, _ = square
    with pytest.raises(ValueError, match=r"boundary tag\(s\) \[1\] are not in the mesh's facet tags"):
        Solver(mesh, 1, ROCK, bcs=[Traction(1)])


def test_two_conditions_on_one_tag(square):
    mesh, ft = square
    with pytest.raises(ValueError, match=r"each boundary tag may carry one boundary condition"):
        Solver(mesh, 1, ROCK, facet_tags=ft, bcs=[Traction(1), Traction(1, pressure=1e6)])


def test_material_tag_not_in_mesh():
    mesh, _, ct = exact.strip(-1.0, 1.0, 4, 0.5, 1)  # cell tags 1, 2
    with pytest.raises(ValueError, match=r"material cell tag\(s\) \[3\] are not in the mesh's cell tags \[1, 2\]"):
        Solver(mesh, 1, {1: ROCK, 3: ROCK}, cell_tags=ct)


@pytest.mark.parametrize("times", [(0.0, 1e-3, 1e-3), (0.0, 2e-3, 1e-3)])
def test_history_times_must_increase(times):
    with pytest.raises(ValueError, match=r"history times must increase strictly; times\[1\] = .* is followed by "):
        PiecewiseLinear(times, (0.0, 1e6, 2e6))


def test_history_lengths_must_match():
    with pytest.raises(ValueError, match=r"history needs equally long, non-empty times and values; got 2 and 3"):
        PiecewiseLinear((0.0, 1e-3), (0.0, 1e6, 2e6))


def test_run_end_time_must_be_positive():
    with pytest.raises(ValueError, match=r"t_end must be a positive time in seconds; got "):
        RunOptions(t_end=0.0)


@pytest.mark.parametrize("name, args, word", [
    ("intersection", ["--growth-da", "0"], "--growth-da"),
    ("intersection", ["--growth-r", "-1"], "--growth-r"),
    ("intersection", ["--growth-cod-relax", "1.5"], "--growth-cod-relax"),
    ("intersection", ["--growth-cod-window", "0"], "--growth-cod-window"),
    ("intersection", ["--h-crack", "0"], "--h-crack"),
    ("refracture", ["--growth", "--growth-da", "-2"], "--growth-da"),
    ("refracture", ["--growth", "--growth-beta", "-1"], "--growth-beta"),
    ("refracture", ["--growth-max-radius", "-1"], "--growth-max-radius"),
    ("refracture", ["--pump-rate", "0"], "--pump-rate"),
    ("refracture", ["--pump-rate", "nan"], "--pump-rate"),
    ("refracture", ["--h-crack", "-0.04"], "--h-crack"),
    ("refracture", ["--h-far", "2"], "--h-far"),
    ("intersection", ["--adapt", "0.03", "--growth-remesh", "patch"], "--growth-remesh full"),
    ("intersection", ["--premeshed", "--adapt", "0"], "--adapt"),
    ("intersection", ["--premeshed", "--adapt", "0.03", "--adapt-tol", "-1"], "--adapt-tol"),
    ("refracture", ["--adapt", "-1"], "--adapt"),
    ("refracture", ["--growth", "--adapt", "0.05", "--growth-remesh", "patch"], "--growth-remesh full"),
    # options that the run would ignore
    ("intersection", ["--premeshed", "--growth-da", "3"], "--growth-da: only free growth"),
    ("refracture", ["--premeshed", "--growth-remesh", "full", "--growth-r", "5"], "--growth-r, --growth-remesh"),
    ("intersection", ["--adapt-tol", "0.1"], "give --adapt H_FINE too"),
    ("intersection", ["--growth-direction", "sampled", "--growth-cod-relax", "0.3"], "--growth-cod-relax acts only"),
    ("refracture", ["--growth-remesh", "full", "--growth-patch-radius", "4"], "--growth-patch-radius acts only"),
    ("intersection", ["--adapt", "0.05", "--growth-patch-radius", "4"], "adaptive meshes remesh the whole domain"),
    ("intersection", ["--unregularized", "--pressure-factor", "local"], "drop --pressure-factor"),
    # the time scheme: C above the scheme's documented constant
    ("refracture", ["--scheme", "ader", "--degree", "2", "--cfl", "0.7"], "--cfl must be in (0, 0.69] for --scheme ader"),
    ("refracture", ["--scheme", "lsrk54", "--cfl", "1.5"], "--cfl must be in (0, 1.39] for --scheme lsrk54"),
    ("refracture", ["--cfl", "0.9"], "--cfl must be in (0, 0.85] for --scheme rk4"),
    ("intersection", ["--cfl", "nan"], "--cfl must be in"),
    ("intersection", ["--scheme", "rk5"], "invalid choice: 'rk5'"),
    ("borehole", ["--scheme", "ader", "--cfl", "0.8"], "--cfl must be in (0, 0.73] for --scheme ader"),
])
def test_growth_options_rejected_before_meshing(name, args, word, capsys, tmp_path):
    """Bad growth or mesh options stop a wellbore scenario at once (exit 2) with the option
    and its valid range named, before any meshing or output."""
    with pytest.raises(SystemExit) as info:
        _scenario(name).main(["--quick", "--out", str(tmp_path / "run"), *args])
    assert info.value.code == 2
    assert word in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_growth_limit_inside_the_perforations_rejected(tmp_path, capsys):
    """A growth limit that does not reach beyond the perforation tips is rejected (exit 2)
    before the first mesh is made."""
    with pytest.raises(SystemExit) as info:
        _scenario("refracture").main(["--quick", "--growth-max-radius", "0.2", "--out", str(tmp_path / "run")])
    assert info.value.code == 2 and "perforation tips" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_wellbore_scheme_must_be_known():
    """A wellbore description refuses a misspelt scheme when it is made, naming the schemes."""
    rf = _scenario("refracture")
    with pytest.raises(ValueError, match=r"scheme must be one of rk4, ssprk3, lsrk54, lsrk144, ader; got 'RK4'"):
        rf.description(quick=True, scheme="RK4")
    assert rf.description(quick=True, scheme="ader").scheme == "ader"


def test_refracture_mesh_sizes_are_the_ones_asked_for():
    """--h-crack and --h-far reach the re-fracture's domain, with adaptive meshes too (where
    they are the coarse sizes); the growth's r scales with h_crack."""
    rf = _scenario("refracture")
    from hydrofrac import wellbore
    desc = rf.description(quick=True, h_crack=0.06, h_far=0.4, growth=wellbore.Growth())
    assert (desc.domain.h_crack, desc.domain.h_far) == (0.06, 0.4)
    assert rf.description(quick=True).domain.h_crack == 0.05
    adapted = rf.description(quick=True, adapt=0.02, h_crack=0.07, h_far=0.45)
    assert (adapted.domain.h_crack, adapted.domain.h_far) == (0.07, 0.45)
    assert wellbore.growth_driver(desc).params.r == pytest.approx(wellbore.Growth().r * 0.06)
