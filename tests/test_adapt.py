"""Adaptive meshes (hydrofrac.adapt; docs/model.md, "Adaptive meshes"): refinement that
follows a moving front at its known speed and coarsening behind it."""
import numpy as np
import pytest
from mpi4py import MPI

from hydrofrac.adapt import Adapt, AdaptDriver, cell_sizes, jump_indicator, size_levels, thin
from hydrofrac.boundary import Absorbing, PiecewiseLinear, Traction
from hydrofrac.material import ROCK
from hydrofrac.meshes.fractures import OUTER, WELLBORE, Domain, Refinement, fracture_mesh
from hydrofrac.problem import Problem
from hydrofrac.solver import Solver

PEAK = 10e6
PULSE = PiecewiseLinear([0.0, 40e-6, 80e-6], [0.0, PEAK, 0.0])  # wellbore pressure pulse
DOMAIN = Domain(half_width=1.5, half_height=1.5, wellbore_radius=0.1, h_crack=0.25, h_far=0.25, grading=0.3)


def _build(refine):
    fm = fracture_mesh(MPI.COMM_WORLD, DOMAIN, refine=refine)
    s = Solver(fm.mesh, 1, ROCK, facet_tags=fm.facet_tags,
               bcs=[Traction(WELLBORE, pressure=PULSE), Absorbing(OUTER)])
    return Problem(s)


def _front_run(params, t_marks):
    """Run the pulse; at each mark: the mean radius of the flagged points (all levels), the
    number of cells, and the smallest cell size at radii 0.2-0.3 m (the front's place at the
    first mark)."""
    drv = AdaptDriver(_build, params)
    prob = drv.problem
    out = []
    for t_mark in t_marks:
        while prob.solver.t < t_mark - 1e-12:
            prob.solver.step()
            prob.after_step()
            new = drv(prob)
            if new is not None:
                prob = new
        s = prob.solver
        pts = np.vstack([np.zeros((0, 2))] + list(drv.levels.values()))
        g = s.geometry
        n = cell_sizes(s).size
        c = g.x0[:n] + g.J[:n] @ np.array([1 / 3, 1 / 3])
        r = np.linalg.norm(c, axis=1)
        near = (r > 0.2) & (r < 0.3)
        h_near = s.comm.allreduce(float(cell_sizes(s)[near].min()) if near.any() else np.inf, op=MPI.MIN)
        out.append((float(np.linalg.norm(pts, axis=1).mean()) if len(pts) else np.nan, s.num_cells, h_near))
    return drv, out


ADAPT = Adapt(h_fine=0.05, radius=0.05, stress_scale=PEAK, tol=0.05, check_every=5)


def test_refinement_follows_a_moving_front_at_the_wave_speed_and_coarsens_behind_it():
    """A pressure pulse on the wellbore wall sends a cylindrical P wave out at c_d. The fine zone
    (the flagged points) moves with it: its mean radius grows at c_d within 10 %; behind
    it the mesh coarsens back (the cells near the wall return to more than twice h_fine)."""
    t_marks = [120e-6, 240e-6]
    drv, out = _front_run(ADAPT, t_marks)
    (r1, n1, h1), (r2, n2, h2) = out
    speed = (r2 - r1) / (t_marks[1] - t_marks[0])
    assert abs(speed / ROCK.cd - 1) < 0.10, (speed, ROCK.cd, out)
    assert drv.refines >= 2 and drv.coarsens >= 1, drv.report()
    assert h2 > 2 * ADAPT.h_fine, out  # behind the front: coarse again
    # the fine zone is a ring, not the domain: far fewer cells than h_fine everywhere
    uniform = (2 * DOMAIN.half_width) ** 2 / (np.sqrt(3) / 4 * ADAPT.h_fine ** 2)
    assert n2 < 0.5 * uniform, (n2, uniform)


