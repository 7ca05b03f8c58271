"""``POST /analyze``: verify a given controller on a plant (metrics, checks)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter, Body, Depends, HTTPException, Request
from fastapi.responses import JSONResponse

from tuner.jsonio import jsonable

from ..convert import FieldError, analysis_inputs, body_loc
from ..deps import client_id, get_analyze_job, get_pool
from ..disconnect import unless_disconnected
from ..errors import internal_message
from ..pool import JobFailed, JobTimeout, WorkerPool
from ..schemas import ROLL_ANALYZE_EXAMPLE, AnalyzeRequest, AnalyzeResponse
from ..settings import Settings, get_settings
from .tune import ERRORS

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
    job: Callable[[dict[str, Any]], Any] = Depends(get_analyze_job),
    client: str = Depends(client_id),
) -> JSONResponse:
    plant, ctrl, spec = analysis_inputs(body)
    payload = {"plant": plant, "controller": ctrl, "spec": spec}
    try:
        out = await unless_disconnected(
            request, pool.run(job, payload, timeout_s=settings.analyze_timeout_s, client=client))
    except JobTimeout:
        raise HTTPException(504, f"the analysis took longer than {settings.analyze_timeout_s:g} s and was "
                                 "stopped") from None
    except JobFailed as e:
        if e.kind == "tuner_error":
            raise FieldError(body_loc(e.info.get("field") or ("controller",)), e.info["message"],
                             type="tuner_error") from None
        raise HTTPException(500, internal_message(e.info, "analysis")) from None
    return JSONResponse(jsonable({**out, "controller": ctrl.to_dict()}))
