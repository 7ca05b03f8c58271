"""``POST /tradeoff``: the speed/robustness trade-off curve (:mod:`tuner.tradeoff`), every point verified."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse

from tuner.jsonio import jsonable

from ..convert import FieldError, body_loc, request_budget, request_plant_limit, tuning_problem, vehicle_of
from ..deps import client_id, get_pool, get_tradeoff_job
from ..jobrun import run_job
from ..pool import WorkerPool
from ..schemas import TradeoffRequest, TradeoffResponse
from ..settings import Settings, get_settings
from .tune import ERRORS

__all__ = ["router"]

router = APIRouter(tags=["tuning"])


@router.post(
    "/tradeoff", response_model=TradeoffResponse, responses=ERRORS,
    summary="The speed/robustness trade-off curve: verified optima from the fastest design to the most robust",
    description="Point k is the minimum-settling design with `y` (Mks or the control peak) at most m_k, the "
                "limits falling geometrically from the fastest design's value towards the floor no design passes; "
                "every point meets the rest of the spec and is verified; settling increases strictly along it. "
                "`options.time_budget_s` is the budget of the whole curve.",
)
async def post_tradeoff(
    body: TradeoffRequest,
    request: Request,
    settings: Settings = Depends(get_settings),
    pool: WorkerPool = Depends(get_pool),
    job: Callable[[dict[str, Any]], Any] = Depends(get_tradeoff_job),
    client: str = Depends(client_id),
) -> JSONResponse:
    budget = request_budget(body, settings)
    request_plant_limit(body, settings)
    if body.spec is not None and body.spec.objective not in ("settling_time", "auto"):
        raise FieldError(("body", "spec", "objective"), "the trade-off's speed axis is the settling time: leave "
                         "spec.objective at settling_time")
    for f in ("identification_id", "robust", "monte_carlo"):
        if getattr(body, f, None) is not None:
            raise FieldError(("body", f), f"/tradeoff takes a plant (and plants); {f} is for POST /tune: tune the "
                             "identification there, or give its model as plant")
    if body.plant is None:
        raise FieldError(("body", "plant"), "give the plant: {\"expr\": \"...\"} or {\"num\": [...], \"den\": [...]}")
    problem, _ = tuning_problem(body, vehicle=vehicle_of(body))  # a firmware law bound to its vehicle
    payload = {"problem": problem, "y": body.y, "points": body.points, "seed": body.options.seed,
               "time_budget_s": budget}
    result = await run_job(
        request, pool, job, payload, timeout_s=settings.solve_limit_s(budget), client=client, what="solver",
        loc=body_loc,
        timeout_detail=lambda e: f"the curve did not finish within its time budget of {budget:g} s (stopped at "
                                 f"{e.limit_s:.3g} s); retry with a larger options.time_budget_s or fewer points")
    return JSONResponse(jsonable(result))
