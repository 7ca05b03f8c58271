"""Margins against a brute-force dense Nyquist evaluation and closed-loop roots, written here.

Every loop is built twice: once through the library (plant, controller, build_loop) and once
from raw coefficients in this file (``reference.open_loop``: matrix-exponential ZOH, numpy
products). The brute force evaluates L on 250 000 frequencies, finds the gain crossings and
the negative-real-axis crossings itself, and the gain margins are checked a third way: the
closed loop ``den + k*num`` must change stability exactly there.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import control as ct
import numpy as np
import pytest
import reference as ref
from quadrotor import DT
from scipy import optimize

from tuner.analysis.margins import margins
from tuner.analysis.response import closed_loop_poles, is_stable
from tuner.controllers import ControllerTF, controller_tf
from tuner.loop import build_loop
from tuner.plant import make_plant

# raw coefficients of the thesis models (quadrotor.md), written out here on purpose
YAW_G = ([0.2843 * 18.611], [1, 18.611])
ROLL_G = ([0.2655 * 14.8528**2], [1, 14.195, 14.8528**2])
PITCH_G = ([0.377568 * 3.5184**2], [1, 2 * 0.5006 * 3.5184, 3.5184**2])
PID_Z_DEN = [1, -1, 0]  # z (z - 1)


@dataclass(frozen=True)
class Case:
    plant: tuple  # (num, den)
    controller: tuple  # (num, den)
    dt: float | None
    plant_is_discrete: bool = False

    def loop(self):
        g = make_plant(*self.plant, dt=self.dt if self.plant_is_discrete else None)
        c = ControllerTF(num=np.asarray(self.controller[0], float), den=np.asarray(self.controller[1], float),
                         dt=self.dt)
        return build_loop(g, c)

    def polys(self):
        return ref.open_loop(*self.plant, *self.controller, dt=self.dt, plant_is_discrete=self.plant_is_discrete)


def _matched(K, wz, wp, dt):
    zd, pd = math.exp(-wz * dt), math.exp(-wp * dt)
    g = K * (1 - pd) / (1 - zd)
    return [g, -g * zd], [1, -pd]


CASES = {
    # the thesis's digital PIDs at dt = 0.04 (integrator + pole at z = 0)
    "yaw_pid_z": Case(YAW_G, ([1, -0.475], PID_Z_DEN), DT),
    "roll_pid_z": Case(ROLL_G, (3.868 * np.array([1, -1.305, 0.5668]), PID_Z_DEN), DT),
    "pitch_pid_z_x2.7": Case(PITCH_G, (2.7 * 37.79 * np.array([1, -1.85, 0.8686]), PID_Z_DEN), DT),
    # altitude: 0.04/(z-1) with PI 5 + 2/(z-1) = (5z - 3)/(z - 1): type 2, discrete
    "altitude": Case(([0.04], [1, -1]), ([5, -3], [1, -1]), DT, plant_is_discrete=True),
    # the same scaled so that the true upper gain margin is 6.0 dB (k_max = 12.5, see below)
    "altitude_gm6": Case(([0.04], [1, -1]), (6.265 * np.array([5, -3]), [1, -1]), DT, plant_is_discrete=True),
    # type 2: 1/s^2 with the lead 0.5 (s/0.5 + 1)/(s/2 + 1) = (2s + 1)/(s + 2)
    "double_integrator_lead": Case(([1], [1, 0, 0]), ([2, 1], [1, 2]), None),
    # the same lead, matched pole-zero at dt = 0.04, on the ZOH of 1/s^2
    "double_integrator_lead_dt": Case(([1], [1, 0, 0]), _matched(0.5, 0.5, 2.0, DT), DT),
    # conditionally stable: 3 (s+1)^2 / (s^3 (s/10+1)^2): both an upper and a lower gain margin
    "conditionally_stable": Case(([3, 6, 3], ref.polyprod([1, 0, 0, 0], [0.1, 1], [0.1, 1])), ([1], [1]), None),
    # open-loop unstable plant 1/(s-1)
    "unstable_pi": Case(([1], [1, -1]), ([3, 1], [1, 0]), None),
    "unstable_pi_dt": Case(([1], [1, -1]), ([3 + 1 * DT, -3], [1, -1]), DT),
    "unstable_lead": Case(([1], [1, -1]), ([30, 60], [1, 20]), None),
    # three gain crossings, the worst phase margin at the last one
    "three_gain_crossings": Case(([2, 20, 200], ref.polyprod([1, 0], [1, 1, 100])), ([1], [1]), None),
}
STABLE = sorted(CASES)


@pytest.fixture(scope="module")
def brute():
    """Brute-force figures of every case, computed once."""
    out = {}
    for name, case in CASES.items():
        n, d = case.polys()
        b = ref.nyquist_margins(n, d, case.dt)
        out[name] = (n, d, b)
    return out


@pytest.fixture(scope="module")
def ours():
    return {name: (case.loop(), margins(case.loop())) for name, case in CASES.items()}


def _same_db(a, b, tol=0.01):
    if math.isinf(a) or math.isinf(b):
        return a == b
    return abs(a - b) <= tol


# -- the loop the library builds is the one we build ----------------------------------------------

@pytest.mark.parametrize("name", STABLE)
def test_loop_matches_independent_construction(name, ours, brute):
    """L(jw) from the library's factored/state-space forms equals the independent polynomial construction
    (low order here, so the polynomials are accurate) over three decades around the crossover."""
    loop, m = ours[name]
    n, d, _ = brute[name]
    dt = CASES[name].dt
    wc = m.crossover_rad_s
    w = np.logspace(np.log10(wc) - 1.5, np.log10(wc) + 1.5, 200)
    if dt:
        w = w[w < 0.999 * np.pi / dt]
    x = 1j * w if dt is None else np.exp(1j * w * dt)
    want = np.polyval(n, x) / np.polyval(d, x)
    np.testing.assert_allclose(loop.freqresp(w), want, rtol=1e-8)


# -- stability from the closed-loop poles -------------------------------------------------------

@pytest.mark.parametrize("name", STABLE)
def test_closed_loop_stable_by_independent_roots(name, ours, brute):
    loop, _ = ours[name]
    n, d, _ = brute[name]
    assert ref.stable_at_gain(n, d, 1.0, CASES[name].dt)  # every case here is a stable design
    assert is_stable(loop)
    r = np.sort_complex(ref.closed_loop_roots(n, d))
    p = np.sort_complex(closed_loop_poles(loop))
    np.testing.assert_allclose(np.sort(np.abs(p)), np.sort(np.abs(r)), rtol=1e-6, atol=1e-9)


def test_unstable_plant_pi_closed_loop_poles_by_hand():
    # 1/(s-1) with 3 + 1/s: s(s-1) + 3s + 1 = s^2 + 2s + 1 = (s+1)^2
    loop = CASES["unstable_pi"].loop()
    np.testing.assert_allclose(np.sort(closed_loop_poles(loop).real), [-1, -1], atol=1e-6)
    assert is_stable(loop)


@pytest.mark.parametrize("k, stable", [(0.9, True), (1.2, False)])
def test_yaw_digital_pid_stability_limit_by_hand(k, stable):
    # yaw ZOH is b/(z - p) with p = exp(-18.611*0.04), b = 0.2843 (1 - p); the printed controller cancels
    # (z - 0.475) ~ (z - p), leaving z^2 - z + K b: complex roots on |z| = 1 when K b = 1
    p = math.exp(-18.611 * DT)
    b = 0.2843 * (1 - p)
    K = k / b
    case = Case(YAW_G, (K * np.array([1, -0.475]), PID_Z_DEN), DT)
    assert is_stable(case.loop()) is stable
    assert ref.stable_at_gain(*case.polys(), 1.0, DT) is stable


# -- margins vs brute force ---------------------------------------------------------------------

@pytest.mark.parametrize("name", STABLE)
def test_phase_margin_worst_over_all_gain_crossings(name, ours, brute):
    _, m = ours[name]
    _, _, b = brute[name]
    assert m.phase_margin_deg == pytest.approx(b["pm"], abs=0.01)
    assert m.crossover_rad_s == pytest.approx(b["wc"], rel=1e-3)


@pytest.mark.parametrize("name", STABLE)
def test_gain_margins_match_bruteforce(name, ours, brute):
    _, m = ours[name]
    _, _, b = brute[name]
    assert _same_db(m.gain_margin_db, b["gm_db"]), (m.gain_margin_db, b["gm_db"])
    assert _same_db(m.gain_margin_lower_db, b["gml_db"]), (m.gain_margin_lower_db, b["gml_db"])


@pytest.mark.parametrize("name", STABLE)
def test_gain_margins_are_where_the_closed_loop_changes_stability(name, ours, brute):
    """Third, unrelated check: roots of den + k num just inside and just outside each margin."""
    _, m = ours[name]
    n, d, _ = brute[name]
    dt = CASES[name].dt
    if math.isfinite(m.gain_margin_db):
        k = 10 ** (m.gain_margin_db / 20)
        assert k > 1
        assert ref.stable_at_gain(n, d, k * (1 - 1e-4), dt)
        assert not ref.stable_at_gain(n, d, k * (1 + 1e-4), dt)
    else:  # no upper limit: stable however much the gain is raised (checked over six decades)
        assert all(ref.stable_at_gain(n, d, k, dt) for k in np.logspace(0, 6, 61))
    if math.isfinite(m.gain_margin_lower_db):
        k = 10 ** (m.gain_margin_lower_db / 20)
        assert k < 1
        assert ref.stable_at_gain(n, d, k * (1 + 1e-4), dt)
        assert not ref.stable_at_gain(n, d, k * (1 - 1e-4), dt)
    else:
        assert all(ref.stable_at_gain(n, d, k, dt) for k in np.logspace(-6, 0, 61))


@pytest.mark.parametrize("name", STABLE)
def test_disk_margin_and_ms_match_bruteforce(name, ours, brute):
    _, m = ours[name]
    _, _, b = brute[name]
    # balanced disk margin = min over w of 2|1+L|/|1-L|; Ms = max over w of 1/|1+L|
    assert m.disk_margin == pytest.approx(ref.disk_margin_bruteforce(b["L"]), rel=1e-3)
    assert m.ms == pytest.approx(ref.ms_bruteforce(b["L"]), rel=1e-4)


def test_conditionally_stable_loop_has_both_margins(ours):
    _, m = ours["conditionally_stable"]
    assert 0 < m.gain_margin_db < math.inf
    assert -math.inf < m.gain_margin_lower_db < 0


def test_open_loop_unstable_plant_lower_margin_by_routh(ours):
    # PI: k (3s+1)/(s(s-1)): char s^2 + (3k-1) s + k, stable iff k > 1/3
    # lead: k 30(s+2)/((s+20)(s-1)): char s^2 + (19+30k) s + (60k-20), stable iff k > 1/3 as well
    for name in ("unstable_pi", "unstable_lead"):
        _, m = ours[name]
        assert m.gain_margin_lower_db == pytest.approx(20 * math.log10(1 / 3), abs=1e-6), name
        assert m.gain_margin_db == math.inf, name


def test_unstable_plant_pi_phase_margin_closed_form(ours):
    # |L(jw)| = 1 for L = (3s+1)/(s(s-1)): 9w^2 + 1 = w^2 (w^2 + 1) -> w^2 = 4 + sqrt(17)
    w = math.sqrt(4 + math.sqrt(17))
    L = (1 + 3j * w) / (1j * w * (1j * w - 1))
    pm = 180 + math.degrees(np.angle(L))
    _, m = ours["unstable_pi"]
    assert m.crossover_rad_s == pytest.approx(w, rel=1e-9)
    assert m.phase_margin_deg == pytest.approx(pm, abs=1e-6)


def test_double_integrator_with_lead_closed_form(ours):
    # L = 0.5 (2s+1)/(s^2 (s/2+1)): |L(j1)| = 0.5 sqrt(5)/sqrt(1.25) = 1, so wc = 1 and
    # PM = atan(1/0.5) - atan(1/2) = 36.87 deg (the lead's maximum, asin(3/5)); the phase stays above
    # -180 deg for all w > 0, so neither gain margin exists
    _, m = ours["double_integrator_lead"]
    assert m.crossover_rad_s == pytest.approx(1.0, rel=1e-9)
    assert m.phase_margin_deg == pytest.approx(math.degrees(math.asin(0.6)), abs=1e-6)
    assert m.gain_margin_db == math.inf
    assert m.gain_margin_lower_db == -math.inf
    # sampled at 0.04 the ZOH adds lag: a finite upper margin appears, still no lower one
    _, md = ours["double_integrator_lead_dt"]
    assert math.isfinite(md.gain_margin_db) and md.gain_margin_lower_db == -math.inf


def test_three_crossings_worst_is_not_the_first(ours, brute):
    _, _, b = brute["three_gain_crossings"]
    L = b["L"]
    m_ = np.log(np.abs(L))
    idx = np.flatnonzero(np.sign(m_[:-1]) * np.sign(m_[1:]) < 0)
    assert idx.size == 3
    pms = [180 + math.degrees(np.angle(L[i])) for i in idx]
    assert np.argmin(pms) == 2 and pms[0] - pms[2] > 30
    _, m = ours["three_gain_crossings"]
    assert m.phase_margin_deg == pytest.approx(min(pms), abs=0.05)


# -- where control.margin misleads -------------------------------------------------------------

@pytest.mark.parametrize("name, k_true", [("altitude", 12.5), ("altitude_gm6", 12.5 / 6.265)])
def test_discrete_integrating_loop_where_control_margin_misleads(name, k_true, ours, brute):
    """Altitude loop L = k 0.04 (5z-3)/(z-1)^2.

    Jury for z^2 + (0.2k - 2) z + (1 - 0.12k): P(1) = 0.08k > 0, P(-1) = 4 - 0.32k > 0,
    |1 - 0.12k| < 1: stable iff 0 < k < 12.5; the limit is at z = -1 (the Nyquist frequency),
    so the true upper gain margin is 20 log10(12.5) = 21.94 dB, and no lower margin exists.
    python-control reports a tiny "gain margin" (about -200 dB) at a frequency near zero instead.
    """
    _, m = ours[name]
    _, _, b = brute[name]
    gm_true = 20 * math.log10(k_true)
    assert b["gm_db"] == pytest.approx(gm_true, abs=1e-6)
    assert m.gain_margin_db == pytest.approx(gm_true, abs=1e-6)
    assert m.gain_margin_lower_db == -math.inf
    n, d, _ = brute[name]
    L = ct.tf(n, d, DT)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gm_ct, pm_ct, _, _ = ct.stability_margins(L)[:4]
    gm_ct_db = 20 * math.log10(gm_ct)
    assert gm_ct_db < -100  # nonsense, and not the stability limit
    # and nothing happens at python-control's "margin": the loop is stable on both sides of it
    assert ref.stable_at_gain(n, d, gm_ct * 0.5, DT)
    assert ref.stable_at_gain(n, d, gm_ct * 2.0, DT)
    assert abs(gm_ct_db - gm_true) > 100
    # the phase margins agree (there is a single gain crossing)
    assert m.phase_margin_deg == pytest.approx(pm_ct, abs=1e-3)


def test_altitude_gm6_is_six_db(ours):
    _, m = ours["altitude_gm6"]
    assert m.gain_margin_db == pytest.approx(6.0, abs=0.01)


# -- a loop with hand-derivable everything ------------------------------------------------------

def test_integrator_loop_one_over_z_minus_one_by_hand():
    """L = 1/(z - 1) (P = 25 on 0.04/(z-1)).

    |L| = 1 where |z - 1| = 1: z = exp(j pi/3), wc = pi/(3 dt); L there = exp(-j 2pi/3): PM = 60 deg.
    At z = -1, L = -1/2: upper GM = 20 log10 2 = 6.02 dB. 1 + L = z/(z-1): |S| = |z - 1| <= 2 = Ms (at z=-1).
    Disk margin: 2|1+L|/|1-L| = 2/|z - 2| >= 2/3 (at z = -1). T = 1/z: |T| = 1 everywhere, no bandwidth.
    """
    loop = build_loop(make_plant([0.04], [1, -1], dt=DT), ControllerTF(np.array([25.0]), np.array([1.0]), DT))
    m = margins(loop)
    assert m.phase_margin_deg == pytest.approx(60.0, abs=1e-6)
    assert m.crossover_rad_s == pytest.approx(math.pi / (3 * DT), rel=1e-9)
    assert m.gain_margin_db == pytest.approx(20 * math.log10(2), abs=1e-9)
    assert m.gain_margin_lower_db == -math.inf
    assert m.phase_crossover_rad_s == pytest.approx(math.pi / DT)
    assert m.ms == pytest.approx(2.0, rel=1e-9)
    assert m.disk_margin == pytest.approx(2 / 3, rel=1e-9)
    assert m.bandwidth_rad_s == math.inf


# -- bandwidth ------------------------------------------------------------------------------------

def test_bandwidth_first_order_closed_loop():
    # L = 2/s: T = 2/(s + 2), |T| = 1/sqrt(2) at w = 2
    loop = build_loop(make_plant([2], [1, 0]), controller_tf("p", {"Kp": 1}, dt=None))
    assert margins(loop).bandwidth_rad_s == pytest.approx(2.0, rel=1e-9)


@pytest.mark.parametrize("zeta", [0.2, 0.5, 0.7])
def test_bandwidth_second_order_closed_loop(zeta):
    # T = wn^2/(s^2 + 2 zeta wn s + wn^2): wb = wn sqrt(1 - 2 zeta^2 + sqrt(4 zeta^4 - 4 zeta^2 + 2))
    wn = 3.0
    loop = build_loop(make_plant([wn**2], [1, 2 * zeta * wn, 0]), controller_tf("p", {"Kp": 1}, dt=None))
    wb = wn * math.sqrt(1 - 2 * zeta**2 + math.sqrt(4 * zeta**4 - 4 * zeta**2 + 2))
    assert margins(loop).bandwidth_rad_s == pytest.approx(wb, rel=1e-8)


# -- delay ----------------------------------------------------------------------------------------

TAU = 0.5
W_U = optimize.brentq(lambda w: math.atan(w) + w * TAU - math.pi, 0.1, 10.0)  # phase -180 deg
K_U = math.hypot(1.0, W_U)  # |G(j w_u)| = 1/sqrt(1 + w_u^2)


@pytest.mark.parametrize("frac", [0.3, 0.9, 1.1])
def test_first_order_with_delay_margins_closed_form(frac):
    """K e^{-0.5 s}/(s + 1): ultimate gain from atan(w) + 0.5 w = pi; PM from |L| = 1 at w = sqrt(K^2 - 1)."""
    K = frac * K_U
    loop = build_loop(make_plant([1], [1, 1], delay=TAU), controller_tf("p", {"Kp": K}, dt=None))
    m = margins(loop)
    if frac < 1:
        assert m.gain_margin_db == pytest.approx(20 * math.log10(K_U / K), abs=1e-6)
    else:  # beyond the ultimate gain the crossing at -1/k lies inside -1: a lower margin
        assert m.gain_margin_lower_db == pytest.approx(20 * math.log10(K_U / K), abs=1e-6)
    if K > 1:
        wc = math.sqrt(K * K - 1)
        assert m.crossover_rad_s == pytest.approx(wc, rel=1e-8)
        # the signed classical value: 180 deg plus the phase unwrapped from low frequency (negative beyond K_U, where
        # the phase lag at the crossing exceeds 180 deg; its magnitude is the distance in phase from -1)
        signed = 180 - math.degrees(math.atan(wc) + wc * TAU)
        assert m.phase_margin_deg == pytest.approx(signed, abs=1e-6)
        assert (m.phase_margin_deg < 0) == (frac > 1)
    else:
        assert m.phase_margin_deg == math.inf  # |L| < 1 everywhere: no gain crossing


def test_a_lag_of_more_than_a_turn_is_the_distance_from_minus_one():
    """0.5 wn^2/(s^2 + 0.02 wn s + wn^2) e^{-0.0765 s}, wn = 226: a lightly damped mode's peak crosses |L| = 1 after
    the delay has lagged the phase by more than a turn (180 + the unwrapped phase is -522 and -1210 deg at the two
    crossings). The sign of 180 + phase says nothing there: the margin is the distance in phase from -1,
    180 - |principal angle|, at the nearer crossing (an identified pitch loop of a closed-loop PX4 log was reported at
    PM -634.9 deg with Ms 1.5 and a disk margin of 0.93). The crossings are found here from the closed form."""
    wn, zeta, tau, k = 226.0, 0.01, 0.0765, 0.5

    def G(w):
        return k * wn**2 / ((1j * w) ** 2 + 2 * zeta * wn * 1j * w + wn**2) * np.exp(-1j * w * tau)

    grid = np.linspace(1.0, 400.0, 400001)
    side = np.abs(G(grid)) - 1.0
    idx = np.flatnonzero(np.sign(side[:-1]) != np.sign(side[1:]))
    wcs = [optimize.brentq(lambda x: abs(G(x)) - 1.0, grid[i], grid[i + 1]) for i in idx]
    assert len(wcs) == 2
    unwrapped = [-math.degrees(math.atan2(2 * zeta * wn * w, wn**2 - w**2) + w * tau) for w in wcs]
    assert all(180 + u < -180 for u in unwrapped)  # the case: more than a turn of lag at every crossing
    distance = min(180 - abs(math.degrees(np.angle(G(w)))) for w in wcs)
    loop = build_loop(make_plant([k * wn**2], [1, 2 * zeta * wn, wn**2], delay=tau),
                      controller_tf("p", {"Kp": 1.0}, dt=None))
    assert margins(loop).phase_margin_deg == pytest.approx(distance, abs=1e-6)


@pytest.mark.parametrize("frac, stable", [(0.9, True), pytest.param(1.1, False, marks=pytest.mark.slow)])
def test_first_order_with_delay_stability_flips_at_the_ultimate_gain(frac, stable):
    # a P controller with a delay: regression for the static gain that Tustin turned into k(z-1)/(z-1)
    loop = build_loop(make_plant([1], [1, 1], delay=TAU), controller_tf("p", {"Kp": frac * K_U}, dt=None))
    assert is_stable(loop) is stable
