"""The batch computes what every plant of a set shares once a batch (the controllers' responses on the frequency grid
and their state-space realisations) and hands it to each plant's evaluation: the figures must be bitwise those each
plant's evaluation computes on its own (a PX4 rate law with its gain-variation members; a 2-DOF pid2 on two plants,
continuous, whose reference path has a realisation of its own)."""

from __future__ import annotations

import numpy as np
import pytest

from tuner import Spec
from tuner.controllers import get_structure
from tuner.optimize.batch import BatchEvaluator
from tuner.optimize.space import make_space
from tuner.plant import plant_from_expr
from tuner.problem import TuningProblem


def _batch(exprs, structure, dt):
    plants = [plant_from_expr(e) for e in exprs]
    problem = TuningProblem.build(plants if len(plants) > 1 else plants[0], structure=get_structure(structure), dt=dt,
                                  spec=Spec())
    space = make_space(problem.structure, plants[0], dt, scale=problem.scale)
    batch = BatchEvaluator(problem, space)
    batch.kernels = None  # the numpy path (the reference)
    return problem, space, batch


def _alone(batch, X):
    """Each plant's figures with nothing shared (what BatchEvaluator.evaluate did before it shared them)."""
    num, den, ok, num_r = batch.usable_controllers(X)
    return [batch._evaluate_plant(pd, num, den, ok, num_r) for pd in batch.plants]


@pytest.mark.parametrize("case", [(["200/((s+2)*(0.03*s+1))"], "px4_rate", 0.0025),
                                  (["1/(s+1)^3", "1.3/(s+1)^2/(0.5*s+1)"], "pid2", None)])
def test_shared_parts_give_each_plants_own_figures(case):
    exprs, structure, dt = case
    problem, space, batch = _batch(*case)
    assert len(batch.plants) >= 2  # (px4_rate: its gain-variation members)
    rng = np.random.default_rng(5)
    V = rng.uniform(space.lo, space.hi, size=(40, space.lo.size))
    X = np.array([space.params(v) for v in V])
    r = batch.evaluate(X)
    alone = _alone(batch, X)
    assert len(r.per_plant) == len(alone)
    compared = 0
    for shared, own in zip(r.per_plant, alone):
        assert set(shared) == set(own)
        for k in own:
            assert np.array_equal(np.asarray(shared[k]), np.asarray(own[k]), equal_nan=True), k
            compared += int(np.isfinite(np.asarray(own[k], dtype=float)).sum())
    assert compared > 100  # finite figures were compared, not only NaN rows
