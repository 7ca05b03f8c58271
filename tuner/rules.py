"""The default design limits that act on a structure's parameters (not on the loop's response).

A bottom-layer module (structures and specs only; ``tuner.optimize.rules`` re-exports it, the name it had).

The derivative-filter rule (``Spec.filter_n_max``): ``N = Td/Tf = Kd / (Kp Tf) <= N_max`` for the structures
with a filtered derivative (:func:`has_filter_rule`). The same function serves numbers (the
verifier and the batched search) and CasADi symbols (the NLP); the verifier's check is :func:`filter_check`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .controllers import Structure
from .spec import Check, Spec
from .tolerances import LIMIT_RTOL

__all__ = ["filter_n", "filter_n_batch", "filter_check", "applies", "has_filter_rule", "FILTERED", "nyquist_check",
           "checks"]

FILTERED = ("pd", "pid", "pid2", "pid_mf2", "pidf2")  # structures with a derivative filter Tf


def has_filter_rule(st: Structure) -> bool:
    """Whether the derivative-filter rule N = Td/Tf <= filter_n_max applies to ``st``."""
    return st.name in FILTERED and {"Kp", "Kd", "Tf"} <= set(st.params)


def applies(st: Structure, spec: Spec) -> bool:
    """Whether the derivative-filter rule constrains ``st`` under ``spec``."""
    return spec.filter_n_max is not None and has_filter_rule(st)


def _idx(st: Structure) -> tuple[int, int, int]:
    p = st.params
    return p.index("Kp"), p.index("Kd"), p.index("Tf")


def filter_n(st: Structure, x: Any) -> float:
    """``N = |Kd| / (|Kp| Tf)`` of parameters ``x`` (inf when Kp or Tf is 0 and Kd is not; 0 without D)."""
    ip, idd, it = _idx(st)
    kp, kd, tf = abs(float(x[ip])), abs(float(x[idd])), float(x[it])
    if kd == 0:
        return 0.0
    return kd / (kp * tf) if kp > 0 and tf > 0 else math.inf


def filter_n_batch(st: Structure, X: np.ndarray) -> np.ndarray:
    """:func:`filter_n` of each row of ``X``."""
    ip, idd, it = _idx(st)
    kp, kd, tf = np.abs(X[:, ip]), np.abs(X[:, idd]), X[:, it]
    with np.errstate(divide="ignore", invalid="ignore"):
        n = np.where(kd == 0, 0.0, kd / (kp * tf))
    return np.where(np.isnan(n), np.inf, n)


def filter_check(st: Structure, spec: Spec, x: Any) -> Check:
    """The verifier's check of the rule for parameters ``x``."""
    n, lim = filter_n(st, x), float(spec.filter_n_max)
    ok = bool(n <= lim * (1 + LIMIT_RTOL))
    return Check("filter_n", "<=", lim, n, ok, 0.0 if ok else (n - lim if math.isfinite(n) else math.inf))


def nyquist_check(st: Structure, spec: Spec, x: Any, dt: float | None) -> Check | None:
    """The verifier's check of ``Spec.filter_nyquist`` (Tf >= dt/pi at a sample time), or None where it does not
    apply (continuous, no filter, lifted). The search keeps it as its box's floor; the verifier checks it anyway."""
    if not (spec.filter_nyquist and dt is not None and "Tf" in st.params):
        return None
    tf, lim = float(x[st.params.index("Tf")]), dt / math.pi
    ok = bool(tf >= lim * (1 - LIMIT_RTOL))
    return Check("filter_tf_s", ">=", lim, tf, ok, 0.0 if ok else lim - tf)


def checks(st: Structure, spec: Spec, x: Any, dt: float | None) -> list[Check]:
    """Every check of the rules on the parameters that applies to ``st`` under ``spec``."""
    out = [filter_check(st, spec, x)] if applies(st, spec) else []
    ny = nyquist_check(st, spec, x, dt)
    return out + ([ny] if ny is not None else [])
