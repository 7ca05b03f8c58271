"""python-control in and out (issue 14): ``control.TransferFunction``/``StateSpace`` as plants and controllers
of ``tune``, ``analyze`` and ``make_plant``; results as python-control objects.

References: the same plant written as an expression; python-control's own ``c2d`` (ZOH) and evaluation of
its transfer functions for the loop's L, S, T; the controller's coefficients evaluated with ``numpy.polyval``.
"""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from numpy.testing import assert_allclose
from quadrotor import DT, ROLL, ROLL_C

from tuner import analyze, controller_from_expr, make_plant, plant_from_expr, tune
from tuner.errors import InvalidPlantError, TunerError

# exactly representable coefficients: the expression parser (which factors as written) and the coefficient
# path (roots of the expanded polynomial) then hold bit for bit the same zeros, poles and gain
EXPR = "4/(s^2+2*s+4)"
G = ct.tf([4.0], [1.0, 2.0, 4.0])
ROLL_TF = ct.tf([0.2655 * 14.8528**2], [1.0, 14.195, 14.8528**2])
ROLL_CTRL_TF = ct.tf([3.868, -3.868 * 1.305, 3.868 * 0.5668], [1.0, -1.0, 0.0], DT)
W = np.array([0.05, 0.3, 1.0, 3.0, 10.0, 30.0, 70.0])  # rad/s, below pi/DT = 78.5


def same_metrics(a, b, rtol=1e-9):
    for k, v in vars(a.metrics).items():
        w = getattr(b.metrics, k)
        if isinstance(v, bool) or not math.isfinite(v):
            assert v == w, k
        else:
            assert_allclose(w, v, rtol=rtol, atol=1e-12, err_msg=k)


# -- in ---------------------------------------------------------------------------------------------------------

@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_the_same_plant_as_expression_and_as_control_tf_tunes_identically():
    pe, pc = plant_from_expr(EXPR), make_plant(G)
    assert np.array_equal(pe.zpk.poles, pc.zpk.poles) and pe.zpk.gain == pc.zpk.gain
    r1 = tune(pe, structure="pi", dt=0.05, time_budget_s=120)
    r2 = tune(G, structure="pi", dt=0.05, time_budget_s=120)
    assert r1.solver["stop"] == r2.solver["stop"] != "budget"  # not cut by the clock: deterministic
    assert r1.gains == r2.gains
    assert r1.to_dict()["metrics"] == r2.to_dict()["metrics"]


def test_roll_model_as_control_tf_analyses_as_the_expression():
    a1 = analyze(plant_from_expr(ROLL), controller_from_expr(ROLL_C, dt=DT))
    a2 = analyze(ROLL_TF, ROLL_CTRL_TF)
    same_metrics(a1, a2)
    assert a2.loop.dt == DT


def test_state_space_plant_and_controller():
    a1 = analyze(plant_from_expr(ROLL), controller_from_expr(ROLL_C, dt=DT))
    a2 = analyze(ct.ss(ROLL_TF), ct.ss(ROLL_CTRL_TF))
    assert_allclose(np.sort_complex(a2.loop.plant.poles), np.sort_complex(a1.loop.plant.poles), rtol=1e-10)
    same_metrics(a1, a2, rtol=1e-7)


def test_a_discrete_model_keeps_its_dt_and_its_delay_is_whole_samples():
    gd = ct.c2d(ROLL_TF, DT, "zoh")
    p = make_plant(gd, delay=2 * DT)
    assert p.dt == DT and p.delay_s == pytest.approx(2 * DT)
    # the loop on the discrete plant at the samples = the loop on the continuous plant (its ZOH is gd)
    a_d = analyze(gd, ROLL_CTRL_TF, delay=2 * DT)
    a_c = analyze(plant_from_expr(ROLL, delay=2 * DT), controller_from_expr(ROLL_C, dt=DT))
    assert_allclose(a_d.metrics.phase_margin_deg, a_c.metrics.phase_margin_deg, rtol=1e-6)
    assert_allclose(a_d.metrics.gain_margin_db, a_c.metrics.gain_margin_db, rtol=1e-6)
    with pytest.raises(InvalidPlantError) as ei:
        make_plant(gd, delay=0.5 * DT)
    assert ei.value.field == ("delay",)


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_robust_tuning_over_a_list_of_control_models_with_per_plant_delays():
    plants = [ct.tf([1.0], [10.0, 1.0]), ct.tf([1.2], [10.0, 1.0]), ct.tf([0.8], [12.0, 1.0])]
    res = tune(plants, structure="pi", dt=0.5, delay=[1.0, 1.0, 1.5], time_budget_s=120)
    assert len(res.analyses) == 3
    assert [a.loop.delay_samples for a in res.analyses] == [2, 2, 3]
    assert_allclose(res.analyses[1].loop.plant.dc_gain(), 1.2)
    with pytest.raises(InvalidPlantError) as ei:
        tune(plants, structure="pi", dt=0.5, delay=[1.0, 1.0])
    assert ei.value.field == ("delay",)


