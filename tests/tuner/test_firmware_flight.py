"""Fly a tuned firmware law on its true plant with the law written here, independently of the tuner: the phase
margin and the settling time the tuner claims against what this simulation measures.

The laws are written from ../shared/reference/firmware.md (PX4 ``RateControl::update``, ArduPilot
``AC_PID::update_all``), as classes that run one sample at a time. The plant is a roll-rate airframe from normalised
torque to the gyro rate as logged (a motor lag, the rigid body, PX4's second-order gyro low-pass at 40 Hz, one
sample of computation delay). The phase margin comes from the law's own impulse response (its DTFT, not the
tuner's transfer function) times the plant's exact ZOH response from scipy; the settling time from the loop
simulated sample by sample with the plant evaluated 20 times per sample (between samples), as the verifier does.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from tuner import Spec, tune

DT = 0.0025  # 400 Hz
DELAY_SAMPLES = 1
W_GYRO = 2 * math.pi * 40.0
# torque -> rate: 250/(s (0.02 s + 1)), the gyro's Butterworth low-pass at 40 Hz
NUM = [250.0 * W_GYRO**2]
DEN = list(np.polymul(np.polymul([0.02, 1.0, 0.0], [1.0]), [1.0, math.sqrt(2) * W_GYRO, W_GYRO**2]))


def _alpha(f_hz: float, dt: float) -> float:
    return 1.0 if f_hz <= 0 else dt / (dt + 1.0 / (2.0 * math.pi * f_hz))


class PX4Rate:
    """PX4's rate law, one sample per call (clamps included: the integrator limit, no growth into saturation,
    the fade for large errors, the output limits)."""

    def __init__(self, g: dict, dt: float, u_min: float = -math.inf, u_max: float = math.inf) -> None:
        self.g, self.dt, self.lo, self.hi = g, dt, u_min, u_max
        self.a = _alpha(g["dgyro_hz"], dt)
        self.xi = self.w_prev = self.wdot_f = 0.0  # running at rest (hover) before the step

    def __call__(self, r: float, w: float) -> float:
        g, dt = self.g, self.dt
        k = g["K"]
        e = r - w
        wdot = (w - self.w_prev) / dt
        self.wdot_f += self.a * (wdot - self.wdot_f)
        self.w_prev = w
        u_raw = k * g["P"] * e + self.xi - k * g["D"] * self.wdot_f + g["FF"] * r
        u = min(max(u_raw, self.lo), self.hi)
        # updateIntegral: no growth in the direction the output saturates; fade for large errors; clamp
        ei = e
        if (u_raw > self.hi and ei > 0) or (u_raw < self.lo and ei < 0):
            ei = 0.0
        fade = max(0.0, 1.0 - (ei / math.radians(400.0)) ** 2)
        self.xi = min(max(self.xi + fade * k * g["I"] * ei * dt, -g["int_lim"]), g["int_lim"])
        return u


class ArduPilotRate:
    """ArduPilot's AC_PID::update_all plus its FF, one sample per call (IMAX; the integrator only shrinks while
    the output is limited; the output limits)."""

    def __init__(self, g: dict, dt: float, u_min: float = -math.inf, u_max: float = math.inf) -> None:
        self.g, self.dt, self.lo, self.hi = g, dt, u_min, u_max
        self.at, self.ae, self.ad = (_alpha(g[k], dt) for k in ("fltt_hz", "flte_hz", "fltd_hz"))
        self.T = self.E = self.D = self.I = self.e_prev = 0.0  # running at rest (hover) before the step: the
        self.limited = False  # filters' first-call reset is long past

    def __call__(self, target: float, w: float) -> float:
        g, dt = self.g, self.dt
        self.T += self.at * (target - self.T)
        self.E += self.ae * ((self.T - w) - self.E)
        self.D += self.ad * ((self.E - self.e_prev) / dt - self.D)
        self.e_prev = self.E
        step = g["I"] * self.E * dt
        if not self.limited or (self.I > 0 and step < 0) or (self.I < 0 and step > 0):
            self.I = min(max(self.I + step, -g["imax"]), g["imax"])
        u_raw = g["P"] * self.E + g["D"] * self.D + self.I + g["FF"] * self.T
        u = min(max(u_raw, self.lo), self.hi)
        self.limited = u != u_raw
        return u


LAWS = {"px4_rate": PX4Rate, "ardupilot_rate": ArduPilotRate}


def law_response(name: str, g: dict, w: np.ndarray) -> np.ndarray:
    """``C_fb(e^{j w dt})`` of the law from its impulse response on the measurement (r = 0): the first difference
    of the response decays (the integrator's pole at 1 is removed), its DTFT over (1 - e^{-j w dt})."""
    n = 4000
    law = LAWS[name](g, DT)
    y = np.zeros(n)
    y[0] = 1.0
    u = np.array([-law(0.0, yk) for yk in y])  # C_fb acts on -y
    v = np.diff(np.concatenate([[0.0], u]))
    z = np.exp(-1j * np.outer(w * DT, np.arange(n)))
    return (z @ v) / (1 - np.exp(-1j * w * DT))


def plant_response(w: np.ndarray) -> np.ndarray:
    b, a, _ = signal.cont2discrete((NUM, DEN), DT, method="zoh")
    _, h = signal.freqz(np.ravel(b), a, worN=w * DT)
    return h * np.exp(-1j * w * DT * DELAY_SAMPLES)


def phase_margin(name: str, g: dict) -> float:
    """The worst phase margin over the gain crossings of the law's loop on a fine grid (linear interpolation)."""
    w = np.geomspace(1.0, 0.999 * math.pi / DT, 6000)
    L = law_response(name, g, w) * plant_response(w)
    mag = np.log(np.abs(L))
    ph = np.degrees(np.unwrap(np.angle(L)))
    pms = []
    for i in np.flatnonzero(np.sign(mag[:-1]) != np.sign(mag[1:])):
        t = mag[i] / (mag[i] - mag[i + 1])
        p = (ph[i] + t * (ph[i + 1] - ph[i]) + 180.0) % 360.0
        pms.append(p - 360.0 if p > 180.0 else p)
    return min(pms)


def fly(name: str, g: dict, *, amplitude: float = 1.0, u_min: float = -math.inf, u_max: float = math.inf,
        t_end: float = 1.0, sub: int = 20) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A setpoint step flown sample by sample: the law at each sample, the plant's state advanced ``sub`` times per
    sample by its exact ZOH map (the output between samples); returns (t, y) at the fine points and u per sample."""
    A, B, C, _ = signal.tf2ss(NUM, DEN)
    h = DT / sub
    Ad, Bd, _, _, _ = signal.cont2discrete((A, B, C, np.zeros((1, 1))), h, method="zoh")
    law = LAWS[name](g, DT, u_min, u_max)
    n = int(round(t_end / DT))
    x = np.zeros(A.shape[0])
    us = [0.0] * (DELAY_SAMPLES + 1)
    ts, ys, u_out = [], [], []
    for k in range(n):
        w_meas = float((C @ x)[0])
        u = law(amplitude, w_meas)
        u_out.append(u)
        us.append(u)
        u_applied = us[-1 - DELAY_SAMPLES]
        for j in range(sub):
            ts.append(k * DT + j * h)
            ys.append(float((C @ x)[0]))
            x = Ad @ x + Bd.ravel() * u_applied
    return np.array(ts), np.array(ys), np.array(u_out)


def settling_time(t: np.ndarray, y: np.ndarray, final: float, band: float = 0.02) -> float:
    out = np.flatnonzero(np.abs(y - final) > band * abs(final))
    return float(t[out[-1] + 1]) if out.size else 0.0


def exported_gains(res, tmp_path) -> dict:
    """The result exported as its firmware's parameter file and read back (the values the vehicle gets)."""
    from tuner.export.paramfile import param_file
    from tuner.firmware import read_params

    fmt = "px4" if res.structure == "px4_rate" else "ardupilot"
    text, name = param_file(res.to_dict(), fmt)
    p = tmp_path / name
    p.write_text(text)
    v = read_params(p, firmware=fmt)
    return {**v.gains, **v.fixed}


@pytest.mark.slow
@pytest.mark.parametrize("name", ["px4_rate", "ardupilot_rate"])
def test_the_tuned_law_flies_as_claimed(name, tmp_path):
    import control as ct

    res = tune(ct.tf(NUM, DEN), structure=name, dt=DT, delay=DT * DELAY_SAMPLES, time_budget_s=10)
    assert res.meets_spec
    g = exported_gains(res, tmp_path)  # what the ground station loads, read back: the design that flies
    pm = phase_margin(name, g)
    assert pm >= 60.0 - 0.5  # the spec, to the grid's resolution
    assert res.metrics.phase_margin_deg == pytest.approx(pm, abs=2.0)
    t, y, _ = fly(name, g, t_end=max(1.0, 4 * res.metrics.settling_time_s))
    ts = settling_time(t, y, 1.0)
    assert res.metrics.settling_time_s == pytest.approx(ts, rel=0.05)
    overshoot = 100 * (y.max() - 1.0)
    assert res.metrics.overshoot_pct == pytest.approx(overshoot, abs=0.5)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["px4_rate", "ardupilot_rate"])
