"""The quadrotor thesis case (shared/reference/quadrotor.md): its models and controllers as printed."""

from __future__ import annotations

import math

import numpy as np
import pytest
import reference as ref
from quadrotor import ALT_C, ALT_PLANT, DT, PITCH, PITCH_C, ROLL, ROLL_C, YAW, YAW_C, scaled

from tuner.analysis.verify import analyze
from tuner.controllers import controller_from_expr
from tuner.plant import plant_from_expr

# -- ZOH at 0.04 s reproduces the thesis's discrete models, to the printed digits ---------------

# G(z) as printed: (numerator coefficients, denominator coefficients after the leading 1)
PRINTED_DISCRETE = {
    "yaw": (YAW, ["0.1493"], ["-0.475"]),
    "roll": (ROLL, ["0.03802", "0.03141"], ["-1.305", "0.5668"]),
    "pitch": (PITCH, ["0.003564", "0.0034"], ["-1.85", "0.8686"]),
}


def _sig_digits(printed: str) -> int:
    digits = printed.lstrip("-").replace(".", "").lstrip("0")
    return len(digits)


def _as_printed(value: float, printed: str) -> str:
    return f"{value:.{_sig_digits(printed)}g}"


@pytest.mark.parametrize("axis", sorted(PRINTED_DISCRETE))
def test_zoh_reproduces_thesis_discrete_models(axis):
    expr, num_p, den_p = PRINTED_DISCRETE[axis]
    d = plant_from_expr(expr).zoh(DT)
    assert d.dt == DT
    assert d.den[0] == 1.0
    assert [_as_printed(v, p) for v, p in zip(d.num, num_p)] == num_p
    assert [_as_printed(v, p) for v, p in zip(d.den[1:], den_p)] == den_p
    assert d.num.size == len(num_p) and d.den.size == len(den_p) + 1


def test_zoh_yaw_closed_form():
    # 0.2843 * 18.611/(s + 18.611): b = 0.2843 (1 - e^{-18.611*0.04}), pole e^{-18.611*0.04}
    p = math.exp(-18.611 * DT)
    d = plant_from_expr(YAW).zoh(DT)
    np.testing.assert_allclose(d.num, [0.2843 * (1 - p)], rtol=1e-12)
    np.testing.assert_allclose(d.den, [1, -p], rtol=1e-12)


@pytest.mark.parametrize("expr", [YAW, ROLL, PITCH])
def test_continuous_equivalent_of_thesis_models_round_trips(expr):
    c = plant_from_expr(expr)
    back = c.zoh(DT).continuous_equivalent()
    np.testing.assert_allclose(back.den, c.den, rtol=1e-8)
    np.testing.assert_allclose(back.num, c.num, rtol=1e-8)


# -- the attitude controllers as printed, analysed as sampled-data loops -------------------------

# expected figures: quadrotor.md, "These rows do not reproduce. Evaluated as printed ..."
ROWS = {
    "roll_x1": (ROLL, ROLL_C, dict(pm=75.4, gm=18.3, overshoot=(0.0, 0.05), settling=0.43)),
    "pitch_x1": (PITCH, PITCH_C, dict(pm=75.1, gm=17.8, settling=0.42)),
    "pitch_x2.7": (PITCH, scaled(PITCH_C, 2.7), dict(pm=51.4, overshoot=(18.9, 0.05))),
    "yaw_K1": (YAW, YAW_C, dict(pm=77.2, settling=0.82)),
    "altitude": (ALT_PLANT, ALT_C, dict(pm=22.9, overshoot=(59.0, 0.5))),
}


@pytest.fixture(scope="module")
def analysed():
    out = {}
    for name, (g, c, _) in ROWS.items():
        out[name] = analyze(plant_from_expr(g, dt=DT), controller_from_expr(c, dt=DT))
    return out


