"""Riemann solutions of the contact modes, their combination, the contact fraction eta and
the damage law (verification.md cases 7 and 10; model.md §2-4).

The formulas under test live in :mod:`hydrofrac.riemann` only; these tests check them
against the identities that define them (characteristics preserved on each side, one
traction, the kinematic condition of each mode), not against copies of the formulas.
The last test runs a bonded interface in the solver past its strength (case 10).
"""
import numpy as np
import pytest
from mpi4py import MPI
from scipy.integrate import solve_ivp

from hydrofrac import ROCK
from hydrofrac import riemann as rm
from hydrofrac.boundary import Absorbing, PiecewiseLinear, Symmetry, Traction
from hydrofrac.interface import Crack, DamageParams, Interface, crack_facet_indices
from hydrofrac.solver import Solver

from helpers import CRACK, LEFT, RIGHT, SIDES, strip  # the strip mesh helper

N = 2000  # random interface points per test
RTOL = 1e-12  # round-off, relative to the size of the characteristic values


def random_problem(seed, order):
    """Random traces and impedances; ``order`` = "Z+>Z-" or "Z+<Z-" in both components.

    Velocities O(1) m/s, tractions O(Z * 1 m/s); impedances of rock-like media
    (Z_s < Z_d) differing by up to a factor 5 between the sides.
    """
    rng = np.random.default_rng(seed)
    Zd_big = rng.uniform(8e6, 2e7, N)
    Zs_big = Zd_big * rng.uniform(0.5, 0.65, N)
    Zbig = np.stack([Zd_big, Zs_big], axis=1)
    Zsmall = Zbig * rng.uniform(0.2, 0.9, size=(N, 2))
    Zp, Zm = (Zbig, Zsmall) if order == "Z+>Z-" else (Zsmall, Zbig)
    assert (np.all(Zp > Zm) if order == "Z+>Z-" else np.all(Zp < Zm))
    vp, vm = rng.normal(size=(N, 2)), rng.normal(size=(N, 2))
    sp, sm = rng.normal(size=(N, 2)) * 1e7, rng.normal(size=(N, 2)) * 1e7
    S = rng.normal(size=(N, 2)) * 1e7
    k = rng.uniform(0.0, 1.2, size=N)
    return dict(vp=vp, vm=vm, sp=sp, sm=sm, Zp=Zp, Zm=Zm), S, k, rng


def scale(P):
    """Typical size of a characteristic value s -+ Z v at each point (for round-off tolerances)."""
    return (np.abs(P["sp"]) + np.abs(P["sm"]) + P["Zp"] * np.abs(P["vp"]) + P["Zm"] * np.abs(P["vm"])).max()


def assert_characteristics(P, s, v_plus, v_minus, comps=(0, 1)):
    """s - Z+ v+ = s+ - Z+ v+ (from side +) and s + Z- v- = s- + Z- v- (from side -)."""
    tol = RTOL * scale(P)
    for c in comps:
        lhs_p = s[:, c] - P["Zp"][:, c] * v_plus[:, c]
        rhs_p = P["sp"][:, c] - P["Zp"][:, c] * P["vp"][:, c]
        lhs_m = s[:, c] + P["Zm"][:, c] * v_minus[:, c]
        rhs_m = P["sm"][:, c] + P["Zm"][:, c] * P["vm"][:, c]
        assert np.abs(lhs_p - rhs_p).max() <= tol, f"side + characteristic broken in component {c}"
        assert np.abs(lhs_m - rhs_m).max() <= tol, f"side - characteristic broken in component {c}"


ORDERS = ["Z+>Z-", "Z+<Z-"]