def test_the_saturated_step_is_the_laws(name, tmp_path):
    """An 8 rad/s step with |u| <= 0.4 (the proportional kick alone asks for about 1): the tuner's saturated step
    (tuner.analysis.saturation) against the laws above with their own clamps, flown between samples."""
    import control as ct

    from tuner.analysis.saturation import Actuator

    act = Actuator.of(u_max=0.4, step_size=8.0)
    # the fastest reference step (its proportional kick saturates most; the default's load design kicks less)
    res = tune(ct.tf(NUM, DEN), structure=name, dt=DT, delay=DT * DELAY_SAMPLES, time_budget_s=10, actuator=act,
               spec=Spec(objective="settling_time", gain_variation=None))
    s = res.analyses[0].saturated
    assert s is not None and s.saturated_fraction > 0.05  # it does saturate
    t, y, u = fly(name, exported_gains(res, tmp_path), amplitude=8.0, u_min=-0.4, u_max=0.4,
                  t_end=float(s.response.t[-1]))
    assert np.max(np.abs(u)) == pytest.approx(0.4)
    ts = settling_time(t, y, 8.0)
    assert s.metrics.settling_time_s == pytest.approx(ts, rel=0.05)
    assert s.metrics.overshoot_pct == pytest.approx(100 * (y.max() - 8.0) / 8.0, abs=1.5)
