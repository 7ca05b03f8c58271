"""Unusable data and options: every class gives an InvalidDataError naming the problem and the field."""

from __future__ import annotations

import numpy as np
import pytest
from flight import AXES, fly
from numpy.testing import assert_allclose

from tuner import identify
from tuner.errors import InvalidDataError, TunerError
from tuner.identify.data import MIN_SAMPLES, lowest_frequency_rad_s, make_record


@pytest.fixture(scope="module")
def log():
    return fly(*AXES["pitch"], seed=5, duration_s=60.0)


def _raises(field: str, match: str, **kw):
    with pytest.raises(InvalidDataError, match=match) as e:
        identify(**kw)
    assert e.value.field == (field,), e.value.field
    assert isinstance(e.value, TunerError) and isinstance(e.value, ValueError)
    return e.value


def _kw(log, **over):
    kw = {"input": log.u, "output": log.y, "time": log.t, "poles": 2}
    kw.update(over)
    return kw


def test_mismatched_lengths(log):
    _raises("output", r"input has 3001 samples but output has 3000", **_kw(log, output=log.y[:-1]))


@pytest.mark.parametrize("field, bad", [("input", np.nan), ("output", np.inf), ("output", -np.inf)])
def test_non_finite_samples_are_named_with_their_index(log, field, bad):
    arr = (log.u if field == "input" else log.y).copy()
    arr[[17, 400]] = bad
    kw = _kw(log, **{field: arr})
    _raises(field, rf"{field}\[17\] is {bad!r} \(2 non-finite samples in all\)", **kw)


def test_constant_input_and_constant_output(log):
    _raises("input", "input is constant .*nothing excites the plant", **_kw(log, input=np.full(log.u.size, 0.3)))
    _raises("output", "output is constant .*does not respond", **_kw(log, output=np.zeros(log.y.size)))


def test_too_few_samples(log):
    n = MIN_SAMPLES - 1
    _raises("input", rf"{n} samples given; identification needs at least {MIN_SAMPLES}",
            **_kw(log, input=log.u[:n], output=log.y[:n], time=log.t[:n]))


def test_too_few_cycles_for_the_requested_band(log):
    # 60 s, 20 % held out: 48 s fitted, windows up to 24 s, two periods -> 8*pi/48 = 0.524 rad/s
    e = _raises("band", r"band starts at 0.1 rad/s, but the fitted part of the record \(48.02 s\) has too few cycles "
                        r"there: it resolves down to 0.523 rad/s", **_kw(log, band=(0.1, 10.0)))
    assert "record at least 314 s" in str(e)  # 8*pi/0.1 / 0.8


def test_band_above_nyquist(log):
    _raises("band", r"band ends at 200 rad/s, above 90 % of the Nyquist frequency \(141.4 rad/s at 50 Hz\)",
            **_kw(log, band=(1.0, 200.0)))


@pytest.mark.parametrize("band", [(10.0, 1.0), (0.0, 5.0), (1.0, np.inf), (1.0,), "1-10"])
def test_malformed_band(log, band):
    _raises("band", "band must", **_kw(log, band=band))


def test_time_column_not_increasing_not_uniform_or_short(log):
    t = log.t.copy()
    t[50] = t[49]
    _raises("time", r"time is not strictly increasing: time\[50\] = .* after time\[49\]", **_kw(log, time=t))
    t = log.t.copy()
    t[1000:] += 0.005  # one interval 25 % long: a dropped-and-shifted sample
    _raises("time", r"time is not uniformly sampled: the interval after time\[999\] is 0.025 s.*resample",
            **_kw(log, time=t))
    _raises("time", "time has 3000 samples but input and output have 3001", **_kw(log, time=log.t[:-1]))


def test_small_time_jitter_is_accepted_and_gives_the_mean_rate(log):
    t = log.t + np.random.default_rng(0).uniform(-1e-4, 1e-4, log.t.size)  # 0.5 % jitter
    rec = make_record(log.u, log.y, time=t)
    assert_allclose(rec.dt, (t[-1] - t[0]) / (t.size - 1))


def test_time_xor_rate(log):
    _raises("time", "give exactly one of time", **_kw(log, rate_hz=50.0))
    _raises("rate_hz", "give exactly one of time", **_kw(log, time=None))
    for bad in (0.0, -5.0, np.nan, "fast"):
        _raises("rate_hz", "rate_hz must be", **_kw(log, time=None, rate_hz=bad))


def test_no_coherent_band_when_the_output_is_unrelated(log):
    noise = np.random.default_rng(3).standard_normal(log.u.size)
    _raises("output", "no coherent band", **_kw(log, output=noise))


def test_no_coherent_band_inside_a_requested_band(log):
    # beyond the sweep's top (25 rad/s) only sensor noise and remnant remain
    _raises("band", r"no coherent band: only \d+ of 25 fit frequencies in 60-130 rad/s have coherence >= 0.6",
            **_kw(log, band=(60.0, 130.0)))


@pytest.mark.parametrize("over, field, match", [
    ({"poles": 0}, "poles", "poles must be an integer from 1 to 8, got 0"),
    ({"poles": 9}, "poles", "poles must be an integer from 1 to 8"),
    ({"poles": 2.0}, "poles", "poles must be an integer"),
    ({"poles": True}, "poles", "poles must be an integer"),
    ({"zeros": 3}, "zeros", "zeros must be an integer from 0 to 2, got 3"),
    ({"delay": "soon"}, "delay", "delay must be 'auto', a number of seconds >= 0, or None"),
    ({"delay": -0.1}, "delay", r"delay must be a number in \[0, 1e\+06\]"),
    ({"delay": 0.05, "delay_step": 0.04}, "delay", "delay 0.05 s is not a whole number of delay_step=0.04 s"),
    ({"delay_step": 0.0}, "delay_step", "delay_step must be a number in"),
    ({"holdout": 0.9}, "holdout", r"holdout must be a number in \[0, 0.5\]"),
    ({"coherence_min": 1.0}, "coherence_min", "coherence_min must be a number in"),
    ({"n_points": 3}, "n_points", "n_points must be an integer from 8 to 200"),
    ({"seed": -1}, "seed", "seed must be an integer"),
])
def test_bad_options(log, over, field, match):
    _raises(field, match, **_kw(log, **over))


def test_lowest_frequency_rule():
    assert_allclose(lowest_frequency_rad_s(80.0), 2 * 2 * np.pi / 40.0)  # two periods in half the record


def test_record_split_and_detrend():
    n = 1000
    t = np.arange(n) * 0.01
    u = np.sin(3 * t) + 2.0 + 0.5 * t
    y = np.cos(2 * t) - 1.0 - 0.1 * t
    rec = make_record(u, y, time=t)
    assert rec.dt == pytest.approx(0.01) and rec.n == n
    fit, rest = rec.split(0.25)
    assert (fit.n, rest.n) == (750, 250) and rest.t0 == pytest.approx(7.5)
    d = rec.detrended()
    for s in (d.u, d.y):  # no mean and no slope left
        assert abs(s.mean()) < 1e-12 and abs(np.polyfit(t, s, 1)[0]) < 1e-12
    assert rec.split(0.0) == (rec, None)
