"""Crossing or arrest of a crack at a natural fracture (docs/model.md §6, "Crossing or
arrest"), in the ``crossing`` scenario: a debonded crack ends on a closed natural fracture
normal to it, under remote tension T = 0.7 MPa normal to the crack and compression
P = 1 MPa across the fracture; the far-side criterion (tensile, β = 0) is evaluated in the
stress the fracture's interface transmits.

* a bonded fracture (D = 0) is crossed;
* a frictionless debonded one arrests the crack (it transmits no shear; the far side stays
  at the remote T = 0.7 MPa, below the onset s_ = 1 MPa), for the whole 0.9 ms;
* friction decides through the stick and slip solutions.  Renshaw & Pollard's (1995)
  criterion for a crack normal to a frictional interface, -σ_n / (T0 - σ_p) >
  (0.35 + 0.35/μ)/1.06 with σ_n = -P, σ_p = T, T0 = s_, gives μ_c = 0.11: μ = 0.05 must
  arrest and μ = 0.3 must cross;
* 1 and 2 ranks give the same outcome at the same step;
* a tip that would stop just short of a crack (closer than da/4) meets it: a thinner gap
  made a sliver cell and a 5e-11 s step.
"""
from types import SimpleNamespace

import numpy as np
import pytest
from mpi4py import MPI

from hydrofrac.growth import SNAP, GrowthDriver, GrowthParams, Tip, renshaw_pollard_friction
from hydrofrac.loader import scenario


def crossing_run(friction, damage=1.0, angle=90.0, comm=MPI.COMM_WORLD, t_end=9e-4):
    sc = scenario("crossing")
    problem = sc.setup(comm, angle=angle, friction=friction, damage=damage)
    while problem.solver.t < t_end * (1 - 1e-12) and sc.outcome(problem.growth)[0] != "crossed":
        problem.solver.step()
        new = problem.growth(problem)
        problem = new if new is not None else problem
    return problem.growth, sc.outcome(problem.growth)


def test_renshaw_pollard_threshold():
    assert renshaw_pollard_friction(-1.0e6, 0.7e6, 1.0e6) == pytest.approx(0.11, abs=0.005)


def test_bonded_fracture_is_crossed():
    drv, (what, t) = crossing_run(0.0, damage=0.0)
    assert what == "crossed"
    assert drv.counts()["crossings"] == 1 and drv.counts()["arrests"] == 0
    child = [e for e in drv.tree if e["event"] == "crossing"][0]["child"]
    p = np.array(drv.paths[child])
    assert p[0][0] == pytest.approx(0.06, abs=1e-9) and p[-1][0] > 0.06  # starts on it, goes beyond


def test_frictionless_fracture_arrests():
    drv, (what, _) = crossing_run(0.0)
    assert what == "arrested" and drv.counts()["arrests"] == 1 and drv.counts()["crossings"] == 0
    assert drv.tips[0].active is False


@pytest.mark.parametrize("mu, want", [(0.05, "arrested"), (0.3, "crossed")])
def test_friction_decides_through_the_riemann_solutions(mu, want):
    assert crossing_run(mu)[1][0] == want


@pytest.mark.mpi
def test_crossing_same_on_one_and_two_ranks():
    par = crossing_run(0.3, comm=MPI.COMM_WORLD)
    ser = crossing_run(0.3, comm=MPI.COMM_SELF)
    assert par[1][0] == ser[1][0] == "crossed"
    assert par[1][1] == pytest.approx(ser[1][1], rel=1e-9)
    assert par[0].counts() == ser[0].counts()


def test_tip_just_short_of_a_crack_meets_it():
    d = GrowthDriver(lambda polylines: SimpleNamespace(), [Tip(np.array([0.0, 0.0]), np.array([1.0, 0.0]))],
                     GrowthParams(r=0.1), da=0.2, threshold=1.0, tags=[300],
                     obstacles=[np.array([[0.3, -1.0], [0.3, 1.0]]), np.array([[0.0, 0.5], [0.5, 0.5]])])
    # ends 0.5 µm short of the fracture at x = 0.3: meets it where its extension crosses
    hit, tangent = d._crossing(np.array([0.1, 0.0]), np.array([0.2999995, 0.0]), 0)
    np.testing.assert_allclose(hit, [0.3, 0.0]) and np.testing.assert_allclose(np.abs(tangent), [0.0, 1.0])
    assert d._crossing(np.array([0.1, 0.0]), np.array([0.3 - 1.01 * SNAP * 0.2, 0.0]), 0) is None
    # ends beside the end of the other crack (0.5, 0.5): meets it at that end
    hit, _ = d._crossing(np.array([0.6, 0.3]), np.array([0.52, 0.49]), 0)
    np.testing.assert_allclose(hit, [0.5, 0.5])


