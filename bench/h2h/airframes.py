"""The airframes of the head-to-head: one roll axis each, from the rate law's output to the rate at the IMU.

Each airframe is the continuous plant from the law's output u (normalised torque, the allocator's -1..1) to the
angular rate at the IMU, in factored form::

    w_imu/u = b e^{-s tau} / ((tau_m s + 1)(s + a)) * F(s)

- ``b`` (rad/s^2 per unit torque): control effectiveness, the angular acceleration full torque gives (max arm
  thrust difference times arm over the roll inertia);
- ``tau_m`` (s): the motor and propeller speed-up lag (first order);
- ``a`` (1/s): aerodynamic rate damping (rotor flapping and inflow; 0 for a pure integrator);
- ``tau`` (s): computation plus ESC update and transport delay (a whole number of raw gyro samples here, so that
  the raw-rate simulation holds it exactly);
- ``F(s)`` = 1, or for the flexible frame a lightly damped structural mode seen by the gyro:
  ``(s^2/wz^2 + 2 zz s/wz + 1)/(s^2/wf^2 + 2 zf s/wf + 1)`` (a resonance at wf followed by an antiresonance at wz,
  what an IMU on a flexible arm/plate off the mode's node sees);

then the gyro low-pass upstream of the rate the law reads (second-order Butterworth: PX4's ``IMU_GYRO_CUTOFF``,
ArduPilot's ``INS_GYRO_FILTER``; they run on every raw gyro sample), the raw gyro rate and the loop rate.

The numbers are chosen to be typical of the class, not identified from one vehicle; each is justified in the
airframe's ``why``. The firmware-side filters are each firmware's defaults unless the airframe's ``why`` says
otherwise (PX4: ``IMU_GYRO_CUTOFF`` 40 Hz, ``IMU_DGYRO_CUTOFF`` 20 Hz,
src/modules/sensors/vehicle_angular_velocity/imu_gyro_parameters.yaml @ 21a553621f7a2ab923bf0c8881cfde0b9f6e3d2b;
ArduPilot: ``INS_GYRO_FILTER`` 20 Hz, the rate PID's FLTT 20 / FLTE 0 / FLTD 20 Hz,
libraries/AC_AttitudeControl/AC_AttitudeControl_Multi.h @ 05ae9d2fdcc0b259e590b3e2198d7c2972a65c2b).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import control as ct
import numpy as np

__all__ = ["Airframe", "AIRFRAMES", "get_airframe"]


@dataclass(frozen=True)
class Airframe:
    """One roll axis: the continuous plant, the sensor chain and the rates (see the module docstring)."""

    name: str
    why: str
    b: float  # control effectiveness, rad/s^2 per unit torque
    tau_m: float  # motor lag, s
    a: float  # aerodynamic damping, 1/s
    delay_s: float  # computation + transport delay, s
    loop_hz: float  # rate loop (IMU_GYRO_RATEMAX / SCHED_LOOP_RATE)
    raw_hz: float  # raw gyro sample rate (the FIFO rate the gyro filters run at)
    px4_gyro_hz: float = 40.0  # IMU_GYRO_CUTOFF
    ap_gyro_hz: float = 20.0  # INS_GYRO_FILTER
    flex: tuple[float, float, float, float] | None = None  # (wf, zf, wz, zz) rad/s
    throttle_hover: float = 0.35  # MOT_THST_HOVER (ArduPilot's twitch size uses it)
    horizon_s: float = 3.0  # first simulation horizon (extended while not settled)
    effectiveness: float = 1.0  # the 0.8x / 1.25x rows scale b
    #: the vehicle's gains before the autotunes, as a fraction of the firmware defaults (PX4: MC_ROLLRATE_K; ArduPilot:
    #: P, I, D): 1 unless the defaults are not flyable on the airframe
    start_scale: float = 1.0

    @property
    def dt(self) -> float:
        return 1.0 / self.loop_hz

    def gyro_hz(self, firmware: str) -> float:
        return self.px4_gyro_hz if firmware == "px4" else self.ap_gyro_hz

    def scaled(self, k: float) -> Airframe:
        """The same airframe with its control effectiveness times ``k`` (the robustness rows)."""
        return replace(self, effectiveness=self.effectiveness * k)

    # -- the continuous plant ------------------------------------------------------------------------------
    def body_ss(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A, B, C)`` of the continuous plant from the applied torque (after the delay) to
        ``[w_imu, angle]``: motor lag, rigid body with damping, the structural mode, the roll angle (the rigid
        rate integrated). States: motor torque, rigid rate, [mode states], angle."""
        bb = self.b * self.effectiveness
        # motor: m' = (u - m)/tau_m ; rigid rate: w' = bb m - a w ; angle: th' = w
        n_f = 2 if self.flex else 0
        n = 3 + n_f
        A = np.zeros((n, n))
        B = np.zeros((n, 1))
        C = np.zeros((2, n))
        A[0, 0] = -1.0 / self.tau_m
        B[0, 0] = 1.0 / self.tau_m
        A[1, 0] = bb
        A[1, 1] = -self.a
        A[n - 1, 1] = 1.0  # angle
        C[1, n - 1] = 1.0
        if self.flex:
            wf, zf, wz, zz = self.flex
            # F(s) = (s^2/wz^2 + 2 zz s/wz + 1)/(s^2/wf^2 + 2 zf s/wf + 1) driven by the rigid rate:
            # F = r + (c1 s + c0)/(s^2 + 2 zf wf s + wf^2), r = wf^2/wz^2 (controllable canonical form)
            r = wf**2 / wz**2
            c1 = 2 * zz * wf**2 / wz - r * 2 * zf * wf
            c0 = wf**2 - r * wf**2
            A[2, 3] = 1.0
            A[3, 2] = -wf**2
            A[3, 3] = -2 * zf * wf
            A[3, 1] = 1.0  # the mode is driven by the rigid rate
            C[0, 1] = r
            C[0, 2] = c0
            C[0, 3] = c1
        else:
            C[0, 1] = 1.0
        return A, B, C

    def rate_tf(self) -> ct.TransferFunction:
        """``w_imu/u`` without the delay and the gyro filter (factored products of low-order factors)."""
        bb = self.b * self.effectiveness
        g = ct.tf([bb], [self.tau_m, 1.0]) * ct.tf([1.0], [1.0, self.a])
        if self.flex:
            wf, zf, wz, zz = self.flex
            g = g * ct.tf([1 / wz**2, 2 * zz / wz, 1.0], [1 / wf**2, 2 * zf / wf, 1.0])
        return g

    def plant_tf(self, firmware: str) -> ct.TransferFunction:
        """What the law sees, for the tuner: ``rate_tf`` times the firmware's gyro Butterworth low-pass (the delay
        is given separately, ``delay_s``)."""
        wc = 2 * math.pi * self.gyro_hz(firmware)
        return self.rate_tf() * ct.tf([wc**2], [1.0, math.sqrt(2) * wc, wc**2])