@pytest.mark.parametrize("call", ["tune", "analyze", "make_plant"])
def test_dt_true_asks_for_the_sample_time(call):
    g = ct.tf([1.0], [1.0, -0.5], True)
    with pytest.raises(TunerError, match="sample time") as ei:
        if call == "tune":
            tune(g, structure="pi", time_budget_s=1)
        elif call == "analyze":
            analyze(g, ct.tf([1.0], [1.0], 0.1))
        else:
            make_plant(g)
    assert ei.value.field[-1] == "dt" and "dt=True" in str(ei.value)


def test_mimo_and_foreign_objects_are_refused():
    mimo = ct.ss(-np.eye(2), np.eye(2), np.eye(2), np.zeros((2, 2)))
    with pytest.raises(InvalidPlantError, match="SISO"):
        make_plant(mimo)
    with pytest.raises(InvalidPlantError) as ei:
        tune("1/(s+1)", structure="pi")
    assert "plant_from_expr" in str(ei.value)
    with pytest.raises(InvalidPlantError, match="delay"):
        tune(plant_from_expr(EXPR), structure="pi", delay=1.0)  # a Plant carries its own delay


# -- out --------------------------------------------------------------------------------------------------------

@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_to_control_is_the_controller_at_every_frequency():
    res = tune(G, structure="pid", dt=0.05, time_budget_s=120)
    c = res.controller
    k = res.to_control()
    assert k.dt == 0.05
    z = np.exp(1j * W * 0.05)
    assert_allclose(k(z), np.polyval(c.num, z) / np.polyval(c.den, z), rtol=1e-12)
    kc = analyze(G, controller_from_expr("2+3/s", dt=None)).to_control()
    assert kc.dt == 0
    assert_allclose(kc(1j * W), 2 + 3 / (1j * W), rtol=1e-12)


def test_loop_tfs_of_a_sampled_data_loop_are_the_zoh_loop_with_the_delay_as_z_power():
    a = analyze(ROLL_TF, ROLL_CTRL_TF, delay=2 * DT)
    L, S, T = a.loop_tfs()
    assert L.dt == S.dt == T.dt == DT
    # reference: python-control's own ZOH of the plant, times z^-2, times the controller
    ref = ROLL_CTRL_TF * ct.c2d(ROLL_TF, DT, "zoh") * ct.tf([1.0], [1.0, 0.0, 0.0], DT)
    z = np.exp(1j * W * DT)
    assert_allclose(L(z), ref(z), rtol=1e-9)
    assert_allclose(S(z), 1 / (1 + ref(z)), rtol=1e-9)
    assert_allclose(T(z), ref(z) / (1 + ref(z)), rtol=1e-9)
    assert_allclose(L(z), a.loop.freqresp(W), rtol=1e-9)  # the verifier's L (from realisations)
    # the closed-loop poles are S's poles, uncancelled
    assert_allclose(np.sort_complex(S.poles()), np.sort_complex(a.poles), atol=1e-8)


def test_loop_tfs_of_a_continuous_loop_with_delay_use_pade():
    tau = 0.3
    a = analyze(G, controller_from_expr("1+0.5/s", dt=None), delay=tau)
    L, S, T = a.loop_tfs(pade_order=6)
    w = np.array([0.01, 0.1, 0.5])  # far below the Padé approximation's limit (order/tau)
    exact = (4 / ((1j * w) ** 2 + 2j * w + 4)) * (1 + 0.5 / (1j * w)) * np.exp(-1j * w * tau)
    assert_allclose(L(1j * w), exact, rtol=1e-9)
    L0, _, _ = a.loop_tfs(pade_order=None)  # the rational part only
    assert_allclose(L0(1j * w), exact * np.exp(1j * w * tau), rtol=1e-12)
    with pytest.raises(TunerError):
        a.loop_tfs(pade_order=0)


def test_identify_result_to_control():
    from flight import AXES, fly

    from tuner import identify

    num, den = AXES["roll"]
    log = fly(num, den, delay_s=0.04, seed=3, duration_s=60.0)
    res = identify(log.u, log.y, rate_hz=1 / log.dt, poles=2, delay="auto", delay_step=DT)
    g = res.to_control()
    assert g.dt == 0
    p = res.plant()
    assert_allclose(g(1j * W), p.freqresp(W) * np.exp(1j * W * p.delay_s), rtol=1e-10)
    assert res.delay_s == p.delay_s
    analyze(g, ROLL_CTRL_TF, delay=res.delay_s)  # and it goes straight into the tuner


def test_export_takes_a_control_tf():
    from tuner.export import export_controller

    text = export_controller(ROLL_CTRL_TF, format="text", name="roll")
    assert "u[k] = 3.868 * e[k]" in text and "dt = 0.04 s" in text
