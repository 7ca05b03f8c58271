"""Reading a vehicle's parameters (tuner.firmware.params): QGroundControl .params, Mission Planner .parm and the
parameters a ULog stores, each field checked, and every bad input refused with the field and what to change."""

from __future__ import annotations

import numpy as np
import pytest

from tests.ulog_writer import Topic, write_ulog
from tuner.errors import TunerError
from tuner.firmware import read_params, vehicle_from_text
from tuner.firmware.params import parse_params_text

QGC = """# Onboard parameters for Vehicle 1
#
# Stack: PX4 Pro
# MAV ID  Component ID  Name  Value  Type
1\t1\tIMU_DGYRO_CUTOFF\t30.000000000000000000\t9
1\t1\tIMU_GYRO_CUTOFF\t40.000000000000000000\t9
1\t1\tIMU_GYRO_RATEMAX\t800\t6
1\t1\tMC_PITCHRATE_D\t0.004000000189989805\t9
1\t1\tMC_PITCHRATE_FF\t0.000000000000000000\t9
1\t1\tMC_PITCHRATE_I\t0.300000011920928955\t9
1\t1\tMC_PITCHRATE_K\t0.800000011920928955\t9
1\t1\tMC_PITCHRATE_P\t0.180000007152557373\t9
1\t1\tMC_PR_INT_LIM\t0.400000005960464478\t9
1\t1\tMC_PITCH_P\t6.500000000000000000\t9
1\t1\tMC_ROLLRATE_P\t0.150000005960464478\t9
"""
PARM = """# ArduCopter
ATC_RAT_PIT_P,0.1350000
ATC_RAT_PIT_I,0.1350000
ATC_RAT_PIT_D 0.0036
ATC_RAT_PIT_FF,0.02
ATC_RAT_PIT_IMAX,0.45
ATC_RAT_PIT_FLTT,25
ATC_RAT_PIT_FLTE,0
ATC_RAT_PIT_FLTD,30
ATC_ANG_PIT_P,4.5
SCHED_LOOP_RATE,300
INS_GYRO_FILTER,20
"""


def test_qgroundcontrol_params(tmp_path):
    p = tmp_path / "quad.params"
    p.write_text(QGC)
    v = read_params(p, axis="pitch")
    assert v.firmware == "px4" and v.axis == "pitch" and v.loop_hz == 800.0 and v.dt == pytest.approx(1 / 800)
    assert v.gains == pytest.approx({"P": 0.18, "I": 0.3, "D": 0.004, "FF": 0.0})
    assert v.fixed == pytest.approx({"K": 0.8, "dgyro_hz": 30.0, "int_lim": 0.4, "tq_hz": 0.0,  # (no yaw filter)
                                     "dgyro_order": 1.0, "raw_hz": 0.0})  # (no version, no raw rate: assumed)
    assert v.gyro_cutoff_hz == 40.0 and v.att_p == 6.5
    # a parameter file says neither the firmware's version nor the raw gyro rate: the D path's two assumptions
    assert len(v.notes) == 2 and "first order" in v.notes[0] and "raw gyro rate is not in" in v.notes[1]


def test_ardupilot_parm(tmp_path):
    p = tmp_path / "copter.parm"
    p.write_text(PARM)
    v = read_params(p, axis="pitch", firmware="ardupilot")
    assert v.firmware == "ardupilot" and v.loop_hz == 300.0
    assert v.gains == pytest.approx({"P": 0.135, "I": 0.135, "D": 0.0036, "FF": 0.02})
    assert v.fixed == pytest.approx({"fltt_hz": 25.0, "flte_hz": 0.0, "fltd_hz": 30.0, "imax": 0.45, "dff": 0.0})
    assert v.att_p == 4.5 and v.gyro_cutoff_hz == 20.0


def test_ulog_parameters(tmp_path):
    t = np.arange(200) * 2500
    topic = Topic("vehicle_angular_velocity", [("float", "xyz", 3)], t, {"xyz": np.zeros((200, 3))})
    p = write_ulog(tmp_path / "flight.ulg", [topic], params={
        "MC_ROLLRATE_P": 0.2, "MC_ROLLRATE_I": 0.25, "MC_ROLLRATE_D": 0.0035, "MC_ROLLRATE_FF": 0.01,
        "MC_ROLLRATE_K": 1.0, "MC_RR_INT_LIM": 0.3, "IMU_DGYRO_CUTOFF": 25.0, "IMU_GYRO_RATEMAX": 400})
    v = read_params(p, axis="roll", firmware="px4")
    assert v.firmware == "px4" and v.loop_hz == 400.0
    assert v.gains == pytest.approx({"P": 0.2, "I": 0.25, "D": 0.0035, "FF": 0.01}, rel=1e-6)  # float32
    assert v.fixed["dgyro_hz"] == pytest.approx(25.0)


