"""Request bodies -> library objects. The library validates; this module only says where.

Every :class:`tuner.errors.TunerError` carries ``field``, a path relative to what the library
was given (``("expr",)`` for a plant, ``("plants", 2, "delay")`` or ``("dt",)`` for a problem);
:func:`body_loc` turns it into the request-body location FastAPI uses (``["body", "plants", 1,
"delay"]``), answered as 422 by :class:`FieldError`. No message is read to find a field.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from tuner.controllers import ControllerTF, controller_from_coeffs, controller_from_expr, controller_tf
from tuner.errors import TunerError
from tuner.loop import build_loop
from tuner.plant import Plant, make_plant, plant_from_expr
from tuner.problem import TuningProblem
from tuner.spec import Spec

from .schemas import AnalyzeRequest, ControllerIn, PlantIn, TuneRequest

__all__ = ["FieldError", "error_type", "body_loc", "tuning_problem", "analysis_inputs", "plant_dict"]

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

    @classmethod
    def of(cls, e: TunerError, loc: Loc) -> FieldError:
        return cls(loc, str(e), type=error_type(e))


def error_type(e: BaseException | str) -> str:
    """``InvalidPlantError`` (an instance, or the class name) -> ``invalid_plant``."""
    name = (e if isinstance(e, str) else type(e).__name__).removesuffix("Error")
    out = "".join("_" + c.lower() if c.isupper() else c for c in name).lstrip("_")
    return out or "invalid"


_OPTIONS = ("seed", "time_budget_s", "effort")


def body_loc(field: Sequence[str | int]) -> Loc:
    """A problem-relative field path -> its place in a /tune or /analyze body.

    ``plants[0]`` is the body's ``plant``, ``plants[i]`` is ``plants[i-1]``; options live
    under ``options``; everything else is at the top level.
    """
    f = tuple(field)
    if f[:1] == ("plants",) and len(f) >= 2 and isinstance(f[1], int):
        return ("body", "plant", *f[2:]) if f[1] == 0 else ("body", "plants", f[1] - 1, *f[2:])
    if f[:1] == ("plants",):
        return ("body", "plants")
    if f[:1] and f[0] in _OPTIONS:
        return ("body", "options", *f)
    return ("body", *f) if f else ("body",)


def _plant(p: PlantIn, index: int) -> Plant:
    """The library's plant from one body plant (``index`` in the problem's plant list)."""
    try:
        if p.expr is not None:
            plant = plant_from_expr(p.expr, dt=p.dt, delay=p.delay)
        else:
            plant = make_plant(p.num, p.den, dt=p.dt, delay=p.delay)
    except TunerError as e:
        raise FieldError.of(e, body_loc(("plants", index, *e.field))) from None
    if p.dt is not None and not plant.is_discrete:  # the library takes an s-plant's dt as the loop's
        raise FieldError(body_loc(("plants", index, "dt")), "the plant is in s (continuous), so it has no sample "
                         "time: leave plant.dt null and give the controller sample time as the top-level dt",
                         type="invalid_plant")
    return plant


def request_budget(body: Any, settings: Any) -> float:
    """The solve's time budget of a /tune-like body (its own, or the server's default), within the server's
    maximum (422 at ``options.time_budget_s`` otherwise)."""
    budget = body.options.time_budget_s or settings.default_budget_s
    if budget > settings.max_budget_s:
        raise FieldError(("body", "options", "time_budget_s"),
                         f"time_budget_s={budget:g} is above this server's maximum of {settings.max_budget_s:g} s")
    return budget


def request_plant_limit(body: Any, settings: Any) -> int:
    """The most plants one request may tune (the server's and the library's limits); 422 at ``plants`` when the
    body (plant + plants) gives more."""
    from tuner.problem import MAX_PLANTS

    limit = min(settings.max_plants, MAX_PLANTS)
    n = 1 + len(body.plants or [])
    if n > limit:
        raise FieldError(("body", "plants"), f"{n} plants given (plant + plants); at most {limit} per request")
    return limit


def tuning_problem(body: TuneRequest, *, identification: Any = None) -> TuningProblem:
    """The validated problem of a /tune body (the one semantic validation of the request); with an
    ``identification`` (of ``identification_id``), its plant set (:func:`tuner.robust.plant_set`)."""
    if identification is not None:
        from tuner.robust import plant_set

        try:
            plants = plant_set(identification, body.robust, dt=body.dt)[0]
        except TunerError as e:
            raise FieldError.of(e, ("body", "robust") if e.field == ("robust",) else body_loc(e.field)) from None
    else:
        plants = [_plant(p, i) for i, p in enumerate([body.plant, *(body.plants or [])])]
    try:
        return TuningProblem.build(plants, structure=body.structure, spec=body.spec, dt=body.dt)
    except TunerError as e:
        raise FieldError.of(e, body_loc(e.field)) from None


def _controller(c: ControllerIn, dt: float | None) -> ControllerTF:
    if c.expr is not None:
        return controller_from_expr(c.expr, dt=dt)
    if c.structure is not None:
        return controller_tf(c.structure, c.gains or {}, dt=dt)
    return controller_from_coeffs(c.num, c.den, dt=dt)


def analysis_inputs(body: AnalyzeRequest) -> tuple[Plant, ControllerTF, Spec]:
    """Plant, controller (at ``dt``, else at a discrete plant's dt) and spec of an /analyze body, validated
    as one loop."""
    plant = _plant(body.plant, 0)
    dt = body.dt if body.dt is not None else plant.dt
    try:
        ctrl = _controller(body.controller, dt)
    except TunerError as e:
        loc = ("body", "dt") if e.field == ("dt",) else ("body", "controller", *e.field)
        raise FieldError.of(e, loc) from None
    try:
        build_loop(plant, ctrl)
    except TunerError as e:
        raise FieldError.of(e, body_loc(("plants", 0, *e.field[1:]) if e.field[:1] == ("plant",) else e.field)) \
            from None
    return plant, ctrl, body.spec if body.spec is not None else Spec()


def plant_dict(plant: Plant) -> dict[str, Any]:
    """The numbers the library accepted (what is stored, and redrawn in plots)."""
    return {"num": [float(c) for c in plant.num], "den": [float(c) for c in plant.den],
            "dt": plant.dt, "delay": float(plant.delay_s)}
