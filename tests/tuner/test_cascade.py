"""Cascades: the composite outer plant and the exact simulation of the whole cascade."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from quadrotor import DT, PITCH, PITCH_C, ROLL
from scipy import signal

from tuner import Spec, analyze, controller_from_expr, controller_tf, plant_from_expr
from tuner.analysis.cascade import outer_plant, simulate_cascade
from tuner.errors import InvalidPlantError

G = "9.81/s^2"
PITCH_TUNED = {"K": 71.02, "a1": -1.8685, "a2": 0.88732}  # a pitch PID that meets the spec
LEAD = {"K": 0.06, "wz": 0.19, "wp": 32.0}


def test_thesis_position_model():
    """ZOH of g/s^2 at 0.04 s is g * 0.0008 (z+1)/(z-1)^2 (shared/reference/quadrotor.md)."""
    p = plant_from_expr(G).zoh(DT)
    assert_allclose(p.num, [9.81 * 0.0008, 9.81 * 0.0008], rtol=1e-9)
    assert_allclose(p.den, [1.0, -2.0, 1.0], atol=1e-12)


def _freq(num, den, z):
    return np.polyval(num, z) / np.polyval(den, z)


def test_outer_plant_is_the_sampled_cascade():
    """P = Ci Z[Gi Go] / (1 + Ci Z[Gi]), checked pointwise on the unit circle from independently
    discretised pieces (scipy's ZOH, not python-control's)."""
    gi, go = plant_from_expr(PITCH), plant_from_expr(G)
    ci = controller_tf("pid_z", PITCH_TUNED, dt=DT)
    P = outer_plant(gi, ci, go)
    assert P.dt == DT and P.order == 6  # 2 (pitch) + 2 (PID) + 2 (g/s^2): a minimal realisation
    assert P.continuous_equivalent() is None  # a sampled model: the verifier evaluates at the samples

    b1, a1, _ = signal.cont2discrete((gi.num, gi.den), DT, method="zoh")
    b2, a2, _ = signal.cont2discrete((np.polymul(gi.num, go.num), np.polymul(gi.den, go.den)), DT, method="zoh")
    th = np.linspace(0.05, 3.0, 40)
    z = np.exp(1j * th)
    C = _freq(ci.num, ci.den, z)
    want = C * _freq(np.squeeze(b2), a2, z) / (1 + C * _freq(np.squeeze(b1), a1, z))
    assert_allclose(P.freqresp(th / DT), want, rtol=1e-6)
    assert_allclose(_freq(P.num, P.den, z), want, rtol=1e-6)  # the coefficients shown describe it too


def test_held_angle_model_for_a_discrete_inner_plant():
    """Inner plant in z: the thesis's T_i(z) Z[Go](z) (angle held between samples)."""
    gi = plant_from_expr("0.1493/(z-0.475)", dt=DT)
    ci = controller_from_expr("3*(z-0.475)/(z*(z-1))", dt=DT)
    P = outer_plant(gi, ci, plant_from_expr(G))
    th = np.linspace(0.05, 3.0, 25)
    z = np.exp(1j * th)
    C = _freq(ci.num, ci.den, z)
    Gi = 0.1493 / (z - 0.475)
    Go = 9.81 * 0.0008 * (z + 1) / (z - 1) ** 2
    assert_allclose(P.freqresp(th / DT), C * Gi / (1 + C * Gi) * Go, rtol=1e-9)


def test_simulation_matches_the_verifier_at_the_samples():
    """Two independent paths (state-space simulation of the cascade vs the verifier on the composite
    polynomial plant) agree at every sample; between samples the simulation adds the true output."""
    gi, go = plant_from_expr(PITCH), plant_from_expr(G)
    ci = controller_tf("pid_z", PITCH_TUNED, dt=DT)
    co = controller_tf("lead", LEAD, dt=DT)
    a = analyze(outer_plant(gi, ci, go), co, Spec())
    r = a.response
    sim = simulate_cascade(gi, ci, go, co, horizon_s=float(r.t[-1]), y_final=r.y_final)
    assert sim is not None
    assert sim.response.y_samples.size == r.y_samples.size
    assert_allclose(sim.response.y_samples, r.y_samples, atol=1e-8)
    assert sim.response.y.size == 20 * r.y_samples.size  # 20 points per sample
    # the true position is smooth: between samples it differs from the sampled overshoot only slightly
    assert abs(sim.metrics.overshoot_pct - a.metrics.overshoot_pct) < 0.5
    assert sim.metrics.settling_time_s == pytest.approx(a.metrics.settling_time_s, abs=DT)


def test_printed_x_cascade_is_unstable():
    """The thesis's printed X lead around its printed pitch PID is unstable (quadrotor.md)."""
    P = outer_plant(plant_from_expr(PITCH), controller_from_expr(PITCH_C, dt=DT), plant_from_expr(G))
    a = analyze(P, controller_from_expr("3.3*(z-0.64)/(z-0.56)", dt=DT))
    assert not a.metrics.stable
    assert np.max(np.abs(a.poles)) > 1.0


def test_order_limit_and_continuous_inner_controller():
    gi = plant_from_expr("1/(s+1)^9")
    ci = controller_tf("pid", {"Kp": 1, "Ki": 0.1, "Kd": 0.1, "Tf": 0.1}, dt=0.1)
    with pytest.raises(InvalidPlantError, match="order 21, above the limit 20"):  # 9 + 2 + 10
        outer_plant(gi, ci, plant_from_expr("1/(s+1)^10"))
    with pytest.raises(InvalidPlantError, match="inner controller must be discrete"):
        outer_plant(plant_from_expr(ROLL), controller_from_expr("1+1/s", dt=None), plant_from_expr(G))


