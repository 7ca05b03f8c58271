"""PX4's and ArduPilot's rate laws, one sample per call, written here from the firmware sources (not from tuner).

PX4 (``src/lib/rate_control/rate_control.cpp`` @ 0155b3a86295e554b4099188bfcb45d0724cd04b, ``RateControl::update``
and ``updateIntegral``; the gains ``K*P, K*I, K*D`` and an unscaled FF set in
``src/modules/mc_rate_control/MulticopterRateControl.cpp`` ``parameters_updated``)::

    torque = P e + I_state - D wdot + FF w_sp           e = w_sp - w (w: the gyro low-passed rate)
    then updateIntegral: e' = e, but not growing into a saturated direction;
         i_factor = max(0, 1 - (e'/radians(400))^2);  I_state = clamp(I_state + i_factor I e' dt, +-int_lim)

``wdot`` is ``vehicle_angular_velocity.xyz_derivative``: computed in
``src/modules/sensors/vehicle_angular_velocity/VehicleAngularVelocity.cpp`` (``FilterAngularAcceleration``) on
every raw gyro sample from the gyro-low-passed samples (``FilterAngularVelocity`` filters the array in place
first), differenced over the raw dt and low-passed by a first-order ``AlphaFilter`` at ``IMU_DGYRO_CUTOFF``
(``_lp_filter_acceleration`` is ``AlphaFilter<float>`` in VehicleAngularVelocity.hpp
@ 85e60904e810939752623b4c9c2fa305504a73e4; ``AlphaFilter::setCutoffFreq(fs, fc)`` gives
``alpha = (1/fs)/(1/fs + 1/(2 pi fc))``, src/lib/mathlib/math/filter/AlphaFilter.hpp
@ f66bdc0f22d072fcb9b4a57c12e9beae302e16fc; 2021-era code used a ``LowPassFilter2p`` there). That raw-rate path
lives in :mod:`h2h.sim`; the law here takes its last value.

ArduPilot (``libraries/AC_PID/AC_PID.cpp`` @ 00e79c1a8acab395a4f068e626b86bde8855a3cb, ``update_all`` and
``update_i``; FF is ``get_ff() = _target * _kff``, the filtered target, added by the rate controller)::

    T += aT (target - T);  E += aE ((T - w) - E);  Dv += aD ((E - E_prev)/dt - Dv)
    I += I E dt unless limited and growing; clamp +-IMAX           (before the output)
    out = P E + D Dv + I + FF T

``a = dt/(dt + 1/(2 pi f))`` (``calc_lowpass_alpha_dt``; ``f <= 0``: 1). The laws start at rest (the filters'
first-call reset long past: a vehicle hovering before the step).

Each law also gives its linear matrices (clamps off) by applying its own update to unit vectors, so the linear
loop in :mod:`h2h.metrics` is the per-sample code, not a second transcription.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["PX4_DEFAULTS", "AP_DEFAULTS", "alpha", "PX4Law", "ArduPilotLaw", "make_law", "law_matrices"]

#: MC_ROLLRATE_P/I/D/FF/K, MC_RR_INT_LIM (src/modules/mc_rate_control/mc_rate_control_params.yaml
#: @ e87d6afab11bd496de871a9c4fed05d42dd8e1f2); the D-gyro cutoff IMU_DGYRO_CUTOFF 20 Hz
PX4_DEFAULTS = {"P": 0.15, "I": 0.2, "D": 0.003, "FF": 0.0, "K": 1.0, "dgyro_hz": 20.0, "int_lim": 0.3}
#: ATC_RAT_RLL_P/I/D/FF/IMAX and the filters (AC_AttitudeControl_Multi.h @ 05ae9d2fdcc0b259e590b3e2198d7c2972a65c2b:
#: AC_ATC_MULTI_RATE_RP_P/I/D/IMAX/FILT_HZ; FLTE 0)
AP_DEFAULTS = {"P": 0.135, "I": 0.135, "D": 0.0036, "FF": 0.0, "fltt_hz": 20.0, "flte_hz": 0.0, "fltd_hz": 20.0,
               "imax": 0.5}


def alpha(f_hz: float, dt: float) -> float:
    """First-order low-pass coefficient (ArduPilot's calc_lowpass_alpha_dt, PX4's AlphaFilter)."""
    if f_hz <= 0:
        return 1.0
    return dt / (dt + 1.0 / (2.0 * math.pi * f_hz))


@dataclass
class PX4Law:
    """``RateControl::update`` for one axis. Inputs per sample: the setpoint, the filtered rate, the D-path value
    ``wdot`` (from the sensor chain). ``sat_pos`` / ``sat_neg``: the allocator's saturation flags."""

    g: dict
    dt: float
    linear: bool = False  # no fade, no clamp (the linear matrices)
    state: np.ndarray = field(default_factory=lambda: np.zeros(1))
    int_clamped: bool = False

    n_in = 3  # (r, w, wdot)

    def update(self, s: np.ndarray, r: float, w: float, wdot: float, sat_pos: bool = False,
               sat_neg: bool = False) -> tuple[np.ndarray, float]:
        g = self.g
        k = g["K"]
        e = r - w
        u = k * g["P"] * e + s[0] - k * g["D"] * wdot + g["FF"] * r
        ei = e
        if sat_pos:
            ei = min(ei, 0.0)
        if sat_neg:
            ei = max(ei, 0.0)
        if self.linear:
            xi = s[0] + k * g["I"] * ei * self.dt
        else:
            f = ei / math.radians(400.0)
            f = max(0.0, 1.0 - f * f)
            xi = s[0] + f * k * g["I"] * ei * self.dt
            lim = g["int_lim"]
            if abs(xi) > lim:
                self.int_clamped = True
            xi = min(max(xi, -lim), lim)
        return np.array([xi]), u

    def step(self, r: float, w: float, wdot: float = 0.0, **kw) -> float:
        self.state, u = self.update(self.state, r, w, wdot, **kw)
        return u


