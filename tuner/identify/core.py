"""``identify(input, output, ...)``: from a logged record to a fitted, checked transfer function."""

from __future__ import annotations

import logging
import math
import numbers
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..errors import InvalidDataError
from ..tolerances import LIMIT_RTOL
from .data import MIN_SAMPLES, Record, lowest_frequency_rad_s, make_record
from .result import J_ACCEPTABLE, J_GOOD, J_POINT_MAX, FitPoints, IdentifyResult
from .spectral import composite, frequency_response

__all__ = ["MAX_POLES", "DelaySpec", "identify", "zoh_factor"]

log = logging.getLogger(__name__)

MAX_POLES = 8
DelaySpec = str | float | None


def _int(v: Any, name: str, lo: int, hi: int) -> int:
    if isinstance(v, bool) or not isinstance(v, numbers.Integral) or not lo <= int(v) <= hi:
        raise InvalidDataError(f"{name} must be an integer from {lo} to {hi}, got {v!r}", field=name)
    return int(v)


def _float(v: Any, name: str, lo: float, hi: float, *, lo_open: bool = False, hi_open: bool = False) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError) as e:
        raise InvalidDataError(f"{name} must be a number, got {v!r}", field=name) from e
    bad = not math.isfinite(x) or x < lo or x > hi or (lo_open and x == lo) or (hi_open and x == hi)
    if isinstance(v, bool) or bad:
        lo_s, hi_s = ("(" if lo_open else "["), (")" if hi_open else "]")
        raise InvalidDataError(f"{name} must be a number in {lo_s}{lo:g}, {hi:g}{hi_s}, got {v!r}", field=name)
    return x


def _delay(delay: DelaySpec, step: float | None) -> DelaySpec:
    if delay is None or delay == "auto":
        return delay
    if isinstance(delay, str):
        raise InvalidDataError(f"delay must be 'auto', a number of seconds >= 0, or None, got {delay!r}",
                               field="delay")
    tau = _float(delay, "delay", 0.0, 1e6)
    if step is not None and tau:
        k = tau / step
        if abs(k - round(k)) > 1e-6 * max(1.0, k):
            raise InvalidDataError(f"delay {tau} s is not a whole number of delay_step={step} s ({k:.4g} steps)",
                                   field="delay")
        tau = round(k) * step
    return tau


def _band(band: Sequence[float] | None) -> tuple[float, float] | None:
    if band is None:
        return None
    try:
        lo, hi = (float(x) for x in band)
    except (TypeError, ValueError) as e:
        raise InvalidDataError(f"band must be two frequencies [w_min, w_max] in rad/s, got {band!r}",
                               field="band") from e
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
        raise InvalidDataError(f"band must satisfy 0 < w_min < w_max (rad/s), got {band!r}", field="band")
    return lo, hi


