"""The model family and the fit: factored sections against scipy's responses, CIFER's cost by hand,
exact Jacobians, exact recovery from noise-free data, whole-sample delays chosen by brute force."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import signal

from tuner.identify.fit import W_P, Problem, coherence_weight, cost_terms, fit_model
from tuner.identify.model import Model, Structure

W = np.geomspace(0.3, 30.0, 25)


def _model(poles: int, zeros: int, values: dict[str, float], delay: float = 0.0) -> Model:
    return Model.from_values(poles, zeros, {**values, "delay_s": delay})


CASES = {
    "roll": (2, 0, {"gain": 0.2655, "pole_wn_1_rad_s": 14.8528, "pole_zeta_1": 0.4778}, 0.04),
    "yaw": (1, 0, {"gain": 0.2843, "pole_1_rad_s": 18.611}, 0.02),
    "lead-lag": (3, 1, {"gain": -2.0, "pole_wn_1_rad_s": 6.0, "pole_zeta_1": 0.3, "pole_2_rad_s": 1.5,
                        "zero_1_rad_s": 4.0}, 0.06),
    "two-pairs": (4, 2, {"gain": 1.5, "pole_wn_1_rad_s": 2.0, "pole_zeta_1": 0.7, "pole_wn_2_rad_s": 12.0,
                         "pole_zeta_2": 0.15, "zero_wn_1_rad_s": 5.0, "zero_zeta_1": 0.5}, 0.0),
}


@pytest.mark.parametrize("name", CASES)
def test_sections_match_scipy_freqs_of_the_expanded_polynomials(name):
    poles, zeros, values, delay = CASES[name]
    m = _model(poles, zeros, values, delay)
    num, den = m.tf()
    _, h = signal.freqs(num, den, worN=W)
    assert_allclose(m.freqresp(W), h * np.exp(-1j * W * delay), rtol=1e-10)
    assert_allclose(np.polyval(num, 0) / np.polyval(den, 0), values["gain"], rtol=1e-12)  # DC gain = K
    mag, ph = m.bode(W)
    assert_allclose(mag, 20 * np.log10(np.abs(h)), atol=1e-9)
    assert np.all(np.abs(np.diff(ph)) < 90.0)  # the model's phase is continuous on the grid


@pytest.mark.parametrize("name", CASES)
def test_state_space_realises_the_rational_part(name):
    poles, zeros, values, _ = CASES[name]
    m = _model(poles, zeros, values)
    A, B, C, D = m.state_space()
    h = np.array([(C @ np.linalg.solve(1j * w * np.eye(A.shape[0]) - A, B) + D)[0, 0] for w in W])
    assert_allclose(h, m.freqresp(W), rtol=1e-9)


def test_cost_by_hand():
    # 1 dB everywhere at coherence 1: J = 20 W(1) = 20 (1.58 (1 - 1/e))^2
    w1 = (1.58 * (1 - math.exp(-1))) ** 2
    assert_allclose(coherence_weight(np.array([1.0])), [w1])
    assert_allclose(np.mean(cost_terms(np.ones(10), np.zeros(10), np.ones(10))), 20 * w1)
    # 7.57 deg weighs like 1 dB (W_p = 0.01745); wrapping: 352.43 deg is -7.57 deg
    assert_allclose(W_P * 7.57 ** 2, 1.0, rtol=1e-3)
    assert_allclose(cost_terms(np.zeros(1), np.array([352.43]), np.ones(1)), cost_terms(np.zeros(1), np.array([7.57]),
                                                                                           np.ones(1)))
    # coherence 0.6: weight (1.58 (1 - e^-0.6))^2
    assert_allclose(coherence_weight(np.array([0.6])), [(1.58 * (1 - math.exp(-0.6))) ** 2])


def _problem(m: Model, *, noise: float = 0.0, seed: int = 0, free_delay: bool = True) -> Problem:
    h = m.freqresp(W)
    if noise:
        rng = np.random.default_rng(seed)
        h = h * (1 + noise * (rng.standard_normal(W.size) + 1j * rng.standard_normal(W.size)))
    st = Structure(m.structure.poles, m.structure.zeros, free_delay)
    return Problem(w=W, mag_db=20 * np.log10(np.abs(h)), phase_deg=np.degrees(np.angle(h)),
                   coherence=np.full(W.size, 0.95), structure=st, sign=m.sign)


@pytest.mark.parametrize("name", CASES)
def test_jacobian_is_exact(name):
    poles, zeros, values, delay = CASES[name]
    m = _model(poles, zeros, values, delay)
    p = _problem(m, noise=0.05)
    theta = np.concatenate([m.theta, [delay]]) * (1 + 0.01)
    J = p.jacobian(theta)
    eps = 1e-6
    num = np.column_stack([(p.residuals(theta + eps * e) - p.residuals(theta - eps * e)) / (2 * eps)
                           for e in np.eye(theta.size)])
    assert_allclose(J, num, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("name", CASES)
def test_fit_recovers_noise_free_data_exactly(name):
    poles, zeros, values, delay = CASES[name]
    m = _model(poles, zeros, values, delay)
    h = m.freqresp(W)
    out = fit_model(W, h, np.ones(W.size), poles=poles, zeros=zeros, delay="auto", delay_step=None,
                    band=(W[0], W[-1]), tau_max=1.0, n_starts=30, seed=0)
    assert out.cost < 1e-10
    got = out.model.values()
    for k, v in values.items():
        assert got[k] == pytest.approx(v, rel=1e-5), k
    assert got["delay_s"] == pytest.approx(delay, abs=1e-7)


def test_fixed_and_absent_delays_are_respected():
    m = _model(*CASES["roll"][:3], delay=0.04)
    h = m.freqresp(W)
    fixed = fit_model(W, h, np.ones(W.size), poles=2, zeros=0, delay=0.04, delay_step=None, band=(W[0], W[-1]),
                      tau_max=1.0)
    assert fixed.cost < 1e-10 and fixed.model.delay_s == 0.04 and not fixed.model.structure.free_delay
    none = fit_model(W, h, np.ones(W.size), poles=2, zeros=0, delay=None, delay_step=None, band=(W[0], W[-1]),
                     tau_max=1.0)
    assert none.model.delay_s == 0.0 and none.cost > 1.0  # the phase lag of the delay is not explained


def test_delay_step_picks_the_best_whole_multiple():
    """True delay 0.05 s, step 0.04 s: the chosen multiple is the one a brute-force scan prefers."""
    m = _model(*CASES["roll"][:3], delay=0.05)
    h = m.freqresp(W)
    coh = np.ones(W.size)
    out = fit_model(W, h, coh, poles=2, zeros=0, delay="auto", delay_step=0.04, band=(W[0], W[-1]), tau_max=1.0)
    k = out.model.delay_s / 0.04
    assert abs(k - round(k)) < 1e-12
    scan = {d: fit_model(W, h, coh, poles=2, zeros=0, delay=d, delay_step=None, band=(W[0], W[-1]),
                         tau_max=1.0).cost for d in (0.0, 0.04, 0.08, 0.12)}
    assert out.model.delay_s == min(scan, key=scan.get)
    assert out.cost == pytest.approx(min(scan.values()), rel=1e-6)
    exact = fit_model(W, _model(*CASES["roll"][:3], delay=0.08).freqresp(W), coh, poles=2, zeros=0, delay="auto",
                      delay_step=0.04, band=(W[0], W[-1]), tau_max=1.0)
    assert exact.model.delay_s == pytest.approx(0.08) and exact.cost < 1e-10


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_fit_is_deterministic():
    m = _model(*CASES["lead-lag"][:3], delay=0.06)
    p = _problem(m, noise=0.05)
    h = 10 ** (p.mag_db / 20) * np.exp(1j * np.radians(p.phase_deg))
    a, b = (fit_model(W, h, p.coherence, poles=3, zeros=1, delay="auto", delay_step=None, band=(W[0], W[-1]),
                      tau_max=1.0, seed=4) for _ in range(2))
    assert_allclose(a.model.theta, b.model.theta, rtol=0, atol=0)
