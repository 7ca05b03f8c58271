"""The facade: ``tune(plant_or_plants, *, structure, spec, ...) -> TuneResult``.

1. Global stage (:mod:`tuner.optimize.search`, Optuna): a seeded search over the
   structure's coordinates, scored by the verifier, finds the basins.
2. Local stage (:mod:`tuner.optimize.nlp`, CasADi/IPOPT): the best few distinct
   candidates are refined on the exact problem (crossover frequencies as
   decision variables, step response between samples as envelope constraints).
3. Every candidate is re-verified by :mod:`tuner.analysis` at full resolution on
   every plant; only verified numbers are reported, and the best verified
   candidate wins. When none meets the spec, the least-violating one is returned
   with ``meets_spec: false`` and the failing constraints.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .analysis.verify import Analysis
from .controllers import ControllerTF
from .errors import TunerError
from .jsonio import jsonable
from .optimize.design import initial_guess
from .optimize.scoring import Evaluator, Scored
from .optimize.space import Space, make_space
from .plant import Plant
from .problem import MAX_PLANTS, TuningProblem
from .spec import Spec

__all__ = ["TuneResult", "tune", "designed_starts", "MAX_PLANTS"]

log = logging.getLogger(__name__)

@dataclass(frozen=True, eq=False)
class TuneResult:
    structure: str
    gains: dict[str, float]
    controller: ControllerTF
    analyses: tuple[Analysis, ...]  # the verifier's, one per plant (nominal first)
    solver: dict[str, Any]
    spec: Spec

    @property
    def meets_spec(self) -> bool:
        return all(a.meets_spec for a in self.analyses)

    @property
    def worst(self) -> Analysis:
        """The analysis of the plant that decides the result (fails, or has the worst objective)."""
        failing = [a for a in self.analyses if not a.meets_spec]
        if failing:
            return failing[0]
        return max(self.analyses, key=lambda a: a.metrics.settling_time_s)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (after :func:`~tuner.analysis.jsonable`): the analyze fields + gains, controller, solver.

        ``metrics`` and ``checks`` are the nominal plant's; with several plants,
        ``plants`` holds every plant's metrics and checks and ``meets_spec`` is
        true only if all pass.
        """
        nominal = self.analyses[0].to_dict()
        out: dict[str, Any] = {
            "structure": self.structure,
            "gains": dict(self.gains),
            "controller": self.controller.to_dict(),
            "metrics": nominal["metrics"],
            "checks": nominal["checks"],
            "meets_spec": self.meets_spec,
            "failing": sorted({c.name for a in self.analyses for c in a.failing}),
            "solver": dict(self.solver),
            "spec": self.spec.model_dump(),
        }
        if len(self.analyses) > 1:
            out["plants"] = [a.to_dict() for a in self.analyses]
        return out

    def to_json(self) -> dict[str, Any]:
        return jsonable(self.to_dict())


