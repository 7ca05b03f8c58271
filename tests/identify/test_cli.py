"""``tuner identify FILE.csv ...``: tables, JSON, the plot, and exit code 2 with a message for bad input."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from flight import AXES, THIRD_ORDER, fly

from tuner.cli import main


def _write(path, rows, header=("t", "cmd", "angle"), comment: str | None = "# a flight log") -> str:
    with open(path, "w", newline="") as f:
        if comment:
            f.write(comment + "\n")
        w = csv.writer(f)
        w.writerow(header)
        for r in rows:
            w.writerow(r)
    return str(path)


@pytest.fixture(scope="module")
def log():
    return fly(*AXES["pitch"], seed=8, duration_s=60.0)


@pytest.fixture
def csv_file(tmp_path, log):
    rows = ([f"{t:.6g}", f"{u:.6g}", f"{y:.6g}"] for t, u, y in zip(log.t, log.u, log.y))
    return _write(tmp_path / "pitch.csv", rows)


ARGS = ["--time", "t", "--input", "cmd", "--output", "angle", "--poles", "2", "--delay-step", "0.04"]


def test_tables(csv_file, capsys):
    assert main(["identify", csv_file, *ARGS]) == 0
    out = capsys.readouterr().out
    assert out.startswith("G(s) = (") and "delay=0.04 s" in out
    for text in ("pole_wn_1_rad_s", "pole_zeta_1", "CR bound", "cost J = ", ": good (CIFER",
                 "time-domain check on the held-out end of the record (48", "x the noise floor"):
        assert text in out, text


def test_json_fields(csv_file, capsys):
    assert main(["identify", csv_file, *ARGS, "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert {"num", "den", "delay"} <= set(d["model"]) and d["model"]["delay"] == pytest.approx(0.04)
    assert d["cost"] < 50 and d["quality"] == "good" and len(d["band_rad_s"]) == 2
    fr = d["frequency_response"]
    assert {"w", "mag_db", "phase_deg", "coherence"} <= set(fr) and len(fr["w"]) == len(fr["coherence"]) > 50
    assert set(d["uncertainty"]) == {"gain", "pole_wn_1_rad_s", "pole_zeta_1", "delay_s"}
    assert {"nrmse", "theil_u", "fit_pct"} <= set(d["validation"])


def test_rate_instead_of_time_and_a_plot(tmp_path, log, capsys):
    path = _write(tmp_path / "norate.csv", ([f"{u:.6g}", f"{y:.6g}"] for u, y in zip(log.u, log.y)),
                  header=("cmd", "angle"), comment=None)
    png = tmp_path / "fit.png"
    assert main(["identify", path, "--rate", "50", "--input", "cmd", "--output", "angle", "--poles", "2",
                 "--plot", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"wrote {png}" in capsys.readouterr().out


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_check_exits_1_on_a_poor_fit(tmp_path, capsys):
    third = fly(*THIRD_ORDER, seed=4)
    path = _write(tmp_path / "third.csv", ([f"{t:.6g}", f"{u:.6g}", f"{y:.6g}"]
                                           for t, u, y in zip(third.t, third.u, third.y)))
    assert main(["identify", path, *ARGS, "--check"]) == 1
    assert "try more poles" in capsys.readouterr().out
    assert main(["identify", path, *ARGS[:-4], "--poles", "3", "--check"]) == 0


def _err(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.startswith("tuner: error: ")
    return err


def test_bad_inputs_exit_2_naming_the_problem(tmp_path, csv_file, log, capsys):
    err = _err(capsys, ["identify", csv_file, *ARGS[:2], "--input", "stick", *ARGS[4:]])
    assert "no column 'stick' (for the input); columns: ['t', 'cmd', 'angle']" in err
    err = _err(capsys, ["identify", str(tmp_path / "none.csv"), *ARGS])
    assert "none.csv: cannot read" in err
    err = _err(capsys, ["identify", csv_file, *ARGS, "--band", "0.05", "10"])
    assert "--band: band starts at 0.05 rad/s" in err and "too few cycles" in err
    err = _err(capsys, ["identify", csv_file, *ARGS, "--zeros", "3"])
    assert "--zeros: zeros must be an integer from 0 to 2, got 3" in err
    rows = [[f"{t:.6g}", "0.5", f"{y:.6g}"] for t, y in zip(log.t, log.y)]
    err = _err(capsys, ["identify", _write(tmp_path / "const.csv", rows), *ARGS])
    assert "--input cmd: input is constant (0.5): nothing excites the plant" in err
    rows = [[f"{t:.6g}", f"{u:.6g}", f"{y:.6g}"] for t, u, y in zip(log.t, log.u, log.y)]
    rows[10][2] = "n/a"
    err = _err(capsys, ["identify", _write(tmp_path / "text.csv", rows), *ARGS])
    assert "text.csv, line 13, column 'angle': not a number: 'n/a'" in err  # comment + header + 10 rows
    rows[10][2] = "nan"
    err = _err(capsys, ["identify", _write(tmp_path / "nan.csv", rows), *ARGS])
    assert "nan.csv, line 13, column 'angle': nan (non-finite)" in err
    rows = [[f"{t:.6g}", f"{u:.6g}", f"{y:.6g}"] for t, u, y in zip(log.t[::-1], log.u, log.y)]
    err = _err(capsys, ["identify", _write(tmp_path / "back.csv", rows), *ARGS])
    assert "--time t: time is not strictly increasing" in err
    noise = np.random.default_rng(0).standard_normal(log.u.size)
    rows = [[f"{t:.6g}", f"{u:.6g}", f"{y:.6g}"] for t, u, y in zip(log.t, log.u, noise)]
    err = _err(capsys, ["identify", _write(tmp_path / "noise.csv", rows), *ARGS])
    assert "--output angle: no coherent band" in err


def test_argument_errors_exit_2(csv_file, capsys):
    for argv in (["identify", csv_file, *ARGS, "--delay", "soon"],
                 ["identify", csv_file, *ARGS, "--rate", "50"]):  # both
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2
    assert "expected auto, none or seconds, got 'soon'" in capsys.readouterr().err
    # no --time/--rate: a CSV needs one (a ULog log does not, hence not an argparse rule)
    err = _err(capsys, ["identify", csv_file, "--input", "cmd", "--output", "angle", "--poles", "2"])
    assert "a CSV log needs --time COL (a time column) or --rate HZ" in err


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_unwritable_plot_is_a_clean_error(csv_file, tmp_path, capsys):
    err = _err(capsys, ["identify", csv_file, *ARGS, "--plot", str(tmp_path / "no" / "dir" / "fit.png")])
    assert "--plot" in err and "cannot write" in err