# --------------------------------------------------------------------------------------
# Case 7: each mode
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("order", ORDERS)
def test_bonded_mode(order):
    """Bonded / stick: characteristics preserved, one traction and one velocity."""
    P, _, _, _ = random_problem(1, order)
    s, v = rm.bonded(**P)
    assert_characteristics(P, s, v, v)
    # the traction read off each side's characteristic is the same (single-valued)
    s_from_p = P["sp"] + P["Zp"] * (v - P["vp"])
    s_from_m = P["sm"] - P["Zm"] * (v - P["vm"])
    assert np.abs(s_from_p - s_from_m).max() <= RTOL * scale(P)


@pytest.mark.parametrize("order", ORDERS)
def test_bonded_targets_equal_agreeing_traces(order):
    """Traces that already agree (v+ = v-, s+ = s-) are their own bonded solution."""
    P, _, _, _ = random_problem(2, order)
    P["vm"], P["sm"] = P["vp"].copy(), P["sp"].copy()
    s, v = rm.bonded(**P)
    np.testing.assert_allclose(s, P["sp"], rtol=0, atol=RTOL * scale(P))
    np.testing.assert_allclose(v, P["vp"], rtol=0, atol=RTOL * np.abs(P["vp"]).max())


@pytest.mark.parametrize("order", ORDERS)
def test_separation_mode(order):
    """Separation: target traction S on both sides, characteristics preserved, and the
    normal separation-velocity jump [[v_S^1]] = v_S^1- - v_S^1+ = (2/Z~^1)(s_B^1 - S^1) (eqs. 11-12)."""
    P, S, _, _ = random_problem(3, order)
    s, v_plus, v_minus = rm.separation(**P, S=S)
    np.testing.assert_array_equal(s, S)
    assert_characteristics(P, s, v_plus, v_minus)
    s_B, _ = rm.bonded(**P)
    Zt = rm.reduced_impedance(P["Zp"], P["Zm"])
    jump = v_minus - v_plus
    expected = 2.0 / Zt * (s_B - S)
    np.testing.assert_allclose(jump[:, 0], expected[:, 0], rtol=0, atol=RTOL * scale(P) / Zt.min())
    # Z~ is the harmonic mean: between the two impedances
    assert np.all((Zt >= np.minimum(P["Zp"], P["Zm"])) & (Zt <= np.maximum(P["Zp"], P["Zm"])))


@pytest.mark.parametrize("order", ORDERS)
def test_slip_mode(order):
    """Contact-slip: normal component bonded, tangential traction k<-s_B^1> sign(s_B^2),
    characteristics preserved, slip rate (2/Z~^2)(s_B^2 - s_SL^2), never above the
    Coulomb bound, and dissipative wherever slip is the active mode (gamma = 0)."""
    P, _, k, _ = random_problem(4, order)
    bonded = rm.bonded(**P)
    s_B, v_B = bonded
    s, v_plus, v_minus = rm.slip(**P, k=k)
    # computing the bonded predictor inside or passing it gives the same
    s2, vp2, vm2 = rm.slip(**P, k=k, s_B=s_B, v_B=v_B)
    np.testing.assert_array_equal(s, s2)
    np.testing.assert_array_equal(v_plus, vp2)
    assert_characteristics(P, s, v_plus, v_minus)
    # normal: the bonded values, no normal jump
    np.testing.assert_array_equal(s[:, 0], s_B[:, 0])
    np.testing.assert_array_equal(v_plus[:, 0], v_B[:, 0])
    np.testing.assert_array_equal(v_minus[:, 0], v_B[:, 0])
    # tangential traction: the Coulomb bound, in the stick-predictor direction
    bound = k * rm.macaulay(-s_B[:, 0])
    assert np.all(np.abs(s[:, 1]) <= bound * (1 + 1e-15))
    np.testing.assert_allclose(np.abs(s[:, 1]), bound, rtol=1e-15, atol=0)
    assert np.all(s[:, 1] * s_B[:, 1] >= 0)
    # slip rate
    Zt = rm.reduced_impedance(P["Zp"], P["Zm"])
    slip_rate = v_minus[:, 1] - v_plus[:, 1]
    np.testing.assert_allclose(slip_rate, 2.0 / Zt[:, 1] * (s_B[:, 1] - s[:, 1]), rtol=0,
                               atol=RTOL * scale(P) / Zt.min())
    # dissipation where the slip mode is the one used (gamma = 0): the power absorbed by
    # the interface is s* . (v*- - v*+) (side + has outward normal n, side - has -n)
    gamma = rm.stick_flag(s_B, k)
    slipping = gamma == 0
    assert 0.2 * N < slipping.sum() < 0.95 * N, "the random sample must contain both stick and slip points"
    power = (s * (v_minus - v_plus)).sum(axis=1)
    assert np.all(power[slipping] >= 0)
    assert np.all(s[slipping, 1] * slip_rate[slipping] >= 0)
    # ... and the sign convention is not vacuous: the slip formula applied where the
    # point actually sticks would inject energy at some points
    assert np.any(power[~slipping & (np.abs(s_B[:, 1]) < bound)] < 0)