def identify(
    input: Sequence[float],
    output: Sequence[float],
    *,
    time: Sequence[float] | None = None,
    rate_hz: float | None = None,
    poles: int,
    zeros: int = 0,
    delay: DelaySpec = "auto",
    delay_step: float | None = None,
    band: Sequence[float] | None = None,
    holdout: float | str = "auto",
    verify: Mapping[str, Any] | None = None,
    coherence_min: float = 0.6,
    n_points: int = 25,
    windows_s: Sequence[float] | None = None,
    n_starts: int = 20,
    seed: int = 0,
    reference: Sequence[float] | None = None,
    controller: Any = None,
    closed_loop_signs: Sequence[str] = (),
    hold: str | None = None,
    time_unit: str = "auto",
    reference_biased: str = "",
    firmware: str | None = None,
) -> IdentifyResult:
    """Identify a continuous transfer function (with a delay) from logged input/output data.

    The record is validated and split: the first ``1 - holdout`` is detrended and turned into a
    frequency response with coherence (several Welch windows composited, as CIFER's COMPOSITE);
    the model is fitted over the coherent band by minimising CIFER's cost ``J``; the Cramér–Rao
    bounds of its parameters are computed at the optimum; and the model is simulated on the
    held-out rest of the record (Theil's inequality coefficient, NRMSE).

    Parameters
    ----------
    input, output : sequence of float, or a list of them
        The logged plant input (e.g. the stick or attitude command) and output (e.g. the
        angle), equal lengths, finite, at least 128 samples. Several records (lists of
        sequences: repeated sweeps, or the segments of a log with gaps) are fitted together:
        their auto- and cross-spectra are averaged over all their windows (as CIFER concatenates
        sweeps); they share the sample rate.
    time : sequence of float (or a list of them, one per record), optional
        Sample times (in ``time_unit``): strictly increasing and uniform within 1 %. Give this or
        ``rate_hz``.
    rate_hz : float, optional
        Sample rate of a uniformly sampled record, Hz. Give this or ``time``.
    poles : int
        Number of poles of the model, 1 to 8 (as quadratic sections, plus one real pole if odd).
    zeros : int
        Number of zeros, 0 to ``poles``. Poles and zeros are stable / minimum phase.
    delay : "auto", float or None
        ``"auto"`` estimates an equivalent time delay (default); a number fixes it (seconds);
        ``None`` or 0 fits none.
    delay_step : float, optional
        Restrict the delay to whole multiples of this (s): the sample time of the loop the model
        is for, where the tuner accepts only whole-sample delays. With ``delay="auto"`` the best
        multiple is chosen; a fixed ``delay`` must be a multiple.
    band : (float, float), optional
        Fit band ``[w_min, w_max]`` in rad/s. Default: the widest stretch where the coherence is
        at least ``coherence_min``. ``w_min`` may not be below what the record resolves (two
        periods in a window of half the fitted part), ``w_max`` not above 90 % of Nyquist.
    holdout : "auto" or float
        What the time-domain check runs on. A fraction (up to 0.5) holds out the end of the (last)
        record; 0 = no check. ``"auto"`` (default): with ``verify``, nothing is held out; else the
        last 20 % is held out only when it excites the coherent band (at least half of its input
        power inside it: doublets) and keeping it out does not narrow the band (the top of the band
        within 12 %, the width within 0.15 decades). Otherwise (the tail of a frequency sweep is its
        incoherent high-frequency end) the whole record is fitted and the check is on the fitted
        record, labelled so (``validation.source == "fit"``). Every check is judged against the
        noise floor it can see (see :mod:`tuner.identify.validate`).
    verify : mapping, optional
        A separate verification record (CIFER verifies on doublets flown separately):
        ``{"input": [...], "output": [...]}`` sampled like the fitted record, or with its own
        ``"time"`` or ``"rate_hz"``. The check runs on it.
    coherence_min : float
        Frequencies with a lower coherence are not fitted (CIFER: 0.6).
    n_points : int
        Number of log-spaced fit frequencies in the band (8 to 200; CIFER: 20-30). Points below
        ``coherence_min`` are dropped.
    windows_s : sequence of float, optional
        Window lengths of the spectral estimate, s (default: five from half the fitted part
        down, see :func:`tuner.identify.spectral.window_lengths`).
    n_starts : int
        Starting points of the fit (1 to 200).
    seed : int
        Seeds the random starting points: same data, same seed, same model.
    reference : sequence of float (or a list of them), optional
        The exogenous signal of data flown under feedback: an injected excitation, or the setpoint flown in a
        rate mode (sampled like ``input``). The response is then the joint input-output estimate
        ``S_ry / S_ru`` (:func:`tuner.identify.spectral.joint_composite`), unbiased by the feedback when ``r`` is
        exogenous (see ``reference_biased``), with the
        coherence of the output and of the input with ``r``; the band is where ``r`` explains both.
    controller : ControllerTF, optional
        The controller the data were flown with, at the record's sample time (e.g. a rate law from the log's
        parameters): the direct estimate is compared with ``-1/C``; where they agree the data say nothing about
        the plant (see ``closed_loop`` in the result).
    closed_loop_signs : sequence of str
        What the caller knows of the data: each a sign that they were flown under feedback (the input is a
        controller's output; the log stores the rate controller's parameters). Without ``reference``, a fit of
        data flown under feedback is never rated good or acceptable: ``quality`` is ``"closed-loop"``.
    hold : "zoh" or None
        How the plant saw the logged input between its samples. ``"zoh"``: held (a controller's output, a torque
        setpoint or an actuator command, as a PX4 ULog's input is put on its grid): the hold is removed from the
        measured response before the fit, so the continuous model put back at the record's sample time with a
        zero-order hold reproduces the measured discrete response, and a tune at that sample time counts the
        hold once (``options["hold_check"]`` says how closely). ``None`` (default): the input was a continuous
        signal sampled (a pilot's stick), fitted as measured.

    time_unit : {"auto", "s", "ms", "us"}
        The unit of ``time`` (and of a ``verify`` record's). ``"auto"`` (default) reads seconds, and refuses a
        column whose steps say it is in another unit until it is said: steps in whole numbers of 100 and more
        (a timestamp in microseconds, as PX4's CSV exports have), or of 0.1 to 1 (a kHz log in milliseconds, or a
        1-10 Hz log in seconds); steps of 1 to 100 get a warning (milliseconds?).
    reference_biased : str
        Why ``reference`` is not exogenous (a rate setpoint flown in an attitude mode, where it is the outer loop's
        output: :func:`tuner.identify.ulog.flown_edges` says so from the log): the joint estimate is then reported
        as biased by the outer loop, never as unbiased. Empty (default): the reference is taken as exogenous.
    firmware : a registered firmware's name ("px4", "ardupilot", ...) or None
        The autopilot that flew the log: the advice on a weak or closed-loop log names what to fly on it
        (:func:`tuner.identify.flight.what_to_fly`).

    Returns
    -------
    IdentifyResult
        Model, cost, band, frequency response, uncertainty, validation, warnings; ``quality`` is J's
        verdict and ``check`` the time-domain one, side by side; ``.plant()`` for
        :func:`tuner.tune`, ``.to_control()`` (the rational part as a ``control.TransferFunction``) and
        ``.delay_s``, ``.plot()``.

    Raises
    ------
    InvalidDataError
        Unusable data or options; ``field`` names the input (``input``, ``output``, ``time``,
        ``rate_hz``, ``band``, ``poles``, ...).
    IdentificationError
        The fit failed from every start.

    Examples
    --------
    A first-order plant ``5/(s + 5)`` driven by white noise at 100 Hz, 30 s:

    >>> import control
    >>> import numpy as np
    >>> from tuner import identify
    >>> u = np.random.default_rng(0).standard_normal(3000)
    >>> y = control.forced_response(control.c2d(control.tf([5], [1, 5]), 0.01), U=u).outputs
    >>> res = identify(u, y, rate_hz=100, poles=1, delay=None, band=[1.1, 30], n_starts=2)
    >>> res.quality, round(float(res.plant().poles[0].real))
    ('good', -5)
    >>> res.quality, res.check  # J's verdict and the time-domain check's, side by side
    ('good', 'good')
    >>> res.verdict  # doctest: +ELLIPSIS
    'J = ... over 1.1-30 rad/s (25 frequencies): good (CIFER: ...); time-domain check on the fitted record ...: good'
    """
    from .fit import fit_model
    from .spectral import unexplained_rms

    poles = _int(poles, "poles", 1, MAX_POLES)
    zeros = _int(zeros, "zeros", 0, poles)
    step = None if delay_step is None else _float(delay_step, "delay_step", 0.0, 1e6, lo_open=True)
    delay = _delay(delay, step)
    req_band = _band(band)
    auto = isinstance(holdout, str) and holdout == "auto"
    if isinstance(holdout, str) and not auto:
        raise InvalidDataError(f"holdout must be 'auto' or a fraction from 0 to 0.5, got {holdout!r}", field="holdout")
    holdout = AUTO_HOLDOUT if auto else _float(holdout, "holdout", 0.0, 0.5)
    coherence_min = _float(coherence_min, "coherence_min", 0.0, 1.0, lo_open=True, hi_open=True)
    n_points = _int(n_points, "n_points", 8, 200)
    n_starts = _int(n_starts, "n_starts", 1, 200)
    seed = _int(seed, "seed", 0, 2**32 - 1)

    if hold not in ("zoh", None):
        raise InvalidDataError(f"hold must be 'zoh' or None, got {hold!r}", field="hold")
    recs = _records(input, output, time, rate_hz, time_unit)
    joint = None
    reference_biased = str(reference_biased or "") if reference is not None else ""
    if reference is not None:
        try:
            joint = (_records(reference, output, time, rate_hz, time_unit),
                     _records(reference, input, time, rate_hz, time_unit))
        except InvalidDataError as e:
            raise InvalidDataError(f"reference: {e}", field="reference") from None
        if [r.n for r in joint[0]] != [r.n for r in recs]:
            raise InvalidDataError("reference must have as many samples as input and output (per record)",
                                   field="reference")
    ver = None if verify is None else _verify_record(verify, recs[0].dt, time_unit)
    if ver is not None and auto:
        holdout = 0.0
    rec = recs[-1]
    if holdout > 0:
        head, tail = rec.split(holdout)
        fit_recs = [*recs[:-1], head]
    else:
        head, tail, fit_recs = rec, None, recs
    if min(r.n for r in fit_recs) < MIN_SAMPLES:
        raise InvalidDataError(f"holding out {holdout:g} of {rec.n} samples leaves {head.n} to fit; at least "
                               f"{MIN_SAMPLES} are needed", field="holdout")
    fit_dur = max(r.duration_s for r in fit_recs)
    if isinstance(delay, float) and delay > fit_dur / 4.0:
        raise InvalidDataError(
            f"delay {delay:g} s is longer than a quarter of the fitted part of the record ({fit_dur:g} s, "
            f"the longest delay its spectra resolve: {fit_dur / 4.0:.4g} s); give a shorter delay, "
            "'auto', or a longer record", field="delay")
    _check_band(req_band, fit_dur, recs[0].nyquist_rad_s, recs[0].dt, holdout)
    notes: list[str] = []
    if joint is not None:  # the whole record is fitted: the reference's excitation is where the information is
        if holdout > 0 and not auto:
            raise InvalidDataError("with a reference the whole record is fitted (the joint estimate needs all of "
                                   "the excitation): give holdout 0 or 'auto', or a separate verify record",
                                   field="holdout")
        fit_recs, tail, head, holdout = recs, None, rec, 0.0
        fit_dur = max(r.duration_s for r in fit_recs)
        if ver is None:
            notes.append("with a reference the whole record is fitted: the time-domain check is on the fitted "
                         "record (give a separate verification record for an independent check)")
    # the whole record's coherent band, for the decision on holding its tail out (_tail_unfit), before the head's
    # spectra: the two sets are never held at once (a 10^6-sample log: 293 MB at the peak with both, 220 MB without)
    band_all: tuple[float, float] | None = None
    if auto and tail is not None and not np.std(tail.u) < _TAIL_QUIET * np.std(head.u):
        try:
            band_all = _spectral(recs, req_band, windows_s, coherence_min)[2]
        except InvalidDataError:
            band_all = None
    try:
        if joint is not None:
            spectra, fr, used, jspec = _joint_spectral(fit_recs, joint, req_band, windows_s, coherence_min, firmware)
        else:
            spectra, fr, used = _spectral(fit_recs, req_band, windows_s, coherence_min, firmware)
    except InvalidDataError:
        if not (auto and tail is not None):
            raise
        spectra, fr, used = None, None, None
    if auto and tail is not None:
        reason = ("without it there is no coherent band" if used is None else
                  _tail_unfit(tail, head, used, band_all))
        if reason:  # the whole record is fitted, and checked
            notes.append(f"the last {holdout:.0%} of the record was not held out: {reason}; the time-domain check "
                         "is on the fitted record (give a verification record for an independent check)")
            fit_recs, tail = recs, None
            fit_dur = max(r.duration_s for r in fit_recs)
            _check_band(req_band, fit_dur, recs[0].nyquist_rad_s, recs[0].dt, 0.0)
            spectra = fr = None  # the head's spectra go before the whole record's are computed (half the memory)
            spectra, fr, used = _spectral(fit_recs, req_band, windows_s, coherence_min, firmware)
    w_fit = np.geomspace(used[0], used[1], n_points)
    if joint is not None:
        from .spectral import joint_composite

        pts = joint_composite(*jspec, w_fit)
    else:
        pts = composite(spectra, w_fit)
    keep = (pts.coherence >= coherence_min) & np.isfinite(pts.h)
    n_par = 1 + poles + zeros + (1 if delay == "auto" else 0)
    if keep.sum() < max(n_par + 2, 6):
        raise InvalidDataError(
            f"no coherent band: only {int(keep.sum())} of {n_points} fit frequencies in {used[0]:.3g}-{used[1]:.3g} "
            f"rad/s have coherence >= {coherence_min:g} (at least {max(n_par + 2, 6)} are needed for {n_par} "
            "parameters); excite the plant over the band, or choose another band" + _fly(firmware),
            field="band" if req_band is not None else "output")
    w, h, coh = pts.w[keep], pts.h[keep], pts.coherence[keep]
    dt_log = recs[0].dt
    h_measured = h
    if hold == "zoh":  # the continuous model is fitted without the hold: G(jw) = H(e^{jw dt}) / hold(w)
        h = h / zoh_factor(w, dt_log)
    tau_max = min(math.pi / used[0], fit_dur / 4.0)
    out = fit_model(w, h, coh, poles=poles, zeros=zeros, delay=delay, delay_step=step, band=used,
                    tau_max=tau_max, n_starts=n_starts, seed=seed)
    if hold == "zoh":  # the hold's alias terms, from the model itself: refit to h / (hold x alias correction)
        corr = _alias_correction(out.model, w, dt_log)
        if corr is not None:
            h = h / corr
            out = fit_model(w, h, coh, poles=poles, zeros=zeros, delay=delay, delay_step=step, band=used,
                            tau_max=tau_max, n_starts=n_starts, seed=seed)
    model = out.model
    dm, dp = out.problem.errors(model.theta)
    from .fit import cost_terms

    points = FitPoints(w=w, mag_db=out.problem.mag_db, phase_deg=out.problem.phase_deg, coherence=coh,
                       cost=cost_terms(dm, dp, coh))
    unc = _uncertainty(out, delay)
    val, check_u = _check(model, spectra, fit_recs, rec, head, tail, ver, holdout)
    cov = _uncertainty(out, delay, covariance=True)
    warns = _warnings(out.cost, points, used, model, unc, val, n_points=n_points, tau_max=tau_max,
                      delay=delay, check=check_u, fit_u=np.concatenate([r.u for r in fit_recs]),
                      want_check=holdout > 0 or ver is not None)
    if time is not None and time_unit == "auto" and 1.0 <= dt_log <= 100.0:  # a log's clock in milliseconds?
        warns.insert(0, f"the time column steps by {dt_log:.4g} (a sample every {dt_log:.4g} s, {1 / dt_log:.3g} Hz): "
                        f"if it is in milliseconds, divide it by 1000 ({1000 / dt_log:.4g} Hz); the model's time "
                        "constants and delay are in the time column's units")
    closed = _closed_loop(spectra, fr, dt_log, joint is not None, controller, closed_loop_signs, coherence_min,
                          reference_band=used if joint is not None else None, reference_biased=reference_biased,
                          firmware=firmware)
    if closed.get("detected") and (joint is None or reference_biased):
        warns.insert(0, closed["message"])
    hold_check = _hold_check(model, w, h_measured, coh, dt_log) if hold == "zoh" else None
    options = {"poles": poles, "zeros": zeros, "delay": delay, "delay_step": step, "hold": hold,
               "estimate": ("direct" if joint is None else "joint (reference, biased by the outer loop)"
                            if reference_biased else "joint (reference)"),
               "reference_biased": reference_biased or None,
               "band": None if req_band is None else list(req_band), "holdout": "auto" if auto else holdout,
               "coherence_min": coherence_min, "n_points": n_points, "n_starts": n_starts, "seed": seed,
               "fit_starts_converged": out.starts, "delay_candidates_s": list(out.delay_candidates_s),
               "records": len(recs), "verify": None if ver is None else {"n_samples": ver.n, "rate_hz": 1 / ver.dt},
               "noise_floor_rms": unexplained_rms(spectra), "notes": notes, "hold_check": hold_check}
    return IdentifyResult(model=model, cost=out.cost, band_rad_s=(float(used[0]), float(used[1])),
                          frequency_response=fr, fit_points=points, uncertainty=unc, validation=val,
                          warnings=tuple(warns), rate_hz=1.0 / rec.dt, n_samples=sum(r.n for r in recs),
                          fit_duration_s=sum(r.duration_s for r in fit_recs), options=options,
                          covariance=cov, closed_loop=closed)


