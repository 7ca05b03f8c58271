"""Plants: validation rules, normalisation, delay, ZOH and its inverse, checked by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
import reference as ref
from numpy.testing import assert_allclose

from tuner.errors import InvalidExpressionError, InvalidPlantError, TunerError
from tuner.plant import MAX_ORDER, Plant, make_plant, plant_from_expr

# -- validation: every rule, with a message naming the problem ------------------------------

NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize(
    "num, den, kw, words",
    [
        ([1], [1, NAN], {}, "den has non-finite coefficients"),
        ([1], [1, INF], {}, "den has non-finite coefficients"),
        ([INF], [1, 1], {}, "num has non-finite coefficients"),
        ([1, -INF], [1, 1], {}, "num has non-finite coefficients"),
        ([1], [1, None], {}, "non-finite"),
        ([1], [0], {}, "den is zero"),
        ([1], [0, 0, 0], {}, "den is zero"),
        ([0], [1, 1], {}, "num is zero"),
        ([0, 0], [1, 1], {}, "num is zero"),
        ([1, 0, 0], [1, 1], {}, "improper"),
        ([1, 2], [0, 0, 5], {}, "improper"),  # leading zeros trimmed first: (s+2)/5 is improper
        ([], [1], {}, "num must be a non-empty list"),
        ([1], [], {}, "den must be a non-empty list"),
        ([1], [[1, 2], [3, 4]], {}, "den must be a non-empty list"),
        (["a"], [1, 1], {}, "num must be a list of numbers"),
        ([1], [1, 1, 1], {"max_order": 1}, "plant order 2 is above the limit 1"),
        ([1], [1, 1], {"dt": 0}, "dt must be finite and > 0"),
        ([1], [1, 1], {"dt": -0.04}, "dt must be finite and > 0"),
        ([1], [1, 1], {"dt": NAN}, "dt must be finite and > 0"),
        ([1], [1, 1], {"dt": INF}, "dt must be finite and > 0"),
        ([1], [1, 1], {"dt": "fast"}, "dt must be a number"),
        ([1], [1, 1], {"delay": -0.1}, "delay must be finite and >= 0"),
        ([1], [1, 1], {"delay": NAN}, "delay must be finite and >= 0"),
        ([1], [1, 1], {"delay": INF}, "delay must be finite and >= 0"),
        ([1], [1, 1], {"delay": "long"}, "delay must be a number"),
        # in discrete time a delay is a whole number of samples: 0.05/0.04 = 1.25
        ([1], [1, -0.5], {"dt": 0.04, "delay": 0.05}, "not a whole number of samples"),
        ([1], [1, -0.5], {"dt": 0.04, "delay": 0.001}, "not a whole number of samples"),
    ],
)
def test_make_plant_rejects(num, den, kw, words):
    with pytest.raises(InvalidPlantError) as ei:
        make_plant(num, den, **kw)
    assert words in str(ei.value)
    assert isinstance(ei.value, ValueError) and isinstance(ei.value, TunerError)


def test_order_limit_default_is_20():
    assert MAX_ORDER == 20
    den20 = np.poly(-np.arange(1, 21) / 10)
    assert make_plant([1], den20).order == 20
    with pytest.raises(InvalidPlantError, match="plant order 21 is above the limit 20"):
        make_plant([1], np.poly(-np.arange(1, 22) / 10))
    with pytest.raises(InvalidPlantError, match="above the limit 20"):
        plant_from_expr("1/(s+1)^21")
    assert plant_from_expr("1/(s+1)^21", max_order=21).order == 21


@pytest.mark.parametrize(
    "text, kw, err, words",
    [
        ("1/(z-0.5)", {}, InvalidPlantError, "plant is in z: give its sample time dt"),
        ("s/(z+1)", {"dt": 0.04}, InvalidExpressionError, "mixes 's' and 'z'"),
        ("z/(s+1)", {}, InvalidExpressionError, "mixes 's' and 'z'"),
        ("s^2/(s+1)", {}, InvalidPlantError, "improper"),
        ("0/(s+1)", {}, InvalidPlantError, "num is zero"),
        ("(s-s)/(s+1)", {}, InvalidPlantError, "num is zero"),
        ("1/(z-0.5)", {"dt": 0}, InvalidPlantError, "dt must be finite and > 0"),
        ("1/(z-0.5)", {"dt": NAN}, InvalidPlantError, "dt must be finite and > 0"),
        ("1/(z-0.5)", {"dt": 0.04, "delay": 0.06}, InvalidPlantError, "not a whole number of samples"),
        ("1/(z-0.5)", {"dt": 0.04, "delay": -0.04}, InvalidPlantError, "delay must be finite and >= 0"),
        ("1/(s+1)", {"delay": -1}, InvalidPlantError, "delay must be finite and >= 0"),
    ],
)
def test_plant_from_expr_rejects(text, kw, err, words):
    with pytest.raises(err) as ei:
        plant_from_expr(text, **kw)
    assert words in str(ei.value)


# -- what a valid plant holds -------------------------------------------------------------

def test_coefficients_normalised_monic_and_trimmed():
    p = make_plant([0, 0, 4, 8], [0, 2, 6, 4])  # (4s+8)/(2s^2+6s+4) = (2s+4)/(s^2+3s+2)
    assert_allclose(p.num, [2, 4])
    assert_allclose(p.den, [1, 3, 2])
    assert p.dt is None and p.order == 2 and not p.is_discrete


def test_open_loop_unstable_plants_are_accepted():
    p = plant_from_expr("1/((s-1)(s+3))")
    assert_allclose(p.den, [1, 2, -3])
    q = make_plant([1], [1, -1.5], dt=0.1)  # pole at z = 1.5
    assert q.is_discrete and q.dt == 0.1


def test_s_expression_ignores_loop_dt_and_z_expression_takes_it():
    p = plant_from_expr("1/(s+1)", dt=0.04)
    assert p.dt is None  # the loop's sample time; the model stays continuous
    q = plant_from_expr("0.5/(z-0.5)", dt=0.04)
    assert q.dt == 0.04
    assert_allclose(q.num, [0.5])


def test_dc_gain_by_hand():
    assert make_plant([3], [1, 2]).dc_gain() == pytest.approx(1.5)  # 3/2
    assert make_plant([0.5], [1, -0.5], dt=0.1).dc_gain() == pytest.approx(1.0)  # 0.5/(1-0.5)
    assert make_plant([1], [1, 0]).dc_gain() == math.inf
    assert make_plant([-1], [1, -1], dt=0.1).dc_gain() == -math.inf


def test_freqresp_by_hand_with_exact_delay():
    p = make_plant([1], [1, 1], delay=0.3)
    w = np.array([1.0, 2.0])
    # 1/(1 + jw) * exp(-j 0.3 w)
    expected = 1 / (1 + 1j * w) * np.exp(-0.3j * w)
    assert_allclose(p.freqresp(w), expected, rtol=1e-14)
    d = make_plant([1], [1, -0.5], dt=0.1)
    z = np.exp(1j * w * 0.1)
    assert_allclose(d.freqresp(w), 1 / (z - 0.5), rtol=1e-14)


def test_discrete_delay_folded_as_whole_samples():
    p = make_plant([0.5], [1, -0.5], dt=0.04, delay=0.12)  # 3 samples
    num, den = p.rational_discrete()
    assert_allclose(num, [0.5])
    assert_allclose(den, [1, -0.5, 0, 0, 0])  # (z - 0.5) z^3
    with pytest.raises(InvalidPlantError, match="continuous"):
        make_plant([1], [1, 1]).rational_discrete()


# -- ZOH discretisation -------------------------------------------------------------------

def test_zoh_first_order_closed_form():
    # ZOH of K a/(s+a): K (1 - e^{-a dt}) / (z - e^{-a dt})
    K, a, dt = 2.0, 3.0, 0.1
    d = make_plant([K * a], [1, a]).zoh(dt)
    e = math.exp(-a * dt)
    assert_allclose(d.num, [K * (1 - e)], rtol=1e-12)
    assert_allclose(d.den, [1, -e], rtol=1e-12)
    assert d.dt == dt


def test_zoh_double_integrator_closed_form():
    # ZOH of 1/s^2: dt^2 (z + 1) / (2 (z - 1)^2)
    dt = 0.04
    d = make_plant([1], [1, 0, 0]).zoh(dt)
    assert_allclose(d.num, [dt**2 / 2, dt**2 / 2], rtol=1e-10)
    assert_allclose(d.den, [1, -2, 1], rtol=1e-12)


@pytest.mark.parametrize("num, den", [([5.0], [1, 2, 5]), ([1, 3], [1, 4, 6, 4]), ([2, 0], [1, 1, 9])])
def test_zoh_matches_matrix_exponential(num, den):
    dt = 0.05
    d = make_plant(num, den).zoh(dt)
    b, a = ref.zoh(num, den, dt)  # augmented matrix exponential, written in tests/reference.py
    assert_allclose(d.den, a, rtol=1e-9, atol=1e-12)
    assert_allclose(d.num, b, rtol=1e-8, atol=1e-12)


def test_zoh_carries_whole_sample_delay_and_a_fraction_in_the_realisation():
    p = make_plant([1], [1, 1], delay=0.08)
    d = p.zoh(0.04)
    assert d.delay_s == pytest.approx(0.08) and d.zoh_fraction == 0.0
    assert_allclose(d.rational_discrete()[1], np.concatenate([d.den, [0, 0]]))
    # 0.05 = 1 sample + 0.01 s: the modified z-transform of 1/(s+1), written out:
    # G(z) = z^-1 [(1 - e^{-(dt-phi)}) z + (e^{-(dt-phi)} - e^{-dt})] / (z (z - e^{-dt}))
    f = make_plant([1], [1, 1], delay=0.05).zoh(0.04)
    assert f.delay_s == pytest.approx(0.04) and f.zoh_fraction == pytest.approx(0.01)
    z = np.exp(1j * np.linspace(0.1, 70, 9) * 0.04)
    a, b = math.exp(-0.03), math.exp(-0.04)
    want = ((1 - a) * z + (a - b)) / (z * (z - b)) / z
    got = np.polyval(f.num, z) / np.polyval(f.den, z) / z
    assert_allclose(got, want, rtol=1e-10)


def test_zoh_of_discrete_plant():
    d = make_plant([0.5], [1, -0.5], dt=0.04)
    assert d.zoh(0.04) is d
    with pytest.raises(InvalidPlantError, match="resampling"):
        d.zoh(0.02)
    with pytest.raises(InvalidPlantError, match="dt must be finite"):
        make_plant([1], [1, 1]).zoh(0.0)


# -- continuous equivalent (inverse ZOH) --------------------------------------------------

@pytest.mark.parametrize(
    "num, den, dt",
    [
        ([5.2911073], [1, 18.611], 0.04),
        ([4.0], [1, 0.8, 4.0], 0.04),
        ([1, 3], [1, 5, 6], 0.1),
        ([2.0], [1, -1.0], 0.05),  # open-loop unstable
    ],
)
def test_continuous_equivalent_round_trips(num, den, dt):
    c = make_plant(num, den)
    d = c.zoh(dt)
    back = d.continuous_equivalent()
    assert back is not None and back.dt is None
    assert_allclose(back.den, c.den, rtol=1e-7, atol=1e-9)
    assert_allclose(back.num, c.num, rtol=1e-7, atol=1e-9)
    again = back.zoh(dt)
    assert_allclose(again.num, d.num, rtol=1e-9)
    assert_allclose(again.den, d.den, rtol=1e-9)


def test_continuous_equivalent_of_integrators_by_hand():
    # 0.04/(z-1) at dt = 0.04 is the ZOH of 1/s
    ce = make_plant([0.04], [1, -1], dt=0.04).continuous_equivalent()
    assert_allclose(ce.num, [1.0], rtol=1e-9)
    assert_allclose(ce.den, [1.0, 0.0], atol=1e-12)
    # 1/(z-1)^2 at dt = 0.1: -5*ZOH[1/s] + 100*ZOH[1/s^2]
    #   = (-0.5(z-1) + 0.5(z+1))/(z-1)^2 = 1/(z-1)^2, so the answer is (-5 s + 100)/s^2
    ce2 = make_plant([1], [1, -2, 1], dt=0.1).continuous_equivalent()
    assert_allclose(ce2.num, [-5.0, 100.0], rtol=1e-7)
    assert_allclose(ce2.den, [1.0, 0.0, 0.0], atol=1e-9)


@pytest.mark.parametrize("den", [[1, 0.5], [1, 0], [1, 0.3, 0.0]])
def test_continuous_equivalent_none_for_poles_on_negative_axis_or_zero(den):
    # a ZOH equivalent has poles exp(p dt): never on the negative real axis or at 0
    assert make_plant([1], den, dt=0.1).continuous_equivalent() is None


def test_continuous_equivalent_of_continuous_plant_is_itself():
    p = make_plant([1], [1, 1])
    assert p.continuous_equivalent() is p


def test_describe_names_dt_and_delay():
    s = make_plant([0.5], [1, -0.5], dt=0.04, delay=0.08).describe()
    assert "z" in s and "dt=0.04" in s and "delay=0.08 s" in s
    assert isinstance(make_plant([1], [1, 1]), Plant)
