"""``POST /tune``: tune a controller, store the result, answer it with its id."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter, Body, Depends, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from tuner.errors import TunerError
from tuner.jsonio import jsonable
from tuner.robust import MC_SIGMA, MONTE_CARLO_DRAWS, check_spread

from ..convert import (
    FieldError,
    body_loc,
    plant_dict,
    request_budget,
    request_plant_limit,
    tuning_problem,
    vehicle_of,
)
from ..deps import client_id, get_pool, get_store, get_tune_job
from ..jobrun import run_job
from ..pool import WorkerPool
from ..schemas import ROLL_EXAMPLE, ErrorOut, TuneRequest, TuneResponse, ValidationErrorOut
from ..settings import Settings, get_settings
from ..store import Store

_SECONDS_PER_DRAW = 0.5  # the Monte Carlo check's allowance per draw (a verification), beyond the budget

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
    budget = request_budget(body, settings)
    limit = request_plant_limit(body, settings)
    ident, record = await _identification(body, store)
    vehicle = vehicle_of(body, record)
    problem, vehicle = tuning_problem(body, identification=ident, vehicle=vehicle)
    if ident is not None and len(problem.plants) > limit:
        raise FieldError(("body", "robust"), f"the identified model's robust set has {len(problem.plants)} plants; "
                         f"this server tunes at most {limit} per request: fit fewer parameters, or tune the nominal "
                         "model (robust null)")
    if body.actuator is not None and problem.dt is None:
        raise FieldError(("body", "dt"), "actuator: the saturated step runs the law at its sample time: give dt")
    payload = {"problem": problem, "seed": body.options.seed, "time_budget_s": budget, "effort": body.options.effort,
               "vehicle": vehicle, "actuator": None if body.actuator is None else body.actuator.to_actuator()}
    timeout_s = settings.solve_limit_s(budget)
    if ident is not None:
        n_mc = body.monte_carlo if body.monte_carlo is not None else (MONTE_CARLO_DRAWS if body.robust else 0)
        if n_mc:  # draws from bounds too wide are no plants of this airframe: refused before the solve
            try:
                check_spread(ident, MC_SIGMA, dt=problem.dt, field="monte_carlo")
            except TunerError as e:
                raise FieldError.of(e, ("body", "monte_carlo")) from None
        payload.update(identification=ident, robust=body.robust, monte_carlo=n_mc)
        timeout_s += _SECONDS_PER_DRAW * n_mc
    await run_in_threadpool(store.require_ready)  # no solve whose result could not be stored (503)
    retry = f"Retry with a larger options.time_budget_s (at most {settings.max_budget_s:g}) or a simpler structure."
    result = await run_job(
        request, pool, job, payload, timeout_s=timeout_s, client=client, what="solver",
        loc=body_loc,
        timeout_detail=lambda e: f"the solve did not finish within its time budget of {budget:g} s (stopped at "
                                 f"{e.limit_s:.3g} s, grace included); no verified result to return. {retry}",
        budget_detail=lambda info: f"nothing could be verified within the time budget of {budget:g} s "
                                   f"({info['message']}). {retry}")
    from tuner.controllers import deprecation_note

    note = deprecation_note(body.structure)
    if note and isinstance(result, dict) and isinstance(result.get("solver"), dict):  # pidf2: say it is pid_mf2
        result["solver"]["notes"] = [*result["solver"].get("notes", []), note]
    request = body.model_dump(mode="json")
    if ident is None:  # a plain request is stored as before
        for k in ("identification_id", "robust", "monte_carlo"):
            request.pop(k, None)
    for k, v in (("vehicle", vehicle), ("actuator", body.actuator)):
        if v is None:  # a request without them is stored as before
            request.pop(k, None)
    request.update(spec=problem.spec.model_dump(mode="json"), dt=problem.dt)
    request["options"]["time_budget_s"] = budget
    record = await run_in_threadpool(store.add, request=request, plants=[plant_dict(p) for p in problem.plants],
                                     result=result)
    return JSONResponse(jsonable({"id": record.id, "created_at": record.created_at.isoformat(), **result}))


async def _identification(body: Any, store: Store) -> tuple[Any, Any]:
    """The stored identification a /tune or /analyze body names (``identification_id``), as an IdentifyResult, and
    its record (both None without one); checks that the body gives exactly one of plant and identification_id, and
    robust/monte_carlo only with the latter."""
    if (body.plant is None) == (body.identification_id is None):
        raise FieldError(("body", "plant"), "give plant (a model) or identification_id (a stored identification, "
                         "POST /identify), not both" if body.plant is not None else "Field required: give plant (a "
                         "model) or identification_id (a stored identification, POST /identify)")
    if body.identification_id is None:
        for name in ("robust", "monte_carlo"):
            if getattr(body, name, None) is not None:
                raise FieldError(("body", name), f"{name} needs identification_id: the uncertainty of an identified "
                                 "model (POST /identify)")
        return None, None
    if getattr(body, "plants", None):
        raise FieldError(("body", "plants"), "plants with identification_id: the plant set comes from the "
                         "identification (robust); leave plants out")
    rec = await run_in_threadpool(store.get_identification, body.identification_id)
    if rec is None:
        raise FieldError(("body", "identification_id"), f"no stored identification with id "
                         f"{body.identification_id!r} (GET /identifications lists them)")
    from tuner.identify.result import IdentifyResult

    try:
        return IdentifyResult.from_dict(rec.result), rec
    except (TunerError, KeyError, TypeError, ValueError) as e:
        raise FieldError(("body", "identification_id"), f"the stored identification cannot be read: {e}") from None
