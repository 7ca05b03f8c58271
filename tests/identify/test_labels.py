"""Honest labels: J's verdict and the time-domain check side by side, the check on data that excite
the fitted band and judged against the noise floor the data show (issue 19, part 4)."""

from __future__ import annotations

import numpy as np
import pytest
from flight import fly, true_response
from scipy import signal

from tuner import identify
from tuner.identify.data import Record
from tuner.identify.model import Model
from tuner.identify.spectral import frequency_response, pooled, unexplained_rms, window_spectra
from tuner.identify.validate import NOISE_RATIO_LIMIT, THEIL_LIMIT, validate

NEW_USER = ([2.0 * 64.0], [1.0, 2 * 0.5 * 8.0, 64.0])  # K 2, wn 8, zeta 0.5
GUSTY = ([0.31 * 12.2**2], [1.0, 2 * 0.42 * 12.2, 12.2**2])  # K 0.31, wn 12.2, zeta 0.42


def _errors(log, res, n: int = 300) -> tuple[float, float]:
    w = np.geomspace(*res.band_rad_s, n)
    ratio = res.model.freqresp(w) / true_response(log, w)
    return float(np.max(np.abs(20 * np.log10(np.abs(ratio))))), float(np.max(np.abs(np.degrees(np.angle(ratio)))))


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_a_sweep_only_log_as_a_new_user_makes_it_is_not_poor():
    """A 100 Hz log that is one sweep to its end (no doublets): the last 20 % is the top of the sweep.
    Holding it out used to cut the band to ~13 rad/s; now it is fitted, and checked on the record."""
    log = fly(*NEW_USER, delay_s=0.033, log_hz=100.0, sweep_fraction=1.0, seed=0)
    res = identify(log.u, log.y, time=log.t, poles=2)
    mag, ph = _errors(log, res)
    assert mag <= 1.0 and ph <= 5.0, (mag, ph)
    assert res.band_rad_s[1] > 20.0  # the whole sweep's band
    assert res.quality == "good" and res.check == "good"
    v = res.validation
    assert v.source == "fit" and v.t_start_s == 0.0 and v.duration_s == pytest.approx(90.0, abs=0.02)
    assert any("holds the top of the sweep" in n for n in res.options["notes"]), res.options["notes"]
    assert "poor" not in res.verdict and "J = " in res.verdict
    assert "time-domain check on the fitted record" in res.verdict
    # held out by force, the tail narrows the band: the previous default's result, for contrast
    forced = identify(log.u, log.y, time=log.t, poles=2, holdout=0.2)
    assert forced.band_rad_s[1] < 0.7 * res.band_rad_s[1] and forced.validation.source == "holdout"


def test_a_gusty_log_with_doublets_is_noise_limited_not_poor():
    """Strong gusts: even the true model's Theil on the held-out doublets exceeds 0.3. The check says
    so (noise-limited), beside a good J; the model is within 1 dB / 5 deg of the truth."""
    log = fly(*GUSTY, delay_s=0.020, gust_frac=0.5, seed=2)
    res = identify(log.u, log.y, time=log.t, poles=2)
    mag, ph = _errors(log, res)
    assert mag <= 1.0 and ph <= 5.0, (mag, ph)
    v = res.validation
    assert v.source == "holdout" and v.t_start_s == pytest.approx(72.0, abs=0.05)  # the doublets
    assert v.theil_u > THEIL_LIMIT  # the old label: "poor"
    assert v.noise_ratio <= NOISE_RATIO_LIMIT and res.check == "noise-limited" and res.quality == "good"
    assert not any("does not predict" in w for w in res.warnings)
    # the truth itself, through the same check, scores about the same: the floor is the noise, not the fit
    true = Model.from_values(2, 0, {"gain": 0.31, "pole_wn_1_rad_s": 12.2, "pole_zeta_1": 0.42, "delay_s": 0.02})
    rec = Record(u=log.u, y=log.y, dt=log.dt)
    vt = validate(true, rec, round(0.8 * rec.n), u_trim=float(np.mean(log.u[:round(0.8 * rec.n)])),
                  noise_rms=v.noise_rms)
    assert vt.theil_u > THEIL_LIMIT and abs(vt.noise_ratio - v.noise_ratio) < 0.15


def test_the_check_still_fails_a_wrong_model_on_a_quiet_record():
    """Low noise: a model with twice the gain is far above the floor, and Theil says so too."""
    log = fly(*GUSTY, delay_s=0.020, gust_frac=0.02, noise_frac=0.01, seed=3)
    res = identify(log.u, log.y, time=log.t, poles=2)
    assert res.check == "good"
    vals = res.model.values()
    wrong = Model.from_values(2, 0, {**vals, "gain": 2 * vals["gain"]})
    rec = Record(u=log.u, y=log.y, dt=log.dt)
    k = round(0.8 * rec.n)
    vw = validate(wrong, rec, k, u_trim=float(np.mean(log.u[:k])), noise_rms=res.validation.noise_rms)
    assert vw.verdict == "poor" and vw.noise_ratio > 5
    # 30 % too much gain: Theil meets the guideline, but the error is several times the floor: "fair"
    off = Model.from_values(2, 0, {**vals, "gain": 1.3 * vals["gain"]})
    vo = validate(off, rec, k, u_trim=float(np.mean(log.u[:k])), noise_rms=res.validation.noise_rms)
    assert vo.theil_u <= THEIL_LIMIT and vo.noise_ratio > 2 * NOISE_RATIO_LIMIT and vo.verdict == "fair"


