"""Stored results: ``GET /tunes``, ``GET /tunes/{id}``, and its plots."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal

from fastapi import APIRouter, Depends, HTTPException, Path, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, Response

from tuner.jsonio import jsonable

from ..deps import client_id, get_plot_cache, get_plot_job, get_plot_pool, get_store
from ..plotcache import PlotCache
from ..pool import JobFailed, JobTimeout, WorkerPool
from ..schemas import ErrorOut, TuneList, TuneRecordOut
from ..settings import Settings, get_settings
from ..store import Store, TuneRecord

__all__ = ["router", "draw_in_pool", "NOT_FOUND", "PLOT_ERRORS", "UNAVAILABLE"]

router = APIRouter(prefix="/tunes", tags=["results"])

UNAVAILABLE = {503: {"model": ErrorOut, "description": "storage unavailable (see Retry-After)"}}
NOT_FOUND = {404: {"model": ErrorOut, "description": "no stored result with this id"},
              401: {"model": ErrorOut, "description": "TUNER_API_KEY is set and X-API-Key is missing or wrong"},
              **UNAVAILABLE}
PLOT_ERRORS = {**NOT_FOUND,
                500: {"model": ErrorOut, "description": "the plot could not be drawn"},
                429: {"model": ErrorOut, "description": "this client has as many plot requests waiting as it may "
                                                        "(see Retry-After)"},
                503: {"model": ErrorOut, "description": "every plot process busy (see Retry-After), or storage "
                                                        "unavailable"},
                504: {"model": ErrorOut, "description": "drawing overran its time limit"}}
TuneId = Path(min_length=1, max_length=64, description="the id returned by POST /tune")


@router.get("", response_model=TuneList, summary="List stored results, newest first",
            responses={401: NOT_FOUND[401], **UNAVAILABLE})
async def list_tunes(
    limit: int = Query(20, ge=1, le=100), offset: int = Query(0, ge=0, le=10**12),
    store: Store = Depends(get_store),
) -> JSONResponse:
    items, total = await run_in_threadpool(store.list, limit=limit, offset=offset)
    return JSONResponse({
        "items": [{"id": r.id, "created_at": r.created_at.isoformat(), "structure": r.structure,
                   "meets_spec": r.meets_spec} for r in items],
        "total": total, "limit": limit, "offset": offset,
    })


async def _record(store: Store, tune_id: str) -> TuneRecord:
    rec = await run_in_threadpool(store.get, tune_id)
    if rec is None:
        raise HTTPException(404, f"no stored tune result with id {tune_id!r}")
    return rec


@router.get("/{tune_id}", response_model=TuneRecordOut, responses=NOT_FOUND, summary="One stored result")
async def get_tune(tune_id: str = TuneId, store: Store = Depends(get_store)) -> JSONResponse:
    rec = await _record(store, tune_id)
    return JSONResponse(jsonable({"id": rec.id, "created_at": rec.created_at.isoformat(), **rec.result,
                                  "request": rec.request}))


async def draw_in_pool(pool: WorkerPool, job: Callable[[dict[str, Any]], Any], payload: dict[str, Any],
                       settings: Settings, client: str = "") -> bytes:
    """Run a plot job in the plot pool: 504 past ``plot_timeout_s``, 500 if drawing failed."""
    try:
        return await pool.run(job, payload, timeout_s=settings.plot_timeout_s, client=client)
    except JobTimeout:
        raise HTTPException(504, f"drawing took longer than {settings.plot_timeout_s:g} s and was stopped") from None
    except JobFailed as e:
        raise HTTPException(500, f"the plot could not be drawn ({e.info.get('error')}); it has been logged") from None


async def _draw(rec: TuneRecord, kind: str, fmt: str, pool: WorkerPool, job: Callable[[dict[str, Any]], Any],
                settings: Settings, client: str) -> bytes:
    gains = ", ".join(f"{k}={v:.4g}" for k, v in rec.result.get("gains", {}).items())
    payload = {"plants": rec.plants, "controller": rec.result["controller"], "spec": rec.result["spec"],
               "kind": kind, "fmt": fmt,
               "title": f"{rec.structure}: {gains}" + ("" if rec.meets_spec else " (spec NOT met)")}
    return await draw_in_pool(pool, job, payload, settings, client)


_PLOT_DOC = ("`kind=step`: the step response (the output between samples as a line, at the samples as markers) "
             "with the settling band, the overshoot limit and the control signal u(t) below; `kind=bode`: the "
             "open loop with the phase and gain margins marked; `kind=nyquist`: with the unit circle and the "
             "1/Ms circle around -1; `kind=all` (default): the three side by side. Every plant of a robust tune "
             "is drawn and labelled, the nominal one bold. Drawn (`tuner.analysis.plots`) in a process apart "
             "from the solvers and cached per result, kind and format (a stored result never changes): `ETag` "
             "and `If-None-Match` are honoured; `Cache-Control` is `private` when the server needs an API key.")
_MEDIA = {"png": "image/png", "svg": "image/svg+xml"}
PlotKind = Query("all", description="which plot: step (with u(t)), bode, nyquist, or all three")
Kind = Literal["all", "step", "bode", "nyquist"]


async def _plot_response(request: Request, tune_id: str, kind: str, fmt: str, store: Store, pool: WorkerPool,
                         cache: PlotCache, job: Callable[[dict[str, Any]], Any], settings: Settings,
                         client: str) -> Response:
    from importlib import metadata

    rec = await _record(store, tune_id)
    try:
        version = metadata.version("tuner")
    except metadata.PackageNotFoundError:  # pragma: no cover
        version = "0"
    etag = f'"{rec.id}.{kind}.{fmt}.{version}"'
    scope = "private" if settings.api_key is not None else "public"
    headers = {"Cache-Control": f"{scope}, max-age=86400, immutable", "ETag": etag}
    if etag in [t.strip() for t in request.headers.get("if-none-match", "").split(",")]:
        return Response(status_code=304, headers=headers)
    data = await cache.get_or_draw((rec.id, kind, fmt), lambda: _draw(rec, kind, fmt, pool, job, settings, client))
    return Response(data, media_type=_MEDIA[fmt], headers=headers)


@router.get("/{tune_id}/plot.png", response_class=Response, summary="Plot of a stored result (PNG)",
            description=_PLOT_DOC, responses={**PLOT_ERRORS, 200: {"content": {"image/png": {}}}})
async def plot_png(request: Request, tune_id: str = TuneId, kind: Kind = PlotKind, store: Store = Depends(get_store),
                   pool: WorkerPool = Depends(get_plot_pool), cache: PlotCache = Depends(get_plot_cache),
                   job: Callable[[dict[str, Any]], Any] = Depends(get_plot_job),
                   settings: Settings = Depends(get_settings), client: str = Depends(client_id)) -> Response:
    return await _plot_response(request, tune_id, kind, "png", store, pool, cache, job, settings, client)


@router.get("/{tune_id}/plot.svg", response_class=Response, summary="Plot of a stored result (SVG)",
            description=_PLOT_DOC, responses={**PLOT_ERRORS, 200: {"content": {"image/svg+xml": {}}}})
async def plot_svg(request: Request, tune_id: str = TuneId, kind: Kind = PlotKind, store: Store = Depends(get_store),
                   pool: WorkerPool = Depends(get_plot_pool), cache: PlotCache = Depends(get_plot_cache),
                   job: Callable[[dict[str, Any]], Any] = Depends(get_plot_job),
                   settings: Settings = Depends(get_settings), client: str = Depends(client_id)) -> Response:
    return await _plot_response(request, tune_id, kind, "svg", store, pool, cache, job, settings, client)
