"""Inputs found by fuzzing the service: each must give the library's error (or a result), never a crash."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from tuner import TunerError, make_plant, plant_from_expr
from tuner.analysis.verify import analyze
from tuner.errors import InvalidPlantError
from tuner.tradeoff import tradeoff
from tuner.tuning import tune


def test_overflow_when_made_monic_is_rejected():
    with pytest.raises(InvalidPlantError, match="overflow"):
        make_plant([1e300], [1e-300, 1.0])


@pytest.mark.parametrize("den", [[1.0, 1e300], [1.0] + [1e20] * 20])
def test_extreme_coefficients_give_an_error_or_an_honest_result(den):
    plant = make_plant([1.0], den)
    try:
        r = tune(plant, structure="pi", dt=0.1, time_budget_s=120)
    except TunerError as e:  # an error must say what to change
        assert re.search(r"rescale|overflow|coefficient", str(e)), str(e)
    else:  # no spec claimed unless the verifier, run afresh on the returned controller, says so
        again = analyze(plant, r.controller, r.spec)
        assert again.meets_spec == r.meets_spec
        assert [(c.name, c.ok) for c in again.checks] == [(c.name, c.ok) for c in r.analyses[0].checks]


def test_sub_microsecond_continuous_delay_is_a_clear_error():
    with pytest.raises(InvalidPlantError, match="too short to simulate"):
        tune(make_plant([1.0], [1.0, 1.0], delay=1e-9), structure="pi", time_budget_s=5)


def test_a_tiny_budget_still_returns_a_verified_result():
    # the plant-based starts are always scored, so there is always a verified candidate to return
    r = tune(plant_from_expr("1/(s+1)"), structure="pi", dt=0.1, time_budget_s=0.01)
    assert r.solver["budget_exhausted"] is True
    # the verdict on stability, checked independently: closed-loop poles of the ZOH loop, written here
    a = math.exp(-0.1)  # G(z) = (1 - a)/(z - a)
    n0, n1 = (float(x) for x in r.controller.num)  # C(z) = (n0 z + n1)/(z - 1)
    assert list(r.controller.den) == [1.0, -1.0]
    poles = np.roots(np.polyadd(np.polymul([1.0, -a], [1.0, -1.0]), (1 - a) * np.array([n0, n1])))
    assert r.analyses[0].metrics.stable == bool(np.max(np.abs(poles)) < 1.0)


@pytest.mark.parametrize("seed", [-1, 2**32, 1.5])
def test_bad_seed(seed):
    with pytest.raises(TunerError, match="seed"):
        tune(plant_from_expr("1/(s+1)"), structure="pi", dt=0.1, seed=seed)


@pytest.mark.parametrize("budget", [True, 0, -1.0, math.inf, math.nan, "10"])
def test_bad_budget_is_named(budget):
    """``time_budget_s=True`` was taken as 1 s (a bool is an int): every non-number, and every number that is not a
    finite positive count of seconds, is refused by name, by ``tune`` and by ``tradeoff``."""
    with pytest.raises(TunerError, match="time_budget_s must be a finite number > 0"):
        tune(plant_from_expr("1/(s+1)"), structure="pi", dt=0.1, time_budget_s=budget)
    with pytest.raises(TunerError, match="time_budget_s must be a finite number > 0"):  # the trade-off curve too
        tradeoff(plant_from_expr("1/(s+1)"), structure="pi", dt=0.1, time_budget_s=budget)
