"""Controller structures against the formulas documented in tuner/controllers.py, by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from quadrotor import DT, PITCH, ROLL, YAW

from tuner.controllers import STRUCTURES, controller_from_expr, controller_tf, get_structure
from tuner.errors import InvalidControllerError, InvalidExpressionError, TunerError
from tuner.optimize.design import bounds, initial_guess
from tuner.plant import plant_from_expr

# -- discrete forms at dt, hand-computed coefficients ------------------------------------------


def test_pi_discrete_backward_euler_by_hand():
    # Kp + Ki dt z/(z-1) with Kp=2, Ki=3, dt=0.1: (2(z-1) + 0.3 z)/(z-1) = (2.3 z - 2)/(z - 1)
    c = controller_tf("pi", {"Kp": 2, "Ki": 3}, dt=0.1)
    assert_allclose(c.num, [2.3, -2.0], rtol=1e-14)
    assert_allclose(c.den, [1.0, -1.0])
    assert c.dt == 0.1


def test_pd_discrete_by_hand():
    # Kp + Kd (z-1)/((Tf+dt) z - Tf), Kp=2, Kd=0.5, Tf=0.05, dt=0.1:
    # 2 + 0.5(z-1)/(0.15 z - 0.05) = (0.3z - 0.1 + 0.5z - 0.5)/(0.15z - 0.05) = (16/3 z - 4)/(z - 1/3)
    c = controller_tf("pd", {"Kp": 2, "Kd": 0.5, "Tf": 0.05}, dt=0.1)
    assert_allclose(c.num, [16 / 3, -4.0], rtol=1e-13)
    assert_allclose(c.den, [1.0, -1 / 3], rtol=1e-13)


def test_pid_discrete_by_hand():
    # sum of the two above: (2.3z-2)/(z-1) + (10/3)(z-1)/(z-1/3)
    # num = (2.3z-2)(z-1/3) + (10/3)(z-1)^2 = 5.63333 z^2 - 9.43333 z + 4
    # den = (z-1)(z-1/3) = z^2 - 4/3 z + 1/3
    c = controller_tf("pid", {"Kp": 2, "Ki": 3, "Kd": 0.5, "Tf": 0.05}, dt=0.1)
    assert_allclose(c.num, [2.3 + 10 / 3, -2.3 / 3 - 2 - 20 / 3, 2 / 3 + 10 / 3], rtol=1e-13)
    assert_allclose(c.den, [1.0, -4 / 3, 1 / 3], rtol=1e-13)


def test_pid_discrete_with_zero_filter_is_the_backward_difference():
    # Tf = 0: Kd (z-1)/(dt z); with Kp=1, Ki=1, Kd=1, dt=0.1:
    # 1 + 0.1 z/(z-1) + 10 (z-1)/z = (z(z-1) + 0.1 z^2 + 10 (z-1)^2)/(z(z-1)) = (11.1 z^2 - 21 z + 10)/(z^2 - z)
    c = controller_tf("pid", {"Kp": 1, "Ki": 1, "Kd": 1, "Tf": 0}, dt=0.1)
    assert_allclose(c.num, [11.1, -21.0, 10.0], rtol=1e-13)
    assert_allclose(c.den, [1.0, -1.0, 0.0], atol=1e-15)


def test_pid_z_is_the_thesis_form():
    # K (z^2 + a1 z + a2)/(z (z-1)) with the printed roll controller
    c = controller_tf("pid_z", {"K": 3.868, "a1": -1.305, "a2": 0.5668}, dt=DT)
    assert_allclose(c.num, [3.868, 3.868 * -1.305, 3.868 * 0.5668], rtol=1e-14)
    assert_allclose(c.den, [1.0, -1.0, 0.0])
    # same as the expression the thesis prints
    e = controller_from_expr("3.868*(z^2-1.305*z+0.5668)/(z*(z-1))", dt=DT)
    assert_allclose(c.num, e.num, rtol=1e-14)
    assert_allclose(c.den, e.den, atol=1e-15)


def test_pid_z_requires_dt():
    with pytest.raises(InvalidControllerError, match="discrete: give dt"):
        controller_tf("pid_z", {"K": 1, "a1": 0, "a2": 0}, dt=None)


@pytest.mark.parametrize("name, K, wz, wp", [("lead", 2.0, 1.0, 10.0), ("lag", 0.5, 2.0, 0.2)])
def test_lead_lag_matched_pole_zero_by_hand(name, K, wz, wp):
    dt = 0.1
    c = controller_tf(name, {"K": K, "wz": wz, "wp": wp}, dt=dt)
    zd, pd = math.exp(-wz * dt), math.exp(-wp * dt)
    g = K * (1 - pd) / (1 - zd)
    assert_allclose(c.num, [g, -g * zd], rtol=1e-14)
    assert_allclose(c.den, [1.0, -pd], rtol=1e-14)
    # DC gain K: C(1) = g (1 - zd)/(1 - pd)
    assert np.polyval(c.num, 1.0) / np.polyval(c.den, 1.0) == pytest.approx(K, rel=1e-13)


def test_leadlag_is_the_product_of_matched_forms():
    dt = 0.05
    x = {"K": 3.0, "wz1": 2.0, "wp1": 20.0, "wz2": 0.5, "wp2": 0.05}
    c = controller_tf("leadlag", x, dt=dt)
    e = np.exp
    z1, p1, z2, p2 = e(-2.0 * dt), e(-20.0 * dt), e(-0.5 * dt), e(-0.05 * dt)
    g = 3.0 * (1 - p1) / (1 - z1) * (1 - p2) / (1 - z2)
    assert_allclose(c.num, g * np.poly([z1, z2]), rtol=1e-13)
    assert_allclose(c.den, np.poly([p1, p2]), rtol=1e-13)


# -- continuous forms -------------------------------------------------------------------------

def test_continuous_forms_by_hand():
    c = controller_tf("p", {"Kp": 4}, dt=None)
    assert_allclose(c.num, [4])
    assert_allclose(c.den, [1])
    c = controller_tf("pi", {"Kp": 2, "Ki": 3}, dt=None)  # (2s + 3)/s
    assert_allclose(c.num, [2, 3])
    assert_allclose(c.den, [1, 0])
    # Kp + Kd s/(Tf s + 1) = ((Kp Tf + Kd) s + Kp)/(Tf s + 1); Kp=2, Kd=0.5, Tf=0.05 -> (0.6 s + 2)/(0.05 s + 1)
    c = controller_tf("pd", {"Kp": 2, "Kd": 0.5, "Tf": 0.05}, dt=None)
    assert_allclose(c.num, [12.0, 40.0], rtol=1e-13)
    assert_allclose(c.den, [1.0, 20.0], rtol=1e-13)
    # Kp + Ki/s + Kd s/(Tf s+1) = ((Kp Tf + Kd) s^2 + (Kp + Ki Tf) s + Ki)/(Tf s^2 + s)
    #   Kp=2, Ki=3, Kd=0.5, Tf=0.05: (0.6 s^2 + 2.15 s + 3)/(0.05 s^2 + s)
    c = controller_tf("pid", {"Kp": 2, "Ki": 3, "Kd": 0.5, "Tf": 0.05}, dt=None)
    assert_allclose(c.num, [12.0, 43.0, 60.0], rtol=1e-13)
    assert_allclose(c.den, [1.0, 20.0, 0.0], atol=1e-13)
    # K (s/wz + 1)/(s/wp + 1) = K wp/wz (s + wz)/(s + wp); K=2, wz=1, wp=10 -> 20 (s+1)/(s+10)
    c = controller_tf("lead", {"K": 2, "wz": 1, "wp": 10}, dt=None)
    assert_allclose(c.num, [20.0, 20.0], rtol=1e-14)
    assert_allclose(c.den, [1.0, 10.0], rtol=1e-14)


@pytest.mark.parametrize(
    "name, dt",
    [(n, dt) for n in sorted(STRUCTURES) for dt in (None, 0.05) if not (STRUCTURES[n].discrete_only and dt is None)
     and STRUCTURES[n].firmware is None],  # the firmware laws: against the laws run per sample, test_firmware_laws
)
def test_structure_frequency_response_matches_documented_formula(name, dt):
    """Evaluate the docstring's formula directly at complex points; compare with num/den."""
    st = get_structure(name)
    vals = {"Kp": 1.7, "Ki": 2.3, "Kd": 0.31, "Tf": 0.02, "K": 1.9, "wz": 3.0, "wp": 30.0,
            "a1": -1.2, "a2": 0.4, "wz1": 2.0, "wp1": 25.0, "wz2": 0.7, "wp2": 0.07, "b": 0.6, "c": 0.3}
    if name == "lag":
        vals.update(wz=3.0, wp=0.3)
    x = {p: vals[p] for p in st.params}
    c = st.tf(x, dt)

    def first_order(K, wz, wp, v):
        if dt is None:
            return K * (v / wz + 1) / (v / wp + 1)
        zd, pd = math.exp(-wz * dt), math.exp(-wp * dt)
        return K * (1 - pd) / (1 - zd) * (v - zd) / (v - pd)

    def formula(v):
        Kp, Ki, Kd, Tf = (x.get(k, 0.0) for k in ("Kp", "Ki", "Kd", "Tf"))
        if dt is None:
            i_term, d_term = Ki / v, Kd * v / (Tf * v + 1)
        else:
            i_term, d_term = Ki * dt * v / (v - 1), Kd * (v - 1) / ((Tf + dt) * v - Tf)
        if name in ("p", "pi", "pd", "pid", "pid2"):  # pid2: its feedback part (on -y) is pid's controller
            return Kp + (i_term if "i" in name else 0) + (d_term if "d" in name else 0)
        if name == "pid_z":
            return x["K"] * (v**2 + x["a1"] * v + x["a2"]) / (v * (v - 1))
        if name == "pid_mf2":  # the documented form; at dt: backward-Euler PID (one-sample derivative) x Tustin filter
            if dt is None:
                return (Kp + Ki / v + Kd * v) / (Tf**2 * v**2 + math.sqrt(2) * Tf * v + 1)
            sv = 2 / dt * (v - 1) / (v + 1)
            return (Kp + Ki * dt * v / (v - 1) + Kd * (v - 1) / (dt * v)) / (Tf**2 * sv**2 + math.sqrt(2) * Tf * sv + 1)
        if name in ("lead", "lag"):
            return first_order(x["K"], x["wz"], x["wp"], v)
        assert name == "leadlag"
        return first_order(x["K"], x["wz1"], x["wp1"], v) * first_order(1.0, x["wz2"], x["wp2"], v)

    for v in (0.3 + 0.8j, -0.6 + 0.2j, 2.5 - 1.0j, 1j * 7.0):
        assert np.polyval(c.num, v) / np.polyval(c.den, v) == pytest.approx(formula(v), rel=1e-12)
    # and freqresp uses s = jw or z = exp(jw dt)
    w = np.array([0.7, 5.0])
    v = 1j * w if dt is None else np.exp(1j * w * dt)
    assert_allclose(c.freqresp(w), [formula(vi) for vi in v], rtol=1e-12)