AUTO_HOLDOUT = 0.2
#: the direct estimate "is" -1/C where their median relative difference over the coherent band is below this
INVERSE_MATCH = 0.25


def zoh_factor(w: np.ndarray, dt: float) -> np.ndarray:
    """The zero-order hold's response ``(1 - e^{-jw dt})/(jw dt) = e^{-jw dt/2} sinc(w dt/2)``: a held input's
    sampled response is the continuous one times this (the alias terms of a low-pass plant neglected; checked
    after the fit against the exact ZOH model, ``options["hold_check"]``)."""
    x = np.asarray(w, dtype=float) * dt / 2.0
    return np.exp(-1j * x) * np.sinc(x / np.pi)


def _fly(firmware: str | None) -> str:
    """The advice on what to fly, as the end of a sentence ("" without a firmware)."""
    from ..firmware.registry import names

    if firmware not in names():
        return ""
    from .flight import what_to_fly

    return ". What to fly: " + what_to_fly(firmware)


def _joint_spectral(recs: list[Record], joint: tuple[list[Record], list[Record]], req_band: Any,
                    windows_s: Any, coherence_min: float,
                    firmware: str | None = None) -> tuple[list[Any], Any, tuple[float, float], tuple]:
    """The direct spectra (for the time-domain check and the noise floor), the joint estimate ``S_ry/S_ru`` on
    the usual grid, its band (where r explains y and u), and the r-spectra for the fit points."""
    from .spectral import coherent_band, frequency_response, joint_composite

    fr_ry, s_ry = frequency_response([r.detrended() for r in joint[0]], windows_s=windows_s)
    wins = [sp.window_s for sp in s_ry]
    _, s_ru = frequency_response([r.detrended() for r in joint[1]], windows_s=wins)
    _, spectra = frequency_response([r.detrended() for r in recs], windows_s=wins)
    fr = joint_composite(s_ry, s_ru, fr_ry.w)
    if req_band is not None:
        used = req_band
    else:
        try:
            used = coherent_band(fr, coherence_min=coherence_min)
        except InvalidDataError as e:
            raise InvalidDataError(f"the reference has no power where it explains the output and the input: {e}; "
                                   "excite the loop through the reference (a sweep or a multisine on the setpoint), "
                                   "or name the signal that was injected" + _fly(firmware),
                                   field="reference") from None
    return spectra, fr, used, (s_ry, s_ru)


