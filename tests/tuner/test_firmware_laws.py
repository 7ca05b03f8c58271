"""The firmware rate laws ``px4_rate`` and ``ardupilot_rate``: their transfer functions against the laws run sample by
sample as the firmware runs them (written here from the sources quoted in ../shared/reference/firmware.md, in the
linear range: no clamp binds), the fixed values carried in the gains, and tuning them."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from tuner import tune
from tuner.controllers import get_structure
from tuner.errors import TunerError

DT = 0.0025  # 400 Hz


def _alpha(f_hz: float, dt: float) -> float:
    return 1.0 if f_hz <= 0 else dt / (dt + 1.0 / (2.0 * math.pi * f_hz))


def px4_law(r: np.ndarray, w: np.ndarray, g: dict, dt: float) -> np.ndarray:
    """PX4's RateControl::update, per sample (no saturation, the integrator far from its limit)."""
    kp, ki, kd = g["K"] * g["P"], g["K"] * g["I"], g["K"] * g["D"]
    a = _alpha(g["dgyro_hz"], dt)
    x_i, w_prev, wdot_f = 0.0, 0.0, 0.0
    u = np.zeros(r.size)
    for k in range(r.size):
        e = r[k] - w[k]
        wdot = (w[k] - w_prev) / dt  # the derivative of the filtered rate
        wdot_f += a * (wdot - wdot_f)  # AlphaFilter at IMU_DGYRO_CUTOFF
        w_prev = w[k]
        u[k] = kp * e + x_i - kd * wdot_f + g["FF"] * r[k]  # the integrator before this sample's update
        x_i += ki * e * dt
    return u


def ardupilot_law(target: np.ndarray, w: np.ndarray, g: dict, dt: float) -> np.ndarray:
    """ArduPilot's AC_PID::update_all plus the FF it sends to the mixer, per sample (no limit reached)."""
    at, ae, ad = _alpha(g["fltt_hz"], dt), _alpha(g["flte_hz"], dt), _alpha(g["fltd_hz"], dt)
    T = E = D = integ = 0.0
    e_prev = 0.0
    u = np.zeros(target.size)
    for k in range(target.size):
        T += at * (target[k] - T)
        E += ae * ((T - w[k]) - E)
        D += ad * ((E - e_prev) / dt - D)
        e_prev = E
        integ += g["I"] * E * dt  # updated before the output
        u[k] = g["P"] * E + g["D"] * D + integ + g["FF"] * T
    return u


def _tf_output(ctrl, r, w):
    """``u = C_r r - C_fb w`` from the structure's transfer functions (lfilter from rest)."""
    return signal.lfilter(ctrl.num_r, ctrl.den, r) - signal.lfilter(ctrl.num, ctrl.den, w)


