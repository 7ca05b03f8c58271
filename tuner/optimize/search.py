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
    """The default Optuna sampler: a seeded multivariate TPE (``max(10, 4 n_params)`` start-up trials), whose
    density estimates are built once per batch (:func:`_batch_tpe`; Optuna's own TPE where its internals differ)."""
    cls = _batch_tpe() or _optuna().samplers.TPESampler
    return cls(seed=seed, multivariate=True, group=False, n_startup_trials=max(10, 4 * n_params), constant_liar=False)


_BATCH_TPE: list[Any] = []


def _batch_tpe() -> Any:
    """Optuna's TPE sampler with its two density estimates (the trials split into the best ``gamma(n)`` and the rest,
    a Parzen estimator of each) built once per set of completed trials, not once per ask; or None where this
    Optuna's TPE does not have the internals the subclass relies on (then Optuna's own class is used).

    Why: :meth:`SeededSearch.ask` asks a batch of ``n`` points with nothing told between them. Optuna's TPE, without
    the constant liar, sees the same completed trials at every ask of the batch, yet re-reads and re-sorts all of them
    and rebuilds both estimators each time: with 400 points a batch over a pool of 2000 (the quadrotor study's
    position loops) that was 11 of a tune's 23 s. Each ask still draws its own ``n_ei_candidates`` from the
    below-estimator with the sampler's random state and picks the best ratio, as Optuna's ``_sample`` does, so the
    points are bitwise those of Optuna's class (tests/tuner/test_search.py compares them)."""
    if _BATCH_TPE:
        return _BATCH_TPE[0]
    import inspect

    optuna = _optuna()
    from optuna.samplers._tpe import sampler as tpe_mod

    base = optuna.samplers.TPESampler
    methods = ("_sample", "_build_parzen_estimator", "_compute_acquisition_func", "_compare")
    attrs = ("_constant_liar", "_constraints_func", "_gamma", "_rng", "_n_ei_candidates")
    try:
        probe = base(seed=0)
        ok = all(callable(getattr(base, n, None)) for n in methods) and all(hasattr(probe, n) for n in attrs) and \
            all(callable(getattr(tpe_mod, n, None)) for n in ("default_gamma", "default_gamma_multiobjective")) and \
            list(inspect.signature(tpe_mod._split_trials).parameters) == ["study", "trials", "n_below"] and \
            list(inspect.signature(base._sample).parameters) == ["self", "study", "trial", "search_space"]
    except (AttributeError, TypeError, ValueError):
        ok = False
    if not ok:
        _BATCH_TPE.append(None)
        return None

    states = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)

    class BatchTPESampler(base):  # type: ignore[misc, valid-type]
        _memo: tuple[Any, ...] | None = None

        def _sample(self, study: Any, trial: Any, search_space: dict[str, Any]) -> dict[str, Any]:
            if self._constant_liar or self._constraints_func is not None:
                return super()._sample(study, trial, search_space)
            trials = study._get_trials(deepcopy=False, states=states, use_cache=True)
            # completed trials are never changed or removed: their count identifies the set (the study is held in
            # the memo, so its id is not reused while the memo lives)
            key = (id(study), study._study_id, len(trials), tuple(search_space.items()))
            memo = self._memo  # (read once: another thread may replace it between a check and a second read)
            if memo is None or memo[0] != key:
                if self._gamma is None:  # (as Optuna's _sample)
                    self._gamma = tpe_mod.default_gamma if len(study.directions) <= 1 else \
                        tpe_mod.default_gamma_multiobjective
                below, above = tpe_mod._split_trials(study, trials, self._gamma(len(trials)))
                memo = (key, study, self._build_parzen_estimator(study, search_space, below, handle_below=True),
                        self._build_parzen_estimator(study, search_space, above, handle_below=False))
                self._memo = memo
            _, _, mpe_below, mpe_above = memo
            samples_below = mpe_below.sample(self._rng.rng, self._n_ei_candidates)
            ret = base._compare(samples_below, self._compute_acquisition_func(samples_below, mpe_below, mpe_above))
            for name, dist in search_space.items():
                ret[name] = dist.to_external_repr(ret[name])
            return ret

        def __reduce__(self) -> tuple[Any, ...]:
            # a class made in a function is not importable by name: pickled as Optuna's TPE is, rebuilt through
            # _unpickle_batch_tpe; the memo (which holds the study) is not pickled
            state = {k: v for k, v in self.__dict__.items() if k != "_memo"}
            return _unpickle_batch_tpe, (), state

    _BATCH_TPE.append(BatchTPESampler)
    return BatchTPESampler


def _unpickle_batch_tpe() -> Any:
    """A bare :func:`_batch_tpe` sampler, its state set by pickle (``__reduce__``); Optuna's own class where this
    Optuna lacks the internals the subclass relies on."""
    cls = _batch_tpe() or _optuna().samplers.TPESampler
    return cls.__new__(cls)


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
