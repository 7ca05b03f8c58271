"""A time column's unit (issue 42, item 2): a microsecond timestamp (PX4's CSV exports) read as seconds made the
model's time constants a million times too slow without a word, and a 2 kHz log in milliseconds was not pointed out.
With ``time_unit="auto"`` such a column is refused (exit 2, 422 at time_unit) until its unit is said; ``"us"`` and
``"ms"`` read it, giving the model of the same log timed in seconds."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from flight import AXES, fly

from tuner.cli import main
from tuner.errors import InvalidDataError
from tuner.identify import identify


@pytest.fixture(scope="module")
def log250():
    return fly(*AXES["pitch"], seed=8, duration_s=40.0, log_hz=250.0)


def _same(a, b) -> None:
    """The same model, parameter by parameter (the time base differs by rounding only)."""
    va, vb = a.model.values(), b.model.values()
    assert va.keys() == vb.keys() and all(va[k] == pytest.approx(vb[k], rel=1e-6, abs=1e-12) for k in va), (va, vb)
    assert a.rate_hz == pytest.approx(b.rate_hz)


def test_a_microsecond_timestamp_is_refused_then_read_when_said(log250):
    t_us = np.round(log250.t * 1e6).astype(np.int64) + 1_234_000_000  # a logger's clock: whole microseconds
    with pytest.raises(InvalidDataError, match=r"steps by 4000 in whole numbers: a timestamp in microseconds "
                                               r"\(as PX4 logs one: 250 Hz\)\? say which unit it is: 'us'") as e:
        identify(log250.u, log250.y, time=t_us, poles=2)
    assert e.value.field == ("time_unit",)
    _same(identify(log250.u, log250.y, time=t_us, poles=2, time_unit="us"),
          identify(log250.u, log250.y, time=log250.t, poles=2))


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_a_khz_log_in_milliseconds_is_refused_then_read_when_said():
    fk = fly(*AXES["pitch"], seed=8, duration_s=20.0, log_hz=2000.0, sim_hz=2000.0)
    with pytest.raises(InvalidDataError, match=r"steps by 0.5: milliseconds \(a 2000 Hz log\)\? say which unit it "
                                               r"is: 'ms' to read it so, or 's' if the samples are 0.5 s apart") as e:
        identify(fk.u, fk.y, time=fk.t * 1e3, poles=2)
    assert e.value.field == ("time_unit",)
    _same(identify(fk.u, fk.y, time=fk.t * 1e3, poles=2, time_unit="ms"), identify(fk.u, fk.y, time=fk.t, poles=2))
    slow = identify(fk.u, fk.y, time=fk.t * 1e3, poles=2, time_unit="s")  # said to be a 2 Hz log: taken so, no word
    assert slow.rate_hz == pytest.approx(2.0) and not any("milliseconds" in w for w in slow.warnings)


def test_plain_seconds_and_a_bad_unit(log250):
    assert identify(log250.u, log250.y, time=log250.t, poles=2).rate_hz == pytest.approx(250.0)
    with pytest.raises(InvalidDataError, match="time_unit must be 'auto', 's', 'ms' or 'us', got 'h'"):
        identify(log250.u, log250.y, time=log250.t, poles=2, time_unit="h")


def test_the_command_line_points_at_time_unit(log250, tmp_path, capsys):
    p = tmp_path / "px4.csv"
    with open(p, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["timestamp", "cmd", "rate"])
        w.writerows((int(round(t * 1e6)), f"{u:.6g}", f"{y:.6g}") for t, u, y in zip(log250.t, log250.u, log250.y))
    args = ["identify", str(p), "--time", "timestamp", "--input", "cmd", "--output", "rate", "--poles", "2"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("tuner: error: --time-unit: the time column steps by 4000 in whole numbers"), err
    assert main([*args, "--time-unit", "us", "--json"]) == 0
    assert '"rate_hz": 250.0' in capsys.readouterr().out
