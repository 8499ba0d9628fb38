"""Branching of fast cracks (docs/model.md §6, "Branching").

* **The criterion on the exact field of a moving crack.**  For a mode-I crack running at a
  steady speed v, the singular near-tip field (Freund 1990, eq. 4.3.11) makes the maximum of
  the hoop stress leave the crack line above v ≈ 0.6 c_s (Yoffe 1951).  The sampled
  effective stress s̆(θ) of the growth criterion, evaluated on that exact field, must show
  one maximum (straight ahead) below this speed and two separated maxima above it, and the
  speed where it splits must be 0.60 c_s within 1 % for β = 0 (the hoop stress itself) and
  for β = 1.
* **A dynamic set-up** (``scenarios/branching.py``).  A traction-free crack (0.5 m, debonded)
  in a block under a uniaxial tension T normal to it runs straight; a crack-parallel
  compression of 4 MPa enters from the absorbing sides (the outer state) and reaches the
  running tip after ~400 µs, which gives the criterion two maxima, near ±45°.  Under T = 0.8 MPa the tip runs at ~1000 m/s there
  (above the branching speed of the test, 0.5 c_R = 832 m/s) and splits into two tips, one
  along each maximum; under T = 0.7 MPa it runs at ~600 m/s and turns along one maximum only.
  1 and 2 ranks give the same tree.
"""
import numpy as np
import pytest
from mpi4py import MPI

from hydrofrac import ROCK
from hydrofrac.growth import GrowthDriver, separated_maxima
from hydrofrac.loader import scenario


def moving_crack_profile(v, beta, theta, mat=ROCK):
    """s̆(θ) on the plane through the tip along θ, at unit distance, of the singular field of
    a mode-I crack moving at speed v (Freund 1990, eq. 4.3.11; K_I = 1)."""
    ad, as_ = np.sqrt(1 - (v / mat.cd) ** 2), np.sqrt(1 - (v / mat.cs) ** 2)
    D = 4 * ad * as_ - (1 + as_ ** 2) ** 2
    x, y = np.cos(theta), np.sin(theta)
    rd, rs = np.sqrt(x * x + (ad * y) ** 2), np.sqrt(x * x + (as_ * y) ** 2)
    thd, ths = np.arctan2(ad * y, x), np.arctan2(as_ * y, x)
    k = 1.0 / (np.sqrt(2 * np.pi) * D)
    cd_, cs_ = np.cos(thd / 2) / np.sqrt(rd), np.cos(ths / 2) / np.sqrt(rs)
    s11 = k * ((1 + as_ ** 2) * (1 + 2 * ad ** 2 - as_ ** 2) * cd_ - 4 * ad * as_ * cs_)
    s22 = k * (-(1 + as_ ** 2) ** 2 * cd_ + 4 * ad * as_ * cs_)
    s12 = k * 2 * ad * (1 + as_ ** 2) * (np.sin(thd / 2) / np.sqrt(rd) - np.sin(ths / 2) / np.sqrt(rs))
    nx, ny, tx, ty = -np.sin(theta), np.cos(theta), np.cos(theta), np.sin(theta)
    trx, try_ = s11 * nx + s12 * ny, s12 * nx + s22 * ny
    sn, st = trx * nx + try_ * ny, trx * tx + try_ * ty
    return np.sqrt(np.maximum(sn, 0) ** 2 + (beta * st) ** 2)


@pytest.mark.parametrize("beta", [0.0, 1.0])
def test_criterion_splits_at_the_yoffe_speed(beta):
    th = np.radians(np.linspace(-85.0, 85.0, 341))

    def two(v):
        return separated_maxima(th, moving_crack_profile(v, beta, th), 0.0, np.radians(1e-3), 0.0)

    assert two(0.3 * ROCK.cR) == [] and two(0.55 * ROCK.cs) == []
    pair = two(0.7 * ROCK.cR)
    assert len(pair) == 2 and pair[0][0] == pytest.approx(-pair[1][0], abs=1e-6) and abs(pair[0][0]) > 0.3
    lo, hi = 0.3 * ROCK.cs, 0.8 * ROCK.cs
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if two(mid) else (mid, hi)
    assert hi / ROCK.cs == pytest.approx(0.60, rel=0.01)


