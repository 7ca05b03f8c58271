"""``POST /identify`` (a record in, a fitted model out, stored) and the stored identifications:
``GET /identifications``, ``GET /identifications/{id}``, its plots and its data."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Body, Depends, HTTPException, Path, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, ConfigDict, Field

from tuner.jsonio import jsonable

from ..convert import FieldError, error_type
from ..deps import client_id, get_identify_job, get_identify_plot_job, get_plot_pool, get_pool, get_store
from ..jobrun import run_job
from ..pool import WorkerPool
from ..quota import check_identification_quota
from ..schemas_identify import (
    IDENTIFY_EXAMPLE,
    MAX_ULOG_BASE64,
    IdentificationData,
    IdentificationList,
    IdentificationRecordOut,
    IdentifyRequest,
    IdentifyResponse,
)
from ..settings import Settings, get_settings
from ..store import IdentificationRecord, Store
from .tune import ERRORS
from .tunes import NOT_FOUND, PLOT_ERRORS, UNAVAILABLE, draw_in_pool

__all__ = ["router"]

router = APIRouter(tags=["identification"])

_SAMPLES = ("input", "output", "time", "rate_hz")
IdentId = Path(min_length=1, max_length=64, description="the id returned by POST /identify")


def _check(body: IdentifyRequest) -> None:
    """Cross-field checks the schema cannot express, each naming its field."""
    if body.ulog is not None:
        for name in ("input", "output", "time", "reference"):
            if getattr(body, name) is not None:
                raise FieldError(("body", name), f"give either ulog or {name} (the samples come from the log; a "
                                 "reference: ulog.reference)")
        if body.time_unit != "auto":
            raise FieldError(("body", "time_unit"), "time_unit is the unit of time samples; a ulog's timestamps "
                                                    "are read as the log gives them")
    else:
        if body.input is None or body.output is None:
            raise FieldError(("body", "input" if body.input is None else "output"),
                             "give input and output samples (or a ulog log)")
        n = len(body.input)
        if len(body.output) != n:
            raise FieldError(("body", "output"), f"output has {len(body.output)} samples but input has {n}: give "
                                                 "equal-length records")
        if (body.time is None) == (body.rate_hz is None):
            raise FieldError(("body", "rate_hz" if body.time is None else "time"),
                             "give exactly one of time (sample times, s) or rate_hz (the sample rate)")
        if body.time is not None and len(body.time) != n:
            raise FieldError(("body", "time"), f"time has {len(body.time)} samples but input and output have {n}")
        if body.reference is not None and len(body.reference) != n:
            raise FieldError(("body", "reference"), f"reference has {len(body.reference)} samples but input and "
                             f"output have {n}")
    v = body.verify
    if v is not None:
        if len(v.output) != len(v.input):
            raise FieldError(("body", "verify", "output"), f"output has {len(v.output)} samples but input has "
                                                           f"{len(v.input)}")
        if v.time is not None and v.rate_hz is not None:
            raise FieldError(("body", "verify", "time"), "give at most one of time or rate_hz")
        if v.time is not None and len(v.time) != len(v.input):
            raise FieldError(("body", "verify", "time"), f"time has {len(v.time)} samples but input has "
                                                         f"{len(v.input)}")
    if body.zeros > body.poles:
        raise FieldError(("body", "zeros"), f"zeros={body.zeros} is more than poles={body.poles}: the model would "
                                            "be improper")
    if body.band is not None and not body.band[0] < body.band[1]:
        raise FieldError(("body", "band"), f"band must be [w_min, w_max] with w_min < w_max, got {body.band}")


def _ulog_bytes(body: IdentifyRequest) -> bytes | None:
    if body.ulog is None:
        return None
    import base64
    import binascii

    try:
        raw = base64.b64decode(body.ulog.data, validate=True)
    except (binascii.Error, ValueError):
        raise FieldError(("body", "ulog", "data"), "not base64 (standard alphabet, padded): encode the .ulg file, "
                                                   "e.g. base64 -w0 flight.ulg") from None
    return raw


@router.post(
    "/identify", response_model=IdentifyResponse, responses=ERRORS,
    summary="Identify a transfer function from a logged input/output record",
    description="Frequency response with coherence (Welch spectra, several windows composited), a model with "
                "`poles`/`zeros` and a delay fitted over the coherent band by CIFER's cost J, Cramér–Rao bounds of "
                "its parameters, and a time-domain check (on `verify`, the held-out end of the record, or the fitted "
                "record) judged against the noise floor, reported as `check` beside J's `quality`. The samples are "
                "JSON arrays, or a PX4 ULog log (`ulog`: base64 and the two TOPIC.FIELD signals). The result and the "
                "record are stored. Bad data (unequal lengths, non-finite values, a constant input, a record too "
                "short for the band, a time column that is not uniform, no coherent band): 422 naming the field.",
)
async def post_identify(
    body: Annotated[IdentifyRequest, Body(openapi_examples={
        "first-order lag": {"summary": "a sweep through 10/(s+10) with a 40 ms delay, 30 s at 50 Hz",
                            "value": IDENTIFY_EXAMPLE}})],
    request: Request,
    settings: Settings = Depends(get_settings),
    store: Store = Depends(get_store),
    pool: WorkerPool = Depends(get_pool),
    job: Callable[[dict[str, Any]], Any] = Depends(get_identify_job),
    client: str = Depends(client_id),
) -> JSONResponse:
    _check(body)
    # the quota before any work (a ULog upload's sample count is known only after parsing: checked again then)
    await run_in_threadpool(check_identification_quota, store, settings,
                            len(body.input) if body.input is not None else 0)
    options = body.model_dump(exclude={*_SAMPLES, "ulog", "verify", "reference"})
    hold = {"zoh": "zoh", "none": None}.get(options.pop("hold"), "zoh" if body.ulog is not None else None)
    raw = _ulog_bytes(body)
    if raw is not None:
        payload = {"ulog": {"data": raw, "input": body.ulog.input, "output": body.ulog.output,
                            "reference": body.ulog.reference},
                   "rate_hz": body.rate_hz, "hold": hold, **options}
    else:
        payload = {"input": np.asarray(body.input, dtype=float), "output": np.asarray(body.output, dtype=float),
                   "time": None if body.time is None else np.asarray(body.time, dtype=float),
                   "rate_hz": body.rate_hz, "hold": hold, **options}
        if body.reference is not None:
            payload["reference"] = np.asarray(body.reference, dtype=float)
    options["hold"] = "zoh" if hold else "none"
    if body.verify is not None:
        payload["verify"] = {k: np.asarray(v, dtype=float) if isinstance(v, list) else v
                             for k, v in body.verify.model_dump().items() if v is not None}
    result = await run_job(
        request, pool, job, payload, timeout_s=settings.identify_timeout_s, client=client, what="identification",
        loc=lambda f: ("body", *f), default_field=("input",),  # the library's path is the body's
        type_of=lambda info: error_type(info["error"]),
        timeout_detail=lambda e: f"the identification took longer than {settings.identify_timeout_s:g} s and was "
                                 "stopped; decimate the record or fit fewer poles")
    samples = result.pop("_samples", None)  # a ULog log's records on the grid
    log_parameters = result.pop("_parameters", None)  # and the parameters it stores (a tune's vehicle)
    if samples is not None:  # a ULog's samples are known now: they count against the quota as an array's do
        await run_in_threadpool(check_identification_quota, store, settings, int(result["n_samples"]))
        request = {**options, "n_samples": result["n_samples"], "sampling": "ulog",
                   "ulog": {"input": body.ulog.input, "output": body.ulog.output, "reference": body.ulog.reference,
                            "bytes": len(raw or b"")}}
        data = {"input": [x for r in samples["inputs"] for x in r],
                "output": [x for r in samples["outputs"] for x in r], "time": None, "rate_hz": samples["rate_hz"],
                "record_lengths": [len(r) for r in samples["inputs"]]}
    else:
        request = {**options, "n_samples": len(body.input),
                   "sampling": "time" if body.time is not None else "rate_hz"}
        data = {"input": body.input, "output": body.output, "time": body.time, "rate_hz": body.rate_hz}
    if body.verify is not None:
        request["verify"] = {"n_samples": len(body.verify.input)}
        data["verify"] = body.verify.model_dump()
    if body.reference is not None:
        data["reference"] = body.reference
    stored = {**result, "log_parameters": log_parameters} if log_parameters else result
    rec = await run_in_threadpool(store.add_identification, request=request, data=data, result=stored)
    return JSONResponse(jsonable({"id": rec.id, "created_at": rec.created_at.isoformat(), **result}))


class _ULogData(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)
    data: str = Field(min_length=16, max_length=MAX_ULOG_BASE64, description="the .ulg file, base64 (standard "
                      "alphabet, padded)")


@router.post("/ulog/signals", responses=ERRORS, summary="The signals and rate-law parameters a PX4 ULog log holds",
             description="Every numeric TOPIC[:INSTANCE].FIELD with its rate (what `ulog.input`, `ulog.output` and "
                         "`ulog.reference` of POST /identify may name), the rate law's parameters the log stores as "
                         "a QGroundControl .params text (`params_text`: a tune's `vehicle.params`) and the loop rate "
                         "they name. 422 at `ulog.data` for a body that is not base64 or not a ULog.")
async def post_ulog_signals(
    body: _ULogData, request: Request, settings: Settings = Depends(get_settings),
    pool: WorkerPool = Depends(get_pool), client: str = Depends(client_id),
) -> JSONResponse:
    import base64
    import binascii

    from ..jobs import ulog_signals_job

    try:
        raw = base64.b64decode(body.data, validate=True)
    except (binascii.Error, ValueError):
        raise FieldError(("body", "data"), "not base64 (standard alphabet, padded): encode the .ulg file, e.g. "
                                           "base64 -w0 flight.ulg") from None
    out = await run_job(
        request, pool, ulog_signals_job, {"data": raw}, timeout_s=settings.identify_timeout_s, client=client,
        what="log reading", loc=lambda f: ("body", "data"), default_field=("data",),
        type_of=lambda info: error_type(info["error"]),
        timeout_detail=lambda e: f"reading the log took longer than {settings.identify_timeout_s:g} s; cut the log")
    return JSONResponse(jsonable(out))


@router.get("/identifications", response_model=IdentificationList, summary="List stored identifications, newest first",
            tags=["results"], responses={401: NOT_FOUND[401], **UNAVAILABLE})
async def list_identifications(
    limit: int = Query(20, ge=1, le=100), offset: int = Query(0, ge=0, le=10**12),
    store: Store = Depends(get_store),
) -> JSONResponse:
    items, total = await run_in_threadpool(store.list_identifications, limit=limit, offset=offset)
    return JSONResponse(jsonable({
        "items": [{"id": r.id, "created_at": r.created_at.isoformat(), "poles": r.poles, "zeros": r.zeros,
                   "cost": r.cost, "quality": r.quality, "n_samples": r.n_samples} for r in items],
        "total": total, "limit": limit, "offset": offset,
    }))


async def _record(store: Store, ident_id: str, *, with_data: bool = False) -> IdentificationRecord:
    rec = await run_in_threadpool(lambda: store.get_identification(ident_id, with_data=with_data))
    if rec is None:
        raise HTTPException(404, f"no stored identification with id {ident_id!r}")
    return rec


@router.get("/identifications/{ident_id}", response_model=IdentificationRecordOut, responses=NOT_FOUND,
            tags=["results"], summary="One stored identification")
async def get_identification(ident_id: str = IdentId, store: Store = Depends(get_store)) -> JSONResponse:
    rec = await _record(store, ident_id)
    return JSONResponse(jsonable({"id": rec.id, "created_at": rec.created_at.isoformat(), **rec.result,
                                  "request": rec.request}))


@router.get("/identifications/{ident_id}/data", response_model=IdentificationData, responses=NOT_FOUND,
            tags=["results"], summary="The record an identification was made from, as submitted")
async def get_identification_data(ident_id: str = IdentId, store: Store = Depends(get_store)) -> JSONResponse:
    rec = await _record(store, ident_id, with_data=True)
    return JSONResponse(rec.data)


_PLOT_DOC = ("Bode plot of the data (coherent points in colour) and the fitted model, the fit points and the band, "
             "a coherence panel, and the held-out time-domain check.")


async def _plot(ident_id: str, fmt: str, store: Store, pool: WorkerPool, job: Callable[[dict[str, Any]], Any],
                settings: Settings, media: str) -> Response:
    rec = await _record(store, ident_id)
    img = await draw_in_pool(pool, job, {"result": rec.result, "fmt": fmt}, settings)
    scope = "private" if settings.api_key is not None else "public"  # as the tune plots
    return Response(img, media_type=media, headers={"Cache-Control": f"{scope}, max-age=86400"})


@router.get("/identifications/{ident_id}/plot.png", response_class=Response, tags=["results"],
            summary="Plot of a stored identification (PNG)", description=_PLOT_DOC,
            responses={**PLOT_ERRORS, 200: {"content": {"image/png": {}}}})
async def plot_png(ident_id: str = IdentId, store: Store = Depends(get_store),
                   pool: WorkerPool = Depends(get_plot_pool),
                   job: Callable[[dict[str, Any]], Any] = Depends(get_identify_plot_job),
                   settings: Settings = Depends(get_settings)) -> Response:
    return await _plot(ident_id, "png", store, pool, job, settings, "image/png")


@router.get("/identifications/{ident_id}/plot.svg", response_class=Response, tags=["results"],
            summary="Plot of a stored identification (SVG)", description=_PLOT_DOC,
            responses={**PLOT_ERRORS, 200: {"content": {"image/svg+xml": {}}}})
async def plot_svg(ident_id: str = IdentId, store: Store = Depends(get_store),
                   pool: WorkerPool = Depends(get_plot_pool),
                   job: Callable[[dict[str, Any]], Any] = Depends(get_identify_plot_job),
                   settings: Settings = Depends(get_settings)) -> Response:
    return await _plot(ident_id, "svg", store, pool, job, settings, "image/svg+xml")
