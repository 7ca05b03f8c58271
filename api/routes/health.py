"""``GET /health``: liveness, database, solver pool, the NLPs' compiled code (background compiles pending),
library versions (no API key needed)."""

from __future__ import annotations

import logging
import platform
from functools import lru_cache
from importlib import metadata

from fastapi import APIRouter, Depends
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from ..deps import get_plot_cache, get_plot_pool, get_pool, get_store
from ..plotcache import PlotCache
from ..pool import WorkerPool
from ..schemas import HealthOut
from ..store import Store

__all__ = ["router", "versions"]

log = logging.getLogger("api.health")
_WARNED: list[bool] = []  # (the cache's read failure logged as a warning once per process)
router = APIRouter(tags=["service"])

_PACKAGES = ("tuner", "numpy", "scipy", "control", "casadi", "optuna", "fastapi", "pydantic", "sqlalchemy",
             "uvicorn", "matplotlib")


@lru_cache(maxsize=1)
def versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def nlp_code() -> dict[str, object]:
    """The solvers' NLP code cache (:func:`tuner.optimize.nlp.codecache.status`): the service's solver processes
    compile new problem shapes in the background without saying so; this says how many are pending. Information
    only: it never changes the status code. A few globs of the cache folder (codecache itself is light: no CasADi,
    and numpy is loaded already); in a thread, off the event loop, as the database's ping."""
    from tuner.optimize.nlp import codecache

    try:
        return codecache.status()
    except Exception as e:  # (a cache folder it cannot read: said, never a 500; logged once, not at every probe)
        (log.debug if _WARNED else log.warning)("/health: the NLP code cache could not be read: %s", e)
        _WARNED.append(True)
        return {"mode": codecache.mode(), "pending": None, "compiled": None, "marked": None,
                "error": f"the NLP code cache could not be read: {type(e).__name__}"}


@router.get("/health", response_model=HealthOut, summary="Service status and library versions",
            responses={503: {"model": HealthOut, "description": "the database is unreachable"}})
async def health(store: Store = Depends(get_store), pool: WorkerPool = Depends(get_pool),
                 plot_pool: WorkerPool = Depends(get_plot_pool),
                 plot_cache: PlotCache = Depends(get_plot_cache)) -> JSONResponse:
    db_ok = await run_in_threadpool(store.ping)
    body = {"status": "ok" if db_ok else "degraded", "database": "ok" if db_ok else "unreachable",
            "workers": pool.stats(), "plots": {**plot_pool.stats(), **{f"cache_{k}": v for k, v in
                                                                       plot_cache.stats().items()}},
            "nlp_code": await run_in_threadpool(nlp_code), "versions": versions()}
    return JSONResponse(body, status_code=200 if db_ok else 503)
