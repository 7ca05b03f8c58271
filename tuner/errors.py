"""One root exception, with subclasses of the builtins (Optuna's habit)."""

from __future__ import annotations

__all__ = [
    "TunerError",
    "InvalidExpressionError",
    "InvalidPlantError",
    "InvalidControllerError",
    "InvalidSpecError",
]


class TunerError(Exception):
    """Root of every error this package raises on purpose."""


class InvalidExpressionError(TunerError, ValueError):
    """A transfer-function expression could not be parsed.

    ``position`` is the 0-based character offset of the problem, when known.
    """

    def __init__(self, message: str, *, position: int | None = None) -> None:
        self.position = position
        if position is not None:
            message = f"{message} (at position {position})"
        super().__init__(message)


class InvalidPlantError(TunerError, ValueError):
    """A plant model is malformed: coefficients, order, properness, dt, delay."""


class InvalidControllerError(TunerError, ValueError):
    """A controller structure or its parameters are invalid."""


class InvalidSpecError(TunerError, ValueError):
    """A specification value is out of range or inconsistent."""