def _closed_loop(spectra: list[Any], fr: Any, dt: float, joint: bool, controller: Any, signs: Sequence[str],
                 coherence_min: float, *, reference_band: Any = None, reference_biased: str = "",
                 firmware: str | None = None) -> dict[str, Any]:
    """What tells that the data were flown under feedback, and what it means for the estimate."""
    from .spectral import coherent_band, composite

    found = [str(x) for x in signs]
    match = None
    if controller is not None:
        direct = fr if not joint else composite(spectra, fr.w)
        try:
            lo, hi = coherent_band(direct, coherence_min=coherence_min)
        except InvalidDataError:
            lo = hi = None
        if lo is not None:
            sel = (direct.w >= lo) & (direct.w <= hi) & (direct.coherence >= coherence_min) & np.isfinite(direct.h)
            if sel.any():
                c = controller.freqresp(direct.w[sel])
                rel = np.abs(direct.h[sel] * c + 1.0)  # |H - (-1/C)| / |1/C|
                match = {"median_relative_difference": float(np.median(rel)), "band_rad_s": [float(lo), float(hi)],
                         "share_within": float(np.mean(rel < INVERSE_MATCH))}
                if match["median_relative_difference"] < INVERSE_MATCH:
                    found.append(f"the direct estimate matches -1/C of the known controller (median relative "
                                 f"difference {100 * match['median_relative_difference']:.0f} % over {lo:.3g}-"
                                 f"{hi:.3g} rad/s)")
    if joint and reference_biased:
        found.append("the reference is not exogenous")
    detected = bool(found)
    if not detected:
        return {"detected": False, "signs": [], "estimate": "joint" if joint else "direct", "inverse_match": match}
    if joint and reference_biased:
        lo, hi = reference_band
        msg = (f"the response is the joint input-output estimate with the reference over {lo:.3g}-{hi:.3g} rad/s, "
               f"but {reference_biased}: where the disturbance, not the pilot, drives the setpoint, the outer "
               "loop's feedback moves the estimate toward the inner loop's inverse" + _fly(firmware))
        return {"detected": True, "signs": found, "estimate": "joint", "message": msg, "inverse_match": match,
                "reference_exogenous": False}
    if joint:
        lo, hi = reference_band
        msg = ("the data were flown under feedback (" + "; ".join(found) + "); the response is the joint "
               f"input-output estimate with the reference, unbiased by the feedback over {lo:.3g}-{hi:.3g} rad/s, "
               "where the reference explains both the output and the input")
    else:
        msg = ("the data were flown under feedback (" + "; ".join(found) + "): where the disturbance, not an "
               "excitation, drives the loop, the direct estimate from input to output is the controller's "
               "inverse -1/C, at high coherence, and says nothing about the plant; this fit is not rated good or "
               "acceptable. Give the exogenous signal as the reference (an injected excitation, or the rate "
               "setpoint flown in a rate mode), and excite the loop through it" + _fly(firmware))
    return {"detected": True, "signs": found, "estimate": "joint" if joint else "direct", "message": msg,
            "inverse_match": match}


