"""The tuning service. Start it with::

    python -m api --host 127.0.0.1 --port 8000

(:mod:`api.server`: uvicorn with a header deadline and a connection cap; ``uvicorn api.main:create_app --factory``
serves the same app without them.)

Nothing heavy happens at import time: :func:`create_app` builds the routes, and the app's
lifespan starts the solver and plot processes and opens the database (creating the table if
needed); shutting down stops them. A database that is unreachable at start-up does not stop the
service: it starts, logs so, answers ``/health`` with 503 "database unreachable" and the routes
that need storage with 503, and retries in the background until the database is back.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import TYPE_CHECKING

from fastapi import FastAPI

from .settings import Settings

if TYPE_CHECKING:
    from .store import Store

__all__ = ["create_app"]

log = logging.getLogger("api")

DESCRIPTION = """
Optimisation-based controller tuning with an independent verifier, as a service.

* `POST /tune`: a plant model (or several, for robust tuning), a controller structure and a
  specification in, verified gains and margins out; every result is stored.
* `POST /analyze`: verify a given controller on a plant.
* `GET /tunes`, `GET /tunes/{id}`, `GET /tunes/{id}/plot.png` / `.svg`: stored results.
* `GET /tunes/{id}/export?format=c|python|text`: the stored controller as C99, a Python class or its
  difference equation (direct form II transposed; optional output limits with anti-windup).
* `POST /identify`: a logged input/output record (JSON samples, or a PX4 ULog log in base64) in, a fitted
  transfer function out (frequency response with coherence, CIFER's cost J, Cramér–Rao bounds, and a
  time-domain check judged against the noise floor, its verdict beside J's); stored,
  and listed by `GET /identifications`, `GET /identifications/{id}` (`/plot.png`, `/plot.svg`, `/data`).

Non-finite numbers are the strings `"Infinity"`, `"-Infinity"`, `"NaN"`
(e.g. an infinite gain margin: no phase crossover). Invalid input gets 422 with the field
named in `loc`. Solves run in a bounded pool of processes: past the time budget the best
verified result is returned (`solver.budget_exhausted` says so), or 504 if nothing could be
verified and the solver overran (it is stopped); when every solver is busy and the queue is full,
503 with `Retry-After`. One client (API key, else address) holds at most
`TUNER_MAX_INFLIGHT_PER_CLIENT` solvers at once (by default all but one); its further requests
wait behind other clients', and beyond `TUNER_MAX_QUEUED_PER_CLIENT` waiting ones it gets 429
with `Retry-After`. Plots are drawn in processes of their own and cached.
"""


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app. ``settings`` default to the environment (``TUNER_*``)."""
    from fastapi_offline import FastAPIOffline

    from .deps import client_key
    from .errors import install_error_handlers
    from .guard import Guard
    from .limits import BodySizeLimit, HeadAsGet
    from .routes import api_router, public_router

    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        from .jobs import PLOT_MODULES
        from .plotcache import PlotCache
        from .pool import WorkerPool
        from .store import Store

        store = Store(settings.database_url)
        pool = WorkerPool(
            size=settings.workers, queue_size=settings.effective_queue_size,
            queue_timeout_s=settings.queue_timeout_s, start_timeout_s=settings.worker_start_timeout_s,
            max_tasks_per_worker=settings.max_tasks_per_worker, start_method=settings.start_method,
            memory_mb=settings.worker_memory_mb, max_running_per_client=settings.effective_max_inflight_per_client,
            max_waiting_per_client=settings.effective_max_queued_per_client,
        )
        plot_pool = WorkerPool(
            size=settings.plot_workers, queue_size=settings.plot_queue_size, queue_timeout_s=settings.plot_timeout_s,
            start_timeout_s=settings.worker_start_timeout_s, max_tasks_per_worker=settings.max_tasks_per_worker,
            start_method=settings.start_method, memory_mb=settings.worker_memory_mb, warm=PLOT_MODULES, nice=5,
            max_running_per_client=settings.plot_workers,
            max_waiting_per_client=max(1, settings.plot_queue_size // 2),
        )
        await asyncio.gather(pool.start(), plot_pool.start())
        app.state.store, app.state.pool, app.state.plot_pool = store, pool, plot_pool
        app.state.plot_cache = PlotCache(int(settings.plot_cache_mb * 1024 * 1024))
        connecting = asyncio.get_running_loop().create_task(_connect(store, settings.db_retry_s))
        log.info("tuner service: %d solver processes, %d plot process(es), database %s", settings.workers,
                 settings.plot_workers, store.backend)
        if settings.api_key is None and settings.allow_no_key:
            log.warning("TUNER_ALLOW_NO_KEY: no API key, and connections to every address are answered: anyone who "
                        "reaches this service can tune, and read every stored result and log")
        elif settings.api_key is None:
            log.info("no TUNER_API_KEY: only connections to a loopback address are answered")
        try:
            yield
        finally:
            connecting.cancel()
            await asyncio.gather(pool.close(), plot_pool.close())
            store.dispose()

    # /docs and /redoc from the Swagger UI and ReDoc files shipped in fastapi-offline (no CDN: they work without
    # internet); the assets are served under /static-offline-docs, open like /docs. No online spec validator.
    app = FastAPIOffline(
        title="tuner", version=_version(), description=DESCRIPTION, lifespan=lifespan,
        swagger_ui_parameters={"validatorUrl": None},
        openapi_tags=[{"name": "tuning"}, {"name": "analysis"}, {"name": "identification"}, {"name": "results"},
                      {"name": "service"}],
    )
    app.state.settings = settings
    install_error_handlers(app)
    app.include_router(public_router)
    app.include_router(api_router)
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_body_bytes,
                       path_limits={"/identify": settings.max_identify_body_bytes,
                                    "/ulog/signals": settings.max_identify_body_bytes})
    app.add_middleware(HeadAsGet)
    # outermost: host, key and per-client limit from the headers before any body is read; body read timeout
    app.add_middleware(Guard, allowed_hosts=settings.allowed_host_set,
                       api_key=None if settings.api_key is None else settings.api_key.get_secret_value(),
                       body_timeout_s=settings.body_timeout_s, client_of=client_key,
                       pool_of=lambda: getattr(app.state, "pool", None),
                       loopback_only=settings.api_key is None and not settings.allow_no_key)
    return app


async def _connect(store: Store, max_pause_s: float) -> None:
    """Create the tables; while the database is unreachable, say so once and retry with back-off."""
    from .store import StoreError, reason

    pause, attempt = 0.25, 0
    while True:
        try:
            await asyncio.to_thread(store.create_schema)
        except StoreError as e:
            attempt += 1
            if attempt == 1:
                log.warning("database unreachable at start-up (%s): the service runs; /health answers 503 "
                            "\"database unreachable\" and storage routes 503 until it is back; retrying every "
                            "%g s at most", reason(e.__cause__), max_pause_s)
            await asyncio.sleep(pause)
            pause = min(max_pause_s, 2 * pause)
            continue
        if attempt:
            log.info("database reachable again after %d attempt(s): tables ready", attempt + 1)
        return


def _version() -> str:
    from tuner._lazy import installed_version

    return installed_version("0")