# -- bounds and initial guess -----------------------------------------------------------------

PLANTS = {
    "yaw": YAW,
    "roll": ROLL,
    "pitch": PITCH,
    "unstable": "1/(s-1)",
    "double_integrator": "1/s^2",
    "integrator_lag": "1/(s*(s+1))",
    "negative_gain": "-2/(s+1)",
    "fast": "1000/(s+1000)",
}


@pytest.mark.parametrize("dt", [None, DT])
@pytest.mark.parametrize("plant", sorted(PLANTS))
def test_bounds_contain_the_initial_guess(plant, dt):
    p = plant_from_expr(PLANTS[plant])
    for name, st in STRUCTURES.items():
        if st.discrete_only and dt is None:
            continue
        g = initial_guess(st, p, dt)
        lo, hi = bounds(st, p, dt)
        assert set(g) == set(st.params)
        x = st.vector(g)
        assert np.all(lo < hi), name
        assert np.all((lo <= x) & (x <= hi)), (name, dict(zip(st.params, zip(lo, x, hi))))
        for a, b in st.orderings:  # lead: wz < wp; lag: wp < wz
            assert g[a] < g[b], (name, a, b, g)
        st.tf(g, dt)  # a valid controller
        if dt is not None:
            # frequencies stay at or below the Nyquist frequency pi/dt
            for k, v in zip(st.kinds, x):
                if k == "freq":
                    assert v <= math.pi / dt * (1 + 1e-12), (name, v)


