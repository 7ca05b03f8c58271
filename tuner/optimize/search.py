"""Everything Optuna: the seeded global search, in batches.

A :class:`SeededSearch` wraps one Optuna study over the structure's coordinates (the sampler and the
storage are injectable: seeded TPE in memory by default; a storage URL such as ``sqlite:///study.db``
or ``postgresql://...`` is accepted). Points scored elsewhere (the designed starts, the local stage's
solutions) are told to the study in bulk, so the sampler models everything the tune has seen; new
points are asked in batches and scored by the batched verifier
(:class:`tuner.optimize.batch.BatchEvaluator`) in one call.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .space import Space

__all__ = ["SeededSearch", "default_sampler", "UNSCORABLE"]

log = logging.getLogger(__name__)


def _optuna() -> Any:
    """Optuna, imported on first use (its import, 0.06 s of CPU, is not paid by a tune that never asks it: the
    default effort's), its logging at WARNING."""
    import optuna

    if not _QUIET:
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        _QUIET.append(True)
    return optuna


_QUIET: list[bool] = []

UNSCORABLE = 1e6  # the score told for a point that could not be scored at all


def default_sampler(seed: int, n_params: int) -> Any:
    """The default Optuna sampler: a seeded multivariate TPE (``max(10, 4 n_params)`` start-up trials)."""
    return _optuna().samplers.TPESampler(
        seed=seed, multivariate=True, group=False, n_startup_trials=max(10, 4 * n_params), constant_liar=False,
    )


class SeededSearch:
    """The Optuna side of a tune: ``tell`` scored points in bulk, ``ask`` new ones in batches."""

    def __init__(self, space: Space, *, seed: int, sampler: Any = None, storage: Any = None,
                 study_name: str | None = None) -> None:
        optuna = _optuna()
        self.space = space
        self.sampler = sampler or default_sampler(seed, len(space.names))
        self.study = optuna.create_study(direction="minimize", sampler=self.sampler, storage=storage,
                                         study_name=study_name, load_if_exists=study_name is not None)
        self.dists = {n: optuna.distributions.FloatDistribution(float(lo), float(hi))
                      for n, lo, hi in zip(space.names, space.lo, space.hi)}

    def _params(self, v: np.ndarray) -> dict[str, float]:
        return {n: float(np.clip(x, lo, hi)) for n, x, lo, hi in zip(self.space.names, v, self.space.lo,
                                                                      self.space.hi)}

    def tell(self, V: Sequence[np.ndarray], scores: Sequence[float]) -> None:
        """Add points scored elsewhere as completed trials (one storage call)."""
        trials = [_optuna().trial.create_trial(params=self._params(v), distributions=self.dists,
                                            value=float(s) if math.isfinite(s) else UNSCORABLE)
                  for v, s in zip(V, scores)]
        if trials:
            self.study.add_trials(trials)

    def ask(self, n: int) -> tuple[list[Any], np.ndarray]:
        """``n`` new points from the sampler: (trials, coordinates)."""
        trials = [self.study.ask(self.dists) for _ in range(n)]
        V = np.array([[t.params[k] for k in self.space.names] for t in trials]) if trials else \
            np.zeros((0, len(self.space.names)))
        return trials, V

    def told(self, trials: Sequence[Any], scores: Sequence[float]) -> None:
        """Complete asked trials with their scores."""
        for t, s in zip(trials, scores):
            self.study.tell(t, float(s) if math.isfinite(s) else UNSCORABLE)

    def n_trials(self) -> int:
        """The number of trials in the study (told and asked)."""
        return len(self.study.get_trials(deepcopy=False))
