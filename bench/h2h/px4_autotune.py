"""PX4's multicopter attitude autotune, ported: excitation, prefilters, ARX RLS, GMVC design, checks.

Sources (PX4/PX4-Autopilot; file @ commit as read):

- src/modules/mc_autotune_attitude_control/mc_autotune_attitude_control.cpp
  @ 1e1cbde1201973c3a6adee1af3c828c72b37be4a (``Run``, ``checkFilters``, ``updateStateMachine``,
  ``getIdentificationSignal``, ``copyGains``, ``areGainsGood``, ``saveGainsToParams``) and its header
  mc_autotune_attitude_control.hpp @ 011a4138d02cad755392d73825879e5b90cec1e0 (``_model_dt_min`` 2 ms,
  ``_model_dt_max`` 10 ms, ``_publishing_dt_s`` 100 ms, the wash-out ``AlphaFilter _signal_filter``);
  parameters mc_autotune_attitude_control_params.yaml @ 1685103f9c127c258fe088fc7232fd0a0b49a31c
  (``MC_AT_SYSID_AMP`` 0.7, ``MC_AT_RISE_TIME`` 0.14 s);
- src/lib/system_identification/system_identification.cpp @ 25ed6b67fb1174d88b4834076ec812c3fabd139d and
  system_identification.hpp @ 086d1653b992d81eaf4feafd2a5bf21ff190f307 (``ArxRls<2, 2, 1>``, the input/output
  ``LowPassFilter2p`` at ``IMU_GYRO_CUTOFF`` and the first-order high-pass at 0.5 Hz, both at the torque
  setpoint's rate; the model updated every ``_model_update_scaler`` samples);
- src/lib/system_identification/arx_rls.hpp @ 25ed6b67fb1174d88b4834076ec812c3fabd139d (the same at
  f929353e779a41434625a877d1a9d200f5c16272): ``P`` initialised to 1e4 I, the update
  ``P = (P - P phi phi' P/(lambda + phi' P phi))/lambda``, ``theta += P phi (y - phi' theta)``, the regressor
  ``[-y[k-1], -y[k-2], u[k-1], u[k-2], u[k-3]]`` (delay 1), no update until the buffers are full,
  ``lambda = 1 - dt/60 s``;
- src/lib/pid_design/pid_design.hpp @ 021bbcdc2eb0c5802b46f91ec092021631f9291e (``computePidGmvc``; Yamamoto,
  Fujii, Kaneda 1998), called with ``sigma`` = the rise time (yaw 0.2 s), ``delta`` 0, ``lambda`` 0.7.

What the port does, in order, on the simulated vehicle (:mod:`h2h.sim`) flying the firmware's PX4 law with the
vehicle's current gains: the roll state's reset (``_sys_id.reset()``, the step counter at 5 of 10, the input scale
``1/(MC_ROLLRATE_P * MC_ROLLRATE_K)``); every loop sample the prefilters on (scaled torque setpoint, filtered
rate); every ``scaler`` samples the RLS update; every publication (the first sample more than 100 ms after the
last) the state machine (converged: every ``diag(P) < 50`` and more than 5 s in the state: the gains of the
*previous* publication are copied), the model's coefficients rescaled by the input scale, the GMVC design at
``model_dt``, the D clip (``-0.001 < kd < 0`` -> 0), the attitude gain, and the next excitation value (a square
wave of decreasing half-periods 6, 10, 9, ..., 2, 6, 5, ... publications, 0 or ``MC_AT_SYSID_AMP``, minus its own
0.2 s wash-out), which becomes the rate setpoint from the next sample on. Then ``areGainsGood`` and the saved
parallel form ``P = kc, I = kc ki, D = kc kd, K = 1``.

Simplified (said in the report): the attitude loop is not flown (the excitation is the rate setpoint; the washed-out
square wave returns the rate to 0 by itself); only the roll axis is identified and checked; float64 instead of
float32 (``int(model_dt/filter_dt)`` is taken in float32 as the firmware does); the sample interval is exact
(no jitter); the turbulence is a seeded low-passed torque at the plant input; the module starts with its filters
initialised (the 1000-interval rate measurement done).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .airframes import Airframe
from .laws import PX4_DEFAULTS, PX4Law
from .sim import biquad, lift

__all__ = ["gmvc", "ArxRls", "SystemIdentification", "Px4AutotuneResult", "px4_autotune"]

MODEL_DT_MIN = 2e-3
MODEL_DT_MAX = 10e-3
PUBLISH_DT = 0.1
CONVERGED_THR = 50.0
SYSID_AMP = 0.7  # MC_AT_SYSID_AMP
RISE_TIME = 0.14  # MC_AT_RISE_TIME


def gmvc(num, den, dt: float, sigma: float = 0.1, delta: float = 1.0, lbda: float = 0.5) -> tuple[float, float, float]:
    """``computePidGmvc``: ``(kc, ki, kd)`` in the standard form ``u = kc (1 + ki dt/(1 - z^-1) + kd/dt (1 - z^-1))``
    (ki = 1/Ti with the firmware's extra ``/5``, kd = Td) for the model ``(b0 + b1 z^-1 + b2 z^-2) z^-1 /
    (1 + a1 z^-1 + a2 z^-2)``."""
    sigma = min(max(sigma, 0.01), 1.0)
    delta = min(max(delta, 0.0), 1.0)
    lbda = min(max(lbda, 0.0), 10.0)
    a1, a2 = den[1], den[2]
    b0, b1, b2 = num
    rho = dt / sigma
    mu = 0.25 * (1.0 - delta) + 0.51 * delta
    p1 = -2.0 * math.exp(-rho / (2.0 * mu)) * math.cos(math.sqrt(4.0 * mu - 1.0) * rho / (2.0 * mu))
    p2 = math.exp(-rho / mu)
    e1 = -a1 + p1 + 1.0
    f0 = -a1 * e1 + a1 - a2 + e1 + p2
    f1 = a1 * e1 - a2 * e1 + a2
    f2 = a2 * e1
    nu = lbda + (e1 + 1.0) * (b0 + b1 + b2)
    if abs(nu) < np.finfo(np.float32).eps:
        return 0.0, 0.0, 0.0
    kc = -(f1 + 2.0 * f2) / nu
    if f1 + 2.0 * f2 == 0.0:  # float division by zero in the firmware (inf/nan): only before the model moves
        return kc, math.nan, math.nan
    ki = -(f0 + f1 + f2) / (dt * (f1 + 2.0 * f2))
    ki /= 5.0
    kd = -dt * f2 / (f1 + 2.0 * f2)
    return kc, ki, kd


class ArxRls:
    """``ArxRls<N, M, D>``: recursive least squares without matrix inversion, forgetting factor ``lam``."""

    def __init__(self, n: int = 2, m: int = 2, d: int = 1) -> None:
        self.n, self.m, self.d = n, m, d
        self.lam = 1.0
        self.reset()

    def reset(self) -> None:
        k = self.n + self.m + 1
        self.P = np.eye(k) * 10e3
        self.theta = np.zeros(k)
        self.u = np.zeros(self.m + self.d + 1)
        self.y = np.zeros(self.n + 1)
        self.nb = 0
        self.innovation = 0.0

    def set_forgetting(self, time_constant: float, dt: float) -> None:
        self.lam = 1.0 - dt / time_constant

    def update(self, u: float, y: float) -> None:
        n, m, d = self.n, self.m, self.d
        self.y[:-1] = self.y[1:]
        self.u[:-1] = self.u[1:]
        self.u[m + d] = u
        self.y[n] = y
        if self.nb <= m + n + d:  # addInputOutput counts until the buffers are full; update() waits for that
            self.nb += 1
            if self.nb <= m + n + d:
                return
        phi = np.concatenate([-self.y[n - 1::-1][:n], self.u[m::-1][:m + 1]])
        P = self.P
        Pphi = P @ phi
        self.P = (P - np.outer(Pphi, Pphi) / (self.lam + phi @ Pphi)) / self.lam
        self.innovation = self.y[n] - phi @ self.theta
        self.theta = self.theta + self.P @ phi * self.innovation


class _LowPass2p:
    """``math::LowPassFilter2p`` (direct form II; ``reset`` to a steady state at the sample)."""

    def __init__(self, fs: float, fc: float) -> None:
        self.b0, self.b1, self.b2, self.a1, self.a2 = biquad(fs, fc)
        self.d1 = self.d2 = 0.0

    def apply(self, x: float) -> float:
        d0 = x - self.d1 * self.a1 - self.d2 * self.a2
        out = d0 * self.b0 + self.d1 * self.b1 + self.d2 * self.b2
        self.d2, self.d1 = self.d1, d0
        return out

    def reset(self, x: float) -> float:
        v = x / (self.b0 + self.b1 + self.b2)
        self.d1 = self.d2 = v
        return self.apply(x)


class SystemIdentification:
    """``SystemIdentification``: the LPF + HPF prefilters on (u, y) and the ``ArxRls<2, 2, 1>``."""

    def __init__(self, fs: float, lpf_hz: float, hpf_hz: float = 0.5) -> None:
        self.rls = ArxRls(2, 2, 1)
        self.u_lpf = _LowPass2p(fs, lpf_hz)
        self.y_lpf = _LowPass2p(fs, lpf_hz)
        self.alpha_hpf = fs / (fs + 2.0 * math.pi * hpf_hz)
        self.reset()

    def reset(self) -> None:
        self.rls.reset()
        self.u_hpf = self.y_hpf = self.u_prev = self.y_prev = 0.0
        self.initialized = False

    def update_filters(self, u: float, y: float) -> None:
        if not self.initialized:
            self.u_lpf.reset(u)
            self.y_lpf.reset(y)
            self.u_hpf = self.y_hpf = 0.0
            self.u_prev, self.y_prev = u, y
            self.initialized = True
            return
        ul = self.u_lpf.apply(u)
        yl = self.y_lpf.apply(y)
        self.u_hpf = self.alpha_hpf * self.u_hpf + self.alpha_hpf * (ul - self.u_prev)
        self.y_hpf = self.alpha_hpf * self.y_hpf + self.alpha_hpf * (yl - self.y_prev)
        self.u_prev, self.y_prev = ul, yl

    def update(self) -> None:
        self.rls.update(self.u_hpf, self.y_hpf)


@dataclass
class Px4AutotuneResult:
    ok: bool
    gains: dict | None  # P, I, D, FF, K (parallel form, K = 1) over the vehicle's fixed values
    reason: str
    model_num: list
    model_den: list
    model_dt: float
    identified_s: float  # time in the roll state until convergence
    kid: tuple = ()
    att_p: float = math.nan
    variances: list = field(default_factory=list)


def _model_scaler(loop_dt: float, gyro_hz: float) -> int:
    f32 = np.float32
    model_dt = min(max(max(1.0 / (2.0 * gyro_hz), loop_dt), MODEL_DT_MIN), MODEL_DT_MAX)
    return max(int(f32(model_dt) / f32(loop_dt)), 1)


def px4_autotune(af: Airframe, start: dict | None = None, *, seed: int = 0, turbulence: float = 0.01,
                 rise_time: float = RISE_TIME, amp: float = SYSID_AMP, timeout_s: float = 20.0
                 ) -> Px4AutotuneResult:
    """Run the autotune's roll identification on ``af`` flying PX4's law with ``start`` (the vehicle's current
    gains, default the firmware's) and design from the converged model."""
    g = {**PX4_DEFAULTS, **(start or {})}
    T = af.dt
    lifted = lift(af, "px4", dgyro_hz=g["dgyro_hz"])
    law = PX4Law(g, T)
    fs = 1.0 / T  # the torque setpoint's rate: every loop sample
    gyro_hz = af.px4_gyro_hz
    scaler = _model_scaler(T, gyro_hz)
    model_dt = scaler * T
    sysid = SystemIdentification(fs, gyro_hz, 0.5)
    sysid.rls.set_forgetting(60.0, model_dt)
    # the wash-out filter of the excitation: AlphaFilter(0.1 s, 0.2 s), updated at each publication
    a_sig = PUBLISH_DT / (0.2 + PUBLISH_DT)
    sig_state = 0.0
    # roll state entry (updateStateMachine, init -> roll)
    sysid.reset()
    steps_counter, max_steps, signal_sign = 5, 10, 1
    input_scale = 1.0 / (g["P"] * g["K"])
    rng = np.random.default_rng(seed)
    # turbulence: white noise through a 2 Hz first-order low-pass, std `turbulence` torque
    a_t = T / (T + 1 / (2 * math.pi * 2.0))
    turb_w = rng.standard_normal(int(timeout_s / T) + 10) * turbulence * math.sqrt((2 - a_t) / a_t)
    turb = 0.0
    X = np.zeros(lifted.nx)
    F, G, Cy = lifted.F, lifted.G[:, 0], lifted.Cy
    publish_every = int(math.floor(PUBLISH_DT / T + 1e-9)) + 1  # "elapsed > 100 ms"
    rate_sp = 0.0
    counter = 0
    kid = kid_prev = (0.0, 0.0, 0.0)
    att_p = att_p_prev = math.nan
    n = int(round(timeout_s / T))
    num = den = None
    for k in range(n):
        y = Cy @ X
        u = law.step(rate_sp, y[0], y[1])
        turb += a_t * (turb_w[k] - turb)
        X = F @ X + G * (u + turb)
        # the module, on this torque setpoint (and the angular velocity of the same sample)
        sysid.update_filters(input_scale * u, y[0])
        counter += 1
        if counter >= scaler:
            sysid.update()
            counter = 0
        if k % publish_every == 0:
            t_state = k * T
            var = np.diag(sysid.rls.P)
            if np.all(var < CONVERGED_THR) and t_state > 5.0:
                kc, ki, kd = kid_prev  # copyGains: the previous publication's design
                good = 0 < kc < 0.5 and 0 < ki < 10 and 0 <= kd < 0.1 and 0 < att_p_prev < 12
                gains = {"P": kc, "I": kc * ki, "D": kc * kd, "FF": 0.0, "K": 1.0,
                         "dgyro_hz": g["dgyro_hz"], "int_lim": g["int_lim"]}
                return Px4AutotuneResult(good, gains if good else None,
                                         "converged" if good else f"areGainsGood fails: kc {kc:.4g}, ki {ki:.4g}, "
                                         f"kd {kd:.4g}", num, den, model_dt, t_state, kid_prev, att_p_prev,
                                         var.tolist())
            theta = sysid.rls.theta
            num = [theta[2] * input_scale, theta[3] * input_scale, theta[4] * input_scale]
            den = [1.0, theta[0], theta[1]]
            kid_prev, att_p_prev = kid, att_p
            kc, ki, kd = gmvc(num, den, model_dt, rise_time, 0.0, 0.7)
            if -0.001 < kd < 0.0:
                kd = 0.0
            kid = (kc, ki, kd)
            att_p = min(max(1.0 / (math.radians(60.0) * kc), 2.0), 6.5) if kc != 0 else 6.5
            if k > 0 and sysid.initialized:  # getIdentificationSignal (not on the roll state's entry publication)
                if steps_counter > max_steps:
                    signal_sign = 0 if signal_sign == 1 else 1
                    steps_counter = 0
                    max_steps = max_steps - 1 if max_steps > 1 else 5
                steps_counter += 1
                step = signal_sign * amp
                rate_sp = step - sig_state
                sig_state += a_sig * (step - sig_state)
            else:
                rate_sp = 0.0
    return Px4AutotuneResult(False, None, f"no convergence within {timeout_s:g} s (timeout)", num or [], den or [],
                             model_dt, timeout_s, kid, att_p, np.diag(sysid.rls.P).tolist())
