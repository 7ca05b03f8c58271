"""``identify(input, output, ...)``: from a logged record to a fitted, checked transfer function."""

from __future__ import annotations

import logging
import math
import numbers
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import InvalidDataError
from .data import MIN_SAMPLES, lowest_frequency_rad_s, make_record
from .result import J_ACCEPTABLE, J_GOOD, J_POINT_MAX, FitPoints, IdentifyResult

__all__ = ["MAX_POLES", "DelaySpec", "identify"]

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
    holdout: float = 0.2,
    coherence_min: float = 0.6,
    n_points: int = 25,
    windows_s: Sequence[float] | None = None,
    n_starts: int = 20,
    seed: int = 0,
) -> IdentifyResult:
    """Identify a continuous transfer function (with a delay) from logged input/output data.

    The record is validated and split: the first ``1 - holdout`` is detrended and turned into a
    frequency response with coherence (several Welch windows composited, as CIFER's COMPOSITE);
    the model is fitted over the coherent band by minimising CIFER's cost ``J``; the Cramér–Rao
    bounds of its parameters are computed at the optimum; and the model is simulated on the
    held-out rest of the record (Theil's inequality coefficient, NRMSE).

    Parameters
    ----------
    input, output : sequence of float
        The logged plant input (e.g. the stick or attitude command) and output (e.g. the
        angle), equal lengths, finite, at least 128 samples.
    time : sequence of float, optional
        Sample times in seconds: strictly increasing and uniform within 1 %. Give this or
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
    holdout : float
        Fraction of the record, at its end, kept out of the fit for the time-domain check
        (0 to 0.5; 0 = no check). Put the doublets there.
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

    Returns
    -------
    IdentifyResult
        Model, cost, band, frequency response, uncertainty, validation, warnings; ``.plant()`` for
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
    >>> res.verdict  # doctest: +ELLIPSIS
    'good: J = ... over 1.1-30 rad/s (25 frequencies); held-out check: Theil ..., fit ... %'
    """
    from .fit import fit_model
    from .spectral import coherent_band, composite, frequency_response

    poles = _int(poles, "poles", 1, MAX_POLES)
    zeros = _int(zeros, "zeros", 0, poles)
    step = None if delay_step is None else _float(delay_step, "delay_step", 0.0, 1e6, lo_open=True)
    delay = _delay(delay, step)
    req_band = _band(band)
    holdout = _float(holdout, "holdout", 0.0, 0.5)
    coherence_min = _float(coherence_min, "coherence_min", 0.0, 1.0, lo_open=True, hi_open=True)
    n_points = _int(n_points, "n_points", 8, 200)
    n_starts = _int(n_starts, "n_starts", 1, 200)
    seed = _int(seed, "seed", 0, 2**32 - 1)

    rec = make_record(input, output, time=time, rate_hz=rate_hz)
    fit_rec, check_rec = rec.split(holdout)
    if fit_rec.n < MIN_SAMPLES:
        raise InvalidDataError(f"holding out {holdout:g} of {rec.n} samples leaves {fit_rec.n} to fit; at least "
                               f"{MIN_SAMPLES} are needed", field="holdout")
    w_lowest = lowest_frequency_rad_s(fit_rec.duration_s)
    if req_band is not None:
        lo, hi = req_band
        if lo < w_lowest * (1 - 1e-9):
            need = 8 * math.pi / lo / (1.0 - holdout)
            raise InvalidDataError(
                f"band starts at {lo:g} rad/s, but the fitted part of the record ({fit_rec.duration_s:g} s) has too "
                f"few cycles there: it resolves down to {w_lowest:.3g} rad/s (two periods in a window of half of "
                f"it); record at least {need:.3g} s, or start the band at {w_lowest:.3g} rad/s or above",
                field="band")
        if hi > 0.9 * rec.nyquist_rad_s:
            raise InvalidDataError(f"band ends at {hi:g} rad/s, above 90 % of the Nyquist frequency "
                                   f"({0.9 * rec.nyquist_rad_s:.4g} rad/s at {1 / rec.dt:g} Hz): log faster, or lower "
                                   "the band's upper end", field="band")
    det = fit_rec.detrended()
    fr, spectra = frequency_response(det, windows_s=windows_s)
    used = req_band if req_band is not None else coherent_band(fr, coherence_min=coherence_min)
    w_fit = np.geomspace(used[0], used[1], n_points)
    pts = composite(spectra, w_fit)
    keep = (pts.coherence >= coherence_min) & np.isfinite(pts.h)
    n_par = 1 + poles + zeros + (1 if delay == "auto" else 0)
    if keep.sum() < max(n_par + 2, 6):
        raise InvalidDataError(
            f"no coherent band: only {int(keep.sum())} of {n_points} fit frequencies in {used[0]:.3g}-{used[1]:.3g} "
            f"rad/s have coherence >= {coherence_min:g} (at least {max(n_par + 2, 6)} are needed for {n_par} "
            "parameters); excite the plant over the band, or choose another band",
            field="band" if req_band is not None else "output")
    w, h, coh = pts.w[keep], pts.h[keep], pts.coherence[keep]
    tau_max = min(math.pi / used[0], fit_rec.duration_s / 4.0)
    out = fit_model(w, h, coh, poles=poles, zeros=zeros, delay=delay, delay_step=step, band=used,
                    tau_max=tau_max, n_starts=n_starts, seed=seed)
    model = out.model
    dm, dp = out.problem.errors(model.theta)
    from .fit import cost_terms

    points = FitPoints(w=w, mag_db=out.problem.mag_db, phase_deg=out.problem.phase_deg, coherence=coh,
                       cost=cost_terms(dm, dp, coh))
    unc = _uncertainty(out, delay)
    val = None
    if check_rec is not None:
        from .validate import validate

        val = validate(model, rec, fit_rec.n, u_trim=float(np.mean(fit_rec.u)))
    warns = _warnings(out.cost, points, used, model, unc, val, n_points=n_points, tau_max=tau_max,
                      delay=delay, check=check_rec, fit_u=fit_rec.u)
    options = {"poles": poles, "zeros": zeros, "delay": delay, "delay_step": step,
               "band": None if req_band is None else list(req_band), "holdout": holdout,
               "coherence_min": coherence_min, "n_points": n_points, "n_starts": n_starts, "seed": seed,
               "fit_starts_converged": out.starts, "delay_candidates_s": list(out.delay_candidates_s)}
    return IdentifyResult(model=model, cost=out.cost, band_rad_s=(float(used[0]), float(used[1])),
                          frequency_response=fr, fit_points=points, uncertainty=unc, validation=val,
                          warnings=tuple(warns), rate_hz=1.0 / rec.dt, n_samples=rec.n,
                          fit_duration_s=fit_rec.duration_s, options=options)