def test_a_tip_that_starts_on_a_crack_is_arrested():
    d = GrowthDriver(lambda polylines: SimpleNamespace(), [Tip(np.array([0.3, 0.2]), np.array([1.0, 0.0])),
                                                          Tip(np.array([0.0, 0.0]), np.array([1.0, 0.0]))],
                     GrowthParams(r=0.1), da=0.2, threshold=1.0, tags=[300, 301],
                     obstacles=[np.array([[0.3, -1.0], [0.3, 1.0]])])
    assert list(d.arrested) == [0] and not d.tips[0].active and d.tips[1].active
    # a crack's own end (a natural fracture's tip growing from it) is no crack met
    d = GrowthDriver(lambda polylines: SimpleNamespace(), [Tip(np.array([0.3, 1.0]), np.array([0.0, 1.0]))],
                     GrowthParams(r=0.1), da=0.2, threshold=1.0, tags=[300],
                     obstacles=[np.array([[0.3, -1.0], [0.3, 1.0]])])
    assert d.arrested == {} and d.tips[0].active


def test_a_crossing_tip_does_not_meet_the_crack_it_starts_on():
    """A tip that starts on a crack (a crossing) sits on it only to the 1 nm snap of the points;
    its first segment leaves the crack at an angle and must not meet it at its own start (that
    made a zero-length segment, which Gmsh cannot mesh)."""
    d = GrowthDriver(lambda polylines: SimpleNamespace(), [Tip(np.array([0.0, 0.0]), np.array([1.0, 0.0]))],
                     GrowthParams(r=0.1), da=0.1, threshold=1.0, tags=[300],
                     obstacles=[np.array([[0.3, -1.0], [0.3, 1.0]])])
    p = np.array([0.3 - 4e-10, 0.2])  # on the crack x = 0.3 to within 1 nm, on the near side
    d.paths[0] = [np.array([0.0, 0.2]), p]
    d.paths.append([p.copy()])
    d.tips.append(Tip(p.copy(), np.array([np.cos(0.3), np.sin(0.3)])))
    d.tags.append(301)
    q = p + 0.1 * np.array([np.cos(0.3), np.sin(0.3)])
    assert d._crossing(p, q, 1) is None


def test_a_tip_next_to_a_crack_stops_instead_of_making_a_sliver():
    """A tip whose next segment would meet another crack within SNAP * Δa of the tip (a tip that
    starts on one crack beside another) stops where it is, for good: no segment (a 0.3 mm one
    cut the full-size re-fracture's step 1000x), no arrest that could cross."""
    from types import SimpleNamespace as NS
    da = 0.2
    d = GrowthDriver(lambda polylines: NS(), [Tip(np.array([0.0, 0.0]), np.array([1.0, 0.0]))],
                     GrowthParams(r=0.1), da=da, threshold=1.0, tags=[300],
                     obstacles=[np.array([[0.3, -1.0], [0.3, 1.0]])])
    start = np.array([0.3 - 0.1 * SNAP * da, 0.0])  # 0.1 SNAP Δa short of the crack at x = 0.3
    d.paths[0] = [np.array([0.0, 0.0]), start]
    d.tips[0].point = start.copy()
    d._extend(NS(t=1e-3), 0, start + np.array([da, 0.0]), 0.0, 2e6)
    assert len(d.paths[0]) == 2 and not d.tips[0].active and 0 not in d.arrested
    np.testing.assert_allclose(d.tips[0].point, start)
    assert d.tree[-1]["event"] == "arrest" and d.events == []
    # a tip farther away than SNAP * Δa still reaches the crack and is arrested on it (it may cross)
    start = np.array([0.3 - 2 * SNAP * da, 0.0])
    d = GrowthDriver(lambda polylines: NS(), [Tip(np.array([0.0, 0.0]), np.array([1.0, 0.0]))],
                     GrowthParams(r=0.1), da=da, threshold=1.0, tags=[300],
                     obstacles=[np.array([[0.3, -1.0], [0.3, 1.0]])])
    d.paths[0] = [np.array([0.0, 0.0]), start]
    d._extend(NS(t=1e-3), 0, start + np.array([da, 0.0]), 0.0, 2e6)
    np.testing.assert_allclose(d.paths[0][-1], [0.3, 0.0])
    assert 0 in d.arrested


