"""The loop on the measured frequency response (tuner.analysis.measured): figures against closed forms and the
verifier, the error ranges, and the warning when the model is not what was measured."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from tuner import analyze, controller_from_coeffs, make_plant
from tuner.analysis.measured import loop_figures, measured_comparison
from tuner.identify.spectral import FrequencyResponse

DT = 0.01


def _ident(h_of_w, w, *, coherence=0.99, band=None, duration=60.0, windows=(30.0, 10.0)):
    """An identification-like record: the measured response ``h_of_w`` on ``w`` (what measured_comparison reads)."""
    fr = FrequencyResponse(w=w, h=h_of_w(w), coherence=np.full(w.size, coherence), windows_s=windows)
    band = band or (float(w[0]), float(w[-1]))
    return SimpleNamespace(frequency_response=fr, band_rad_s=band, options={"coherence_min": 0.6},
                           fit_duration_s=duration, rate_hz=1 / DT)


def _zoh_response(plant, w):
    """The plant's exact ZOH response at DT on the unit circle, from scipy (independent of the loop's code)."""
    from scipy import signal

    num, den = plant
    sysd = signal.cont2discrete((num, den), DT, method="zoh")
    _, h = signal.freqz(np.ravel(sysd[0]), sysd[1], worN=w * DT)
    return h


def test_loop_figures_closed_form():
    w = np.geomspace(0.05, 20, 2000)
    L = 2.0 / (1j * w * (1j * w + 1) * (0.1j * w + 1))  # phase crossover where w^2 = 1/0.1 -> w = sqrt(10)
    f = loop_figures(w, L, np.ones(w.size, bool))
    wg = math.sqrt(10.0)
    gm = -20 * math.log10(2.0 / (wg * abs(1j * wg + 1) * abs(0.1j * wg + 1)))
    assert f.gain_margin_db == pytest.approx(gm, abs=0.02)
    wc = f.crossover_rad_s
    assert abs(2.0 / (wc * abs(1j * wc + 1) * abs(0.1j * wc + 1))) == pytest.approx(1.0, abs=2e-3)
    pm = 180 - 90 - math.degrees(math.atan(wc)) - math.degrees(math.atan(0.1 * wc))
    assert f.phase_margin_deg == pytest.approx(pm, abs=0.05)
    assert f.ms == pytest.approx(float(np.max(1 / np.abs(1 + L))), rel=1e-12)


def test_exact_measurement_agrees_with_the_verifier():
    plant = ([4.0], [1.0, 3.0, 2.0])
    ctrl = controller_from_coeffs([0.505, -0.5], [1.0, -1.0], dt=DT)  # a PI at DT (Kp 0.5, Ki 0.5)
    a = analyze(make_plant(*plant), ctrl)
    w = np.geomspace(0.05, 0.9 * math.pi / DT, 600)
    cmp = measured_comparison(_ident(lambda w: _zoh_response(plant, w), w), a)
    assert cmp.warnings == ()
    assert cmp.measured.phase_margin_deg == pytest.approx(a.metrics.phase_margin_deg, abs=0.3)
    assert cmp.model.phase_margin_deg == pytest.approx(a.metrics.phase_margin_deg, abs=0.3)
    lo, hi = cmp.measured.phase_margin_range
    assert lo <= cmp.measured.phase_margin_deg <= hi and hi - lo < 10.0  # coherence 0.99 from two averages: eps 0.05
    assert cmp.measured.ms == pytest.approx(a.metrics.ms, rel=0.02)


def test_a_model_that_is_not_the_airframe_is_flagged():
    """The airframe has 30 more samples of delay than the model: the phase margin measured is lower by w_c 30 DT
    (16 deg, beyond the data's error of about 4)."""
    plant = ([4.0], [1.0, 3.0, 2.0])
    ctrl = controller_from_coeffs([0.505, -0.5], [1.0, -1.0], dt=DT)
    a = analyze(make_plant(*plant), ctrl)
    w = np.geomspace(0.05, 0.9 * math.pi / DT, 600)
    cmp = measured_comparison(_ident(lambda w: _zoh_response(plant, w) * np.exp(-30j * w * DT), w), a)
    drop = math.degrees(a.metrics.crossover_rad_s * 30 * DT)
    assert cmp.measured.phase_margin_deg == pytest.approx(a.metrics.phase_margin_deg - drop, abs=0.5)
    assert any(msg.startswith("phase margin") for msg in cmp.warnings)


def test_a_crossover_outside_the_coherent_band_is_not_measured():
    plant = ([4.0], [1.0, 3.0, 2.0])
    ctrl = controller_from_coeffs([0.505, -0.5], [1.0, -1.0], dt=DT)
    a = analyze(make_plant(*plant), ctrl)
    w = np.geomspace(0.05, 0.9 * math.pi / DT, 600)
    band = (0.05, 0.3 * a.metrics.crossover_rad_s)
    cmp = measured_comparison(_ident(lambda w: _zoh_response(plant, w), w, band=band), a)
    assert math.isnan(cmp.measured.phase_margin_deg)
    assert any("not measured" in n for n in cmp.notes)
    assert cmp.warnings == ()
