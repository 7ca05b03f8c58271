"""The load stage's batching (tuner.optimize.setpoint): its pattern searches run side by side in one batch per poll
and each distinct candidate is scored once; that is only the searches they are alone if the batch scores each row on
its own. Both checked: the PX4 rate law's batch (its gain-variation members, the load stage's horizon) scores rows
alone and in batches bitwise alike, and searches run side by side end where each run alone ends."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tuner import Spec
from tuner.controllers import get_structure
from tuner.optimize import setpoint as sp
from tuner.optimize.batch import BatchEvaluator
from tuner.optimize.space import make_space
from tuner.plant import plant_from_expr
from tuner.problem import TuningProblem


def _px4():
    plant = plant_from_expr("200/((s+2)*(0.03*s+1))")
    problem = TuningProblem.build(plant, structure=get_structure("px4_rate"), dt=0.0025, spec=Spec())
    space = make_space(problem.structure, plant, 0.0025, scale=problem.scale)
    batch = BatchEvaluator(problem, space)
    batch.kernels = None  # the numpy path (the reference)
    return problem, space, batch


def test_the_batch_scores_each_row_on_its_own():
    problem, space, batch = _px4()
    rng = np.random.default_rng(3)
    good = {"P": 0.29, "I": 1.17, "D": 0.0055, "FF": 0.0}  # (the load design tune() returns here)
    x = np.array([good.get(p, v) for p, v in zip(problem.structure.params, space.params(0.5 * (space.lo + space.hi)))])
    V = np.clip(space.from_params(x) + 0.15 * rng.standard_normal((24, space.lo.size)), space.lo, space.hi)
    X = np.array([space.params(v) for v in V])
    for limit in (0.3, 2.0):
        m, ts = sp._merit(batch, X, limit)
        alone = [sp._merit(batch, X[j:j + 1], limit) for j in range(len(X))]
        assert np.array_equal(m, np.concatenate([a[0] for a in alone]))
        assert np.array_equal(ts, np.concatenate([a[1] for a in alone]))
        assert np.isfinite(ts).sum() >= 3 and (m >= sp.PENALTY).sum() >= 1  # settled and failing rows both
        merits = sp._Merits(batch, limit)
        twice = np.concatenate([X[:5], X, X[3:9]])  # repeated rows are looked up
        n0 = batch.n_evals
        assert np.array_equal(merits(twice), np.concatenate([m[:5], m, m[3:9]]))
        assert batch.n_evals - n0 == len(X)


class _Bowl:
    """A batch stand-in: the 'settling time' of a row is a bowl around ``c`` in the search coordinates; rows past a
    wall fail (a violation growing with the distance)."""

    def __init__(self, space, c):
        self.space, self.c, self.rows = space, c, 0

    def evaluate(self, X, incumbent_s=None):
        V = np.array([self.space.from_params(x) for x in X])
        self.rows += len(X)
        d = np.sum((V - self.c) ** 2 * np.arange(1, V.shape[1] + 1), axis=1)
        wall = V[:, 0] > self.c[0] + 0.5
        ts = 0.1 + d
        return SimpleNamespace(per_plant=[{"settling_time_s": np.where(wall, np.inf, ts)}], feasible=~wall,
                               violation=np.where(wall, V[:, 0] - self.c[0], 0.0))


def test_searches_side_by_side_end_where_each_alone_ends():
    _, space, _ = _px4()
    rng = np.random.default_rng(5)
    c = space.lo + 0.4 * (space.hi - space.lo)
    free = list(range(1, space.lo.size))
    jobs = [(np.clip(c + 0.2 * rng.standard_normal(c.size), space.lo, space.hi), {0: float(x)})
            for x in (space.params(c)[0], 2 * space.params(c)[0], space.params(c)[0])]
    jobs.append((jobs[0][0].copy(), jobs[0][1]))  # the same search twice: its rows are looked up the second time
    together = sp._settle_locally(sp._Merits(_Bowl(space, c), 1.0), space, jobs, free)
    for job, got in zip(jobs, together):
        alone = sp._settle_locally(sp._Merits(_Bowl(space, c), 1.0), space, [job], free)[0]
        assert np.array_equal(got[0], alone[0]) and got[1] == alone[1] and got[2] == alone[2]
        assert got[2] > 10  # it polled
    assert together[0][1] < 0.2  # it found the bowl


@pytest.mark.slow  # (a tune: about 3 s)
def test_running_levels_ahead_changes_nothing(monkeypatch):
    """The load stage of a PX4 rate tune with its levels run ahead (batched) and each at its turn alone: the same
    design, the same record (levels found, candidates counted, settling and balance), fewer batch calls."""
    from tuner.plant import plant_from_expr as expr
    from tuner.tuning import tune

    seen = {}
    real = sp.raise_integral

    def keep(problem, engine, x0):
        seen["args"] = (problem, engine, np.array(x0, float))
        return real(problem, engine, x0)

    monkeypatch.setattr(sp, "raise_integral", keep)
    tune(expr("200/((s+2)*(0.03*s+1))"), structure="px4_rate", dt=0.0025, seed=0, effort="fast")
    problem, engine, x0 = seen["args"]
    calls = {"n": 0}
    evaluate = BatchEvaluator.evaluate

    def counted(self, X, **kw):
        calls["n"] += 1
        return evaluate(self, X, **kw)

    monkeypatch.setattr(BatchEvaluator, "evaluate", counted)
    out = {}
    for ahead in (True, False):
        monkeypatch.setattr(sp, "RUN_AHEAD", ahead)
        calls["n"] = 0
        x, rec, _ = real(problem, engine, x0)
        out[ahead] = (x, rec, calls["n"])
    assert np.array_equal(out[True][0], out[False][0])
    assert out[True][1] == out[False][1]
    assert out[True][1].levels >= 1 and out[True][1].evaluated > 100
    assert out[True][2] < out[False][2]


def test_a_continuous_loop_with_a_delay_is_scored_row_by_row():
    """(Review of issue 41.) A continuous loop with a delay is simulated at a step and over a horizon its whole batch
    shares, so a row's figures depend on the batch it is in (PID on 1/(s+1)^2 with 0.2 s of delay: most of 24 nearby
    rows score differently alone and together): there the load stage's merits score each row alone, as they would
    one search at a time (the cache and the side-by-side searches would otherwise change the answer with the company
    a row keeps)."""
    plant = plant_from_expr("1/(s+1)^2", delay=0.2)
    problem = TuningProblem.build(plant, structure=get_structure("pid"), dt=None, spec=Spec())
    batch = BatchEvaluator(problem, make_space(problem.structure, plant, None, scale=problem.scale))
    rng = np.random.default_rng(0)
    X = np.array([1.0, 0.6, 0.3, 0.03]) * np.exp(0.3 * rng.standard_normal((24, 4)))
    alone = np.concatenate([sp._merit(batch, X[j:j + 1], 50.0)[0] for j in range(len(X))])
    assert np.sum(sp._merit(batch, X, 50.0)[0] != alone) > 0  # (the batch's company matters here)
    merits = sp._Merits(batch, 50.0)
    assert merits.alone and np.array_equal(merits(X), alone)