def tune(
    plant_or_plants: Plant | Sequence[Plant] | TuningProblem,
    *,
    structure: str | None = None,
    spec: Spec | None = None,
    dt: float | None = None,
    seed: int = 0,
    time_budget_s: float = 10.0,
    n_trials: int | None = None,
    n_starts: int = 2,
    sampler: Any = None,
    storage: Any = None,
    local: bool = True,
    nlp_solver: str = "ipopt",
) -> TuneResult:
    """Tune ``structure`` on a plant (or a set of plants: every constraint on every plant).

    Parameters
    ----------
    plant_or_plants : Plant or sequence of Plant
        The nominal plant first; for robust tuning, the whole set.
    structure : str
        One of :data:`tuner.controllers.STRUCTURES`.
    spec : Spec, optional
        Defaults to the thesis spec (PM >= 60 deg, GM >= 6 dB, overshoot <= 10 %, zero
        steady-state error, minimum 2 % settling time).
    dt : float, optional
        Controller sample time; ``None`` = continuous (or the plants' dt if discrete).
    seed : int
        Seeds the global search: same seed, same gains.
    time_budget_s : float
        Wall-time budget; past it the best verified candidate so far is returned.
    n_trials : int, optional
        Global-stage evaluations (default scales with the number of parameters).
    n_starts : int
        How many distinct global-stage candidates the local NLP refines.
    sampler, storage
        Optuna sampler and storage (in-memory by default; a storage URL is accepted).
    local : bool
        Run the CasADi local stage (``False`` = global search only, for comparison).
    nlp_solver : str
        ``"ipopt"`` (default) or ``"sqp"`` (CasADi's SQP with qpOASES; same problem).
    """
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or not 0 <= int(seed) < 2**32:
        raise TunerError(f"seed must be an integer from 0 to 2**32 - 1, got {seed!r}", field="seed")
    if not (isinstance(time_budget_s, (int, float)) and math.isfinite(time_budget_s) and time_budget_s > 0):
        raise TunerError(f"time_budget_s must be a finite number > 0, got {time_budget_s!r}", field="time_budget_s")
    if nlp_solver not in ("ipopt", "sqp"):
        raise TunerError(f"nlp_solver must be 'ipopt' or 'sqp', got {nlp_solver!r}", field="nlp_solver")
    t0 = time.perf_counter()
    deadline = t0 + float(time_budget_s)
    if isinstance(plant_or_plants, TuningProblem):
        if structure is not None or spec is not None or dt is not None:
            raise TunerError("a TuningProblem already holds the structure, spec and dt: do not pass them again",
                             field="structure")
        problem = plant_or_plants
    else:
        if structure is None:
            raise TunerError("give the controller structure, e.g. structure='pid'", field="structure")
        problem = TuningProblem.build(plant_or_plants, structure=structure, spec=spec, dt=dt)
    plants, st, dt, spec = list(problem.plants), problem.structure, problem.dt, problem.spec
    space = make_space(st, plants[0], dt, scale=problem.scale)
    ev = Evaluator(plants, st, dt, spec, w0=space.w0)

    from .optimize.search import global_search

    n_trials = n_trials or 15 * len(st.params) + 20
    found = global_search(ev, space, seed=seed, n_trials=n_trials, deadline=deadline, sampler=sampler,
                          storage=storage, x0=designed_starts(space, plants[0], dt), top_k=n_starts)
    info: dict[str, Any] = {"seed": seed, "global_evaluations": found.n_evals, "global_best": found.best_score}
    candidates = [space.params(v) for _, v in found.top]
    # NLP starts: the global stage's best, the best plant-based start (a pole-cancelling design
    # often lies in the best basin even when it scores worse than what the sampler found), then
    # the next distinct global candidates
    starts = [v for _, v in found.top[:1]]
    if found.best_enqueued is not None:
        starts.append(found.best_enqueued[1])
    starts += [v for _, v in found.top[1:]]
    starts = _distinct_starts(starts, space)[:n_starts]
    nlp_info: dict[str, Any] = {"nlp_iterations": 0, "nlp_evaluations": 0, "starts_tried": 0, "nlp_solves_ok": 0}
    if local:
        from .optimize.nlp.refine import refine

        for v in starts:
            if time.perf_counter() > deadline:
                break
            r = refine(ev, space, v, deadline=deadline, solver=nlp_solver)
            nlp_info["starts_tried"] += 1
            nlp_info["nlp_iterations"] += r.iterations
            nlp_info["nlp_evaluations"] += r.evaluations
            nlp_info["nlp_solves_ok"] += int(r.success)
            candidates.extend(space.params(c) for c in r.candidates)
    best_x, best = _verify_best(ev, candidates)
    info.update(nlp_info)
    info.update({
        "method": f"optuna+casadi-{nlp_solver}" if local else "optuna",
        "wall_time_s": time.perf_counter() - t0,
        "verifier_evaluations": ev.n_evals,
        "budget_exhausted": time.perf_counter() > deadline,
        "candidates_verified": len(candidates),
    })
    return TuneResult(structure=st.name, gains=st.named(best_x), controller=ev.controller(best_x),
                      analyses=best.analyses, solver=info, spec=spec)


def _distinct_starts(vs: list[np.ndarray], space: Space) -> list[np.ndarray]:
    span = np.maximum(space.hi - space.lo, 1e-12)
    out: list[np.ndarray] = []
    for v in vs:
        if all(np.linalg.norm((v - w) / span) > 0.05 for w in out):
            out.append(v)
    return out


def designed_starts(space: Space, plant: Plant, dt: float | None) -> list[np.ndarray]:
    """Plant-based starts enqueued before the search: the structure's initial guess with all
    gains scaled by 10^-1.5 ... 10^0.5 (most loops are stable somewhere on that ray)."""
    st = space.structure
    g = initial_guess(st, plant, dt, scale=(space.k0, space.w0))
    x0 = np.array([g[p] for p in st.params])
    starts = []
    for decades in (0.0, -0.25, 0.25, -0.5, 0.5, -1.0, -1.5):
        x = x0.copy()
        for i, kind in enumerate(st.kinds):
            if kind == "gain":
                x[i] *= 10.0 ** decades
        starts.append(space.from_params(x))
    return starts


def _verify_best(ev: Evaluator, candidates: list[np.ndarray], *, full_checks: int = 3) -> tuple[np.ndarray, Scored]:
    """Rank distinct candidates with the search-resolution verifier, then verify the best few at full
    resolution; the best *fully verified* candidate wins (its numbers are the ones reported)."""
    seen: set[tuple[float, ...]] = set()
    ranked: list[tuple[float, int, np.ndarray]] = []
    for i, x in enumerate(candidates):
        key = tuple(np.round(x, 12))
        if key in seen or not np.all(np.isfinite(x)):
            continue
        seen.add(key)
        ranked.append((ev.score(x).score, i, x))
    ranked.sort(key=lambda r: (r[0], r[1]))
    best_x: np.ndarray | None = None
    best: Scored | None = None
    for _, _, x in ranked[:full_checks]:
        s = ev.score(x, full=True)
        if s.analyses and (best is None or s.score < best.score):
            best_x, best = x, s
    if best is None:
        raise TunerError("no candidate could be evaluated")
    return best_x, best
