"""The saturated step (tuner.analysis.saturation): with limits that never bind it is the verifier's linear step;
a hand-checked saturated case between samples; the firmware laws' integrator handling; flags and fields."""

from __future__ import annotations

import json
import math

import control as ct
import numpy as np
import pytest

from tuner import analyze, controller_from_coeffs, controller_tf, make_plant
from tuner.analysis.saturation import Actuator, saturated_step
from tuner.cli import main
from tuner.errors import TunerError
from tuner.loop import build_loop

PLANT = make_plant([4.0], [1.0, 2.0, 4.0], delay=0.013)  # a fractional delay at dt = 0.01
DT = 0.01
WIDE = Actuator.of(u_max=1e9, step_size=0.01)  # small: PX4's fade, 1 - (e/400 deg/s)^2, is 1 to 2e-6

CASES = [
    ("pi", {"Kp": 0.6, "Ki": 1.2}),
    ("pid", {"Kp": 0.8, "Ki": 1.5, "Kd": 0.1, "Tf": 0.02}),
    ("pid_z", {"K": 0.9, "a1": -1.75, "a2": 0.77}),
    ("pid2", {"Kp": 0.8, "Ki": 1.5, "Kd": 0.1, "Tf": 0.02, "b": 0.7, "c": 0.0}),
    ("lead", {"K": 0.8, "wz": 2.0, "wp": 20.0}),
    ("px4_rate", {"P": 0.8, "I": 1.5, "D": 0.08, "FF": 0.1, "K": 1.0, "dgyro_hz": 20.0, "int_lim": 1e9}),
    ("px4_rate", {"P": 0.8, "I": 1.5, "D": 0.08, "FF": 0.1, "K": 1.0, "dgyro_hz": 10.0, "int_lim": 1e9,
                  "dgyro_order": 2.0, "raw_hz": 800.0}),  # the 2021-era D path on 8 raw samples per loop sample
    ("ardupilot_rate", {"P": 0.8, "I": 1.5, "D": 0.08, "FF": 0.1, "fltt_hz": 10.0, "flte_hz": 15.0,
                        "fltd_hz": 20.0, "imax": 1e9}),
]


@pytest.mark.parametrize("name, gains", CASES, ids=[c[0] for c in CASES])
def test_limits_that_never_bind_give_the_linear_step(name, gains):
    c = controller_tf(name, gains, dt=DT)
    a = analyze(PLANT, c)
    s = saturated_step(a.loop, WIDE, structure=name, gains=gains, horizon_s=float(a.response.t[-1]))
    assert s.saturated_fraction == 0.0
    n = a.response.t.size
    np.testing.assert_allclose(s.response.t[:n], a.response.t, atol=1e-12)
    np.testing.assert_allclose(s.response.y[:n] / WIDE.step_size, a.response.y,
                               atol=1e-6 * max(1.0, np.max(np.abs(a.response.y))))
    assert s.metrics.overshoot_pct == pytest.approx(a.metrics.overshoot_pct, abs=1e-3)  # (the fade: 1e-4)
    assert s.metrics.settling_time_s == pytest.approx(a.metrics.settling_time_s, rel=1e-4)


def test_amplitude_scales_a_linear_step():
    c = controller_tf("pi", {"Kp": 0.6, "Ki": 1.2}, dt=DT)
    loop = build_loop(PLANT, c)
    one = saturated_step(loop, Actuator.of(u_max=1e9, step_size=1.0), horizon_s=5)
    five = saturated_step(loop, Actuator.of(u_max=1e9, step_size=-5.0), horizon_s=5)
    np.testing.assert_allclose(five.response.y, -5.0 * one.response.y, atol=1e-9)
    assert five.metrics.settling_time_s == pytest.approx(one.metrics.settling_time_s)


def test_a_clamped_p_on_an_integrator_between_samples():
    """1/s with u = 2 e clamped to 1: the output ramps at slope 1 (exactly t between the samples) until e = 0.5,
    then e decays by (1 - 2 dt) per sample: y(9.5 + tau) = 10 - 0.5 (1 - 2 dt)^(tau/dt)."""
    loop = build_loop(make_plant([1.0], [1.0, 0.0]), controller_from_coeffs([2.0], [1.0], dt=DT))
    s = saturated_step(loop, Actuator.of(u_min=-1.0, u_max=1.0, step_size=10.0), horizon_s=12.0)
    t, y = s.response.t, s.response.y
    ramp = t <= 9.5 - DT
    np.testing.assert_allclose(y[ramp], t[ramp], atol=1e-12)
    k = np.arange(0, 200)
    tk = 9.5 + k * DT
    want = 10.0 - 0.5 * (1 - 2 * DT) ** k
    np.testing.assert_allclose(np.interp(tk, s.response.t_samples, s.response.y_samples), want, atol=1e-9)


