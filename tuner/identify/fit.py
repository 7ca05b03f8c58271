"""Fitting the parametric model to a frequency response: CIFER's cost, multi-start least squares.

The cost over ``n`` frequencies (Tischler & Remple, ch. 11; CIFER's transfer-function fit)::

    J = (20/n) sum_i W_gamma,i [W_g (|T_hat|_dB - |T|_dB)^2 + W_p (angle T_hat - angle T)^2]

magnitudes in dB, phases in degrees (the difference wrapped to +-180), ``W_g = 1``,
``W_p = 0.01745`` and ``W_gamma = [1.58 (1 - exp(-gamma^2))]^2``. ``J`` is a sum of squares of
residuals ``r`` (:meth:`Problem.residuals`, with their exact derivatives), so
:func:`scipy.optimize.least_squares` (trust-region reflective, bounded) minimises it exactly.
Several starts (section frequencies spread over the band, then seeded random ones; for each the
best gain in closed form and a delay from the phase slope) guard against local minima.

A delay restricted to whole multiples of ``delay_step`` (the sample time of the loop the model
is for) is found by fitting it freely first, then re-fitting with each nearby multiple fixed.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import IdentificationError
from ..tolerances import SAMPLE_COUNT_TOL
from .model import Model, Structure, section_kinds

__all__ = ["W_G", "W_P", "FitOutcome", "Problem", "coherence_weight", "cost_terms", "fit_model"]

log = logging.getLogger(__name__)

W_G = 1.0
W_P = 0.01745


def coherence_weight(coherence: np.ndarray) -> np.ndarray:
    """CIFER's ``W_gamma = [1.58 (1 - exp(-gamma^2))]^2`` (``coherence`` is gamma^2)."""
    return (1.58 * (1.0 - np.exp(-np.asarray(coherence, dtype=float)))) ** 2


def _wrap_deg(x: np.ndarray) -> np.ndarray:
    return (np.asarray(x) + 180.0) % 360.0 - 180.0


def cost_terms(mag_err_db: np.ndarray, phase_err_deg: np.ndarray, coherence: np.ndarray) -> np.ndarray:
    """Per-frequency costs ``20 W_gamma (W_g dmag^2 + W_p dphase^2)``; ``J`` is their mean."""
    return 20.0 * coherence_weight(coherence) * (W_G * mag_err_db ** 2 + W_P * _wrap_deg(phase_err_deg) ** 2)


