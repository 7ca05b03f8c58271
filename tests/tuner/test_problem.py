"""TuningProblem: one statement of the problem, validated once, errors located by ``field``."""

from __future__ import annotations

import pytest
from quadrotor import DT, ROLL

from tuner import Spec, TunerError, TuningProblem, make_plant, plant_from_expr
from tuner.optimize.design import plant_scale

ROLL_P = plant_from_expr(ROLL)


@pytest.mark.parametrize("args, field", [
    (dict(plant_or_plants=ROLL_P, structure="pidd"), ("structure",)),
    (dict(plant_or_plants=ROLL_P, structure="pid_z"), ("dt",)),
    (dict(plant_or_plants=ROLL_P, structure="pid", dt=0), ("dt",)),
    (dict(plant_or_plants=[], structure="pid"), ("plants",)),
    (dict(plant_or_plants=[ROLL_P, "1/(s+1)"], structure="pid"), ("plants", 1)),
    (dict(plant_or_plants=[ROLL_P, make_plant([1.0], [1.0, 1.0], delay=201.5 * DT)], structure="pid", dt=DT),
     ("plants", 1, "delay")),  # above MAX_DELAY_SAMPLES (a fraction of a sample is fine: exact)
    (dict(plant_or_plants=make_plant([0.04], [1.0, -1.0], dt=0.04), structure="pi", dt=0.05), ("dt",)),
    (dict(plant_or_plants=[make_plant([0.04], [1.0, -1.0], dt=0.04), make_plant([0.05], [1.0, -1.0], dt=0.05)],
          structure="pi"), ("plants", 1, "dt")),
    (dict(plant_or_plants=ROLL_P, structure="pi", spec={"ms_max": 2}), ("spec",)),
])
def test_invalid_problems_name_the_field(args, field):
    with pytest.raises(TunerError) as ei:
        TuningProblem.build(**args)
    assert ei.value.field == field, (ei.value, ei.value.field)


def test_problem_holds_the_validated_inputs_and_the_scale_once():
    zp = make_plant([0.04], [1.0, -1.0], dt=0.04)
    p = TuningProblem.build([zp], structure="pi", spec=Spec(ms_max=2.0))
    assert p.dt == 0.04 and p.structure.name == "pi" and p.spec.ms_max == 2.0 and p.nominal is zp
    assert p.scale == plant_scale(zp, 0.04)
