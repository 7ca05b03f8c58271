"""Betaflight's rate PID (tuner/firmware/betaflight.py) against pidController written here from its source
(betaflight/betaflight src/main/flight/pid.c at 47f4485, pid_init.c's pidInitConfig, mixer.c's PID_MIXER_SCALING),
in the firmware's own units (deg/s in, the PID sum out), and its CLI files. The contract suite
(test_contract.py) covers what every firmware must do; these are Betaflight's own facts."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from tuner.controllers import get_structure
from tuner.errors import TunerError
from tuner.export.paramfile import make_param_file
from tuner.firmware.params import read_params, vehicle_from_text

DT = 1.0 / 8000.0

DUMP = """# diff all
# version
# Betaflight / STM32F7X2 (S7X2) 4.4.2
board_name MATEKF722
feature -AIRMODE
set gyro_lpf1_static_hz = 0
set dterm_lpf1_dyn_min_hz = 75
set dterm_lpf1_dyn_max_hz = 150
set dterm_lpf1_type = PT1
set pid_process_denom = 2
profile 1
set p_roll = 60
profile 0
set p_roll = 45
set i_roll = 80
set d_roll = 40
set f_roll = 120
set d_min_roll = 30
set iterm_relax = RP
set p_yaw = 45
set i_yaw = 80
set d_yaw = 0
set f_yaw = 120
rateprofile 0
set roll_rc_rate = 100
# restore original profile selection
profile 0
save
"""


def pid_controller(r_dps, y_dps, P, I, D, F, *, lpf1, lpf2, yaw_lpf, yaw, dt):  # noqa: E741 (pid.h's names)
    """pidController per loop (no limit reached): the PID sum, in PID units, from setpoints and gyro in deg/s."""
    kp, ki, kd, kf = 0.032029 * P, 0.244381 * I, 0.000529 * D, 0.013754 * (F * 0.01)
    if yaw:
        ki *= 2.5  # pid_init.c: pidCoefficient[FD_YAW].Ki *= 2.5f

    def k(f):  # pt1FilterGain
        return 1.0 if f <= 0 else dt / (1.0 / (2 * math.pi * f) + dt)

    s1 = s2 = prev_g = i_term = prev_sp = p_state = 0.0
    out = []
    for sp, gyro in zip(r_dps, y_dps):
        s1 = s1 + k(lpf1) * (gyro - s1)
        s2 = s2 + k(lpf2) * (s1 - s2)
        err = sp - gyro
        p = kp * err
        if yaw:
            p_state = p_state + k(yaw_lpf) * (p - p_state)
            p = p_state
        i_term = i_term + ki * dt * err
        d = kd * -(s2 - prev_g) / dt
        prev_g = s2
        f = kf * (sp - prev_sp) / dt
        prev_sp = sp
        out.append(p + i_term + d + f)
    return np.array(out)


@pytest.mark.parametrize("axis", ["roll", "yaw"])
def test_the_law_is_pidcontroller(axis):
    rng = np.random.default_rng(5)
    r, w = rng.standard_normal(800), rng.standard_normal(800)  # rad/s
    st = get_structure("betaflight_rate")
    fixed = {**st.fixed_values, **({"yaw_lpf_hz": 100.0, "i_mult": 2.5} if axis == "yaw" else {})}
    g = {"P": 45.0, "I": 80.0, "D": 40.0 if axis == "roll" else 10.0, "FF": 120.0, **fixed}
    c = st.tf(g, DT)
    u = signal.lfilter(c.num_r, c.den, r) - signal.lfilter(c.num, c.den, w)
    pid_sum = pid_controller(np.degrees(r), np.degrees(w), 45.0, 80.0, g["D"], 120.0, lpf1=75.0, lpf2=150.0,
                             yaw_lpf=100.0, yaw=axis == "yaw", dt=DT)
    # mixer.c: Sum / PID_MIXER_SCALING (the transfer function's poles near 1 at 8 kHz: 1e-10 of the output's scale)
    np.testing.assert_allclose(u, pid_sum / 1000.0, rtol=1e-9, atol=1e-9 * np.max(np.abs(u)))


def test_a_cli_diff_is_read_from_the_selected_profile():
    v = vehicle_from_text(DUMP, axis="roll", source="quad.txt")
    assert v.firmware == "betaflight"
    assert v.gains == {"P": 45.0, "I": 80.0, "D": 40.0, "FF": 120.0}  # profile 0's, not profile 1's 60
    assert v.fixed["dlpf1_hz"] == 75.0 and v.fixed["dlpf2_hz"] == 150.0 and v.fixed["i_mult"] == 1.0
    assert v.loop_hz == 4000.0 and "8 kHz" in v.loop_source  # 8 kHz over pid_process_denom 2, assumed and said
    text = " ".join(v.notes)
    assert "d_min_roll = 30" in text and "iterm_relax" in text and "dterm_lpf1_dyn_min_hz = 75" in text
    y = vehicle_from_text(DUMP, axis="yaw", source="quad.txt")
    assert y.fixed["i_mult"] == 2.5 and y.fixed["yaw_lpf_hz"] == 100.0  # yaw_lowpass_hz not in it: the default


@pytest.mark.parametrize("line, name", [("set dterm_lpf1_type = BIQUAD", "dterm_lpf1_type"),
                                        ("set dterm_lpf2_type = PT2", "dterm_lpf2_type"),
                                        ("set dterm_notch_hz = 260", "dterm_notch_hz")])
def test_what_the_model_does_not_hold_is_refused_by_name(line, name):
    with pytest.raises(TunerError, match=name):
        vehicle_from_text(DUMP + line + "\n", axis="roll", source="quad.txt")


def test_a_word_where_the_law_reads_a_number_is_refused_and_a_filter_beyond_its_range_said():
    # (review of issue 40: `set p_roll = abc` was skipped silently, the earlier line's 45 used; the D-term low-passes
    # had no upper end, so 1e30 Hz was read without a word; settings.c takes 0-LPF_MAX_HZ, 1000)
    with pytest.raises(TunerError, match=r"quad.txt line \d+: p_roll = 'abc' is not a number"):
        vehicle_from_text(DUMP + "set p_roll = abc\n", axis="roll", source="quad.txt")
    with pytest.raises(TunerError, match=r"dterm_lpf1_type = 'PT4' is not a D-term low-pass type"):
        vehicle_from_text(DUMP + "set dterm_lpf1_type = PT4\n", axis="roll", source="quad.txt")
    v = vehicle_from_text(DUMP + "set craft_name = abc\nset gyro_to_use = FIRST\n", axis="roll", source="quad.txt")
    assert v.gains["P"] == 45.0 and not v.warnings  # (settings the law does not read may hold words)
    v = vehicle_from_text(DUMP + "set dterm_lpf2_static_hz = 5000\n", axis="roll", source="quad.txt")
    assert v.fixed["dlpf2_hz"] == 5000.0
    assert any("dterm_lpf2_static_hz = 5000 is outside its documented range [0, 1000]" in w for w in v.warnings)
    assert not vehicle_from_text(DUMP + "set dterm_lpf2_static_hz = 1000\n", axis="roll", source="quad.txt").warnings


def test_the_export_is_cli_set_lines_with_whole_gains(tmp_path):
    res = {"structure": "betaflight_rate", "controller": {"dt": DT}, "meets_spec": True, "axis": "pitch",
           "gains": {"P": 47.4, "I": 83.6, "D": 46.0, "FF": 125.0, "dlpf1_hz": 75.0, "dlpf2_hz": 150.0,
                     "yaw_lpf_hz": 0.0, "iterm_limit": 400.0, "i_mult": 1.0}}
    pf = make_param_file(res, "betaflight")
    lines = [ln for ln in pf.text.splitlines() if not ln.startswith("#")]
    assert lines == ["set p_pitch = 47", "set i_pitch = 84", "set d_pitch = 46", "set f_pitch = 125",
                     "set iterm_limit = 400"]
    assert pf.name == "betaflight_rate_pitch.txt"
    p = tmp_path / pf.name
    p.write_text(pf.text)
    v = read_params(p, axis="pitch")
    assert v.firmware == "betaflight" and v.gains == {"P": 47.0, "I": 84.0, "D": 46.0, "FF": 125.0}


def test_a_gain_beyond_its_range_is_refused_at_export():
    res = {"structure": "betaflight_rate", "controller": {"dt": DT}, "meets_spec": True,
           "gains": {"P": 300.0, "I": 80.0, "D": 40.0, "FF": 120.0, "dlpf1_hz": 75.0, "dlpf2_hz": 150.0,
                     "yaw_lpf_hz": 0.0, "iterm_limit": 400.0, "i_mult": 1.0}}
    with pytest.raises(TunerError, match=r"p_roll = 300 is outside betaflight's documented range \[0, 250\]"):
        make_param_file(res, "betaflight")


def test_a_typed_plant_is_told_betaflights_gyro_filters_are_not_modelled():
    # (review: the note said "the vehicle's file gives no gyro low-pass" of a file that sets gyro_lpf1_static_hz; its
    # chain (PT1s, dynamic by default, notches, RPM filter) is not PX4's or ArduPilot's Butterworth, so none is added)
    from types import SimpleNamespace

    from tuner import make_plant
    from tuner.export.paramfile import _gyro_words
    from tuner.firmware.bind import typed_plant

    plant = make_plant([10.0], [1.0, 1.0])
    out, rec = typed_plant(plant, SimpleNamespace(firmware="betaflight", gyro_cutoff_hz=100.0))
    assert out is plant and rec["unmodelled"] and "not modelled" in rec["note"]
    words = _gyro_words({}, {"typed_plant": rec}, "gyro_lpf1_static_hz")
    assert "not modelled" in words and "gives none" not in words


def test_a_gain_the_whole_numbers_change_is_said_and_one_they_zero_refused():
    # (review: a tuned I of 0.19 was written as i_roll = 0 under a header of the tuned design's figures)
    base = {"structure": "betaflight_rate", "controller": {"dt": DT}, "meets_spec": True,
            "gains": {"P": 1.88, "I": 0.19, "D": 40.0, "FF": 120.0, "dlpf1_hz": 75.0, "dlpf2_hz": 150.0,
                      "yaw_lpf_hz": 0.0, "iterm_limit": 400.0, "i_mult": 1.0}}
    with pytest.raises(TunerError, match=r"i_roll = 0\.19 is stored as a whole number, 0") as e:
        make_param_file(base, "betaflight")
    assert e.value.field == ("gains", "I")
    pf = make_param_file(base, "betaflight", force=True)
    assert "i_roll 0.19 -> 0" in pf.text and "p_roll 1.88 -> 2" in pf.text and "set i_roll = 0" in pf.text
    ok = {**base, "gains": {**base["gains"], "P": 45.2, "I": 80.0}}  # 45.2 -> 45: 0.4 %, not said
    assert "by more than 1 %" not in make_param_file(ok, "betaflight").text
