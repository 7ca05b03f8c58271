"""PX4's multicopter rate law behind the firmware seam (:class:`~tuner.firmware.base.Firmware`).

The law's arithmetic is :func:`tuner.firmware.laws.px4_coeffs` / :func:`~tuner.firmware.laws.px4_ref_coeffs`
(``src/lib/rate_control/rate_control.cpp``, ``RateControl::update``; the module's docstring there names the
sources); the names and documented ranges are :data:`tuner.firmware.names.PX4` and ``RANGES["px4"]``
(``mc_rate_control_params.c`` and the files its docstring names). Here: the loop rate from a log or the parameters
(``VehicleAngularVelocity``), the integrator's behaviour in saturation (:class:`Simulator`), the QGroundControl
``.params`` lines, and what to fly for an identification.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from . import laws
from . import names as _names
from .base import Firmware

__all__ = ["FIRMWARE", "Simulator", "px4_flag_period", "PX4_STATUS_INTERVAL_S"]

_FADE_RAD_S = math.radians(400.0)  # PX4's integrator fade: the error at which the integration stops
_FILES = "PX4 parameters (a QGroundControl .params file, or a ULog .ulg)"


#: ControlAllocator::Run publishes control_allocator_status "at limited rate": ``if (now - _last_status_pub >= 5_ms)``
#: (src/modules/control_allocator/ControlAllocator.cpp, PX4-Autopilot main 2023-2025)
PX4_STATUS_INTERVAL_S = 5e-3


def px4_flag_period(dt: float) -> int:
    """Every how many rate-loop samples PX4's saturation flags are new: ``ceil(5 ms/dt)``.

    ``ControlAllocator::Run`` runs on each torque setpoint, after the rate loop's sample, and publishes
    ``control_allocator_status`` only when 5 ms have passed since its last publication (:data:`PX4_STATUS_INTERVAL_S`);
    ``MulticopterRateControl::Run`` sets the flags (``unallocated_torque`` > 0: positive, < 0: negative) only when a
    new status arrived (``_control_allocator_status_sub.update``) and keeps them otherwise. So at loop sample ``k``
    the law uses the flags of the allocator's run at the last publication before ``k``: 1 to ``ceil(5 ms/dt)``
    samples late (1-2 at 400 Hz and at 250 Hz, 1-5 at 1 kHz).

    Examples
    --------
    >>> from tuner.firmware.px4 import px4_flag_period
    >>> px4_flag_period(1 / 400), px4_flag_period(1 / 250), px4_flag_period(1 / 1000), px4_flag_period(0.01)
    (2, 2, 5, 1)
    """
    return max(1, math.ceil(PX4_STATUS_INTERVAL_S / dt - 1e-9))


class Simulator:
    """PX4's ``RateControl`` one sample per call, ``u = law(r, y)``: the integrator's update after the output,
    clamped to ``+-int_lim``, no growth in the direction the output saturates (the allocator's saturation flags, as
    they arrive: :func:`px4_flag_period`), and the fade ``max(0, 1 - (e/400 deg/s)^2)``
    (``rate_control.cpp``, ``updateIntegral``); the D path as the firmware computes it
    (:func:`tuner.firmware.laws.dgyro_filter`); the yaw torque low-pass ``MC_YAW_TQ_CUTOFF``
    (``MulticopterRateControl::Run``) before the allocator clamps."""

    #: the saturation flags as the allocator delivers them (:func:`px4_flag_period`); False: this sample's own, what
    #: this module simulated before issue 40 (``bench/dpath.py`` measures the difference)
    flags_late = True

    def __init__(self, g: dict[str, float], dt: float, lo: float, hi: float) -> None:
        self.k, self.p, self.i, self.d, self.ff = g["K"], g["P"], g["I"], g["D"], g["FF"]
        self.lim, self.dt, self.lo, self.hi = g["int_lim"], dt, lo, hi
        fq = g.get("tq_hz", 0.0)
        from .laws import dgyro_filter

        nd, qd = dgyro_filter(g, dt)  # the D path at the loop rate (the raw-rate filter decimated)
        self.dn = [float(c) / float(qd[0]) for c in nd]
        self.dq = [float(c) / float(qd[0]) for c in qd]
        self.ds = [0.0] * (len(self.dq) - 1)  # its state (transposed direct form II)
        self.aq = 1.0 if fq <= 0 else dt / (dt + 1.0 / (2.0 * math.pi * fq))  # the yaw torque low-pass
        self.xi = self.y_prev = self.q = 0.0
        self.every, self.k_sample = px4_flag_period(dt), 0
        self.sat_pos = self.sat_neg = False  # the flags as the law holds them (the last status received)

    def _dpath(self, x: float) -> float:
        b, a, s = self.dn, self.dq, self.ds
        out = b[0] * x + s[0]
        for i in range(len(s)):
            s[i] = b[i + 1] * x - a[i + 1] * out + (s[i + 1] if i + 1 < len(s) else 0.0)
        return out

    def __call__(self, r: float, y: float) -> tuple[float, bool]:
        e = r - y
        yd = self._dpath((y - self.y_prev) / self.dt)
        self.y_prev = y
        # the law's torque, then MulticopterRateControl's yaw low-pass (MC_YAW_TQ_CUTOFF) before the allocator clamps
        self.q += self.aq * (self.k * (self.p * e - self.d * yd) + self.xi + self.ff * r - self.q)
        v = self.q
        u = min(max(v, self.lo), self.hi)
        if not self.flags_late:
            self.sat_pos, self.sat_neg = v > self.hi, v < self.lo
        ei = e  # no growth into saturation, by the flags the law holds (the allocator's earlier run)
        if self.sat_pos:
            ei = min(ei, 0.0)
        if self.sat_neg:
            ei = max(ei, 0.0)
        fade = max(0.0, 1.0 - (ei / _FADE_RAD_S) ** 2)
        self.xi = min(max(self.xi + fade * self.k * self.i * ei * self.dt, -self.lim), self.lim)
        if self.flags_late and self.k_sample % self.every == 0:  # published now: the law reads it next sample
            self.sat_pos, self.sat_neg = v > self.hi, v < self.lo
        self.k_sample += 1
        return u, u != v


def loop_rate(raw: Mapping[str, float], names: Mapping[str, str], source: str, log: Mapping[str, Any] | None,
              notes: list[str], fld: str) -> tuple[float | None, str] | None:
    """PX4's loop rate (None: not told; the caller assumes the default). ``MulticopterRateControl::Run`` runs on
    every ``vehicle_angular_velocity``, which the gyro drives and ``VehicleAngularVelocity`` publishes from
    ``IMU_GYRO_RATEMAX`` ("maximum publication rate", ``imu_gyro_parameters.c``): every ``samples =
    roundf(gyro_rate / RATEMAX)`` (at least 1) gyro publications (``VehicleAngularVelocity::UpdateSampleRate``,
    ``src/modules/sensors/vehicle_angular_velocity/``, PX4-Autopilot main: ``set_required_updates(samples)`` and a
    minimum interval of ``1/RATEMAX - 1/(2 gyro_rate)``), so the loop runs at ``gyro_rate / samples``: a 2 kHz gyro
    under a cap of 800 at 667 Hz, a 1 kHz one at 1 kHz (above the "cap"). A log's
    ``vehicle_imu_status.gyro_rate_hz`` gives the gyro's rate (taken as its publication rate: a FIFO driver that
    publishes in batches runs the loop slower, said). The parameter alone is a stated fallback."""
    name = names["loop_hz"]
    gyro = (log or {}).get("gyro_rate_hz")
    cap = raw.get(name)
    if gyro:
        where = f"vehicle_imu_status.gyro_rate_hz in {source}"
        if cap is None or cap <= 0:
            return float(round(gyro)), f"the gyro's rate {gyro:.1f} Hz ({where}; no {name} cap in it)"
        samples = max(1, math.floor(gyro / cap + 0.5))  # roundf: half away from zero (both positive here)
        if samples == 1:
            return float(round(gyro)), (f"the gyro's rate {gyro:.1f} Hz ({where}), every sample published under "
                                        f"the cap {name} {cap:g}")
        return float(gyro / samples), (f"the gyro's rate {gyro:.1f} Hz ({where}) over {samples}: "
                                       f"VehicleAngularVelocity publishes every {samples} samples under {name} "
                                       f"{cap:g} (a FIFO gyro that publishes in batches runs the loop slower)")
    logged = (log or {}).get("logged_gyro_hz")
    if cap is None and logged:
        notes.append(f"{name} not in {source} (older firmware): the loop rate is taken from the log's timing")
        return float(round(logged)), (f"the timing of sensor_combined in {source}: the gyro's samples as logged, "
                                      f"{logged:.1f} Hz (a lower bound if the logger thinned the topic; the "
                                      "log has no vehicle_imu_status)")
    if cap is not None:
        why = ("the log has no vehicle_imu_status" if log is not None else
               "a parameter file; a ULog's vehicle_imu_status would give the gyro's rate")
        return float(cap), f"{name} {cap:g} Hz in {source}: a cap on the gyro's rate, taken as the loop's ({why})"
    return None


#: the first PX4 release whose D path is the first-order AlphaFilter (see :func:`_px4_dpath`)
PX4_ALPHA_DGYRO_RELEASE = (1, 13)


def _px4_dpath(log: Mapping[str, Any] | None, loop_hz: float | None, dgyro_hz: float | None, source: str,
               notes: list[str]) -> dict[str, float]:
    """PX4's D path for :func:`tuner.firmware.laws.dgyro_filter`: ``dgyro_order`` and ``raw_hz``, with a note for
    what was assumed. ``dgyro_hz`` is the vehicle's ``IMU_DGYRO_CUTOFF``, None where its parameters lack it.

    * Firmware without ``IMU_DGYRO_CUTOFF`` (before v1.11, which added ``vehicle_angular_acceleration``, PX4 PR
      #14034) computes the D term in the rate controller at the loop rate: the loop-rate law (first order, the
      loop rate), said; that generation's own D filter (``MC_DTERM_CUTOFF``) is not modelled.

    * The generation from the log's firmware version (``ver_sw_release``): releases before v1.13 filter the
      difference with a ``LowPassFilter2p`` (second order: v1.12 moved the D path onto the raw FIFO samples, PX4
      PR #15820, with ``IMU_DGYRO_CUTOFF`` 30 Hz by default, PR #16188); later ones with an ``AlphaFilter`` (first
      order; in main by October 2022, PR #20521 discussing "the delay from the AlphaFilter"). The boundary is taken as
      v1.13 (not checked against the v1.13.0 tag). Without a version (a parameter file, an old log): first order,
      the current firmware's, said.
    * The raw gyro rate: the log's ``vehicle_imu_status.gyro_raw_rate_hz`` (the FIFO's), else its ``gyro_rate_hz``
      (the gyro's publication rate: a FIFO driver's raw rate is higher, said), else the timing of
      ``sensor_combined``; without a log, the loop rate (0: the D path differenced at the loop rate, conservative
      for the first-order filter, not for the second-order one), said.
    """
    log = log or {}
    rel = log.get("ver_sw_release")
    if dgyro_hz is None:
        notes.append(f"IMU_DGYRO_CUTOFF is not in {source} (PX4 before v1.11): the D term is taken as differenced and "
                     "first-order filtered at the loop rate (that firmware computes it in the rate controller; its "
                     "MC_DTERM_CUTOFF filter is not modelled)")
        return {"dgyro_order": 1.0, "raw_hz": 0.0}
    if rel:
        major, minor, patch = (rel >> 24) & 0xFF, (rel >> 16) & 0xFF, (rel >> 8) & 0xFF
        order = 2.0 if (major, minor) < PX4_ALPHA_DGYRO_RELEASE else 1.0
        if dgyro_hz > 0:
            notes.append(f"PX4 v{major}.{minor}.{patch} (ver_sw_release in {source}): the D path's filter is "
                         + ("second order (LowPassFilter2p, the releases before v1.13)" if order == 2 else
                            "first order (AlphaFilter, v1.13 and later)"))
    else:
        order = 1.0
        if dgyro_hz > 0:
            notes.append(f"the firmware version is not in {source}: the D path's filter assumed first order "
                         "(AlphaFilter, PX4 v1.13 and later); releases before v1.13 filter it with a second-order "
                         "LowPassFilter2p (give a ULog of the vehicle, whose ver_sw_release says which)")
    raw, what = None, ""
    for key, words in (("gyro_raw_rate_hz", "vehicle_imu_status.gyro_raw_rate_hz"),
                       ("gyro_rate_hz", "vehicle_imu_status.gyro_rate_hz (the gyro's publication rate; a FIFO "
                                        "gyro's raw samples may be faster)"),
                       ("logged_gyro_hz", "the timing of sensor_combined (a lower bound)")):
        v = log.get(key)
        if v and v > 0:
            raw, what = float(v), words
            break
    if raw is None:
        notes.append(f"the raw gyro rate is not in {source}: PX4 differences and filters the D path on every raw "
                     "gyro sample (1-8 kHz); assumed at the loop rate (conservative for the first-order filter, not "
                     "for the second-order one; a ULog of the vehicle gives the rate)")
        return {"dgyro_order": order, "raw_hz": 0.0}
    if loop_hz and raw <= loop_hz * (1 + 1e-6):
        return {"dgyro_order": order, "raw_hz": 0.0}  # the D path runs at the loop rate: the law as it was
    notes.append(f"the D path is differenced and filtered at the raw gyro rate {raw:.0f} Hz ({what} in {source})")
    return {"dgyro_order": order, "raw_hz": float(round(raw))}


def _log_fixed(log: Mapping[str, Any] | None, loop_hz: float | None, raw: Mapping[str, float],
               names: Mapping[str, str], fixed: Mapping[str, float], source: str, notes: list[str]) -> dict[str, float]:
    """The D path's generation and raw rate (:func:`_px4_dpath`), from the log and the vehicle's parameters."""
    return _px4_dpath(log, loop_hz, fixed["dgyro_hz"] if names["dgyro_hz"] in raw else None, source, notes)


def _loop_fix(loop_hz: float | None, loop_source: str, names: Mapping[str, str], notes: list[str],
              rng: tuple[float, float]) -> tuple[float | None, str]:
    """``IMU_GYRO_RATEMAX = 0``: PX4 runs the loop at the gyro's own rate, which a parameter file does not say."""
    if loop_hz is not None and loop_hz == 0:
        notes.append(f"{names['loop_hz']} = 0: PX4 then runs the rate loop at the gyro's own rate, which the "
                     "parameters do not say: give dt (the rate loop's sample time)")
        return None, ""
    return loop_hz, loop_source