def _alias_correction(model: Any, w: np.ndarray, dt: float) -> np.ndarray | None:
    """``exact ZOH(model)(e^{jw dt}) / (model(jw) hold(w))``: what the hold's first-order factor misses (the alias
    terms of the sampled model), near 1 for a low-pass model well below Nyquist; None if it cannot be computed."""
    from ..plant import make_plant

    num, den = model.tf()
    try:
        exact = make_plant(num, den, delay=float(model.delay_s or 0.0)).zoh(dt).freqresp(w)
        approx = model.freqresp(w) * zoh_factor(w, dt)
    except Exception:
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        c = exact / approx
    return c if np.all(np.isfinite(c)) else None


def _hold_check(model: Any, w: np.ndarray, h: np.ndarray, coherence: np.ndarray, dt: float) -> dict[str, float]:
    """The fitted continuous model put back at ``dt`` with an exact zero-order hold (its delay's fraction of a
    sample included), against the measured discrete response at the fit points: median and largest differences."""
    from ..plant import make_plant

    num, den = model.tf()
    try:
        zoh = make_plant(num, den, delay=float(model.delay_s or 0.0)).zoh(dt)
        hz = zoh.freqresp(w)
    except Exception:
        return {"checked": False}
    with np.errstate(divide="ignore", invalid="ignore"):
        d_db = 20.0 * np.log10(np.abs(hz) / np.abs(h))
        d_deg = np.degrees(np.angle(hz / h))
    ok = np.isfinite(d_db) & np.isfinite(d_deg)
    if not ok.any():
        return {"checked": False}
    return {"checked": True, "median_db": float(np.median(np.abs(d_db[ok]))),
            "max_db": float(np.max(np.abs(d_db[ok]))), "median_deg": float(np.median(np.abs(d_deg[ok]))),
            "max_deg": float(np.max(np.abs(d_deg[ok])))}
