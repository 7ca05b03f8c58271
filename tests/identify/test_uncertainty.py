"""Cramér–Rao bounds against Monte Carlo: refit many noisy realisations, compare the spread."""

from __future__ import annotations

import numpy as np
import pytest

from tuner.identify.fit import Problem, fit_model
from tuner.identify.model import Model, Structure
from tuner.identify.uncertainty import cramer_rao

W = np.geomspace(0.5, 40.0, 25)
TRUE = {"gain": 0.2655, "pole_wn_1_rad_s": 14.85, "pole_zeta_1": 0.48, "delay_s": 0.04}


def _noisy(rng: np.random.Generator, sigma_db: float, sigma_deg: float) -> np.ndarray:
    """The true response with independent errors in dB and degrees (what the cost's residuals assume)."""
    m = Model.from_values(2, 0, TRUE)
    mag, ph = m.bode(W)
    mag = mag + sigma_db * rng.standard_normal(W.size)
    ph = ph + sigma_deg * rng.standard_normal(W.size)
    return 10 ** (mag / 20) * np.exp(1j * np.radians(ph))


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_bounds_match_the_monte_carlo_spread():
    rng = np.random.default_rng(7)
    coh = np.full(W.size, 0.9)
    vals, bounds = [], []
    for _ in range(120):
        h = _noisy(rng, 0.5, 0.5 / np.sqrt(0.01745))  # 0.5 dB and the equally weighted phase error
        out = fit_model(W, h, coh, poles=2, zeros=0, delay="auto", delay_step=None, band=(W[0], W[-1]),
                        tau_max=1.0, n_starts=4, seed=0)
        unc = cramer_rao(out.problem, out.model.theta)
        vals.append([unc[k].value for k in TRUE])
        bounds.append([unc[k].cr_bound for k in TRUE])
    vals, bounds = np.array(vals), np.array(bounds)
    spread = vals.std(axis=0, ddof=1)
    ratio = spread / bounds.mean(axis=0)
    # 120 samples: the spread itself is known to about +-13 % (1 sigma); allow 30 %
    assert np.all((ratio > 0.7) & (ratio < 1.3)), dict(zip(TRUE, ratio))
    # and the mean is unbiased within its own standard error
    assert np.all(np.abs(vals.mean(axis=0) - list(TRUE.values())) < 4 * spread / np.sqrt(len(vals)))


def test_insensitivity_is_the_one_parameter_bound_and_never_larger():
    rng = np.random.default_rng(1)
    h = _noisy(rng, 0.5, 3.0)
    out = fit_model(W, h, np.full(W.size, 0.9), poles=2, zeros=0, delay="auto", delay_step=None,
                    band=(W[0], W[-1]), tau_max=1.0)
    unc = cramer_rao(out.problem, out.model.theta)
    A = out.problem.jacobian(out.model.theta)
    r = out.problem.residuals(out.model.theta)
    s2 = r @ r / (A.shape[0] - A.shape[1])
    for i, (name, u) in enumerate(unc.items()):
        assert u.insensitivity_pct <= u.cr_bound_pct + 1e-12
        if name != "delay_s":  # log-parameters: % = 100 x the bound of the log
            assert u.insensitivity_pct == pytest.approx(100 * np.sqrt(s2 / (A[:, i] @ A[:, i])))


def test_a_parameter_the_data_cannot_see_gets_a_huge_bound():
    """A third pole far above the band (1000 rad/s, band up to 40) is not determined."""
    m = Model.from_values(2, 0, TRUE)
    h = m.freqresp(W) * (1 + 0.01 * np.random.default_rng(0).standard_normal(W.size))
    st = Structure(3, 0, True)
    theta = np.log([0.2655, 14.85, 0.48, 1000.0])
    p = Problem(w=W, mag_db=20 * np.log10(np.abs(h)), phase_deg=np.degrees(np.angle(h)),
                coherence=np.full(W.size, 0.9), structure=st)
    unc = cramer_rao(p, np.concatenate([theta, [0.04]]))
    assert unc["pole_2_rad_s"].cr_bound_pct > 100.0
    assert unc["gain"].cr_bound_pct < 20.0
