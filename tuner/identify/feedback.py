"""Telling that a log was flown under feedback, from what the log says about itself.

Every flight log is closed loop: with ``u = C(r - y)`` and a disturbance on the airframe, the direct estimate
``S_uy/S_uu`` tends to ``-1/C`` wherever the disturbance dominates the reference (a hover in turbulence: it *is*
``-1/C``, at coherence 1). The signs read here (../shared/reference/firmware.md, "Identification from data flown
under feedback"):

* the input is a controller's output: PX4's torque and thrust setpoints, actuator controls, motor and servo
  commands; a CSV column named so;
* the log stores the rate controller's parameters (``MC_ROLLRATE_P``, ``ATC_RAT_RLL_P``, ...): the vehicle flew
  with that law on;
* the law itself, rebuilt from those parameters (:func:`known_controller`), so that
  :func:`tuner.identify` can compare the direct estimate with ``-1/C``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

__all__ = ["CONTROLLER_OUTPUTS", "signs_of", "axis_of", "known_controller", "hints"]

#: PX4 topics whose fields are a controller's output (the plant's input in a log flown under feedback)
CONTROLLER_OUTPUTS = ("vehicle_torque_setpoint", "vehicle_thrust_setpoint", "actuator_controls", "actuator_motors",
                      "actuator_servos", "actuator_outputs")
_CSV_HINTS = re.compile(r"torque_?setpoint|actuator|motor_?cmd|\bROut\b|rate_?ctrl_?out", re.IGNORECASE)
_RATE_PARAMS = ("MC_ROLLRATE_P", "MC_PITCHRATE_P", "MC_YAWRATE_P", "ATC_RAT_RLL_P", "ATC_RAT_PIT_P",
                "ATC_RAT_YAW_P")


def signs_of(input_name: str, parameters: Mapping[str, float] | None = None) -> list[str]:
    """The signs, in words, that a log whose input is ``input_name`` (a CSV column or a ULog ``TOPIC.FIELD``) and
    that stores ``parameters`` was flown under feedback.

    Examples
    --------
    >>> from tuner.identify.feedback import signs_of
    >>> signs_of("vehicle_torque_setpoint.xyz[0]", {"MC_ROLLRATE_P": 0.15})  # doctest: +NORMALIZE_WHITESPACE
    ["the input vehicle_torque_setpoint.xyz[0] is a controller's output",
     "the log stores the rate controller's parameters (MC_ROLLRATE_P)"]
    >>> signs_of("stick_roll", {})
    []
    """
    out = []
    topic = input_name.split(".", 1)[0].split(":", 1)[0]
    if any(topic.startswith(t) for t in CONTROLLER_OUTPUTS) or ("." not in input_name
                                                                 and _CSV_HINTS.search(input_name)):
        out.append(f"the input {input_name} is a controller's output")
    found = [p for p in _RATE_PARAMS if p in (parameters or {})]
    if found:
        out.append(f"the log stores the rate controller's parameters ({', '.join(found[:3])})")
    return out


def axis_of(input_name: str) -> str | None:
    """The body axis a ULog input field is on (``xyz[0]``/``control[0]`` roll, ``[1]`` pitch, ``[2]`` yaw)."""
    m = re.search(r"\[(\d)\]\s*$", input_name)
    if m is None:
        return None
    return {"0": "roll", "1": "pitch", "2": "yaw"}.get(m.group(1))


def known_controller(parameters: Mapping[str, float], input_name: str, dt: float) -> Any:
    """The rate law the log's parameters describe on the input's axis, at ``dt`` (None when the parameters or the
    axis are not there): PX4's or ArduPilot's, its feedback path ``C`` being what ``-1/C`` compares with."""
    axis = axis_of(input_name)
    if axis is None or not parameters:
        return None
    from ..controllers import get_structure
    from ..errors import TunerError
    from ..firmware.params import vehicle_from_raw
    from ..firmware.registry import get_firmware

    try:
        v = vehicle_from_raw(dict(parameters), axis=axis)
        st = get_structure(get_firmware(v.firmware).structure).with_fixed(v.fixed)
        return st.tf({**v.gains, **st.fixed_values}, dt)
    except TunerError:
        return None


def hints(input_name: str, parameters: Mapping[str, float] | None, rate_hz: float | None) -> dict[str, Any]:
    """What a log tells :func:`tuner.identify` of its feedback: ``closed_loop_signs`` and the ``controller`` its
    parameters describe (at the log's rate), as keyword arguments."""
    params = dict(parameters or {})
    return {"closed_loop_signs": signs_of(input_name, params),
            "controller": known_controller(params, input_name, 1.0 / rate_hz) if params and rate_hz else None}
