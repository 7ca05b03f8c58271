"""Inputs found by fuzzing the service: each must give the library's error (or a result), never a crash."""

from __future__ import annotations

import math
import re
import warnings

import numpy as np
import pytest

from tuner import TunerError, make_plant, plant_from_expr
from tuner.analysis.margins import disk_margin
from tuner.analysis.verify import analyze
from tuner.controllers import ControllerTF, controller_from_coeffs, controller_from_expr, controller_tf
from tuner.errors import InvalidControllerError, InvalidPlantError
from tuner.loop import build_loop
from tuner.lti import roots_of
from tuner.plant import make_plant_zpk
from tuner.tradeoff import tradeoff
from tuner.tuning import tune


def test_overflow_when_made_monic_is_rejected():
    with pytest.raises(InvalidPlantError, match="overflow"):
        make_plant([1e300], [1e-300, 1.0])


@pytest.mark.parametrize("den", [[1.0, 1e300], [1.0] + [1e20] * 20])
@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_extreme_coefficients_give_an_error_or_an_honest_result(den):
    try:
        plant = make_plant([1.0], den)  # the second: 19 roots near the unit circle, 1.5e-4 off beside -1e20
        r = tune(plant, structure="pi", dt=0.1, time_budget_s=120)
    except TunerError as e:  # an error must say what to change
        assert re.search(r"rescale|overflow|coefficient", str(e)), str(e)
    else:  # no spec claimed unless the verifier, run afresh on the returned controller, says so
        again = analyze(plant, r.controller, r.spec)
        assert again.meets_spec == r.meets_spec
        assert [(c.name, c.ok) for c in again.checks] == [(c.name, c.ok) for c in r.analyses[0].checks]


def test_sub_microsecond_continuous_delay_is_a_clear_error():
    with pytest.raises(InvalidPlantError, match="too short to simulate"):
        tune(make_plant([1.0], [1.0, 1.0], delay=1e-9), structure="pi", time_budget_s=5)


def test_a_tiny_budget_still_returns_a_verified_result():
    # the plant-based starts are always scored, so there is always a verified candidate to return
    r = tune(plant_from_expr("1/(s+1)"), structure="pi", dt=0.1, time_budget_s=0.01)
    assert r.solver["budget_exhausted"] is True
    # the verdict on stability, checked independently: closed-loop poles of the ZOH loop, written here
    a = math.exp(-0.1)  # G(z) = (1 - a)/(z - a)
    n0, n1 = (float(x) for x in r.controller.num)  # C(z) = (n0 z + n1)/(z - 1)
    assert list(r.controller.den) == [1.0, -1.0]
    poles = np.roots(np.polyadd(np.polymul([1.0, -a], [1.0, -1.0]), (1 - a) * np.array([n0, n1])))
    assert r.analyses[0].metrics.stable == bool(np.max(np.abs(poles)) < 1.0)


@pytest.mark.parametrize("seed", [-1, 2**32, 1.5])
def test_bad_seed(seed):
    with pytest.raises(TunerError, match="seed"):
        tune(plant_from_expr("1/(s+1)"), structure="pi", dt=0.1, seed=seed)


@pytest.mark.parametrize("budget", [True, 0, -1.0, math.inf, math.nan, "10"])
def test_bad_budget_is_named(budget):
    """``time_budget_s=True`` was taken as 1 s (a bool is an int): every non-number, and every number that is not a
    finite positive count of seconds, is refused by name, by ``tune`` and by ``tradeoff``."""
    with pytest.raises(TunerError, match="time_budget_s must be a finite number > 0"):
        tune(plant_from_expr("1/(s+1)"), structure="pi", dt=0.1, time_budget_s=budget)
    with pytest.raises(TunerError, match="time_budget_s must be a finite number > 0"):  # the trade-off curve too
        tradeoff(plant_from_expr("1/(s+1)"), structure="pi", dt=0.1, time_budget_s=budget)


# found by the property test (CI, stop 37): PI with Kp 1e-300 and Ki 1e300 is Kp (s + Ki/Kp)/s, a zero at -1e600,
# beyond double precision. Its roots could not be computed (numpy raised LinAlgError from inside analyze), whatever
# the form the controller came in; each form now names its field.
@pytest.mark.parametrize("make, field", [
    (lambda: controller_tf("pi", {"Kp": 1e-300, "Ki": 1e300}, dt=None), ("gains",)),
    (lambda: controller_from_coeffs([1e-300, 1e300], [1.0, 0.0], dt=None), ("den",)),
    (lambda: controller_from_expr("(1e-300*s + 1e300)/s", dt=None), ("expr",)),
    (lambda: plant_from_expr("(1e-300*s + 1e300)/(s + 1)"), ("expr",)),
    (lambda: plant_from_expr("1/(1e-300*s + 1e300)"), ("expr",)),
    # zeros at +-j 1e300: the numerator's companion matrix overflows (a denominator is made monic first, and
    # that overflow is refused before: test_overflow_when_made_monic_is_rejected)
    (lambda: make_plant([1e-300, 0.0, 1e300], [1.0, 1.0, 1.0]), ("num",)),
], ids=["structure", "coeffs", "controller expr", "plant zero", "plant pole", "plant num"])
def test_a_root_beyond_double_precision_is_named(make, field):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow warning escapes either
        with pytest.raises(TunerError, match="double precision|overflow") as e:
            make()
    assert e.value.field == field