def _vehicle_notes(axis: str, fixed: Mapping[str, float]) -> list[str]:
    if axis == "yaw" and fixed["tq_hz"] > 0:
        return [f"PX4 low-passes the yaw torque at MC_YAW_TQ_CUTOFF = {fixed['tq_hz']:g} Hz after the rate law "
                "and before it publishes vehicle_torque_setpoint: the filter is part of the designed loop (a "
                "plant identified from vehicle_torque_setpoint starts after it)"]
    return []


def _filters_header(values: Mapping[str, float], gyro_words: str) -> str:
    tq = values.get("tq_hz", 0.0)
    d_order, raw = values.get("dgyro_order", 1.0), values.get("raw_hz", 0.0)
    return (f"filters assumed: D-term low-pass IMU_DGYRO_CUTOFF {values['dgyro_hz']:g} Hz (not written: set it "
            "to this value), " + ("second order (LowPassFilter2p, PX4 before v1.13)" if d_order == 2 else
                                  "first order (AlphaFilter, PX4 v1.13 and later)")
            + (f", on every raw gyro sample at {raw:g} Hz" if raw > 0 else ", differenced at the loop rate")
            + (f", yaw torque low-pass MC_YAW_TQ_CUTOFF {tq:g} Hz in the designed loop (not "
               "written: set it to this value)" if tq > 0 else "")
            + "; " + gyro_words)