def test_a_tip_meets_a_crack_at_its_vertex_when_near_it():
    """A meeting point within SNAP * Δa of a vertex of the crack met moves onto that vertex
    (a meeting 0.4 mm from a grown path's vertex cut the full-size re-fracture's step 43x:
    Gmsh keeps both points and the edge between them); farther away it stays where the
    segment crosses.  A vertex outside the tips' region (a perforation's wall end) is no
    place to meet: the tip stops where it is."""
    from types import SimpleNamespace as NS
    da = 0.2
    other = np.array([[0.3, -1.0], [0.3, 0.05], [0.3, 1.0]])  # a grown path with a vertex at y = 0.05

    def driver(inside=None):
        d = GrowthDriver(lambda polylines: NS(), [Tip(np.array([0.0, 0.0]), np.array([1.0, 0.0]))],
                         GrowthParams(r=0.1), da=da, threshold=1.0, tags=[300], obstacles=[other],
                         inside=inside)
        d.paths[0] = [np.array([0.0, 0.0]), np.array([0.2, 0.0])]
        d.tips[0].point = d.paths[0][-1].copy()
        return d

    near = 0.05 - 0.4 * SNAP * da  # the segment crosses 0.4 SNAP Δa below the vertex
    d = driver()
    d._extend(NS(t=1e-3), 0, np.array([0.2 + da, near]), 0.0, 2e6)
    np.testing.assert_allclose(d.paths[0][-1], [0.3, 0.05])
    assert 0 in d.arrested and not d.tips[0].active
    u = d.tips[0].direction  # the segment's own direction, onto the vertex
    np.testing.assert_allclose(u, np.array([0.1, 0.05]) / np.hypot(0.1, 0.05))
    far = 0.05 - 1.5 * SNAP * da
    d = driver()
    d._extend(NS(t=1e-3), 0, np.array([0.2 + da, 2 * far]), 0.0, 2e6)
    np.testing.assert_allclose(d.paths[0][-1], [0.3, far])
    # the vertex lies outside the tips' region: no segment, the tip stops where it is
    d = driver(inside=lambda p: p[1] < 0.04)
    d._extend(NS(t=1e-3), 0, np.array([0.2 + da, near]), 0.0, 2e6)
    assert len(d.paths[0]) == 2 and not d.tips[0].active and 0 not in d.arrested


def test_a_tip_meets_a_crack_where_another_one_meets_it_when_near_it():
    """A meeting point within SNAP * Δa of the point where another crack already meets the
    crack met (or leaves it) moves onto that point, though it is no vertex of the crack met:
    in the full-size re-fracture a tip met a perforation 1.4 mm from where another tip had met
    it and crossed it, and the step fell 11x.  Farther away it stays where the segment crosses."""
    from types import SimpleNamespace as NS
    da = 0.2
    perforation = np.array([[-0.4, 0.0], [-0.1, 0.0]])  # no vertex between its ends
    junction = np.array([-0.2397, 0.0])  # where another tip met it, and its crossing starts

    def driver():
        d = GrowthDriver(lambda polylines: NS(), [Tip(np.array([-0.2, -0.3]), np.array([0.0, 1.0]))],
                         GrowthParams(r=0.1), da=da, threshold=1.0, tags=[300], obstacles=[perforation])
        d.paths[0] = [np.array([-0.2, -0.3]), np.array([-0.2, -0.1])]
        d.tips[0].point = d.paths[0][-1].copy()
        d.paths.append([np.array([-0.2397, 0.3]), junction.copy()])  # the tip that met it from above
        d.paths.append([junction.copy(), np.array([-0.3, -0.1])])  # its crossing, down and away
        d.tips += [Tip(junction.copy(), np.array([0.0, -1.0]), False), Tip(np.array([-0.3, -0.1]), np.array([-1.0, -1.0]))]
        d.tags += [301, 302]
        return d

    start = np.array([-0.2, -0.1])
    for miss, snapped in ((0.0014, True), (1.5 * SNAP * da, False)):
        d = driver()
        x = junction[0] + miss  # where the segment crosses the perforation
        d._extend(NS(t=1e-3), 0, start + 2 * (np.array([x, 0.0]) - start), 0.0, 2e6)
        assert 0 in d.arrested and not d.tips[0].active
        np.testing.assert_allclose(d.paths[0][-1], junction if snapped else [x, 0.0], atol=1e-9)


