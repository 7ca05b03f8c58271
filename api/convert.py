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

__all__ = ["FieldError", "error_type", "body_loc", "tuning_problem", "analysis_inputs", "plant_dict", "vehicle_of",
           "bound_structure", "law_gains"]

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


def _vehicle_loc(e: TunerError) -> Loc:
    """Where a vehicle's error lies in the body: its parameters, or the field it contradicts."""
    if e.field in (("vehicle",), ("params",)) or e.field[:1] == ("params",):
        return ("body", "vehicle")
    return body_loc(e.field)


def vehicle_of(body: Any, identification_record: Any = None) -> Any:
    """The :class:`~tuner.firmware.params.VehicleParams` of a /tune or /analyze body's ``vehicle`` (None without one):
    parsed from its ``params`` text, or from the parameters stored with the identification it names."""
    v = getattr(body, "vehicle", None)
    if v is None:
        return None
    from tuner.firmware.bind import FIRMWARE_OF, law_choices
    from tuner.firmware.params import vehicle_from_text

    structure = body.structure if hasattr(body, "structure") else getattr(body.controller, "structure", None)
    if structure not in FIRMWARE_OF:
        raise FieldError(("body", "vehicle"), f"vehicle sets a firmware rate law's fixed values; the structure is "
                         f"{structure!r}: use {law_choices()}")
    firmware = FIRMWARE_OF[structure]
    if v.from_identification:
        params = None if identification_record is None else (identification_record.result or {}).get(
            "log_parameters")
        if not params:
            raise FieldError(("body", "vehicle", "from_identification"), "the identification named by "
                             "identification_id was not made from a ULog with stored parameters: give "
                             "vehicle.params (the text of the vehicle's .params or .parm file)")
        text, fmt, source = params, "ulog", "the ULog's parameters"
    else:
        text, fmt, source = v.params, None, "vehicle.params"
    try:
        return vehicle_from_text(text, fmt=fmt, axis=v.axis, firmware=firmware, source=source)
    except TunerError as e:
        raise FieldError(("body", "vehicle", "params" if v.params is not None else "from_identification"), str(e),
                         type=error_type(e)) from None


def bound_structure(body: Any, vehicle: Any) -> tuple[Any, float | None]:
    """The body's structure (a firmware law bound to ``vehicle``'s fixed values) and the loop's dt (the vehicle's
    loop rate unless the body gives dt, which must agree)."""
    if vehicle is None:
        return body.structure, body.dt
    from tuner.firmware.bind import bind_law

    try:
        st, dt, _ = bind_law(body.structure, vehicle, body.dt, field="vehicle")
    except TunerError as e:
        raise FieldError.of(e, _vehicle_loc(e)) from None
    return st, dt


def typed(plants: list[Plant], vehicle: Any) -> tuple[list[Plant], Any]:
    """Typed plants (the request's own, not an identification's) for a vehicle: its gyro low-pass added to each and
    said in the vehicle's record (:func:`tuner.firmware.bind.typed_plant`), as the command line and ``tune()`` do."""
    if vehicle is None or not getattr(vehicle, "firmware", None):
        return plants, vehicle
    import dataclasses

    from tuner.firmware.bind import typed_plant

    out, rec = [], None
    for p in plants:
        q, rec = typed_plant(p, vehicle)
        out.append(q)
    if rec is None:
        return plants, vehicle
    return out, dataclasses.replace(vehicle, typed_plant=rec, notes=(*vehicle.notes, rec["note"]))


