"""``GET /tunes/{id}/export``: a stored result's controller as C99, a Python class or its difference equation."""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter, Depends, Query
from fastapi.responses import PlainTextResponse, Response

from tuner.errors import TunerError
from tuner.firmware.registry import by_format, firmwares, formats

from ..convert import FieldError, error_type
from ..deps import get_store
from ..store import Store
from .tunes import NOT_FOUND, TuneId, _record

__all__ = ["router"]

router = APIRouter(prefix="/tunes", tags=["results"])

_DOC = ("The stored controller as it runs on the target, in direct form II transposed, double precision: `c` is "
        "C99 (`N_state`, `void N_init(N_state *s)`, `double N_update(N_state *s, double e)` returning u), "
        "`python` a standalone class `N` with `update(e)`, `text` the difference equation. e = r - y. A result "
        "tuned at a sample time is exported as it is; a continuous one needs `dt` and is discretised by `method` "
        "(`tustin`, `zoh`, or `structure`: the structure's own discretisation). `u_min`/`u_max` clamp the output; "
        "a controller with integral action then gets anti-windup by conditional integration (the integrator, "
        "split off by partial fractions, is held while integrating would drive the saturated output further). "
        "A 2-DOF `pid2` result takes r and y: `double N_update(N_state *s, double r, double y)` (Python "
        "`update(r, y)`), D on c r - y (c = 0: on the measurement), anti-windup by `anti_windup` (conditional "
        "integration or back-calculation with tracking time `tt`). The header of the text says all of this. "
        "`px4` and `ardupilot` give a `px4_rate` / `ardupilot_rate` result as the parameter file its ground station "
        "loads (QGroundControl `.params`, Mission Planner `.parm`) for the result's axis (another `axis` is a 422; "
        "without a vehicle, `axis`, default roll), every value as the firmware stores it (float32) and inside its "
        "documented range; a design that does not meet its spec (or meets it on the model only), or a value outside "
        "its range, needs `force=true` (a 422 at `force` otherwise), and the file's header then says so. "
        "422 (with `loc`) for a bad format, name, dt, method or limits.")
_SUFFIX = {"c": "c", "python": "py", "text": "txt", **{f.export_format: f.suffix for f in firmwares()}}
#: c, python, text and every registered firmware's parameter file (tuner.firmware.registry)
ExportFormat = Literal[("c", "python", "text", *formats())]  # type: ignore[valid-type]
_FORMAT_DOC = f"c, python or text; {' or '.join(formats())}: a rate law's parameter file"
_QUERY = {"name", "dt", "method", "u_min", "u_max", "format", "anti_windup", "tt"}


@router.get("/{tune_id}/export", response_class=Response, summary="A stored controller as code", description=_DOC,
            responses={**NOT_FOUND, 200: {"content": {"text/plain": {"schema": {"type": "string"}}}}})
async def export_tune(
    tune_id: str = TuneId,
    format: ExportFormat = Query(
        ..., description=_FORMAT_DOC),
    axis: Literal["roll", "pitch", "yaw"] | None = Query(None, description="a firmware's parameter file: the axis "
                                                          "(default: the tune's vehicle's, else roll)"),
    name: str = Query("controller", min_length=1, max_length=56, description="a C identifier: N_state, N_init, "
                      "N_update, and the Python class"),
    dt: float | None = Query(None, description="sample time, s: needed for a continuous result"),
    method: Literal["tustin", "zoh", "structure"] = Query("tustin", description="discretisation of a continuous "
                                                                                 "result"),
    u_min: float | None = Query(None, description="lower output limit"),
    u_max: float | None = Query(None, description="upper output limit"),
    anti_windup: Literal["conditional", "back_calculation"] = Query(
        "conditional", description="pid2 results (N_update(s, r, y)): conditional integration or back-calculation "
        "with tracking time tt (default sqrt(Ti Td), Ti for a PI); 1-DOF controllers: conditional"),
    tt: float | None = Query(None, description="back-calculation tracking time, s (>= dt)"),
    force: bool = Query(False, description="px4/ardupilot: write the file even for a design that does not meet its "
                        "spec (or meets it on the model only), or with a value outside the documented range; the "
                        "header says so"),
    store: Store = Depends(get_store),
) -> PlainTextResponse:
    from tuner.export import check_name, equation_of, render
    from tuner.export.source import clamp_note

    try:
        check_name(name)
    except TunerError as e:
        raise FieldError(("query", "name"), str(e), type=error_type(e)) from None
    rec = await _record(store, tune_id)
    if by_format(format) is not None:
        return _param_file(rec.result, format, axis, force, {"dt": dt, "u_min": u_min, "u_max": u_max, "tt": tt})
    if force:
        raise FieldError(("query", "force"), f"force: only for format {' or '.join(formats())} (a parameter file)")
    try:
        de = equation_of(rec.result, dt=dt, method=method, u_min=u_min, u_max=u_max, anti_windup=anti_windup, tt=tt)
        text = render(de, format, name)
        note = clamp_note(rec.result, u_min, u_max)
    except TunerError as e:
        f = str(e.field[0]) if e.field else ""
        if f not in _QUERY:  # the stored controller with these limits (the only choice left to the caller)
            f = "u_min" if u_min is not None else "u_max" if u_max is not None else "dt"
        raise FieldError(("query", f), str(e), type=error_type(e)) from None
    headers = {"Content-Disposition": f'inline; filename="{name}.{_SUFFIX[format]}"'}
    if note:  # in the source too (a comment), and as a header for the page and scripts
        text = f"{ {'c': '// ', 'python': '# '}.get(format, '')}WARNING: {note}\n{text}"
        headers["X-Tuner-Warning"] = note
    return PlainTextResponse(text, headers=headers)


def _param_file(result: dict, format: str, axis: str | None, force: bool, unused: dict) -> PlainTextResponse:
    from tuner.export.paramfile import clean, make_param_file

    for k, v in unused.items():
        if v is not None:
            raise FieldError(("query", k), f"{k}: not for format {format} (a parameter file holds the law's gains)")
    try:
        pf = make_param_file(result, format, axis=axis, force=force)
    except TunerError as e:
        f = str(e.field[0]) if e.field else "format"
        # the choice the caller has: the axis, force (the verdict, a value outside its range), else the format
        forceable = f == "force" or (f == "gains" and "--force" in str(e))
        loc = "axis" if f == "axis" else "force" if forceable else "format"
        raise FieldError(("query", loc), str(e), type=error_type(e)) from None
    headers = {"Content-Disposition": f'attachment; filename="{pf.name}"'}
    if pf.warnings:  # in the header of the file too; here for the page and scripts (one line)
        headers["X-Tuner-Warning"] = clean("; ".join(pf.warnings), 2000)
    return PlainTextResponse(pf.text, headers=headers)