def test_stick_flag():
    """gamma = 1 iff |s_B^2| <= k <-s_B^1>; no stick without compression unless no shear."""
    s_B = np.array([[-1.0, 0.5], [-1.0, 0.7], [-1.0, -0.6], [1.0, 0.0], [1.0, 0.1], [-2.0, -1.2]])
    k = 0.6
    np.testing.assert_array_equal(rm.stick_flag(s_B, k), [1, 0, 1, 1, 0, 1])


def test_sanity_compression_sign():
    """Side + moving into side - (v+_1 > v-_1) with unloaded traces gives s_1 < 0 (compression)."""
    for order in ORDERS:
        P, _, _, rng = random_problem(5, order)
        P["sp"][:] = 0.0
        P["sm"][:] = 0.0
        P["vm"][:, 0] = P["vp"][:, 0] - rng.uniform(1e-3, 2.0, size=N)
        s, _ = rm.bonded(**P)
        assert np.all(s[:, 0] < 0)


@pytest.mark.parametrize("order", ORDERS)
def test_combination(order):
    """s*, v*+- of the damage model (eqs. 6-7): the fractions sum to one, so the characteristics
    of both sides are preserved and the traction is single-valued for any D, eta, gamma."""
    P, S, k, rng = random_problem(6, order)
    bonded = rm.bonded(**P)
    slip = rm.slip(**P, k=k, s_B=bonded[0], v_B=bonded[1])
    sep = rm.separation(**P, S=S)
    D = rng.uniform(0, 1, N)
    D[:100], D[100:200] = 0.0, 1.0
    eta = rng.uniform(0, 1, N)
    eta[200:300], eta[300:400] = 0.0, 1.0
    gamma = rm.stick_flag(bonded[0], k)
    a = rm.mode_weights(D, eta, gamma)
    assert all(np.all((x >= 0) & (x <= 1)) for x in a)
    np.testing.assert_allclose(a[0] + a[1] + a[2], 1.0, rtol=0, atol=1e-15)
    s, v_plus, v_minus = rm.combine(D, eta, gamma, bonded, slip, sep)
    assert_characteristics(P, s, v_plus, v_minus)
    # limits: D = 0 is the bonded solution; D = 1, eta = 0 the separation solution
    np.testing.assert_array_equal(s[:100], bonded[0][:100])
    np.testing.assert_array_equal(v_plus[:100], bonded[1][:100])
    sep_only = (D == 1) & (eta == 0)
    np.testing.assert_allclose(s[sep_only], S[sep_only], rtol=1e-15, atol=0)
    # in full contact (D = 1, eta = 1) no normal opening rate: [[v*^1]] = 0
    contact = (D == 1) & (eta == 1)
    contact[400:450] = True
    D2, eta2 = np.where(contact, 1.0, D), np.where(contact, 1.0, eta)
    _, vp2, vm2 = rm.combine(D2, eta2, gamma, bonded, slip, sep)
    np.testing.assert_array_equal(vm2[contact, 0] - vp2[contact, 0], 0.0)


