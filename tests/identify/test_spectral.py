"""Spectral estimation: the window spectra are scipy's Welch/CSD numbers, the composite recovers a
known response, the composite weights are the random-error weights, the band rules hold."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import signal
from scipy.fft import next_fast_len

from tuner.errors import InvalidDataError
from tuner.identify.data import Record
from tuner.identify.spectral import (
    FrequencyResponse,
    WindowSpectra,
    coherent_band,
    composite,
    frequency_response,
    window_lengths,
    window_spectra,
)


@pytest.mark.parametrize("n, nper", [(5000, 900), (5001, 333), (4096, 2048), (700, 700)])
def test_window_spectra_are_scipy_welch_and_csd(n, nper):
    rng = np.random.default_rng(n)
    u = rng.standard_normal(n).cumsum()
    y = np.convolve(u, [0.5, 0.3, 0.1], "same") + rng.standard_normal(n)
    sp = window_spectra(Record(u=u, y=y, dt=0.02), nper * 0.02)
    kw = {"fs": 50.0, "window": "hann", "nperseg": nper, "noverlap": int(0.8 * nper),
          "nfft": next_fast_len(4 * nper), "detrend": "linear"}
    f, guu = signal.welch(u, **kw)
    _, gyy = signal.welch(y, **kw)
    _, guy = signal.csd(u, y, **kw)
    assert_allclose(sp.w, 2 * np.pi * f)
    for mine, ref in ((sp.guu, guu), (sp.gyy, gyy), (sp.guy, guy)):
        assert_allclose(mine, ref, rtol=0, atol=1e-12 * np.max(np.abs(ref)))


def test_composite_recovers_a_known_discrete_response():
    """White noise through a known digital filter, no noise: H equals freqz, coherence 1."""
    rng = np.random.default_rng(0)
    dt = 0.01
    u = rng.standard_normal(60_000)
    b, a = signal.butter(2, 0.2)  # corner at 0.2 * Nyquist = 31.4 rad/s
    y = signal.lfilter(b, a, u)
    fr, _ = frequency_response(Record(u=u, y=y, dt=dt))
    _, h = signal.freqz(b, a, worN=fr.w * dt)
    band = fr.w < 100.0  # where the filter still passes something
    assert np.all(fr.coherence[band] > 0.999)
    assert_allclose(20 * np.log10(np.abs(fr.h[band] / h[band])), 0.0, atol=0.05)
    assert_allclose(np.degrees(np.angle(fr.h[band] / h[band])), 0.0, atol=0.3)


def _window(window_s: float, n_avg: float, guy: complex, guu: float, gyy: float) -> WindowSpectra:
    w = np.array([0.0, 100.0])
    return WindowSpectra(window_s=window_s, n_avg=n_avg, w=w, guu=np.full(2, guu), gyy=np.full(2, gyy),
                         guy=np.full(2, guy))


def test_composite_weights_are_the_inverse_random_error():
    """Two windows at one frequency, coherence 0.9 and 0.5: weights 2 n 0.9/0.1 and 2 n 0.5/0.5."""
    a = _window(20.0, 3.0, guy=0.9 + 0j, guu=1.0, gyy=0.9)  # |Guy|^2/(Guu Gyy) = 0.9
    b = _window(10.0, 6.0, guy=0.5j, guu=1.0, gyy=0.5)  # coherence 0.5
    wa, wb = 2 * 3.0 * 0.9 / 0.1, 2 * 6.0 * 0.5 / 0.5
    fr = composite([a, b], np.array([5.0]))
    guy = (wa * 0.9 + wb * 0.5j) / (wa + wb)
    guu = 1.0
    gyy = (wa * 0.9 + wb * 0.5) / (wa + wb)
    assert_allclose(fr.h, [guy / guu])
    assert_allclose(fr.coherence, [abs(guy) ** 2 / (guu * gyy)])


def test_a_window_counts_only_above_two_of_its_periods():
    a = _window(20.0, 3.0, guy=0.9 + 0j, guu=1.0, gyy=0.9)
    b = _window(4.0, 6.0, guy=0.5j, guu=1.0, gyy=0.5)
    w = np.array([2.0, 4 * np.pi / 4.0 + 1e-9])  # below and just above 2 periods of the 4 s window
    fr = composite([a, b], w)
    assert_allclose(fr.h[0], 0.9)  # only the long window
    assert abs(fr.h[1] - 0.9) > 0.01  # both


def test_window_lengths_follow_the_record():
    ws = window_lengths(80.0, 0.02, w_max_rad_s=100.0)
    assert ws[0] == pytest.approx(40.0) and ws[-1] == pytest.approx(5.0) and len(ws) == 5
    assert_allclose(np.diff(np.log(ws)), np.log(5.0 / 40.0) / 4)  # log-spaced
    assert window_lengths(80.0, 0.02, w_max_rad_s=10.0)[-1] == pytest.approx(20 * 2 * np.pi / 10.0)  # 20 periods
    assert window_lengths(80.0, 0.02, w_max_rad_s=2.0) == (40.0,)
    assert window_lengths(3.0, 0.01, w_max_rad_s=100.0) == (1.5,)  # too short for several


def _fr(coh: np.ndarray) -> FrequencyResponse:
    w = np.geomspace(0.1, 100.0, coh.size)
    return FrequencyResponse(w=w, h=np.ones(coh.size, dtype=complex), coherence=coh)


def test_coherent_band_takes_the_widest_run_and_bridges_narrow_dips():
    w = np.geomspace(0.1, 100.0, 121)  # 40 points per decade
    coh = np.where((w >= 0.5) & (w <= 20.0), 0.9, 0.2)
    coh[(w > 3.0) & (w < 3.3)] = 0.4  # a dip of < 0.1 decade: bridged
    coh[(w >= 40.0) & (w <= 60.0)] = 0.95  # a narrower run, separated by a wide gap
    lo, hi = coherent_band(FrequencyResponse(w=w, h=np.ones(w.size, complex), coherence=coh))
    assert lo == pytest.approx(w[w >= 0.5][0]) and hi == pytest.approx(w[w <= 20.0][-1])


def test_coherent_band_refuses_a_chance_stretch():
    w = np.geomspace(0.1, 100.0, 121)
    coh = np.where((w >= 1.0) & (w <= 1.5), 0.7, 0.1)  # 0.18 decades
    with pytest.raises(InvalidDataError, match=r"only over .* \(0.1[0-9] decades; at least 0.25") as e:
        coherent_band(FrequencyResponse(w=w, h=np.ones(w.size, complex), coherence=coh))
    assert e.value.field == ("output",)
    with pytest.raises(InvalidDataError, match="no coherent band"):
        coherent_band(_fr(np.full(50, 0.3)))
