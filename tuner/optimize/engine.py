"""The anytime search: rounds of global sampling and local refinement until converged or out of budget.

Round 0 is deterministic (the same for every seed): the structure's plant-based starts, a fixed
space-filling set of points and, for a structure that contains a smaller one (``leadlag`` contains
``lead``; ``pid2`` contains ``pid`` at b = c = 1), the smaller structure's designed starts; all
scored in one batch (:class:`~tuner.optimize.batch.BatchEvaluator`), the best few distinct ones
refined by the CasADi NLP (:mod:`~tuner.optimize.nlp`). Later rounds ask Optuna's seeded sampler
(which has been told every point scored so far) for a batch, and refine the best new distinct
candidates. The search stops when

* **converged**: in round 0, two refinements from distinct starts reached the same best value
  (within half a sample of settling time, or 0.1 %), or the ``STALE_REFINES`` refinements after the
  best one did not improve on it; after that, no round improved the best by more than that in
  ``PATIENCE`` rounds; or
* **budget**: the time budget (minus what the final verification needs) is used up.

``info["stop"]`` says which. The final choice is made by the full verifier, never by the search.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..controllers import get_structure
from ..problem import TuningProblem
from .batch import BatchEvaluator, Start
from .design import initial_guess, zero_variants
from .scoring import Evaluator, Scored
from .search import SeededSearch
from .space import Space, make_space

__all__ = ["Engine", "designed_starts", "PATIENCE", "NLP_OBJECTIVES"]

#: the objectives the local NLP states exactly (``nlp.transcribe._objective``); the others (bandwidth) are
#: optimised by the global search alone
NLP_OBJECTIVES = ("settling_time", "itae", "iae", "ie", "mks", "disk_margin")

log = logging.getLogger(__name__)

PATIENCE = 1
STALE_REFINES = 2  # refinements in a row that did not improve on the best: round 0 has converged
DESIGN_POINTS = 48  # the fixed space-filling set of round 0
DESIGN_SEED = 20261201  # fixed: round 0 does not depend on the user's seed
ROUND_TRIALS = 24  # Optuna points per later round
# the local scan around the incumbent after round 0's refinements (see Engine._scan): a fixed cloud
SCAN_POINTS = 96
SCAN_DECADES = 0.3  # half-width per coordinate, in the search's coordinates (decades for gains and times)
SCAN_SEED = 20261202
GAIN_DECADES = (0.0, -0.25, 0.25, -0.5, 0.5, -1.0, -1.5)  # the designed starts' gains, in decades of the guess


def designed_starts(space: Space, plant, dt: float | None, *, variants: bool = False, spec: Any = None
                    ) -> list[np.ndarray]:
    """Plant-based starts: the structure's initial guess with all gains scaled by 10^-1.5 ... 10^0.5
    (most loops are stable somewhere on that ray); ``variants``: the same for each placement of the
    controller's zeros of :func:`~tuner.optimize.design.zero_variants` (the first is the classic one)."""
    st = space.structure
    scale = (space.k0, space.w0)
    zs = zero_variants(plant, dt, space.w0) if variants else [None]
    guesses = []
    for zeros in zs:
        with np.errstate(all="ignore"):
            g = initial_guess(st, plant, dt, scale=scale, zeros=zeros, spec=spec)
        x0 = np.array([g[p] for p in st.params])
        if np.all(np.isfinite(x0)) and not any(np.allclose(x0, g0, rtol=1e-9, atol=0) for g0 in guesses):
            guesses.append(x0)  # placements a structure cannot tell apart (one zero) only once
    starts = []
    for decades in GAIN_DECADES:  # every placement at the nominal gain first
        for x0 in guesses:
            x = x0.copy()
            for i, kind in enumerate(st.kinds):
                if kind == "gain":
                    x[i] *= 10.0 ** decades
            starts.append(space.from_params(x))
    return starts


