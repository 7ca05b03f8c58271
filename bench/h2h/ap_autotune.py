"""ArduPilot's multicopter AutoTune, emulated: the twitch tests and their gain updates, flown on ArduPilot's law.

Sources (ArduPilot/ardupilot; file @ commit as read):

- libraries/AC_AutoTune/AC_AutoTune_Multi.cpp @ a75d1d40108e8688cf063d02f07b3b1054a74ee3: the constants
  (``AUTOTUNE_AGGR`` default 0.1, constrained to 0.05..0.2; ``AUTOTUNE_MIN_D`` 0.001; RD/RP/SP steps 0.05; RD_MAX
  0.2; RP_MIN 0.01, RP_MAX 2.0; SP_MIN 0.5, SP_MAX 40; ``AUTOTUNE_D_UP_DOWN_MARGIN`` 0.2; backoffs RD 1.0, RP 1.0,
  SP 0.9; ``AUTOTUNE_PI_RATIO_FINAL`` 1.0; the step timeout 1000 ms; target rate 45..180 deg/s), ``load_test_gains``
  (P, I = 0.01 P, D, FF 0, FLTT 0, SMAX 0), ``twitch_test_init`` / ``twitch_test_run`` (the rate step
  ``target_rate`` from ``max_rate_step_bf_roll``, the angle step ``target_angle``, the measured rate through a
  first-order low-pass at twice FLTD), ``twitching_test_rate``, ``twitching_abort_rate``, ``twitching_test_angle``,
  ``updating_rate_d_up``, ``updating_rate_d_down``, ``updating_rate_p_up_d_down``, ``updating_angle_p_down``,
  ``updating_angle_p_up``, ``set_gains_post_tune``, ``save_tuning_gains`` (I = P, FF and FLTT restored);
- libraries/AC_AutoTune/AC_AutoTune.cpp @ 79f4e0a2d86464d0eca7d66f5db0ad9e8846d6cb (``control_attitude``: a twitch
  per test, ``UPDATE_GAINS``, ``counter >= AUTOTUNE_SUCCESS_COUNT`` (4, AC_AutoTune.h) ends a tune type, the
  counter and ``step_scaler`` reset, ``next_tune_type``) and AC_AutoTune_Multi.h
  @ 1fe5c5fbd0382e485da973e5554b5d7f9ed3973f (the sequence RD_UP, RD_DOWN, RP_UP, SP_DOWN, SP_UP);
- libraries/AC_AttitudeControl/AC_AttitudeControl.cpp @ 00f02a67266abf4a5ac287a22ea9a98fdb38561f
  (``max_rate_step_bf_roll`` = 2 clamp(MOT_THST_HOVER, 0.1, 0.5) / ((1 - a)^3 a D/dt + P), a = min(FLTE, FLTD
  alphas); the angle loop without the square-root controller, as the twitch runs it: rate target = angle P times
  the angle error); the abort angle 20 deg and the angle target 10..20 deg (AUTOTUNE_TARGET_ANGLE_RLLPIT_CD 2000,
  AUTOTUNE_TARGET_MIN_ANGLE_RLLPIT_CD 1000, AC_AutoTune.h of the same era); ``ATC_ANG_RLL_P`` 4.5.

Each twitch is flown on :mod:`h2h.sim` with ArduPilot's law (:mod:`h2h.laws`), the mixer output clamped to +-1 and
the integrator frozen while it is (the ``limit`` flag). Simplified (said in the report): every twitch starts from
rest, level, at zero rate (the WAITING_FOR_LEVEL phase with the intra-test gains is not flown; ``start_rate`` 0);
the direction alternates in the firmware, which a linear symmetric airframe cannot tell apart, so every twitch is
flown positive; no pilot input, no position hold, no roll-over protection (never reached here); the millisecond
clock is exact; only the roll axis is tuned; the maximum-acceleration measurement (``ATC_ACCEL_R_MAX``) is not
used (it does not enter the rate law).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .airframes import Airframe
from .laws import AP_DEFAULTS, ArduPilotLaw, alpha
from .sim import lift

__all__ = ["ApAutotuneResult", "ap_autotune", "ANGLE_P_DEFAULT"]

AGGR = 0.1
MIN_D = 0.001
RD_STEP = RP_STEP = SP_STEP = 0.05
RD_MAX = 0.2
RP_MIN, RP_MAX = 0.01, 2.0
SP_MIN, SP_MAX = 0.5, 40.0
D_UP_DOWN_MARGIN = 0.2
RD_BACKOFF, RP_BACKOFF, SP_BACKOFF = 1.0, 1.0, 0.9
PI_RATIO_FINAL = 1.0
STEP_TIMEOUT = 1.0  # AUTOTUNE_TESTING_STEP_TIMEOUT_MS
TARGET_RATE_CDS = 18000.0
TARGET_MIN_RATE_CDS = 4500.0
TARGET_ANGLE_CD, TARGET_MIN_ANGLE_CD = 2000.0, 1000.0
ABORT_ANGLE_CD = 2000.0
SUCCESS_COUNT = 4
ANGLE_P_DEFAULT = 4.5  # ATC_ANG_RLL_P
SEQUENCE = ("RD_UP", "RD_DOWN", "RP_UP", "SP_DOWN", "SP_UP")
MAX_TWITCHES = 300  # per tune type (a bound of this emulation, not the firmware's)


def _cd(x_rad: float) -> float:
    return math.degrees(x_rad) * 100.0


@dataclass
class ApAutotuneResult:
    ok: bool
    gains: dict | None
    angle_p: float
    reason: str
    twitches: dict = field(default_factory=dict)  # per tune type
    history: list = field(default_factory=list)  # (type, rp, rd, sp, max, min) per twitch


class _Tuner:
    def __init__(self, af: Airframe, start: dict, angle_p: float) -> None:
        self.af = af
        self.orig = dict(start)
        self.rp, self.rd, self.sp = start["P"], start["D"], angle_p
        self.counter = 0
        self.ignore_next = False
        self.step_scaler = 1.0
        self.lifted = lift(af, "ardupilot")
        self.dt = af.dt

    # -- flying a twitch -----------------------------------------------------------------------------------
    def _test_gains(self) -> dict:
        return {**self.orig, "P": self.rp, "I": self.rp * 0.01, "D": self.rd, "FF": 0.0, "fltt_hz": 0.0}

    def _max_rate_step(self, g: dict) -> float:
        a = min(alpha(g["flte_hz"], self.dt), alpha(g["fltd_hz"], self.dt))
        hover = min(max(self.af.throttle_hover, 0.1), 0.5)
        return 2.0 * hover * 1.0 / ((1 - a) ** 3 * a * g["D"] / self.dt + g["P"])

    def twitch(self, kind: str) -> tuple[str, float, float, float, float]:
        """Fly one twitch; returns (outcome, rate_min, rate_max, angle_min, angle_max) in cd, cd/s."""
        g = self._test_gains()
        dt = self.dt
        target_max_rate = max(TARGET_MIN_RATE_CDS, self.step_scaler * TARGET_RATE_CDS)
        target_rate = min(max(_cd(self._max_rate_step(g)), TARGET_MIN_RATE_CDS), target_max_rate)
        target_angle = min(max(_cd(self._max_rate_step(g) / self.sp), TARGET_MIN_ANGLE_CD), TARGET_ANGLE_CD)
        self.target_rate, self.target_angle = target_rate, target_angle
        a_filt = alpha(2.0 * g["fltd_hz"], dt)
        law = ArduPilotLaw(g, dt)
        L = self.lifted
        F, G, Cy, Ca = L.F, L.G[:, 0], L.Cy, L.Ca[0]
        X = np.zeros(L.nx)
        rot = 0.0
        rmin = rmax = amin = amax = 0.0
        limit = False
        t_limit = STEP_TIMEOUT
        angle_rate = kind in ("SP_DOWN", "SP_UP")
        att_target = math.radians(target_angle / 100.0) if angle_rate else 0.0
        n = int(math.ceil(STEP_TIMEOUT / dt)) + 2
        for k in range(n):
            t = (k + 1) * dt  # the step started in the previous (levelling) iteration
            w = Cy[0] @ X
            ang = Ca @ X
            if angle_rate:
                rate_target = self.sp * (att_target - ang)
            else:
                rate_target = math.radians(target_rate / 100.0)
            u_raw = law.step(rate_target, w, limit=limit)
            u = min(max(u_raw, -1.0), 1.0)
            limit = u != u_raw
            # the measurement of this iteration (the gyro and attitude the AHRS gives at this sample)
            rot += a_filt * (_cd(w) - rot)
            lean = _cd(ang)
            X = F @ X + G * u
            if angle_rate:
                if lean > amax:
                    amax = amin = lean
                if lean < amin and amax > target_angle * (1 + 0.5 * AGGR) * 0.5:
                    amin = lean
                if rot > rmax:
                    rmax = rmin = rot
                if rot < rmin:
                    rmin = rot
                tgt = target_angle * (1 + 0.5 * AGGR)
                if amax < tgt * 0.75:
                    t_limit = min(t * 3.0, STEP_TIMEOUT)
                if amax > tgt or amax - amin > amax * AGGR or t >= t_limit:
                    return "update", rmin, rmax, amin, amax
            else:
                tgt = target_rate * (1 + 0.5 * AGGR) if kind == "RP_UP" else target_rate
                if rot > rmax:
                    rmax = rmin = rot
                if rot < rmin and rmax > tgt * 0.5:
                    rmin = rot
                if rmax < tgt * 0.75:
                    t_limit = min(t * 3.0, STEP_TIMEOUT)
                done = rmax > tgt or rmax - rmin > rmax * AGGR or t >= t_limit
                if lean >= ABORT_ANGLE_CD:  # twitching_abort_rate, called after the test: its step wins
                    if rot == rmin and self.step_scaler > 0.5:
                        self.step_scaler *= 0.9
                        return "restart", rmin, rmax, amin, amax
                    return "update", rmin, rmax, amin, amax
                if done:
                    return "update", rmin, rmax, amin, amax
        return "update", rmin, rmax, amin, amax

    # -- the gain updates -----------------------------------------------------------------------------------
    def rate_d_up(self, rmin: float, rmax: float) -> None:
        tr = self.target_rate
        if rmax > tr:
            self.rp -= self.rp * RP_STEP
            if self.rp < RP_MIN:
                self.rp = RP_MIN
                self.rd -= self.rd * RD_STEP
                if self.rd <= MIN_D:
                    self.rd = MIN_D
                    self.counter = SUCCESS_COUNT
        elif rmax < tr * (1 - D_UP_DOWN_MARGIN) and self.rp <= RP_MAX:
            self.rp += self.rp * RP_STEP
            if self.rp >= RP_MAX:
                self.rp = RP_MAX
        elif rmax - rmin > rmax * AGGR:
            self.ignore_next = True
            self.counter += 1
        elif not self.ignore_next:
            if self.counter > 0:
                self.counter -= 1
            self.rd += self.rd * RD_STEP * 2.0
            if self.rd >= RD_MAX:
                self.rd = RD_MAX
                self.counter = SUCCESS_COUNT
        else:
            self.ignore_next = False

    def rate_d_down(self, rmin: float, rmax: float) -> None:
        tr = self.target_rate
        if rmax > tr:
            self.rp -= self.rp * RP_STEP
            if self.rp < RP_MIN:
                self.rp = RP_MIN
                self.rd -= self.rd * RD_STEP
                if self.rd <= MIN_D:
                    self.rd = MIN_D
                    self.counter = SUCCESS_COUNT
        elif rmax < tr * (1 - D_UP_DOWN_MARGIN) and self.rp <= RP_MAX:
            self.rp += self.rp * RP_STEP
            if self.rp >= RP_MAX:
                self.rp = RP_MAX
        elif rmax - rmin < rmax * AGGR:
            if not self.ignore_next:
                self.counter += 1
            else:
                self.ignore_next = False
        else:
            self.ignore_next = True
            if self.counter > 0:
                self.counter -= 1
            self.rd -= self.rd * RD_STEP
            if self.rd <= MIN_D:
                self.rd = MIN_D
                self.counter = SUCCESS_COUNT

    def rate_p_up_d_down(self, rmin: float, rmax: float) -> None:
        tr = self.target_rate
        if rmax > tr * (1 + 0.5 * AGGR):
            self.ignore_next = True
            self.counter += 1
        elif tr * (1 - D_UP_DOWN_MARGIN) < rmax < tr and rmax - rmin > rmax * AGGR and self.rd > MIN_D:
            if self.counter > 0:
                self.counter -= 1
            self.rd -= self.rd * RD_STEP
            if self.rd <= MIN_D:
                self.rd = MIN_D
            self.rp -= self.rp * RP_STEP
            if self.rp <= RP_MIN:
                self.rp = RP_MIN
        elif not self.ignore_next:
            if self.counter > 0:
                self.counter -= 1
            self.rp += self.rp * RP_STEP
            if self.rp >= RP_MAX:
                self.rp = RP_MAX
                self.counter = SUCCESS_COUNT
        else:
            self.ignore_next = False

    def angle_p_down(self, amax: float) -> None:
        if amax < self.target_angle * (1 + 0.5 * AGGR):
            if not self.ignore_next:
                self.counter += 1
            else:
                self.ignore_next = False
        else:
            self.ignore_next = True
            if self.counter > 0:
                self.counter -= 1
            self.sp -= self.sp * SP_STEP
            if self.sp <= SP_MIN:
                self.sp = SP_MIN
                self.counter = SUCCESS_COUNT

    def angle_p_up(self, amax: float, rmin: float, rmax: float) -> None:
        ta = self.target_angle
        if amax > ta * (1 + 0.5 * AGGR) or (amax > ta and rmin < -rmax * AGGR):
            self.ignore_next = True
            self.counter += 1
        elif not self.ignore_next:
            if self.counter > 0:
                self.counter -= 1
            self.sp += self.sp * SP_STEP
            if self.sp >= SP_MAX:
                self.sp = SP_MAX
                self.counter = SUCCESS_COUNT
        else:
            self.ignore_next = False

    def post_tune(self, kind: str) -> None:
        if kind == "RD_DOWN":
            self.rd = max(MIN_D, self.rd * RD_BACKOFF)
            self.rp = max(RP_MIN, self.rp * RD_BACKOFF)
        elif kind == "RP_UP":
            self.rp = max(RP_MIN, self.rp * RP_BACKOFF)
        elif kind == "SP_UP":
            self.sp = max(SP_MIN, self.sp * SP_BACKOFF)


def ap_autotune(af: Airframe, start: dict | None = None, *, angle_p: float = ANGLE_P_DEFAULT) -> ApAutotuneResult:
    """Run AutoTune's roll sequence on ``af`` from ``start`` (the vehicle's current rate gains, default the
    firmware's) and return the gains it saves."""
    g0 = {**AP_DEFAULTS, **(start or {})}
    tu = _Tuner(af, g0, angle_p)
    counts: dict[str, int] = {}
    history = []
    for kind in SEQUENCE:
        tu.counter = 0
        tu.step_scaler = 1.0
        n = 0
        while tu.counter < SUCCESS_COUNT:
            if n >= MAX_TWITCHES:
                return ApAutotuneResult(False, None, tu.sp, f"{kind} did not finish in {MAX_TWITCHES} twitches",
                                        counts, history)
            outcome, rmin, rmax, amin, amax = tu.twitch(kind)
            n += 1
            history.append((kind, tu.rp, tu.rd, tu.sp, rmax / 100, rmin / 100, amax / 100))
            if outcome == "restart":
                continue
            if kind == "RD_UP":
                tu.rate_d_up(rmin, rmax)
            elif kind == "RD_DOWN":
                tu.rate_d_down(rmin, rmax)
            elif kind == "RP_UP":
                tu.rate_p_up_d_down(rmin, rmax)
            elif kind == "SP_DOWN":
                tu.angle_p_down(amax)
            else:
                tu.angle_p_up(amax, rmin, rmax)
        tu.post_tune(kind)
        counts[kind] = n
    gains = {**g0, "P": tu.rp, "I": tu.rp * PI_RATIO_FINAL, "D": tu.rd}
    return ApAutotuneResult(True, gains, tu.sp, "complete", counts, history)
