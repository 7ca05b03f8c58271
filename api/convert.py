"""Request bodies -> library objects, with every library error tied to the field it came from.

The library raises :class:`tuner.errors.TunerError` subclasses with messages that
say what is wrong; here they become :class:`FieldError` with the body location
(``["body", "plant", "expr"]``, ``["body", "dt"]``, ...), answered as 422 in
FastAPI's validation-error format.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from tuner.controllers import ControllerTF, controller_from_expr, controller_tf, get_structure
from tuner.errors import TunerError
from tuner.plant import Plant, check_dt, make_plant, plant_from_expr
from tuner.spec import Spec

from .schemas import ControllerIn, PlantIn

__all__ = ["FieldError", "to_plant", "plant_dict", "to_controller", "check_loop_dt", "error_type", "spec_or_default",
           "tuner_error_loc"]

Loc = tuple[str | int, ...]


class FieldError(Exception):
    """Bad input in one field of the body: answered 422 with ``loc`` and the message."""

    def __init__(self, loc: Sequence[str | int], message: str, *, type: str = "value_error") -> None:
        super().__init__(message)
        self.loc = tuple(loc)
        self.message = message
        self.type = type

    def detail(self) -> list[dict[str, Any]]:
        return [{"loc": list(self.loc), "msg": self.message, "type": self.type}]


def error_type(e: BaseException) -> str:
    """``InvalidPlantError`` -> ``invalid_plant``."""
    name = type(e).__name__.removesuffix("Error")
    out = "".join("_" + c.lower() if c.isupper() else c for c in name).lstrip("_")
    return out or "invalid"


def _plant_field(p: PlantIn, message: str) -> str:
    """Which field of a plant a library message is about."""
    low = message.lower()
    if low.startswith("delay"):
        return "delay"
    if low.startswith("dt") or "sample time dt" in low or "give its sample time" in low:
        return "dt"
    if p.expr is not None:
        return "expr"
    if low.startswith("num") or "numerator" in low:
        return "num"
    return "den"


def to_plant(p: PlantIn, loc: Loc) -> Plant:
    try:
        if p.expr is not None:
            plant = plant_from_expr(p.expr, dt=p.dt, delay=p.delay)
        else:
            plant = make_plant(p.num, p.den, dt=p.dt, delay=p.delay)
    except TunerError as e:
        raise FieldError((*loc, _plant_field(p, str(e))), str(e), type=error_type(e)) from e
    if not (np.all(np.isfinite(plant.num)) and np.all(np.isfinite(plant.den))):
        field = "expr" if p.expr is not None else "den"
        raise FieldError((*loc, field), "coefficients overflow when divided by the leading denominator coefficient; "
                         "rescale the model", type="invalid_plant")
    if p.dt is not None and not plant.is_discrete:  # plant_from_expr ignores dt for a plant in s
        raise FieldError((*loc, "dt"), "the plant is in s (continuous), so it has no sample time: leave plant.dt "
                         "null and give the controller sample time as the top-level dt", type="invalid_plant")
    return plant


def plant_dict(plant: Plant) -> dict[str, Any]:
    """The numbers the library accepted (what the worker rebuilds and what is stored)."""
    return {"num": [float(c) for c in plant.num], "den": [float(c) for c in plant.den],
            "dt": plant.dt, "delay": float(plant.delay_s)}


def check_loop_dt(plants: Sequence[tuple[Plant, Loc]], dt: float | None, *, structure: str | None) -> float | None:
    """The loop's sample time, or a FieldError naming ``dt`` or the plant that disagrees."""
    for plant, loc in plants:
        if plant.is_discrete and dt is not None and abs(plant.dt - dt) > 1e-9 * dt:
            raise FieldError(("body", "dt"), f"{_where(loc)} is discrete at dt={plant.dt} but dt={dt} was given; "
                             "a discrete plant is not resampled")
    discrete = [(p, loc) for p, loc in plants if p.is_discrete]
    if discrete and len({p.dt for p, _ in discrete}) > 1:
        p, loc = discrete[-1]
        raise FieldError((*loc, "dt"), f"plants are discrete at different sample times "
                         f"{sorted({q.dt for q, _ in discrete})}")
    loop_dt = dt if dt is not None else (discrete[0][0].dt if discrete else None)
    if structure is not None:
        st = get_structure(structure)
        if st.discrete_only and loop_dt is None:
            raise FieldError(("body", "dt"), f"structure {structure!r} is discrete: give the controller sample time dt")
    if loop_dt is not None:
        for plant, loc in plants:  # a continuous plant in a sampled loop: whole-sample delay
            if not plant.is_discrete and plant.delay_s:
                d = plant.delay_s / loop_dt
                if abs(d - round(d)) > 1e-6 * max(1.0, d):
                    raise FieldError((*loc, "delay"), f"delay {plant.delay_s} s is not a whole number of samples of "
                                     f"dt={loop_dt} s ({d:.4g} samples); give a multiple of dt")
    return loop_dt


def _where(loc: Loc) -> str:
    return "plant" if len(loc) == 2 else f"plants[{loc[-1]}]"


def to_controller(c: ControllerIn, dt: float | None, loc: Loc) -> ControllerTF:
    try:
        dt = check_dt(dt)
    except TunerError as e:
        raise FieldError(("body", "dt"), str(e), type=error_type(e)) from e
    if c.expr is not None:
        try:
            return controller_from_expr(c.expr, dt=dt)
        except TunerError as e:
            raise FieldError((*loc, "expr"), str(e), type=error_type(e)) from e
    if c.structure is not None:
        try:
            return controller_tf(c.structure, c.gains or {}, dt=dt)
        except TunerError as e:
            field = "structure" if "discrete" in str(e) else "gains"
            raise FieldError(("body", "dt") if field == "structure" else (*loc, field), str(e),
                             type=error_type(e)) from e
    num = np.trim_zeros(np.asarray(c.num, dtype=float), "f")
    den = np.trim_zeros(np.asarray(c.den, dtype=float), "f")
    if den.size == 0:
        raise FieldError((*loc, "den"), "den is zero: the denominator needs a non-zero coefficient")
    if num.size == 0:
        raise FieldError((*loc, "num"), "num is zero: the controller has no gain")
    if num.size > den.size:
        raise FieldError((*loc, "num"), f"improper controller: numerator degree {num.size - 1} > "
                         f"denominator degree {den.size - 1}; add a filter pole")
    return ControllerTF(num=num / den[0], den=den / den[0], dt=dt)


def spec_or_default(spec: Spec | None) -> Spec:
    return spec if spec is not None else Spec()


def tuner_error_loc(message: str, error: str) -> tuple[str, ...]:
    """Where a library error raised during the solve belongs (the route pre-checks the common ones)."""
    low = message.lower()
    if error == "InvalidSpecError" or low.startswith("spec"):
        return ("body", "spec")
    if "structure" in low:
        return ("body", "structure")
    if " dt" in low or low.startswith("dt"):
        return ("body", "dt")
    return ("body", "plant")