@pytest.mark.parametrize("name", sorted(ROWS))
def test_thesis_rows_as_evaluated_on_the_reference_page(name, analysed):
    m = analysed[name].metrics
    exp = ROWS[name][2]
    assert m.stable
    # the page rounds to 0.1 deg / 0.1 dB / 0.01 s: within 0.5 deg, 0.2 dB, 0.01 s
    assert m.phase_margin_deg == pytest.approx(exp["pm"], abs=0.5)
    if "gm" in exp:
        assert m.gain_margin_db == pytest.approx(exp["gm"], abs=0.2)
    if "settling" in exp:
        assert m.settling_time_s == pytest.approx(exp["settling"], abs=0.01)
    if "overshoot" in exp:
        value, tol = exp["overshoot"]
        assert m.overshoot_pct == pytest.approx(value, abs=tol)
    assert m.steady_state_error == pytest.approx(0.0, abs=1e-9)  # every loop has an integrator


def test_thesis_claims_do_not_reproduce(analysed):
    # claimed in the thesis: roll 12.3 dB / 68.6 deg; pitch (x2.7) 60.1 deg; altitude 11.1 dB / 65.9 deg
    assert abs(analysed["roll_x1"].metrics.gain_margin_db - 12.3) > 5
    assert abs(analysed["roll_x1"].metrics.phase_margin_deg - 68.6) > 5
    assert analysed["pitch_x2.7"].metrics.phase_margin_deg < 60.1 - 5
    assert abs(analysed["altitude"].metrics.phase_margin_deg - 65.9) > 40


def test_pitch_x27_fails_phase_margin_and_overshoot(analysed):
    a = analysed["pitch_x2.7"]
    assert not a.meets_spec
    failing = {c.name: c for c in a.failing}
    assert set(failing) == {"phase_margin_deg", "overshoot_pct"}
    assert failing["phase_margin_deg"].required == 60.0
    assert failing["phase_margin_deg"].achieved == pytest.approx(51.4, abs=0.5)
    assert failing["overshoot_pct"].required == 10.0
    assert failing["overshoot_pct"].achieved == pytest.approx(18.9, abs=0.05)


@pytest.mark.parametrize("name", ["roll_x1", "pitch_x1", "yaw_K1"])
def test_printed_gains_meet_the_spec(name, analysed):
    assert analysed[name].meets_spec, [(c.name, c.achieved) for c in analysed[name].failing]


def test_altitude_as_printed_fails_on_margins_and_overshoot(analysed):
    a = analysed["altitude"]
    assert {c.name for c in a.failing} == {"phase_margin_deg", "overshoot_pct"}
    # its true upper gain margin is at the Nyquist frequency: k < 12.5 by Jury (see test_margins)
    assert a.metrics.gain_margin_db == pytest.approx(20 * math.log10(12.5), abs=1e-6)


def test_yaw_tuned_gain_is_unstable():
    """Yaw x10.7924: roots of the uncancelled characteristic polynomial computed here.

    ZOH of the yaw model (closed form) b/(z - p), controller K (z - 0.475)/(z (z - 1)):
    char = z (z - 1)(z - p) + K b (z - 0.475).
    """
    K = 10.7924
    p = math.exp(-18.611 * DT)
    b = 0.2843 * (1 - p)
    char = np.polyadd(np.polymul([1, -1, 0], [1, -p]), K * b * np.array([1, -0.475]))
    assert np.max(np.abs(np.roots(char))) > 1.0
    a = analyze(plant_from_expr(YAW), controller_from_expr(scaled(YAW_C, K), dt=DT))
    assert not a.metrics.stable
    assert np.max(np.abs(a.poles)) == pytest.approx(np.max(np.abs(np.roots(char))), rel=1e-9)
    assert not a.meets_spec
    assert math.isnan(a.metrics.overshoot_pct) and a.metrics.settling_time_s == math.inf


@pytest.mark.parametrize("name", ["roll_x1", "yaw_K1", "pitch_x2.7"])
def test_thesis_margins_match_bruteforce(name, analysed):
    a = analysed[name]
    g, c, _ = ROWS[name]
    gp, cc = plant_from_expr(g), controller_from_expr(c, dt=DT)  # the coefficients as written
    b = ref.nyquist_margins(*ref.open_loop(gp.num, gp.den, cc.num, cc.den, DT), DT)
    assert a.metrics.phase_margin_deg == pytest.approx(b["pm"], abs=0.01)
    assert a.metrics.gain_margin_db == pytest.approx(b["gm_db"], abs=0.01)
    assert a.metrics.gain_margin_lower_db == b["gml_db"] == -math.inf

