"""--params on the command line: the loop the vehicle flew (analyze --identified --structure --params), the
measured-response figures beside the model's, and every bad combination an exit 2 naming the argument."""

from __future__ import annotations

import json

import pytest
from closed_loop import fly, write

from tuner.cli import main

PARAMS = ("1\t1\tMC_ROLLRATE_P\t0.15\t9\n1\t1\tMC_ROLLRATE_I\t0.2\t9\n1\t1\tMC_ROLLRATE_D\t0.003\t9\n"
          "1\t1\tIMU_GYRO_RATEMAX\t400\t6\n")
PARM = "ATC_RAT_RLL_P,0.135\nATC_RAT_RLL_I,0.135\nATC_RAT_RLL_D,0.0036\nSCHED_LOOP_RATE,400\n"
PLANT = "250/(s*(0.02*s+1))"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("vehicle")
    (d / "quad.params").write_text(PARAMS)
    (d / "copter.parm").write_text(PARM)
    return d


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    d = tmp_path_factory.mktemp("ident")
    log = write(fly("sweep", seconds=40, seed=2, sweep_amplitude=3.0, turbulence=0.03), d / "sweep.ulg")
    out = d / "id.json"
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["identify", str(log), "--input", "vehicle_torque_setpoint.xyz[0]", "--output",
                     "vehicle_angular_velocity.xyz[0]", "--reference", "vehicle_rates_setpoint.roll", "--poles", "3",
                     "--zeros", "2", "--json"]) == 0
    out.write_text(buf.getvalue())
    return log, out


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_analyze_the_loop_the_vehicle_flew(identified, capsys):
    log, ident = identified
    assert main(["analyze", "--identified", str(ident), "--structure", "px4_rate", "--params", str(log),
                 "--json"]) in (0, 1)
    d = json.loads(capsys.readouterr().out)
    assert d["structure"] == "px4_rate" and d["gains"]["P"] == pytest.approx(0.15)
    assert d["controller"]["dt"] == pytest.approx(0.0025) and d["vehicle"]["firmware"] == "px4"
    m = d["measured"]  # the loop on the measured response, beside the model's, over the coherent band
    assert m["points"] > 20 and m["measured"]["phase_margin_deg"] == pytest.approx(
        m["model"]["phase_margin_deg"], abs=max(5.0, m["measured"]["phase_margin_range"][1]
                                                - m["measured"]["phase_margin_range"][0]))
    assert m["warnings"] == []  # a good model of the airframe: no disagreement beyond the data's error
    assert main(["analyze", "--identified", str(ident), "--structure", "px4_rate", "--params", str(log)]) in (0, 1)
    out = capsys.readouterr().out
    assert "the loop the vehicle flies: px4_rate" in out and "on the measured response" in out


@pytest.mark.parametrize("args, words", [
    (["tune", "--plant", PLANT, "--structure", "px4_rate", "--params", "{d}/copter.parm"],
     "--params: {d}/copter.parm: a .parm file is ArduPilot's; px4_rate needs"),
    (["tune", "--plant", PLANT, "--structure", "px4_rate", "--params", "{d}/quad.params", "--dt", "0.004"],
     "--dt: dt = 0.004 s contradicts the vehicle's loop rate 400 Hz"),
    (["tune", "--plant", PLANT, "--structure", "pid", "--params", "{d}/quad.params"],
     "--params: sets a firmware rate law's vehicle"),
    (["tune", "--plant", PLANT, "--structure", "px4_rate", "--params", "{d}/none.params"], "cannot read"),
    (["analyze", "--plant", PLANT, "--structure", "px4_rate"], "needs --params"),
    (["analyze", "--plant", PLANT, "--controller", "1", "--params", "{d}/quad.params"], "give --structure"),
    (["analyze", "--plant", PLANT, "--structure", "ardupilot_rate", "--params", "{d}/quad.params"],
     "holds px4 parameters"),
])
def test_bad_vehicle_arguments_exit_2(files, args, words, capsys):
    args = [a.format(d=files) for a in args]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("tuner: error: ") and words.format(d=files) in err, err
