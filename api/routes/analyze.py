"""``POST /analyze``: verify a given controller on a plant (metrics, checks)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter, Body, Depends, Request
from fastapi.responses import JSONResponse

from tuner.jsonio import jsonable

from ..convert import FieldError, analysis_inputs, body_loc, law_gains, vehicle_of
from ..deps import client_id, get_analyze_job, get_pool, get_store
from ..jobrun import run_job
from ..pool import WorkerPool
from ..schemas import ROLL_ANALYZE_EXAMPLE, AnalyzeRequest, AnalyzeResponse
from ..settings import Settings, get_settings
from ..store import Store
from .tune import ERRORS, _identification

__all__ = ["router"]

router = APIRouter(tags=["analysis"])

_EXAMPLES = {
    "quadrotor roll": {"summary": "the thesis's digital PID on the roll model", "value": ROLL_ANALYZE_EXAMPLE},
    "structure and gains": {
        "summary": "a continuous PI given by its gains",
        "value": {"plant": {"expr": "0.2843*18.611/(s+18.611)"},
                  "controller": {"structure": "pi", "gains": {"Kp": 2.0, "Ki": 40.0}}},
    },
}


@router.post("/analyze", response_model=AnalyzeResponse, responses=ERRORS,
             summary="Verify a controller on a plant: margins, step metrics, spec checks")
async def post_analyze(
    body: Annotated[AnalyzeRequest, Body(openapi_examples=_EXAMPLES)],
    request: Request,
    settings: Settings = Depends(get_settings),
    pool: WorkerPool = Depends(get_pool),
    store: Store = Depends(get_store),
    job: Callable[[dict[str, Any]], Any] = Depends(get_analyze_job),
    client: str = Depends(client_id),
) -> JSONResponse:
    ident, record = await _identification(body, store)
    vehicle = vehicle_of(body, record)  # read once: the controller's fixed values and the law's gains both come from it
    plant, ctrl, spec, vehicle = analysis_inputs(body, vehicle, identification=ident)
    # (an identification is analysed as such: its model, and the loop on its measured response with their checks)
    payload = {"plant": plant if ident is None else ident, "controller": ctrl, "spec": spec}
    if body.actuator is not None:
        if ctrl.dt is None:
            raise FieldError(("body", "dt"), "actuator: the saturated step runs the law at its sample time: give dt "
                             "and the controller in z")
        c = body.controller
        gains = law_gains(body, vehicle, ctrl.dt) if c.structure is not None else None
        payload.update(actuator=body.actuator.to_actuator(), structure=c.structure, gains=gains)
    out = await run_job(
        request, pool, job, payload, timeout_s=settings.analyze_timeout_s, client=client, what="analysis",
        loc=body_loc, default_field=("controller",),
        timeout_detail=lambda e: f"the analysis took longer than {settings.analyze_timeout_s:g} s and was stopped")
    extra = {}
    if vehicle is not None and getattr(vehicle, "typed_plant", None) is not None:  # the gyro low-pass added, or not
        extra["vehicle"] = {"typed_plant": dict(vehicle.typed_plant)}
    return JSONResponse(jsonable({**out, "controller": ctrl.to_dict(), **extra}))