def test_px4_integrator_limit_and_no_growth_into_saturation():
    """A plant of gain 0.1 (1/(10 s + 10)) with an I-only PX4 law: the output needs u = 10 r, beyond the limit 1;
    the integrator stops at int_lim (0.3) and the output saturates only if the P part pushes it there."""
    plant = make_plant([0.1], [1.0, 1.0])
    g = {"P": 0.0, "I": 5.0, "D": 0.0, "FF": 0.0, "K": 1.0, "dgyro_hz": 0.0, "int_lim": 0.3}
    loop = build_loop(plant, controller_tf("px4_rate", g, dt=DT))
    s = saturated_step(loop, Actuator.of(u_max=1.0, step_size=1.0), structure="px4_rate", gains=g, horizon_s=30)
    assert np.max(s.response.u) == pytest.approx(0.3)  # the integrator's limit, below the actuator's
    assert s.response.y_samples[-1] == pytest.approx(0.03, rel=1e-3)  # 0.1 x 0.3: a steady error
    g2 = dict(g, int_lim=5.0)
    s2 = saturated_step(build_loop(plant, controller_tf("px4_rate", g2, dt=DT)), Actuator.of(u_max=1.0),
                        structure="px4_rate", gains=g2, horizon_s=30)
    assert np.max(s2.response.u) == pytest.approx(1.0)  # the actuator's limit now
    # no growth into saturation: the integrator stops at the limit instead of winding up to int_lim = 5
    assert s2.response.y_samples[-1] == pytest.approx(0.1, rel=1e-3)


def test_px4_fade_stops_integration_for_large_errors():
    """An error of 400 deg/s and more integrates nothing (f_I = 0)."""
    plant = make_plant([0.01], [1.0, 1.0])
    g = {"P": 0.0, "I": 1.0, "D": 0.0, "FF": 0.0, "K": 1.0, "dgyro_hz": 0.0, "int_lim": 10.0}
    loop = build_loop(plant, controller_tf("px4_rate", g, dt=DT))
    big = math.radians(400.0) * 2
    s = saturated_step(loop, Actuator.of(u_max=100.0, step_size=big), structure="px4_rate", gains=g, horizon_s=1)
    assert np.max(np.abs(s.response.u)) == 0.0


def test_ardupilot_imax_and_the_limit_flag():
    plant = make_plant([0.1], [1.0, 1.0])
    g = {"P": 0.0, "I": 5.0, "D": 0.0, "FF": 0.0, "fltt_hz": 0.0, "flte_hz": 0.0, "fltd_hz": 0.0, "imax": 0.3}
    loop = build_loop(plant, controller_tf("ardupilot_rate", g, dt=DT))
    s = saturated_step(loop, Actuator.of(u_max=1.0), structure="ardupilot_rate", gains=g, horizon_s=30)
    assert np.max(s.response.u) == pytest.approx(0.3)
    g2 = dict(g, imax=1.0, P=2.0)
    s2 = saturated_step(build_loop(plant, controller_tf("ardupilot_rate", g2, dt=DT)), Actuator.of(u_max=0.5),
                        structure="ardupilot_rate", gains=g2, horizon_s=30)
    # limited: the integrator only shrinks, so it never passes the value it had when the output first clamped
    u = s2.response.u[::20]  # per sample
    first = int(np.argmax(u >= 0.5 - 1e-12))
    e_first = 1.0 - s2.response.y_samples[first]
    i_first = u[first - 1] - 2.0 * (1.0 - s2.response.y_samples[first - 1]) if first else 0.0
    assert e_first > 0 and i_first <= 0.5 + 1e-9


@pytest.mark.parametrize("kw, field", [({"u_min": 1.0, "u_max": 0.5}, "u_min"), ({"u_max": math.inf}, "u_max"),
                                       ({"step_size": 1.0}, "u_max"), ({"u_max": 1.0, "step_size": 0.0}, "step_size")])
def test_actuator_validation(kw, field):
    with pytest.raises(TunerError) as ei:
        Actuator.of(**kw)
    assert ei.value.field == (field,)


def test_continuous_loops_are_refused():
    loop = build_loop(PLANT, controller_from_coeffs([1.0, 1.0], [1.0, 0.0], dt=None))
    with pytest.raises(TunerError, match="give dt"):
        saturated_step(loop, Actuator.of(u_max=1.0))


def test_cli_analyze_with_limits(capsys):
    args = ["analyze", "--plant", "4/(s^2+2*s+4)", "--delay", "0.013", "--dt", "0.01",
            "--controller", "(0.612*z - 0.6)/(z - 1)"]
    assert main(args + ["--u-max", "0.8", "--step-size", "2", "--json"]) in (0, 1)
    out = json.loads(capsys.readouterr().out)
    assert out["saturated_step"]["u_max"] == 0.8 and out["saturated_step"]["step_size"] == 2.0
    assert any(c["name"] == "saturated_overshoot_pct" for c in out["checks"])
    assert main(args + ["--step-size", "2"]) == 2
    assert "--step-size" in capsys.readouterr().err
    assert main(args + ["--u-min", "1", "--u-max", "0.5"]) == 2
    assert "--u-min" in capsys.readouterr().err
    assert main(["analyze", "--plant", "1/(s+1)", "--controller", "1/s", "--u-max", "1"]) == 2
    assert "sample time" in capsys.readouterr().err


def test_tune_without_limits_is_unchanged():
    r = analyze(ct.tf([1], [1, 1]), ct.c2d(ct.tf([2, 2], [1, 0]), 0.05), dt=0.05)
    assert r.saturated is None and "saturated_step" not in r.to_dict()
