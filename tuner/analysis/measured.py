"""The loop on the *measured* frequency response: PM, GM and Ms from the identification's data, next to the model's.

A model is a fit; the frequency response it was fitted to is the measurement. With an identification at hand the
loop ``L = C G`` can be evaluated on the measured ``G(jw)`` itself, at the frequencies where the data are coherent,
and compared with the same figures of the model's loop on the same frequencies. Where they disagree by more than
the measurement's own random error the model is not the airframe there, and the margins the tuner reports from the
model are not the ones the vehicle will have.

The random error of a frequency-response point with coherence ``g2`` from ``n_d`` averages is
``eps = sqrt((1 - g2)/(2 n_d g2))`` (relative magnitude; the phase error is ``asin(eps)``; Bendat & Piersol, Random
Data, 4th ed., table 9.6). ``n_d`` is counted conservatively: the fitted duration over the longest window of the
composite (the fewest averages any of its windows has). Each figure comes with the range it spans when every point
moves by its error (magnitude times ``1 +- eps``, phase ``+- asin(eps)``).

Crossings are interpolated between neighbouring coherent points (linear in log frequency); a crossing outside the
coherent band, or in a gap of incoherent points, is not measured: the figure is then ``nan`` with a note. A phase
crossing where ``|L| > 1`` counts as a negative gain margin: the data alone cannot tell a conditionally stable loop
from an unstable one.

The hold is counted once, at the loop's sample time: an identification with ``hold = "zoh"`` (a ULog's default: the
input held on the log's grid) measured the plant times the log's zero-order hold, which is replaced by the loop's
(``zoh(w, dt_loop) / zoh(w, dt_log)``, the first-order factor of :func:`tuner.identify.core.zoh_factor`, alias terms
neglected); one without (``hold`` None: a continuous input sampled) measured the plant alone, to which the loop's
hold is added. (Before, a log at 49.9 Hz under a loop at 400 Hz kept the log's 10 ms hold: 57 deg at 100 rad/s.)

**The measured figures are checks** (:func:`with_measured`, issue 39): on an identified plant the verdict includes
the airframe. The phase and gain margins measured (and Ms, when the spec limits it) are judged by the worst end of
their error range, which the data cannot exclude (``measured_phase_margin_deg``, ``measured_gain_margin_db``,
``measured_ms`` in the analysis' checks); a figure not measured (``nan``) does not pass. An identification rated
below acceptable (J's verdict ``poor``, or ``closed-loop``: fitted from data flown under feedback without a
reference) makes the result one on the model only (the check ``identification_quality``): whatever the figures, the
model is not confirmed to be the airframe.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["LoopFigures", "MeasuredComparison", "loop_figures", "measured_comparison", "measured_checks",
           "identification_check", "with_measured", "MEASURED_CHECKS", "IDENTIFICATION_CHECK", "QUALITY_OK"]

#: the checks on the measured response (the prefix of their names: ``measured_`` and the model's metric)
MEASURED_CHECKS = ("measured_phase_margin_deg", "measured_gain_margin_db", "measured_ms")
#: the check of the identification's rating, and the ratings that pass it (tuner.identify: J's verdict)
IDENTIFICATION_CHECK = "identification_quality"
QUALITY_OK = ("good", "acceptable")


@dataclass(frozen=True)
class LoopFigures:
    """PM, GM and Ms of a loop on a set of frequencies, with the range each spans under the points' errors."""

    phase_margin_deg: float
    crossover_rad_s: float
    gain_margin_db: float
    ms: float
    phase_margin_range: tuple[float, float] = (math.nan, math.nan)
    gain_margin_range: tuple[float, float] = (math.nan, math.nan)
    ms_range: tuple[float, float] = (math.nan, math.nan)

    def to_dict(self) -> dict[str, Any]:
        """The figures by name (ranges as ``[lo, hi]``)."""
        return {"phase_margin_deg": self.phase_margin_deg, "crossover_rad_s": self.crossover_rad_s,
                "gain_margin_db": self.gain_margin_db, "ms": self.ms,
                "phase_margin_range": list(self.phase_margin_range),
                "gain_margin_range": list(self.gain_margin_range), "ms_range": list(self.ms_range)}


