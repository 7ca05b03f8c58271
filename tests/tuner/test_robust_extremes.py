"""Issue 39 item 5: the robust set and the Monte Carlo check never crash.

pyulog's sample.ulg, identified from its roll torque to its roll rate (a closed-loop fit, J 2627), has Cramér–Rao
bounds of 767336 % on its pole frequency: the 2-sigma corners were ``778.7 * exp(2 * 7673)`` and ``tune(...,
robust=2)`` died of an OverflowError (the service answered 500). Bounds too wide for a set are now refused before
any work (exit 2 / 422 at ``robust`` or ``monte_carlo``), naming the parameters; here a property test drives
``plant_set`` and ``monte_carlo`` with generated identifications, extremes included (parameters and bounds over
twelve decades, correlated), and each either returns plants that are numbers or raises a TunerError at its field.
"""

from __future__ import annotations

import math
from dataclasses import replace
from functools import lru_cache

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from tuner import TunerError, controller_from_coeffs, identify
from tuner.identify.model import Model
from tuner.identify.uncertainty import ParameterUncertainty
from tuner.robust import MAX_SPREAD, check_spread, monte_carlo, plant_set

SETTINGS = dict(deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck),
                max_examples=80)


@lru_cache(maxsize=1)
def base():
    """A second-order identification with a delay (the structure of a rate loop's fit), from a noise-free sweep."""
    rng = np.random.default_rng(3)
    u = rng.standard_normal(6000)
    # 2 poles (wn 20 rad/s, zeta 0.5) and 2 samples of delay at 200 Hz, by a recursion written here
    dt, wn, z = 0.005, 20.0, 0.5
    a1, a2 = 2 * math.exp(-z * wn * dt) * math.cos(wn * dt * math.sqrt(1 - z * z)), -math.exp(-2 * z * wn * dt)
    y = np.zeros(u.size)
    for k in range(4, u.size):
        y[k] = a1 * y[k - 1] + a2 * y[k - 2] + (1 - a1 - a2) * u[k - 3]
    return identify(u, y, rate_hz=200, poles=2, delay="auto", n_starts=2)


def _with(base, values: dict[str, float], sigma: dict[str, float], corr: np.ndarray):
    """``base`` with the model's parameters ``values`` and the bounds ``sigma`` (1-sigma, the parameters' units),
    correlated by ``corr``."""
    o = base.model.structure
    model = Model.from_values(o.poles, o.zeros, values)
    names = list(base.uncertainty)
    unc = {n: ParameterUncertainty(value=values[n], cr_bound=sigma[n],
                                   cr_bound_pct=100 * sigma[n] / abs(values[n]) if values[n] else math.inf,
                                   insensitivity=sigma[n], insensitivity_pct=math.inf) for n in names}
    s = np.array([sigma[n] for n in names])
    return replace(base, model=model, uncertainty=unc, covariance=corr * np.outer(s, s))


def _corr(n: int, seed: int, strength: float) -> np.ndarray:
    """A random correlation matrix: identity for strength 0, strongly correlated near 1."""
    a = np.random.default_rng(seed).standard_normal((n, n))
    c = (1 - strength) * np.eye(n) + strength * (a @ a.T) / n
    d = np.sqrt(np.diag(c))
    return c / np.outer(d, d)


def log_uniform(lo: float, hi: float) -> st.SearchStrategy[float]:
    return st.one_of(st.sampled_from([10.0 ** lo, 10.0 ** hi]), st.floats(lo, hi).map(lambda e: float(10.0 ** e)))


@settings(**SETTINGS)
@given(gain=log_uniform(-6, 6), wn=log_uniform(-3, 4), zeta=log_uniform(-3, 1), delay=st.floats(0.0, 1.0),
       rel=st.lists(st.one_of(log_uniform(-6, -0.7), log_uniform(-6, 6)), min_size=3, max_size=3),
       delay_sigma=st.one_of(log_uniform(-6, -2), log_uniform(-6, 3)),
       seed=st.integers(0, 10), strength=st.floats(0.0, 0.99), k=st.sampled_from([0.5, 2.0, 10.0]),
       dt=st.sampled_from([None, 0.0025, 0.04]))
