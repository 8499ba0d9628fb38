"""Probes: fields at points (exact for fields in the DG space, the same on 1 and 2 ranks),
probes.csv of a scenario against the two-bar answer (verification case 9), crack probes."""
import csv
import sys

import numpy as np
import pytest
from mpi4py import MPI

from conftest import ROOT
from hydrofrac import ROCK, compat
from hydrofrac.probes import field_at, parse_points
from hydrofrac.solver import Solver


def quadratic(x):
    return np.vstack([1 + x[0] * x[1], x[0] ** 2 - 2 * x[1], 3 * x[0] - x[1] ** 2, x[0] * x[1] + 0.5, -x[1]])


def check_field_at():
    mesh = compat.create_rectangle(MPI.COMM_WORLD, (0.0, 0.0), (1.0, 1.0), 5, 4)
    solver = Solver(mesh, 2, ROCK)
    solver.set_initial_state(quadratic)
    rng = np.random.default_rng(1)
    pts = np.r_[rng.uniform(0, 1, size=(40, 2)), [[0.2, 0.25], [0.4, 0.5], [0.0, 0.0]]]  # some on facets/vertices
    got = field_at(solver, pts)
    np.testing.assert_allclose(got, quadratic(pts.T).T, rtol=1e-10, atol=1e-12)
    assert np.all(np.isnan(field_at(solver, [[2.0, 0.5]])))  # outside: NaN, on every rank


def test_field_at_is_exact_for_fields_in_the_space():
    check_field_at()


def check_point_sets_located_together(monkeypatch):
    """Several point sets (the growth criterion's, one per tip): the sets not located yet on
    this mesh are located in one query (and one reduction), the others come from the cache,
    and every set gets the values it gets alone."""
    import hydrofrac.probes as pr
    mesh = compat.create_rectangle(MPI.COMM_WORLD, (0.0, 0.0), (1.0, 1.0), 5, 4)
    solver = Solver(mesh, 2, ROCK)
    solver.set_initial_state(quadratic)
    rng = np.random.default_rng(2)
    sets = [rng.uniform(0, 1, size=(n, 2)) for n in (7, 5, 9)]
    alone = [field_at(solver, X) for X in sets]  # (a solver of its own: each set located alone)
    solver = Solver(mesh, 2, ROCK)
    solver.set_initial_state(quadratic)
    queries = []
    real = pr.compat.cells_containing
    monkeypatch.setattr(pr.compat, "cells_containing", lambda m, X, c=None: queries.append(len(X)) or real(m, X, c))
    field_at(solver, sets[1])
    got = pr.fields_at(solver, sets)
    assert queries == [5, 16]  # the second set alone, then the two others together
    for g, a in zip(got, alone):
        np.testing.assert_array_equal(g, a)
    assert pr.fields_at(solver, sets[::-1]) and queries == [5, 16]  # all cached now


def test_point_sets_located_together(monkeypatch):
    check_point_sets_located_together(monkeypatch)


@pytest.mark.mpi
def test_point_sets_located_together_mpi(monkeypatch):
    check_point_sets_located_together(monkeypatch)


@pytest.mark.mpi
def test_field_at_is_exact_for_fields_in_the_space_mpi():
    check_field_at()


def test_points_are_located_in_a_tree_of_the_cells_near_them(monkeypatch):
    """A point set (the growth criterion's circle of samples around a tip) is located in a
    bounding-box tree of the owned cells whose boxes meet the set's box only: the same cells,
    hence the same values, as the tree of all cells, from a tree of fewer cells."""
    import hydrofrac.probes as pr
    mesh = compat.create_rectangle(MPI.COMM_WORLD, (0.0, 0.0), (1.0, 1.0), 16, 16)
    solver = Solver(mesh, 2, ROCK)
    solver.set_initial_state(quadratic)
    a = np.radians(np.linspace(-85, 85, 121))
    circle = np.column_stack([0.5 + 0.05 * np.cos(a), 0.5 + 0.05 * np.sin(a)])
    circle = np.vstack([circle, [[0.5, 0.5], [0.5 + 1 / 16, 0.5]]])  # a vertex and a point on an edge
    trees = []
    real = pr.compat.cells_containing
    monkeypatch.setattr(pr.compat, "cells_containing", lambda m, X, c=None: trees.append(c) or real(m, X, c))
    got = field_at(solver, circle)
    nloc = compat.num_cells_local(mesh)
    assert 0 < len(trees[0]) < nloc / 10
    pts, cells = real(mesh, circle)  # the tree of all cells
    own = cells < nloc
    assert sorted(zip(pts[own], cells[own])) == sorted(zip(*real(mesh, circle, trees[0])))
    np.testing.assert_allclose(got, quadratic(circle.T).T, rtol=1e-10, atol=1e-12)


def test_probe_points_are_checked():
    with pytest.raises(ValueError, match="x,y;x,y"):
        parse_points("1,2;3")


def test_two_bars_probe_against_the_exact_answer(tmp_path, run_python):
    """x = -0.5 m: at rest with sigma_xx = -Z_d v0 once the compression wave from the contact
    has passed (0.5/c_d) and until the release from the free end returns (1.5/c_d); moving at
    -v0 after separation (case 9: stress 1 %, velocity 0.5 %)."""
    out = tmp_path / "r"
    run_python([ROOT / "scenarios" / "two_bars.py", "--quick", "--frames", "1", "--out", out,
                "--probes=-0.5,0.00625"], timeout=300)
    rows = list(csv.DictReader(open(out / "probes.csv")))
    t = np.array([float(r["t"]) for r in rows])
    vx = np.array([float(r["p0_v_x"]) for r in rows])
    sxx = np.array([float(r["p0_s_xx"]) for r in rows])
    assert np.all(np.diff(t) > 0) and len(rows) > 100
    plateau = (t > 0.6 / ROCK.cd) & (t < 1.4 / ROCK.cd)
    assert abs(np.mean(sxx[plateau]) / (-ROCK.Zd * 1.0) - 1) < 0.01
    assert np.abs(np.mean(vx[plateau])) < 0.01
    assert abs(vx[-1] + 1.0) < 0.005


def test_crack_probe_reads_the_interface_state():
    """Sneddon's crack (D = 1, hydraulically loaded) after the pressure ramp has started: the
    crack probe gives D = 1, f_p = 1, the interface's own opening at a Gauss point's arc
    length, and a wider opening at the centre than near a tip (serial: the Gauss point is
    this rank's)."""
    from hydrofrac.loader import scenario
    from hydrofrac.probes import CRACK_FIELDS
    sn = scenario("sneddon")
    problem = sn.setup(degree=1, size=4.0, h_crack=0.2, h_far=1.0)
    for _ in range(20):
        problem.solver.step()
        problem.after_step()
    tag = problem.network.cracks[0].tag
    iface = problem.interface
    x_q = iface.points.reshape(-1, 2)[7, 0]  # a Gauss point; the crack runs from (-1, 0) to (1, 0)
    got = problem.crack_probe([(tag, 1.0), (tag, 0.05), (tag, x_q + 1.0)])
    col = {k: i for i, k in enumerate(CRACK_FIELDS)}
    np.testing.assert_allclose(got[:, col["D"]], 1.0)
    np.testing.assert_allclose(got[:, col["f_p"]], 1.0)
    assert got[2, col["opening"]] == iface.state[1].reshape(-1)[7]
    assert got[0, col["opening"]] > got[1, col["opening"]] > 0  # wider at the centre than near a tip
    with pytest.raises(ValueError, match="no crack with tag"):
        problem.crack_probe([(12345, 0.0)])
