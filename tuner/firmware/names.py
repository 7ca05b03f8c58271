"""The firmware's parameter names for each rate law and axis, each value's documented range, and how the firmware
stores it.

Ranges, read from the firmware's parameter metadata (the ``@min``/``@max`` and ``@Range`` comments that ground
stations show and check edits against; neither firmware's parameter store enforces them: a value outside is held
and flown as it is, except where a module clamps it itself, named below):

* PX4 ``src/modules/mc_rate_control/mc_rate_control_params.c`` (PX4/PX4-Autopilot at 00ba1d7; the same in
  ``mc_rate_control_params.yaml`` at 0227117): roll P 0.01-0.5, pitch P 0.01-0.6, yaw P 0-0.6; I >= 0; roll D
  0-0.01, pitch and yaw D >= 0; FF >= 0; K 0.01-5; the integrator limits ``MC_*R_INT_LIM`` >= 0. The attitude P
  (``src/modules/mc_att_control/mc_att_control_params.yaml`` at e87d6af): 0-12 (roll, pitch), 0-5 (yaw). The loop
  rate ``IMU_GYRO_RATEMAX`` (an INT32, Hz) 0-2000 and the D-term low-pass ``IMU_DGYRO_CUTOFF`` 0-1000 Hz
  (``src/modules/sensors/vehicle_angular_velocity/imu_gyro_parameters.c`` at 050fa47; a rate of 0 means the
  sensor's own, which is no loop rate the tuner can use).
* ArduPilot Copter ``libraries/AC_AttitudeControl/AC_AttitudeControl_Multi.cpp`` (``@Range``, ArduPilot/ardupilot
  master as stored in the public-source index, whose record of that version names no commit; the commit it lists
  for the path, 67c5752, holds an older file with one ``FILT`` per axis): roll and pitch P 0.01-0.5, I 0.01-2.0,
  D 0-0.05, FF 0-0.5, IMAX 0-1, FLTT 5-100 Hz, FLTE 0-100 Hz, FLTD 5-100 Hz; yaw P 0.1-2.5, I 0.01-1.0, D 0-0.02,
  FF 0-0.5, IMAX 0-1, FLTT 1-50 Hz, FLTE 0-20 Hz, FLTD 5-50 Hz; the angle P (``AC_AttitudeControl.cpp``) 3-12. The
  loop rate ``SCHED_LOOP_RATE`` (an AP_Int16, Hz): ``libraries/AP_Scheduler/AP_Scheduler.cpp`` (at 24d233d) clamps
  it to 50-2000 when the scheduler starts: the one range here the firmware enforces.

Storage: both firmwares hold these parameters as IEEE single precision (PX4 ``PARAM_DEFINE_FLOAT``, ArduPilot
``AP_Float``), the loop rates as integers (PX4 ``PARAM_DEFINE_INT32``, ArduPilot ``AP_Int16``). A value beyond
float32's range (3.4e38) is not a value a vehicle can hold.

A bound the metadata leaves open is ``inf``.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["AXES", "PX4", "ARDUPILOT", "law_names", "law_ranges", "RANGES", "CLAMPED", "SOURCE", "INTEGER", "SCALE",
           "FLOAT32_MAX", "FLOAT32_EPS", "stored_value", "range_problem"]

AXES = ("roll", "pitch", "yaw")
_INF = math.inf
FLOAT32_MAX = (2.0 - 2.0 ** -23) * 2.0 ** 127  # 3.4028235e38, numpy's finfo(float32).max (numpy not imported here:
#                                               the firmware registry is read by the command line's parser)
FLOAT32_EPS = 2.0 ** -23  # single precision's relative resolution, finfo(float32).eps


def _px4(axis: str) -> dict[str, str]:
    a = {"roll": "ROLL", "pitch": "PITCH", "yaw": "YAW"}[axis]
    s = {"roll": "RR", "pitch": "PR", "yaw": "YR"}[axis]
    return {"P": f"MC_{a}RATE_P", "I": f"MC_{a}RATE_I", "D": f"MC_{a}RATE_D", "FF": f"MC_{a}RATE_FF",
            "K": f"MC_{a}RATE_K", "int_lim": f"MC_{s}_INT_LIM", "dgyro_hz": "IMU_DGYRO_CUTOFF",
            "gyro_hz": "IMU_GYRO_CUTOFF", "loop_hz": "IMU_GYRO_RATEMAX", "att_p": f"MC_{a}_P",
            "rate_max_dps": f"MC_{a}RATE_MAX", **({"tq_hz": "MC_YAW_TQ_CUTOFF"} if axis == "yaw" else {})}


def _ardupilot(axis: str) -> dict[str, str]:
    a = {"roll": "RLL", "pitch": "PIT", "yaw": "YAW"}[axis]
    return {"P": f"ATC_RAT_{a}_P", "I": f"ATC_RAT_{a}_I", "D": f"ATC_RAT_{a}_D", "FF": f"ATC_RAT_{a}_FF",
            "imax": f"ATC_RAT_{a}_IMAX", "fltt_hz": f"ATC_RAT_{a}_FLTT", "flte_hz": f"ATC_RAT_{a}_FLTE",
            "fltd_hz": f"ATC_RAT_{a}_FLTD", "gyro_hz": "INS_GYRO_FILTER", "loop_hz": "SCHED_LOOP_RATE",
            "att_p": f"ATC_ANG_{a}_P", "dff": f"ATC_RAT_{a}_D_FF"}


#: ArduPilot's AC_PID parameters the linear law does not hold (``AC_PID.cpp``, ``update_all``): the P+D limit
#: ``PDMX`` (a clamp on ``|P + D|``), the target and error notches ``NTF``/``NEF`` (indices of ``FILTn_*`` notch
#: filters), and the slew limiter ``SMAX`` (``_slew_limiter.modifier``: it lowers P and D only after the P+D output's
#: slew rate exceeds SMAX in alternating directions, i.e. on an oscillation, so a loop that does not oscillate flies
#: the linear law)
ARDUPILOT_UNMODELLED = ("PDMX", "NTF", "NEF")
ARDUPILOT_SLEW = "SMAX"


#: per firmware and axis: the law's quantity -> the parameter's name
PX4 = {ax: _px4(ax) for ax in AXES}
ARDUPILOT = {ax: _ardupilot(ax) for ax in AXES}


def _px4_ranges(ax: str) -> dict[str, tuple[float, float]]:
    return {"P": {"roll": (0.01, 0.5), "pitch": (0.01, 0.6), "yaw": (0.0, 0.6)}[ax], "I": (0.0, _INF),
            "D": (0.0, 0.01) if ax == "roll" else (0.0, _INF), "FF": (0.0, _INF), "K": (0.01, 5.0),
            "int_lim": (0.0, _INF), "att_p": (0.0, 5.0) if ax == "yaw" else (0.0, 12.0),
            "dgyro_hz": (0.0, 1000.0), "loop_hz": (0.0, 2000.0)}


def _ardupilot_ranges(ax: str) -> dict[str, tuple[float, float]]:
    if ax == "yaw":
        own = {"P": (0.1, 2.5), "I": (0.01, 1.0), "D": (0.0, 0.02), "fltt_hz": (1.0, 50.0), "flte_hz": (0.0, 20.0),
               "fltd_hz": (5.0, 50.0)}
    else:
        own = {"P": (0.01, 0.5), "I": (0.01, 2.0), "D": (0.0, 0.05), "fltt_hz": (5.0, 100.0),
               "flte_hz": (0.0, 100.0), "fltd_hz": (5.0, 100.0)}
    return own | {"FF": (0.0, 0.5), "imax": (0.0, 1.0), "att_p": (3.0, 12.0), "loop_hz": (50.0, 2000.0)}


#: per firmware and axis: the law's quantity -> (min, max) as documented (see the module's docstring)
RANGES: dict[str, dict[str, dict[str, tuple[float, float]]]] = {
    "px4": {ax: _px4_ranges(ax) for ax in AXES},
    "ardupilot": {ax: _ardupilot_ranges(ax) for ax in AXES},
}
#: the quantities whose range the firmware itself enforces, and how (the rest are metadata only)
CLAMPED: dict[str, dict[str, str]] = {
    "ardupilot": {"loop_hz": "AP_Scheduler clamps SCHED_LOOP_RATE to 50-2000 Hz when it starts (AP_Scheduler.cpp)"},
    "px4": {},
}
#: per firmware: the quantity -> the source file that documents its range (the module's docstring names the commits)
SOURCE: dict[str, dict[str, str]] = {
    "px4": {**dict.fromkeys(("P", "I", "D", "FF", "K", "int_lim"), "PX4's mc_rate_control_params.c"),
            "att_p": "PX4's mc_att_control_params.yaml",
            **dict.fromkeys(("dgyro_hz", "loop_hz"), "PX4's imu_gyro_parameters.c")},
    "ardupilot": {**dict.fromkeys(("P", "I", "D", "FF", "imax", "fltt_hz", "flte_hz", "fltd_hz"),
                                  "ArduPilot's AC_AttitudeControl_Multi.cpp"),
                  "att_p": "ArduPilot's AC_AttitudeControl.cpp", "loop_hz": "ArduPilot's AP_Scheduler.cpp"},
}
#: the quantities stored as integers (the rest are float32)
INTEGER: dict[str, tuple[str, ...]] = {"px4": ("loop_hz",), "ardupilot": ("loop_hz",)}
#: per firmware and axis: the scale a value is resolved against (the zero rule of :func:`stored_value`): the
#: documented maximum where the metadata gives one, else the firmware's default (PX4's I: 0.2, yaw 0.1; its integrator
#: limit 0.3), else for PX4's D and FF, which share a unit with roll's D and the axis' P, those maxima
SCALE: dict[str, dict[str, dict[str, float]]] = {
    "px4": {ax: {"P": _px4_ranges(ax)["P"][1], "I": 0.1 if ax == "yaw" else 0.2, "D": 0.01,
                 "FF": _px4_ranges(ax)["P"][1], "K": 5.0, "int_lim": 0.3, "att_p": _px4_ranges(ax)["att_p"][1]}
            for ax in AXES},
    "ardupilot": {ax: {k: hi for k, (_, hi) in _ardupilot_ranges(ax).items() if k != "loop_hz"} for ax in AXES},
}


def law_names(firmware: str, axis: str) -> dict[str, str]:
    """The parameter names of ``firmware``'s rate law on ``axis`` (quantity -> name).

    Examples
    --------
    >>> from tuner.firmware.names import law_names
    >>> law_names("px4", "pitch")["int_lim"], law_names("ardupilot", "yaw")["P"]
    ('MC_PR_INT_LIM', 'ATC_RAT_YAW_P')
    """
    from .registry import get_firmware

    return get_firmware(firmware).law_names(axis)


def law_ranges(firmware: str, axis: str) -> dict[str, tuple[float, float]]:
    """The documented ranges of the rate law's tuned parameters (``P``, ``I``, ``D``, ``FF``) of ``firmware`` on
    ``axis``: what a ground station offers for each (its parameter metadata; neither firmware enforces them on
    board). The search keeps a tuned law inside them, so that every design can be written to the vehicle's file.

    Examples
    --------
    >>> from tuner.firmware.names import law_ranges
    >>> law_ranges("px4", "roll")["P"], law_ranges("ardupilot", "yaw")["I"]
    ((0.01, 0.5), (0.01, 1.0))
    """
    from .registry import get_firmware

    r = get_firmware(firmware).ranges(axis)
    return {k: tuple(r[k]) for k in ("P", "I", "D", "FF") if k in r}


def stored_value(firmware: str, axis: str, key: str, value: float) -> float:
    """``value`` as the firmware stores it (float32), with the zero rule: a magnitude below float32's resolution
    (``FLOAT32_EPS``, 2^-23) times the parameter's scale (:data:`SCALE`) is 0. The firmware's single-precision sums
    cannot resolve such a term against the values of that parameter's own range; a gain at the optimum's zero shows as
    6e-18 only through double-precision rounding. Raises ValueError for a value no vehicle can hold (not finite, or
    beyond float32's range).

    Examples
    --------
    >>> from tuner.firmware.names import stored_value
    >>> stored_value("px4", "roll", "D", 6.16627746e-18), stored_value("px4", "roll", "P", 0.12)
    (0.0, 0.11999999731779099)
    """
    v = float(value)
    if not math.isfinite(v) or abs(v) > FLOAT32_MAX:
        raise ValueError(f"{v!r} is not a value {firmware} can store (single precision: finite, at most "
                         f"{FLOAT32_MAX:.8g} in magnitude)")
    from .registry import get_firmware

    fw = get_firmware(firmware)
    scale = fw.scale(axis).get(key, 1.0)
    if abs(v) < FLOAT32_EPS * scale:
        return 0.0
    if key in fw.integer:  # stored as an integer: the whole number nearest
        return float(round(v))
    import numpy as np

    return float(np.float32(v))


def range_problem(firmware: str, axis: str, key: str, value: float) -> dict[str, Any] | None:
    """What is wrong with ``value`` of ``key`` against its documented range and storage, or None: ``lo``, ``hi``,
    ``side`` (``low``, ``high``, ``integer``), ``enforced`` (how the firmware clamps it, or None: metadata only),
    ``source`` (the file documenting it).

    Examples
    --------
    >>> from tuner.firmware.names import range_problem
    >>> range_problem("px4", "roll", "K", 50.0)["side"], range_problem("px4", "roll", "K", 1.0)
    ('high', None)
    """
    from .registry import get_firmware

    fw = get_firmware(firmware)
    lo, hi = fw.ranges(axis).get(key, (-_INF, _INF))
    v = float(value)
    enforced = fw.clamped.get(key)
    src = fw.range_source.get(key, f"{firmware}'s parameter metadata")
    if v < lo:
        return {"lo": lo, "hi": hi, "side": "low", "enforced": enforced, "source": src}
    if v > hi:
        return {"lo": lo, "hi": hi, "side": "high", "enforced": enforced, "source": src}
    if key in fw.integer and v != round(v):
        return {"lo": lo, "hi": hi, "side": "integer", "enforced": None, "source": src}
    return None
