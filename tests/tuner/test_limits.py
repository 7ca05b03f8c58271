"""The documented limits (README "Limits"), each refused before any work with the field that is over it."""

from __future__ import annotations

import pytest

from tuner import TunerError, TuningProblem, analyze, controller_from_coeffs, controller_from_expr, controller_tf
from tuner.controllers import MAX_CONTROLLER_ORDER
from tuner.loop import MAX_DELAY_SAMPLES, build_loop
from tuner.plant import MAX_DT_S, MIN_DT_S, plant_from_expr


def test_one_controller_order_limit_for_both_forms():
    n = MAX_CONTROLLER_ORDER
    ok_expr = f"(s+1)^{n // 2}*(s+1)^{n - n // 2}/((s+2)^{n // 2}*(s+2)^{n - n // 2})"
    assert controller_from_expr(ok_expr, dt=None).den.size == n + 1
    assert controller_from_coeffs([1.0], [1.0] * (n + 1), dt=None).den.size == n + 1
    with pytest.raises(TunerError, match=f"order {n + 1} is above the limit {n}") as ei:
        controller_from_expr(ok_expr + "/(s+3)", dt=None)
    assert ei.value.field == ("expr",)
    with pytest.raises(TunerError, match=f"order {n + 1} is above the limit {n}") as ei:
        controller_from_coeffs([1.0], [1.0] * (n + 2), dt=None)
    assert ei.value.field == ("den",)
    # the degree-80 expression (accepted, then a 500)
    with pytest.raises(TunerError, match="order 80") as ei:
        controller_from_expr("(s+1)^40*(s+1)^40/((s+2)^40*(s+2)^40)", dt=None)
    assert ei.value.field == ("expr",)


@pytest.mark.parametrize("dt", [MIN_DT_S / 10, MAX_DT_S * 10, 0.0, -1.0, float("nan"), float("inf"), "fast", True])
def test_dt_range(dt):
    with pytest.raises(TunerError) as ei:
        controller_tf("pi", {"Kp": 1.0, "Ki": 1.0}, dt=dt)
    assert ei.value.field == ("dt",)
    with pytest.raises(TunerError) as ei:
        TuningProblem.build(plant_from_expr("1/(s+1)"), structure="pi", dt=dt)
    assert ei.value.field == ("dt",)


def test_dt_range_ends_are_accepted():
    for dt in (MIN_DT_S, MAX_DT_S):
        assert controller_tf("pi", {"Kp": 1.0, "Ki": 1.0}, dt=dt).dt == dt


def test_delay_in_samples_limit():
    dt = 0.01
    c = controller_tf("pi", {"Kp": 0.1, "Ki": 0.05}, dt=dt)
    build_loop(plant_from_expr("1/(s+1)", delay=MAX_DELAY_SAMPLES * dt), c)  # at the limit: accepted
    over = plant_from_expr("1/(s+1)", delay=(MAX_DELAY_SAMPLES + 1) * dt)
    with pytest.raises(TunerError, match=f"above the limit of {MAX_DELAY_SAMPLES} samples") as ei:
        analyze(over, c)
    assert ei.value.field == ("plant", "delay")
    with pytest.raises(TunerError, match="give a larger sample time") as ei:
        TuningProblem.build([plant_from_expr("1/(s+1)"), over], structure="pi", dt=dt)
    assert ei.value.field == ("plants", 1, "delay")
    # the same delay in a continuous loop is fine (4000 fine steps whatever the delay)
    assert TuningProblem.build(over, structure="pi").dt is None


def test_stability_undecidable_is_refused_with_the_field():
    """PI with gains 1e150 on 1/(s+1): poles at -1 and -1e150; the eigenvalues' error (~1e3 eps ||A||) is far
    larger than 1, so double precision cannot say whether the slow pole is left of the axis."""
    with pytest.raises(TunerError, match="too many decades") as ei:
        analyze(plant_from_expr("1/(s+1)"), controller_tf("pi", {"Kp": 1e150, "Ki": 1e150}, dt=None))
    assert ei.value.field == ("controller",)


def test_stiff_but_decidable_loop_is_stable():
    """PI with gains 1e10 on 1/(s+1): closed loop (s+1)(s+1e10), stable. The previous rule (every pole left of
    -1e-9 * the largest pole's magnitude, i.e. of -10) called it unstable."""
    an = analyze(plant_from_expr("1/(s+1)"), controller_tf("pi", {"Kp": 1e10, "Ki": 1e10}, dt=None))
    assert an.metrics.stable


def test_campaign_finds_answer_with_the_field():
    """Three 500s of bench/hostile.py's first run, each now a TunerError naming the field or an answer."""
    from tuner import make_plant

    # 1e200/(s+1e100) with 1e200 (s+1)/(s+1e100): each finite, the loop's products overflow
    with pytest.raises(TunerError, match="product of the plant's and the controller's gains") as ei:
        analyze(make_plant([1e100], [1e-100, 1.0]), controller_from_coeffs([1e100, 1e100], [1e-100, 1.0], dt=None))
    assert ei.value.field == ("controller",)
    # a controller whose own realisation overflows (gain 1e200, pole at -1e200)
    with pytest.raises(TunerError, match="realisation overflows") as ei:
        controller_from_coeffs([1e100, 1e-100], [1e-100, 1e100], dt=None)
    assert ei.value.field == ("den",)
    # a pole at 0 and a zero at 2e59: the section pairing took log(0) (math domain error)
    p = make_plant([4.4532155357515966e-58, -95.88195199719486],
                   [1.0, -4.0560509220854306e+51, 2.5304970965264796e+41, -2.536894277375648e+59,
                    3.054748781226136e-11, 7.016154498437253e-17, 0.2339484807328639, 0.001006527050394427,
                    706.5491265075992, 971.4541594422008, 7.160237279471231e-22, 7.09600543634719])
    an = analyze(p, controller_from_expr("1.7377440335371554e-175*(s+0.5)/(s+0.9)", dt=None))
    assert an.metrics.stable is False  # poles at +4e51 and more: unstable whatever the tiny gain