_TAIL_IN_BAND = 0.5  # share of the tail's input power inside the band for it to count as exciting it
_TAIL_QUIET = 0.05  # a tail whose input's spread is below this share of the head's hardly excites the plant
_TAIL_AT_EDGES = 0.25  # share of the tail's input power in the part of the band only it makes coherent


def _check_band(req_band: tuple[float, float] | None, fit_dur: float, nyquist: float, dt: float,
                holdout: float) -> None:
    if req_band is None:
        return
    lo, hi = req_band
    w_lowest = lowest_frequency_rad_s(fit_dur)
    if lo < w_lowest * (1 - LIMIT_RTOL):
        need = 8 * math.pi / lo / (1.0 - holdout)
        raise InvalidDataError(
            f"band starts at {lo:g} rad/s, but the fitted part of the record ({fit_dur:g} s) has too "
            f"few cycles there: it resolves down to {w_lowest:.3g} rad/s (two periods in a window of half of "
            f"it); record at least {need:.3g} s, or start the band at {w_lowest:.3g} rad/s or above",
            field="band")
    if hi > 0.9 * nyquist:
        raise InvalidDataError(f"band ends at {hi:g} rad/s, above 90 % of the Nyquist frequency "
                               f"({0.9 * nyquist:.4g} rad/s at {1 / dt:g} Hz): log faster, or lower "
                               "the band's upper end", field="band")


def _spectral(recs: list[Record], req_band: tuple[float, float] | None, windows_s: Sequence[float] | None,
              coherence_min: float, firmware: str | None = None) -> tuple[list[Any], Any, tuple[float, float]]:
    from .spectral import coherent_band, frequency_response

    fr, spectra = frequency_response([r.detrended() for r in recs], windows_s=windows_s)
    try:
        used = req_band if req_band is not None else coherent_band(fr, coherence_min=coherence_min)
    except InvalidDataError as e:
        if not _fly(firmware):
            raise
        raise InvalidDataError(str(e) + _fly(firmware), field=e.field) from None
    return spectra, fr, used


def _band_power_share(u: np.ndarray, dt: float, band: tuple[float, float]) -> float:
    """Share of the (detrended) signal's power between ``band`` (rad/s), by its periodogram."""
    from scipy.signal import detrend

    p = np.abs(np.fft.rfft(detrend(u, type="linear"))) ** 2
    w = 2 * np.pi * np.fft.rfftfreq(u.size, dt)
    total = float(p[1:].sum())
    return float(p[(w >= band[0]) & (w <= band[1])].sum() / total) if total > 0 else 0.0


