"""Inputs found by fuzzing the service: each must give the library's error (or a result), never a crash."""

from __future__ import annotations

import pytest

from tuner import TunerError, make_plant, plant_from_expr
from tuner.errors import InvalidPlantError
from tuner.tuning import tune


def test_overflow_when_made_monic_is_rejected():
    with pytest.raises(InvalidPlantError, match="overflow"):
        make_plant([1e300], [1e-300, 1.0])


@pytest.mark.parametrize("den", [[1.0, 1e300], [1.0] + [1e20] * 20])
def test_extreme_coefficients_give_an_error_or_an_honest_result(den):
    try:
        r = tune(make_plant([1.0], den), structure="pi", dt=0.1, time_budget_s=5)
    except TunerError as e:
        assert str(e)
    else:  # no spec claimed unless the verifier says so
        assert r.meets_spec == all(a.meets_spec for a in r.analyses)


def test_sub_microsecond_continuous_delay_is_a_clear_error():
    with pytest.raises(InvalidPlantError, match="too short to simulate"):
        tune(make_plant([1.0], [1.0, 1.0], delay=1e-9), structure="pi", time_budget_s=5)


def test_a_tiny_budget_still_returns_a_verified_result():
    # the plant-based starts are always scored, so there is always a verified candidate to return
    r = tune(plant_from_expr("1/(s+1)"), structure="pi", dt=0.1, time_budget_s=0.01)
    assert r.solver["budget_exhausted"] is True
    assert r.analyses and r.analyses[0].metrics.stable in (True, False)


@pytest.mark.parametrize("seed", [-1, 2**32, 1.5])
def test_bad_seed(seed):
    with pytest.raises(TunerError, match="seed"):
        tune(plant_from_expr("1/(s+1)"), structure="pi", dt=0.1, seed=seed)
