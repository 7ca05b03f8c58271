"""Service settings, from the environment (prefix ``TUNER_``), injected as a dependency.

=============================  ==========================  ==============================================
variable                       default                     meaning
=============================  ==========================  ==============================================
``TUNER_DATABASE_URL``         ``sqlite:///./tuner.db``    SQLAlchemy URL; e.g. ``postgresql+psycopg://
                                                           user@host:5432/db``
``TUNER_API_KEY``              unset                       if set, ``/tune``, ``/analyze`` and ``/tunes``
                                                           need a matching ``X-API-Key`` header (one key
                                                           reads every result and log: keys are not scoped)
``TUNER_ALLOW_NO_KEY``         unset                       without a key, only connections to a loopback
                                                           address are answered (and ``python -m api``
                                                           does not start on another); ``1``: answer every
                                                           address without a key, on purpose (logged)
``TUNER_HEADER_TIMEOUT_S``     ``10``                      request headers must arrive within this from the
                                                           connection's start or its last answer, else 408
                                                           and closed (``python -m api``)
``TUNER_MAX_CONNECTIONS``      ``512``                     open connections; beyond: 503 and closed at
                                                           once (``python -m api``)
``TUNER_WORKERS``              number of usable CPUs       solver processes
``TUNER_QUEUE_SIZE``           ``16 * workers``            requests that may wait for a solver; beyond
                                                           workers + queue: 503 with ``Retry-After``
``TUNER_QUEUE_TIMEOUT_S``      ``60``                      longest wait for a free solver, then 503
``TUNER_MAX_INFLIGHT_PER_``    ``workers - 1`` (at least   solvers one client (API key, else address)
``CLIENT``                     1)                          holds at once; its further requests wait
                                                           behind other clients' (fair queue)
``TUNER_MAX_QUEUED_PER_``      ``queue size / 2`` (at      requests one client may have waiting; beyond
``CLIENT``                     least 1)                    that: 429 with ``Retry-After``
``TUNER_DEFAULT_BUDGET_S``     ``10``                      solve budget when the request gives none
``TUNER_MAX_BUDGET_S``         ``60``                      largest budget a request may ask for (<= 60)
``TUNER_SOLVE_GRACE_S``        ``2``                       a solve is stopped (504) at budget + grace,
``TUNER_SOLVE_GRACE_FRACTION`` ``0.25``                    grace = GRACE_S + GRACE_FRACTION * budget
                                                           (the solver's final verification may overrun)
``TUNER_ANALYZE_TIMEOUT_S``    ``10``                      limit of one ``/analyze`` (then 504)
``TUNER_PLOT_TIMEOUT_S``       ``20``                      limit of drawing one plot (then 504)
``TUNER_PLOT_WORKERS``         ``1``                       plot processes (apart from the solvers; run at
                                                           a lower CPU priority than the solvers)
``TUNER_PLOT_QUEUE_SIZE``      ``32``                      plot requests that may wait; beyond: 503
``TUNER_PLOT_CACHE_MB``        ``64``                      drawn plots kept in memory, per result id, kind
                                                           and format (results never change)
``TUNER_DB_RETRY_S``           ``5``                       while the database is unreachable at start-up,
                                                           the longest pause between two attempts
``TUNER_MAX_BODY_BYTES``       ``1000000``                 larger request bodies: 413
``TUNER_MAX_IDENTIFY_BODY_BYTES`` ``24000000``             the same for ``POST /identify`` and ``/ulog/signals`` (flight
                                                           logs: 200,000 samples of input, output and
                                                           time as JSON are about 13 MB)
``TUNER_IDENTIFY_TIMEOUT_S``   ``60``                      limit of one identification (then 504)
``TUNER_MAX_PLANTS``           ``20``                      plants per robust request (nominal included)
``TUNER_ALLOWED_HOSTS``        ``127.0.0.1,localhost,::1`` ``Host`` names served (comma-separated); others
                                                           get 400 (DNS rebinding); ``*``: any
``TUNER_BODY_TIMEOUT_S``       ``60``                      a request body must arrive within this, else 408
``TUNER_MAX_IDENTIFICATIONS``  ``1000``                    stored identifications; beyond: 507
``TUNER_MAX_IDENTIFICATION_``  ``20000000``                samples of all stored identifications' records
``SAMPLES``                                                together; beyond: 507
``TUNER_MAX_TASKS_PER_WORKER`` ``200``                     a solver process is replaced after this many jobs
``TUNER_START_METHOD``         ``forkserver``              how solver processes start (or ``spawn``)
``TUNER_WORKER_MEMORY_MB``     ``4096``                    address-space cap of one solver process; a
                                                           solve that needs more fails (500) instead of
                                                           exhausting the machine; a quarter of it holds
                                                           the solver's NLP build cache (the library's own
                                                           bound: ``TUNER_NLP_CACHE_MB``, 2048)
=============================  ==========================  ==============================================
"""