@pytest.mark.parametrize("mode", ["bonded", "separation", "slip", "combined"])
def test_mirror_symmetry(mode):
    """Swapping the sides and flipping n gives the mirrored solution: in Cartesian
    components the traction on the flipped plane is -s* and the target velocities swap."""
    rng = np.random.default_rng(7)
    angle = rng.uniform(0, 2 * np.pi, N)
    n = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    Za = np.stack([rng.uniform(5e6, 2e7, N), rng.uniform(2e6, 4e6, N)], axis=1)
    Zb = np.stack([rng.uniform(1e6, 4e6, N), rng.uniform(0.5e6, 1e6, N)], axis=1)
    va, vb = rng.normal(size=(N, 2)), rng.normal(size=(N, 2))
    sig = [rng.normal(size=(N, 2, 2)) * 1e7 for _ in range(2)]
    sig = [0.5 * (x + x.transpose(0, 2, 1)) for x in sig]
    S = rng.normal(size=(N, 2)) * 1e7  # local components: a traction-like load, e.g. a pressure
    k = rng.uniform(0, 1, N)
    D, eta = rng.uniform(0, 1, N), rng.uniform(0, 1, N)

    def solve(normal, vplus, vminus, sigplus, sigminus, Zp, Zm):
        loc = lambda c: rm.to_local(c, normal)  # noqa: E731
        P = dict(vp=loc(vplus), vm=loc(vminus), sp=loc(np.einsum("nij,nj->ni", sigplus, normal)),
                 sm=loc(np.einsum("nij,nj->ni", sigminus, normal)), Zp=Zp, Zm=Zm)
        bonded = rm.bonded(**P)
        if mode == "bonded":
            out = (bonded[0], bonded[1], bonded[1])
        elif mode == "separation":
            out = rm.separation(**P, S=S)
        elif mode == "slip":
            out = rm.slip(**P, k=k)
        else:
            gamma = rm.stick_flag(bonded[0], k)
            out = rm.combine(D, eta, gamma, bonded, rm.slip(**P, k=k), rm.separation(**P, S=S))
        return [rm.to_global(x, normal) for x in out]

    s, v_plus, v_minus = solve(n, va, vb, sig[0], sig[1], Za, Zb)
    s_f, v_plus_f, v_minus_f = solve(-n, vb, va, sig[1], sig[0], Zb, Za)
    np.testing.assert_allclose(s_f, -s, rtol=0, atol=1e-12 * np.abs(s).max())
    np.testing.assert_allclose(v_plus_f, v_minus, rtol=0, atol=1e-12 * np.abs(v_minus).max())
    np.testing.assert_allclose(v_minus_f, v_plus, rtol=0, atol=1e-12 * np.abs(v_plus).max())


def test_frame_helpers():
    """to_local / to_global are inverse rotations with t = n rotated by +90 degrees."""
    rng = np.random.default_rng(8)
    angle = rng.uniform(0, 2 * np.pi, 100)
    n = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    t = rm.tangent(n)
    np.testing.assert_allclose(np.cross(n, t), 1.0, rtol=0, atol=1e-15)
    x = rng.normal(size=(100, 2))
    np.testing.assert_allclose(rm.to_global(rm.to_local(x, n), n), x, rtol=0, atol=1e-14)


# --------------------------------------------------------------------------------------
# Case 7: the contact fraction eta (model.md §4)
# --------------------------------------------------------------------------------------
DELTA0, W0 = -0.01, 0.01


def _max_neighbour_jump(num):
    """Largest change of eta between neighbouring samples of a num x num grid covering both
    regularisation bands and some margin, and the grid spacings."""
    d = np.linspace(3 * DELTA0, -2 * DELTA0, num)
    w = np.linspace(-2 * W0, 3 * W0, num)
    E = rm.eta_regularized(d[:, None], w[None, :], DELTA0, W0)
    jump = max(np.abs(np.diff(E, axis=0)).max(), np.abs(np.diff(E, axis=1)).max())
    return jump, d[1] - d[0], w[1] - w[0], (d, w)