def _tail_unfit(tail: Record, head: Record, band_fit: tuple[float, float],
                band_all: tuple[float, float] | None) -> str:
    """Why the record's tail should not be held out ("" if it may): it hardly excites the band,
    or holding it out narrows the band (the tail of a sweep). ``band_all``: the whole record's coherent band (None:
    it has none; the head's is taken)."""
    if np.std(tail.u) < _TAIL_QUIET * np.std(head.u):
        return "it hardly excites the plant"
    if band_all is None:
        band_all = band_fit
    share = _band_power_share(tail.u, tail.dt, band_all)
    if share < _TAIL_IN_BAND:
        return (f"only {share:.0%} of its input power lies in the coherent band {band_all[0]:.3g}-{band_all[1]:.3g} "
                "rad/s")
    edges = (_band_power_share(tail.u, tail.dt, (band_fit[1], band_all[1])) if band_all[1] > band_fit[1] else 0.0) + (
        _band_power_share(tail.u, tail.dt, (band_all[0], band_fit[0])) if band_all[0] < band_fit[0] else 0.0)
    if edges > _TAIL_AT_EDGES:
        return (f"{edges:.0%} of its input power lies where only it makes the data coherent (the band is "
                f"{band_all[0]:.3g}-{band_all[1]:.3g} rad/s with it, {band_fit[0]:.3g}-{band_fit[1]:.3g} without: "
                "it holds the top of the sweep)")
    return ""


def _check(model: Any, spectra: list[Any], fit_recs: list[Record], rec: Record, head: Record, tail: Record | None,
           ver: Record | None, holdout: float) -> tuple[Any, np.ndarray | None]:
    """The time-domain check (or ``None``) and the input it ran on (for the excitation warning)."""
    from .spectral import unexplained_rms
    from .validate import validate, validate_segments

    if ver is not None:
        try:
            _, own = frequency_response(ver.detrended())
            floor = unexplained_rms(own)
        except InvalidDataError:  # too short for spectra: the fitted record's floor
            floor = unexplained_rms(spectra)
        return validate(model, ver, 0, u_trim=float(np.mean(ver.u)), noise_rms=floor, source="verify"), ver.u
    floor = unexplained_rms(spectra)
    if tail is not None:
        return validate(model, rec, head.n, u_trim=float(np.mean(head.u)), noise_rms=floor), tail.u
    if holdout > 0:  # auto fell back to the whole record
        segs = [(r, 0, float(np.mean(r.u))) for r in fit_recs]
        return validate_segments(model, segs, noise_rms=floor, source="fit"), None
    return None, None


def _records(input: Any, output: Any, time: Any, rate_hz: Any, time_unit: str = "auto") -> list[Record]:
    """One record, or several (lists of sequences), validated; several share the sample time."""
    multi = _is_multi(input) or _is_multi(output)
    if not multi:
        return [make_record(input, output, time=time, rate_hz=rate_hz, time_unit=time_unit)]
    if not (_is_multi(input) and _is_multi(output)) or len(input) != len(output):
        raise InvalidDataError("several records: give input and output as lists of the same number of records",
                               field="output")
    if time is not None and not (_is_multi(time) and len(time) == len(input)):
        raise InvalidDataError(f"several records: give time as a list of {len(input)} time columns, or rate_hz",
                               field="time")
    if len(input) > MAX_RECORDS:
        raise InvalidDataError(f"{len(input)} records given; at most {MAX_RECORDS}", field="input")
    recs = []
    for i, (u, y) in enumerate(zip(input, output)):
        try:
            recs.append(make_record(u, y, time=None if time is None else time[i], rate_hz=rate_hz,
                                    time_unit=time_unit))
        except InvalidDataError as e:
            raise InvalidDataError(f"record {i + 1} of {len(input)}: {e}", field=e.field) from None
    for i, r in enumerate(recs[1:], 2):
        if abs(r.dt - recs[0].dt) > 1e-6 * recs[0].dt:
            raise InvalidDataError(f"record {i} is sampled at {1 / r.dt:.6g} Hz, record 1 at {1 / recs[0].dt:.6g} Hz: "
                                   "records fitted together share the sample rate; resample them", field="time")
    return recs


MAX_RECORDS = 100


def _is_multi(x: Any) -> bool:
    return isinstance(x, (list, tuple)) and len(x) > 0 and np.ndim(x[0]) == 1


def _verify_record(verify: Any, dt: float, time_unit: str = "auto") -> Record:
    if not isinstance(verify, Mapping) or "input" not in verify or "output" not in verify:
        raise InvalidDataError("verify must be a mapping with input and output (and optionally time or rate_hz)",
                               field="verify")
    extra = set(verify) - {"input", "output", "time", "rate_hz"}
    if extra:
        raise InvalidDataError(f"verify: unknown keys {sorted(extra)}; give input, output, time or rate_hz",
                               field="verify")
    t, r = verify.get("time"), verify.get("rate_hz")
    try:
        return make_record(verify["input"], verify["output"], time=t,
                           rate_hz=(1.0 / dt if t is None and r is None else r), time_unit=time_unit)
    except InvalidDataError as e:
        raise InvalidDataError(f"verify: {e}", field=("verify", *e.field)) from None