def test_missing_values_are_the_firmware_defaults_and_said():
    v = vehicle_from_text("MC_ROLLRATE_P,0.1\nMC_ROLLRATE_I,0.1\nMC_ROLLRATE_D,0.001\n", axis="roll")
    assert v.fixed == {"K": 1.0, "dgyro_hz": 20.0, "int_lim": 0.3, "tq_hz": 0.0, "dgyro_order": 1.0, "raw_hz": 0.0} \
        and v.loop_hz == 400.0
    assert any("IMU_GYRO_RATEMAX" in n for n in v.notes) and any("MC_ROLLRATE_K" in n for n in v.notes)


@pytest.mark.parametrize("text, firmware, what", [
    ("ATC_RAT_RLL_P,0.1\nATC_RAT_RLL_I,0.1\nATC_RAT_RLL_D,0.001\n", "px4", "ArduPilot|ardupilot"),
    ("MC_ROLLRATE_P,0.1\nMC_ROLLRATE_I,0.1\n", None, "MC_ROLLRATE_D"),
    ("FOO,1\n", None, "none of the known firmwares' rate parameters"),
    ("MC_ROLLRATE_P,abc\n", None, "not a number"),
    ("MC_ROLLRATE_P,nan\n", None, "not a finite number"),
    ("MC_ROLLRATE_P,0.1\nMC_ROLLRATE_I,0.1\nMC_ROLLRATE_D,0.001\nMC_ROLLRATE_K,0\n", None, "MC_ROLLRATE_K"),
    ("# nothing\n", None, "no parameters"),
])
def test_bad_parameters_are_refused(text, firmware, what):
    with pytest.raises(TunerError, match=what) as ei:
        vehicle_from_text(text, axis="roll", firmware=firmware)
    assert ei.value.field == ("params",)


def test_a_parm_file_for_px4_is_refused(tmp_path):
    p = tmp_path / "copter.parm"
    p.write_text(PARM)
    with pytest.raises(TunerError, match=r"\.parm file is ArduPilot's; px4_rate needs"):
        read_params(p, axis="pitch", firmware="px4")


def test_files_that_are_not_parameters(tmp_path):
    with pytest.raises(TunerError, match="cannot read"):
        read_params(tmp_path / "none.params")
    b = tmp_path / "bin.params"
    b.write_bytes(b"\x00\x01\x02" * 10)
    with pytest.raises(TunerError, match="binary"):
        read_params(b)
    u = tmp_path / "bad.ulg"
    u.write_bytes(b"ULog\x01\x12\x35" + b"\x01" * 20)
    with pytest.raises(TunerError, match="ULog"):
        read_params(u)


def test_qgc_lines_must_have_five_columns():
    with pytest.raises(TunerError, match="5 tab-separated columns"):
        parse_params_text("1\t1\tMC_ROLLRATE_P\t0.1\t9\n1\t1\tMC_ROLLRATE_I\n")


def test_a_name_twice_with_two_values_is_refused_naming_both_lines():
    """Issue 42: the second value was taken silently; which one the vehicle flies cannot be told."""
    from tuner.errors import TunerError
    from tuner.firmware.params import parse_params_text

    qgc = "1\t1\tMC_ROLLRATE_P\t0.15\t9\n1\t1\tMC_ROLLRATE_I\t0.2\t9\n1\t1\tMC_ROLLRATE_P\t0.9\t9\n"
    with pytest.raises(TunerError, match=r"quad.params line 3: MC_ROLLRATE_P = 0.9 again, after 0.15 on line 1: "
                                         r"keep one of the two lines") as e:
        parse_params_text(qgc, source="quad.params")
    assert e.value.field == ("params",)
    same = "ATC_RAT_RLL_P,0.1\n# saved twice\nATC_RAT_RLL_P,0.1\n"  # the same value twice says nothing new
    assert parse_params_text(same) == ({"ATC_RAT_RLL_P": 0.1}, "parm")


@pytest.mark.parametrize("value", ["1_5", "0.1_5", "١٢", "１"])
def test_numbers_python_reads_but_no_file_writes_are_refused(value):
    """float() reads '1_5' as 15 and other scripts' digits as numbers; a parameter file's value is plain ASCII."""
    from tuner.errors import TunerError
    from tuner.firmware.params import parse_params_text

    with pytest.raises(TunerError, match=f"MC_ROLLRATE_P = '{value}' is not a number"):
        parse_params_text(f"MC_ROLLRATE_P,{value}\n")
