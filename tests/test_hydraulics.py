"""Hydraulic load: connectivity (connected components), loaded state, pressure factor, Sneddon,
the intersection problems and bad input (issue 4; verification.md cases 11-12)."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hydrofrac import ROCK
from hydrofrac.boundary import PiecewiseLinear
from hydrofrac.hydraulics import (HydraulicParams, components, connected_factor, fluid_fill, loaded_facets,
                                  pressure_factor_vertices, wet_points)

ROOT = Path(__file__).resolve().parents[1]


# --------------------------------------------------------------------------- connectivity
def _network(edges):
    return np.array(edges, dtype=np.int64)


def test_t_junction_merges_and_loads():
    # perforation 0-1-2 (source), path 2-3, natural fracture 10-3-11 (T-junction at 3)
    E = _network([[0, 1], [1, 2], [2, 3], [10, 3], [3, 11], [20, 21]])
    source = np.array([1, 1, 0, 0, 0, 0], bool)
    # path not debonded yet: natural fracture is a separate, unloaded component
    active = np.array([1, 1, 0, 1, 1, 1], bool)
    roots = components(E, active)
    assert roots[0] == roots[1] and roots[3] == roots[4] and roots[0] != roots[3]
    assert roots[2] == -1
    np.testing.assert_array_equal(loaded_facets(E, active, source), [1, 1, 0, 0, 0, 0])
    # the path debonds: everything connected through vertex 2 and 3 is loaded, the isolated crack is not
    active[2] = True
    np.testing.assert_array_equal(loaded_facets(E, active, source), [1, 1, 1, 1, 1, 0])


def test_x_junction_and_two_sources():
    # two cracks crossing at vertex 5 (X-junction), one with a source; a second network with its own source
    E = _network([[1, 5], [5, 2], [3, 5], [5, 4], [7, 8], [8, 9]])
    source = np.array([1, 0, 0, 0, 0, 1], bool)
    active = np.ones(6, bool)
    roots = components(E, active)
    assert len(set(roots[:4])) == 1 and len(set(roots[4:])) == 1 and roots[0] != roots[4]
    assert loaded_facets(E, active, source).all()
    # without the source the second network is unloaded
    source[5] = False
    np.testing.assert_array_equal(loaded_facets(E, active, source), [1, 1, 1, 1, 0, 0])


def test_pressure_factor_uses_all_facets_at_a_vertex():
    # loaded perforation facet 0-1 wide open; natural fracture facets 1-2, 2-3 closed
    E = _network([[0, 1], [1, 2], [2, 3]])
    loaded = np.ones(3, bool)
    scale = np.full(3, 1e-6)
    ends = np.array([[5e-6, 5e-6], [-1e-8, -1e-8], [-1e-8, -1e-8]])
    fp = pressure_factor_vertices(E, loaded, ends, scale)
    # at vertex 1 the perforation's opening counts: the junction end of the NF facet is fully loaded
    np.testing.assert_allclose(fp[1], [1.0, 0.0])
    np.testing.assert_allclose(fp[2], [0.0, 0.0])
    # half the threshold aperture -> f_p = 0.5 (eq. 15)
    ends[1, 1] = 0.5e-6
    fp = pressure_factor_vertices(E, loaded, ends, scale)
    np.testing.assert_allclose(fp[2, 0], 0.5)
    # unloaded facets carry no load
    fp = pressure_factor_vertices(E, np.array([1, 0, 0], bool), ends, scale)
    np.testing.assert_allclose(fp[1:], 0.0)


def test_pressure_factor_through_connected_apertures():
    # perforation 0-1 (source), crack 1-2-3-4-5: closed at vertex 2, wide open beyond it (an
    # outer end that closes last), and a branch 3-6 open too
    E = _network([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [3, 6]])
    loaded = np.ones(6, bool)
    source = np.array([1, 0, 0, 0, 0, 0], bool)
    scale = np.full(6, 1e-6)
    ends = np.array([[5e-6, 5e-6], [3e-6, -1e-8], [-1e-8, 4e-6], [4e-6, 4e-6], [4e-6, 4e-6], [4e-6, 2e-6]])
    local = pressure_factor_vertices(E, loaded, ends, scale)
    conn = pressure_factor_vertices(E, loaded, ends, scale, source=source)
    # at each vertex alone (eq. 15) the open part beyond the closed vertex takes the full load
    np.testing.assert_allclose(local[3:], 1.0)
    # through connected apertures it takes none: no open path joins it to the wellbore
    np.testing.assert_allclose(conn[1], [1.0, 0.0])
    np.testing.assert_allclose(conn[2:], 0.0)
    # half open at vertex 2: everything beyond carries at most half
    ends[1, 1] = ends[2, 0] = 0.5e-6
    conn = pressure_factor_vertices(E, loaded, ends, scale, source=source)
    np.testing.assert_allclose(conn[1], [1.0, 0.5])
    np.testing.assert_allclose(conn[2:], 0.5)
    # a second, open route around the closed vertex (1-7-3) restores the load beyond it
    E2 = np.vstack([E, [[1, 7], [7, 3]]])
    ends2 = np.vstack([ends, [[4e-6, 4e-6], [4e-6, 4e-6]]])
    conn = pressure_factor_vertices(E2, np.ones(8, bool), ends2, np.full(8, 1e-6), source=np.r_[source, 0, 0] > 0)
    np.testing.assert_allclose(conn[3:6], 1.0)
    np.testing.assert_allclose(conn[1], [1.0, 0.5])  # the closed vertex itself stays as open as it is


def _random_networks(rng, max_vertices, max_facets, p_active, count=200):
    """``count`` random networks (E, active, source): repeated edges, self-loops, several
    sources among the active facets, vertex ids that are not 0..n-1."""
    for _ in range(count):
        nv, m = rng.integers(3, max_vertices), rng.integers(2, max_facets)
        E = rng.integers(0, nv, size=(m, 2)) * 7 + 3
        active = rng.random(m) < p_active
        yield E, active, (rng.random(m) < 0.15) & active


def test_connected_factor_is_the_widest_path():
    """Against a brute-force relaxation of max-min paths on random graphs (repeated edges,
    self-loops, several sources, unloaded facets)."""
    def brute(E, loaded, fp, source):
        b = {v: 0.0 for v in np.unique(E[loaded])}
        for i in np.flatnonzero(loaded & source):
            b[E[i, 0]] = b[E[i, 1]] = 1.0
        w = np.where(source, 1.0, fp.min(axis=1))
        for _ in range(len(b) + 2):
            for i in np.flatnonzero(loaded):
                u, v = E[i]
                b[v], b[u] = max(b[v], min(b[u], w[i])), max(b[u], min(b[v], w[i]))
        out = np.zeros_like(fp)
        for i in np.flatnonzero(loaded):
            out[i] = [b[E[i, 0]], b[E[i, 1]]]
        return out
    rng = np.random.default_rng(1)
    for E, loaded, source in _random_networks(rng, 30, 50, 0.8):
        fp = rng.random((E.shape[0], 2)) * (rng.random((E.shape[0], 2)) < 0.7)
        np.testing.assert_allclose(connected_factor(E, loaded, fp, source), brute(E, loaded, fp, source))


def test_the_network_numbered_once_gives_the_same_loaded_set_and_fill_order():
    """A network's vertex numbering, made once per mesh and passed as ``index``, gives the
    loaded facets and the fluid's fill order of the numbering made at each call: the same
    components (against a brute-force flood fill), the same distances bit for bit."""
    from hydrofrac.hydraulics import fill_order, vertex_index

    def flood(E, active, source):
        on = set(np.flatnonzero(active & source))
        grew = True
        while grew:
            verts = {v for i in on for v in E[i]}
            new = {i for i in np.flatnonzero(active) if E[i, 0] in verts or E[i, 1] in verts} - on
            on |= new
            grew = bool(new)
        return np.isin(np.arange(len(E)), sorted(on))
    rng = np.random.default_rng(4)
    for E, active, source in _random_networks(rng, 40, 60, 0.7):
        index = vertex_index(E)
        loaded = loaded_facets(E, active, source, index)
        np.testing.assert_array_equal(loaded, flood(E, active, source))
        np.testing.assert_array_equal(loaded, loaded_facets(E, active, source))
        L = rng.random(E.shape[0])
        for a, b in zip(fill_order(E, L, loaded, source, index), fill_order(E, L, loaded, source)):
            np.testing.assert_array_equal(a, b)


# --------------------------------------------------------------------------- a finite fluid volume
def test_fluid_fills_the_network_from_the_sources_outward():
    """docs/model.md, "A finite fluid volume": a volume V fills the loaded facets in the order
    of their distance along the network from the sources, each up to its capacity; the facet
    at the front is wet over the fraction V fills; the sources are always wet, the facets
    beyond the front, unloaded facets and facets not connected to a source are dry."""
    # source 0-1; arm A 1-2-3-4 (facets listed outward, the last one reversed: 4 -> 3), a
    # shorter arm B 1-5, an unloaded facet 5-6 and a loaded island 7-8 with no source
    E = _network([[0, 1], [1, 2], [2, 3], [4, 3], [1, 5], [5, 6], [7, 8]])
    L = np.array([1.0, 1.0, 1.0, 1.0, 0.5, 1.0, 1.0])
    loaded = np.array([1, 1, 1, 1, 1, 0, 1], bool)
    source = np.array([1, 0, 0, 0, 0, 0, 0], bool)
    cap = np.array([9.0, 2.0, 3.0, 4.0, 1.0, 1.0, 1.0])
    # order by distance: B (0.25: mean of 0 and 0.5), A1 (0.5), A2 (1.5), A3 (2.5)
    for V, want in [(0.0, [1, 0, 0, 0, 0, 0, 0]), (0.5, [1, 0, 0, 0, 0.5, 0, 0]),
                    (2.0, [1, 0.5, 0, 0, 1, 0, 0]), (4.5, [1, 1, 0.5, 0, 1, 0, 0]),
                    (8.0, [1, 1, 1, 0.5, 1, 0, 0]), (50.0, [1, 1, 1, 1, 1, 0, 0])]:
        wet, near = fluid_fill(E, L, loaded, source, cap, V)
        np.testing.assert_allclose(wet, want, err_msg=f"V = {V}")
    # the front facet 4 -> 3 fills from its end 3, the one nearer the source
    np.testing.assert_array_equal(near[1:5], [0, 0, 1, 0])


def test_wet_points_fill_each_facet_from_its_near_end():
    s_q = np.array([0.1127, 0.5, 0.8873])  # 3 Gauss points from va
    w = wet_points(np.array([0.5, 0.5, 1.0, 0.0]), np.array([0, 1, 0, 1]), s_q)
    np.testing.assert_allclose(w.mean(axis=1), [0.5, 0.5, 1.0, 0.0])  # the facet's fraction
    np.testing.assert_allclose(w[0], [1.0, 0.5, 0.0])  # from va
    np.testing.assert_allclose(w[1], [0.0, 0.5, 1.0])  # from vb


def test_dry_crack_carries_no_traction():
    """Eq. (16) behind the front, S = 0 (an unloaded crack's) beyond it: a dry point neither
    carries p_h nor the compressive bonded traction that holds a loaded, closing crack open."""
    from hydrofrac import riemann as rm
    fp = np.array([[1.0, 0.25]])
    S0, cS = rm.hydraulic_law(fp, np.array([True]), wet=np.array([[1.0, 0.0]]))
    np.testing.assert_allclose(S0[..., 0], [[-1.0, 0.0]])
    np.testing.assert_allclose(cS, [[0.0, 0.0]])
    S0, cS = rm.hydraulic_law(fp, np.array([True]))
    np.testing.assert_allclose(cS, [[0.0, -0.75]])


# --------------------------------------------------------------------------- the compiled update
@pytest.mark.parametrize("nq", [1, 2, 3, 4, 7, 8, 9, 16, 19])
def test_the_compiled_update_has_the_bits_of_the_numpy_formulas(nq):
    """Hydraulics.update's compiled passes give every bit the array formulas give (the row sums
    in numpy's pairwise order, the fluid front from numpy's running sum, the load at the Gauss
    points, eq. (16)): a last-digit change in the capacity or the front moves a re-fracture's
    network (docs/benchmarks.md, "The hydraulic update in three compiled passes")."""
    from hydrofrac import riemann as rm
    from hydrofrac.hydraulics import _fill, _point_loads, _send_rows
    rng = np.random.default_rng(nq)
    m = 400
    D = np.clip(rng.random((m, nq)) * 1.02, 0, 1)
    D[::7] = 0.99 + 1e-17 * rng.standard_normal((len(D[::7]), nq))  # means at the threshold
    op = rng.standard_normal((m, nq)) * 10.0 ** rng.uniform(-9, -3, (m, nq))
    w = rng.random((m, nq)) * 10.0 ** rng.uniform(-3, 0, (m, 1))
    source = rng.random(m) < 0.1
    floor = 1e-6 * rng.random(m)
    send = np.empty((m, 4))
    _send_rows(D, op, w, np.ones((m, nq)), source, 0.99, floor, send)
    np.testing.assert_array_equal(send[:, 0] > 0.5, (D.mean(axis=1) >= 0.99) | source)
    np.testing.assert_array_equal(send[:, 1:3], np.stack([op[:, 0], op[:, -1]], axis=1))
    np.testing.assert_array_equal(send[:, 3], np.maximum((op * w).sum(axis=1), floor))
    # the fluid's front
    loaded = rng.random(m) < 0.8
    order = rng.permutation(np.flatnonzero(loaded & ~source))
    cap = send[:, 3]
    for V in (0.0, 0.3 * cap[order].sum(), 2 * cap.sum()):
        wet = np.empty(m)
        _fill(order, cap, loaded, source, V, wet)
        want = np.zeros(m)
        want[loaded & source] = 1.0
        c = cap[order]
        before = np.cumsum(c) - c
        want[order] = np.clip((V - before) / np.maximum(c, 1e-300), 0.0, 1.0)
        np.testing.assert_array_equal(wet, want)
    # the load at the Gauss points
    s, _ = np.polynomial.legendre.leggauss(nq)
    s_q = 0.5 * (s + 1)
    rank = np.argsort(np.argsort(s_q))
    fp_ends = rng.random((m, 2))
    near = (rng.random(m) < 0.5).astype(np.int64)
    for regularized in (True, False):
        for volume in (True, False):
            out = [np.empty((m, nq)) for _ in range(3)] + [np.empty((m, nq, 2)), np.empty((m, nq))]
            _point_loads(fp_ends, regularized, 1 - s_q, s_q, source, loaded, volume, wet, near, rank, *out)
            fp = fp_ends[:, :1] * (1 - s_q) + fp_ends[:, 1:] * s_q if regularized else np.ones((m, nq))
            fp[source & regularized] = 1.0
            fp[~loaded] = 0.0
            wq = np.clip(wet[:, None] * nq - np.where(near[:, None] == 0, rank, nq - 1 - rank), 0.0, 1.0)
            np.testing.assert_array_equal(out[0], fp)
            on = loaded[:, None] * (wq if volume else 1.0)
            np.testing.assert_array_equal(out[3][..., 0], -on * fp)
            np.testing.assert_array_equal(out[3][..., 1], 0.0)
            np.testing.assert_array_equal(out[4], -on * (1.0 - fp))
            if volume:
                np.testing.assert_array_equal(out[1], wq)
                np.testing.assert_array_equal(out[2], fp * wq)
    S0, cS = rm.hydraulic_law(fp, loaded)
    np.testing.assert_array_equal(cS, -(loaded[:, None] * 1.0) * (1.0 - fp))
    # each facet's mean f_p, which the monitors read every step: ndarray.mean's bits
    from types import SimpleNamespace
    from hydrofrac.hydraulics import Hydraulics
    fp_q = rng.random((m, nq))
    hyd = SimpleNamespace(fp_q=fp_q, iface=SimpleNamespace(nq=nq))
    np.testing.assert_array_equal(Hydraulics.facet_fp(hyd), fp_q.mean(axis=1))


# --------------------------------------------------------------------------- bad input
def test_bad_hydraulic_parameters():
    with pytest.raises(ValueError, match="increase strictly"):
        PiecewiseLinear([0.0, 2e-6, 1e-6], [1.0, 2.0, 3.0])
    p = PiecewiseLinear([0.0, 1e-6], [2.425e6, 19.4e6])
    for bad in (0.0, -0.1, 1.5):
        with pytest.raises(ValueError, match="delta_bar"):
            HydraulicParams(pressure=p, sources=[100], delta_bar=bad)
    with pytest.raises(ValueError, match="sources"):
        HydraulicParams(pressure=p, sources=[])
    with pytest.raises(ValueError, match="volume"):
        HydraulicParams(pressure=p, sources=[100], volume=PiecewiseLinear([0.0, 1.0], [0.0, -1.0]))


def test_bad_geometry_is_rejected_before_meshing():
    from mpi4py import MPI

    from hydrofrac.meshes.fractures import Domain, Fracture, Perforation, fracture_mesh
    dom = Domain(half_width=2.0, half_height=2.0, wellbore_radius=0.1, h_crack=0.1, h_far=0.5)
    with pytest.raises(ValueError, match="outside the domain"):
        fracture_mesh(MPI.COMM_WORLD, dom, perforations=[Perforation(0.0, 5.0)])
    with pytest.raises(ValueError, match="outside the domain"):
        fracture_mesh(MPI.COMM_WORLD, dom, fractures=[Fracture((1.0, 0.0), 90.0, 4.5)])
    with pytest.raises(ValueError, match="crosses itself"):
        fracture_mesh(MPI.COMM_WORLD, dom, paths=[np.array([[0.5, 0.5], [1.0, 0.5], [0.8, 0.8], [0.8, 0.2]])])
    with pytest.raises(ValueError, match="enters the wellbore"):
        fracture_mesh(MPI.COMM_WORLD, dom, fractures=[Fracture((0.0, 0.0), 0.0, 1.0)])


def test_gmsh_failure_saves_geometry(tmp_path):
    from mpi4py import MPI

    from hydrofrac.meshes.gmsh_util import build_mesh

    def bad(model):
        model.occ.addRectangle(0, 0, 0, 1, 1)
        model.occ.synchronize()
        model.addPhysicalGroup(2, [1], 1)
        model.mesh.field.setNumber(model.mesh.field.add("Distance"), "NoSuchOption", 1.0)  # Gmsh raises

    with pytest.raises(RuntimeError, match="failed_geometry"):
        build_mesh(MPI.COMM_WORLD, bad, name="bad", out=tmp_path)
    assert list(tmp_path.glob("failed_geometry.*"))


# --------------------------------------------------------------------------- scenarios
def _run(script, tmp_path, *args):
    out = tmp_path / Path(script).stem
    cmd = [sys.executable, str(ROOT / "scenarios" / script), "--quick", "--out", str(out), *args]
    subprocess.run(cmd, check=True, cwd=ROOT, capture_output=True, text=True)
    return json.loads((out / "summary.json").read_text()), out


@pytest.mark.parametrize("p0", [2.425e6, 0.0], ids=["confined", "unconfined"])
def test_sneddon_opening(tmp_path, p0):
    """Case 11: static opening of a pressurised crack within 2 % (L2, |x| < 0.9a), under the
    confinement p0 = 2.425 MPa with net pressure p_h - p0 = 1 MPa, and unconfined."""
    s, _ = _run("sneddon.py", tmp_path, "--p0", str(p0))
    acc = s["accuracy"]
    assert acc["opening_centre_exact"] == pytest.approx(0.192e-3, rel=2e-3)
    assert acc["opening_L2_rel_error"] < 0.02, acc


@pytest.fixture(scope="module")
def intersections(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ix")
    return {mode: _run(f"intersection_{mode}.py", tmp) for mode in ("regularized", "unregularized")}


def test_intersection_free_growth_stays_radial_and_joins(intersections):
    """The scenarios' default: free growth, kink angle from the crack's opening and slip
    (under-relaxed by 0.5).  By the 4-fold symmetry of the perforations the exact paths
    are radial until the 0° crack nears the natural fracture: every segment within 5° of
    radial (the tolerance of a predicted kink angle), every path within 2° overall (the
    mode-I tolerance), 2 or more extensions per tip that does not meet the fracture (under
    the 1 ms ramp, by 1.3 ms); the 0° crack meets the natural fracture, the others do not
    reach anything."""
    from hydrofrac.loader import scenario
    x_nf = scenario("intersection").X_NF_QUICK
    for mode, (s, out) in intersections.items():
        g = json.loads((out / "growth.json").read_text())
        assert [j["tip"] for j in g["joined"]] == [0], (mode, g["joined"])
        assert g["joined"][0]["point"][0] == pytest.approx(x_nf, abs=1e-9)
        for i, path in enumerate(g["paths"][:4]):  # the perforation tips (then the natural fracture's)
            p = np.array(path)
            assert len(p) >= (2 if i == 0 else 3), (mode, i, len(p) - 1)
            radial = p[0] / np.linalg.norm(p[0])
            seg = np.diff(p, axis=0)
            ang = np.degrees(np.arctan2(seg[:, 0] * radial[1] - seg[:, 1] * radial[0], seg @ radial))
            assert np.abs(ang).max() < 5.0, (mode, i, ang)
            total = p[-1] - p[0]
            assert abs(np.degrees(np.arctan2(total[0] * radial[1] - total[1] * radial[0], total @ radial))) < 2.0
        assert s["accuracy"]["remeshes"] >= 5 and s["accuracy"]["joined"] == 1


def test_natural_fracture_tips_grow_once_loaded(tmp_path):
    """Every free crack end is a tip (``--growth-natural-tips``): the natural fracture's two ends
    grow by the same criterion, on their own state.  Under the confinement they wait; once the
    hydraulic load has entered the fracture they grow, away from the wellbore side (the paper's
    figs. 8c, 9c)."""
    for mode, (s, out) in {"unregularized": _run("intersection_unregularized.py", tmp_path,
                                                 "--growth-natural-tips")}.items():
        g = json.loads((out / "growth.json").read_text())
        t_load = s["accuracy"]["intersection_time"]
        nf_tips = [4, 5]
        first = {i: min((e["t"] for e in g["events"] if e["tip"] == i), default=None) for i in nf_tips}
        assert all(t is not None and t > t_load for t in first.values()), (mode, first, t_load)
        for i in nf_tips:
            p = np.array(g["paths"][i])
            seg = p[-1] - p[0]  # beyond the fracture's line, outward: a clear +x component
            assert seg[0] > 0.2 * np.linalg.norm(seg), (mode, i, p)
            assert abs(p[-1][1]) > abs(p[0][1]), (mode, i, p)  # and beyond its end


def test_intersection_happens_near_paper_time(intersections):
    """--quick (its own fracture distance, 0.52 m: coarser cracks grow later): the
    intersection within 700-1050 µs, on the 1 ms ramp (p_h between 14.3 and 19.4 MPa)."""
    for mode, (s, _) in intersections.items():
        t = s["accuracy"]["intersection_time"]
        assert 700e-6 < t < 1050e-6, (mode, t)
        assert s["accuracy"]["p_h_at_intersection"] == pytest.approx(2.425e6 + 16.975e6 * min(t / 1e-3, 1.0),
                                                                     rel=1e-9)
        assert abs(s["energy"]["balance_error_relative"]) < 1e-2, (mode, s["energy"])


def test_intersection_at_the_papers_time_and_pressure_full_size(tmp_path, run_command):
    """Full size, 2 ranks, to the intersection: the paper states that at the intersection,
    ≈ 800 µs, p_h ≈ 16 MPa (docs/model.md); within 10 % of both (the paper's ≈, and our own
    choice of the fracture's distance, which moves the time in steps of one extension)."""
    out = tmp_path / "full"
    cmd = ["mpirun", "--oversubscribe", "-n", "2", sys.executable, str(ROOT / "scenarios" / "intersection_regularized.py"),
           "--t-end", "8.5e-4", "--frames", "2", "--out", str(out)]
    run_command(cmd)
    acc = json.loads((out / "summary.json").read_text())["accuracy"]
    assert acc["intersection_time"] == pytest.approx(800e-6, rel=0.1), acc
    assert acc["p_h_at_intersection"] == pytest.approx(16.0e6, rel=0.1), acc


def test_natural_fracture_branches_loaded_only_behind_the_front_full_size(tmp_path, run_command):
    """Full size, 2 ranks, to 1.35 ms (the scenario's defaults: the natural fracture's ends are
    tips, the pressure factor goes through connected apertures).  Its ends grow once the
    crack's stress reaches them; the cracks grown from an end carry load (f_p > 0.5) only
    once the load front along the fracture has reached that end (within 0.1 m of it):
    hydraulic load cannot pass a closed part of the network (docs/model.md, "The pressure
    factor through connected apertures").  With the factor at each vertex alone
    (``--pressure-factor local``) a branch was loaded 93 µs ahead of the front (measured)."""
    out = tmp_path / "full"
    cmd = ["mpirun", "--oversubscribe", "-n", "2", sys.executable, str(ROOT / "scenarios" / "intersection_regularized.py"),
           "--t-end", "1.35e-3", "--frames", "2", "--out", str(out)]
    run_command(cmd)
    acc = json.loads((out / "summary.json").read_text())["accuracy"]
    g = json.loads((out / "growth.json").read_text())
    assert {e["tip"] for e in g["events"]} >= {4, 5}, "the natural fracture's ends did not grow"
    for k in range(2):
        t_end, t_branch = acc[f"nf_end{k}_loaded_time"], acc[f"nf_end{k}_branch_loaded_time"]
        print(f"end {k}: end zone loaded at {t_end * 1e6:.1f} µs, its branch at {t_branch * 1e6:.1f} µs")
        assert np.isfinite(t_end) and np.isfinite(t_branch), acc
        assert t_branch >= t_end, (k, t_end, t_branch)


def test_pressure_factor_spreads_from_the_junction(intersections):
    """Regularised: the loaded length on the natural fracture grows over many steps (history rows
    are written every step), never a quarter of the fracture in one step; unregularised: the
    whole fracture is loaded at connection."""
    import csv
    s, out = intersections["regularized"]
    rows = list(csv.DictReader(open(out / "history.csv")))
    L = np.array([float(r["nf_loaded_length"]) for r in rows])
    total = s["accuracy"]["nf_length"]
    jumps = np.diff(L)
    assert L.max() > 0.2 * total
    assert jumps.max() < 0.25 * total, jumps.max()
    s, out = intersections["unregularized"]
    rows = list(csv.DictReader(open(out / "history.csv")))
    L = np.array([float(r["nf_loaded_length"]) for r in rows])
    first = np.argmax(L > 0)
    assert L[first] == pytest.approx(total, rel=1e-9)


def test_regularisation_velocity_spike_measured(intersections):
    """The velocity spike of the natural fracture more than 0.25 m from the junction, within
    50 µs after intersection, in both modes (the same problem until the connection, so they
    must intersect at the same time): the peak opening rate of its faces and their peak
    particle speed.  Unregularised, the whole fracture is loaded at once and opens at once;
    regularised, the load has not reached that part yet: it stays closed, and its faces move
    with the waves only.  The measured numbers are printed and reported in docs/studies/scenarios.md."""
    reg = intersections["regularized"][0]["accuracy"]
    unreg = intersections["unregularized"][0]["accuracy"]
    assert reg["intersection_time"] == unreg["intersection_time"]
    ro, uo = reg["nf_peak_opening_rate_50us"], unreg["nf_peak_opening_rate_50us"]
    rv, uv = reg["nf_peak_velocity_50us"], unreg["nf_peak_velocity_50us"]
    print(f"natural fracture > 0.25 m from the junction, 50 µs after intersection: peak opening rate "
          f"unregularised {uo:.4f} m/s, regularised {ro:.4f} m/s; peak particle speed unregularised {uv:.4f} m/s, "
          f"regularised {rv:.4f} m/s (ratio {uv / rv:.3f})")
    assert all(np.isfinite([ro, uo, rv, uv])) and rv > 0
    # unregularised: the suddenly applied pressure opens the whole fracture
    assert uo > 0.1 * (unreg["p_h_at_intersection"] - 2.425e6) / ROCK.Zd, uo
    assert ro < uo and rv < uv, (ro, uo, rv, uv)


def test_growth_speed_limit(intersections, tmp_path):
    """``--growth-max-speed`` bounds every tip's speed (the default growth, limited only by the
    check interval and the debonding of the last segment, runs faster than that)."""
    free = intersections["regularized"][0]["accuracy"]["tip_speed_max"]
    s, out = _run("intersection_regularized.py", tmp_path, "--growth-max-speed", "300")
    speeds = [e["speed"] for e in json.loads((out / "growth.json").read_text())["events"] if e["speed"]]
    assert free > 300 and speeds and max(speeds) <= 300 * (1 + 1e-9), (free, max(speeds))


@pytest.mark.mpi
@pytest.mark.parametrize("connected", [False, True], ids=["local", "connected"])
def test_pressure_factor_same_on_1_and_2_ranks(connected):
    """Case 6 for the hydraulic update: the network's fixed data are gathered once per mesh and
    its state once per step (one Allgatherv); f_p at every Gauss point of the re-fracture's
    pre-meshed network (every facet debonded, openings varying along the cracks from closed to
    wide open) is the same on COMM_WORLD as on one rank, matched by coordinates."""
    from mpi4py import MPI
    sys.path.insert(0, str(ROOT / "scenarios"))
    import refracture

    def factors(comm):
        problem = refracture.setup(comm, quick=True, degree=1, connected=connected, pump_rate=float("inf"))
        iface, hyd = problem.interface, problem.hydraulics
        xq = iface.va[:, None, :] + hyd.s_q[None, :, None] * (iface.vb - iface.va)[:, None, :]
        iface.state[0][:] = 1.0
        iface.state[1][:] = iface.delta_scale[:, None] * 0.2 * (np.sin(9 * xq[..., 0]) + np.cos(7 * xq[..., 1]))
        hyd.update()
        pts = np.concatenate(comm.allgather(xq.reshape(-1, 2)))
        fp = np.concatenate(comm.allgather(hyd.fp_q.reshape(-1)))
        order = np.lexsort(np.round(pts / 1e-9).T[::-1])
        return pts[order], fp[order]

    comm = MPI.COMM_WORLD
    pts_n, fp_n = factors(comm)
    pts_1, fp_1 = factors(MPI.COMM_SELF)
    assert 0.05 < (fp_1 == 1.0).mean() < 0.95 and ((fp_1 > 0) & (fp_1 < 1)).any()  # all three regimes
    np.testing.assert_allclose(pts_n, pts_1, atol=1e-12)
    np.testing.assert_array_equal(fp_n, fp_1)
