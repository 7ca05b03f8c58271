"""Logs that say what was flown (issue 40 item 3): only armed, airborne stretches are identified, a log with none is
refused saying what was seen, a rate setpoint is an exogenous reference only in a rate mode or with an excitation,
a grid faster than an input is logged is refused naming the topic, and the advice names what to fly.

The states are written with tests/ulog_writer.py in PX4's own message layouts (msg/VehicleStatus.msg: arming_state
2 = ARMED, nav_state 10 = ACRO; msg/ActuatorArmed.msg; msg/VehicleLandDetected.msg; msg/VehicleControlMode.msg);
the stretches expected are computed here from the times written, not by the code under test."""

from __future__ import annotations

import numpy as np
import pytest
from closed_loop import fly, write
from ulog_writer import Topic

from tuner.cli import main
from tuner.errors import InvalidDataError
from tuner.identify.flight import what_to_fly
from tuner.identify.ulog import read_ulog

IN, OUT, REF = "vehicle_torque_setpoint.xyz[0]", "vehicle_angular_velocity.xyz[0]", "vehicle_rates_setpoint.roll"
T0_US = 1_000_000  # closed_loop.write's first timestamp


def _steps(name, fields, times_s, rows):
    ts = np.asarray([T0_US + int(t * 1e6) for t in times_s], dtype=np.int64)
    vals = {f: np.asarray([r[i] for r in rows]) for i, (_, f, _) in enumerate(fields)}
    return Topic(name, fields, ts, vals)


def _states(armed, landed, *, attitude=1, nav=0):
    """vehicle_status, actuator_armed and vehicle_land_detected at 1 Hz over 60 s; ``armed``/``landed``: functions
    of the time (s from the log's first sample)."""
    t = np.arange(0.0, 60.0, 1.0)
    vs = _steps("vehicle_status", [("uint8_t", "arming_state", 0), ("uint8_t", "nav_state", 0)], t,
                [(2 if armed(x) else 1, nav) for x in t])
    aa = _steps("actuator_armed", [("bool", "armed", 0)], t, [(bool(armed(x)),) for x in t])
    ld = _steps("vehicle_land_detected", [("bool", "landed", 0)], t, [(bool(landed(x)),) for x in t])
    cm = _steps("vehicle_control_mode", [("bool", "flag_control_rates_enabled", 0),
                                          ("bool", "flag_control_attitude_enabled", 0)], t,
                [(True, bool(attitude))] * t.size)
    return (vs, aa, ld, cm)


@pytest.fixture(scope="module")
def sweep():
    return fly("sweep", seconds=60, seed=2, sweep_amplitude=3.0, turbulence=0.03)


def test_a_log_never_armed_is_refused_saying_what_was_seen(sweep, tmp_path, capsys):
    path = write(sweep, tmp_path / "ground.ulg", _states(lambda t: False, lambda t: True))
    with pytest.raises(InvalidDataError, match="never armed and airborne") as e:
        read_ulog(path, {"input": IN, "output": OUT})
    assert e.value.field == ("file",) and "arming state 1 (2 is armed)" in str(e.value)
    assert "landed 1" in str(e.value) and "MANUAL" in str(e.value)
    assert main(["identify", str(path), "--input", IN, "--output", OUT, "--poles", "2"]) == 2
    assert "no flight to identify from" in capsys.readouterr().err


def test_only_the_armed_airborne_stretch_is_identified(sweep, tmp_path):
    # armed 10-50 s, on the ground until 15 s: the state at 1 Hz holds from each sample to the next
    path = write(sweep, tmp_path / "flight.ulg", _states(lambda t: 10 <= t < 50, lambda t: t < 15))
    rec = read_ulog(path, {"input": IN, "output": OUT})
    assert len(rec.inputs) == 1
    t_first = rec.t_starts_s[0] - T0_US * 1e-6  # the log's clock starts at 0: the first sample is at 1 s
    assert t_first == pytest.approx(15.0, abs=1.5 / rec.rate_hz)
    assert rec.inputs[0].size / rec.rate_hz == pytest.approx(35.0, abs=2.0 / rec.rate_hz)
    assert any("left out" in n for n in rec.flight["notes"])
    full = read_ulog(write(sweep, tmp_path / "nostate.ulg"), {"input": IN, "output": OUT})
    assert full.inputs[0].size > 1.6 * rec.inputs[0].size  # without states: the whole log, and a note says so
    assert any("no arming state" in n for n in full.flight["notes"])


@pytest.mark.parametrize("attitude, biased", [(1, True), (0, False)])
@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_a_rate_setpoint_is_exogenous_only_in_a_rate_mode(sweep, tmp_path, attitude, biased, capsys):
    path = write(sweep, tmp_path / "f.ulg", _states(lambda t: True, lambda t: False, attitude=attitude,
                                                    nav=0 if attitude else 10))
    rec = read_ulog(path, {"input": IN, "output": OUT, "reference": REF})
    assert bool(rec.flight["reference_biased"]) is biased
    import json
    code = main(["identify", str(path), "--input", IN, "--output", OUT, "--reference", REF, "--poles", "2",
                 "--json"])
    d = json.loads(capsys.readouterr().out)
    assert code == 0
    msg = d["closed_loop"]["message"]
    if biased:
        assert "biased by the outer loop" in msg and "unbiased" not in msg and "MANUAL" in msg
        assert d["warnings"][0] == msg and "What to fly: PX4" in msg
        assert d["options"]["estimate"] == "joint (reference, biased by the outer loop)"
    else:
        assert "unbiased by the feedback" in msg and d["options"]["reference_biased"] is None


def test_a_grid_faster_than_the_input_is_logged_is_refused(sweep, tmp_path, capsys):
    path = write(sweep, tmp_path / "f.ulg")
    logged = 1.0 / float(np.median(np.diff(sweep.t)))  # the topics' rate, from the times written
    with pytest.raises(InvalidDataError, match=r"vehicle_torque_setpoint at 400 Hz") as e:
        read_ulog(path, {"input": IN, "output": OUT}, rate_hz=2.5 * logged)
    assert e.value.field == ("rate_hz",) and "at most 400 Hz" in str(e.value)
    assert read_ulog(path, {"input": IN, "output": OUT}, rate_hz=logged).rate_hz == logged
    assert main(["identify", str(path), "--input", IN, "--output", OUT, "--poles", "2", "--rate", "1000"]) == 2
    assert capsys.readouterr().err.startswith("tuner: error: --rate")


@pytest.mark.parametrize("firmware, words", [
    ("px4", ["Acro", "SDLOG_PROFILE bit 3", "0.3 rad/s", "60-90 s", "vehicle_torque_setpoint.xyz[1]"]),
    ("ardupilot", ["SystemID mode (mode 25)", "SID_AXIS 8", "SID_MAGNITUDE", "LOG_BITMASK", "RATE.POut"]),
])
def test_the_advice_names_what_to_fly(firmware, words):
    text = what_to_fly(firmware, "pitch")
    for w in words:
        assert w in text
