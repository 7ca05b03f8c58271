"""Step metrics against closed forms and an independent fine simulation (matrix exponential)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import reference as ref
from numpy.testing import assert_allclose
from quadrotor import DT, ROLL, ROLL_C
from scipy import signal

from tuner.analysis.response import is_stable, step_metrics, step_response
from tuner.analysis.verify import analyze
from tuner.controllers import ControllerTF, controller_from_expr, controller_tf
from tuner.loop import build_loop
from tuner.plant import make_plant, plant_from_expr
from tuner.spec import Spec

# -- first order: PI that cancels the plant pole, L = wc/s -------------------------------------

A, WC = 2.0, 5.0  # plant a/(s+a); PI Kp = wc/a, Ki = wc  ->  C G = wc (s+a)/(s (s+a)) = wc/s


@pytest.fixture(scope="module")
def first_order():
    p = make_plant([A], [1, A])
    c = controller_tf("pi", {"Kp": WC / A, "Ki": WC}, dt=None)
    return analyze(p, c)


def test_first_order_settling_rise_overshoot(first_order):
    # y = 1 - exp(-wc t): 2 % band at ln(50)/wc; 10 % at ln(10/9)/wc, 90 % at ln(10)/wc
    m = first_order.metrics
    assert m.settling_time_s == pytest.approx(math.log(50) / WC, rel=1e-5)
    assert m.rise_time_s == pytest.approx(math.log(9) / WC, rel=1e-5)
    assert m.overshoot_pct == pytest.approx(0.0, abs=1e-9)
    assert m.steady_state_error == pytest.approx(0.0, abs=1e-12)


def test_first_order_control_signal(first_order):
    # u = C S r = (Kp s + Ki)/(s + wc): u(0+) = Kp = 2.5, u(inf) = Ki/wc = 1; u = 1 + (Kp - 1) exp(-wc t)
    r = first_order.response
    assert first_order.metrics.control_peak == pytest.approx(WC / A, rel=1e-9)
    expected = 1 + (WC / A - 1) * np.exp(-WC * r.t)
    assert_allclose(r.u, expected, atol=1e-9)
    assert_allclose(r.y, 1 - np.exp(-WC * r.t), atol=1e-9)


def test_settling_band_is_configurable():
    p = make_plant([A], [1, A])
    c = controller_tf("pi", {"Kp": WC / A, "Ki": WC}, dt=None)
    m = analyze(p, c, Spec(settling_band_pct=5.0)).metrics
    assert m.settling_time_s == pytest.approx(math.log(20) / WC, rel=1e-5)  # exp(-wc t) = 0.05


def test_not_settled_within_horizon_is_inf():
    loop = build_loop(make_plant([A], [1, A]), controller_tf("pi", {"Kp": WC / A, "Ki": WC}, dt=None))
    # horizon 0.7 ln(50)/wc = 0.55 s: past the 90 % time ln(10)/wc = 0.46 s, before settling at 0.78 s
    r = step_response(loop, horizon_s=0.7 * math.log(50) / WC)
    m = step_metrics(r)
    assert m.settling_time_s == math.inf
    assert m.rise_time_s == pytest.approx(math.log(9) / WC, rel=1e-4)
    # a horizon that ends before 90 %: the rise time is not defined
    assert math.isnan(step_metrics(step_response(loop, horizon_s=0.4)).rise_time_s)


def test_type0_loop_steady_state_error_by_hand():
    # P = 4 on 1/(s+1): T = 4/(s+5), y_final = 0.8, error 0.2; y = 0.8 (1 - exp(-5t))
    a = analyze(make_plant([1], [1, 1]), controller_tf("p", {"Kp": 4}, dt=None))
    m = a.metrics
    assert m.steady_state_error == pytest.approx(0.2, abs=1e-12)
    assert m.settling_time_s == pytest.approx(math.log(50) / 5, rel=1e-5)
    assert m.overshoot_pct == pytest.approx(0.0, abs=1e-9)
    assert m.control_peak == pytest.approx(4.0)  # u(0+) = Kp
    assert not a.meets_spec and [c.name for c in a.failing] == ["steady_state_error"]


# -- second order with known damping ------------------------------------------------------------

@pytest.mark.parametrize("zeta", [0.2, 0.5, 0.7])
def test_second_order_overshoot_and_settling(zeta):
    """P = 1 on wn^2/(s (s + 2 zeta wn)): T = wn^2/(s^2 + 2 zeta wn s + wn^2).

    Overshoot 100 exp(-zeta pi/sqrt(1-zeta^2)); settling and rise from the analytic response
    y = 1 - exp(-zeta wn t)/sqrt(1-zeta^2) sin(wd t + acos zeta), evaluated on 2e6 points here.
    """
    wn = 3.0
    a = analyze(make_plant([wn**2], [1, 2 * zeta * wn, 0]), controller_tf("p", {"Kp": 1}, dt=None))
    m = a.metrics
    assert m.overshoot_pct == pytest.approx(100 * math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2)), abs=1e-4)
    wd = wn * math.sqrt(1 - zeta**2)
    t = np.linspace(0, a.response.t[-1], 2_000_001)
    y = 1 - np.exp(-zeta * wn * t) / math.sqrt(1 - zeta**2) * np.sin(wd * t + math.acos(zeta))
    assert m.settling_time_s == pytest.approx(ref.settling_time(t, y, 1.0), abs=1e-4)
    t10 = t[np.argmax(y >= 0.1)]
    t90 = t[np.argmax(y >= 0.9)]
    assert m.rise_time_s == pytest.approx(t90 - t10, abs=1e-4)
    assert_allclose(a.response.y, np.interp(a.response.t, t, y), atol=1e-6)


# -- sampled data: ripple between samples --------------------------------------------------------

@pytest.fixture(scope="module")
def ripple():
    """A deadbeat digital controller on the roll model that hides ripple between samples.

    With the ZOH model G(z) = (b1 z + b0)/(z^2 + a1 z + a2), the controller
    C(z) = (z^2 + a1 z + a2)/((b1 z + b0)(z - 1)) cancels the plant's poles *and* its sampled
    zero at -b0/b1 = -0.826, so C G = 1/(z - 1) and T(z) = 1/z: at the samples the output is 1 from
    the first sample on. The control u = T/G = (z^2 + a1 z + a2)/(z (b1 z + b0)) rings as
    (-0.826)^k, and so does the continuous output between samples.
    """
    gn, gd = [0.2655 * 14.8528**2], [1, 14.195, 14.8528**2]
    (b1, b0), (_, a1, a2) = ref.zoh(gn, gd, DT)
    c = ControllerTF(num=np.array([1, a1, a2]), den=np.polymul([b1, b0], [1, -1]), dt=DT)
    a = analyze(make_plant(gn, gd), c)
    return a, (gn, gd), (b1, b0, a1, a2)


def test_ripple_sampled_output_settles_in_one_sample(ripple):
    a, _, _ = ripple
    r = a.response
    assert r.between_samples
    assert_allclose(r.y_samples[0], 0.0, atol=1e-12)
    assert_allclose(r.y_samples[1:], 1.0, atol=1e-9)  # T(z) = 1/z
    # so the settling time at sample instants is one sample
    assert ref.settling_time(r.t_samples, r.y_samples, 1.0) <= DT


def test_ripple_control_sequence_matches_independent_discrete_simulation(ripple):
    a, _, (b1, b0, a1, a2) = ripple
    r = a.response
    k = r.t_samples.size
    # u = (z^2 + a1 z + a2)/(z (b1 z + b0)) on a unit step, by scipy.signal.lfilter here
    u = signal.lfilter([1, a1, a2], np.polymul([1, 0], [b1, b0]), np.ones(k))
    n = r.t.size // k
    assert_allclose(r.u[::n], u, rtol=1e-9, atol=1e-9)
    assert u[1] * u[2] < 0  # it alternates in sign: the ringing


def test_ripple_continuous_settling_matches_fine_simulation(ripple):
    a, (gn, gd), (b1, b0, a1, a2) = ripple
    m = a.metrics
    k = a.response.t_samples.size
    u = signal.lfilter([1, a1, a2], np.polymul([1, 0], [b1, b0]), np.ones(k))
    t, y = ref.fine_step(gn, gd, u, DT, 400)  # plant driven by the staircase, 400 points per sample
    ts_fine = ref.settling_time(t, y, 1.0)
    # the continuous output rings for many samples after the sampled output has settled
    assert ts_fine > 10 * DT
    assert m.settling_time_s > 10 * DT
    assert m.settling_time_s == pytest.approx(ts_fine, abs=0.001)
    # and the overshoot is between samples, invisible at the samples (all exactly 1)
    peak_fine = 100 * (y.max() - 1)
    assert peak_fine > 20
    assert m.overshoot_pct == pytest.approx(peak_fine, abs=0.05)
    # the library's fine output agrees with the matrix-exponential simulation at common instants
    r = a.response
    n = r.t.size // k
    assert_allclose(r.y, np.interp(r.t, t, y), atol=1e-9)
    assert_allclose(r.y[::n], y[::400][: r.t_samples.size], atol=1e-8)


def test_thesis_roll_between_samples_matches_fine_simulation():
    a = analyze(plant_from_expr(ROLL), controller_from_expr(ROLL_C, dt=DT))
    r = a.response
    k = r.t_samples.size
    gn, gd = [0.2655 * 14.8528**2], [1, 14.195, 14.8528**2]
    b, d = ref.zoh(gn, gd, DT)
    ln = np.polymul(3.868 * np.array([1, -1.305, 0.5668]), b)
    ld = np.polymul([1, -1, 0], d)
    cp = np.polyadd(ld, ln)
    u = signal.lfilter(np.polymul(3.868 * np.array([1, -1.305, 0.5668]), d), cp, np.ones(k))
    ys = signal.lfilter(np.concatenate([[0.0], ln]) if ln.size < cp.size else ln, cp, np.ones(k))
    assert_allclose(r.y_samples, ys, atol=1e-9)
    t, y = ref.fine_step(gn, gd, u, DT, 200)
    assert a.metrics.settling_time_s == pytest.approx(ref.settling_time(t, y, 1.0), abs=0.002)
    assert a.metrics.control_peak == pytest.approx(np.max(np.abs(u)), rel=1e-9)
    assert a.metrics.control_peak == pytest.approx(3.868, rel=1e-9)  # u[0] = K: the largest


# -- unstable loops and the nan/inf conventions ------------------------------------------------

def test_unstable_loop_step_metrics_are_undefined():
    # P = 1 on 2/((s-1)(s+3)): char (s-1)(s+3) + 2 = s^2 + 2s - 1, a root at -1 + sqrt(2) > 0
    a = analyze(make_plant([2], [1, 2, -3]), controller_tf("p", {"Kp": 1}, dt=None))
    m = a.metrics
    assert not m.stable
    assert max(np.roots([1, 2, -1]).real) > 0
    assert math.isnan(m.overshoot_pct) and math.isnan(m.rise_time_s) and math.isnan(m.steady_state_error)
    assert m.settling_time_s == math.inf
    assert a.response is None
    assert not a.meets_spec


def test_discrete_plant_without_continuous_equivalent_reports_samples_only():
    # pole at z = -0.5 is not exp(p dt) of any real p: no output between samples can be claimed
    loop = build_loop(make_plant([1.5], [1, 0.5], dt=0.1), controller_from_expr("0.2*z/(z-1)", dt=0.1))
    assert is_stable(loop)
    r = step_response(loop)
    assert not r.between_samples
    assert_allclose(r.t, r.t_samples)


def test_discrete_plant_with_continuous_equivalent_uses_it_between_samples():
    # 0.04/(z-1) at 0.04 is the ZOH of 1/s: with PI 5 + 2/(z-1) the output between samples is the
    # integral of the staircase u, i.e. linear between sample values
    loop = build_loop(make_plant([0.04], [1, -1], dt=DT), controller_from_expr("5+2/(z-1)", dt=DT))
    r = step_response(loop)
    assert r.between_samples
    k = r.t_samples.size
    n = r.t.size // k
    y_lin = np.interp(r.t, r.t_samples, r.y_samples)
    assert_allclose(r.y[: (k - 1) * n], y_lin[: (k - 1) * n], atol=1e-9)
