"""Parameter files out (tuner export --format px4|ardupilot): what the ground station loads, read back by the
project's own reader (the round trip), the documented ranges enforced, and the wrong result refused."""

from __future__ import annotations

import json

import pytest

from tuner.cli import main
from tuner.errors import TunerError
from tuner.export.paramfile import param_file
from tuner.firmware import read_params

PX4 = {"structure": "px4_rate", "controller": {"dt": 0.0025}, "meets_spec": True,
       "metrics": {"phase_margin_deg": 60.0, "gain_margin_db": 11.0, "overshoot_pct": 1.7, "settling_time_s": 0.08},
       "gains": {"P": 0.127, "I": 0.21, "D": 0.0017, "FF": 0.0023, "K": 0.9, "dgyro_hz": 25.0, "int_lim": 0.35}}
ARDU = {"structure": "ardupilot_rate", "controller": {"dt": 0.0025}, "meets_spec": True,
        "gains": {"P": 0.123, "I": 0.081, "D": 0.0025, "FF": 0.0, "fltt_hz": 20.0, "flte_hz": 0.0, "fltd_hz": 20.0,
                  "imax": 0.5}}


@pytest.mark.parametrize("axis", ["roll", "pitch", "yaw"])
def test_px4_round_trip(tmp_path, axis):
    text, name = param_file(PX4, "px4", axis=axis)
    assert name == f"px4_rate_{axis}.params"
    assert text.startswith("# tuner ") and "loop rate 400 Hz" in text and "IMU_DGYRO_CUTOFF 25 Hz" in text
    p = tmp_path / name
    p.write_text(text + "1\t1\tIMU_GYRO_RATEMAX\t400\t6\n1\t1\tIMU_DGYRO_CUTOFF\t25\t9\n")
    v = read_params(p, axis=axis, firmware="px4")
    assert v.gains == pytest.approx({k: PX4["gains"][k] for k in ("P", "I", "D", "FF")}, rel=1e-12)
    got = {k: v.fixed[k] for k in ("K", "dgyro_hz", "int_lim")}
    assert got == pytest.approx({k: PX4["gains"][k] for k in ("K", "dgyro_hz", "int_lim")}, rel=1e-12)
    for line in text.splitlines():
        if not line.startswith("#"):
            cols = line.split("\t")
            assert len(cols) == 5 and cols[:2] == ["1", "1"] and cols[4] == "9"


def test_ardupilot_round_trip(tmp_path):
    text, name = param_file(ARDU, "ardupilot", axis="pitch")
    assert name == "ardupilot_rate_pitch.parm" and "ATC_RAT_PIT_FLTD,20.0" in text
    p = tmp_path / name
    p.write_text(text)
    v = read_params(p, axis="pitch", firmware="ardupilot")
    assert v.gains == pytest.approx({k: ARDU["gains"][k] for k in ("P", "I", "D", "FF")}, rel=1e-12)
    assert v.fixed == pytest.approx({**{k: ARDU["gains"][k] for k in ("fltt_hz", "flte_hz", "fltd_hz", "imax")},
                                     "dff": 0.0})


def test_attitude_p_for_a_cascade():
    text, _ = param_file(PX4, "px4", axis="roll", att_p=6.5)
    assert "1\t1\tMC_ROLL_P\t6.5\t9" in text
    with pytest.raises(TunerError, match=r"MC_ROLL_P = 13 is outside px4's documented range \[0, 12\]"):
        param_file(PX4, "px4", axis="roll", att_p=13.0)


@pytest.mark.parametrize("result, fmt, what", [
    ({**PX4, "gains": {**PX4["gains"], "P": 0.8}}, "px4", r"MC_ROLLRATE_P = 0.8 is outside px4's documented range"),
    ({**PX4, "gains": {**PX4["gains"], "D": 0.02}}, "px4", r"MC_ROLLRATE_D = 0.02 is outside"),
    ({**ARDU, "gains": {**ARDU["gains"], "I": 0.0}}, "ardupilot", r"ATC_RAT_RLL_I = 0 is outside"),
    (PX4, "ardupilot", "holds the ardupilot_rate law; this result's structure is 'px4_rate'"),
    ({"structure": "pid", "gains": {"Kp": 1.0}}, "px4", "structure is 'pid'"),
    ({**PX4, "gains": {"P": 0.1, "I": 0.1, "D": 0.0, "FF": 0.0}}, "px4", "lack K"),
])
def test_refused(result, fmt, what):
    with pytest.raises(TunerError, match=what):
        param_file(result, fmt)


def test_cli_export(tmp_path, capsys):
    r = tmp_path / "r.json"
    r.write_text(json.dumps(PX4))
    out = tmp_path / "roll.params"
    assert main(["export", "--result", str(r), "--format", "px4", "--out", str(out)]) == 0
    assert read_params(out, firmware="px4").gains["P"] == pytest.approx(0.127)
    assert main(["export", "--result", str(r), "--format", "ardupilot"]) == 2
    assert "ardupilot_rate" in capsys.readouterr().err
    assert main(["export", "--result", str(r), "--format", "px4", "--u-max", "1"]) == 2
    assert main(["export", "--result", str(r), "--format", "c", "--axis", "roll"]) == 2
    capsys.readouterr()
    ctrl = __import__("tuner").controller_tf("px4_rate", PX4["gains"], dt=0.0025)
    r.write_text(json.dumps({**PX4, "controller": ctrl.to_dict()}))
    assert main(["export", "--result", str(r), "--format", "c"]) == 2  # the firmware runs its own law
    assert "export its parameter file (format px4)" in capsys.readouterr().err
    r.write_text(json.dumps(PX4))
    r.write_text(json.dumps({**PX4, "gains": {**PX4["gains"], "P": 0.9}}))
    assert main(["export", "--result", str(r), "--format", "px4"]) == 2
    assert "MC_ROLLRATE_P = 0.9" in capsys.readouterr().err


@pytest.mark.slow
def test_tune_with_params_then_export(tmp_path, capsys):
    """The whole path: a vehicle's .params in, a px4_rate tune, its parameter file out, read back."""
    params = tmp_path / "quad.params"
    params.write_text("1\t1\tMC_ROLLRATE_P\t0.15\t9\n1\t1\tMC_ROLLRATE_I\t0.2\t9\n1\t1\tMC_ROLLRATE_D\t0.003\t9\n"
                      "1\t1\tMC_ROLLRATE_K\t1\t9\n1\t1\tIMU_DGYRO_CUTOFF\t30\t9\n1\t1\tIMU_GYRO_RATEMAX\t400\t6\n")
    code = main(["tune", "--plant", "250/(s*(0.02*s+1))", "--delay", "0.0025", "--structure", "px4_rate",
                 "--params", str(params), "--budget", "5", "--json"])
    out = capsys.readouterr().out
    assert code == 0
    res = json.loads(out)
    assert res["vehicle"]["source"] == "quad.params" and res["current"]["gains"]["P"] == 0.15
    assert res["gains"]["dgyro_hz"] == 30.0 and res["controller"]["dt"] == pytest.approx(0.0025)
    r = tmp_path / "r.json"
    r.write_text(out)
    f = tmp_path / "new.params"
    code = main(["export", "--result", str(r), "--format", "px4", "--out", str(f)])
    if code == 2:  # a design outside PX4's ranges is refused, never written: then say which
        pytest.fail(capsys.readouterr().err)
    text = f.read_text()
    assert "# vehicle: quad.params" in text and "current: MC_ROLLRATE_P 0.15" in text
    assert read_params(f, firmware="px4").gains["P"] == pytest.approx(res["gains"]["P"])
