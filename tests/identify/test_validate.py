"""The time-domain check: the simulation against a fine continuous simulation, the metrics by hand."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import signal

from tuner.identify.data import Record
from tuner.identify.model import Model
from tuner.identify.validate import simulate, validate

MODELS = {
    "real pole": (1, 0, {"gain": 2.0, "pole_1_rad_s": 5.0}),
    "pair + zero": (3, 1, {"gain": -0.7, "pole_wn_1_rad_s": 8.0, "pole_zeta_1": 0.3, "pole_2_rad_s": 3.0,
                           "zero_1_rad_s": 6.0}),
    "proper (zeros = poles)": (1, 1, {"gain": 1.0, "pole_1_rad_s": 10.0, "zero_1_rad_s": 2.0}),
}


@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize("delay", [0.0, 0.04, 0.05, 0.013])  # whole samples of 0.02 s, and fractions
def test_simulation_is_exact_for_a_held_input(name, delay):
    """Reference: the continuous model at 1 kHz (lsim) with the input held between 50 Hz samples and
    delayed by a whole number of 1 ms steps."""
    poles, zeros, values = MODELS[name]
    m = Model.from_values(poles, zeros, {**values, "delay_s": delay})
    dt, fine = 0.02, 0.001
    rng = np.random.default_rng(0)
    u = rng.standard_normal(200)
    held = np.repeat(u, round(dt / fine))
    d = round(delay / fine)
    held = np.concatenate([np.zeros(d), held[: held.size - d]])
    t = np.arange(held.size) * fine
    num, den = m.tf()
    _, y_ref, _ = signal.lsim((num, den), held, t, interp=False)  # ZOH between 1 ms steps: exact
    y = simulate(m, u, dt)
    step = round(dt / fine)
    assert_allclose(y, y_ref[::step], atol=1e-9 * np.max(np.abs(y_ref)) + 1e-12)


def test_perfect_data_validates_perfectly_and_bias_and_drift_are_found():
    m = Model.from_values(2, 0, {"gain": 0.3, "pole_wn_1_rad_s": 4.0, "pole_zeta_1": 0.5, "delay_s": 0.04})
    dt = 0.02
    rng = np.random.default_rng(2)
    u = signal.lfilter([0.2], [1, -0.8], rng.standard_normal(3000))
    t = np.arange(u.size) * dt
    y = simulate(m, u, dt) + 0.3 + 0.01 * (t - t[2400:].mean())
    v = validate(m, Record(u=u, y=y, dt=dt), 2400)
    assert v.nrmse < 1e-7 and v.theil_u < 1e-7 and v.ok
    assert v.bias == pytest.approx(0.3) and v.drift_per_s == pytest.approx(0.01)
    assert v.t_start_s == pytest.approx(48.0) and v.duration_s == pytest.approx(12.0)


def test_metrics_by_hand():
    """A model that predicts half the response: e = y/2 (after the fitted bias, which is 0 here)."""
    m = Model.from_values(1, 0, {"gain": 1.0, "pole_1_rad_s": 1000.0, "delay_s": 0.0})  # ~ a unit gain
    dt = 0.001
    t = np.arange(20_000) * dt
    u = np.sin(2 * np.pi * t)  # whole periods: zero mean, zero slope over each half
    v = validate(m, Record(u=0.5 * u, y=u, dt=dt), 10_000)
    # y_model ~ u/2, e ~ u/2: NRMSE = 0.5, Theil = rms(u/2) / (rms(u) + rms(u/2)) = 1/3
    assert v.nrmse == pytest.approx(0.5, abs=2e-3)
    assert v.theil_u == pytest.approx(1 / 3, abs=2e-3)
    assert v.fit_pct == pytest.approx(50.0, abs=0.2)
    assert validate(m, Record(u=u, y=u, dt=dt), 19_995) is None  # nothing left to check
