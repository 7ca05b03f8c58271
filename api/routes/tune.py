"""``POST /tune``: tune a controller, store the result, answer it with its id."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter, Body, Depends, HTTPException, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from tuner.jsonio import jsonable
from tuner.problem import MAX_PLANTS

from ..convert import FieldError, body_loc, plant_dict, tuning_problem
from ..deps import client_id, get_pool, get_store, get_tune_job
from ..disconnect import unless_disconnected
from ..errors import internal_message
from ..pool import JobFailed, JobTimeout, WorkerPool
from ..schemas import ROLL_EXAMPLE, ErrorOut, TuneRequest, TuneResponse, ValidationErrorOut
from ..settings import Settings, get_settings
from ..store import Store

__all__ = ["router", "ERRORS"]

router = APIRouter(tags=["tuning"])

_EXAMPLES = {
    "quadrotor roll": {
        "summary": "quadrotor roll attitude, digital PID K(z^2+a1 z+a2)/(z(z-1)) at 25 Hz",
        "value": ROLL_EXAMPLE,
    },
    "yaw, continuous PI": {
        "summary": "quadrotor yaw model, continuous PI, default spec",
        "value": {"plant": {"expr": "0.2843*18.611/(s+18.611)"}, "structure": "pi",
                  "options": {"seed": 0, "time_budget_s": 5}},
    },
}

ERRORS: dict[int | str, dict[str, Any]] = {
    400: {"model": ErrorOut, "description": "the body could not be read (not UTF-8 text)"},
    401: {"model": ErrorOut, "description": "TUNER_API_KEY is set and X-API-Key is missing or wrong"},
    413: {"model": ErrorOut, "description": "request body too large"},
    422: {"model": ValidationErrorOut, "description": "invalid input; `loc` names the field"},
    500: {"model": ErrorOut, "description": "the solver failed internally or crashed (it is replaced); "
                                            "never an answer to invalid input"},
    429: {"model": ErrorOut, "description": "this client already has as many requests waiting as it may "
                                            "(TUNER_MAX_QUEUED_PER_CLIENT; see Retry-After)"},
    503: {"model": ErrorOut, "description": "every solver busy and the queue full (see Retry-After), "
                                            "or storage unavailable"},
    504: {"model": ErrorOut, "description": "nothing could be verified: the solve overran its time budget "
                                            "plus grace and was stopped"},
}


@router.post(
    "/tune", response_model=TuneResponse, responses=ERRORS, summary="Tune a controller on a plant (or a set)",
    description="Runs the seeded global search and the local NLP within `options.time_budget_s`, verifies the "
                "result independently and stores it. Non-finite numbers are the strings `Infinity`, `-Infinity`, "
                "`NaN`.",
)
async def post_tune(
    body: Annotated[TuneRequest, Body(openapi_examples=_EXAMPLES)],
    request: Request,
    settings: Settings = Depends(get_settings),
    store: Store = Depends(get_store),
    pool: WorkerPool = Depends(get_pool),
    job: Callable[[dict[str, Any]], Any] = Depends(get_tune_job),
    client: str = Depends(client_id),
) -> JSONResponse:
    budget = body.options.time_budget_s or settings.default_budget_s
    if budget > settings.max_budget_s:
        raise FieldError(("body", "options", "time_budget_s"),
                         f"time_budget_s={budget:g} is above this server's maximum of {settings.max_budget_s:g} s")
    limit = min(settings.max_plants, MAX_PLANTS)
    extra = body.plants or []
    if 1 + len(extra) > limit:
        raise FieldError(("body", "plants"),
                         f"{1 + len(extra)} plants given (plant + plants); at most {limit} per request")
    problem = tuning_problem(body)
    payload = {"problem": problem, "seed": body.options.seed, "time_budget_s": budget, "effort": body.options.effort}
    await run_in_threadpool(store.require_ready)  # no solve whose result could not be stored (503)
    try:
        result = await unless_disconnected(
            request, pool.run(job, payload, timeout_s=settings.solve_limit_s(budget), client=client))
    except JobTimeout as e:
        raise HTTPException(504, f"the solve did not finish within its time budget of {budget:g} s "
                                 f"(stopped at {e.limit_s:.3g} s, grace included); no verified result to "
                                 f"return. Retry with a larger options.time_budget_s (at most "
                                 f"{settings.max_budget_s:g}) or a simpler structure.") from None
    except JobFailed as e:
        if e.kind == "tuner_error" and e.info.get("timeout"):  # the library: nothing verified within the budget
            raise HTTPException(504, f"nothing could be verified within the time budget of {budget:g} s "
                                     f"({e.info['message']}). Retry with a larger options.time_budget_s (at most "
                                     f"{settings.max_budget_s:g}) or a simpler structure.") from None
        if e.kind == "tuner_error":
            raise FieldError(body_loc(e.info.get("field") or ()), e.info["message"], type="tuner_error") from None
        raise HTTPException(500, internal_message(e.info, "solver")) from None
    request = body.model_dump(mode="json")
    request.update(spec=problem.spec.model_dump(mode="json"), dt=problem.dt)
    request["options"]["time_budget_s"] = budget
    record = await run_in_threadpool(store.add, request=request, plants=[plant_dict(p) for p in problem.plants],
                                     result=result)
    return JSONResponse(jsonable({"id": record.id, "created_at": record.created_at.isoformat(), **result}))
