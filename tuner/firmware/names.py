"""The firmware's parameter names for each rate law and axis, and each gain's documented range.

Ranges, read from the firmware's parameter metadata:

* PX4: ``src/modules/mc_rate_control/mc_rate_control_params.c`` (``@min``/``@max``): roll P 0.01-0.5, pitch P
  0.01-0.6, yaw P 0-0.6; I >= 0; roll D 0-0.01, pitch and yaw D >= 0; FF >= 0; K 0.01-5; the integrator limits
  >= 0. The attitude P (``mc_att_control_params.c``): 0-12 (roll, pitch), 0-5 (yaw).
* ArduPilot Copter: ``libraries/AC_AttitudeControl/AC_AttitudeControl_Multi.cpp`` (``@Range``): roll and pitch P
  0.01-0.5, I 0.01-2.0, D 0-0.05, FF 0-0.5, IMAX 0-1, FLTT 5-100 Hz; yaw P 0.1-2.5, I 0.01-1.0, D 0-0.02,
  FF 0-0.5; the angle P (``AC_AttitudeControl.cpp``) 3-12.

A bound the metadata leaves open is ``inf``.
"""

from __future__ import annotations

import math

__all__ = ["AXES", "PX4", "ARDUPILOT", "law_names", "law_ranges", "RANGES"]

AXES = ("roll", "pitch", "yaw")
_INF = math.inf


def _px4(axis: str) -> dict[str, str]:
    a = {"roll": "ROLL", "pitch": "PITCH", "yaw": "YAW"}[axis]
    s = {"roll": "RR", "pitch": "PR", "yaw": "YR"}[axis]
    return {"P": f"MC_{a}RATE_P", "I": f"MC_{a}RATE_I", "D": f"MC_{a}RATE_D", "FF": f"MC_{a}RATE_FF",
            "K": f"MC_{a}RATE_K", "int_lim": f"MC_{s}_INT_LIM", "dgyro_hz": "IMU_DGYRO_CUTOFF",
            "gyro_hz": "IMU_GYRO_CUTOFF", "loop_hz": "IMU_GYRO_RATEMAX", "att_p": f"MC_{a}_P",
            "rate_max_dps": f"MC_{a}RATE_MAX"}


def _ardupilot(axis: str) -> dict[str, str]:
    a = {"roll": "RLL", "pitch": "PIT", "yaw": "YAW"}[axis]
    return {"P": f"ATC_RAT_{a}_P", "I": f"ATC_RAT_{a}_I", "D": f"ATC_RAT_{a}_D", "FF": f"ATC_RAT_{a}_FF",
            "imax": f"ATC_RAT_{a}_IMAX", "fltt_hz": f"ATC_RAT_{a}_FLTT", "flte_hz": f"ATC_RAT_{a}_FLTE",
            "fltd_hz": f"ATC_RAT_{a}_FLTD", "gyro_hz": "INS_GYRO_FILTER", "loop_hz": "SCHED_LOOP_RATE",
            "att_p": f"ATC_ANG_{a}_P"}


#: per firmware and axis: the law's quantity -> the parameter's name
PX4 = {ax: _px4(ax) for ax in AXES}
ARDUPILOT = {ax: _ardupilot(ax) for ax in AXES}

#: per firmware and axis: the law's quantity -> (min, max) as documented (see the module's docstring)
RANGES: dict[str, dict[str, dict[str, tuple[float, float]]]] = {
    "px4": {ax: {"P": {"roll": (0.01, 0.5), "pitch": (0.01, 0.6), "yaw": (0.0, 0.6)}[ax], "I": (0.0, _INF),
                 "D": (0.0, 0.01) if ax == "roll" else (0.0, _INF), "FF": (0.0, _INF), "K": (0.01, 5.0),
                 "int_lim": (0.0, _INF), "att_p": (0.0, 5.0) if ax == "yaw" else (0.0, 12.0)} for ax in AXES},
    "ardupilot": {ax: ({"P": (0.1, 2.5), "I": (0.01, 1.0), "D": (0.0, 0.02)} if ax == "yaw" else
                       {"P": (0.01, 0.5), "I": (0.01, 2.0), "D": (0.0, 0.05)})
                  | {"FF": (0.0, 0.5), "imax": (0.0, 1.0), "fltt_hz": (0.0, 100.0), "flte_hz": (0.0, 100.0),
                     "fltd_hz": (0.0, 100.0), "att_p": (3.0, 12.0)} for ax in AXES},
}


def law_names(firmware: str, axis: str) -> dict[str, str]:
    """The parameter names of ``firmware``'s rate law on ``axis`` (quantity -> name).

    Examples
    --------
    >>> from tuner.firmware.names import law_names
    >>> law_names("px4", "pitch")["int_lim"], law_names("ardupilot", "yaw")["P"]
    ('MC_PR_INT_LIM', 'ATC_RAT_YAW_P')
    """
    table = {"px4": PX4, "ardupilot": ARDUPILOT}[firmware]
    return dict(table[axis])


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
    r = RANGES[firmware][axis]
    return {k: tuple(r[k]) for k in ("P", "I", "D", "FF") if k in r}
