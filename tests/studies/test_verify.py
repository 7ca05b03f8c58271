"""``tuner verify FILE --gains GAINS.json``: the CI gate on committed gains."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tuner.cli import main

ROOT = Path(__file__).resolve().parents[2]
QUAD = ROOT / "studies" / "quadrotor.toml"
GAINS = ROOT / "studies" / "quadrotor.gains.json"


@pytest.fixture
def gains():
    return json.loads(GAINS.read_text())


def _write(tmp_path, data) -> str:
    p = tmp_path / "gains.json"
    p.write_text(json.dumps(data))
    return str(p)


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_committed_gains_verify(capsys):
    assert main(["verify", str(QUAD), "--gains", str(GAINS)]) == 0
    out = capsys.readouterr().out
    assert "all 9 loops of study 'quadrotor' meet their spec" in out
    for name in ("roll", "pitch", "yaw", "x", "y", "altitude"):
        assert name in out


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_committed_gains_json_figures(capsys):
    assert main(["verify", str(QUAD), "--gains", str(GAINS), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert set(d) == {"roll", "pitch", "yaw", "x", "y", "altitude", "roll_limited", "pitch_limited", "yaw_limited"}
    for name, e in d.items():
        assert e["meets_spec"] is True, name
        assert e["metrics"]["phase_margin_deg"] >= 60.0 and e["metrics"]["gain_margin_db"] >= 6.0
    assert d["x"]["cascade"]["inner"] == "pitch" and d["y"]["cascade"]["inner"] == "roll"


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_pitch_gain_times_three_fails_and_is_named(tmp_path, gains, capsys):
    gains["pitch"]["gains"]["K"] *= 3
    assert main(["verify", str(QUAD), "--gains", _write(tmp_path, gains)]) == 1
    cap = capsys.readouterr()
    err = cap.err.strip().splitlines()
    assert len(err) == 1 and "fail their spec" in err[0] and "pitch (" in err[0]
    assert "roll (" not in err[0] and "yaw (" not in err[0]  # only the broken loop (and what wraps it)
    assert "FAIL" in cap.out


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_outer_loop_alone_broken(tmp_path, gains, capsys):
    gains["y"]["gains"]["K"] *= 10
    assert main(["verify", str(QUAD), "--gains", _write(tmp_path, gains)]) == 1
    err = capsys.readouterr().err
    assert "y (" in err and "roll (" not in err


@pytest.mark.parametrize("mutate, message", [
    (lambda g: g.pop("yaw"), "loop 'yaw': missing"),
    (lambda g: g["roll"].update(structure="pid"), "loop 'roll': structure is 'pid'"),
    (lambda g: g["roll"].update(dt=0.02), "loop 'roll': dt is 0.02"),
    (lambda g: g["roll"]["gains"].pop("a2"), "loop 'roll': gains: pid_z takes parameters"),
    (lambda g: g.update(z={"gains": {}}), "loops not in study 'quadrotor': ['z']"),
])
def test_bad_gains_file_exits_2(tmp_path, gains, capsys, mutate, message):
    mutate(gains)
    assert main(["verify", str(QUAD), "--gains", _write(tmp_path, gains)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_unreadable_inputs_exit_2(tmp_path, capsys):
    assert main(["verify", str(QUAD), "--gains", str(tmp_path / "none.json")]) == 2
    assert "cannot read" in capsys.readouterr().err
    p = tmp_path / "g.json"
    p.write_text("{not json")
    assert main(["verify", str(QUAD), "--gains", str(p)]) == 2
    assert "not valid JSON" in capsys.readouterr().err
    assert main(["verify", str(tmp_path / "none.toml"), "--gains", str(GAINS)]) == 2
