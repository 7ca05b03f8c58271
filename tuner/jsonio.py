"""JSON with meaningful non-finite numbers, through pydantic.

``inf`` and ``nan`` mean something here (an infinite gain margin: no phase crossover; ``nan``:
not defined), so they are written as the strings ``"Infinity"``, ``"-Infinity"`` and ``"NaN"``
(pydantic's ``inf_nan_mode="strings"``) instead of being dropped or breaking strict JSON parsers.
numpy scalars and arrays are accepted.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pydantic_core

__all__ = ["jsonable", "dumps"]


def _fallback(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def dumps(obj: Any, *, indent: int | None = None) -> str:
    """``obj`` as JSON text; non-finite floats as "Infinity"/"-Infinity"/"NaN"."""
    return pydantic_core.to_json(obj, indent=indent, inf_nan_mode="strings", fallback=_fallback).decode()


def jsonable(obj: Any) -> Any:
    """``obj`` converted to JSON-safe Python values (dicts, lists, str, float, int, bool, None).

    Non-finite floats become ``"Infinity"``, ``"-Infinity"`` and ``"NaN"``; numpy scalars and arrays become
    numbers and lists.

    Examples
    --------
    >>> import math
    >>> import numpy as np
    >>> from tuner import jsonable
    >>> jsonable({"gm_db": math.inf, "x": np.float64(1.5), "poles": np.array([-1.0, -2.0]), "pm": math.nan})
    {'gm_db': 'Infinity', 'x': 1.5, 'poles': [-1.0, -2.0], 'pm': 'NaN'}
    """
    return json.loads(dumps(obj))
