"""Parameter confidence at the optimum: Cramér–Rao bounds and insensitivities (CIFER practice).

With ``A = dr/dtheta`` the exact Jacobian of the fit residuals (``J = sum r^2``) at the optimum,
the residual variance estimated as ``s^2 = J / (m - p)`` (``m`` residuals, ``p`` parameters) and
the Fisher information approximated by ``A^T A / s^2`` (the Gauss–Newton Hessian):

* **Cramér–Rao bound** of parameter ``i``: ``sqrt([(A^T A)^-1]_ii * s^2)``, the standard deviation
  no unbiased estimator can beat, *all other parameters free*;
* **insensitivity**: ``sqrt(s^2 / (A^T A)_ii)``, the same with *the others held fixed* (large
  when the cost hardly changes with the parameter).

Both are given in the parameter's units and in % of its value (for the log-parameterised gain,
frequencies and damping ratios the % is the relative bound directly). Guidelines (Tischler &
Remple): CR bounds within about 20 %, insensitivities within about 10 %.

The fit frequencies are treated as independent, as in CIFER, so the bounds are lower bounds:
with independent errors at the fit points they are calibrated (tests/identify/test_uncertainty.py,
a Monte Carlo: scatter / bound 0.9-1.05), but on flight data, where neighbouring points of the
composite response share errors (gusts, few averages at low frequency), the scatter of the
identified parameters over 12 synthetic flights was 0.7 to 2.7 times the bound
(``bench/identify_cases.py``). Read a 5 % bound as "a few per cent to about 15 %".
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .fit import Problem

__all__ = ["CR_LIMIT_PCT", "INSENSITIVITY_LIMIT_PCT", "ParameterUncertainty", "cramer_rao", "covariance"]

CR_LIMIT_PCT = 20.0
INSENSITIVITY_LIMIT_PCT = 10.0


@dataclass(frozen=True)
class ParameterUncertainty:
    """One parameter: value and 1-sigma bounds (units of the value, and % of it; ``inf`` = not identifiable)."""

    value: float
    cr_bound: float
    cr_bound_pct: float
    insensitivity: float
    insensitivity_pct: float

    @property
    def ok(self) -> bool:
        """Well determined: the Cramer-Rao bound and the insensitivity within the CIFER guidelines."""
        return self.cr_bound_pct <= CR_LIMIT_PCT and self.insensitivity_pct <= INSENSITIVITY_LIMIT_PCT

    def to_dict(self) -> dict[str, Any]:
        """The figures as a dict."""
        return asdict(self)


def covariance(problem: Problem, theta: np.ndarray) -> np.ndarray:
    """The parameters' covariance at ``theta`` (``s^2 (A^T A)^-1``, the Cramér–Rao matrix), in parameter order
    (:meth:`~tuner.identify.model.Structure.names`) and in the parameters' own units (gain, rad/s, damping,
    s): ``D Cov_theta D`` with ``D = diag(|value|)`` for the log-parameters and 1 for the delay, so its
    diagonal is the square of the ``cr_bound`` of :func:`cramer_rao`. ``inf`` everywhere when the
    information matrix is singular."""
    theta = np.asarray(theta, dtype=float)
    A = problem.jacobian(theta)
    r = problem.residuals(theta)
    m, p = A.shape
    s2 = float(r @ r) / (m - p) if m > p else math.inf
    M = A.T @ A
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        try:
            cond = np.linalg.cond(M)
            cov = np.linalg.inv(M) * s2 if np.isfinite(cond) and cond < 1e14 else np.full((p, p), np.inf)
        except np.linalg.LinAlgError:
            cov = np.full((p, p), np.inf)
        values = problem.model(theta).values()
        d = np.array([1.0 if n == "delay_s" else abs(values[n]) for n in problem.structure.names()])
        return cov * np.outer(d, d)


def cramer_rao(problem: Problem, theta: np.ndarray) -> dict[str, ParameterUncertainty]:
    """Bounds for every parameter of ``problem`` at ``theta`` (log-parameters, then the delay if free)."""
    theta = np.asarray(theta, dtype=float)
    A = problem.jacobian(theta)
    r = problem.residuals(theta)
    m, p = A.shape
    names = problem.structure.names()
    values = problem.model(theta).values()
    s2 = float(r @ r) / (m - p) if m > p else math.inf
    M = A.T @ A
    diag = np.diag(M)
    with np.errstate(divide="ignore", invalid="ignore"):
        try:
            cond = np.linalg.cond(M)
            cov = np.linalg.inv(M) * s2 if np.isfinite(cond) and cond < 1e14 else np.full((p, p), np.inf)
        except np.linalg.LinAlgError:
            cov = np.full((p, p), np.inf)
        sd = np.sqrt(np.abs(np.diag(cov)))
        ins = np.sqrt(s2 / diag)
    out: dict[str, ParameterUncertainty] = {}
    for i, name in enumerate(names):
        v = values[name]
        sd_i = float(sd[i]) if np.isfinite(sd[i]) else math.inf
        ins_i = float(ins[i]) if np.isfinite(ins[i]) else math.inf
        if name == "delay_s":  # linear parameter: absolute bounds, % of the delay
            cr, ci = sd_i, ins_i
            cr_pct = 100.0 * cr / abs(v) if v else math.inf
            ci_pct = 100.0 * ci / abs(v) if v else math.inf
        else:  # log-parameter: d(value) = |value| d(log value)
            cr, ci = abs(v) * sd_i, abs(v) * ins_i
            cr_pct, ci_pct = 100.0 * sd_i, 100.0 * ins_i
        out[name] = ParameterUncertainty(value=v, cr_bound=cr, cr_bound_pct=cr_pct, insensitivity=ci,
                                         insensitivity_pct=ci_pct)
    return out
