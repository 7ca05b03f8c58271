"""Numerics that hold at order 10 and with delays (issue 11): every reference here is computed in the
test, from a realisation written by hand (bidiagonal chains of first-order lags), never from expanded
polynomials and never with tuner's own state-space code."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import linalg

from tuner import Spec, analyze, controller_tf, make_plant, plant_from_expr, tune
from tuner.analysis.margins import margins
from tuner.controllers import ControllerTF
from tuner.loop import build_loop
from tuner.lti import SS, zpk_from_ss
from tuner.plant import make_plant_zpk

# the loop of the issue: 1/(s+1)^8 at dt = 0.1 with the thesis's digital PID K(z^2+a1 z+a2)/(z(z-1))
K8, A1, A2 = 8.56197007883629, -1.8944797955467914, 0.8956258354822041


def _chain(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x1' = -x1 + u, x_i' = -x_i + x_{i-1}, y = x_n: 1/(s+1)^n as a bidiagonal realisation."""
    A = -np.eye(n) + np.eye(n, k=-1)
    B = np.zeros(n)
    B[0] = 1.0
    C = np.zeros(n)
    C[-1] = 1.0
    return A, B, C


def _zoh(A, B, dt):
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = A * dt, B * dt
    E = linalg.expm(M)
    return E[:n, :n], E[:n, n]


def _closed_loop_radius(k: float, n: int = 8, dt: float = 0.1) -> float:
    """Spectral radius of the closed loop with k * the controller, built by hand (plant chain ZOH, the
    controller K (z^2 + a1 z + a2)/(z (z - 1)) in controllable form, unity feedback)."""
    Phi, Gam = _zoh(*_chain(n)[:2], dt)
    C = _chain(n)[2]
    # K (z^2 + a1 z + a2) / (z^2 - z): u[k] = u[k-1] + K (e[k] + a1 e[k-1] + a2 e[k-2]); states e1, e2, u1
    Kk = k * K8
    nz = n + 3
    Acl = np.zeros((nz, nz))
    # e[k] = -C x[k] (r = 0); u[k] = u1 + Kk(e + a1 e1 + a2 e2)
    u_row = np.zeros(nz)
    u_row[:n] = -Kk * C
    u_row[n] = Kk * A1  # e1
    u_row[n + 1] = Kk * A2  # e2
    u_row[n + 2] = 1.0  # u1
    Acl[:n, :n] = Phi
    Acl[:n, :] += np.outer(Gam, u_row)
    Acl[n, :n] = -C  # e1+ = e
    Acl[n + 1, n] = 1.0  # e2+ = e1
    Acl[n + 2, :] = u_row  # u1+ = u
    return float(np.max(np.abs(np.linalg.eigvals(Acl))))


def test_order_eight_gain_margin_is_the_eigenvalue_crossing():
    """The issue's loop: the tool used to report 80.5 dB; the closed-loop eigenvalues (hand-built
    realisation) cross the unit circle at the true gain margin, about 6.73 dB."""
    loop = build_loop(plant_from_expr("1/(s+1)^8"), controller_tf("pid_z", {"K": K8, "a1": A1, "a2": A2}, dt=0.1))
    gm = margins(loop).gain_margin_db
    assert gm == pytest.approx(6.73, abs=0.2)
    lo, hi = 1.0, 10 ** (8 / 20)  # stable at 1, unstable above the margin: bisection on the radius
    assert _closed_loop_radius(lo) < 1 < _closed_loop_radius(hi)
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if _closed_loop_radius(mid) < 1 else (lo, mid)
    assert gm == pytest.approx(20 * math.log10(lo), abs=0.01)
    a = analyze(plant_from_expr("1/(s+1)^8"), loop.controller)
    assert a.metrics.stable and abs(a.metrics.steady_state_error) < 1e-9  # the integrator: exactly 0


def _dense_margins(L: np.ndarray, w: np.ndarray) -> dict[str, float]:
    """Brute force on a dense grid: PM = min distance in phase from -1 over |L| = 1 crossings; upper GM
    from the negative-real-axis crossings inside the unit circle; Ms = max |S|."""
    m = np.log(np.abs(L))
    i = np.flatnonzero(np.sign(m[:-1]) * np.sign(m[1:]) < 0)
    pms = [180 - abs(math.degrees(np.angle(L[k] + (L[k + 1] - L[k]) * m[k] / (m[k] - m[k + 1])))) for k in i]
    j = np.flatnonzero(np.sign(L.imag[:-1]) * np.sign(L.imag[1:]) < 0)
    xs = [L.real[k] + (L.real[k + 1] - L.real[k]) * L.imag[k] / (L.imag[k] - L.imag[k + 1]) for k in j]
    ks = [-1 / x for x in xs if -1 < x < 0]
    return {"pm": min(pms) if pms else math.inf, "gm_db": 20 * math.log10(min(ks)) if ks else math.inf,
            "ms": float(np.max(1 / np.abs(1 + L)))}


