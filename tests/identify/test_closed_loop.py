"""Identification that survives feedback: logs flown with PX4's rate law in the loop (tests/closed_loop.py), the
closed loop told and never rated good, the joint estimate with a reference against the true plant as logged, and
the hold counted once.

Reference values come from the simulation's own truth: the plant's exact ZOH response from scipy, and PX4's law
written in tests/closed_loop.py (independent of tuner)."""

from __future__ import annotations

import csv
import json

import control as ct
import numpy as np
import pytest
from closed_loop import DT, fly, law_response, true_zoh_response, write

from tuner.cli import main
from tuner.identify import identify

SIGNALS = ["--input", "vehicle_torque_setpoint.xyz[0]", "--output", "vehicle_angular_velocity.xyz[0]"]


@pytest.fixture(scope="module")
def hover(tmp_path_factory):
    return write(fly("hover", seconds=60, seed=1), tmp_path_factory.mktemp("cl") / "hover.ulg")


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    return write(fly("sweep", seconds=60, seed=2, sweep_amplitude=3.0, turbulence=0.03),
                 tmp_path_factory.mktemp("cl") / "sweep.ulg")


def _identify_json(path, *extra, capsys):
    code = main(["identify", str(path), *SIGNALS, *extra, "--json"])
    out = capsys.readouterr().out
    assert code in (0, 1), out
    return json.loads(out)


@pytest.mark.slow
@pytest.mark.parametrize("poles, zeros", [(2, 0), (3, 2)])
def test_a_hover_is_flagged_and_never_rated_good(hover, poles, zeros, capsys):
    d = _identify_json(hover, "--poles", str(poles), "--zeros", str(zeros), capsys=capsys)
    assert d["quality"] == "closed-loop"
    cl = d["closed_loop"]
    assert cl["detected"] and cl["estimate"] == "direct"
    assert "flown under feedback" in cl["message"] and "as the reference" in cl["message"]
    assert "--" not in cl["message"]  # the library's words hold over HTTP too: no command-line flag in them
    assert any("controller's output" in s for s in cl["signs"])
    assert any("MC_ROLLRATE_P" in s for s in cl["signs"])
    assert any("-1/C" in s for s in cl["signs"])  # the direct estimate is the law's inverse
    assert d["warnings"][0] == cl["message"]
    assert main(["identify", str(hover), *SIGNALS, "--poles", str(poles), "--zeros", str(zeros), "--check"]) == 1


@pytest.mark.slow
def test_the_hover_estimate_is_the_inverse_of_the_law(hover):
    """The direct estimate of a hover in turbulence is -1/C, checked against the law written in the test."""
    from tuner.identify.ulog import read_ulog

    r = read_ulog(hover, {"input": SIGNALS[1], "output": SIGNALS[3]})
    res = identify(r.inputs[0], r.outputs[0], rate_hz=r.rate_hz, poles=2)
    fr = res.frequency_response
    sel = (fr.w > 2) & (fr.w < 500)
    rel = np.abs(fr.h[sel] * law_response(fr.w[sel]) + 1)
    assert np.median(rel) < 0.05
    assert res.quality != "closed-loop"  # identify() given no sign and no controller cannot tell by itself
    assert res.closed_loop["detected"] is False


@pytest.mark.slow
@pytest.mark.parametrize("poles, zeros", [(2, 0), (3, 2)])
def test_the_joint_estimate_is_the_plant_as_logged(sweep, poles, zeros, capsys):
    """The rate-setpoint sweep with --reference: the model held at dt within 1.5 dB and 8 deg of the true plant
    as logged over the band; the direct estimate is far off there."""
    d = _identify_json(sweep, "--reference", "vehicle_rates_setpoint.roll", "--poles", str(poles), "--zeros",
                       str(zeros), capsys=capsys)
    assert d["quality"] in ("good", "acceptable")
    assert d["closed_loop"]["detected"] and d["closed_loop"]["estimate"] == "joint"
    lo, hi = d["band_rad_s"]
    assert lo < 10 and hi > 100
    from tuner.identify.result import IdentifyResult

    res = IdentifyResult.from_dict(d)
    w = np.geomspace(lo, hi, 300)
    err = res.plant().zoh(DT).freqresp(w) / true_zoh_response(w)
    assert np.max(np.abs(20 * np.log10(np.abs(err)))) <= 1.5
    assert np.max(np.abs(np.degrees(np.angle(err)))) <= 8.0
    fr = d["frequency_response"]
    assert "coherence_ry" in fr and "coherence_ru" in fr
    direct = _identify_json(sweep, "--poles", str(poles), "--zeros", str(zeros), "--band", str(lo), str(hi),
                            capsys=capsys)
    assert direct["quality"] == "closed-loop"
    dres = IdentifyResult.from_dict(direct)
    derr = dres.plant().zoh(DT).freqresp(w) / true_zoh_response(w)
    assert np.max(np.abs(20 * np.log10(np.abs(derr)))) > 3.0  # what ignoring the feedback costs


