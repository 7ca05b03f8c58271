"""Issue 42 item 1 and issue 39 items 3-4, the file side: parameter files a ground station can trust.

The ranges expected here are written from the firmware sources themselves (not from tuner.firmware.names):
PX4 ``src/modules/mc_rate_control/mc_rate_control_params.c`` (roll P 0.01-0.5, roll D 0-0.01, K 0.01-5, I >= 0) and
``imu_gyro_parameters.c`` (IMU_GYRO_RATEMAX, an INT32, 0-2000); ArduPilot ``AC_AttitudeControl_Multi.cpp``
``@Range`` (roll FLTT 5-100, FLTE 0-100, FLTD 5-100; yaw FLTT 1-50, FLTE 0-20, FLTD 5-50; IMAX 0-1).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tuner.cli import main
from tuner.errors import TunerError
from tuner.export.paramfile import make_param_file, param_file
from tuner.firmware import read_params, vehicle_from_text

VEHICLE = {"firmware": "px4", "axis": "roll", "loop_hz": 400.0, "source": "quad.params",
           "current_gains": {"P": 0.15, "I": 0.2, "D": 0.003, "FF": 0.0}}
PX4 = {"structure": "px4_rate", "controller": {"dt": 0.0025}, "meets_spec": True, "verdict": "meets the spec",
       "basis": "model",
       "metrics": {"phase_margin_deg": 61.0, "gain_margin_db": 11.0, "overshoot_pct": 1.7, "settling_time_s": 0.08},
       "gains": {"P": 0.127, "I": 0.21, "D": 0.0017, "FF": 0.0023, "K": 0.9, "dgyro_hz": 25.0, "int_lim": 0.35},
       "vehicle": VEHICLE}
ARDU = {"structure": "ardupilot_rate", "controller": {"dt": 0.0025}, "meets_spec": True, "verdict": "meets the spec",
        "gains": {"P": 0.123, "I": 0.081, "D": 0.0025, "FF": 0.0, "fltt_hz": 20.0, "flte_hz": 0.0, "fltd_hz": 20.0,
                  "imax": 0.5}}


def _lines(text):
    return [ln for ln in text.splitlines() if not ln.startswith("#")]


# -- the axis ------------------------------------------------------------------------------------------------

def test_an_export_for_another_axis_than_the_results_is_refused(tmp_path, capsys):
    with pytest.raises(TunerError) as e:
        param_file(PX4, "px4", axis="yaw")
    assert e.value.field == ("axis",) and "tuned for the vehicle's roll axis" in str(e.value)
    text, name = param_file(PX4, "px4")  # the result's own axis
    assert name == "px4_rate_roll.params" and all("ROLL" in ln or "RR_" in ln for ln in _lines(text))
    r = tmp_path / "r.json"
    r.write_text(json.dumps(PX4))
    assert main(["export", "--result", str(r), "--format", "px4", "--axis", "yaw"]) == 2
    assert capsys.readouterr().err.startswith("tuner: error: --axis: ")
    no_vehicle = {k: v for k, v in PX4.items() if k != "vehicle"}  # nothing says which axis: the caller does
    assert "MC_YAWRATE_P" in param_file(no_vehicle, "px4", axis="yaw")[0]


# -- what the firmware stores ---------------------------------------------------------------------------------

def test_every_value_is_written_as_the_float32_the_firmware_holds():
    g = {**PX4["gains"], "P": 0.037796230468654525, "I": 0.0028413438826747693}
    text, _ = param_file({**PX4, "gains": g}, "px4")
    written = {ln.split("\t")[2]: ln.split("\t")[3] for ln in _lines(text)}
    for name, key in (("MC_ROLLRATE_P", "P"), ("MC_ROLLRATE_I", "I")):
        assert np.float32(float(written[name])) == np.float32(g[key])  # reads back to the same float32
        assert len(written[name]) <= 12  # the fewest digits doing so (not the double's 17)
    assert written["MC_ROLLRATE_P"] == "0.03779623"


def test_a_gain_zero_at_the_optimum_is_written_as_zero():
    """The zero rule: below float32's resolution 2^-23 times the parameter's scale (roll D: its documented maximum
    0.01, so 1.19e-9) a value is 0; a small gain above that is written."""
    tiny, small = 6.16627746e-18, 1e-6
    assert tiny < 2.0**-23 * 0.01 < small
    text, _ = param_file({**PX4, "gains": {**PX4["gains"], "D": tiny}}, "px4")
    assert "1\t1\tMC_ROLLRATE_D\t0.0\t9" in text and "e-18" not in text
    text, _ = param_file({**PX4, "gains": {**PX4["gains"], "D": small}}, "px4")
    assert "1\t1\tMC_ROLLRATE_D\t1e-06\t9" in text


@pytest.mark.parametrize("key, value", [("int_lim", 1e300), ("I", math.inf), ("FF", 4e38)])
def test_a_value_no_vehicle_can_hold_is_refused_even_with_force(key, value):
    with pytest.raises(TunerError) as e:
        param_file({**PX4, "gains": {**PX4["gains"], key: value}}, "px4", force=True)
    assert e.value.field == ("gains", key) and "single precision" in str(e.value)


def test_a_vehicle_file_with_a_value_beyond_float32_is_refused_naming_it(tmp_path, capsys):
    p = tmp_path / "quad.params"
    p.write_text("1\t1\tMC_ROLLRATE_P\t0.15\t9\n1\t1\tMC_ROLLRATE_I\t0.2\t9\n1\t1\tMC_ROLLRATE_D\t0.003\t9\n"
                 "1\t1\tMC_RR_INT_LIM\t1e300\t9\n")
    assert main(["tune", "--plant", "250/(s*(0.02*s+1))", "--structure", "px4_rate", "--params", str(p)]) == 2
    err = capsys.readouterr().err
    assert "MC_RR_INT_LIM = 1e+300" in err and "single precision" in err and "\n" not in err.strip()


# -- the documented ranges, per axis, and what is said of them ---------------------------------------------------

@pytest.mark.parametrize("axis, key, value, refused", [
    ("roll", "fltt_hz", 0.0, True), ("roll", "fltt_hz", 5.0, False), ("roll", "flte_hz", 25.0, False),
    ("roll", "fltd_hz", 4.0, True), ("yaw", "fltt_hz", 80.0, True), ("yaw", "fltt_hz", 1.0, False),
    ("yaw", "flte_hz", 25.0, True), ("yaw", "flte_hz", 20.0, False), ("yaw", "fltd_hz", 60.0, True),
    ("roll", "imax", 1.5, True),
])
def test_ardupilot_filter_ranges_per_axis(axis, key, value, refused):
    gains = {**ARDU["gains"], key: value}
    if axis == "yaw":  # yaw's own gain ranges: P 0.1-2.5 (a roll P of 0.123 is inside), I 0.01-1.0
        gains.update(P=0.2, I=0.02)
    res = {**ARDU, "gains": gains}
    if refused:
        with pytest.raises(TunerError) as e:
            param_file(res, "ardupilot", axis=axis)
        assert e.value.field == ("gains", key)
        assert "neither firmware enforces it" in str(e.value)
        text, _ = param_file(res, "ardupilot", axis=axis, force=True)  # asked for: written, and named
        assert "written with --force" in text and "outside ardupilot's documented range" in text
    else:
        param_file(res, "ardupilot", axis=axis)


def test_a_refusal_says_what_is_true_and_points_the_right_way():
    with pytest.raises(TunerError) as e:  # the sample.ulg case: a P below the range
        param_file({**PX4, "gains": {**PX4["gains"], "P": 0.0043}}, "px4")
    msg = str(e.value)
    assert "neither firmware enforces it" in msg and "would refuse or clamp" not in msg
    assert "plant's gain is high" in msg and "deg/s" in msg and "lower bandwidth" not in msg
    with pytest.raises(TunerError) as e:  # above: the spec asks too much, or the plant is weak
        param_file({**PX4, "gains": {**PX4["gains"], "P": 0.9}}, "px4")
    assert "plant's gain is low" in str(e.value) and "lower bandwidth" in str(e.value)


# -- the vehicle's own file: read and warned about, not refused ------------------------------------------------

def test_out_of_range_vehicle_values_are_read_and_warned_about():
    v = vehicle_from_text("1\t1\tMC_ROLLRATE_P\t0.15\t9\n1\t1\tMC_ROLLRATE_I\t0.2\t9\n1\t1\tMC_ROLLRATE_D\t0.003\t9\n"
                          "1\t1\tMC_ROLLRATE_K\t50\t9\n1\t1\tIMU_GYRO_RATEMAX\t0.001\t6\n", axis="roll")
    assert v.fixed["K"] == 50.0 and v.loop_hz == 0.001  # read as they are
    k, rate = v.warnings
    assert "MC_ROLLRATE_K = 50 is outside its documented range [0.01, 5]" in k and "mc_rate_control_params.c" in k
    assert "IMU_GYRO_RATEMAX = 0.001 is not a whole number" in rate
    a = vehicle_from_text("ATC_RAT_RLL_P,0.12\nATC_RAT_RLL_I,0.1\nATC_RAT_RLL_D,0.003\nATC_RAT_RLL_IMAX,5\n"
                          "SCHED_LOOP_RATE,400\n", axis="roll")
    assert a.fixed["imax"] == 5.0 and len(a.warnings) == 1 and "ATC_RAT_RLL_IMAX = 5 is outside" in a.warnings[0]
    fast = vehicle_from_text("ATC_RAT_RLL_P,0.12\nATC_RAT_RLL_I,0.1\nATC_RAT_RLL_D,0.003\nSCHED_LOOP_RATE,4000\n",
                             axis="roll")
    assert fast.loop_hz == 2000.0 and "clamps" in fast.warnings[0]  # AP_Scheduler's own clamp: what it runs


@pytest.mark.slow
def test_vehicle_warnings_reach_the_text_and_the_header(tmp_path, capsys):
    p = tmp_path / "quad.params"
    p.write_text("1\t1\tMC_ROLLRATE_P\t0.15\t9\n1\t1\tMC_ROLLRATE_I\t0.2\t9\n1\t1\tMC_ROLLRATE_D\t0.003\t9\n"
                 "1\t1\tMC_ROLLRATE_K\t2\t9\n1\t1\tMC_RR_INT_LIM\t0.3\t9\n1\t1\tIMU_DGYRO_CUTOFF\t1500\t9\n"
                 "1\t1\tIMU_GYRO_RATEMAX\t400\t6\n")
    args = ["tune", "--plant", "250/(s*(0.02*s+1))", "--delay", "0.0025", "--structure", "px4_rate", "--params",
            str(p), "--budget", "3"]
    main(args)
    assert "warning: quad.params: IMU_DGYRO_CUTOFF = 1500 is outside" in capsys.readouterr().out
    main([*args, "--json"])
    r = tmp_path / "r.json"
    r.write_text(capsys.readouterr().out)
    out = tmp_path / "new.params"
    main(["export", "--result", str(r), "--format", "px4", "--out", str(out), "--force"])
    assert "IMU_DGYRO_CUTOFF = 1500 is outside" in capsys.readouterr().err
    assert "# WARNING: the vehicle's parameters: quad.params: IMU_DGYRO_CUTOFF = 1500" in out.read_text()


# -- names and header text are sanitised --------------------------------------------------------------------------

def test_no_newline_or_tab_from_a_file_name_reaches_a_line_of_the_file(tmp_path):
    evil = "quad.params\n1\t1\tMC_ROLLRATE_P\t9.9\t9\r\n1\t1\tMC_ROLLRATE_K\t40\t9\u2028x"
    res = {**PX4, "vehicle": {**VEHICLE, "source": evil, "warnings": ["w\n1\t1\tMC_RR_INT_LIM\t7\t9"],
                              "changes": ["P 1 -> 2\n1\t1\tMC_ROLLRATE_I\t5\t9"]},
           "verdict": "meets the spec\n1\t1\tMC_ROLLRATE_D\t3\t9"}
    text, _ = param_file(res, "px4")
    assert all(ln.startswith("# ") for ln in text.splitlines() if "\t" not in ln or ln.startswith("#"))
    body = _lines(text)
    assert [ln.split("\t")[2] for ln in body] == ["MC_ROLLRATE_P", "MC_ROLLRATE_I", "MC_ROLLRATE_D", "MC_ROLLRATE_FF",
                                                  "MC_ROLLRATE_K", "MC_RR_INT_LIM"]
    assert "\u2028" not in text and "\r" not in text
    p = tmp_path / "x.params"
    p.write_text(text)
    back = read_params(p, firmware="px4")
    assert back.gains["P"] == pytest.approx(0.127) and back.fixed["K"] == pytest.approx(0.9)


# -- the verdict: a failing design, one on the model only, what the header calls verified --------------------------

@pytest.mark.parametrize("change", [{"meets_spec": False, "verdict": "does NOT meet the spec: overshoot_pct = 12"},
                                    {"basis": "model only",
                                     "verdict": "meets the spec on the model only: the identification is rated poor"},
                                    {"meets_spec": None}])
def test_a_design_failing_its_verdict_needs_force_and_says_so(tmp_path, capsys, change):
    res = {k: v for k, v in {**PX4, **change}.items() if v is not None}
    with pytest.raises(TunerError) as e:
        param_file(res, "px4")
    assert e.value.field == ("force",) and "--force" in str(e.value)
    pf = make_param_file(res, "px4", force=True)
    assert any(w.startswith("written with --force") for w in pf.warnings)
    assert "# WARNING: written with --force" in pf.text
    r = tmp_path / "r.json"
    r.write_text(json.dumps(res))
    assert main(["export", "--result", str(r), "--format", "px4"]) == 2
    assert main(["export", "--result", str(r), "--format", "px4", "--force", "--out", str(tmp_path / "f.params")]) == 0
    assert "tuner: warning: written with --force" in capsys.readouterr().err


def _measured(ok_pm, ok_gm):
    checks = [{"name": "measured_phase_margin_deg", "op": ">=", "required": 60.0,
               "achieved": 62.5 if ok_pm else 41.0, "ok": ok_pm, "violation": 0.0 if ok_pm else 19.0},
              {"name": "measured_gain_margin_db", "op": ">=", "required": 6.0, "achieved": 8.0 if ok_gm else "NaN",
               "ok": ok_gm, "violation": 0.0 if ok_gm else "Infinity"},
              {"name": "identification_quality", "op": ">=", "required": "acceptable", "achieved": "good", "ok": True,
               "violation": 0.0}]
    return {"checks": checks, "measured": {"band_rad_s": [1.0, 100.0], "points": 80},
            "identification": {"quality": "good", "cost": 12.0, "check": "good"}}


def test_the_header_calls_verified_only_what_the_measured_response_confirmed():
    both = make_param_file({**PX4, **_measured(True, True), "basis": "model and measured response"}, "px4").text
    assert "# verified on the measured response (1-100 rad/s, 80 coherent points), the worst end of each error " \
           "range: PM 62.5 deg at worst, GM 8 dB at worst" in both
    assert "# on the model (the identified model's loop, not the airframe's): PM 61 deg" in both
    assert "# identification: rated good (J 12" in both
    res = {**PX4, **_measured(False, False), "meets_spec": False, "verdict": "does NOT meet the spec on the measured"}
    text = make_param_file(res, "px4", force=True).text
    assert "# NOT verified on the measured response" in text and "PM 41 deg at worst (required >= 60)" in text
    assert "GM not measured" in text and "# verified" not in text
    plain = make_param_file(PX4, "px4").text  # a model given: no flight data
    assert "# verified" not in plain and "no flight data" in plain


def test_a_proposal_far_from_the_current_tune_is_said_before_the_file(tmp_path, capsys):
    res = {**PX4, "vehicle": {**VEHICLE, "changes": ["crossover 0.443 -> 0.0109 rad/s (41x lower)"]}}
    r = tmp_path / "r.json"
    r.write_text(json.dumps(res))
    out = tmp_path / "f.params"
    assert main(["export", "--result", str(r), "--format", "px4", "--out", str(out)]) == 0
    assert "tuner: warning: the proposal changes the vehicle's current tune by more than 3x: crossover 0.443" in \
        capsys.readouterr().err
    assert "# WARNING: the proposal changes the vehicle's current tune by more than 3x" in out.read_text()