def test_a_controller_built_directly_with_such_a_root_is_refused_by_analyze():
    """The factored form every computation uses is checked where it is made: a ControllerTF built without a
    constructor (as the search does) gives a named error from analyze, not numpy's."""
    c = ControllerTF(num=np.array([1e-300, 1e300]), den=np.array([1.0, 0.0]), dt=None)
    with pytest.raises(InvalidControllerError, match="double precision") as e:
        analyze(plant_from_expr("1e-100/(s + 1e-4)"), c)
    assert e.value.field == ("controller",)


@pytest.mark.parametrize("roots", [
    -np.logspace(0, 14, 8),  # a spread of 1e14
    np.array([-1.0, 0.0, 0.0, -2.0 + 3.0j, -2.0 - 3.0j]),  # exact zeros (trailing zero coefficients)
    np.array([-1e-200, -1e100]),  # balanced: both are found
])
def test_roots_of_keeps_well_posed_roots(roots):
    found = roots_of(np.real(np.poly(roots)))
    assert found is not None
    for r in roots:  # each given root has a computed one within 1e-6 relative
        assert np.min(np.abs(found - r)) <= 1e-6 * max(abs(r), 1e-300), (r, found)


def test_roots_of_keeps_a_pole_at_the_origin_of_a_long_dt():
    """A lead-lag at a long dt: its fast pole maps to z = exp(-p dt) ~ 1e-297, computed as (about) 0: at the
    origin for every purpose, and kept (refusing it refused valid controllers of the search's box)."""
    found = roots_of([1.0, -0.9997527631397585, 1.1968432220606134e-297])
    assert found is not None and np.sort(np.abs(found))[0] < 1e-290
    assert np.max(np.abs(found)) == pytest.approx(0.9997527631397585)


