"""The schema of a result file as export reads it (the JSON of ``tuner tune --json`` or of ``GET /tunes/{id}``):
every field an export formats is checked for its type before anything is formatted, so a crafted or damaged file is
bad input naming the field (``vehicle.gyro_cutoff_hz``), never an internal error. Fields export does not read pass as
they are; what the values mean (a gain within the firmware's range, a proper controller) is the exporters' check.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictFloat, StrictInt, StrictStr, ValidationError

from ..errors import TunerError

__all__ = ["check_result"]

Real = StrictInt | StrictFloat  # a JSON number (not a boolean, not a string)
Coefficients = Annotated[list[Real], Field(min_length=1)]
Figure = StrictBool | Real | Literal["Infinity", "-Infinity", "NaN"] | None  # a metric as jsonio writes it


class _Part(BaseModel):
    model_config = ConfigDict(extra="allow", strict=True)


class _Controller(_Part):  # (num and den: a code export's; a parameter file needs dt only)
    num: Coefficients | None = None
    den: Coefficients | None = None
    dt: Real | None = None
    num_r: Coefficients | None = None


class _Vehicle(_Part):
    firmware: StrictStr | None = None
    axis: Literal["roll", "pitch", "yaw"] | None = None
    loop_hz: Real | None = None
    loop_source: StrictStr | None = None
    gyro_cutoff_hz: Real | None = None
    att_p: Real | None = None
    rate_max_dps: Real | None = None
    source: StrictStr | None = None
    current_gains: dict[str, Real] | None = None
    fixed: dict[str, Real] | None = None
    current_gains_law: dict[str, Real] | None = None
    notes: list[StrictStr] | None = None
    warnings: list[StrictStr] | None = None
    changes: list[StrictStr] | None = None
    ids: list[StrictInt] | None = None
    typed_plant: dict[str, Any] | None = None
    has: list[StrictStr] | None = None


class _Check(_Part):
    name: StrictStr | None = None
    ok: StrictBool | None = None
    achieved: Figure | StrictStr = None  # a figure, or a rating ('closed-loop' for identification_quality)
    required: Figure | StrictStr = None
    op: StrictStr | None = None


class _Measured(_Part):
    band_rad_s: Annotated[list[Figure], Field(min_length=2, max_length=2)] | None = None
    points: Real | None = None


class _Identification(_Part):
    quality: StrictStr | None = None
    cost: Figure = None
    check: StrictStr | None = None


class _Result(_Part):
    structure: StrictStr | None = None
    axis: Literal["roll", "pitch", "yaw"] | None = None
    verdict: StrictStr | None = None
    basis: StrictStr | None = None
    checks: list[_Check] | None = None
    measured: _Measured | None = None
    identification: _Identification | None = None
    gains: dict[str, Real] | None = None
    controller: _Controller | None = None
    dt: Real | None = None
    metrics: dict[str, Figure] | None = None
    meets_spec: StrictBool | None = None
    vehicle: _Vehicle | None = None


def check_result(result: Any) -> Mapping[str, Any]:
    """``result`` as it is, once every field export reads has its type; else a :class:`~tuner.errors.TunerError`
    whose ``field`` is the path in the file (``("vehicle", "gyro_cutoff_hz")``) and whose message names it.

    Examples
    --------
    >>> from tuner.export.resultfile import check_result
    >>> check_result({"controller": {"num": [1.0], "den": [1.0, -1.0], "dt": "fast"}})
    Traceback (most recent call last):
    ...
    tuner.errors.TunerError: controller.dt: a number or null, got 'fast'
    """
    if not isinstance(result, Mapping):
        raise TunerError(f"not a result (a JSON object with a controller), got a JSON {type(result).__name__}")
    try:
        _Result.model_validate(dict(result))
    except ValidationError as e:
        err = e.errors(include_url=False)[0]
        loc = tuple(err["loc"])
        # a union's members each add a level to the location (e.g. 'int', 'float'): the field is the path before
        path = tuple(x for x in loc if not (isinstance(x, str) and (x in _MEMBER or x.startswith(("literal[",
                                                                                                      "function")))))
        where = "".join(f"[{x}]" if isinstance(x, int) else f".{x}" for x in path).lstrip(".") or "the result"
        got = f", got {_shown(err)}"
        raise TunerError(f"{where}: {_what(err, path)}{got}", field=path) from None
    return result


_MEMBER = {"int", "float", "bool", "str", "none", "list[union[int,float]]", "dict[str,union[int,float]]"}


def _what(err: dict[str, Any], path: tuple) -> str:
    kind = err["type"]
    last = path[-1] if path else ""
    if last in ("num", "den", "num_r") or (len(path) >= 2 and path[-2] in ("num", "den", "num_r")):
        return "a list of numbers (the controller's coefficients)"
    if path[:1] == ("metrics",) and len(path) == 2:
        return "a number, true or false, 'Infinity', '-Infinity' or 'NaN'"
    if kind in ("dict_type", "model_type"):
        return "an object"
    if kind in ("list_type", "too_short"):
        return "a non-empty list"
    if last == "axis":
        return "one of roll, pitch, yaw"
    if kind.startswith("string") or last in ("structure", "firmware", "source"):
        return "a string"
    if kind.startswith("bool") or last == "meets_spec":
        return "true or false"
    return "a number" + (" or null" if last in _NULLABLE else "")


_NULLABLE = {"dt", "loop_hz", "gyro_cutoff_hz", "att_p", "rate_max_dps"}


def _shown(err: dict[str, Any]) -> str:
    v = err.get("input")
    s = repr(v)
    return s if len(s) <= 60 else s[:57] + "..."