def test_a_continuous_field_has_no_jump_and_a_step_has_its_height():
    """The indicator is 0 for a field continuous across the facets (a constant state); for a
    cell-wise stress step of height s (cells right of x = 0 against the others) it is, per
    cell, (s / stress_scale) sqrt(L_step / L), with L_step its facets' length on the step and
    L its interior facets' length (the root mean square over the facets)."""
    prob = _build([])
    s = prob.solver
    from hydrofrac import compat
    mesh = s.mesh
    g = s.geometry
    dofs = compat.cell_dofs(s.V)
    X = compat.function_array_of_vec(s.x).reshape(-1, 5)
    X[:] = 0.0
    X[:, 2] = 3e6
    with s.x.localForm() as loc:
        loc.array[:] = X.reshape(-1)
    assert np.max(jump_indicator(s, PEAK)) < 1e-12
    c = g.x0 + np.einsum("cij,j->ci", g.J, [1 / 3, 1 / 3])
    right = c[:, 0] > 0
    X[:, 2] = 0.0
    X[dofs[right].reshape(-1), 2] = 2e6
    with s.x.localForm() as loc:
        loc.array[:] = X.reshape(-1)
    eta = jump_indicator(s, PEAK)
    # expected, from the facets' geometry
    off_cf, cf = compat.connectivity(mesh, 2, 1)
    off_fc, fc = compat.connectivity(mesh, 1, 2)
    x = mesh.geometry.x[:, :2]
    nodes = compat.facet_nodes(mesh, np.arange(off_fc.size - 1))
    length = np.linalg.norm(x[nodes[:, 1]] - x[nodes[:, 0]], axis=1)
    expected = np.zeros(eta.size)
    for k in range(eta.size):
        L = Ls = 0.0
        for f in cf[off_cf[k]:off_cf[k + 1]]:
            cells = fc[off_fc[f]:off_fc[f + 1]]
            if cells.size == 2:
                L += length[f]
                Ls += length[f] * (right[cells[0]] != right[cells[1]])
        expected[k] = 2e6 / PEAK * np.sqrt(Ls / L)
    assert np.count_nonzero(expected) > 10
    assert np.allclose(eta, expected, rtol=1e-9, atol=1e-12)


def test_size_levels_equidistribute_the_indicator():
    """h_K (tol / eta)^(1/(p+1)), floored to h_fine 2^k, never below h_fine."""
    lev = size_levels(0.05, np.array([0.4, 0.4, 0.4, 0.05]), np.array([0.1, 0.8, 100.0, 1.0]), 0.1, 1)
    # 0.4 (1)^(1/2) = 0.4 -> 8 h_fine: level 3; 0.4 (1/8)^(1/2) = 0.141 -> level 1; tiny -> 0
    assert lev.tolist() == [3, 1, 0, 0]
    pts = thin(np.array([[0.0, 0.0], [0.01, 0.01], [0.3, 0.0]]), 0.1)
    assert pts.shape == (2, 2)


@pytest.mark.parametrize("bad, fix", [
    (dict(h_fine=0.0), "h_fine"), (dict(tol=-1.0), "tol"), (dict(band=0.6), "band"),
    (dict(check_every=0), "check_every"), (dict(refine_ratio=1.0), "refine_ratio"),
    (dict(coarsen_fraction=1.0), "coarsen_fraction"), (dict(refine_fraction=-0.1), "refine_fraction"),
])
def test_bad_adapt_parameters_are_named(bad, fix):
    args = dict(h_fine=0.05, radius=0.1, stress_scale=1e6)
    args.update(bad)
    with pytest.raises(ValueError, match=fix):
        Adapt(**args)


def test_a_refinement_is_not_a_local_patch():
    with pytest.raises(ValueError, match="whole domain"):
        fracture_mesh(MPI.COMM_WORLD, DOMAIN, previous=object(), patch_radius=0.1,
                      refine=[Refinement(((0.5, 0.0),), 0.05, 0.1)])


RUN_SCRIPT = """
import sys
sys.path.insert(0, {tests!r})
from test_adapt import ADAPT, AdaptDriver, _build
from hydrofrac.run import RunOptions, run
t_end, out, restart = float(sys.argv[1]), sys.argv[2], sys.argv[3] == "restart"
drv = AdaptDriver(_build, ADAPT)
run(drv.problem, RunOptions(t_end=t_end, out=out, frames=2, restart=restart))
"""


def test_an_adaptive_run_restarted_ends_as_the_straight_one(tmp_path, run_python):
    """The refinement levels and the crack history are in the checkpoint: a run stopped at
    100 us and restarted to 200 us ends with the straight run's mesh, counts and energies.
    (Each run is its own process: DOLFINx 0.5 meshes are not freed safely mid-process.)"""
    import json
    from pathlib import Path
    script = tmp_path / "adaptive_pulse.py"
    script.write_text(RUN_SCRIPT.format(tests=str(Path(__file__).parent)))
    run_python([str(script), "200e-6", str(tmp_path / "straight"), "no"])
    run_python([str(script), "100e-6", str(tmp_path / "split"), "no"])
    run_python([str(script), "200e-6", str(tmp_path / "split"), "restart"])
    straight, split = (json.loads((tmp_path / d / "summary.json").read_text()) for d in ("straight", "split"))
    assert split["cells"] == straight["cells"] and split["accuracy"] == straight["accuracy"]
    for k in ("kinetic", "strain", "work_in"):
        assert split["energy"][k] == pytest.approx(straight["energy"][k], rel=1e-12), k
    assert straight["accuracy"]["adaptive_remeshes"] >= 2