def test_a_crossing_beyond_the_grid_is_an_unknown_margin_not_none():
    """Found by the property test: L = 1e-300/(s (s - 1e6)) has an integrator, so |L| -> inf as w -> 0 and
    crosses 1 near w = 1e-300/1e6 = 1e-306 rad/s (closed form, |L| ~ 1e-306/w there), below the grid's floor of
    1e-300. The phase margin was reported as inf ("no crossing"); it is nan (unknown) and fails its limit."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the unstable loop's step overflows (said as inf)
        an = analyze(make_plant([1e-300], [1.0, -1e6, 0.0]), controller_from_coeffs([1.0], [1.0], dt=None))
    assert math.isnan(an.metrics.phase_margin_deg) and math.isnan(an.metrics.crossover_rad_s)
    assert not next(c for c in an.checks if c.name == "phase_margin_deg").ok
    # and a loop whose crossing is on the grid keeps its margin: 2(s+1)/s * 1/(s+1) = 2/s, PM 90 at 2 rad/s
    ok = analyze(plant_from_expr("1/(s+1)"), controller_from_coeffs([2.0, 2.0], [1.0, 0.0], dt=None))
    assert ok.metrics.phase_margin_deg == pytest.approx(90.0) and ok.metrics.crossover_rad_s == pytest.approx(2.0)


def test_a_crossing_just_beyond_the_grid_is_found_in_closed_form():
    """The grid ends two decades beyond every pole and zero; a loop with |L| = 1 within rounding of an end crosses
    just beyond it, and the margin is searched there (a cold review found them turned to nan by the first fix).
    K/(s+1), K = 1.00001: |L| = 1 at w = sqrt(K^2 - 1), PM = 180 - atan(w) deg. K (s+2)/(s+1), K = 0.99999 (biproper,
    |L| -> K < 1 at high frequency): |L|^2 = K^2 (w^2 + 4)/(w^2 + 1) = 1 at w^2 = (4K^2 - 1)/(1 - K^2), PM =
    180 - |atan(w/2) - atan(w)|."""
    k = 1.00001
    low = analyze(plant_from_expr("1/(s+1)"), controller_from_coeffs([k], [1.0], dt=None)).metrics
    wc = math.sqrt(k * k - 1)
    assert low.crossover_rad_s == pytest.approx(wc, rel=1e-6)
    assert low.phase_margin_deg == pytest.approx(180 - math.degrees(math.atan(wc)), abs=1e-6)
    k = 0.99999
    high = analyze(plant_from_expr("(s+2)/(s+1)"), controller_from_coeffs([k], [1.0], dt=None)).metrics
    wc = math.sqrt((4 * k * k - 1) / (1 - k * k))
    assert high.crossover_rad_s == pytest.approx(wc, rel=1e-6)
    assert high.phase_margin_deg == pytest.approx(180 - abs(math.degrees(math.atan(wc / 2) - math.atan(wc))),
                                                  abs=1e-6)


@pytest.mark.parametrize("plant, num, den, dt", [
    ("1/(s+1)", [1.0], [1.0], 0.01),  # |L(z=1)| = 1 to rounding, below 1 elsewhere
    ("1e-11/(s+1e-10)", [1.0], [1.0], None),  # a pole near DC: |L| <= 0.1
    ("1/s", [0.5, 0.0], [1.0, 1.0], None),  # a washout cancelling the integrator: L = 0.5/(s+1)
    ("0.5*s/(s+1)^2", [1.0, 1.0], [1.0, 0.0], None),  # PI cancelling the plant's zero at 0: L = 0.5/(s+1)
], ids=["unit DC gain", "pole near DC", "washout", "PI on a differentiator"])
def test_a_loop_below_one_everywhere_has_no_crossing(plant, num, den, dt):
    """|L| < 1 at every frequency (closed forms in the ids): no crossing, PM inf, not nan."""
    m = analyze(plant_from_expr(plant), controller_from_coeffs(num, den, dt=dt)).metrics
    assert m.phase_margin_deg == math.inf and math.isnan(m.crossover_rad_s)


def test_the_disk_margin_of_a_loop_gain_near_double_precision_is_a_number():
    """Found by the property test: at |L| ~ 1e308, |1 +- L| overflowed and the ratio 2|1+L|/|1-L| was
    inf/inf = nan, which min() then kept. Closed forms: L = 3 gives 2*4/2 = 4; L = 1.2e308 (1 + j) gives
    2 |1 + L| / |1 - L| = 2 (1 + O(1e-308)) = 2; the loop's own limit, the static 0.5 at z = 1, 2*1.5/0.5 = 6."""
    loop = build_loop(make_plant([0.5], [1.0], dt=0.1), controller_from_coeffs([1.0], [1.0], dt=0.1))
    dm = disk_margin(loop, np.array([1.0, 2.0]), np.array([1.2e308 + 1.2e308j, 3.0]))
    assert dm == pytest.approx(2.0, rel=1e-12)


def test_a_real_axis_point_near_an_imaginary_axis_pole_does_not_overflow():
    """Found by the property test: abs() of a complex L near the pole pair at +-j overflowed (Python raises
    OverflowError). L = 1e300 (s + 1e-4)^2 (s + 1e4) / ((s^2 + 1)(s + 1)^3): relative degree 2, so two closed-loop
    poles go to the root locus's asymptotes, centred at (sum of poles - sum of zeros)/2 = (-3 + 1e4 + 2e-4)/2
    ~ +5000 > 0: they are in the right half-plane and the loop is unstable."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        an = analyze(make_plant_zpk([-1e-4, -1e-4, -1e4], [1j, -1j, -1.0, -1.0, -1.0], 1.0),
                     controller_from_coeffs([1e300], [1.0], dt=None))
    assert an.metrics.stable is False and an.meets_spec is False


def test_a_singular_steady_state_in_a_batch_costs_only_its_own_candidate():
    """Found by the property test: numpy solves a stack all or nothing, so one loop whose steady-state matrix is
    singular in double precision failed the tune with LinAlgError. Now that loop's final value is unknown (nan)
    and the others' are exact: I z = b gives z = b."""
    from tuner.optimize.batch import _solve_dc

    M = np.stack([np.eye(2), np.zeros((2, 2)), 2 * np.eye(2)])
    b = np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]])
    z = _solve_dc(M, b)
    assert z[0].tolist() == [1.0, 2.0] and np.all(np.isnan(z[1])) and z[2].tolist() == [2.5, 3.0]


@pytest.mark.parametrize("delay", [1e308, 1e20, 8.1])
def test_a_delay_beyond_the_sample_limit_is_refused_before_the_discretisation(delay):
    """Issue 42 (found mutating an identification's delay): a delay of 1e308 s at dt 0.04 overflowed the plant's
    discretisation (OverflowError: exit 3); the 200-sample limit is checked first."""
    with pytest.raises(InvalidPlantError, match="above the limit of 200 samples") as e:
        build_loop(make_plant([1.0], [1.0, 1.0], delay=delay), controller_from_expr("2*(z-0.5)/(z-1)", dt=0.04))
    assert e.value.field == ("plant", "delay")