def test_initial_guess_gain_sign_follows_the_plant():
    pos = initial_guess(get_structure("pi"), plant_from_expr("2/(s+1)"), None)
    neg = initial_guess(get_structure("pi"), plant_from_expr("-2/(s+1)"), None)
    assert pos["Kp"] > 0 and pos["Ki"] > 0
    assert neg["Kp"] < 0 and neg["Ki"] < 0


def test_pid_z_initial_guess_cancels_the_plant_poles():
    # the thesis's digital PID puts its zeros on the plant's (discrete) poles:
    # roll ZOH at 0.04 has den z^2 - 1.3052 z + 0.5668
    g = initial_guess(get_structure("pid_z"), plant_from_expr(ROLL), DT)
    assert g["a1"] == pytest.approx(-1.3052445, abs=1e-6)
    assert g["a2"] == pytest.approx(0.56677096, abs=1e-7)


# -- invalid controllers ----------------------------------------------------------------------

@pytest.mark.parametrize(
    "structure, gains, dt, words",
    [
        ("pidx", {"Kp": 1}, None, "unknown structure 'pidx'"),
        ("PID", {"Kp": 1}, None, "unknown structure"),
        ("pi", {"Kp": 1}, None, "missing ['Ki']"),
        ("pi", {"Kp": 1, "Ki": 1, "Kd": 2}, None, "unknown ['Kd']"),
        ("pi", {"Kp": 1, "Ki": 1, "kp": 2}, None, "unknown ['kp']"),
        ("pi", {"Kp": "x", "Ki": 1}, None, "must be numbers"),
        ("pi", {"Kp": float("nan"), "Ki": 1}, None, "must be finite"),
        ("pi", {"Kp": float("inf"), "Ki": 1}, 0.1, "must be finite"),
        ("pid", {"Kp": 1, "Ki": 1, "Kd": 1, "Tf": 0}, None, "Tf must be > 0 in continuous time"),
        ("pid", {"Kp": 1, "Ki": 1, "Kd": 1, "Tf": -0.1}, 0.1, "Tf is a time constant and must be >= 0"),
        ("lead", {"K": 1, "wz": 0, "wp": 1}, None, "wz is a frequency and must be > 0"),
        ("lag", {"K": 1, "wz": 1, "wp": -1}, None, "wp is a frequency and must be > 0"),
        ("pid_z", {"K": 1, "a1": 0, "a2": 0}, None, "discrete: give dt"),
    ],
)
def test_invalid_gains_and_structures(structure, gains, dt, words):
    with pytest.raises(InvalidControllerError) as ei:
        controller_tf(structure, gains, dt=dt)
    assert words in str(ei.value)
    assert isinstance(ei.value, ValueError)