def test_separated_maxima_rules():
    """Two maxima count only if both reach the threshold, lie min_sep apart and stand the
    prominence above the dip between them; they come ordered by |θ|."""
    th = np.radians(np.linspace(-80, 80, 161))
    s = np.exp(-((th - 0.6) / 0.2) ** 2) + 0.9 * np.exp(-((th + 0.5) / 0.2) ** 2)
    (t1, s1), (t2, s2) = separated_maxima(th, s, 0.5, np.radians(20))
    assert t1 == pytest.approx(-0.5, abs=0.01) and t2 == pytest.approx(0.6, abs=0.01)
    assert separated_maxima(th, s, 0.95, np.radians(20)) == []          # the lower one is below the onset
    assert separated_maxima(th, s, 0.5, np.radians(70)) == []           # closer than min_sep
    near = np.exp(-((th - 0.25) / 0.2) ** 2) + np.exp(-((th + 0.25) / 0.2) ** 2)  # dip 0.42 between 1.0s
    assert len(separated_maxima(th, near, 0.5, np.radians(20), prominence=0.5)) == 2
    assert separated_maxima(th, near, 0.5, np.radians(20), prominence=0.7) == []  # too shallow a dip


def branching_run(T, comm=MPI.COMM_WORLD, t_end=5.2e-4, branch_speed=0.5 * ROCK.cR):
    """The ``branching`` scenario under tension T, stepped to ``t_end``; returns the driver."""
    problem = scenario("branching").setup(comm, tension=T, branch_speed=branch_speed)
    while problem.solver.t < t_end:
        problem.solver.step()
        new = problem.growth(problem)
        problem = new if new is not None else problem
    return problem.growth


def test_fast_crack_branches_slow_one_turns():
    fast = branching_run(0.8e6)
    br = [e for e in fast.tree if e["event"] == "branch"]
    assert len(br) == 1, fast.tree
    b = br[0]
    assert b["speed"] >= 0.5 * ROCK.cR
    a1, a2 = sorted(b["angle_deg"])
    assert -60 < a1 < -30 and 30 < a2 < 60, b  # one branch along each maximum, near ±45°
    assert fast.counts()["tips"] == 2 and fast.counts()["branches"] == 1
    slow = branching_run(0.7e6)
    assert slow.counts()["branches"] == 0 and slow.counts()["tips"] == 1
    turned = [abs(a) for _, i, a, _ in slow.events]
    assert max(turned) > 30  # it met the same two maxima and took one
    speeds = [v for v in slow.tip_speeds() if v is not None]
    assert speeds and max(speeds[:-1] or speeds) < 0.5 * ROCK.cR
    # the tree survives a restart: a driver restored from the checkpoint state has it
    again = GrowthDriver.__new__(GrowthDriver)
    again.tags = list(fast.tags)
    again.restore_state(fast.checkpoint_state())
    assert again.tree == fast.tree and again.counts() == fast.counts()


@pytest.mark.mpi
def test_branching_same_on_one_and_two_ranks():
    par = branching_run(0.8e6, comm=MPI.COMM_WORLD)
    ser = branching_run(0.8e6, comm=MPI.COMM_SELF)
    assert [e["event"] for e in par.tree] == [e["event"] for e in ser.tree] == ["branch"]
    assert par.tree[0]["t"] == pytest.approx(ser.tree[0]["t"], rel=1e-9)
    np.testing.assert_allclose(par.tree[0]["angle_deg"], ser.tree[0]["angle_deg"], atol=0.5)
    assert par.counts() == ser.counts()


def test_a_branch_is_a_fork():
    """Branching takes a fork only: two maxima on either side of the crack's direction, each at
    least half the minimum separation from it; a straight-on maximum with a side lobe, or two
    lobes on one side, are a kink (the tip follows the larger)."""
    th = np.radians(np.linspace(-80, 80, 161))

    def lobes(a, b):
        return np.exp(-((th - np.radians(a)) / 0.15) ** 2) + 0.95 * np.exp(-((th - np.radians(b)) / 0.15) ** 2)

    sep = np.radians(20)
    assert len(separated_maxima(th, lobes(-40, 40), 0.5, sep, fork=True)) == 2
    assert separated_maxima(th, lobes(1, -26), 0.5, sep, fork=True) == []    # straight on + a side lobe
    assert separated_maxima(th, lobes(-19, -45), 0.5, sep, fork=True) == []  # both on one side
    assert len(separated_maxima(th, lobes(-19, -45), 0.5, sep)) == 2          # not a fork, but two maxima
