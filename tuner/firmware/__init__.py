"""The autopilots' rate laws and their parameters: :mod:`~tuner.firmware.laws` (PX4's and ArduPilot's laws as the
firmware computes them), :mod:`~tuner.firmware.names` (the parameter names and documented ranges),
:mod:`~tuner.firmware.params` (reading ``.params``, ``.parm`` and ULog parameters) and :mod:`~tuner.firmware.bind`
(a law bound to a vehicle)."""

from __future__ import annotations

from .params import VehicleParams, read_params, vehicle_from_text

__all__ = ["VehicleParams", "read_params", "vehicle_from_text"]
