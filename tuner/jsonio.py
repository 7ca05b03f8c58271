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
    """``obj`` converted to JSON-safe Python values (dicts, lists, str, float, int, bool, None)."""
    return json.loads(dumps(obj))
