"""The autopilots' rate laws and their parameters, one module per firmware behind one interface
(:class:`~tuner.firmware.base.Firmware`; :mod:`~tuner.firmware.px4`, :mod:`~tuner.firmware.ardupilot`,
:mod:`~tuner.firmware.betaflight`), listed in :mod:`~tuner.firmware.registry`, which every other place looks a
firmware up in: :mod:`~tuner.firmware.laws` (PX4's and ArduPilot's laws as the firmware computes them),
:mod:`~tuner.firmware.names` (the parameter names and documented ranges), :mod:`~tuner.firmware.params` (reading
``.params``, ``.parm``, ULog parameters and each firmware's own text files) and :mod:`~tuner.firmware.bind` (a law
bound to a vehicle)."""

from __future__ import annotations

from .params import VehicleParams, read_params, vehicle_from_text

__all__ = ["VehicleParams", "read_params", "vehicle_from_text"]