@dataclass(frozen=True, eq=False)
class Problem:
    """Data at the fit frequencies and the model family; the residuals ``r`` with ``sum(r^2) = J``."""

    w: np.ndarray
    mag_db: np.ndarray
    phase_deg: np.ndarray  # wrapped, as measured
    coherence: np.ndarray
    structure: Structure
    sign: float = 1.0
    fixed_delay_s: float = 0.0

    @property
    def _scale(self) -> tuple[np.ndarray, np.ndarray]:
        c = 20.0 / self.w.size * coherence_weight(self.coherence)
        return np.sqrt(c * W_G), np.sqrt(c * W_P)

    def model(self, theta: np.ndarray) -> Model:
        """The model at parameters ``theta`` (this problem's structure, sign and fixed delay)."""
        return Model(self.structure, np.asarray(theta, dtype=float), sign=self.sign, fixed_delay_s=self.fixed_delay_s)

    def errors(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Model minus data: magnitude (dB) and wrapped phase (deg)."""
        mag, ph = self.model(theta).bode(self.w)
        return mag - self.mag_db, _wrap_deg(ph - self.phase_deg)

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        """The weighted residuals (magnitude, then phase) whose sum of squares is CIFER's cost ``J``."""
        dm, dp = self.errors(theta)
        a, b = self._scale
        return np.concatenate([a * dm, b * dp])

    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        """The Jacobian of :meth:`residuals` with respect to ``theta`` (analytic)."""
        _, _, jm, jp = self.model(theta).bode_jacobian(self.w)
        a, b = self._scale
        return np.vstack([a[:, None] * jm, b[:, None] * jp])

    def cost(self, theta: np.ndarray) -> float:
        """CIFER's cost ``J`` at ``theta``: the sum of squares of :meth:`residuals`."""
        r = self.residuals(theta)
        return float(r @ r)


@dataclass(frozen=True, eq=False)
class FitOutcome:
    """The best model found, its cost ``J`` and the problem it solves (for the uncertainty)."""

    model: Model
    cost: float
    problem: Problem
    starts: int
    delay_candidates_s: tuple[float, ...] = ()


def _bounds(st: Structure, band: tuple[float, float], k0: float, tau_max: float) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = [k0 - 12.0], [k0 + 12.0]
    for n in (st.poles, st.zeros):
        for kind in section_kinds(n):
            lo.append(math.log(band[0] / 20.0))
            hi.append(math.log(band[1] * 20.0))
            if kind == "quad":
                lo.append(math.log(0.01))
                hi.append(math.log(10.0))
    if st.free_delay:
        lo.append(0.0)
        hi.append(tau_max)
    return np.array(lo), np.array(hi)


def _shape_starts(st: Structure, band: tuple[float, float], n_starts: int,
                  rng: np.random.Generator) -> list[list[float]]:
    """Section parameters (log wn, log zeta, log a; poles then zeros) for each start."""
    kinds = section_kinds(st.poles) + section_kinds(st.zeros)
    lo, hi = math.log(band[0]), math.log(band[1])
    out: list[list[float]] = []

    def one(freqs: Sequence[float], zeta: float) -> list[float]:
        th: list[float] = []
        for kind, f in zip(kinds, freqs):
            th.append(f)
            if kind == "quad":
                th.append(math.log(zeta))
        return th

    n_sec = len(kinds)
    if n_sec == 0:
        return [[]]
    for zeta in (0.7, 0.3, 1.5):  # spread over the band, in order
        out.append(one([lo + (hi - lo) * (i + 0.5) / n_sec for i in range(n_sec)], zeta))
    for c in np.linspace(lo, hi, 5):  # everything near one frequency
        for zeta in (0.3, 1.0):
            out.append(one([c] * n_sec, zeta))
    while len(out) < n_starts:
        freqs = rng.uniform(lo - 1.0, hi + 1.0, n_sec)
        out.append(one(list(freqs), float(np.exp(rng.uniform(math.log(0.1), math.log(2.0))))))
    return out[:max(n_starts, 1)]


def _complete_start(prob_free: Problem, shape: list[float], tau_max: float) -> tuple[np.ndarray, float]:
    """A start for the given section parameters: the gain's sign and log-magnitude in closed form,
    the delay from the slope of the remaining phase."""
    st = prob_free.structure
    theta = np.array([0.0] + shape + ([0.0] if st.free_delay else []))
    shape_model = Model(st, theta, sign=1.0, fixed_delay_s=prob_free.fixed_delay_s)
    mag, ph = shape_model.bode(prob_free.w)
    wgt = coherence_weight(prob_free.coherence)
    theta[0] = float(np.sum(wgt * (prob_free.mag_db - mag)) / np.sum(wgt)) / (20.0 / math.log(10.0))
    rest = _wrap_deg(prob_free.phase_deg - ph)
    sign = -1.0 if abs(rest[0]) > 90.0 else 1.0
    if sign < 0:
        rest = _wrap_deg(rest - 180.0)
    if st.free_delay:
        lag = -np.radians(np.unwrap(rest, period=360.0))  # rad, what a delay would have to explain
        tau = float(np.sum(wgt * prob_free.w * lag) / np.sum(wgt * prob_free.w ** 2))
        theta[-1] = min(max(tau, 0.0), tau_max)
    return theta, sign


def _solve(prob: Problem, theta0: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    from scipy.optimize import least_squares

    x0 = np.clip(theta0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    return least_squares(prob.residuals, x0, jac=prob.jacobian, bounds=(lo, hi), method="trf",
                         x_scale="jac", ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=400)


def fit_model(w: np.ndarray, h: np.ndarray, coherence: np.ndarray, *, poles: int, zeros: int,
              delay: str | float | None, delay_step: float | None, band: tuple[float, float], tau_max: float,
              n_starts: int = 20, seed: int = 0) -> FitOutcome:
    """Fit ``poles``/``zeros`` sections (and the delay: ``"auto"``, a fixed value, or ``None``) to ``h``."""
    free = delay == "auto"
    fixed = 0.0 if free or delay is None else float(delay)
    st = Structure(poles=poles, zeros=zeros, free_delay=free)
    mag_db, ph = 20.0 * np.log10(np.abs(h)), np.degrees(np.angle(h))
    base = Problem(w=w, mag_db=mag_db, phase_deg=ph, coherence=coherence, structure=st, fixed_delay_s=fixed)
    rng = np.random.default_rng(seed)
    best = None
    n_tried = 0
    for shape in _shape_starts(st, band, n_starts, rng):
        theta0, sign = _complete_start(base, shape, tau_max)
        prob = Problem(w=w, mag_db=mag_db, phase_deg=ph, coherence=coherence, structure=st, sign=sign,
                       fixed_delay_s=fixed)
        lo, hi = _bounds(st, band, theta0[0], tau_max)
        try:
            r = _solve(prob, theta0, lo, hi)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as e:  # a start that fails is skipped
            log.debug("start failed: %s", e)
            continue
        n_tried += 1
        cost = prob.cost(r.x)
        if math.isfinite(cost) and (best is None or cost < best[0]):
            best = (cost, r.x, prob, lo, hi)
    if best is None:
        raise IdentificationError("the model fit failed from every start (no finite cost); check the data "
                                  "and the numbers of poles and zeros")
    cost, x, prob, lo, hi = best
    if not (free and delay_step):
        return FitOutcome(model=prob.model(x), cost=cost, problem=prob, starts=n_tried)
    return _whole_samples(prob, x, lo, hi, step=float(delay_step), tau_max=tau_max, starts=n_tried)


def _whole_samples(prob: Problem, x: np.ndarray, lo: np.ndarray, hi: np.ndarray, *, step: float, tau_max: float,
                   starts: int) -> FitOutcome:
    """Re-fit with the delay fixed at the whole multiples of ``step`` around the free optimum."""
    tau = float(x[-1])
    k_max = math.floor(tau_max / step + SAMPLE_COUNT_TOL)
    ks = sorted({k for k in range(math.floor(tau / step) - 1, math.ceil(tau / step) + 2) if 0 <= k <= k_max}
                or {0})
    st = Structure(poles=prob.structure.poles, zeros=prob.structure.zeros, free_delay=False)
    best = None
    for k in ks:
        p = Problem(w=prob.w, mag_db=prob.mag_db, phase_deg=prob.phase_deg, coherence=prob.coherence, structure=st,
                    sign=prob.sign, fixed_delay_s=k * step)
        r = _solve(p, x[:-1], lo[:-1], hi[:-1])
        cost = p.cost(r.x)
        if best is None or cost < best[0]:
            best = (cost, r.x, p)
    cost, xk, p = best
    return FitOutcome(model=p.model(xk), cost=cost, problem=p, starts=starts,
                      delay_candidates_s=tuple(k * step for k in ks))