def test_sequence_of_wrong_length_rejected():
    with pytest.raises(InvalidControllerError, match="takes 2 parameters"):
        get_structure("pi").tf([1.0], None)


@pytest.mark.parametrize("dt", [0, -0.04, float("nan")])
def test_structure_rejects_bad_dt(dt):
    with pytest.raises(TunerError, match="dt must be finite and > 0"):
        controller_tf("pi", {"Kp": 1, "Ki": 1}, dt=dt)


@pytest.mark.parametrize(
    "text, dt, err, words",
    [
        ("1/s", DT, InvalidControllerError, "controller is in s but a sample time dt was given"),
        ("(z-0.5)/(z-1)", None, InvalidControllerError, "controller is in z: give its sample time dt"),
        ("(z^2+1)/z", DT, InvalidControllerError, "improper"),
        ("s+1", None, InvalidControllerError, "improper"),
        ("s/(z-1)", DT, InvalidExpressionError, "mixes 's' and 'z'"),
        ("1/(z-1)", 0.0, TunerError, "dt must be finite and > 0"),
        ("__import__('os')", None, InvalidExpressionError, "unknown name"),
    ],
)
def test_controller_from_expr_rejects(text, dt, err, words):
    with pytest.raises(err) as ei:
        controller_from_expr(text, dt=dt)
    assert words in str(ei.value)


def test_controller_from_expr_accepts_proper_forms():
    c = controller_from_expr("5+2/(z-1)", dt=DT)
    assert_allclose(c.num, [5, -3])
    assert_allclose(c.den, [1, -1])
    assert c.dt == DT
    k = controller_from_expr("2.5", dt=None)
    assert_allclose(k.num, [2.5])
    assert k.dt is None
    assert c.to_dict() == {"num": [5.0, -3.0], "den": [1.0, -1.0], "dt": DT}
