"""Dependencies: the store, the pools, the API key, the client's identity, and the functions run in the pools.

Tests replace any of them with ``app.dependency_overrides`` (e.g. a job function
that sleeps, to test the time limit, or one that kills its process).
"""

from __future__ import annotations

import hashlib
import secrets
from collections.abc import Callable
from typing import Any

from fastapi import Depends, HTTPException, Request, Security
from fastapi.security import APIKeyHeader

from .pool import WorkerPool
from .settings import Settings, get_settings
from .store import Store

__all__ = ["get_store", "get_pool", "get_plot_pool", "get_plot_cache", "require_api_key", "client_id", "client_key",
           "get_tune_job", "get_analyze_job", "get_plot_job", "get_identify_job", "get_identify_plot_job"]

_api_key_header = APIKeyHeader(name="X-API-Key", auto_error=False,
                               description="required when the server sets TUNER_API_KEY")


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_pool(request: Request) -> WorkerPool:
    return request.app.state.pool


def get_plot_pool(request: Request) -> WorkerPool:
    """The plot processes: apart from the solvers, so that drawing never takes a solver."""
    return request.app.state.plot_pool


def get_plot_cache(request: Request) -> Any:
    return request.app.state.plot_cache


def one_key(request: Request) -> None:
    """400 when the request carries several X-API-Key headers (the guard refuses them first; this holds for an app
    run without it): one credential, read once."""
    n = len(request.headers.getlist("x-api-key"))
    if n > 1:
        raise HTTPException(400, f"{n} X-API-Key headers: send exactly one")


def client_id(request: Request, key: str | None = Security(_api_key_header)) -> str:
    """Who asks, for the per-client limits: the client's address, with its API key's fingerprint if
    it sent one. The address is the one uvicorn reports (behind a proxy, run uvicorn with
    ``--proxy-headers --forwarded-allow-ips`` so that it is the client's, not the proxy's)."""
    one_key(request)
    return client_key(request.client.host if request.client is not None else "unknown", key)


def client_key(host: str, key: str | None) -> str:
    """:func:`client_id` from the address and the key (also used before the body is read, :mod:`api.guard`)."""
    if key:
        return f"key:{hashlib.sha256(key.encode()).hexdigest()[:12]}@{host}"
    return f"addr:{host}"


def require_api_key(
    request: Request, key: str | None = Security(_api_key_header), settings: Settings = Depends(get_settings)
) -> None:
    one_key(request)
    if settings.api_key is None:
        return
    expected = settings.api_key.get_secret_value().encode()
    if key is None or not secrets.compare_digest(key.encode(), expected):
        raise HTTPException(401, "missing or invalid X-API-Key header", headers={"WWW-Authenticate": "X-API-Key"})


def get_tune_job() -> Callable[[dict[str, Any]], Any]:
    from .jobs import tune_job

    return tune_job


def get_tradeoff_job() -> Callable[[dict[str, Any]], Any]:
    from .jobs import tradeoff_job

    return tradeoff_job


def get_analyze_job() -> Callable[[dict[str, Any]], Any]:
    from .jobs import analyze_job

    return analyze_job


def get_plot_job() -> Callable[[dict[str, Any]], Any]:
    from .jobs import plot_job

    return plot_job


def get_identify_job() -> Callable[[dict[str, Any]], Any]:
    from .jobs import identify_job

    return identify_job


def get_identify_plot_job() -> Callable[[dict[str, Any]], Any]:
    from .jobs import identify_plot_job

    return identify_plot_job