def _uncertainty(out: Any, delay: DelaySpec, *, covariance: bool = False) -> Any:
    """Bounds at the optimum (or, ``covariance``, the parameters' covariance in the order of the bounds); a
    delay chosen among whole steps is bounded as if it were free."""
    from .fit import Problem
    from .model import Structure
    from .uncertainty import covariance as cov_of
    from .uncertainty import cramer_rao

    fn = cov_of if covariance else cramer_rao
    p, m = out.problem, out.model
    if delay == "auto" and not p.structure.free_delay:
        st = Structure(poles=p.structure.poles, zeros=p.structure.zeros, free_delay=True)
        p = Problem(w=p.w, mag_db=p.mag_db, phase_deg=p.phase_deg, coherence=p.coherence, structure=st, sign=p.sign)
        return fn(p, np.concatenate([m.theta, [m.delay_s]]))
    return fn(p, m.theta)


def _warnings(cost: float, points: FitPoints, band: tuple[float, float], model: Any, unc: dict, val: Any, *,
              n_points: int, tau_max: float, delay: DelaySpec, check: np.ndarray | None, fit_u: np.ndarray,
              want_check: bool) -> list[str]:
    from .uncertainty import CR_LIMIT_PCT, INSENSITIVITY_LIMIT_PCT
    from .validate import NOISE_RATIO_LIMIT, SOURCES, THEIL_LIMIT

    out: list[str] = []
    if cost > J_ACCEPTABLE:
        out.append(f"J = {cost:.0f} > {J_ACCEPTABLE:.0f}: the model does not explain the data; try more poles "
                   "(or zeros), a delay, or a narrower band")
    elif cost > J_GOOD:
        out.append(f"J = {cost:.0f}: acceptable (<= {J_ACCEPTABLE:.0f}) but not good (<= {J_GOOD:.0f}); a model "
                   "with more poles may fit better")
    bad = np.flatnonzero(points.cost > J_POINT_MAX)
    if bad.size:
        out.append(f"the cost exceeds {J_POINT_MAX:.0f} at {bad.size} frequencies (worst {points.cost.max():.0f} at "
                   f"{points.w[int(np.argmax(points.cost))]:.3g} rad/s): the model misses the data there")
    if points.w.size < n_points:
        out.append(f"{n_points - points.w.size} of {n_points} fit frequencies had coherence below the threshold "
                   "and were left out")
    decades = math.log10(band[1] / band[0])
    if decades < 1.0:
        out.append(f"the band spans only {decades:.2f} decades ({band[0]:.3g}-{band[1]:.3g} rad/s): the model is "
                   "reliable there only")
    for name, u in unc.items():
        if u.cr_bound_pct > CR_LIMIT_PCT or u.insensitivity_pct > INSENSITIVITY_LIMIT_PCT:
            if name == "delay_s" and abs(u.value) < 1e-9:
                continue  # a zero delay has no relative bound
            out.append(f"{name} = {u.value:.4g}: Cramér–Rao bound {u.cr_bound_pct:.3g} % (limit {CR_LIMIT_PCT:g}), "
                       f"insensitivity {u.insensitivity_pct:.3g} % (limit {INSENSITIVITY_LIMIT_PCT:g}): poorly "
                       "determined by the data; fix it, or fit fewer poles or zeros")
    for name, v in model.values().items():
        if name.endswith("_rad_s") and not band[0] / 3.0 <= v <= 3.0 * band[1]:
            out.append(f"{name} = {v:.4g} rad/s lies outside the band ({band[0]:.3g}-{band[1]:.3g} rad/s): the data "
                       "do not determine it; fit fewer poles or zeros")
    if delay == "auto" and model.delay_s >= 0.999 * tau_max:
        out.append(f"the delay reached its upper bound ({tau_max:.3g} s): the model lacks phase lag some other way")
    if want_check:
        if val is None:
            out.append("no time-domain check: the held-out part is too short")
        elif check is not None and np.std(check) < 0.05 * np.std(fit_u):
            what = "verification record" if val.source == "verify" else "held-out part"
            out.append(f"the {what} hardly excites the plant: its time-domain check means little "
                       "(put doublets there)")
        elif val.verdict == "fair":
            out.append(f"time-domain check on {SOURCES[val.source]}: Theil {val.theil_u:.2f} meets the guideline, but "
                       f"the rms error is {val.noise_ratio:.2f} times the noise floor (> {NOISE_RATIO_LIMIT:g}): the "
                       "data show a response the model misses (more poles or zeros, another band or delay?)")
        elif not val.ok:
            out.append(f"time-domain check on {SOURCES[val.source]}: Theil's inequality coefficient {val.theil_u:.2f} "
                       f"> {THEIL_LIMIT:g} and the rms error is {val.noise_ratio:.2f} times the noise floor "
                       f"(> {NOISE_RATIO_LIMIT:g}): the model does not predict the measured response")
    return out