@pytest.mark.parametrize(("sigma", "rel"), [(0.2, 0.05), (0.05, 0.2)])
def test_noise_floor_against_known_white_noise(sigma, rel):
    """y = G u + white noise of known rms (G simulated by scipy here): the floor is that rms. The
    estimate carries a small upward bias from spectral leakage (about 7 % of rms(G u) here, in
    quadrature): hence the looser tolerance for the weaker noise."""
    rng = np.random.default_rng(5)
    dt, n = 0.01, 12000
    u = signal.lfilter([1.0], [1.0, -0.7], rng.standard_normal(n))
    t = np.arange(n) * dt
    _, y, _ = signal.lsim(([40.0], [1.0, 8.0, 40.0]), u, t, interp=False)
    rec = Record(u=u, y=y + sigma * rng.standard_normal(n), dt=dt)
    _, spectra = frequency_response(rec.detrended())
    assert unexplained_rms(spectra) == pytest.approx(sigma, rel=rel)


def test_pooled_spectra_are_the_segment_weighted_average():
    rng = np.random.default_rng(1)
    a = Record(u=rng.standard_normal(4000), y=rng.standard_normal(4000), dt=0.02)
    b = Record(u=rng.standard_normal(2000), y=rng.standard_normal(2000), dt=0.02)
    sa, sb = window_spectra(a, 10.0), window_spectra(b, 10.0)
    p = pooled([sa, sb])
    assert p.n_avg == sa.n_avg + sb.n_avg
    np.testing.assert_allclose(p.guy, (sa.n_avg * sa.guy + sb.n_avg * sb.guy) / (sa.n_avg + sb.n_avg))
    assert pooled([sa]) is sa


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_a_verification_record_and_several_records():
    """Two sweeps fitted together (spectra pooled) and a third flight as the verification record."""
    flights = [fly(*GUSTY, delay_s=0.02, seed=s, duration_s=60.0, sweep_fraction=1.0) for s in (11, 12)]
    ver = fly(*GUSTY, delay_s=0.02, seed=13, duration_s=60.0)
    res = identify([f.u for f in flights], [f.y for f in flights], rate_hz=50.0, poles=2,
                   verify={"input": ver.u, "output": ver.y})
    mag, ph = _errors(flights[0], res)
    assert mag <= 1.0 and ph <= 5.0, (mag, ph)
    assert res.options["records"] == 2 and res.n_samples == sum(f.u.size for f in flights)
    v = res.validation
    assert v.source == "verify" and v.duration_s == pytest.approx(60.0, abs=0.05) and res.check != "poor"
    one = identify(flights[0].u, flights[0].y, rate_hz=50.0, poles=2, holdout=0)
    # two records: more averages, so smaller bounds
    assert res.uncertainty["pole_wn_1_rad_s"].cr_bound < one.uncertainty["pole_wn_1_rad_s"].cr_bound
    assert one.validation is None and one.check == "none"


def test_bad_records_and_verify_name_the_field():
    from tuner.errors import InvalidDataError

    log = fly(*GUSTY, delay_s=0.02, seed=1, duration_s=30.0)
    with pytest.raises(InvalidDataError, match="record 2 of 2: input has 200 samples but output has 100") as e:
        identify([log.u, log.u[:200]], [log.y, log.y[:100]], rate_hz=50.0, poles=2)
    assert e.value.field == ("output",)
    with pytest.raises(InvalidDataError, match="verify: unknown keys") as e:
        identify(log.u, log.y, rate_hz=50.0, poles=2, verify={"input": log.u, "output": log.y, "dt": 1})
    with pytest.raises(InvalidDataError, match="verify: output is constant") as e:
        identify(log.u, log.y, rate_hz=50.0, poles=2, verify={"input": log.u, "output": np.zeros(log.u.size)})
    assert e.value.field == ("verify", "output")


def test_repr_is_a_few_lines():
    log = fly(*GUSTY, delay_s=0.02, seed=1, duration_s=40.0)
    res = identify(log.u, log.y, time=log.t, poles=2)
    text = repr(res)
    assert text.startswith("IdentifyResult: ") and len(text.splitlines()) <= 5 and len(text) < 600, text
    assert "pole_wn_1_rad_s" in text and f"J {res.cost:.3g}" in text and res.check in text
    assert str(res) == text


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_a_check_on_several_fitted_records_plots_and_round_trips():
    import json

    from tuner.identify import IdentifyResult
    from tuner.jsonio import jsonable

    log = fly(*GUSTY, delay_s=0.02, seed=21, duration_s=100.0, sweep_fraction=1.0)
    k = 3000  # a log split at 60 s: the second piece holds the top of the sweep, so nothing is held out
    res = identify([log.u[:k], log.u[k:]], [log.y[:k], log.y[k:]], rate_hz=50.0, poles=2)
    v = res.validation
    assert v.source == "fit" and v.duration_s == pytest.approx(100.0, abs=0.1)
    assert np.isnan(v.t).sum() == 1 and np.all(np.diff(v.t[np.isfinite(v.t)]) > 0)  # end to end, one break
    text = json.dumps(jsonable(res.to_dict()), allow_nan=False)
    back = IdentifyResult.from_dict(json.loads(text))
    assert back.check == res.check and np.isnan(back.validation.measured).sum() == 1
    assert len(back.plot().axes) == 4