def test_a_tip_moved_onto_a_junction_along_a_crack_from_there_stops():
    """A tip that starts on a crack's vertex and heads back, 16° off that crack, to meet another
    crack 16 mm from where the first leaves it (the full-size re-fracture at h_crack = 0.0415 m)
    would move onto that junction, and its segment would lie on the first crack: it stops
    where it is, for good.  Left where it met the crack, it made a 16° wedge whose cells cut
    the step 8x."""
    from types import SimpleNamespace as NS
    da = 0.083
    arm = np.array([[0.0038, -0.9809], [-0.0031, -1.0636]])  # the crack met
    v = np.round(arm[0] + 0.6610 * (arm[1] - arm[0]), 9)  # where the first crack leaves it
    p = np.array([0.0371, -1.0035])  # that crack's next vertex, where the tip starts
    d = GrowthDriver(lambda polylines: NS(), [Tip(np.array([0.2, -0.9]), np.array([-1.0, -0.5]))],
                     GrowthParams(r=0.1), da=da, threshold=1.0, tags=[300], obstacles=[arm])
    d.paths[0] = [np.array([0.2, -0.9]), p.copy()]
    d.tips[0].point = p.copy()
    d.paths.append([v.copy(), p.copy(), np.array([0.07, -0.93])])  # the first crack, from the junction
    d.tips.append(Tip(np.array([0.07, -0.93]), np.array([1.0, 1.0])))
    d.tags.append(301)
    meet = np.array([0.000526157, -1.020041417])  # 16 mm from the junction, within SNAP * da
    assert np.linalg.norm(meet - v) < SNAP * da
    d._extend(NS(t=1e-3), 0, p + 1.5 * (meet - p), 0.0, 2e6)
    assert len(d.paths[0]) == 2 and not d.tips[0].active and 0 not in d.arrested
    np.testing.assert_allclose(d.tips[0].point, p)


@pytest.mark.parametrize("angle, crosses", [(45.0, False), (47.0, False), (52.0, False), (35.0, False),
                                            (-30.0, True), (60.0, True)])
def test_a_crossing_does_not_run_along_the_crack_it_crosses(angle, crosses):
    """A tip arrested on a crack sits on a vertex of it where it met the crack near one
    (:meth:`GrowthDriver._at_vertex`); the crack may turn there, so the far side of one of its
    segments can hold the direction of the other.  A crossing along that direction (within
    edge_margin, 5°) would lie on the crack (the full-size re-fracture stopped there: "path 4
    and path 15 overlap"), and so would one whose end lies within SNAP * da of the crack (52°
    and 35°: the end would move onto it), so the tip stays arrested; other directions cross."""
    from types import SimpleNamespace as NS
    other = np.array([[0.3, -1.0], [0.3, 0.0], [0.5, 0.2]])  # turns by 45° at (0.3, 0)
    d = GrowthDriver(lambda polylines: NS(), [Tip(np.array([0.0, 0.0]), np.array([1.0, 0.0]))],
                     GrowthParams(r=0.1), da=0.1, threshold=1.0, tags=[300], obstacles=[other])
    p = np.array([0.3, 0.0])
    d.paths[0] = [np.array([0.0, 0.0]), p.copy()]
    d.tips[0].point, d.tips[0].active = p.copy(), False
    d.arrested[0] = (p.copy(), np.array([0.0, 1.0]))
    theta = np.radians(np.linspace(-85.0, 85.0, 121))
    d.far_side_profile = lambda solver, i: (theta, 2.0 * np.cos(theta - np.radians(angle)))
    out = d._cross(NS(t=1e-3), [True])
    assert (0 in out) == crosses and (0 in d.arrested) != crosses
    if crosses:
        assert np.degrees(np.arctan2(*d.tips[out[0]].direction[::-1])) == pytest.approx(angle, abs=0.5)