@pytest.mark.parametrize("dt", [None, 0.2])
@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_order_ten_margins_against_a_brute_force_grid(dt):
    """1/(s+1)^10 with a PID: the margins against a dense grid over the hand-built realisation
    (continuous: the factored form; sampled: C (zI - Phi)^-1 Gam of the chain's ZOH, one solve per point)."""
    gains = {"Kp": 0.55, "Ki": 0.09, "Kd": 0.8, "Tf": 0.3}
    ctrl = controller_tf("pid", gains, dt=dt)
    loop = build_loop(plant_from_expr("1/(s+1)^10"), ctrl)
    m = margins(loop)
    if dt is None:
        w = np.logspace(-3, 2, 200_000)
        G = 1.0 / (1j * w + 1) ** 10  # a product of factors, evaluated as such
    else:
        w = np.logspace(-3, np.log10(0.9999 * np.pi / dt), 100_000)
        A, B, C = _chain(10)
        Phi, Gam = _zoh(A, B, dt)
        z = np.exp(1j * w * dt)
        G = np.array([C @ np.linalg.solve(zk * np.eye(10) - Phi, Gam) for zk in z])
    L = ctrl.freqresp(w) * G
    b = _dense_margins(L, w)
    assert m.phase_margin_deg == pytest.approx(b["pm"], abs=0.02)
    assert m.gain_margin_db == pytest.approx(b["gm_db"], abs=0.02)
    assert m.ms == pytest.approx(b["ms"], rel=1e-4)


# python-control's own margin test table (control/tests/margin_test.py, `tsys`): gm (a factor), pm (deg),
# sm (min |1 + L|, where python-control gives a finite one)
def _sys3():
    zk = zpk_from_ss(SS(np.array([[1.0, 4.0], [3.0, 2.0]]), np.array([1.0, -4.0]), np.array([1.0, 0.0]), 0.0),
                     discrete=False)
    return make_plant_zpk(zk.zeros, zk.poles, zk.gain)


PYTHON_CONTROL_TABLE = [
    ("tf([1, 2], [1, 2, 3])", lambda: make_plant([1, 2], [1, 2, 3]), math.inf, math.inf, None),
    ("tf([1], [1, 2, 3, 4])", lambda: make_plant([1], [1, 2, 3, 4]), 2.0, math.inf, 0.4170),
    ("ss([[1, 4], [3, 2]], ...)", _sys3, math.inf, 147.0743, None),
    ("8.75(4s^2+0.4s+1)/...", lambda: plant_from_expr(
        "(8.75*(4*s^2+0.4*s+1))/((100*s+1)*(s^2+0.22*s+1))/(s^2/100+2*0.04*s/10+1)"), 2.2716, 97.5941, 0.5591),
    ("1/(1+s)", lambda: plant_from_expr("1/(1+s)"), math.inf, math.inf, None),
    ("3(10+s)/(2+s)", lambda: plant_from_expr("3*(10+s)/(2+s)"), math.inf, math.inf, None),
    ("0.01(10-s)/((2+s)(1+s))", lambda: plant_from_expr("0.01*(10-s)/(2+s)/(1+s)"), 300.0, math.inf, 0.9917),
]


@pytest.mark.parametrize("name, make, gm, pm, sm", PYTHON_CONTROL_TABLE, ids=[r[0] for r in PYTHON_CONTROL_TABLE])
def test_python_control_margin_table(name, make, gm, pm, sm):
    """Including 8.75(4s^2+0.4s+1)/...: three gain crossings (97.6, 157.8 and 134.7 deg from -1); the
    phase margin is the smallest distance, 97.59 deg, as python-control's reference says."""
    m = margins(build_loop(make(), ControllerTF(num=np.ones(1), den=np.ones(1), dt=None)))
    got_gm = 10 ** (m.gain_margin_db / 20) if math.isfinite(m.gain_margin_db) else math.inf
    assert got_gm == pytest.approx(gm, abs=1.5e-2) if math.isfinite(gm) else got_gm == math.inf
    assert m.phase_margin_deg == pytest.approx(pm, abs=1.5e-2) if math.isfinite(pm) else m.phase_margin_deg == math.inf
    if sm is not None:
        assert 1 / m.ms == pytest.approx(sm, abs=1.5e-2)


def test_static_gain_and_pure_delay():
    """The ZOH of a static gain is that gain (not k(z-1)/(z-1)); a loop on a pure delay is then judged right:
    K e^{-s} with K < 1 is stable for every delay (|L| < 1), and at dt = 0.1 it has no phase crossing issue."""
    p = make_plant([2.0], [1.0], delay=1.0)
    d = p.zoh(0.1)
    assert d.order == 0 and d.num.tolist() == [2.0] and d.den.tolist() == [1.0] and d.delay_s == pytest.approx(1.0)
    a = analyze(p, controller_tf("p", {"Kp": 0.3}, dt=0.1))
    assert a.metrics.stable and a.metrics.gain_margin_db == pytest.approx(20 * math.log10(1 / 0.6), abs=1e-9)


@pytest.mark.slow
def test_pi_on_a_pure_delay_meets_the_default_spec():
    r = tune(make_plant([1.0], [1.0], delay=1.0), structure="pi", dt=0.1, time_budget_s=60)
    assert r.meets_spec, [c.name for c in r.analyses[0].failing]
    indep = analyze(make_plant([1.0], [1.0], delay=1.0), r.controller, Spec())
    assert indep.meets_spec and indep.metrics.settling_time_s == r.analyses[0].metrics.settling_time_s
