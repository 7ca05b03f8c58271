"""Error answers: always JSON, never a traceback.

* 422: FastAPI's format, ``{"detail": [{"loc": [...], "msg": ..., "type": ...}]}``,
  for schema errors and for the library's :class:`~tuner.errors.TunerError`
  (located by :mod:`api.convert`); the input is not echoed back.
* 413, 429, 503, 504: ``{"detail": "..."}`` saying what happened and what to do; 429 and 503
  carry ``Retry-After`` (429: this client has as many requests waiting as it may; 503: every
  solver busy and the queue full, or the database unreachable).
* 499: the client closed the connection while its solve ran; the solve was cancelled
  (:mod:`api.disconnect`). Nobody receives it; the access log shows it.
* 500: ``{"detail": "internal error ..."}``; the traceback goes to the log only.
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from tuner.jsonio import jsonable

from .convert import FieldError
from .disconnect import CLIENT_CLOSED_REQUEST, ClientDisconnected
from .pool import ClientBusy, JobTimeout, PoolBusy, PoolClosed, WorkerCrashed
from .store import StoreError

__all__ = ["install_error_handlers", "validation_items", "internal_message"]

log = logging.getLogger("api")


def validation_items(errors: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for e in errors:
        msg = str(e.get("msg", "invalid"))
        out.append({"loc": [x if isinstance(x, int) else str(x) for x in e.get("loc", ())], "msg": msg,
                    "type": str(e.get("type", "value_error"))})
    return jsonable(out)


def internal_message(info: dict[str, Any], what: str) -> str:
    if info.get("error") == "MemoryError" or "bad_alloc" in str(info.get("message", "")):
        return f"the {what} ran out of its memory allowance (TUNER_WORKER_MEMORY_MB) and was stopped"
    return f"internal error in the {what} ({info.get('error')}); it has been logged"


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        return JSONResponse({"detail": validation_items(list(exc.errors()))}, status_code=422)

    @app.exception_handler(FieldError)
    async def _field(request: Request, exc: FieldError) -> JSONResponse:
        return JSONResponse({"detail": exc.detail()}, status_code=422)

    @app.exception_handler(ClientDisconnected)
    async def _gone(request: Request, exc: ClientDisconnected) -> JSONResponse:
        return JSONResponse({"detail": "the client closed the connection; the work was cancelled"},
                            status_code=CLIENT_CLOSED_REQUEST)

    @app.exception_handler(ClientBusy)  # before PoolBusy: handlers are looked up along the class's MRO
    async def _client_busy(request: Request, exc: ClientBusy) -> JSONResponse:
        return JSONResponse({"detail": f"{exc}; retry after {exc.retry_after_s} s"}, status_code=429,
                            headers={"Retry-After": str(exc.retry_after_s)})

    @app.exception_handler(PoolBusy)
    async def _busy(request: Request, exc: PoolBusy) -> JSONResponse:
        return JSONResponse({"detail": f"{exc}; retry after {exc.retry_after_s} s"}, status_code=503,
                            headers={"Retry-After": str(exc.retry_after_s)})

    @app.exception_handler(PoolClosed)
    async def _closed(request: Request, exc: PoolClosed) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=503, headers={"Retry-After": "5"})

    @app.exception_handler(StoreError)
    async def _store(request: Request, exc: StoreError) -> JSONResponse:
        log.error("storage error: %s", exc, exc_info=exc.__cause__)
        return JSONResponse({"detail": f"storage unavailable: {exc}; retry later"}, status_code=503,
                            headers={"Retry-After": "5"})

    @app.exception_handler(WorkerCrashed)
    async def _crashed(request: Request, exc: WorkerCrashed) -> JSONResponse:
        log.error("solver process crashed on %s %s", request.method, request.url.path)
        return JSONResponse({"detail": "the solver process crashed while working on this request; it has been "
                                       "replaced and the service goes on. Please report the request body."},
                            status_code=500)

    @app.exception_handler(JobTimeout)
    async def _timeout(request: Request, exc: JobTimeout) -> JSONResponse:  # routes phrase their own 504s
        return JSONResponse({"detail": f"the computation exceeded its time limit of {exc.limit_s:g} s and was "
                                       "stopped"}, status_code=504)

    @app.exception_handler(Exception)
    async def _internal(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return JSONResponse({"detail": "internal error; it has been logged"}, status_code=500)
