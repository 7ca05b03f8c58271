"""Issue 30, item 4: integral action demanded through the registry's ``ki_min`` (CLI ``--ki-min``, API and study
files ``ki_min``), and said when the optimum drops it."""

from __future__ import annotations

import json

import pytest

from tuner import Spec, plant_from_expr, tune
from tuner.cli import main
from tuner.limits import limit

RATE = "25/(s*(0.02*s+1))"  # a 250 Hz rate loop's plant (integrating), delay 8 ms, dt 4 ms


def test_ki_min_is_a_registered_limit_everywhere():
    lim = limit("ki_min")
    assert (lim.flag, lim.check, lim.op, lim.batch, lim.nlp) == ("--ki-min", "integral_gain", ">=", "ki", "ki")
    assert Spec(ki_min=2.0).ki_min == 2.0
    with pytest.raises(ValueError):
        Spec(ki_min=0.0)


def test_ki_min_is_met_by_the_tune_and_checked_by_the_verifier():
    plant = plant_from_expr(RATE, delay=0.008)
    r = tune(plant, structure="pid", dt=0.004, spec=Spec(control_peak_max=3, ki_min=1.0), seed=0)
    assert r.meets_spec
    ki = r.analyses[0].metrics.integral_gain
    assert ki >= 1.0 and ki == pytest.approx(abs(r.gains["Ki"]), rel=1e-9)
    assert any(c.name == "integral_gain" and c.ok for c in r.analyses[0].checks)


def test_ki_min_on_the_command_line(capsys):
    code = main(["tune", "--plant", RATE, "--delay", "0.008", "--dt", "0.004", "--structure", "pid",
                 "--control-peak", "3", "--ki-min", "1", "--json"])
    d = json.loads(capsys.readouterr().out)
    assert code == 0 and d["metrics"]["integral_gain"] >= 1.0 and d["spec"]["ki_min"] == 1.0


def test_ki_min_without_an_integrator_is_refused(capsys):
    assert main(["tune", "--plant", "1/(s+1)", "--structure", "pd", "--ki-min", "1"]) == 2
    err = capsys.readouterr().err
    assert "demands integral action, and pd has none" in err and "ki" in err