def _contained(problem: TuningProblem) -> tuple[str, Any] | None:
    """The smaller structure this one contains, and the map of its gains into this one's parameters.

    (A ``pid`` at ``dt`` contains ``pid_z``, but needs no seeding: its own designed starts, zeros on the
    zero-order-hold plant's poles and Tf at the floor, are exactly ``pid_z``'s.)"""
    if problem.structure.name == "leadlag":
        def from_lead(g: dict[str, float]) -> dict[str, float]:
            return {"K": g["K"], "wz1": g["wz"], "wp1": g["wp"], "wz2": 1.001 * g["wz"], "wp2": g["wz"]}
        return "lead", from_lead
    if problem.structure.name == "pid2":
        # pid2 contains pid at b = c = 1: pid's own starts exactly, and the same with setpoint weights
        def from_pid(g: dict[str, float]) -> list[dict[str, float]]:
            return [{**g, "b": b, "c": c} for b, c in PID2_WEIGHT_SEEDS]
        return "pid", from_pid
    return None


#: structures whose search first runs the contained structure's whole search (:meth:`Engine._contained_answer`)
FULL_CONTAINMENT = ("pid2",)
CONTAINED_SHARE = 0.9  # of the time left: the contained search (the guarantee) runs as a tune of it would; a
                       # budget-bound one leaves pid2 little more than its answer
#: the (b, c) given to pid's designed starts as pid2's seeds: pid itself first, then D on the measurement with
#: full and half proportional setpoint weight
PID2_WEIGHT_SEEDS = ((1.0, 1.0), (1.0, 0.0), (0.5, 0.0))


@dataclass
class _Best:
    score: float = math.inf
    v: np.ndarray | None = None


@dataclass
class RunInfo:
    """The search's record (rounds, why it stopped, evaluation and NLP counts): ``TuneResult.solver``."""

    rounds: int = 0
    stop: str = "budget"
    batch_evaluations: int = 0
    starts_refined: int = 0
    nlp_solves: int = 0
    nlp_iterations: int = 0
    nlp_evaluations: int = 0
    nlp_solves_ok: int = 0
    seeded_from: str | None = None
    history: list[float] = field(default_factory=list)


