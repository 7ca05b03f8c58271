"""Stored results: ``GET /tunes``, ``GET /tunes/{id}``, and its plots."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Path, Query
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, Response

from tuner.jsonio import jsonable

from ..deps import get_plot_job, get_pool, get_store
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
                503: {"model": ErrorOut, "description": "every solver busy (see Retry-After), or storage unavailable"},
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
                       settings: Settings) -> bytes:
    """Run a plot job in the solver pool: 504 past ``plot_timeout_s``, 500 if drawing failed."""
    try:
        return await pool.run(job, payload, timeout_s=settings.plot_timeout_s)
    except JobTimeout:
        raise HTTPException(504, f"drawing took longer than {settings.plot_timeout_s:g} s and was stopped") from None
    except JobFailed as e:
        raise HTTPException(500, f"the plot could not be drawn ({e.info.get('error')}); it has been logged") from None


async def _plot(rec: TuneRecord, fmt: str, pool: WorkerPool, job: Callable[[dict[str, Any]], Any],
                settings: Settings) -> bytes:
    gains = ", ".join(f"{k}={v:.4g}" for k, v in rec.result.get("gains", {}).items())
    payload = {"plants": rec.plants, "controller": rec.result["controller"], "spec": rec.result["spec"],
               "fmt": fmt, "title": f"{rec.structure}: {gains}" + ("" if rec.meets_spec else " (spec NOT met)")}
    return await draw_in_pool(pool, job, payload, settings)


_PLOT_DOC = ("Step response (continuous output, and the samples as markers) and Bode plot of the open loop with "
             "the phase and gain margins marked; all plants of a robust tune, the nominal one solid.")


@router.get("/{tune_id}/plot.png", response_class=Response, summary="Plot of a stored result (PNG)",
            description=_PLOT_DOC, responses={**PLOT_ERRORS, 200: {"content": {"image/png": {}}}})
async def plot_png(tune_id: str = TuneId, store: Store = Depends(get_store), pool: WorkerPool = Depends(get_pool),
                   job: Callable[[dict[str, Any]], Any] = Depends(get_plot_job),
                   settings: Settings = Depends(get_settings)) -> Response:
    rec = await _record(store, tune_id)
    return Response(await _plot(rec, "png", pool, job, settings), media_type="image/png",
                    headers={"Cache-Control": "public, max-age=86400"})


@router.get("/{tune_id}/plot.svg", response_class=Response, summary="Plot of a stored result (SVG)",
            description=_PLOT_DOC, responses={**PLOT_ERRORS, 200: {"content": {"image/svg+xml": {}}}})
async def plot_svg(tune_id: str = TuneId, store: Store = Depends(get_store), pool: WorkerPool = Depends(get_pool),
                   job: Callable[[dict[str, Any]], Any] = Depends(get_plot_job),
                   settings: Settings = Depends(get_settings)) -> Response:
    rec = await _record(store, tune_id)
    return Response(await _plot(rec, "svg", pool, job, settings), media_type="image/svg+xml",
                    headers={"Cache-Control": "public, max-age=86400"})