@dataclass(frozen=True)
class MeasuredComparison:
    """The loop on the measured response and on the model, over the identification's coherent points.

    ``measured`` has the ranges of the measurement's random error; ``model`` is the model's loop on the same
    frequencies (the full-band figures are the analysis' own); ``warnings`` name each figure where the model lies
    outside the measured range."""

    band_rad_s: tuple[float, float]
    points: int
    measured: LoopFigures
    model: LoopFigures
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default=())

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready after :func:`tuner.jsonio.jsonable`."""
        return {"band_rad_s": list(self.band_rad_s), "points": self.points, "measured": self.measured.to_dict(),
                "model": self.model.to_dict(), "warnings": list(self.warnings), "notes": list(self.notes)}


def _crossings(w: np.ndarray, f: np.ndarray, ok: np.ndarray) -> list[tuple[int, float]]:
    """Where ``f`` changes sign between neighbouring valid points: ``(i, t)``, the crossing at ``i + t``."""
    out = []
    for i in range(w.size - 1):
        if ok[i] and ok[i + 1] and (f[i] == 0 or f[i] * f[i + 1] < 0):
            t = 0.0 if f[i] == 0 else f[i] / (f[i] - f[i + 1])
            out.append((i, float(t)))
    return out


def _at(x: np.ndarray, i: int, t: float) -> float:
    return float(x[i] + t * (x[i + 1] - x[i]))


def _figures(w: np.ndarray, L: np.ndarray, ok: np.ndarray) -> tuple[float, float, float, float]:
    """(PM deg, crossover rad/s, GM dB, Ms) of ``L`` on the valid points ``ok`` (nan: no crossing there)."""
    lw = np.log10(w)
    mag = np.abs(L)
    ph = np.degrees(np.unwrap(np.angle(L)))
    pm, wc = math.nan, math.nan
    for i, t in _crossings(w, np.log(np.maximum(mag, 1e-300)), ok):
        p = (_at(ph, i, t) + 180.0) % 360.0
        p = p - 360.0 if p > 180.0 else p
        if math.isnan(pm) or p < pm:
            pm, wc = p, 10 ** _at(lw, i, t)
    gm = math.nan
    for i, t in _crossings(w, L.imag, ok & (L.real < 0)):
        g = -20.0 * math.log10(max(_at(mag, i, t), 1e-300))
        if math.isnan(gm) or g < gm:
            gm = g
    ms = float(np.max(1.0 / np.abs(1.0 + L[ok]))) if ok.any() else math.nan
    return pm, wc, gm, ms


def loop_figures(w: np.ndarray, L: np.ndarray, ok: np.ndarray, eps: np.ndarray | None = None) -> LoopFigures:
    """PM, GM and Ms of ``L(jw)`` on the points ``ok``; with ``eps`` (each point's relative error), the range each
    figure spans when the points move by it (the four corners of magnitude ``1 +- eps`` and phase
    ``+- asin(eps)``).

    Examples
    --------
    >>> import numpy as np
    >>> from tuner.analysis.measured import loop_figures
    >>> w = np.geomspace(0.1, 10, 400)
    >>> L = 1 / (1j * w * (1j * w + 1))  # PM 51.8 deg at 0.786 rad/s, no phase crossover
    >>> f = loop_figures(w, L, np.ones(w.size, bool))
    >>> round(f.phase_margin_deg, 1), round(f.crossover_rad_s, 3), f.gain_margin_db
    (51.8, 0.786, nan)
    """
    pm, wc, gm, ms = _figures(w, L, ok)
    if eps is None:
        return LoopFigures(pm, wc, gm, ms)
    e = np.clip(np.asarray(eps, float), 0.0, 0.99)
    ph = np.arcsin(e)
    pms, gms = [], []
    for m in (1 - e, 1 + e):
        for s in (-1, 1):
            p, _, g, _ = _figures(w, L * m * np.exp(1j * s * ph), ok)
            pms.append(p)
            gms.append(g)
    with np.errstate(divide="ignore"):
        near = np.abs(1.0 + L) - np.abs(L) * e
        ms_hi = float(np.max(np.where(near > 0, 1.0 / np.maximum(near, 1e-300), np.inf)[ok])) if ok.any() else math.nan
        ms_lo = float(np.max((1.0 / (np.abs(1.0 + L) + np.abs(L) * e))[ok])) if ok.any() else math.nan

    def rng(v: list[float], c: float) -> tuple[float, float]:
        v = [x for x in v if not math.isnan(x)]
        return (min(v + [c]), max(v + [c])) if v and not math.isnan(c) else (math.nan, math.nan)

    return LoopFigures(pm, wc, gm, ms, rng(pms, pm), rng(gms, gm), (ms_lo, ms_hi))


def measured_comparison(ident: Any, analysis: Any, *, coherence_min: float | None = None) -> MeasuredComparison:
    """The loop of ``analysis`` (a controller on the model of ``ident``) on the measured frequency response.

    ``ident`` is a :class:`~tuner.identify.IdentifyResult` (its ``frequency_response``, ``band_rad_s``,
    ``fit_duration_s``, ``rate_hz``); ``analysis`` a :class:`~tuner.analysis.Analysis` of a controller on
    ``ident``'s model. The measured ``G`` is the response from the logged input's samples to the output's, so
    at the log's rate it already holds the hold and the computation delay; a loop at another sample time is
    compared all the same, with a note.
    """
    fr = ident.frequency_response
    lo, hi = (float(v) for v in ident.band_rad_s)
    options = getattr(ident, "options", None) or {}
    cmin = float(coherence_min if coherence_min is not None else options.get("coherence_min", 0.6))
    w = np.asarray(fr.w, float)
    g2 = np.asarray(fr.coherence, float)
    h = np.asarray(fr.h, complex)
    ok = (w >= lo * (1 - 1e-9)) & (w <= hi * (1 + 1e-9)) & (g2 >= cmin) & np.isfinite(h)
    loop = analysis.loop
    dt = loop.dt
    dt_log = 1.0 / float(ident.rate_hz) if getattr(ident, "rate_hz", None) else None
    h, hold_note = _held_at_loop(h, w, options.get("hold", "zoh"), dt_log, dt)
    C = loop.controller.freqresp(w)
    L_meas = C * h
    L_model = loop.freqresp(w)
    windows = [float(x) for x in (fr.windows_s or ())]
    n_d = max(1.0, float(ident.fit_duration_s) / max(windows)) if windows else 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        eps = np.sqrt(np.clip(1.0 - g2, 0.0, 1.0) / (2.0 * n_d * np.maximum(g2, 1e-12)))
    meas = loop_figures(w, L_meas, ok, eps)
    model = loop_figures(w, L_model, ok)
    notes = [hold_note] if hold_note else []
    warnings = []
    full = analysis.metrics  # the model's loop over every frequency (the verifier's)
    for name, m_v, (a, b), mod, whole, unit in (
            ("phase margin", meas.phase_margin_deg, meas.phase_margin_range, model.phase_margin_deg,
             full.phase_margin_deg, " deg"),
            ("gain margin", meas.gain_margin_db, meas.gain_margin_range, model.gain_margin_db, full.gain_margin_db,
             " dB"),
            ("Ms", meas.ms, meas.ms_range, model.ms, full.ms, "")):
        if math.isnan(m_v) and math.isfinite(whole):
            notes.append(f"{name}: the model's crossing lies outside the coherent data ({lo:.3g}-{hi:.3g} rad/s): "
                         "not measured")
        elif not math.isnan(m_v) and not math.isnan(mod) and not (a <= mod <= b):
            warnings.append(f"{name}: the model gives {mod:.3g}{unit} and the measured response {m_v:.3g}{unit} "
                            f"(within its error {a:.3g}-{b:.3g}{unit}): the model is not the airframe there; "
                            "check the identification (band, model order, delay)")
    return MeasuredComparison(band_rad_s=(lo, hi), points=int(ok.sum()), measured=meas, model=model,
                              warnings=tuple(warnings), notes=tuple(notes))


def _held_at_loop(h: np.ndarray, w: np.ndarray, hold: Any, dt_log: float | None, dt: float | None
                  ) -> tuple[np.ndarray, str | None]:
    """The measured response with the loop's zero-order hold in place of the log's (the module's docstring), and a
    note when the two sample times differ."""
    from ..identify.core import zoh_factor

    same = dt is not None and dt_log is not None and abs(dt_log - dt) <= 1e-6 * dt
    if same and hold == "zoh":
        return h, None
    out = h
    if hold == "zoh" and dt_log is not None:
        out = out / zoh_factor(w, dt_log)
    if dt is not None:
        out = out * zoh_factor(w, dt)
    note = None
    if dt_log is not None and not same:
        note = (f"the log was identified at {1 / dt_log:g} Hz and the loop runs at "
                + (f"{1 / dt:g} Hz" if dt is not None else "continuously")
                + ": the measured response is taken with the loop's hold in place of the log's (its first-order "
                "factor; the alias terms neglected)")
    return out, note


def _worst(value: float, rng: tuple[float, float], low_is_bad: bool) -> float:
    """The end of a figure's error range the data cannot exclude (the figure itself where its range is unknown)."""
    end = rng[0] if low_is_bad else rng[1]
    return float(end) if not math.isnan(end) else float(value)


def measured_checks(cmp: MeasuredComparison, spec: Any) -> list[Any]:
    """The spec's phase and gain margin limits (and ``ms_max`` when set) judged on the measured response, by the
    worst end of each figure's error range: ``measured_phase_margin_deg`` (>=), ``measured_gain_margin_db`` (>=),
    ``measured_ms`` (<=). A figure not measured (``nan``: its crossing outside the coherent data) does not pass.

    Examples
    --------
    >>> from tuner import Spec
    >>> from tuner.analysis.measured import LoopFigures, MeasuredComparison, measured_checks
    >>> fig = LoopFigures(40.0, 2.0, 9.0, 1.5, (35.0, 44.0), (8.0, 10.0), (1.4, 1.6))
    >>> cmp = MeasuredComparison((1.0, 10.0), 50, fig, fig)
    >>> [(c.name, c.achieved, c.ok) for c in measured_checks(cmp, Spec(phase_margin_min_deg=30))]
    [('measured_phase_margin_deg', 35.0, True), ('measured_gain_margin_db', 8.0, True)]
    """
    from ..spec import Check

    m = cmp.measured
    out = []
    for name, value, rng, limit, low_is_bad in (
            ("measured_phase_margin_deg", m.phase_margin_deg, m.phase_margin_range,
             getattr(spec, "phase_margin_min_deg", None), True),
            ("measured_gain_margin_db", m.gain_margin_db, m.gain_margin_range,
             getattr(spec, "gain_margin_min_db", None), True),
            ("measured_ms", m.ms, m.ms_range, getattr(spec, "ms_max", None), False)):
        if limit is None:
            continue
        got = _worst(value, rng, low_is_bad)
        if math.isnan(got):
            out.append(Check(name, ">=" if low_is_bad else "<=", float(limit), got, False, math.inf))
            continue
        ok = bool(got >= limit) if low_is_bad else bool(got <= limit)
        viol = 0.0 if ok else (abs(got - limit) if math.isfinite(got) else math.inf)
        out.append(Check(name, ">=" if low_is_bad else "<=", float(limit), got, ok, viol))
    return out


def identification_check(ident: Any) -> Any:
    """The check that the identification is rated good or acceptable (``identification_quality``), None for a
    record without a rating."""
    from ..spec import Check

    q = getattr(ident, "quality", None)
    if not isinstance(q, str):
        return None
    ok = q in QUALITY_OK
    return Check(IDENTIFICATION_CHECK, ">=", "acceptable", q, ok, 0.0 if ok else math.inf)


def with_measured(analysis: Any, ident: Any, spec: Any = None) -> Any:
    """``analysis`` (of a controller on ``ident``'s model) with its loop on the measured response (``measured``)
    and the verdict's checks on the airframe appended to its own: :func:`measured_checks` against ``spec`` (default
    ``Spec()``) and :func:`identification_check`. Applied again, it replaces them."""
    from dataclasses import replace

    from ..spec import Spec

    cmp = measured_comparison(ident, analysis)
    own = [c for c in analysis.checks if c.name not in MEASURED_CHECKS and c.name != IDENTIFICATION_CHECK]
    extra = measured_checks(cmp, spec if spec is not None else Spec())
    q = identification_check(ident)
    return replace(analysis, measured=cmp, checks=[*own, *extra, *([q] if q is not None else [])])
