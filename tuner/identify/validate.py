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
  rms error in output units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .data import Record
from .model import Model

__all__ = ["THEIL_LIMIT", "Validation", "simulate", "validate"]

THEIL_LIMIT = 0.3
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

    @property
    def fit_pct(self) -> float:
        """The fit, %: ``100 (1 - NRMSE)``."""
        return 100.0 * (1.0 - self.nrmse)

    @property
    def ok(self) -> bool:
        """The held-out check passes: Theil's inequality coefficient within the limit."""
        return self.theil_u <= THEIL_LIMIT

    def to_dict(self) -> dict[str, Any]:
        """The figures and the series (measured and simulated output) as a dict."""
        return {"t_start_s": self.t_start_s, "duration_s": self.duration_s, "nrmse": self.nrmse,
                "fit_pct": self.fit_pct, "theil_u": self.theil_u, "rms_error": self.rms_error, "bias": self.bias,
                "drift_per_s": self.drift_per_s, "theil_limit": THEIL_LIMIT,
                "series": {"t": self.t.tolist(), "measured": self.measured.tolist(), "model": self.model.tolist()}}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Validation:
        """The inverse of :meth:`to_dict`."""
        s = d.get("series") or {"t": [], "measured": [], "model": []}
        return cls(t_start_s=float(d["t_start_s"]), duration_s=float(d["duration_s"]), nrmse=float(d["nrmse"]),
                   theil_u=float(d["theil_u"]), rms_error=float(d["rms_error"]), bias=float(d["bias"]),
                   drift_per_s=float(d["drift_per_s"]), t=np.asarray(s["t"], dtype=float),
                   measured=np.asarray(s["measured"], dtype=float), model=np.asarray(s["model"], dtype=float))


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
    k = math.floor(model.delay_s / dt + 1e-9)
    frac = model.delay_s - k * dt
    uk = np.concatenate([np.zeros(k), u[: u.size - k]]) if k else u
    n = A.shape[0]
    if n == 0:
        return D[0, 0] * (uk if frac <= 1e-12 * dt else np.concatenate([[0.0], uk[:-1]]))
    if frac <= 1e-12 * dt:
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


def validate(model: Model, rec: Record, start: int, *, u_trim: float = 0.0) -> Validation | None:
    """Compare ``model`` with ``rec`` from sample ``start`` to the end (``None`` if nothing is left)."""
    n = rec.n
    if start >= n - 8:
        return None
    first = max(0, start - _warmup_samples(model, rec.dt))
    y_model = simulate(model, rec.u[first:] - u_trim, rec.dt)[start - first:]
    y = rec.y[start:]
    t = rec.t0 + rec.dt * np.arange(start, n)
    tc = t - t.mean()
    X = np.column_stack([np.ones_like(tc), tc])  # bias and drift of the measurement
    coef, *_ = np.linalg.lstsq(X, y - y_model, rcond=None)
    y_p = y - X @ coef
    e = y_p - y_model
    ref = float(np.mean(y_model))
    den = float(np.linalg.norm(y_p - np.mean(y_p)))
    nrmse = float(np.linalg.norm(e) / den) if den > 0 else math.inf
    rms_e = float(np.sqrt(np.mean(e ** 2)))
    scale = float(np.sqrt(np.mean((y_p - ref) ** 2)) + np.sqrt(np.mean((y_model - ref) ** 2)))
    theil = rms_e / scale if scale > 0 else math.inf
    step = max(1, math.ceil(y.size / _MAX_SERIES))
    return Validation(t_start_s=float(t[0]), duration_s=float(y.size * rec.dt), nrmse=nrmse, theil_u=theil,
                      rms_error=rms_e, bias=float(coef[0]), drift_per_s=float(coef[1]), t=t[::step],
                      measured=y_p[::step], model=y_model[::step])
