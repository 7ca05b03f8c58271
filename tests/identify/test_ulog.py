"""PX4 ULog logs (issue 19, part 5): written here by a minimal writer of the published format
(tests/ulog_writer.py), read through pyulog, resampled, split at gaps, and identified as the CSV."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from flight import AXES, fly, true_response
from ulog_writer import Topic, write_ulog

from tuner.cli import main
from tuner.errors import InvalidDataError
from tuner.identify import IdentifyResult, identify
from tuner.identify.ulog import parse_signal, read_ulog

T0_US = 5_000_000  # the sweep starts 5 s after the logger
IN, OUT = "vehicle_torque_setpoint.xyz[1]", "vehicle_angular_velocity.xyz[1]"


def _vec(x: np.ndarray, axis: int = 1) -> np.ndarray:
    """A (n, 3) float array with ``x`` in column ``axis`` and other signals beside it."""
    v = np.zeros((x.size, 3))
    v[:, axis] = x
    v[:, 0] = 0.5 * np.sin(np.arange(x.size) * 0.01)
    return v


def _topics(t_in_s, u, t_out_s, y) -> list[Topic]:
    xyz = [("float", "xyz", 3)]
    return [Topic("vehicle_torque_setpoint", xyz, T0_US + np.round(np.asarray(t_in_s) * 1e6).astype(int),
                  {"xyz": _vec(u)}),
            Topic("vehicle_angular_velocity", xyz, T0_US + np.round(np.asarray(t_out_s) * 1e6).astype(int),
                  {"xyz": _vec(y)}),
            Topic("vehicle_angular_velocity", xyz, T0_US + 700 + np.round(np.asarray(t_out_s) * 1e6).astype(int),
                  {"xyz": _vec(-y)}, multi_id=1)]


def _csv(path, t, u, y) -> str:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", "cmd", "rate"])
        w.writerows([f"{a:.9g}", f"{b:.9g}", f"{c:.9g}"] for a, b, c in zip(t, u, y))
    return str(path)


def _cli_json(capsys, argv) -> IdentifyResult:
    assert main([*argv, "--poles", "2", "--json"]) == 0
    return IdentifyResult.from_dict(json.loads(capsys.readouterr().out))


def _differ(a: IdentifyResult, b: IdentifyResult) -> tuple[float, float]:
    w = np.geomspace(*a.band_rad_s, 200)
    r = a.model.freqresp(w) / b.model.freqresp(w)
    return float(np.max(np.abs(20 * np.log10(np.abs(r))))), float(np.max(np.abs(np.degrees(np.angle(r)))))


@pytest.fixture(scope="module")
def flight():
    return fly(*AXES["pitch"], seed=31, duration_s=60.0, log_hz=1000.0)  # 1 kHz, to publish topics from


def test_the_same_log_as_ulog_and_as_csv_gives_the_same_model(tmp_path, flight, capsys):
    """Both topics published at 50 Hz at the same instants, the CSV at the same samples (the ULog's
    floats are float32: the models differ by that rounding only)."""
    t, u, y = flight.t[::20], flight.u[::20], flight.y[::20]
    ulg = write_ulog(tmp_path / "pitch.ulg", _topics(t, u, t, y))
    from_csv = _cli_json(capsys, ["identify", _csv(tmp_path / "pitch.csv", t, u, y), "--time", "t",
                                  "--input", "cmd", "--output", "rate"])
    # (a pilot's stick, sampled: --hold none, as the CSV's default; a ULog's default is a held input)
    from_ulog = _cli_json(capsys, ["identify", str(ulg), "--input", IN, "--output", OUT, "--hold", "none"])
    assert from_ulog.rate_hz == pytest.approx(50.0) and from_ulog.n_samples == from_csv.n_samples
    mag, ph = _differ(from_ulog, from_csv)
    assert mag <= 0.1 and ph <= 0.5, (mag, ph)
    assert from_ulog.band_rad_s == pytest.approx(from_csv.band_rad_s, rel=1e-6)


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_asynchronous_topics_resampled_give_the_csv_model(tmp_path, capsys):
    """The command at 50 Hz, the rate gyro at 250 Hz 3 ms out of step (a second instance beside it):
    the output interpolated onto the command's instants gives the model of the CSV sampled there.
    Gusts but no sensor noise, so that the two records differ by the interpolation alone."""
    fl = fly(*AXES["pitch"], seed=31, duration_s=60.0, log_hz=1000.0, noise_frac=0.0, random_walk=0.0)
    t_in, u = fl.t[::20], fl.u[::20]
    t_out, y = fl.t[3::4], fl.y[3::4]
    ulg = write_ulog(tmp_path / "async.ulg", _topics(t_in, u, t_out, y))
    rec = read_ulog(ulg, {"input": IN, "output": OUT})
    assert rec.rate_hz == 50.0 and len(rec.inputs) == 1 and not rec.gaps
    n = rec.inputs[0].size  # the grid starts on the first command after the gyro's first sample
    np.testing.assert_allclose(rec.inputs[0], u[1:1 + n].astype(np.float32))  # held: exact
    y_at = fl.y[20:20 * (n + 1):20]  # the gyro's signal at the commands' instants
    assert np.max(np.abs(rec.outputs[0] - y_at)) < 1e-3 * np.std(y_at)  # linear interpolation from 250 Hz
    from_csv = _cli_json(capsys, ["identify", _csv(tmp_path / "a.csv", t_in[1:1 + n], u[1:1 + n], y_at),
                                  "--time", "t", "--input", "cmd", "--output", "rate"])
    from_ulog = _cli_json(capsys, ["identify", str(ulg), "--input", IN, "--output", OUT, "--hold", "none"])
    mag, ph = _differ(from_ulog, from_csv)
    assert mag <= 0.1 and ph <= 0.5, (mag, ph)
    # the other instance is the negated signal: its model is the same up to the sign
    neg = _cli_json(capsys, ["identify", str(ulg), "--input", IN, "--output", "vehicle_angular_velocity:1.xyz[1]"])
    assert neg.model.gain == pytest.approx(-from_ulog.model.gain, rel=0.02)


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_gaps_split_the_log_into_records_fitted_together(tmp_path):
    """A 1.5 s hole in the gyro topic and a logged dropout: three pieces, fitted as one (120 s, so that
    each piece still resolves the plant's low band)."""
    fl = fly(*AXES["pitch"], seed=33, duration_s=120.0, log_hz=250.0)
    t_in, u = fl.t[::5], fl.u[::5]
    hole = (fl.t > 40.0) & (fl.t < 41.5)
    ulg = write_ulog(tmp_path / "gaps.ulg", _topics(t_in, u, fl.t[~hole], fl.y[~hole]),
                     dropouts=[(T0_US + 80_000_000, 300)])
    rec = read_ulog(ulg, {"input": IN, "output": OUT}, rate_hz=50.0)
    assert len(rec.inputs) == 3 and len(rec.gaps) == 2
    (a1, b1), (a2, b2) = rec.gaps
    assert a1 == pytest.approx(45.0, abs=0.01) and b1 == pytest.approx(46.5, abs=0.01)  # 5 s after the logger
    assert a2 == pytest.approx(85.0, abs=0.01) and b2 - a2 == pytest.approx(0.3, abs=0.01)
    assert rec.t_starts_s[1] >= b1 and rec.t_starts_s[2] >= b2
    res = identify(rec.inputs, rec.outputs, rate_hz=rec.rate_hz, poles=2)
    assert res.options["records"] == 3
    w = np.geomspace(*res.band_rad_s, 200)
    ratio = res.model.freqresp(w) / true_response(fl, w)
    assert np.max(np.abs(20 * np.log10(np.abs(ratio)))) <= 1.0 and np.max(np.abs(np.degrees(np.angle(ratio)))) <= 5


def test_a_log_with_no_long_stretch_between_gaps_is_refused(tmp_path, flight):
    t, u, y = flight.t[::20], flight.u[::20], flight.y[::20]
    keep = (t % 2.0) < 1.0  # one second in two
    ulg = write_ulog(tmp_path / "holes.ulg", _topics(t, u, t[keep], y[keep]))
    with pytest.raises(InvalidDataError, match=r"no stretch of the log between gaps holds 128 samples at 50 Hz "
                                               r"\(gaps: 5\.980-7\.000 s, 7\.980-9\.000 s") as e:
        read_ulog(ulg, {"input": IN, "output": OUT})
    assert e.value.field == ("input",)


def test_wrong_names_list_what_the_log_has(tmp_path, flight, capsys):
    t, u, y = flight.t[::20][:300], flight.u[::20][:300], flight.y[::20][:300]
    ulg = str(write_ulog(tmp_path / "small.ulg", _topics(t, u, t, y)))
    for out, expect in (
            ("vehicle_rates.xyz[0]", "no topic 'vehicle_rates' in the log; topics: ['vehicle_angular_velocity', "
                                     "'vehicle_angular_velocity:1', 'vehicle_torque_setpoint']"),
            ("vehicle_angular_velocity.xyz[3]", "has no field 'xyz[3]'; fields: ['xyz[0]', 'xyz[1]', 'xyz[2]']"),
            ("vehicle_angular_velocity:2.xyz[0]", "has instances [0, 1], not 2"),
            ("angular velocity", "name a ULog signal as TOPIC.FIELD")):
        assert main(["identify", ulg, "--input", IN, "--output", out, "--poles", "2"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"tuner: error: --output {out}: ") and expect in err and "Traceback" not in err, err
    bad = tmp_path / "junk.ulg"
    bad.write_bytes(b"not a log at all" * 10)
    assert main(["identify", str(bad), "--input", IN, "--output", OUT, "--poles", "2"]) == 2
    assert "not a readable ULog file" in capsys.readouterr().err


def test_signal_names():
    assert parse_signal("vehicle_angular_velocity.xyz[0]", "output") == ("vehicle_angular_velocity", 0, "xyz[0]")
    assert parse_signal("actuator_controls_0:1.control[2]", "input") == ("actuator_controls_0", 1, "control[2]")
    assert parse_signal("estimator_status.states.q[1]", "input") == ("estimator_status", 0, "states.q[1]")
    for bad in ("topic", "topic:x.f", ".field", "topic:1", "to pic.f"):
        with pytest.raises(InvalidDataError, match="TOPIC.FIELD"):
            parse_signal(bad, "input")


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_several_files_and_a_verification_log_on_the_command_line(tmp_path, capsys):
    """Two sweeps (ULog and CSV at the same rate) fitted together, a ULog of doublets to verify."""
    logs = [fly(*AXES["pitch"], seed=s, duration_s=45.0, sweep_fraction=1.0) for s in (41, 42)]
    ver = fly(*AXES["pitch"], seed=43, duration_s=45.0)
    a = write_ulog(tmp_path / "a.ulg", _topics(logs[0].t, logs[0].u, logs[0].t, logs[0].y))
    b = _csv(tmp_path / "b.csv", logs[1].t, logs[1].u, logs[1].y)
    v = write_ulog(tmp_path / "v.ulg", _topics(ver.t, ver.u, ver.t, ver.y))
    with pytest.raises(SystemExit):  # one input name for both kinds of file only works with matching names
        main(["identify", str(a), "--file", b, "--time", "t"])
    both = tmp_path / "b2.csv"
    both.write_text(open(b).read().replace("t,cmd,rate", f"t,{IN},{OUT}", 1))
    res = _cli_json(capsys, ["identify", str(a), "--file", str(both), "--rate", "50", "--input", IN,
                             "--output", OUT, "--verify", str(v)])
    assert res.options["records"] == 2 and res.validation.source == "verify" and res.check != "poor"
    w = np.geomspace(*res.band_rad_s, 200)
    ratio = res.model.freqresp(w) / true_response(logs[0], w)
    assert np.max(np.abs(20 * np.log10(np.abs(ratio)))) <= 1.0


def test_the_output_is_taken_at_its_sample_time(tmp_path, flight):
    """A gyro topic with PX4's timestamp_sample (measured 2.5 ms before it is published): the output is
    placed at the sample time; the input at its publication."""
    t, u, y = flight.t[::20], flight.u[::20], flight.y[::20]
    pub = T0_US + np.round(t * 1e6).astype(int)
    gyro = Topic("vehicle_angular_velocity", [("uint64_t", "timestamp_sample", 0), ("float", "xyz", 3)], pub + 2500,
                 {"timestamp_sample": pub, "xyz": _vec(y)})
    ulg = write_ulog(tmp_path / "ts.ulg", [_topics(t, u, t, y)[0], gyro])
    rec = read_ulog(ulg, {"input": IN, "output": OUT})
    n = rec.inputs[0].size
    np.testing.assert_allclose(rec.outputs[0], y[:n].astype(np.float32), rtol=1e-6)  # not 2.5 ms late
    with pytest.raises(InvalidDataError, match=r"fields: \['xyz\[0\]', 'xyz\[1\]', 'xyz\[2\]'\]"):
        read_ulog(ulg, {"input": IN, "output": "vehicle_angular_velocity.timestamp_sample"})


def test_a_log_file_is_opened_once(tmp_path, flight, capsys, monkeypatch):
    """Issue 31: identify tells a CSV from a ULog log and reads it from one handle (a second open of a FIFO hung, and
    a sniff that consumed a pipe's first buffer made a data row the header)."""
    import builtins
    import io
    import os

    t, u, y = flight.t[::20], flight.u[::20], flight.y[::20]
    ulg = str(write_ulog(tmp_path / "pitch.ulg", _topics(t, u, t, y)))
    csv_path = _csv(tmp_path / "pitch.csv", t, u, y)
    opened: list[str] = []
    real = builtins.open

    def counting(file, *args, **kw):
        if str(file) in (ulg, csv_path):
            opened.append(str(file))
        return real(file, *args, **kw)

    real_os_open = os.open

    def counting_os(path, *args, **kw):  # (tuner.fileio opens with os.open, to check the opened handle)
        if str(path) in (ulg, csv_path):
            opened.append(str(path))
        return real_os_open(path, *args, **kw)

    monkeypatch.setattr(builtins, "open", counting)
    monkeypatch.setattr(io, "open", counting)  # (pathlib opens through io.open)
    monkeypatch.setattr(os, "open", counting_os)
    _cli_json(capsys, ["identify", csv_path, "--time", "t", "--input", "cmd", "--output", "rate"])
    assert opened == [csv_path]
    opened.clear()
    _cli_json(capsys, ["identify", ulg, "--input", IN, "--output", OUT])
    assert opened == [ulg]