def _brute_cascade(gi, ci, go, co, horizon_s, n_fine):
    """The cascade stepped one fine step at a time: the two plants in series (scipy's tf2ss, ZOH at dt / n_fine by
    scipy's cont2discrete), the controllers as their transfer functions' difference equations in z, the outer
    reference a unit step. Returns the position at every fine step and at the samples, the outer controller's output
    (the inner loop's reference, held) and the angle at every fine step."""
    dt = ci.dt
    Ai, Bi, Ci, Di = signal.tf2ss(gi.num, gi.den)
    Ao, Bo, Co, Do = signal.tf2ss(go.num, go.den)
    ni, no = Ai.shape[0], Ao.shape[0]
    A = np.block([[Ai, np.zeros((ni, no))], [Bo @ Ci, Ao]])
    B = np.vstack([Bi, Bo @ Di])
    Cx, Cth = np.hstack([Do @ Ci, Co]), np.hstack([Ci, np.zeros((1, no))])
    Ad, Bd, *_ = signal.cont2discrete((A, B, Cx, np.zeros((1, 1))), dt / n_fine, method="zoh")

    def law(c):  # u[k] = (sum b_i e[k-i] - sum_{i>0} a_i u[k-i]) / a_0 on the histories
        b = np.concatenate([np.zeros(len(c.den) - len(c.num)), c.num])
        e_hist, u_hist = [0.0] * len(c.den), [0.0] * len(c.den)

        def step(e):
            e_hist.insert(0, e), e_hist.pop()
            u = (np.dot(b, e_hist) - np.dot(c.den[1:], u_hist[:-1])) / c.den[0]
            u_hist.insert(0, u), u_hist.pop()
            return u
        return step

    outer_law, inner_law = law(co), law(ci)
    x = np.zeros((A.shape[0], 1))
    fine, samples, refs, angles = [], [], [], []
    for _ in range(int(np.ceil(horizon_s / dt)) + 1):
        p, th = (Cx @ x).item(), (Cth @ x).item()
        samples.append(p)
        ref = outer_law(1.0 - p)
        u = inner_law(ref - th)
        for _ in range(n_fine):
            fine.append((Cx @ x).item()), angles.append((Cth @ x).item()), refs.append(ref)
            x = Ad @ x + Bd * u
    return np.array(fine), np.array(samples), np.array(refs), np.array(angles)


@pytest.mark.parametrize("inner_c, outer_c, horizon_s", [
    (("pid_z", PITCH_TUNED), ("lead", LEAD), 8.0),
    (("pid", {"Kp": 40.0, "Ki": 20.0, "Kd": 3.0, "Tf": 0.02}), ("pid", {"Kp": 0.5, "Ki": 0.02, "Kd": 0.3, "Tf": 0.1}),
     12.0),
])
def test_cascade_simulation_matches_a_fine_step_by_step_simulation(inner_c, outer_c, horizon_s):
    """The simulation (the cascade's state composed into one linear recursion a sample, the output between samples
    from the held input) agrees with the cascade stepped fine step by fine step, its controllers run as difference
    equations of their transfer functions: the position at every fine point and at the samples, the outer
    controller's output (the response's u) and the inner plant's output."""
    gi, go = plant_from_expr(PITCH), plant_from_expr(G)
    ci, co = controller_tf(*inner_c, dt=DT), controller_tf(*outer_c, dt=DT)
    sim = simulate_cascade(gi, ci, go, co, horizon_s=horizon_s)
    fine, samples, refs, angles = _brute_cascade(gi, ci, go, co, horizon_s, 20)
    assert sim.response.y.size == fine.size
    scale = np.max(np.abs(fine))
    assert 0.5 < scale < 10  # (a loop that moves: not a trivially matching zero response)
    assert_allclose(sim.response.y, fine, atol=1e-9 * scale)
    assert_allclose(sim.response.y_samples, samples, atol=1e-9 * scale)
    assert_allclose(sim.response.u, refs, atol=1e-9 * np.max(np.abs(refs)))
    assert_allclose(sim.inner_output, angles, atol=1e-9 * np.max(np.abs(angles)))


@pytest.mark.parametrize("gi_e, go_e", [("(s+3)/(s+1)", G), ("(0.5*s+1)/(0.1*s+1)", G), ("(s+3)/(s+1)", "(s+2)/(s+1)")])
def test_simulation_closes_the_algebraic_loop_of_biproper_plants(gi_e, go_e):
    """A biproper plant feeds the held input through at the sample: the simulation closes that algebraic loop as
    :func:`outer_plant` does (it read the angle and position without the feedthrough, 0.4 to 1e86 off here)."""
    gi, go = plant_from_expr(gi_e), plant_from_expr(go_e)
    ci = controller_tf("pid", {"Kp": 2.0, "Ki": 1.0, "Kd": 0.0, "Tf": 0.05}, dt=DT)
    co = controller_tf("lead", LEAD, dt=DT)
    r = analyze(outer_plant(gi, ci, go), co, Spec()).response
    sim = simulate_cascade(gi, ci, go, co, horizon_s=float(r.t[-1]), y_final=r.y_final)
    assert_allclose(sim.response.y_samples, r.y_samples, atol=1e-9 * np.max(np.abs(r.y_samples)))
    assert_allclose(sim.response.y[::20], sim.response.y_samples, atol=1e-12)  # the fine output at the samples
