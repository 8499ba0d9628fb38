"""Baselines of the stability study (issue 7): the failures they are there to show must
stay visible at a small size, so that the comparison cannot silently stop showing them.

* Penalty contact (normal traction -kappa <-delta>): with kappa = 1e14 Pa/m (penetration
  Z_d v0 / kappa = 75 nm, comparable to this method's 80 nm at delta'_0 = -0.01) it fails
  at the bulk CFL step; the step it needs falls like Z~/kappa: an explicit RK4 step on the
  stiff penalty relaxation (rate 2 kappa / Z~) is stable below 2.78 Z~ / (2 kappa).
* Unregularised eta: when a gap closes within a step, the faces overshoot into
  penetration by up to the closing speed times the step.  The regularised map keeps it
  within |delta'_0| delta~ at any step by the dynamics alone (the opening clip disabled):
  the default 80 nm band through the exact closing flow, and a band resolved in time
  (3 steps at the closing jump 2 v0) by its own smoothness.
"""
import numpy as np
import pytest
from mpi4py import MPI

from hydrofrac import ROCK
from hydrofrac.interface import ContactParams
from hydrofrac.postprocess import study_contact_stability as study

V0 = study.V0


@pytest.fixture(scope="module")
def bars():
    return study.bars(MPI.COMM_WORLD, 20)


def test_penalty_fails_at_the_bulk_step_and_needs_a_step_like_Z_over_kappa(bars):
    kappa = 1e14
    mesh, tags = bars
    ok, dt_cfl, *_ = study.run_case(mesh, tags, ContactParams(penalty=kappa), 1.0)
    assert not ok, "penalty contact with kappa = 1e14 Pa/m must fail at the bulk CFL step"
    limit = 2.785 * ROCK.Zd / (2 * kappa)  # RK4 on d(delta)/dt = -(2 kappa / Z~) delta
    assert limit < dt_cfl / 16
    # well below the limit it works and penetrates Z_d v0 / kappa (the spring's static answer)
    ok, dt, pen, _, sn = study.run_case(mesh, tags, ContactParams(penalty=kappa), limit / 2 / dt_cfl)
    assert ok
    assert pen == pytest.approx(ROCK.Zd * V0 / kappa, rel=0.05)
    # the Riemann contact at the bulk step, with 1000x less permitted penetration
    ok, dt, pen, _, _ = study.run_case(mesh, tags, ContactParams(delta0=-1e-4), 1.0)
    assert ok and dt == dt_cfl
    delta_scale = 30e-6 * 2e6 / ROCK.Zd  # tau~ s_bar / Z~ (default damage parameters, equal sides)
    assert pen <= 1e-4 * delta_scale * (1 + 1e-9)
    assert pen < 0.02 * ROCK.Zd * V0 / kappa


def test_unregularised_eta_overshoots_by_the_step(bars):
    mesh, tags = bars
    pens = {}
    for name, contact in (("exact", ContactParams(regularized=False, clip=False)),
                          ("regularised", ContactParams(clip=False)),
                          ("resolved", ContactParams(delta0=None, closing_speed=2 * V0, clip=False))):
        pens[name] = [study.run_case(mesh, tags, contact, f, gap=1e-6)[2] for f in (1.0, 0.25)]
    allowed = 0.01 * 30e-6 * 2e6 / ROCK.Zd  # |delta'_0| delta~ with the defaults
    exact, reg = pens["exact"], pens["regularised"]
    assert exact[0] > 10 * allowed, exact  # overshoot far beyond the permitted penetration ...
    assert exact[1] < 0.5 * exact[0], exact  # ... that depends on the time step
    assert max(reg) <= allowed * (1 + 1e-9), reg  # the dynamics alone hold the default band ...
    assert reg[0] == pytest.approx(reg[1], rel=1e-6)  # ... independent of the step
    dt_cfl = study.run_case(mesh, tags, ContactParams(), 1.0, t_window=0.0)[1]
    for pen, f in zip(pens["resolved"], (1.0, 0.25)):  # a band of 3 steps x 2 v0, at each step
        band = 3 * 2 * V0 * dt_cfl * f
        assert 0.5 * band < pen <= band * (1 + 1e-9), (pens["resolved"], band)