def _log_signals(axis: str) -> dict[str, str]:
    i = {"roll": 0, "pitch": 1, "yaw": 2}[axis]
    return {"input": f"vehicle_torque_setpoint.xyz[{i}]", "output": f"vehicle_angular_velocity.xyz[{i}]",
            "reference": f"vehicle_rates_setpoint.{axis}"}


def what_to_fly(axis: str | None) -> str:
    """What to fly and log on PX4 (``src/modules/logger/params.c`` SDLOG_PROFILE bit 3 "system identification")."""
    from ..identify.flight import SWEEP

    ax = axis or "roll"
    s = _log_signals(ax)
    return ("PX4: arm and take off, then fly Acro (rate setpoints from the sticks, no attitude loop) with " + SWEEP
            + ", or let the multicopter autotune (MC_AT_EN 1, started from the ground station) inject its "
              "excitation; log with SDLOG_PROFILE bit 3 (system identification, +8) set, so "
              "vehicle_torque_setpoint, vehicle_angular_velocity and "
              f"vehicle_rates_setpoint are logged at the loop rate; identify {s['input']} -> "
              f"{s['output']} with {s['reference']} as the reference")


FIRMWARE = Firmware(
    name="px4", title="PX4", structure="px4_rate", coeffs=laws.px4_coeffs, ref_coeffs=laws.px4_ref_coeffs,
    fixed=laws.PX4_FIXED, axis_defaults={"yaw": laws._AXIS_DEFAULTS[("px4", "yaw")]},
    names=lambda ax: _names.PX4[ax], ranges=lambda ax: _names.RANGES["px4"][ax],
    scale=lambda ax: _names.SCALE["px4"][ax], integer=_names.INTEGER["px4"], clamped=_names.CLAMPED["px4"],
    range_source=_names.SOURCE["px4"],
    export_format="px4", suffix="params", files=_FILES, export_order=("P", "I", "D", "FF", "K", "int_lim"),
    write_line=lambda name, value, ids: f"{ids[0]}\t{ids[1]}\t{name}\t{value}\t9", ids_in_file=True,
    filters_header=_filters_header, gyro_param="IMU_GYRO_CUTOFF",
    detect_prefixes=("MC_ROLLRATE_", "MC_PITCHRATE_", "MC_YAWRATE_", "IMU_GYRO_", "SYS_AUTOSTART"),
    default_loop_hz=400.0,  # IMU_GYRO_RATEMAX's default (firmware.md)
    loop_rate=loop_rate, loop_fix=_loop_fix, vehicle_notes=_vehicle_notes, log_fixed=_log_fixed,
    constants=("dgyro_order", "raw_hz"),
    formats=("qgc", "ulog"), refused_formats={"parm": "a .parm file is ArduPilot's"},
    simulator=Simulator,
    simulator_words="PX4's rate law (integrator limit int_lim, no growth into saturation, the 400 deg/s fade)",
    what_to_fly=what_to_fly, log_signals=_log_signals, gain_scale="K", integrator_limit="int_lim",
)