@dataclass
class ArduPilotLaw:
    """``AC_PID::update_all`` plus the rate controller's FF for one axis. Inputs per sample: the target and the
    filtered rate (``wdot`` is ignored: ArduPilot differentiates the filtered error itself, at the loop rate).
    ``limit``: the motors' limit flag for this axis."""

    g: dict
    dt: float
    linear: bool = False
    state: np.ndarray = field(default_factory=lambda: np.zeros(4))  # T, E, Dv, I
    int_clamped: bool = False

    n_in = 3

    def update(self, s: np.ndarray, r: float, w: float, wdot: float = 0.0, limit: bool = False
               ) -> tuple[np.ndarray, float]:
        g, dt = self.g, self.dt
        at, ae, ad = alpha(g["fltt_hz"], dt), alpha(g["flte_hz"], dt), alpha(g["fltd_hz"], dt)
        T, E, Dv, xi = s
        e_last = E
        T = T + at * (r - T)
        E = E + ae * ((T - w) - E)
        Dv = Dv + ad * ((E - e_last) / dt - Dv)
        if g["I"] != 0.0:
            if self.linear:
                xi = xi + g["I"] * E * dt
            elif not limit or (xi > 0 and E < 0) or (xi < 0 and E > 0):
                xi = xi + g["I"] * E * dt
                if abs(xi) > g["imax"]:
                    self.int_clamped = True
                xi = min(max(xi, -g["imax"]), g["imax"])
        else:
            xi = 0.0
        u = g["P"] * E + g["D"] * Dv + xi + g["FF"] * T
        return np.array([T, E, Dv, xi]), u

    def step(self, r: float, w: float, wdot: float = 0.0, **kw) -> float:
        self.state, u = self.update(self.state, r, w, wdot, **kw)
        return u


def make_law(firmware: str, gains: dict, dt: float, linear: bool = False):
    """A fresh law at rest for ``firmware`` (``"px4"`` or ``"ardupilot"``) with ``gains`` over its defaults."""
    if firmware == "px4":
        return PX4Law({**PX4_DEFAULTS, **gains}, dt, linear)
    return ArduPilotLaw({**AP_DEFAULTS, **gains}, dt, linear)


def law_matrices(firmware: str, gains: dict, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, C, D)`` of the linear law (clamps off): ``s' = A s + B v``, ``u = C s + D v``, ``v = (r, w, wdot)``,
    obtained by applying the law's own update to unit states and inputs."""
    law = make_law(firmware, gains, dt, linear=True)
    n = law.state.size
    m = 3
    A = np.zeros((n, n))
    B = np.zeros((n, m))
    C = np.zeros((1, n))
    D = np.zeros((1, m))
    zero = np.zeros(n)
    for i in range(n):
        e = np.zeros(n)
        e[i] = 1.0
        s1, u = law.update(e, 0.0, 0.0, 0.0)
        A[:, i] = s1
        C[0, i] = u
    for j in range(m):
        v = [0.0, 0.0, 0.0]
        v[j] = 1.0
        s1, u = law.update(zero, *v)
        B[:, j] = s1
        D[0, j] = u
    return A, B, C, D