from __future__ import annotations

import os
from typing import Literal

from fastapi import Request
from pydantic import Field, SecretStr, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

__all__ = ["Settings", "get_settings", "MAX_BUDGET_S"]

MAX_BUDGET_S = 60.0  # the hard ceiling of the API (the request schema's limit)


def _cpus() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="TUNER_", extra="ignore", frozen=True)

    database_url: str = "sqlite:///./tuner.db"
    api_key: SecretStr | None = None

    workers: int = Field(default_factory=_cpus, ge=1, le=64)
    queue_size: int | None = Field(None, ge=0, le=10_000, description="default: 16 * workers")
    queue_timeout_s: float = Field(60.0, gt=0, le=3600)
    max_inflight_per_client: int | None = Field(None, ge=1, le=64, description="default: workers - 1 (>= 1)")
    max_queued_per_client: int | None = Field(None, ge=0, le=10_000, description="default: queue size / 2")
    default_budget_s: float = Field(10.0, gt=0, le=MAX_BUDGET_S)
    max_budget_s: float = Field(MAX_BUDGET_S, gt=0, le=MAX_BUDGET_S)
    solve_grace_s: float = Field(2.0, ge=0, le=60)
    solve_grace_fraction: float = Field(0.25, ge=0, le=1)
    analyze_timeout_s: float = Field(10.0, gt=0, le=600)
    plot_timeout_s: float = Field(20.0, gt=0, le=600)
    plot_workers: int = Field(1, ge=1, le=16)
    plot_queue_size: int = Field(32, ge=0, le=10_000)
    plot_cache_mb: float = Field(64.0, ge=0)
    db_retry_s: float = Field(5.0, gt=0, le=300)
    worker_start_timeout_s: float = Field(120.0, gt=0, description="how long the solver processes may take to "
                                          "start, and a job handed to a free solver to be started by it (else it "
                                          "is run again on fresh solvers)")
    start_method: Literal["forkserver", "spawn"] = "forkserver"
    worker_memory_mb: int | None = Field(4096, ge=256, description="address-space cap of a solver process")
    max_tasks_per_worker: int | None = Field(200, ge=1)

    max_body_bytes: int = Field(1_000_000, ge=1024)
    max_identify_body_bytes: int = Field(24_000_000, ge=1024)
    identify_timeout_s: float = Field(60.0, gt=0, le=600)
    max_plants: int = Field(20, ge=1)
    allowed_hosts: str = Field("127.0.0.1,localhost,::1", min_length=1,
                               description="Host names served, comma-separated; '*' for any")
    body_timeout_s: float = Field(60.0, gt=0, le=3600)
    allow_no_key: bool = Field(False, description="without a key, answer connections to any address (on purpose)")
    header_timeout_s: float = Field(10.0, gt=0, le=600, description="request headers must arrive within this")
    max_connections: int = Field(512, ge=1, le=100_000, description="open connections served at once")
    max_identifications: int = Field(1000, ge=0)
    max_identification_samples: int = Field(20_000_000, ge=0)

    @model_validator(mode="after")
    def _consistent(self) -> Settings:
        if self.default_budget_s > self.max_budget_s:
            raise ValueError(f"default_budget_s={self.default_budget_s} is above max_budget_s={self.max_budget_s}")
        return self

    @property
    def allowed_host_set(self) -> frozenset[str] | None:
        """The allowed ``Host`` names (lower case, no port), or ``None`` for any."""
        from .guard import host_name

        names = {host_name(h) for h in self.allowed_hosts.split(",") if h.strip()}
        return None if "*" in names else frozenset(names)

    def solve_limit_s(self, budget_s: float) -> float:
        """When a solve with this budget is stopped from outside."""
        return budget_s + self.solve_grace_s + self.solve_grace_fraction * budget_s

    @property
    def effective_queue_size(self) -> int:
        return 16 * self.workers if self.queue_size is None else self.queue_size

    @property
    def effective_max_inflight_per_client(self) -> int:
        """Solvers one client may hold: by default all but one, so that others always find one."""
        n = max(1, self.workers - 1) if self.max_inflight_per_client is None else self.max_inflight_per_client
        return min(n, self.workers)

    @property
    def effective_max_queued_per_client(self) -> int:
        q = self.effective_queue_size
        return max(1, q // 2) if self.max_queued_per_client is None else self.max_queued_per_client


def get_settings(request: Request) -> Settings:
    """The app's settings (given to :func:`api.main.create_app`, else read from the environment)."""
    return request.app.state.settings