@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_any_identification_gives_a_set_or_a_refusal(gain, wn, zeta, delay, rel, delay_sigma, seed, strength,
                                                      k, dt):
    values = {"gain": gain, "pole_wn_1_rad_s": wn, "pole_zeta_1": zeta, "delay_s": delay}
    sigma = {"gain": rel[0] * gain, "pole_wn_1_rad_s": rel[1] * wn, "pole_zeta_1": rel[2] * zeta,
             "delay_s": delay_sigma}
    res = _with(base(), values, sigma, _corr(4, seed, strength))
    try:
        plants, info = plant_set(res, k, dt=dt)
    except TunerError as e:
        assert e.field == ("robust",), e
    else:
        assert len(plants) == info.n_plants
        for p in plants:  # every member is a plant: finite coefficients
            assert np.all(np.isfinite(p.num)) and np.all(np.isfinite(p.den)) and math.isfinite(p.delay_s)
        event("a robust set")
    ctrl = controller_from_coeffs([1.0], [1.0], dt=dt)
    try:
        mc = monte_carlo(res, ctrl, n=3, seed=seed)
    except TunerError as e:
        assert e.field == ("monte_carlo",), e
    else:
        assert mc.n == 3 and 0.0 <= mc.fraction_meeting_spec <= 1.0
        event("Monte Carlo ran")


def _first_order(gain_rel: float):
    """A gain-and-one-pole identification (no delay) whose gain is uncertain by ``gain_rel`` (relative, 1 sigma)."""
    rng = np.random.default_rng(1)
    u = rng.standard_normal(3000)
    y = np.convolve(u, 0.05 * 0.95 ** np.arange(200))[:3000]
    r = identify(u, y, rate_hz=100, poles=1, delay=None, n_starts=2)
    v = r.model.values()
    sig = {"gain": gain_rel * abs(v["gain"]), "pole_1_rad_s": 1e-6 * v["pole_1_rad_s"]}
    unc = {n: replace(r.uncertainty[n], cr_bound=sig[n]) for n in r.uncertainty}
    return replace(r, uncertainty=unc, covariance=np.diag([sig[n] ** 2 for n in r.uncertainty]))


def test_the_spread_rule_in_closed_form():
    """A gain's K-sigma change moves log G by exactly K sigma_rel at every frequency (a gain is in log space): at
    K = 2 a relative bound of 1.10 moves it by 2.2 < ln 10 (a set), 1.20 by 2.4 > ln 10 (refused, naming the gain)."""
    assert pytest.approx(math.log(10)) == MAX_SPREAD
    assert 2 * 1.10 < MAX_SPREAD < 2 * 1.20
    check_spread(_first_order(1.10), 2.0, dt=0.01)
    plant_set(_first_order(1.10), 2.0, dt=0.01)
    with pytest.raises(TunerError) as e:
        plant_set(_first_order(1.20), 2.0, dt=0.01)
    assert e.value.field == ("robust",)
    msg = str(e.value)
    assert "gain = " in msg and "(1 sigma, 120 %)" in msg and "pole_1_rad_s" not in msg
    assert "Fly an excitation" in msg and "rad/s" in msg
    # the Monte Carlo draws are judged at one sigma: 1.20 is no refusal there, 2.4 is
    monte_carlo(_first_order(1.20), controller_from_coeffs([1.0], [1.0], dt=0.01), n=2)
    with pytest.raises(TunerError) as e:
        monte_carlo(_first_order(2.4), controller_from_coeffs([1.0], [1.0], dt=0.01), n=2)
    assert e.value.field == ("monte_carlo",)


@pytest.mark.parametrize("flag", [["--robust", "2"], ["--monte-carlo", "50"]])
def test_the_cli_refuses_bounds_too_wide_in_one_line(tmp_path, capsys, flag):
    """sample.ulg's case: bounds of 7673 times the values (767336 %): exit 2 and one line naming the flag and the
    parameters, where the tune died of an OverflowError (exit 3)."""
    import json

    from tuner.cli import main
    from tuner.jsonio import jsonable

    b = base()
    names = list(b.uncertainty)
    v = b.model.values()
    res = _with(b, v, {n: 7673.0 * abs(v[n]) for n in names}, np.eye(len(names)))
    p = tmp_path / "id.json"
    p.write_text(json.dumps(jsonable(res.to_dict())))
    rc = main(["tune", "--identified", str(p), "--structure", "pid", "--dt", "0.005", "--budget", "1", *flag])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err, err
    assert err.startswith(f"tuner: error: {flag[0]}: ") and "too wide" in err and "pole_wn_1_rad_s" in err