def test_eta_continuous():
    """eta(delta', w') is continuous: the largest jump between neighbouring samples is bounded
    by the Lipschitz constant (1.5 / band width, from the smoothstep 3x^2 - 2x^3) times the
    spacing, so it goes to zero with the sampling; the exact map of fig. 3 does not."""
    jumps = []
    for num in (101, 1001, 4001):
        jump, hd, hw, (d, w) = _max_neighbour_jump(num)
        assert jump <= 1.5 * max(hd / abs(DELTA0), hw / W0) * (1 + 1e-9)
        jumps.append(jump)
    assert jumps[2] < jumps[1] < jumps[0] and jumps[2] < 2e-3
    exact = rm.eta_exact(d[:, None], w[None, :])
    assert np.abs(np.diff(exact, axis=0)).max() == 1.0  # the unregularised map jumps


def test_eta_exact_outside_bands():
    """Outside the regularisation bands (delta'_0 < delta' < 0, 0 < w' < w'_0) the regularised
    map equals the exact one (penetrated points delta' <= delta'_0 count as closed)."""
    rng = np.random.default_rng(9)
    d = np.r_[rng.uniform(1e-12, 10, 500), rng.uniform(100 * DELTA0, DELTA0, 500)]
    w = np.r_[rng.uniform(-10, -1e-12, 500), rng.uniform(W0, 10, 500)]
    Dg, Wg = np.meshgrid(d, w, indexing="ij")
    reg = rm.eta_regularized(Dg, Wg, DELTA0, W0)
    ex = rm.eta_exact(Dg, Wg)
    np.testing.assert_array_equal(reg, ex)
    # and both values occur
    assert reg.min() == 0.0 and reg.max() == 1.0


def test_eta_full_contact_at_max_penetration():
    """eta = 1 at delta' <= delta'_0 with w' <= 0 (pressed or resting), so the opening rate
    D (1 - eta) [[v_S^1]] is zero there: penetration never exceeds |delta'_0| delta~."""
    d = np.r_[DELTA0, np.linspace(10 * DELTA0, DELTA0, 50)]
    w = np.r_[0.0, -np.logspace(-8, 2, 50)]
    E = rm.eta_regularized(d[:, None], w[None, :], DELTA0, W0)
    np.testing.assert_array_equal(E, 1.0)
    # inside the band eta is strictly between 0 and 1, and decreasing towards opening
    e_band = rm.eta_regularized(np.linspace(DELTA0, 0, 11), -1.0, DELTA0, W0)
    assert e_band[0] == 1.0 and e_band[-1] == 0.0 and np.all(np.diff(e_band) < 0)


def test_exact_closing_flow_against_integration():
    """The closed-form flow through the contact band (riemann.closing_flow_pt; docs/model.md §4)
    against a fine numerical integration of d(delta)/d(xi) = 1 - r(delta') from above the band,
    at its edge and inside it; any closing increment, however large, ends above the floor
    -|delta'_0| delta~ (strictly, unless it starts there), and the flow is monotone in it."""
    band = 8e-8  # |delta'_0| delta~ at the defaults [m]

    def r(d):
        x = min(max(-d / band, 0.0), 1.0)
        return x * x * (3 - 2 * x)
    for d0 in (3e-7, 0.0, -0.2 * band, -0.9 * band, -0.999 * band):
        for dxi in (-1e-8, -1e-7, -5e-7, -1e-5):
            ref = solve_ivp(lambda _x, y: [1 - r(y[0])], (0, dxi), [d0], method="DOP853", rtol=1e-12,
                            atol=1e-22, max_step=band / 50)
            got = rm.closing_flow(d0, dxi, band)
            assert got == pytest.approx(ref.y[0, -1], rel=1e-7, abs=1e-9 * band), (d0, dxi)
    xi = -np.logspace(-12, 2, 200)
    flow = rm.closing_flow(np.full(xi.size, 1e-7), xi, band)
    assert np.all(flow > -band) and np.all(np.diff(flow) <= 0)
    assert rm.closing_flow(-band, -1.0, band) == -band  # at the floor: eta = 1, no motion
    assert rm.closing_flow(1e-7, -4e-8, band) == pytest.approx(6e-8, rel=1e-12)  # above the band: linear


