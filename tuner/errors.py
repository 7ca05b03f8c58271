"""One root exception, with subclasses of the builtins (Optuna's habit).

Every error carries, when known, the input it is about as ``field``: a path such as
``("dt",)``, ``("plants", 2, "delay")`` or ``("controller", "expr")``. Callers that wrap an
input (the CLI, the service, a study file) map that path to their own names (``--dt``,
``["body", "plants", 1, "delay"]``) without reading the message.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = [
    "TunerError",
    "InvalidExpressionError",
    "InvalidPlantError",
    "InvalidControllerError",
    "InvalidSpecError",
    "InvalidDataError",
    "IdentificationError",
    "Field",
]

Field = tuple[str | int, ...]


def _as_field(field: str | int | Sequence[str | int] | None) -> Field:
    if field is None:
        return ()
    if isinstance(field, (str, int)):
        return (field,)
    return tuple(field)


class TunerError(Exception):
    """Root of every error this package raises on purpose.

    ``field`` names the offending input (a path, empty when the error is not about one input).

    Examples
    --------
    >>> from tuner import TunerError, tune
    >>> try:
    ...     tune(None, structure="pi", time_budget_s=-1)
    ... except TunerError as e:
    ...     print(e.field, "|", e)
    ('time_budget_s',) | time_budget_s must be a finite number > 0, got -1
    """

    def __init__(self, message: str, *, field: str | int | Sequence[str | int] | None = None) -> None:
        super().__init__(message)
        self.field: Field = _as_field(field)

    def __reduce__(self):  # pickled across processes (the solver pool) with its field and position
        return (type(self), self.args, self.__dict__)

    def at(self, *prefix: str | int) -> TunerError:
        """Prefix ``field`` with the place the erroneous input came from; returns ``self``.

        ``raise e.at("plants", 2)`` inside ``except TunerError as e`` re-raises the same error
        with ``field == ("plants", 2, *old_field)``.
        """
        self.field = tuple(prefix) + self.field
        return self


class InvalidExpressionError(TunerError, ValueError):
    """A transfer-function expression could not be parsed.

    ``position`` is the 0-based character offset of the problem, when known.

    Examples
    --------
    >>> from tuner import InvalidExpressionError, plant_from_expr
    >>> try:
    ...     plant_from_expr("1/(s+")
    ... except InvalidExpressionError as e:
    ...     print(e.field, e.position is not None)
    ('expr',) True
    """

    def __init__(self, message: str, *, position: int | None = None,
                 field: str | int | Sequence[str | int] | None = None) -> None:
        self.position = position
        if position is not None:
            message = f"{message} (at position {position})"
        super().__init__(message, field=field)


class InvalidPlantError(TunerError, ValueError):
    """A plant model is malformed: coefficients, order, properness, dt, delay.

    Examples
    --------
    >>> from tuner import InvalidPlantError, make_plant
    >>> try:
    ...     make_plant([1.0], [1.0, 1.0], delay=-1)
    ... except InvalidPlantError as e:
    ...     print(e.field)
    ('delay',)
    """


class InvalidControllerError(TunerError, ValueError):
    """A controller structure or its parameters are invalid.

    Examples
    --------
    >>> from tuner import InvalidControllerError, get_structure
    >>> try:
    ...     get_structure("pdi")
    ... except InvalidControllerError as e:
    ...     print(e.field)
    ('structure',)
    """


class InvalidSpecError(TunerError, ValueError):
    """A specification value is out of range or inconsistent (e.g. Ms < 1).

    Raised where a spec is checked against the problem (a :class:`~tuner.spec.Spec` field out of its range is
    refused by pydantic when the spec is built).

    Examples
    --------
    >>> from tuner import InvalidSpecError, TunerError
    >>> issubclass(InvalidSpecError, TunerError) and issubclass(InvalidSpecError, ValueError)
    True
    >>> InvalidSpecError("ms_max must be >= 1", field="ms_max").field
    ('ms_max',)
    """


class InvalidDataError(TunerError, ValueError):
    """Recorded input/output data cannot be used (lengths, NaN, no excitation, too short), or an
    identification option is invalid (a bad number of poles, a band the record cannot resolve ...).

    Examples
    --------
    >>> from tuner import InvalidDataError, identify
    >>> try:
    ...     identify([0.0] * 200, [0.0] * 100, rate_hz=100, poles=1)
    ... except InvalidDataError as e:
    ...     print(e.field)  # doctest: +ELLIPSIS
    (...)
    """


class IdentificationError(TunerError, RuntimeError):
    """The model fit failed on data that passed validation (no start converged to a finite cost).

    Examples
    --------
    >>> from tuner import IdentificationError, TunerError
    >>> issubclass(IdentificationError, TunerError) and issubclass(IdentificationError, RuntimeError)
    True
    """