def test_the_intersection_runs_on_adaptive_meshes(tmp_path):
    """``intersection.py --premeshed --adapt H`` runs end to end: the mesh refines and coarsens
    as the pressure front moves, and the front still reaches the natural fracture."""
    from hydrofrac.loader import scenario
    summ = scenario("intersection").main(["--quick", "--premeshed", "--adapt", "0.06", "--t-end", "6e-4",
                                          "--out", str(tmp_path / "run")])
    acc = summ["accuracy"]
    assert acc["adaptive_refines"] >= 1 and acc["cells_max"] > acc["cells_min"]
    assert 0 < acc["intersection_time"] < 6e-4


def test_growth_on_adaptive_meshes_restarts_and_partitions_alike(tmp_path, run_command, mpirun):
    """Free growth with adaptive meshes (``intersection_regularized.py --quick --adapt 0.06
    --adapt-tol 0.03``: the default tolerance, with the cracks at the fine size and the gentle
    grading, refines nothing in this short run): tips grow and the indicators remesh the
    unchanged geometry too.  A run on 2 ranks and a run
    on 1 rank stopped at 1.0 ms and restarted to 1.2 ms grow the same paths with the same
    adaptive remeshes, and end with the same energies (the refinement points do not depend on
    the partition; the checkpoint holds the levels and the crack history)."""
    import json
    from pathlib import Path
    script = Path(__file__).resolve().parents[1] / "scenarios" / "intersection_regularized.py"
    args = ["--quick", "--adapt", "0.06", "--adapt-tol", "0.03", "--frames", "2"]
    run_command([*mpirun(2), script, *args, "--t-end", "1.2e-3", "--out", tmp_path / "two"], timeout=600)
    run_command([*mpirun(1), script, *args, "--t-end", "1.0e-3", "--out", tmp_path / "one"], timeout=600)
    run_command([*mpirun(1), script, *args, "--t-end", "1.2e-3", "--out", tmp_path / "one", "--restart"],
                timeout=600)
    a, b = (json.loads((tmp_path / d / "summary.json").read_text()) for d in ("two", "one"))
    ga, gb = (json.loads((tmp_path / d / "growth.json").read_text()) for d in ("two", "one"))
    acc = a["accuracy"]
    assert acc["extensions"] >= 3 and acc["adaptive_remeshes"] >= 1, acc
    for key in ("extensions", "remeshes", "adaptive_remeshes", "adaptive_refines", "adaptive_coarsens", "tips"):
        assert b["accuracy"][key] == acc[key], key
    assert a["cells"] == b["cells"] and len(ga["meshes"]) == len(gb["meshes"])
    for p, q in zip(ga["paths"], gb["paths"]):
        np.testing.assert_allclose(np.array(p), np.array(q), rtol=0, atol=1e-9)
    for k in ("kinetic", "strain", "work_in"):
        assert b["energy"][k] == pytest.approx(a["energy"][k], rel=1e-8), k


@pytest.mark.parametrize("name", ["intersection", "refracture"])
def test_adaptive_meshes_keep_the_cracks_at_the_fine_size(name):
    """The cracks of an adaptive mesh are meshed at h_fine by default, not coarser: the
    pressure front advances one crack vertex per update, and cracks at 2 h_fine cost the
    intersection time more than the coarser cracks save (docs/benchmarks.md, "Adaptive
    meshes: the cracks at the fine size").  The first mesh's crack facets are no longer than
    the fine size (Gmsh's sizes stay within 30 % of the field), while the far bulk is coarse."""
    from hydrofrac import wellbore
    from hydrofrac.loader import scenario
    h_fine = 0.08
    desc = scenario(name).description(quick=True, adapt=h_fine)
    problem = wellbore.setup(desc, MPI.COMM_SELF)[0]
    length = problem.interface.length
    assert length.size > 0
    assert length.max() < 1.3 * h_fine, (length.max(), h_fine)
    assert np.median(length) == pytest.approx(h_fine, rel=0.2)
    assert cell_sizes(problem.solver).max() > 4 * h_fine


def test_an_adaptive_mesh_keeps_the_static_meshs_time_step():
    """The far size of an adaptive mesh is reached within ``wellbore.ADAPT_GRADING`` (0.75 m) of
    the cracks: within 0.5 m, Gmsh made small cells at the crack ends, and the intersection's
    time step fell to 0.77 of the static graded mesh's at the same crack size (docs/benchmarks.md,
    "Adaptive meshes: the cracks at the fine size").  The first adaptive mesh (--quick, 6 cm)
    steps as the static one does, within 5 %."""
    from hydrofrac import wellbore
    from hydrofrac.loader import scenario
    ix = scenario("intersection")
    static = wellbore.setup(ix.description(quick=True), MPI.COMM_SELF)[0]
    adaptive = wellbore.setup(ix.description(quick=True, adapt=0.06), MPI.COMM_SELF)[0]
    assert adaptive.solver.dt >= 0.95 * static.solver.dt, (adaptive.solver.dt, static.solver.dt)
