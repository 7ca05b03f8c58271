"""Time-domain check on data the fit has not seen (CIFER's VERIFY, in spirit).

The fitted model, delay included, is driven by the measured input and its output compared with
the measured one over the held-out part of the record:

* the model is simulated exactly for a piecewise-constant (held) input: the sections in state
  space (:meth:`~tuner.identify.model.Model.state_space`), discretised at the log's sample time
  with the delay split into whole samples and a fraction (the modified z-transform of a delayed
  zero-order hold, Åström & Wittenmark), from rest, starting early enough before the held-out
  part for the start to be forgotten (twenty time constants of the slowest pole: e^-20);
* an output bias and a linear drift over the held-out part are estimated by least squares
  (sensor offsets are not dynamics), as VERIFY estimates its bias and reference shift;
* reported: ``nrmse = ||y - y_model|| / ||y - mean(y)||`` (0 = perfect, 1 = no better than the
  mean; ``fit_pct = 100 (1 - nrmse)`` is MATLAB's "fit"), Theil's inequality coefficient
  ``rms(y - y_model) / (rms(y) + rms(y_model))`` (0 = perfect; guideline <= 0.25–0.3) and the
  rms error in output units;
* judged against the **noise floor** the check can see: the rms of the output no linear model of
  the input explains (:func:`~tuner.identify.spectral.unexplained_rms`, from the residual
  spectrum ``G_yy (1 - gamma^2)``), i.e. the rms error a perfect model would have, and the Theil
  coefficient noise alone would give. On a gusty or noisy record Theil exceeds 0.3 even for the
  true model; the check is then ``"noise-limited"`` when the rms error is within
  :data:`NOISE_RATIO_LIMIT` times the floor (the model's own error at most about the noise). On a
  quiet record a model can meet Theil <= 0.3 with an error several times the floor: ``"fair"``.
  Verdicts: ``"good"`` (Theil <= 0.3, error within 1.5 x the floor), ``"fair"`` (Theil <= 0.3, error
  above), ``"noise-limited"`` (Theil above, error within), ``"poor"`` (both above).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..tolerances import SAMPLE_COUNT_TOL, SAMPLE_FRACTION_TOL
from .data import Record
from .model import Model

__all__ = ["NOISE_RATIO_LIMIT", "SOURCES", "THEIL_LIMIT", "Validation", "simulate", "validate", "validate_segments"]

THEIL_LIMIT = 0.3
NOISE_RATIO_LIMIT = 1.5  # rms error / noise floor: the model's own error at most ~1.1 times the noise
SOURCES = {"holdout": "the held-out end of the record", "verify": "the verification record",
           "fit": "the fitted record (no independent data)"}
_MAX_SERIES = 1000  # points kept for the plot


@dataclass(frozen=True, eq=False)
class Validation:
    """The held-out comparison; ``t``, ``measured``, ``model`` are decimated for plotting."""

    t_start_s: float
    duration_s: float
    nrmse: float
    theil_u: float
    rms_error: float
    bias: float
    drift_per_s: float
    t: np.ndarray = field(repr=False)
    measured: np.ndarray = field(repr=False)
    model: np.ndarray = field(repr=False)
    noise_rms: float = math.nan  # the noise floor: rms error of a perfect model (nan: unknown)
    source: str = "holdout"  # "holdout", "verify" or "fit" (see SOURCES)
    theil_scale: float = math.nan  # the Theil denominator rms(y) + rms(y_model)

    @property
    def fit_pct(self) -> float:
        """The fit, %: ``100 (1 - NRMSE)``."""
        return 100.0 * (1.0 - self.nrmse)

    @property
    def noise_ratio(self) -> float:
        """rms error / noise floor (about 1 for a model that explains all the input can explain)."""
        return self.rms_error / self.noise_rms if self.noise_rms > 0 else math.nan

    @property
    def noise_theil(self) -> float:
        """The Theil coefficient the noise floor alone gives (a perfect model's)."""
        return self.noise_rms / self.theil_scale if self.theil_scale > 0 else math.nan

    @property
    def verdict(self) -> str:
        """``"good"`` (Theil <= 0.3 and the rms error within 1.5 times the noise floor), ``"fair"``
        (Theil <= 0.3, the error above: the data show what the model misses), ``"noise-limited"``
        (Theil above 0.3, the error within: noise, not the model) or ``"poor"`` (both above). With no
        floor known, Theil alone: ``"good"`` or ``"poor"``."""
        within = self.noise_ratio <= NOISE_RATIO_LIMIT  # False for nan
        if self.theil_u <= THEIL_LIMIT:
            return "fair" if math.isfinite(self.noise_ratio) and not within else "good"
        return "noise-limited" if within else "poor"

    @property
    def ok(self) -> bool:
        """The check passes: its verdict (Theil beside the noise floor) is not poor."""
        return self.verdict != "poor"

    def describe(self) -> str:
        """One line: what the check ran on, Theil, the fit, the error beside the noise floor, the verdict."""
        s = f"on {SOURCES.get(self.source, self.source)}"
        if self.source != "fit" or self.t_start_s:
            s += f" ({self.t_start_s:.4g}-{self.t_start_s + self.duration_s:.4g} s)"
        s += f": Theil {self.theil_u:.3g} (<= {THEIL_LIMIT:g}), fit {self.fit_pct:.3g} %"
        if math.isfinite(self.noise_ratio):
            s += (f", rms error {self.rms_error:.3g} = {self.noise_ratio:.2f} x the noise floor {self.noise_rms:.3g} "
                  f"(noise alone: Theil {self.noise_theil:.2f})")
        return f"{s}: {self.verdict}"

    def to_dict(self) -> dict[str, Any]:
        """The figures and the series (measured and simulated output) as a dict."""
        return {"t_start_s": self.t_start_s, "duration_s": self.duration_s, "nrmse": self.nrmse,
                "fit_pct": self.fit_pct, "theil_u": self.theil_u, "rms_error": self.rms_error, "bias": self.bias,
                "drift_per_s": self.drift_per_s, "theil_limit": THEIL_LIMIT,
                "source": self.source, "noise_rms": self.noise_rms, "noise_ratio": self.noise_ratio,
                "noise_ratio_limit": NOISE_RATIO_LIMIT, "noise_theil": self.noise_theil,
                "theil_scale": self.theil_scale, "verdict": self.verdict,
                "series": {"t": self.t.tolist(), "measured": self.measured.tolist(), "model": self.model.tolist()}}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Validation:
        """The inverse of :meth:`to_dict`."""
        s = d.get("series") or {"t": [], "measured": [], "model": []}
        return cls(t_start_s=float(d["t_start_s"]), duration_s=float(d["duration_s"]), nrmse=float(d["nrmse"]),
                   theil_u=float(d["theil_u"]), rms_error=float(d["rms_error"]), bias=float(d["bias"]),
                   drift_per_s=float(d["drift_per_s"]), t=np.asarray(s["t"], dtype=float),
                   measured=np.asarray(s["measured"], dtype=float), model=np.asarray(s["model"], dtype=float),
                   noise_rms=float(d.get("noise_rms", math.nan)), source=str(d.get("source", "holdout")),
                   theil_scale=float(d.get("theil_scale", math.nan)))


def _held_integral(A: np.ndarray, B: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """``exp(A t)`` and ``int_0^t exp(A s) ds B``."""
    from scipy.linalg import expm

    n, m = A.shape[0], B.shape[1]
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = expm(M * t)
    return E[:n, :n], E[:n, n:]


def simulate(model: Model, u: np.ndarray, dt: float) -> np.ndarray:
    """Output of ``model`` (delay included) at the samples, for ``u`` held between samples, from rest."""
    from scipy.signal import dlsim

    A, B, C, D = model.state_space()
    u = np.asarray(u, dtype=float)
    k = math.floor(model.delay_s / dt + SAMPLE_COUNT_TOL)
    frac = model.delay_s - k * dt
    if k >= u.size:  # the delay outlasts the record: nothing of the input reaches the output in it
        return np.zeros(u.size)
    uk = np.concatenate([np.zeros(k), u[: u.size - k]]) if k else u
    n = A.shape[0]
    if n == 0:
        return D[0, 0] * (uk if frac <= SAMPLE_FRACTION_TOL * dt else np.concatenate([[0.0], uk[:-1]]))
    if frac <= SAMPLE_FRACTION_TOL * dt:
        phi, gam = _held_integral(A, B, dt)
        sys = (phi, gam, C, D, dt)
    else:  # u(t - tau) takes u_k[j-1] for frac s after each sample, then u_k[j]
        phi, g0 = _held_integral(A, B, dt - frac)
        e_rest, g1 = _held_integral(A, B, frac)
        g1 = phi @ g1
        phi = phi @ e_rest
        Az = np.block([[phi, g1], [np.zeros((1, n)), np.zeros((1, 1))]])
        Bz = np.vstack([g0, np.ones((1, 1))])
        Cz = np.hstack([C, D])
        sys = (Az, Bz, Cz, np.zeros((1, 1)), dt)
    _, y, _ = dlsim(sys, uk)
    return np.asarray(y).ravel()


def _warmup_samples(model: Model, dt: float) -> int:
    A = model.state_space()[0]
    if A.size == 0:
        return math.ceil(model.delay_s / dt) + 1
    sigma = float(np.min(np.abs(np.linalg.eigvals(A).real)))
    return math.ceil((20.0 / max(sigma, 1e-12) + model.delay_s) / dt) + 1


def _segment(model: Model, rec: Record, start: int, u_trim: float) -> tuple[np.ndarray, ...]:
    """Times, measured output less its fitted bias and drift, model output, and the bias/drift."""
    first = max(0, start - _warmup_samples(model, rec.dt))
    y_model = simulate(model, rec.u[first:] - u_trim, rec.dt)[start - first:]
    y = rec.y[start:]
    t = rec.t0 + rec.dt * np.arange(start, rec.n)
    tc = t - t.mean()
    X = np.column_stack([np.ones_like(tc), tc])  # bias and drift of the measurement
    coef, *_ = np.linalg.lstsq(X, y - y_model, rcond=None)
    return t, y - X @ coef, y_model, coef


def validate_segments(model: Model, segments: list[tuple[Record, int, float]], *, noise_rms: float = math.nan,
                      source: str = "holdout") -> Validation | None:
    """Compare ``model`` with each ``(record, start, u_trim)`` from ``start`` to its end (a bias and drift
    fitted per segment), the metrics over all of them; ``None`` if nothing is left."""
    parts = [_segment(model, rec, start, u_trim) for rec, start, u_trim in segments if start < rec.n - 8]
    if not parts:
        return None
    t, y_p, y_model = (np.concatenate([p[i] for p in parts]) for i in range(3))
    coef = parts[0][3]
    e = y_p - y_model
    ref = float(np.mean(y_model))
    den = float(np.linalg.norm(y_p - np.mean(y_p)))
    nrmse = float(np.linalg.norm(e) / den) if den > 0 else math.inf
    rms_e = float(np.sqrt(np.mean(e ** 2)))
    scale = float(np.sqrt(np.mean((y_p - ref) ** 2)) + np.sqrt(np.mean((y_model - ref) ** 2)))
    theil = rms_e / scale if scale > 0 else math.inf
    step = max(1, math.ceil(t.size / _MAX_SERIES))
    dt = segments[0][0].dt
    # the series for the plot: each segment decimated, several laid end to end with a break (nan) between
    series, shift = [], 0.0
    for p in parts:
        ts = p[0] - p[0][0] + shift if series else p[0]
        series.append(np.column_stack([ts[::step], p[1][::step], p[2][::step]]))
        series.append(np.full((1, 3), np.nan))
        shift = float(ts[-1]) + dt
    ser = np.vstack(series[:-1])
    return Validation(t_start_s=float(t[0]), duration_s=float(t.size * dt), nrmse=nrmse, theil_u=theil,
                      rms_error=rms_e, bias=float(coef[0]), drift_per_s=float(coef[1]), t=ser[:, 0],
                      measured=ser[:, 1], model=ser[:, 2], noise_rms=float(noise_rms), source=source,
                      theil_scale=scale)


def validate(model: Model, rec: Record, start: int, *, u_trim: float = 0.0, noise_rms: float = math.nan,
             source: str = "holdout") -> Validation | None:
    """Compare ``model`` with ``rec`` from sample ``start`` to the end (``None`` if nothing is left)."""
    return validate_segments(model, [(rec, start, u_trim)], noise_rms=noise_rms, source=source)
