"""Issue 20: "more budget never returns a worse answer".

The engine's steps are a fixed sequence given the seed; a budget only decides where that sequence ends (the first
step the time left cannot afford ends the search: nothing is skipped for time while a later step runs). Checked on
a clock that the test controls: each reading of it advances a fixed tick, so "time" is a count of the engine's own
checks and every budget is exactly reproducible; the engine is then run with budgets from a few ticks to all it
needs, and each run's scored points must be a prefix of the full run's, its best never worse than a shorter one's.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from tuner import Spec, plant_from_expr
from tuner.optimize import engine as engine_mod
from tuner.optimize.engine import Engine
from tuner.optimize.nlp import refine as refine_mod
from tuner.problem import TuningProblem


class _Ticks:
    """A stand-in for the ``time`` module: ``perf_counter`` advances ``tick`` seconds at every reading."""

    def __init__(self, tick: float) -> None:
        self.now, self.tick = 0.0, tick

    def perf_counter(self) -> float:
        self.now += self.tick
        return self.now


def _run(problem: TuningProblem, budget: float, monkeypatch, effort: Any = "default") -> Engine:
    clock = _Ticks(1e-3)
    monkeypatch.setattr(engine_mod, "time", clock)
    monkeypatch.setattr(refine_mod, "time", clock)
    eng = Engine(problem, seed=3, deadline=clock.perf_counter() + budget, effort=effort)
    eng.run()
    return eng


@pytest.mark.parametrize("expr, structure, dt", [("1/(s+1)^3", "pid", 0.1), ("2/(s*(0.5*s+1))", "pi", 0.05)])
@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_a_larger_budget_runs_a_longer_prefix_of_the_same_search(expr, structure, dt, monkeypatch):
    problem = TuningProblem.build(plant_from_expr(expr), structure=structure, spec=Spec.thesis(), dt=dt)
    full = _run(problem, 1e9, monkeypatch)  # every NLP it needs is built now: the budgets below cut only the search
    assert full.info.stop in ("converged", "work")  # (its evidence rule or its work budget ended it, not the clock)
    n_full = len(full.pool)
    ref = [(s, v) for s, v, _ in full.pool]
    # the full run used this much of the test clock: budgets from a few percent of it to all of it
    used = engine_mod.time.now
    bests, lengths = [], []
    # (a step whose cost, estimated from the steps before it, exceeds the time left ends the search: a budget a
    # little over what the full run used may still end it early; ten times that does not)
    for share in (0.02, 0.1, 0.25, 0.5, 0.8, 10.0):
        eng = _run(problem, share * used, monkeypatch)
        pts = [(s, v) for s, v, _ in eng.pool]
        assert len(pts) <= n_full
        for (s, v), (s0, v0) in zip(pts, ref):
            assert np.array_equal(v, v0) and (s == s0 or (math.isinf(s) and math.isinf(s0))), \
                f"budget share {share}: the search differs from the full one, not just shorter"
        bests.append(eng.best.score)
        lengths.append(len(pts))
    assert lengths == sorted(lengths) and lengths[0] < n_full  # the small budgets did cut the search
    assert all(b1 <= b0 for b0, b1 in zip(bests, bests[1:])), bests  # more budget: never a worse incumbent
    assert bests[-1] == full.best.score and lengths[-1] == n_full
    assert eng.info.stop == full.info.stop


@pytest.mark.parametrize("structure, effort", [("pid", "default"), ("pid", "fast"), ("pid2", "fast")])
@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_a_search_the_budget_cut_short_does_not_claim_convergence(structure, effort, monkeypatch):
    """Every budget from 1 % to all the search needs, in fine steps: a run that scored fewer points or ran fewer NLP
    solves than the full one was cut, and says ``budget`` (a polish the deadline cut inside its bisection, the last
    step of a ``fast`` search, included; so is ``pid2``'s contained ``pid`` search, which a cut ends the whole
    search: its later steps would otherwise depend on where the cut fell)."""
    problem = TuningProblem.build(plant_from_expr("1/(s+1)^3"), structure=structure, spec=Spec.thesis(), dt=0.1)
    full = _run(problem, 1e9, monkeypatch, effort)
    used = engine_mod.time.now
    assert full.info.stop in ("converged", "work")
    cut, bests = 0, []
    for share in np.linspace(0.01, 1.0, 60):
        eng = _run(problem, share * used, monkeypatch, effort)
        if structure != "pid2":  # (pid2 pools its contained search's best so far: a prefix of that search's)
            for (_, v, _), (_, v0, _) in zip(eng.pool, full.pool):  # a prefix: the same search, shorter
                assert np.array_equal(v, v0)
        bests.append(eng.best.score)
        if len(eng.pool) < len(full.pool) or eng.info.nlp_solves < full.info.nlp_solves:
            cut += 1
            assert eng.info.stop == "budget", (share, eng.info.nlp_solves, full.info.nlp_solves)
    assert cut > 0
    assert all(b1 <= b0 for b0, b1 in zip(bests, bests[1:])), bests  # more budget: never a worse incumbent


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_a_search_ends_at_its_work_budget_whatever_its_time_budget_and_does_not_claim_convergence(monkeypatch):
    """A time budget far beyond need (here: a simulated clock) does not let a search whose evidence never holds run
    for ever: it ends after its work budget of restarts (``Effort.max_restarts``), stop "work", unconfirmed."""
    import dataclasses

    problem = TuningProblem.build(plant_from_expr("1/(s+1)^3"), structure="pid", spec=Spec.thesis(), dt=0.1)
    full = _run(problem, 1e9, monkeypatch, "thorough")
    assert full.info.stop in ("converged", "work") and full.info.rounds > 2
    capped = _run(problem, 1e9, monkeypatch, dataclasses.replace(engine_mod.EFFORTS["thorough"], max_restarts=1))
    assert capped.info.rounds == 2 and capped.info.stop == "work" and capped.info.cut is None
    assert capped.optimality()["claim"] == "not confirmed"
    assert capped.best.score >= full.best.score  # the same search, stopped earlier
