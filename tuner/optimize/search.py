"""Everything Optuna: the seeded global stage that finds the basins.

The sampler and the storage are injectable (in-memory TPE by default; a storage
URL such as ``sqlite:///study.db`` or ``postgresql://...`` is accepted). Trials
are scored by the verifier through :class:`tuner.optimize.scoring.Evaluator`; the best
few *distinct* candidates (by distance in the normalised coordinates) are
handed to the local stage.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import optuna

from .scoring import UNSTABLE, Evaluator
from .space import Space

UNSCORABLE = 10 * UNSTABLE

__all__ = ["GlobalResult", "global_search", "default_sampler"]

log = logging.getLogger(__name__)
optuna.logging.set_verbosity(optuna.logging.WARNING)


@dataclass(frozen=True)
class GlobalResult:
    top: list[tuple[float, np.ndarray]]  # (score, coordinates), best first, distinct
    best_score: float
    n_evals: int
    best_enqueued: tuple[float, np.ndarray] | None = None  # the best of the plant-based starts


def default_sampler(seed: int, n_params: int) -> optuna.samplers.BaseSampler:
    return optuna.samplers.TPESampler(
        seed=seed, multivariate=True, group=False, n_startup_trials=max(10, 4 * n_params),
        constant_liar=False,
    )


def global_search(
    ev: Evaluator, space: Space, *, seed: int, n_trials: int, deadline: float | None = None,
    sampler: Any = None, storage: Any = None, study_name: str | None = None, x0: Sequence[np.ndarray] = (),
    top_k: int = 3,
) -> GlobalResult:
    """Seeded search over ``space``; returns the best ``top_k`` distinct candidates."""
    sampler = sampler or default_sampler(seed, len(space.names))
    study = optuna.create_study(direction="minimize", sampler=sampler, storage=storage,
                                study_name=study_name, load_if_exists=study_name is not None)
    dists = {n: optuna.distributions.FloatDistribution(float(lo), float(hi))
             for n, lo, hi in zip(space.names, space.lo, space.hi)}
    for v in x0:
        study.enqueue_trial({n: float(np.clip(x, lo, hi)) for n, x, lo, hi in
                             zip(space.names, v, space.lo, space.hi)}, skip_if_exists=True)
    scored: list[tuple[float, np.ndarray]] = []
    for i in range(n_trials):
        # the enqueued plant-based starts are always scored, so even a tiny budget has candidates
        if i >= len(x0) and deadline is not None and time.perf_counter() > deadline:
            break
        trial = study.ask(dists)
        v = np.array([trial.params[n] for n in space.names])
        s = ev.score(space.params(v)).score
        s = s if math.isfinite(s) else UNSCORABLE
        study.tell(trial, s)
        scored.append((s, v))
    n_run = len(scored)
    enq = sorted(scored[: len(x0)], key=lambda sv: sv[0])
    if storage is not None:  # a shared storage: every completed trial of the study counts (ours included)
        scored = [(float(t.value), np.array([t.params[n] for n in space.names]))
                  for t in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
                  if all(n in t.params for n in space.names)]
    scored.sort(key=lambda sv: sv[0])
    return GlobalResult(top=_distinct(scored, space, top_k), best_score=scored[0][0] if scored else math.inf,
                        n_evals=n_run, best_enqueued=enq[0] if enq else None)


def _distinct(scored: list[tuple[float, np.ndarray]], space: Space, k: int) -> list[tuple[float, np.ndarray]]:
    span = np.maximum(space.hi - space.lo, 1e-12)
    out: list[tuple[float, np.ndarray]] = []
    for s, v in scored:
        if all(np.linalg.norm((v - w) / span) > 0.05 for _, w in out):
            out.append((s, v))
        if len(out) >= k:
            break
    return out