# --------------------------------------------------------------------------------------
# Case 10: the damage law
# --------------------------------------------------------------------------------------
def test_damage_ode_against_reference():
    """Under a held over-stress (D_t = 1), D(t) integrated with the solver's RK4 from
    ``riemann.damage_rate`` follows dD/dt = (1 - exp(-a (1 - D)))/tau (fine scipy reference,
    itself checked against the closed form), reaches 1 and then stays with zero rate."""
    tau, a = 30e-6, 5.0
    dt = tau / 100
    nsteps = 1500  # 15 tau
    rate = lambda D: rm.damage_rate(np.atleast_1d(D), np.ones(1), tau, a)  # noqa: E731
    D = np.zeros(1)
    hist = [0.0]
    for _ in range(nsteps):
        k1 = rate(D)
        k2 = rate(np.minimum(D + 0.5 * dt * k1, 1.0))
        k3 = rate(np.minimum(D + 0.5 * dt * k2, 1.0))
        k4 = rate(np.minimum(D + dt * k3, 1.0))
        D = np.clip(D + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4), D, 1.0)
        hist.append(float(D[0]))
    t = dt * np.arange(nsteps + 1)
    hist = np.array(hist)

    ref = solve_ivp(lambda _t, y: (1.0 - np.exp(-a * (1.0 - y))) / tau, (0, t[-1]), [0.0], method="DOP853",
                    t_eval=t, rtol=1e-13, atol=1e-16, max_step=tau / 10)
    closed = 1.0 - np.log1p(np.expm1(a) * np.exp(-a * t / tau)) / a  # u = 1 - D: e^{au} - 1 ~ e^{-a t / tau}
    assert np.abs(ref.y[0] - closed).max() < 1e-10
    err = np.abs(hist - ref.y[0]).max()
    assert err < 1e-8, f"RK4 damage history differs from the reference by {err:.3g}"
    assert np.all(np.diff(hist) >= 0) and hist.max() <= 1.0
    assert hist[-1] >= 1.0 - 1e-12  # reached 1 (to round-off: the approach is exponential)
    # at D = 1 the rate is zero whatever the load, and damage never heals (D > D_t: no rate)
    assert rm.damage_rate(np.ones(3), np.array([0.0, 0.5, 1.0]), tau, a).tolist() == [0.0, 0.0, 0.0]
    assert rm.damage_rate(np.array([0.6]), np.array([0.2]), tau, a)[0] == 0.0


def test_target_damage_and_effective_stress():
    """D_t = 0 below s_, linear to 1 at s_bar; s_eff = sqrt(<s^1>^2 + (beta s^2)^2)."""
    s_on, s_bar = 1.0e6, 2.0e6
    np.testing.assert_allclose(rm.target_damage(np.array([0, 1e6, 1.5e6, 2e6, 5e6]), s_on, s_bar),
                               [0, 0, 0.5, 1, 1])
    s_B = np.array([[3e6, 4e6], [-3e6, 4e6], [-1e6, 0.0]])
    np.testing.assert_allclose(rm.effective_stress(s_B, 1.0), [5e6, 4e6, 0.0])
    np.testing.assert_allclose(rm.effective_stress(s_B, 0.5), [np.hypot(3e6, 2e6), 2e6, 0.0])


# --------------------------------------------------------------------------------------
# Case 10 in the solver: a bonded interface loaded past its strength debonds
# --------------------------------------------------------------------------------------