class Engine:
    """One tune's search (see the module docstring); :meth:`run` returns the candidates to verify."""

    def __init__(self, problem: TuningProblem, *, seed: int, deadline: float, solver: str = "sqp", local: bool = True,
                 n_starts: int = 3, n_trials: int | None = None, sampler: Any = None, storage: Any = None,
                 reserve_s: float = 0.0) -> None:
        self.problem = problem
        self.space = make_space(problem.structure, problem.nominal, problem.dt, scale=problem.scale,
                                nyquist=problem.spec.filter_nyquist)
        self.ev = Evaluator(list(problem.plants), problem.structure, problem.dt, problem.spec, w0=self.space.w0)
        self.batch = BatchEvaluator(problem, self.space)
        # the local stage states the objectives it optimises exactly (the others: the global search alone)
        self.seed, self.deadline, self.solver = seed, deadline, solver
        self.local = local and problem.spec.objective in NLP_OBJECTIVES
        self.n_starts, self.n_trials = n_starts, n_trials
        self.sampler, self.storage = sampler, storage
        self.reserve_s = reserve_s
        self.info = RunInfo()
        self.pool: list[tuple[float, np.ndarray, bool]] = []  # (batch score, coordinates, refined?)
        self.best = _Best()
        self._search: SeededSearch | None = None
        self._per_point = 0.0  # seconds per point of the last batch
        self._starts: dict[bytes, Start] = {}  # what the batch said about each pooled point (refine's start)

    # -- bookkeeping ------------------------------------------------------------------------------

    def _time_left(self) -> float:
        return self.deadline - self.reserve_s - time.perf_counter()

    def _score(self, V: np.ndarray, *, source: str, refined: bool = False) -> np.ndarray:
        """Batch-score coordinates, add them to the pool, track the best (non-finite points are dropped)."""
        V = np.atleast_2d(np.asarray(V, dtype=float)) if len(V) else np.zeros((0, self.space.lo.size))
        V = V[np.all(np.isfinite(V), axis=1)]
        if len(V) == 0:
            return np.zeros(0)
        X = np.array([self.space.params(v) for v in V])
        t0 = time.perf_counter()
        r = self.batch.evaluate(X, incumbent_s=self.best.score if self._settling else None)
        self._per_point = (time.perf_counter() - t0) / len(V)
        self.info.batch_evaluations += len(V)
        for j, (v, s) in enumerate(zip(V, r.score)):
            v = np.asarray(v, float)
            self.pool.append((float(s), v, refined))
            self._starts[v.tobytes()] = Start.row(r, j)
            if s < self.best.score:
                self.best = _Best(float(s), v)
        return r.score

    @property
    def _settling(self) -> bool:
        return self.problem.spec.objective == "settling_time" and math.isfinite(self.best.score) and \
            self.best.score < 1e3

    def _tol(self) -> float:
        b = self.best.score
        if self.problem.spec.objective == "settling_time":
            return max(1e-3 * abs(b), 0.5 * (self.problem.dt or 0.0))
        return 1e-3 * max(abs(b), 1e-12)

    def _distinct(self, k: int, *, unrefined: bool = True) -> list[np.ndarray]:
        # a 2-DOF structure's setpoint weights do not make a start distinct: the refinement moves them freely, and
        # starts that differ only there (pid's starts seeded with several b, c) are one start for the feedback
        span = np.maximum(self.space.hi - self.space.lo, 1e-12)
        span = np.where([k == "weight" for k in self.space.structure.kinds], np.inf, span)
        chosen: list[np.ndarray] = []
        refined = [v for _, v, r in self.pool if r]
        for _, v, r in sorted(self.pool, key=lambda t: t[0]):
            if unrefined and r:
                continue
            if all(np.linalg.norm((v - w) / span) > 0.05 for w in chosen + refined):
                chosen.append(v)
            if len(chosen) >= k:
                break
        return chosen

    def _refine(self, starts: list[np.ndarray]) -> list[float]:
        """Refine each start; returns the best batch score each refinement reached."""
        from .nlp.refine import refine

        out = []
        for v in starts:
            if self._time_left() <= 0:
                break
            self.pool = [(s, w, True) if w is v else (s, w, r) for s, w, r in self.pool]
            res = refine(self.batch, self.space, v, deadline=self.deadline - self.reserve_s, solver=self.solver,
                         incumbent=self.best.score if self._settling else None, start=self._starts.get(v.tobytes()))
            i = self.info
            i.starts_refined += 1
            i.nlp_solves += res.solves
            i.nlp_iterations += res.iterations
            i.nlp_evaluations += res.evaluations
            i.nlp_solves_ok += int(res.success)
            scores = self._score(np.array(res.candidates), source="nlp", refined=True) if res.candidates else []
            # nan: no solve ran (e.g. no time to build its NLP): no evidence either way for the convergence test
            out.append(float(np.min(scores)) if len(scores) else (math.inf if res.solves else math.nan))
        return out

    # -- rounds -----------------------------------------------------------------------------------

    def _round0(self) -> bool:
        """Deterministic: designed starts, a fixed space-filling set, the contained structure's answer."""
        p = self.problem
        # the plant-based starts first: their best is the incumbent that bounds the simulated horizon of the
        # space-filling points (a point that has not settled by three times the incumbent's settling time
        # is worse anyway)
        starts = designed_starts(self.space, p.nominal, p.dt, variants=True, spec=p.spec)
        span = np.maximum(self.space.hi - self.space.lo, 1e-12)
        S = np.array(starts).reshape(len(starts), -1)
        seeded = [v for v in self._seeded_starts()  # those the structure's own starts do not already hold
                  if not len(S) or np.min(np.max(np.abs(S - v) / span, axis=1)) >= 1e-3]
        seeded = self._contained_answer() + seeded
        n0 = max(1, len(starts) // len(GAIN_DECADES))  # the nominal-gain starts: an incumbent, cheaply
        self._score(np.array(starts[:n0]), source="design")
        # the later batches are cut to what the time left affords (their cost per point is known by now: a slow
        # plant at a fine dt simulates tens of thousands of samples per candidate)
        self._score(np.array(self._affordable(starts[n0:] + seeded)), source="design")
        rng = np.random.default_rng(DESIGN_SEED)
        lo, hi = self.space.lo, self.space.hi
        fixed = [lo + rng.random(lo.size) * (hi - lo) for _ in range(DESIGN_POINTS)]
        self._score(np.array(self._affordable(fixed)), source="design")
        if not self.local:
            return False
        reached: list[float] = []
        converged, stale = False, 0
        for v in self._distinct(self.n_starts):  # one at a time: stop as soon as the evidence is in
            before = self.best.score
            new = self._refine([v])
            reached += new
            if not new or math.isnan(new[-1]):
                continue  # not refined (no time, or no NLP solve): says nothing about convergence
            good = sorted(r for r in reached if math.isfinite(r) and r < 1e3)
            # converged: two refinements from distinct starts agree on the best value, or every refinement
            # after the best one (at least STALE_REFINES of them) failed to improve on it
            agree = len(good) >= 2 and good[1] - good[0] <= self._tol() and good[0] <= self.best.score + self._tol()
            tried = [r for r in reached if not math.isnan(r)]
            stale = stale + 1 if len(tried) > 1 and self.best.score >= before - self._tol() else 0
            converged = agree or stale >= STALE_REFINES
            if converged:
                break
        if self._scan():
            converged = False  # a better basin next to the refined one: the search goes on
        self.info.history.append(self.best.score)
        return converged

    def _scan(self) -> bool:
        """A fixed cloud of points around the incumbent, scored in one batch; the best, if it beats the
        incumbent, is refined. The settling time is discontinuous in the gains: a loop whose slow tail
        just enters the band earlier lies in a thin valley beside the basin a refinement ends in (PI on
        1/(20 s + 1)^2 at dt 0.1: a valley at 3 tau along a diagonal of (Kp, Ki), next to a basin at
        6 tau), too thin for the space-filling points and out of the NLP's reach from the basin."""
        if not self._settling or self.best.v is None or self._time_left() < 2 * SCAN_POINTS * self._per_point:
            return False  # (what the scan costs is known from the batches before it)
        rng = np.random.default_rng(SCAN_SEED)
        half = np.minimum(SCAN_DECADES, 0.1 * (self.space.hi - self.space.lo))
        V = self.best.v + (2 * rng.random((SCAN_POINTS, self.best.v.size)) - 1) * half
        V = np.clip(V, self.space.lo, self.space.hi)
        before, v_before = self.best.score, self.best.v
        self._score(V, source="scan")
        if self.best.score >= before - self._tol() or self.best.v is v_before:
            return False
        if self.local:
            self._refine([self.best.v])
        return True

    def _affordable(self, V: list[np.ndarray]) -> list[np.ndarray]:
        """The first of ``V`` that the time left can score, at the last batch's cost per point."""
        if self._per_point <= 0:
            return V
        return V[:max(0, int(self._time_left() / self._per_point))]

    def _seeded_starts(self) -> list[np.ndarray]:
        """The contained structure's own designed starts, mapped into this structure's coordinates (a ``pid``
        at ``dt`` starts where a ``pid_z`` would: its Tf at the floor is the backward-Euler PID)."""
        sub = _contained(self.problem)
        if sub is None:
            return []
        name, convert = sub
        p = self.problem
        small = get_structure(name)
        space = make_space(small, p.nominal, p.dt, scale=p.scale, nyquist=p.spec.filter_nyquist)
        out = []
        for v in designed_starts(space, p.nominal, p.dt, variants=True, spec=p.spec):
            g = dict(zip(small.params, space.params(v)))
            with np.errstate(all="ignore"):
                mapped = convert(g)
                for gm in (mapped if isinstance(mapped, list) else [mapped]):
                    x = np.array([gm[q] for q in p.structure.params])
                    if np.all(np.isfinite(x)):
                        out.append(self.space.from_params(x))
        self.info.seeded_from = name if out else None
        return out

    def _contained_answer(self) -> list[np.ndarray]:
        """A structure that must never be worse than the one it contains (``pid2`` and ``pid``): that structure's
        own search, run first on the same problem and seed with at most CONTAINED_SHARE of the time left; its best
        candidates, mapped in (b = c = 1 is that very controller, the other weights are starts), lead this round.
        The refinement then starts from the contained optimum with the weights free."""
        if self.problem.structure.name not in FULL_CONTAINMENT:
            return []
        import dataclasses

        name, convert = _contained(self.problem)
        sub_problem = dataclasses.replace(self.problem, structure=get_structure(name))
        left = self._time_left()
        if left <= 0:
            return []
        sub = Engine(sub_problem, seed=self.seed, deadline=time.perf_counter() + CONTAINED_SHARE * left,
                     solver=self.solver, local=self.local, n_starts=self.n_starts, n_trials=self.n_trials)
        sub.run()
        small = sub_problem.structure
        out = []
        for j, (score, x) in enumerate(sub.finalists_scored(3)):
            g = small.named(x)
            for i, gm in enumerate(convert(g)):
                xx = np.array([gm[q] for q in self.problem.structure.params])
                if not np.all(np.isfinite(xx)):
                    continue
                v = self.space.from_params(xx)
                if i == 0:  # b = c = 1: the contained controller itself, pooled with the score its search gave it
                    self.pool.append((float(score), v, False))
                    if score < self.best.score:
                        self.best = _Best(float(score), v)
                    if j == 0:
                        self._contained_x = self.space.params(v)
                else:
                    out.append(v)
        self.info.seeded_from = name
        return out

    def _round(self) -> float:
        """One Optuna round: tell what is new, ask a batch, score it, refine the best new ones."""
        self._tell_new()
        n = self.n_trials or ROUND_TRIALS
        trials, V = self._search.ask(n)
        scores = self._score(V, source="optuna")
        self._search.told(trials, scores)
        self._told = len(self.pool)
        if self.local and self._time_left() > 0:
            self._refine(self._distinct(max(1, self.n_starts - 1)))
        return self.best.score

    def run(self) -> RunInfo:
        """Round 0, then later rounds until the search has converged (see the module; ``stop = "converged"``) or
        the budget ends; returns the record."""
        converged = self._round0()
        self.info.rounds = 1
        stale = 0
        while not converged and self._time_left() > 0:
            before = self.best.score
            self._round()
            self.info.rounds += 1
            self.info.history.append(self.best.score)
            stale = 0 if self.best.score < before - self._tol() else stale + 1
            # a local stage that never ran (no time to build its NLP) has not converged: search on to the budget
            converged = stale >= PATIENCE and (not self.local or self.info.nlp_solves > 0)
        self.info.stop = "converged" if converged else "budget"
        if self.storage is not None:
            self._tell_new()  # with a storage, every point this tune scored lands in the study
        return self.info

    def _tell_new(self) -> None:
        """Tell the seeded search every point scored since it was last told (one bulk call)."""
        if self._search is None:
            self._search = SeededSearch(self.space, seed=self.seed, sampler=self.sampler, storage=self.storage)
            self._told = 0
        new = self.pool[self._told:]
        self._search.tell([v for _, v, _ in new], [s for s, _, _ in new])
        self._told = len(self.pool)

    # -- the answer ---------------------------------------------------------------------------------

    def finalists(self, k: int = 3) -> list[np.ndarray]:
        """The best ``k`` distinct candidates (structure parameters) for the full verification."""
        return [x for _, x in self.finalists_scored(k)]

    def finalists_scored(self, k: int = 3) -> list[tuple[float, np.ndarray]]:
        """:meth:`finalists` with their batch scores."""
        span = np.maximum(self.space.hi - self.space.lo, 1e-12)
        out: list[tuple[float, np.ndarray]] = []
        for s, v, _ in sorted(self.pool, key=lambda t: t[0]):
            if all(np.linalg.norm((v - w) / span) > 1e-6 for _, w in out):
                out.append((s, v))
            if len(out) >= k:
                break
        return [(s, self.space.params(v)) for s, v in out]

    def verify_best(self, k: int = 3) -> tuple[np.ndarray, Scored]:
        """Full-resolution verification of the finalists in the search's order: the first that the verifier
        finds feasible wins (the search's guards make its scores conservative, so the verifier rarely
        disagrees); if none is, the best verified one. ``self.verified`` counts the verifications."""
        best_x, best = None, None
        self.verified = 0
        for x in self.finalists(k):
            s = self.ev.score(x, full=True)
            self.verified += 1
            if s.analyses and (best is None or s.score < best.score):
                best_x, best = x, s
            if best is not None and best.feasible:
                break
        x_c = getattr(self, "_contained_x", None)
        if x_c is not None and not any(np.array_equal(x_c, x) for x in self.finalists(k)):
            # the contained structure's answer (pid2 at b = c = 1 is pid's): verified too, so that the result is
            # never worse than that structure's own tune (the batch's scores of the two may rank them otherwise)
            s = self.ev.score(x_c, full=True)
            self.verified += 1
            if s.analyses and (best is None or (s.feasible, -s.score) > (best.feasible, -best.score)):
                best_x, best = x_c, s
        if best is None:
            from ..errors import TunerError

            raise TunerError("no candidate could be evaluated")
        return best_x, best