def tuning_problem(body: TuneRequest, *, identification: Any = None, vehicle: Any = None
                   ) -> tuple[TuningProblem, Any]:
    """The validated problem of a /tune body (the one semantic validation of the request) and the vehicle as tuned
    for; with an ``identification`` (of ``identification_id``), its plant set (:func:`tuner.robust.plant_set`); with
    a ``vehicle`` (:func:`vehicle_of`), the firmware law bound to it at its loop rate, and typed plants with its gyro
    low-pass (:func:`typed`)."""
    structure, dt = bound_structure(body, vehicle)
    if identification is not None:
        from tuner.robust import plant_set

        try:
            plants = plant_set(identification, body.robust, dt=dt)[0]
        except TunerError as e:
            raise FieldError.of(e, ("body", "robust") if e.field == ("robust",) else body_loc(e.field)) from None
    else:
        plants, vehicle = typed([_plant(p, i) for i, p in enumerate([body.plant, *(body.plants or [])])], vehicle)
    try:
        return TuningProblem.build(plants, structure=structure, spec=body.spec, dt=dt), vehicle
    except TunerError as e:
        loc = body_loc(e.field)
        if identification is not None and loc[1:2] in (("plant",), ("plants",)):
            loc = ("body", "identification_id")  # the plants are the identification's: the request has no plant
        raise FieldError.of(e, loc) from None


def _controller(c: ControllerIn, dt: float | None, vehicle: Any = None) -> ControllerTF:
    if c.expr is not None:
        return controller_from_expr(c.expr, dt=dt)
    if c.structure is not None:
        if vehicle is not None:  # a firmware law on this vehicle: the gains not given are its current ones
            from tuner.firmware.bind import bind_law

            st, dt, now = bind_law(c.structure, vehicle, dt, field="vehicle")
            return st.tf({**now, **(c.gains or {})}, dt)
        return controller_tf(c.structure, c.gains or {}, dt=dt)
    return controller_from_coeffs(c.num, c.den, dt=dt)


def law_gains(body: AnalyzeRequest, vehicle: Any, dt: float | None) -> dict[str, float]:
    """The gains of an /analyze body's structure as the law runs them: a firmware law on a vehicle has the
    vehicle's current gains for those the body leaves out, and its fixed values."""
    gains = dict(body.controller.gains or {})
    if vehicle is None:
        return gains
    from tuner.firmware.bind import bind_law

    _, _, now = bind_law(body.controller.structure, vehicle, dt, field="vehicle")
    return {**now, **gains}


def analysis_inputs(body: AnalyzeRequest, vehicle: Any = None, identification: Any = None
                    ) -> tuple[Plant, ControllerTF, Spec, Any]:
    """Plant, controller (at ``dt``, else at a discrete plant's dt, else the vehicle's loop rate), spec and vehicle
    (a typed plant's gyro low-pass said in its record: :func:`typed`) of an /analyze body, validated as one loop;
    ``vehicle``: the body's (:func:`vehicle_of`), read once by the caller; ``identification`` (of
    ``identification_id``): its fitted model is the plant."""
    if identification is not None:
        plant = identification.plant()
    else:
        [plant], vehicle = typed([_plant(body.plant, 0)], vehicle)
    dt = body.dt if body.dt is not None else plant.dt
    if dt is None and vehicle is not None and getattr(vehicle, "loop_hz", None):
        dt = 1.0 / float(vehicle.loop_hz)
    try:
        ctrl = _controller(body.controller, dt, vehicle)
    except FieldError:
        raise
    except TunerError as e:
        if e.field[:1] == ("vehicle",) or e.field[:1] == ("structure",):
            raise FieldError.of(e, ("body", "vehicle") if e.field[:1] == ("vehicle",) else
                                ("body", "controller", "structure")) from None
        loc = ("body", "dt") if e.field == ("dt",) else ("body", "controller", *e.field)
        raise FieldError.of(e, loc) from None
    try:
        build_loop(plant, ctrl)
    except TunerError as e:
        if identification is not None and e.field[:1] == ("plant",):
            raise FieldError.of(e, ("body", "identification_id")) from None
        raise FieldError.of(e, body_loc(("plants", 0, *e.field[1:]) if e.field[:1] == ("plant",) else e.field)) \
            from None
    return plant, ctrl, body.spec if body.spec is not None else Spec(), vehicle


def plant_dict(plant: Plant) -> dict[str, Any]:
    """The numbers the library accepted (what is stored, and redrawn in plots)."""
    return {"num": [float(c) for c in plant.num], "den": [float(c) for c in plant.den],
            "dt": plant.dt, "delay": float(plant.delay_s)}