def test_bonded_interface_debonds_past_strength():
    """A bonded interface (D = 0) in a strip under a ramped tension held above the
    strength s_bar debonds: D reaches 1 and the interface traction drops to the
    separation traction S (= 0, an unloaded crack); the crack opens."""
    comm = MPI.COMM_WORLD
    L, nx, p = 0.05, 20, 1
    mesh, tags = strip(comm, L, nx)
    mat = ROCK
    dmg = DamageParams(tau=2e-6)  # s_bar = 2 MPa, s_ = 1 MPa, a = 5
    t_arrive = L / mat.cd
    ramp = 2e-6
    tension = 1.5 * dmg.s_bar
    # Traction S = stress.n - p(t) n: p = -tension pulls the left end
    load = PiecewiseLinear((0.0, ramp), (0.0, -tension))
    cracks = [Crack(CRACK, friction=0.6, damage=0.0)]
    solver = Solver(mesh, p, mat, facet_tags=tags, bcs=[Symmetry(SIDES), Traction(LEFT, pressure=load),
                                                        Absorbing(RIGHT)],
                    crack_facets=crack_facet_indices(mesh, tags, cracks))
    iface = Interface(solver, tags, cracks, damage=dmg)
    solver.attach(iface)
    t_end = t_arrive + ramp + 8 * dmg.tau
    D_min, s_B_max = [], []
    while solver.t < t_end:
        solver.step()
        D_min.append(comm.allreduce(float(iface.state[0].min()) if iface.state[0].size else 1.0, op=MPI.MIN))
        s_B_max.append(comm.allreduce(float(np.abs(iface.last["s_B"][:, 0]).max()) if iface.facets.size else 0.0,
                                      op=MPI.MAX))
    D_min = np.array(D_min)
    assert np.all(np.diff(D_min) >= 0), "damage decreased"
    # the bonded traction carried the load past the strength (D_t = 1)
    assert max(s_B_max) > dmg.s_bar
    assert D_min[-1] >= 1 - 1e-6, f"damage reached only {D_min[-1]:.8f}"
    T = iface.last
    if iface.facets.size:
        # traction = S = 0 (to the remaining bonded fraction), crack open and separated
        assert np.abs(T["s_star"]).max() <= 1e-6 * dmg.s_bar
        assert np.all(iface.state[1] > 0)
        assert np.all(T["eta"] == 0.0)


def test_bonded_jump_form_equals_bonded_solution():
    """The jump form used by the matrix-free facet kernel gives each side's correction
    s_B - s±, v_B - v± of the bonded solution (eq. 5) to round-off, for unequal impedances."""
    from hydrofrac.riemann import bonded_jump_pt, bonded_pt
    rng = np.random.default_rng(7)
    for _ in range(50):
        vp, vm = rng.normal(size=2)
        sp, sm = 1e6 * rng.normal(size=2)
        Zp, Zm = 1e6 * (1.0 + 9.0 * rng.random(2))
        sB, vB = bonded_pt(vp, vm, sp, sm, Zp, Zm)
        got = bonded_jump_pt(vm - vp, sm - sp, Zp, Zm)
        want = (sB - sp, vB - vp, sB - sm, vB - vm)
        assert np.allclose(got[0::2], want[0::2], rtol=1e-12, atol=1e-6), (got, want)  # stresses ~1e6 Pa
        assert np.allclose(got[1::2], want[1::2], rtol=1e-12, atol=1e-12), (got, want)  # velocities ~1 m/s