@pytest.mark.parametrize("gains", [
    {"P": 0.15, "I": 0.2, "D": 0.003, "FF": 0.0, "K": 1.0, "dgyro_hz": 20.0, "int_lim": 0.3},
    {"P": 1.0, "I": 0.5, "D": 0.02, "FF": 0.1, "K": 0.35, "dgyro_hz": 30.0, "int_lim": 0.3},
    {"P": 0.2, "I": 0.1, "D": 0.004, "FF": 0.05, "K": 1.0, "dgyro_hz": 0.0, "int_lim": 0.3},  # no D filter
])
def test_px4_rate_is_the_firmware_law(gains):
    rng = np.random.default_rng(0)
    r, w = rng.standard_normal(400), rng.standard_normal(400)
    ctrl = get_structure("px4_rate").tf(gains, DT)
    np.testing.assert_allclose(_tf_output(ctrl, r, w), px4_law(r, w, gains, DT), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("gains", [
    {"P": 0.135, "I": 0.135, "D": 0.0036, "FF": 0.0, "fltt_hz": 20.0, "flte_hz": 0.0, "fltd_hz": 20.0, "imax": 0.5},
    {"P": 0.2, "I": 0.3, "D": 0.005, "FF": 0.08, "fltt_hz": 15.0, "flte_hz": 40.0, "fltd_hz": 25.0, "imax": 0.5},
    {"P": 0.2, "I": 0.3, "D": 0.005, "FF": 0.08, "fltt_hz": 0.0, "flte_hz": 0.0, "fltd_hz": 0.0, "imax": 0.5},
])
def test_ardupilot_rate_is_the_firmware_law(gains):
    rng = np.random.default_rng(1)
    r, w = rng.standard_normal(400), rng.standard_normal(400)
    ctrl = get_structure("ardupilot_rate").tf(gains, DT)
    np.testing.assert_allclose(_tf_output(ctrl, r, w), ardupilot_law(r, w, gains, DT), rtol=1e-9, atol=1e-9)


def test_fixed_values_travel_with_the_gains():
    st = get_structure("px4_rate")
    g = {"P": 0.3, "I": 0.2, "D": 0.01, "FF": 0.0, "K": 0.5, "dgyro_hz": 25.0, "int_lim": 0.3}
    c = st.tf(g, DT)  # the fixed values in the gains rebuild the vehicle's law
    bound = st.with_fixed({"K": 0.5, "dgyro_hz": 25.0})
    c2 = bound.tf({k: g[k] for k in ("P", "I", "D", "FF")}, DT)
    np.testing.assert_allclose(c.num, c2.num)
    np.testing.assert_allclose(c.num_r, c2.num_r)
    assert bound.named([0.3, 0.2, 0.01, 0.0])["K"] == 0.5
    assert bound.key != st.key  # an NLP built for one vehicle is not reused for another


@pytest.mark.parametrize("bad, what", [({"K": 0.0}, "K"), ({"dgyro_hz": -1.0}, "dgyro_hz"),
                                       ({"K": math.nan}, "K"), ({"Kx": 1.0}, "unknown")])
def test_fixed_values_are_validated(bad, what):
    with pytest.raises(TunerError, match=what):
        get_structure("px4_rate").with_fixed(bad)


def test_firmware_gains_are_nonnegative_and_discrete():
    st = get_structure("ardupilot_rate")
    with pytest.raises(TunerError, match="FF must be >= 0"):
        st.tf({"P": 0.1, "I": 0.1, "D": 0.0, "FF": -0.1}, DT)
    with pytest.raises(TunerError, match="discrete"):
        st.tf({"P": 0.1, "I": 0.1, "D": 0.0, "FF": 0.0}, None)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["px4_rate", "ardupilot_rate"])
def test_tune_a_rate_law(name):
    """A roll-rate plant (torque to rate, with the gyro low-pass and a sample of delay), tuned at 400 Hz: the design
    meets the spec, its gains are the firmware's (>= 0, the fixed values as given) and its step, run sample by sample
    through the law above on the plant's exact ZOH discretisation, is the verifier's (at the samples)."""
    import control as ct

    G = ct.tf([25.0], [0.02, 1.0, 0.0]) * ct.tf([1.0], [1 / (2 * math.pi * 40) ** 2, 1.4 / (2 * math.pi * 40), 1])
    res = tune(G, structure=name, dt=DT, delay=DT, time_budget_s=10)
    assert res.meets_spec
    g = res.gains
    assert all(g[p] >= 0 for p in ("P", "I", "D", "FF"))
    Gd = ct.c2d(ct.ss(G), DT, "zoh")
    A, B, C = (np.asarray(m, float) for m in (Gd.A, Gd.B, Gd.C))
    n = 400
    x, u_hist, ys = np.zeros(A.shape[0]), [0.0], []
    law = px4_law if name == "px4_rate" else ardupilot_law
    r = np.ones(n)
    w = np.zeros(n)
    for k in range(n):  # one sample of delay: the output at k uses u[k-1]; closed loop by re-running the law
        w[k] = float((C @ x).ravel()[0])  # strictly proper: no feedthrough
        u = law(r[:k + 1], w[:k + 1], g, DT)[-1]
        u_hist.append(u)
        x = A @ x + B.ravel() * u_hist[-2]
        ys.append(w[k])
    t = res.analyses[0].response.t
    y = res.analyses[0].response.y
    at_samples = np.interp(np.arange(n) * DT, t, y)
    np.testing.assert_allclose(np.asarray(ys), at_samples, atol=2e-3)
