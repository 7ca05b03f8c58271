"""The disturbance figures (DRB, DRP, the unit load step) against computations written here from first principles.

* DRB and DRP: ``|S| = |1/(1 + L)|`` on a dense grid, ``L`` formed from the plant's and controller's factors at
  ``s = jw`` (continuous, the delay as ``exp(-jw tau)``) or from the ZOH-discretised plant at ``z = exp(jw dt)``
  (python-control's ``c2d``, exact at the samples for a held input); DRB is the first grid frequency where
  ``|S| >= 1/sqrt(2)``, interpolated.
* The load step: a fine fixed-step simulation written here (the plant discretised exactly for a held input at a
  step ``h``, the delay as a whole number of steps ``h``, the controller updated every ``dt`` or, continuous, at the
  fine step), ``|y|`` integrated by the trapezoid rule.

Loops: MATLAB's ``pidtune`` PI for ``1/(s+1)^3`` (``1.14 + 0.454/s``, the issue's figure); the thesis roll loop with its
printed controller (``tests/quadrotor.py``); a PI on ``1/(s+1)^3`` with a delay of 0.37 s, continuous, and at
dt = 0.1 (a fractional 3.7 samples).
"""

from __future__ import annotations

import math

import control
import numpy as np
import pytest
from quadrotor import DT, ROLL, ROLL_C

from tuner import analyze, controller_from_expr, plant_from_expr


def _drb_drp(w: np.ndarray, S: np.ndarray) -> tuple[float, float]:
    mag = np.abs(S)
    i = int(np.flatnonzero(mag >= 1 / math.sqrt(2))[0])
    f0, f1 = mag[i - 1] - 1 / math.sqrt(2), mag[i] - 1 / math.sqrt(2)
    t = f0 / (f0 - f1)
    return float(np.exp(np.log(w[i - 1]) + t * (np.log(w[i]) - np.log(w[i - 1])))), 20 * math.log10(mag.max())


def _load_ct_pi(kp: float, ki: float, tau: float, T: float, h: float = 1e-3) -> tuple[float, float, float]:
    """Fine simulation of 1/(s+1)^3 (exact ZOH at h) with u_total = PI(-y) + 1 delayed by tau (whole steps of h)."""
    G = control.c2d(control.ss(control.tf([1], [1, 3, 3, 1])), h, "zoh")
    A, B, C = np.asarray(G.A), np.asarray(G.B).ravel(), np.asarray(G.C).ravel()
    n = int(round(tau / h))
    buf = [0.0] * n
    x, integ = np.zeros(3), 0.0
    K = int(T / h) + 1
    y = np.zeros(K)
    for k in range(K):
        y[k] = C @ x
        e = -y[k]
        u = kp * e + integ + 1.0
        integ += ki * e * h
        buf.append(u)
        x = A @ x + B * buf.pop(0)
    return _figures(np.arange(K) * h, y)


