"""TuningProblem: one statement of the problem, validated once, errors located by ``field``."""

from __future__ import annotations

import cmath
import math

import pytest
from quadrotor import DT, ROLL

from tuner import Spec, TunerError, TuningProblem, make_plant, plant_from_expr

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
    # the scale in closed form: G = 0.04/(z - 1) has phase -(90 deg + w dt/2), -135 deg at w0 = pi/(2 dt)
    # (the ultimate frequency is Nyquist's, excluded), and |G(w0)| = 0.04/|e^{j pi/2} - 1| = 0.04/sqrt(2);
    # the scale is read off an 800-point log grid (1.7 % apart)
    k0, w0 = p.scale
    assert w0 == pytest.approx(math.pi / (2 * 0.04), rel=0.02)
    assert k0 == pytest.approx(abs(cmath.exp(1j * w0 * 0.04) - 1) / 0.04, rel=1e-12)
    assert k0 == pytest.approx(math.sqrt(2) / 0.04, rel=0.02)
    assert p.scale is p.scale  # computed once
