"""The schema of an identification's JSON as :meth:`IdentifyResult.from_dict` reads it (``tuner identify --json``, a
stored identification): every field it rebuilds from is checked for its type and range before anything is built, so
a crafted or damaged file (``--identified``) is bad input naming the field (``model.poles``), never an internal
error. Fields it does not read pass as they are.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictFloat, StrictInt, StrictStr, ValidationError

from ..errors import InvalidDataError

__all__ = ["check_identification"]

Real = StrictInt | StrictFloat
Figure = Real | Literal["Infinity", "-Infinity", "NaN"]  # jsonio writes non-finite numbers as these strings
Figures = list[Figure]
Finite = Annotated[Real, Field(allow_inf_nan=False)]


class _Part(BaseModel):
    model_config = ConfigDict(extra="allow", strict=True)


class _Model(_Part):
    poles: Annotated[StrictInt, Field(ge=1, le=8)]
    zeros: Annotated[StrictInt, Field(ge=0, le=8)]
    parameters: dict[str, Finite]


class _Response(_Part):
    w: Figures
    mag_db: Figures
    phase_deg: Figures
    coherence: Figures
    windows_s: Figures = []
    coherence_ry: Figures | None = None
    coherence_ru: Figures | None = None


class _FitPoints(_Part):
    w: Figures
    mag_db: Figures
    phase_deg: Figures
    coherence: Figures
    cost: Figures


class _Series(_Part):
    t: Figures = []
    measured: Figures = []
    model: Figures = []


class _Validation(_Part):
    t_start_s: Figure
    duration_s: Figure
    nrmse: Figure
    theil_u: Figure
    rms_error: Figure
    bias: Figure
    drift_per_s: Figure
    noise_rms: Figure = "NaN"
    theil_scale: Figure = "NaN"
    source: StrictStr = "holdout"
    series: _Series | None = None


class _Covariance(_Part):
    parameters: list[StrictStr]
    matrix: list[Figures]


class _Identification(_Part):
    model: _Model
    cost: Figure
    band_rad_s: Annotated[list[Annotated[Real, Field(gt=0, allow_inf_nan=False)]], Field(min_length=2, max_length=2)]
    frequency_response: _Response
    fit_points: _FitPoints
    uncertainty: dict[str, dict[str, Figure]]
    validation: _Validation | None = None
    warnings: list[StrictStr] = []
    rate_hz: Annotated[Real, Field(gt=0, allow_inf_nan=False)]
    n_samples: Annotated[StrictInt, Field(ge=0)]
    fit_duration_s: Figure
    options: dict[str, Any] = {}
    covariance: _Covariance | None = None
    closed_loop: dict[str, Any] | None = None


class _Options(_Part):
    coherence_min: Annotated[Real, Field(gt=0, lt=1)] = 0.6
    hold: Literal["zoh"] | None = None
    delay_step: Annotated[Real, Field(gt=0, allow_inf_nan=False)] | None = None
    estimate: StrictStr = "direct"
    notes: list[StrictStr] = []


class _ClosedLoop(_Part):
    detected: StrictBool = False
    signs: list[StrictStr] = []
    message: StrictStr | None = None


def check_identification(d: Any) -> Mapping[str, Any]:
    """``d`` as it is, once every field :meth:`IdentifyResult.from_dict` reads has its type (and the model its
    size: 1 to 8 poles, at most as many zeros, a delay of 0 to 1e6 s); else an
    :class:`~tuner.errors.InvalidDataError` whose ``field`` is the path in the file.

    Examples
    --------
    >>> from tuner.identify.resultfile import check_identification
    >>> check_identification({"model": {"poles": 1e308}})  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    tuner.errors.InvalidDataError: model.poles: ... got 1e+308
    """
    if not isinstance(d, Mapping):
        raise InvalidDataError(f"not an identification (a JSON object with a model), got a JSON {type(d).__name__}")
    parts = ((_Identification, lambda: d, ()), (_Options, lambda: d.get("options") or {}, ("options",)),
             (_ClosedLoop, lambda: d.get("closed_loop") or {}, ("closed_loop",)))  # (the last two once d is checked)
    for schema, part, top in parts:
        try:
            schema.model_validate(dict(part()))
        except ValidationError as e:
            raise _error(e.errors(include_url=False)[0], top) from None
    for part, names in (("frequency_response", ("w", "mag_db", "phase_deg", "coherence", "coherence_ry",
                                                "coherence_ru")),
                        ("fit_points", ("w", "mag_db", "phase_deg", "coherence", "cost"))):
        _same_lengths(d[part], names, part)
    if d.get("validation") and d["validation"].get("series"):
        _same_lengths(d["validation"]["series"], ("t", "measured", "model"), "validation.series")
    m = d["model"]
    if m["zeros"] > m["poles"]:
        raise InvalidDataError(f"model.zeros: {m['zeros']} is more than model.poles ({m['poles']})",
                               field=("model", "zeros"))
    delay = m["parameters"].get("delay_s", 0.0)
    if not 0.0 <= delay <= 1e6:
        raise InvalidDataError(f"model.parameters.delay_s: a delay of 0 to 1e6 s, got {delay!r}",
                               field=("model", "parameters", "delay_s"))
    return d


def _same_lengths(part: Mapping[str, Any], names: tuple[str, ...], where: str) -> None:
    """The lists of one response (its frequencies and their values) as long as each other."""
    have = [(k, len(part[k])) for k in names if part.get(k) is not None]
    for k, n in have[1:]:
        if n != have[0][1]:
            raise InvalidDataError(f"{where}.{k}: {n} values, but {where}.{have[0][0]} has {have[0][1]} (one a "
                                   "frequency or sample)", field=(*where.split("."), k))


def _error(err: dict[str, Any], top: tuple) -> InvalidDataError:
    loc = tuple(x for x in err["loc"] if not (isinstance(x, str) and (x in _MEMBER or x.startswith(("literal[",
                                                                                                       "constrained")))))
    where = "".join(f"[{x}]" if isinstance(x, int) else f".{x}" for x in (*top, *loc)).lstrip(".") or "the file"
    kind, last = err["type"], (loc[-1] if loc else "")
    if kind == "missing":
        what = "missing"
    elif kind in _NUMBER and last in ("poles", "zeros", "n_samples"):
        what = "a whole number"
    elif kind in _NUMBER:
        what = "a number"
    else:
        what = err["msg"][0].lower() + err["msg"][1:]
    got = "" if kind == "missing" else f", got {_shown(err.get('input'))}"
    return InvalidDataError(f"{where}: {what}{got}", field=(*top, *loc))


_NUMBER = {"int_type", "int_parsing", "int_from_float", "float_type", "float_parsing", "literal_error", "finite_number"}


_MEMBER = {"int", "float", "bool", "str", "none", "function-after"}


def _shown(v: Any) -> str:
    s = repr(v)
    return s if len(s) <= 60 else s[:57] + "..."