def test_separation_jump_and_mode_fractions():
    """The separation jump of eqs. 11-12, (2/Z~)(s_B - S), equals v- - v+ of the separation
    solution itself (each side on its own characteristic); the four mode fractions add up
    to one and bonded + stick is the bonded weight of the mixture."""
    rng = np.random.default_rng(3)
    vp, vm, sp, sm = rng.normal(size=(4, 50, 2))
    Zp, Zm = rng.uniform(1e6, 1e7, size=(2, 50, 2))
    S = rng.normal(size=(50, 2))
    sB, _ = rm.bonded(vp, vm, sp, sm, Zp, Zm)
    _, v_p, v_m = rm.separation(vp, vm, sp, sm, Zp, Zm, S)
    Zt = rm.reduced_impedance(Zp, Zm)
    np.testing.assert_allclose(rm.separation_jump(sB[:, 0], S[:, 0], Zt[:, 0]), v_m[:, 0] - v_p[:, 0], rtol=1e-10)
    D, eta, gamma = rng.uniform(size=(3, 50))
    f = rm.mode_fractions(D, eta, gamma)
    np.testing.assert_allclose(f.sum(axis=-1), 1.0, rtol=1e-14)
    aB, aSL, aS = rm.mode_weights(D, eta, gamma)
    np.testing.assert_allclose(f[:, 0] + f[:, 1], aB, rtol=1e-14)
    np.testing.assert_allclose(f[:, 2], aSL, rtol=1e-14)
    np.testing.assert_allclose(f[:, 3], aS, rtol=1e-14)


@pytest.mark.parametrize("scheme", ["rk4", "ader"])
def test_solver_damage_history_follows_the_damage_ode(scheme):
    """Verification case 10 through the solver: a bonded interface (D = 0) in a strip held at a
    tension 50 s_bar normal to it (the initial stress, kept by absorbing ends) has D_t = 1 from
    the start; the solver's own D(t) at its Gauss points follows dD/dt = (1 - exp(-a (1 - D)))/tau~
    (a fine scipy integration) to 1e-6 as long as the bonded traction stays above s_bar, here
    until D = 0.95.  Under rk4, and under ADER, whose interface state follows the third-order
    scheme of its P2 stages (Interface.ADER_STAGES; a second-order one misses by 6e-6)."""
    from hydrofrac.problem import Problem
    comm = MPI.COMM_WORLD
    L, nx = 0.05, 20
    mesh, tags = strip(comm, L, nx)
    dmg = DamageParams(tau=20e-6)
    sigma0 = np.array([[50 * dmg.s_bar, 0.0], [0.0, 0.0]])
    cracks = [Crack(CRACK, friction=0.6, damage=0.0)]
    solver = Solver(mesh, 2, ROCK, facet_tags=tags, sigma0=sigma0, scheme=scheme,
                    bcs=[Symmetry(SIDES), Absorbing(LEFT, stress=sigma0), Absorbing(RIGHT, stress=sigma0)],
                    crack_facets=crack_facet_indices(mesh, tags, cracks))
    problem = Problem(solver, Interface(solver, tags, cracks, damage=dmg))
    iface = problem.interface
    t, D, s_eff = [0.0], [0.0], []
    while D[-1] < 0.95:
        solver.step()
        problem.after_step()
        d = comm.allreduce(float(iface.state[0].mean()) if iface.facets.size else 0.0, op=MPI.MAX)
        spread = comm.allreduce(float(np.ptp(iface.state[0])) if iface.facets.size else 0.0, op=MPI.MAX)
        assert spread < 1e-12  # every point of the (one-dimensional) interface has the same history
        low = comm.allreduce(float(rm.effective_stress(iface.last["s_B"], dmg.beta).min())
                             if iface.facets.size else np.inf, op=MPI.MIN)
        t.append(solver.t)
        D.append(d)
        s_eff.append(low)
    assert min(s_eff) > dmg.s_bar  # the premise: D_t = 1 throughout
    ref = solve_ivp(lambda _t, y: (1.0 - np.exp(-dmg.a * (1.0 - y))) / dmg.tau, (0, t[-1]), [0.0],
                    method="DOP853", t_eval=t, rtol=1e-13, atol=1e-16, max_step=dmg.tau / 50)
    err = np.abs(np.array(D) - ref.y[0]).max()
    assert err < 1e-6, f"the solver's damage history differs from the ODE by {err:.3g}"