AIRFRAMES: dict[str, Airframe] = {a.name: a for a in (
    Airframe(
        "quad400",
        "a 450 mm, 1.6 kg quadrotor (10-inch props) on a 400 Hz loop, 8 kHz gyro FIFO (ICM-42688P): about 140 "
        "rad/s^2 of roll acceleration at full differential torque, 30 ms motor lag, rotor damping 2.5 /s, 4 ms from "
        "the gyro sample to the ESC (computation, DShot/PWM update, ESC); firmware-default gyro filters",
        b=140.0, tau_m=0.030, a=2.5, delay_s=0.004, loop_hz=400.0, raw_hz=8000.0, throttle_hover=0.35,
        horizon_s=3.0),
    Airframe(
        "racer",
        "a 5-inch, 600 g racer on a 1 kHz loop (8 kHz gyro): ~1000 rad/s^2 at full torque (thrust/weight 8, "
        "short arms, low inertia), 15 ms motor lag, damping 4 /s, 1.5 ms to the ESC (DShot); racers run wider "
        "gyro low-passes (80 Hz for both firmwares here; the firmware defaults would cost phase at their "
        "crossover). The firmware default gains are not flyable on it (PM about 4 deg for PX4's, 0.4 deg for "
        "ArduPilot's, measured here): both autotunes start from 0.3 x the defaults (PX4: MC_ROLLRATE_K 0.3), what "
        "a pilot would set before a first hover",
        b=1000.0, tau_m=0.015, a=4.0, delay_s=0.0015, loop_hz=1000.0, raw_hz=8000.0, px4_gyro_hz=80.0,
        ap_gyro_hz=80.0, throttle_hover=0.2, horizon_s=2.0, start_scale=0.3),
    Airframe(
        "hexa250",
        "a large, slow 20 kg hexacopter (30-inch props) on a 250 Hz loop (2 kHz gyro): 18 rad/s^2 at full "
        "torque, 100 ms motor lag (large props), damping 0.6 /s, 8 ms to the ESC (CAN ESCs); gyro low-passes "
        "lowered for the frame's vibration (PX4 30 Hz, ArduPilot 20 Hz)",
        b=18.0, tau_m=0.100, a=0.6, delay_s=0.008, loop_hz=250.0, raw_hz=2000.0, px4_gyro_hz=30.0,
        ap_gyro_hz=20.0, throttle_hover=0.5, horizon_s=8.0),
    Airframe(
        "integrator",
        "no aerodynamic damping: a pure integrator plus motor lag (a prop-guarded 1 kg indoor quadrotor whose "
        "rotor damping is negligible against its inertia), 400 Hz loop, 4 kHz gyro: 90 rad/s^2 at full torque, "
        "40 ms motor lag, 4 ms delay; firmware-default gyro filters",
        b=90.0, tau_m=0.040, a=0.0, delay_s=0.004, loop_hz=400.0, raw_hz=4000.0, throttle_hover=0.4,
        horizon_s=3.0),
    Airframe(
        "flexible",
        "a heavy-lift 12 kg X8 with long carbon arms on a 400 Hz loop (8 kHz gyro): 45 rad/s^2 at full torque, "
        "60 ms motor lag, damping 1.5 /s, 5 ms delay, and its first arm bending/torsion mode at 40 rad/s (6.4 Hz, "
        "damping ratio 0.03) seen by the gyro, antiresonance at 46 rad/s; gyro low-passes PX4 30 Hz, "
        "ArduPilot 20 Hz",
        b=45.0, tau_m=0.060, a=1.5, delay_s=0.005, loop_hz=400.0, raw_hz=8000.0, px4_gyro_hz=30.0,
        ap_gyro_hz=20.0, flex=(40.0, 0.03, 46.0, 0.03), throttle_hover=0.45, horizon_s=4.0),
)}


def get_airframe(name: str) -> Airframe:
    try:
        return AIRFRAMES[name]
    except KeyError:
        raise SystemExit(f"unknown airframe {name!r}: give one of {', '.join(AIRFRAMES)}") from None