def test_a_csv_column_named_as_a_controller_output_is_a_sign(tmp_path, capsys):
    lg = fly("hover", seconds=20, seed=3)
    p = tmp_path / "hover.csv"
    with open(p, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", "torque_setpoint_roll", "rate_roll"])
        w.writerows(zip(lg.t, lg.u, lg.y))
    code = main(["identify", str(p), "--time", "t", "--input", "torque_setpoint_roll", "--output", "rate_roll",
                 "--poles", "2", "--json"])
    d = json.loads(capsys.readouterr().out)
    assert code == 0 and d["quality"] == "closed-loop"


def test_a_reference_with_no_power_is_refused(tmp_path, capsys):
    lg = fly("hover", seconds=20, seed=4)
    p = tmp_path / "flat.csv"
    with open(p, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", "u", "y", "sp"])
        w.writerows(zip(lg.t, lg.u, lg.y, np.zeros(lg.t.size) + 1e-3 * np.sin(lg.t)))
    assert main(["identify", str(p), "--time", "t", "--input", "u", "--output", "y", "--reference", "sp",
                 "--poles", "2"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tuner: error: --reference") and "no power" in err


def test_a_missing_reference_topic_names_it(sweep, capsys):
    assert main(["identify", str(sweep), *SIGNALS, "--reference", "vehicle_rates_setpointx.roll", "--poles", "2"]) == 2
    err = capsys.readouterr().err
    assert "vehicle_rates_setpointx" in err and "topics" in err


def _held_record(noise: float = 0.0, seed: int = 3):
    dt = 0.01
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(3000)
    gd = ct.c2d(ct.tf([20.0], [1.0, 6.0, 20.0]), dt, "zoh")
    y = ct.forced_response(gd, U=np.concatenate([np.zeros(3), u[:-3]])).outputs + noise * rng.standard_normal(u.size)
    return dt, gd, u, y


def test_the_hold_is_counted_once():
    """A held input through 20/(s^2 + 6 s + 20) with 30 ms of delay at 100 Hz: with hold="zoh" the fitted delay is
    the plant's (the half-sample hold is not in it) and the model put back at dt with a zero-order hold is the
    measured discrete system; fitted as measured (hold=None), the delay absorbs dt/2 and the hold would count
    twice in a tune."""
    dt, gd, u, y = _held_record()
    res = identify(u, y, rate_hz=1 / dt, poles=2, hold="zoh")
    assert res.model.delay_s == pytest.approx(0.03, abs=0.5e-3)
    w = np.geomspace(res.band_rad_s[0], 0.5 * np.pi / dt, 200)
    truth = np.array([complex(gd(np.exp(1j * x * dt))) for x in w]) * np.exp(-3j * w * dt)
    err = res.plant().zoh(dt).freqresp(w) / truth
    assert np.max(np.abs(20 * np.log10(np.abs(err)))) < 0.3 and np.max(np.abs(np.degrees(np.angle(err)))) < 2.0
    assert res.options["hold_check"]["median_deg"] < 2.0
    twice = identify(u, y, rate_hz=1 / dt, poles=2, hold=None)
    assert twice.model.delay_s == pytest.approx(0.03 + dt / 2, abs=1e-3)


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_the_hold_defaults_by_the_log(sweep, tmp_path, capsys):
    """A ULog's input is held onto its grid (hold zoh); a CSV's is taken as sampled (none) unless --hold says."""
    d = _identify_json(sweep, "--reference", "vehicle_rates_setpoint.roll", "--poles", "2", capsys=capsys)
    assert d["options"]["hold"] == "zoh" and d["options"]["hold_check"]["checked"]


def test_implausible_rates_and_clocks(tmp_path, capsys):
    """A rate no tune could use is refused; a clock in milliseconds is pointed out; a ULog clock that jumps is
    called corrupt, not a rate problem."""
    import numpy as np

    from tests.ulog_writer import Topic, write_ulog
    from tuner.errors import TunerError

    rng = np.random.default_rng(0)
    u = rng.standard_normal(2000)
    y = np.convolve(u, [0.3, 0.3, 0.2])[:2000]
    with pytest.raises(TunerError, match=r"rate_hz = 1e-12 Hz: the sample interval must be") as ei:
        identify(u, y, rate_hz=1e-12, poles=1)
    assert ei.value.field == ("rate_hz",)
    res = identify(u, y, time=np.arange(2000) * 4.0, poles=1)
    assert "milliseconds" in res.warnings[0] and "250 Hz" in res.warnings[0]
    ts = 1_000_000 + np.arange(2000) * 2500
    ts[1000:] += 10**13  # a clock that jumps by four months
    tq = Topic("vehicle_torque_setpoint", [("float", "xyz", 3)], ts, {"xyz": np.stack([u, u, u], 1)})
    av = Topic("vehicle_angular_velocity", [("float", "xyz", 3)], ts, {"xyz": np.stack([y, y, y], 1)})
    log = write_ulog(tmp_path / "jump.ulg", [tq, av])
    from tuner.cli import main

    assert main(["identify", str(log), "--input", "vehicle_torque_setpoint.xyz[0]", "--output",
                 "vehicle_angular_velocity.xyz[0]", "--poles", "1"]) == 2
    err = capsys.readouterr().err
    assert "corrupt timestamps" in err and "--rate" not in err