def _uncertainty(out: Any, delay: DelaySpec) -> dict:
    """Bounds at the optimum; a delay chosen among whole steps is bounded as if it were free."""
    from .fit import Problem
    from .model import Structure
    from .uncertainty import cramer_rao

    p, m = out.problem, out.model
    if delay == "auto" and not p.structure.free_delay:
        st = Structure(poles=p.structure.poles, zeros=p.structure.zeros, free_delay=True)
        p = Problem(w=p.w, mag_db=p.mag_db, phase_deg=p.phase_deg, coherence=p.coherence, structure=st, sign=p.sign)
        return cramer_rao(p, np.concatenate([m.theta, [m.delay_s]]))
    return cramer_rao(p, m.theta)


def _warnings(cost: float, points: FitPoints, band: tuple[float, float], model: Any, unc: dict, val: Any, *,
              n_points: int, tau_max: float, delay: DelaySpec, check: Any, fit_u: np.ndarray) -> list[str]:
    from .uncertainty import CR_LIMIT_PCT, INSENSITIVITY_LIMIT_PCT
    from .validate import THEIL_LIMIT

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
    if check is not None:
        if val is None:
            out.append("no time-domain check: the held-out part is too short")
        elif np.std(check.u) < 0.05 * np.std(fit_u):
            out.append("the held-out part hardly excites the plant: its time-domain check means little "
                       "(put doublets there)")
        elif not val.ok:
            out.append(f"time-domain check on the held-out data: Theil's inequality coefficient {val.theil_u:.2f} > "
                       f"{THEIL_LIMIT:g}: the model does not predict the held-out response")
    return out
