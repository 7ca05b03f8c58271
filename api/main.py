"""The tuning service. Start it with::

    uvicorn api.main:create_app --factory --host 127.0.0.1 --port 8000

Nothing heavy happens at import time: :func:`create_app` builds the routes, and
the app's lifespan opens the database (creating the table if needed) and starts
the solver processes; shutting down stops them.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI

from .settings import Settings

__all__ = ["create_app"]

log = logging.getLogger("api")

DESCRIPTION = """
Optimisation-based controller tuning with an independent verifier, as a service.

* `POST /tune`: a plant model (or several, for robust tuning), a controller structure and a
  specification in, verified gains and margins out; every result is stored.
* `POST /analyze`: verify a given controller on a plant.
* `GET /tunes`, `GET /tunes/{id}`, `GET /tunes/{id}/plot.png` / `.svg`: stored results.
* `POST /identify`: a logged input/output record in, a fitted transfer function out (frequency
  response with coherence, CIFER's cost J, Cramér–Rao bounds, a check on held-out data); stored,
  and listed by `GET /identifications`, `GET /identifications/{id}` (`/plot.png`, `/plot.svg`, `/data`).

Non-finite numbers are the strings `"Infinity"`, `"-Infinity"`, `"NaN"`
(e.g. an infinite gain margin: no phase crossover). Invalid input gets 422 with the field
named in `loc`. Solves run in a bounded pool of processes: past the time budget the best
verified result is returned, or 504 if the solver overran (it is stopped); when every solver
is busy and the queue is full, 503 with `Retry-After`.
"""


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app. ``settings`` default to the environment (``TUNER_*``)."""
    from .errors import install_error_handlers
    from .limits import BodySizeLimit
    from .routes import api_router, public_router

    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        from fastapi.concurrency import run_in_threadpool

        from .pool import WorkerPool
        from .store import Store

        store = Store(settings.database_url)
        await run_in_threadpool(store.create_schema)
        pool = WorkerPool(
            size=settings.workers, queue_size=settings.effective_queue_size,
            queue_timeout_s=settings.queue_timeout_s, start_timeout_s=settings.worker_start_timeout_s,
            max_tasks_per_worker=settings.max_tasks_per_worker, start_method=settings.start_method,
            memory_mb=settings.worker_memory_mb,
        )
        await pool.start()
        app.state.store, app.state.pool = store, pool
        log.info("tuner service: %d solver processes, database %s", settings.workers, store.backend)
        try:
            yield
        finally:
            await pool.close()
            store.dispose()

    app = FastAPI(
        title="tuner", version=_version(), description=DESCRIPTION, lifespan=lifespan,
        openapi_tags=[{"name": "tuning"}, {"name": "analysis"}, {"name": "identification"}, {"name": "results"},
                      {"name": "service"}],
    )
    app.state.settings = settings
    install_error_handlers(app)
    app.include_router(public_router)
    app.include_router(api_router)
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_body_bytes,
                       path_limits={"/identify": settings.max_identify_body_bytes})
    return app


def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("tuner")
    except metadata.PackageNotFoundError:  # pragma: no cover
        return "0"
