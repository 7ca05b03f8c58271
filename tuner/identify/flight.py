"""What a log says was flown: the armed, airborne stretches, the mode, an injected excitation, and what to fly.

A log is taken at its word only where it says the vehicle flew: armed and off the ground. The firmware's own
records of that (transcribed from their sources; names and values as published):

* **PX4** (``msg/VehicleStatus.msg``, ``msg/ActuatorArmed.msg``, ``msg/VehicleLandDetected.msg``,
  ``msg/VehicleControlMode.msg``, ``msg/AutotuneAttitudeControlStatus.msg``, PX4-Autopilot main as of 2024):
  ``actuator_armed.armed`` (or ``vehicle_status.arming_state == 2``, ARMED in every generation of the message),
  ``vehicle_land_detected.landed == 0``; a rate (acro) mode where ``vehicle_control_mode`` has the rate loop on and
  the attitude loop off (or ``vehicle_status.nav_state == 10``, ACRO); the autotune's excitation while
  ``autotune_attitude_control_status.state`` is not idle (0);
* **ArduPilot** (``libraries/AP_Logger/LogStructure.h``, ``ArduCopter/mode.h``, ArduPilot master as of 2024):
  ``ARM.ArmState``, or the events ``EV.Id`` 10 ARMED / 11 DISARMED; 18 LAND_COMPLETE / 28 NOT_LANDED; the
  ``MODE.ModeNum`` (Copter: 1 ACRO, 25 SYSTEMID: SystemID mode injects the chirp logged in ``SIDD``).

Times here are seconds on the log's clock (its timestamps, µs x 1e-6).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Flight", "intersect", "steps_to_intervals", "union", "px4_flight", "what_to_fly", "setpoint_reference",
           "PX4_NAV_STATES", "COPTER_MODES"]

Intervals = list[tuple[float, float]]

#: PX4's vehicle_status.nav_state values (msg/VehicleStatus.msg), the ones a multicopter flies
PX4_NAV_STATES = {0: "MANUAL (stabilized)", 1: "ALTCTL", 2: "POSCTL", 3: "AUTO_MISSION", 4: "AUTO_LOITER",
                  5: "AUTO_RTL", 10: "ACRO", 14: "OFFBOARD", 15: "STAB", 17: "AUTO_TAKEOFF", 18: "AUTO_LAND",
                  19: "AUTO_FOLLOW_TARGET", 20: "AUTO_PRECLAND", 21: "ORBIT", 22: "AUTO_VTOL_TAKEOFF"}
PX4_ACRO = 10
#: ArduCopter's mode numbers (ArduCopter/mode.h, enum class Number)
COPTER_MODES = {0: "STABILIZE", 1: "ACRO", 2: "ALT_HOLD", 3: "AUTO", 4: "GUIDED", 5: "LOITER", 6: "RTL",
                7: "CIRCLE", 9: "LAND", 11: "DRIFT", 13: "SPORT", 14: "FLIP", 15: "AUTOTUNE", 16: "POSHOLD",
                17: "BRAKE", 18: "THROW", 20: "GUIDED_NOGPS", 21: "SMART_RTL", 22: "FLOWHOLD", 23: "FOLLOW",
                24: "ZIGZAG", 25: "SYSTEMID", 26: "AUTOROTATE", 27: "AUTO_RTL", 28: "TURTLE"}
COPTER_ACRO, COPTER_SYSTEMID = 1, 25
#: signals that are a rate setpoint: exogenous only in a rate mode or with an injected excitation
_RATE_SETPOINTS = ("vehicle_rates_setpoint.", "RATE.RDes", "RATE.PDes", "RATE.YDes", "PIDR.Tar", "PIDP.Tar",
                   "PIDY.Tar")


@dataclass(frozen=True)
class Flight:
    """What the log says was flown. ``flown``: the armed, airborne stretches (None: the log records no arming
    state: every stretch is taken, and ``notes`` says so); ``exogenous``: the stretches where a rate setpoint is an
    exogenous reference (a rate mode, an injected excitation), with ``exogenous_why`` naming which; ``modes``: the
    modes flown while armed; ``seen``: one sentence of what was seen, for a refusal."""

    firmware: str
    flown: Intervals | None
    exogenous: Intervals = field(default_factory=list)
    exogenous_why: str = ""
    modes: list[str] = field(default_factory=list)
    seen: str = ""
    notes: list[str] = field(default_factory=list)


def steps_to_intervals(t: np.ndarray, on: np.ndarray, t_end: float) -> Intervals:
    """The intervals where a sampled state is on, each sample holding until the next (the last until ``t_end``).

    Examples
    --------
    >>> import numpy as np
    >>> steps_to_intervals(np.array([0.0, 1.0, 2.0, 3.0]), np.array([0, 1, 1, 0]), 5.0)
    [(1.0, 3.0)]
    """
    t = np.asarray(t, dtype=float)
    on = np.asarray(on, dtype=bool)
    out: Intervals = []
    start = None
    for ti, oi in zip(t, on):
        if oi and start is None:
            start = float(ti)
        elif not oi and start is not None:
            out.append((start, float(ti)))
            start = None
    if start is not None and t_end > start:
        out.append((start, float(t_end)))
    return out


def intersect(a: Sequence[tuple[float, float]], b: Sequence[tuple[float, float]]) -> Intervals:
    """The intersection of two sorted lists of disjoint intervals.

    Examples
    --------
    >>> intersect([(0, 2), (3, 5)], [(1, 4)])
    [(1, 2), (3, 4)]
    """
    out, i, j = [], 0, 0
    while i < len(a) and j < len(b):
        lo, hi = max(a[i][0], b[j][0]), min(a[i][1], b[j][1])
        if hi > lo:
            out.append((lo, hi))
        if a[i][1] < b[j][1]:
            i += 1
        else:
            j += 1
    return out


def union(*ivs: Sequence[tuple[float, float]]) -> Intervals:
    """The union of lists of intervals, as one sorted list of disjoint intervals (what :func:`intersect` takes):
    overlapping or touching intervals merged.

    Examples
    --------
    >>> union([(1, 6)], [(1, 5), (7, 8)], [(8, 9)])
    [(1, 6), (7, 9)]
    """
    out: Intervals = []
    for a, b in sorted(iv for x in ivs for iv in x):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def total(iv: Sequence[tuple[float, float]]) -> float:
    """The summed length of intervals."""
    return float(sum(b - a for a, b in iv))


def _topic(ul: Any, name: str) -> dict[str, np.ndarray] | None:
    d = next((d for d in ul.data_list if d.name == name and d.multi_id == 0), None)
    if d is None:
        return None
    t = np.asarray(d.data["timestamp"], dtype=float)
    keep = t > 0
    return {k: np.asarray(v)[keep] for k, v in d.data.items()} | {"_t": t[keep] * 1e-6}


#: the topics px4_flight reads (read_ulog adds them to the topics it parses)
PX4_STATE_TOPICS = ("vehicle_status", "actuator_armed", "vehicle_land_detected", "vehicle_control_mode",
                    "autotune_attitude_control_status", "actuator_outputs", "actuator_controls_0",
                    "vehicle_thrust_setpoint")


def _range(x: np.ndarray) -> str:
    lo, hi = float(np.min(x)), float(np.max(x))
    return f"{lo:.4g}" if lo == hi else f"{lo:.4g}-{hi:.4g}"


def px4_flight(ul: Any, t_end: float) -> Flight:
    """The armed, airborne stretches of a PX4 log (pyulog's ``ULog`` holding :data:`PX4_STATE_TOPICS`)."""
    vs, aa, ld, cm = (_topic(ul, n) for n in ("vehicle_status", "actuator_armed", "vehicle_land_detected",
                                              "vehicle_control_mode"))
    at = _topic(ul, "autotune_attitude_control_status")
    seen, notes = [], []
    if aa is not None and "armed" in aa:
        armed = steps_to_intervals(aa["_t"], aa["armed"] != 0, t_end)
        seen.append(f"actuator_armed.armed {_range(aa['armed'])}")
    elif vs is not None and "arming_state" in vs:
        armed = steps_to_intervals(vs["_t"], vs["arming_state"] == 2, t_end)
    else:
        armed = None
    if vs is not None and "arming_state" in vs:
        seen.append(f"arming state {_range(vs['arming_state'])} (2 is armed)")
    if armed is None:
        return Flight("px4", None, notes=["the log records no arming state (no vehicle_status or actuator_armed): "
                                          "every stretch is taken as flown"])
    if ld is not None and "landed" in ld:
        air = steps_to_intervals(ld["_t"], ld["landed"] == 0, t_end)
        flown = intersect(armed, air)
        seen.append(f"landed {_range(ld['landed'])}")
    else:
        flown = armed
        notes.append("the log has no vehicle_land_detected: the armed stretches are taken as airborne")
    modes: list[str] = []
    if vs is not None and "nav_state" in vs:
        ns = vs["nav_state"].astype(int)
        for v in sorted(set(ns[[any(a <= t < b for a, b in (flown or armed)) for t in vs["_t"]]].tolist())
                        or set(ns.tolist())):
            modes.append(f"{PX4_NAV_STATES.get(v, 'nav_state ' + str(v))}")
        seen.append("mode " + ", ".join(f"{PX4_NAV_STATES.get(v, '?')} (nav_state {v})" for v in sorted(set(ns))))
    for name, fld, what in (("actuator_outputs", "output[0]", "PWM"), ("actuator_controls_0", "control[3]", "thrust"),
                            ("vehicle_thrust_setpoint", "xyz[2]", "thrust")):
        d = _topic(ul, name)
        if d is not None and fld in d and d[fld].size:
            seen.append(f"{what} {_range(d[fld])} ({name}.{fld})")
    if cm is not None and "flag_control_rates_enabled" in cm and "flag_control_attitude_enabled" in cm:
        rate = steps_to_intervals(cm["_t"], (cm["flag_control_rates_enabled"] != 0)
                                  & (cm["flag_control_attitude_enabled"] == 0), t_end)
    elif vs is not None and "nav_state" in vs:
        rate = steps_to_intervals(vs["_t"], vs["nav_state"] == PX4_ACRO, t_end)
    else:
        rate = []
    exo, why = rate, "a rate (acro) mode" if rate else ""
    if at is not None and "state" in at:
        tune = steps_to_intervals(at["_t"], at["state"] != 0, t_end)
        if tune:
            exo = union(exo, tune)
            why = (why + " and " if why else "") + "PX4's autotune excitation"
    return Flight("px4", flown, exogenous=exo, exogenous_why=why, modes=modes, seen="; ".join(seen), notes=notes)


def setpoint_reference(name: str | None) -> bool:
    """Whether a reference signal is a rate setpoint (exogenous only in a rate mode or with an excitation)."""
    return bool(name) and any(str(name).startswith(p) for p in _RATE_SETPOINTS)


#: the sweep flown for an identification, any firmware (each firmware's module says how to fly and log it)
SWEEP = ("one axis at a time, a frequency sweep from about 0.3 rad/s (0.05 Hz) to twice the loop's intended "
         "bandwidth (about 60 rad/s, 10 Hz, for a multicopter's rate loop), at a small amplitude around hover "
         "(rates of 20-50 deg/s; about 5-10 % of the torque range), 60-90 s a sweep, two or three sweeps, then "
         "doublets for the check")


def what_to_fly(firmware: str | None, axis: str | None = None) -> str:
    """What to fly, and log, for an identification on ``firmware`` (a registered firmware's name; None: every
    one's), one axis at a time. The band and durations are the rotorcraft practice (Tischler & Remple, *Aircraft and
    Rotorcraft System Identification*, ch. 5: sweeps from about 0.3 rad/s to twice the intended bandwidth, 60-90 s,
    repeated, doublets after) (:data:`SWEEP`); the firmware's settings from its sources, in its module
    (:attr:`tuner.firmware.base.Firmware.what_to_fly`: PX4 ``src/modules/logger/params.c`` SDLOG_PROFILE bit 3
    "system identification"; ArduCopter ``mode_systemid.cpp`` SID_* and ``Copter.h``'s LOG_BITMASK bits).

    Examples
    --------
    >>> "SDLOG_PROFILE" in what_to_fly("px4")
    True
    """
    from ..firmware.registry import firmwares, get_firmware

    if firmware is None:
        return ". ".join(f.what_to_fly(axis) for f in firmwares())
    return get_firmware(firmware).what_to_fly(axis)