def _figures(t: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    a = np.abs(y)
    peak = float(a.max())
    j = int(np.flatnonzero(a > 0.02 * peak)[-1])
    return float(np.trapezoid(a, t)), peak, float(t[j])


def test_pidtune_pi_third_order():
    G, C = control.tf([1], [1, 3, 3, 1]), control.tf([1.14, 0.454], [1, 0])
    m = analyze(G, C).metrics
    w = np.geomspace(1e-3, 1e2, 400001)
    s = 1j * w
    S = 1 / (1 + (1.14 + 0.454 / s) / (s + 1) ** 3)
    drb, drp = _drb_drp(w, S)
    assert m.disturbance_rejection_bandwidth_rad_s == pytest.approx(drb, rel=1e-4)
    assert m.disturbance_rejection_peak_db == pytest.approx(drp, abs=1e-3)
    iae, peak, rec = _load_ct_pi(1.14, 0.454, 0.0, T=m.load_recovery_s + 20)
    assert m.load_peak == pytest.approx(peak, rel=2e-3)
    assert m.load_iae == pytest.approx(iae, rel=5e-3)
    assert m.load_recovery_s == pytest.approx(rec, abs=0.05)
    assert m.load_iae >= 1 / 0.454 * (1 - 1e-3)  # IAE >= IE = 1/Ki


def test_thesis_roll_printed_controller():
    G = plant_from_expr(ROLL)
    C = controller_from_expr(ROLL_C, dt=DT)
    m = analyze(G, C).metrics
    Gc = control.tf([0.2655 * 14.8528 ** 2], [1, 14.195, 14.8528 ** 2])
    Gd = control.c2d(Gc, DT, "zoh")
    w = np.geomspace(1e-2, math.pi / DT * 0.999999, 200001)
    z = np.exp(1j * w * DT)
    Cz = 3.868 * (z ** 2 - 1.305 * z + 0.5668) / (z * (z - 1))
    S = 1 / (1 + Cz * Gd(z))
    drb, drp = _drb_drp(w, S)
    assert m.disturbance_rejection_bandwidth_rad_s == pytest.approx(drb, rel=1e-4)
    assert m.disturbance_rejection_peak_db == pytest.approx(drp, abs=1e-3)
    # the load step between the samples: the plant exact at h = dt/40, the controller's difference equation every dt
    sub = 40
    h = DT / sub
    P = control.c2d(control.ss(Gc), h, "zoh")
    A, B, Cp = np.asarray(P.A), np.asarray(P.B).ravel(), np.asarray(P.C).ravel()
    # C(z) = 3.868 (1 - 1.305 z^-1 + 0.5668 z^-2) / (1 - z^-1):
    # u[k] = u[k-1] + 3.868 (e[k] - 1.305 e[k-1] + 0.5668 e[k-2])
    x = np.zeros(2)
    e = [0.0, 0.0, 0.0]  # e[k], e[k-1], e[k-2]
    u = 0.0
    T = m.load_recovery_s * 3 + 1
    K = int(T / h) + 1
    y = np.zeros(K)
    for k in range(K):
        y[k] = Cp @ x
        if k % sub == 0:
            e = [-y[k], e[0], e[1]]
            u = u + 3.868 * (e[0] - 1.305 * e[1] + 0.5668 * e[2])
        x = A @ x + B * (u + 1.0)
    iae, peak, rec = _figures(np.arange(K) * h, y)
    assert m.load_peak == pytest.approx(peak, rel=5e-3)
    assert m.load_iae == pytest.approx(iae, rel=1e-2)
    assert m.load_recovery_s == pytest.approx(rec, abs=2 * DT)


@pytest.mark.parametrize("dt", [None, 0.1])
def test_fractional_delay(dt):
    tau = 0.37
    kp, ki = 0.5, 0.2
    G = control.tf([1], [1, 3, 3, 1])
    if dt is None:
        m = analyze(G, control.tf([kp, ki], [1, 0]), delay=tau).metrics
        w = np.geomspace(1e-3, 1e2, 400001)
        s = 1j * w
        S = 1 / (1 + (kp + ki / s) * np.exp(-s * tau) / (s + 1) ** 3)
        drb, drp = _drb_drp(w, S)
        iae, peak, rec = _load_ct_pi(kp, ki, tau, T=m.load_recovery_s + 20, h=1e-3)
        assert m.load_iae == pytest.approx(iae, rel=5e-3)
    else:
        # backward-Euler PI at dt: C(z) = kp + ki dt z/(z - 1)
        C = control.tf([kp + ki * dt, -kp], [1, -1], dt)
        m = analyze(G, C, delay=tau).metrics
        w = np.geomspace(1e-3, math.pi / dt * 0.999999, 200001)
        z = np.exp(1j * w * dt)
        # the plant held and delayed 3.7 samples, exact at the samples: over a step the held input is u[k-4] for
        # the first 0.7 of it and u[k-3] for the last 0.3: x[k+1] = Ad x[k] + E_b G_a u[k-4] + G_b u[k-3], with
        # (E, G) the ZOH of the plant over 0.7 dt (a) and 0.3 dt (b)
        from scipy.linalg import expm

        frac, whole = math.modf(tau / dt)
        Gs = control.ss(G)
        A, B, Cm = np.asarray(Gs.A), np.asarray(Gs.B), np.asarray(Gs.C)

        def zoh(T):
            M = np.zeros((4, 4))
            M[:3, :3], M[:3, 3:] = A * T, B * T
            E = expm(M)
            return E[:3, :3], E[:3, 3:]

        Ad, _ = zoh(dt)
        Ea, Ga = zoh(dt * frac)  # the older input, first
        Eb, Gb = zoh(dt * (1 - frac))
        zs = z[::50]
        Gz = np.array([(Cm @ np.linalg.solve(zz * np.eye(3) - Ad,
                                             Eb @ Ga * zz ** (-whole - 1) + Gb * zz ** (-whole)))[0, 0]
                       for zz in zs])
        S = 1 / (1 + (kp + ki * dt * zs / (zs - 1)) * Gz)
        drb, drp = _drb_drp(w[::50], S)
    assert m.disturbance_rejection_bandwidth_rad_s == pytest.approx(drb, rel=1e-3)
    assert m.disturbance_rejection_peak_db == pytest.approx(drp, abs=1e-2)
