"""Service settings, from the environment (prefix ``TUNER_``), injected as a dependency.

=============================  ==========================  ==============================================
variable                       default                     meaning
=============================  ==========================  ==============================================
``TUNER_DATABASE_URL``         ``sqlite:///./tuner.db``    SQLAlchemy URL; e.g. ``postgresql+psycopg://
                                                           user@host:5432/db``
``TUNER_API_KEY``              unset                       if set, ``/tune``, ``/analyze`` and ``/tunes``
                                                           need a matching ``X-API-Key`` header
``TUNER_WORKERS``              number of usable CPUs       solver processes
``TUNER_QUEUE_SIZE``           ``2 * workers``             requests that may wait for a solver; beyond
                                                           workers + queue: 503 with ``Retry-After``
``TUNER_QUEUE_TIMEOUT_S``      ``30``                      longest wait for a free solver, then 503
``TUNER_DEFAULT_BUDGET_S``     ``10``                      solve budget when the request gives none
``TUNER_MAX_BUDGET_S``         ``60``                      largest budget a request may ask for (<= 60)
``TUNER_SOLVE_GRACE_S``        ``2``                       a solve is stopped (504) at budget + grace,
``TUNER_SOLVE_GRACE_FRACTION`` ``0.25``                    grace = GRACE_S + GRACE_FRACTION * budget
                                                           (the solver's final verification may overrun)
``TUNER_ANALYZE_TIMEOUT_S``    ``10``                      limit of one ``/analyze`` (then 504)
``TUNER_PLOT_TIMEOUT_S``       ``20``                      limit of drawing one plot (then 504)
``TUNER_MAX_BODY_BYTES``       ``1000000``                 larger request bodies: 413
``TUNER_MAX_IDENTIFY_BODY_BYTES`` ``24000000``             the same for ``POST /identify`` only (flight
                                                           logs: 200,000 samples of input, output and
                                                           time as JSON are about 13 MB)
``TUNER_IDENTIFY_TIMEOUT_S``   ``60``                      limit of one identification (then 504)
``TUNER_MAX_PLANTS``           ``20``                      plants per robust request (nominal included)
``TUNER_MAX_TASKS_PER_WORKER`` ``200``                     a solver process is replaced after this many jobs
``TUNER_START_METHOD``         ``forkserver``              how solver processes start (or ``spawn``)
``TUNER_WORKER_MEMORY_MB``     ``4096``                    address-space cap of one solver process; a
                                                           solve that needs more fails (500) instead of
                                                           exhausting the machine
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
    queue_size: int | None = Field(None, ge=0, le=10_000, description="default: 2 * workers")
    queue_timeout_s: float = Field(30.0, gt=0, le=3600)
    default_budget_s: float = Field(10.0, gt=0, le=MAX_BUDGET_S)
    max_budget_s: float = Field(MAX_BUDGET_S, gt=0, le=MAX_BUDGET_S)
    solve_grace_s: float = Field(2.0, ge=0, le=60)
    solve_grace_fraction: float = Field(0.25, ge=0, le=1)
    analyze_timeout_s: float = Field(10.0, gt=0, le=600)
    plot_timeout_s: float = Field(20.0, gt=0, le=600)
    worker_start_timeout_s: float = Field(120.0, gt=0)
    start_method: Literal["forkserver", "spawn"] = "forkserver"
    worker_memory_mb: int | None = Field(4096, ge=256, description="address-space cap of a solver process")
    max_tasks_per_worker: int | None = Field(200, ge=1)

    max_body_bytes: int = Field(1_000_000, ge=1024)
    max_identify_body_bytes: int = Field(24_000_000, ge=1024)
    identify_timeout_s: float = Field(60.0, gt=0, le=600)
    max_plants: int = Field(20, ge=1)

    @model_validator(mode="after")
    def _consistent(self) -> Settings:
        if self.default_budget_s > self.max_budget_s:
            raise ValueError(f"default_budget_s={self.default_budget_s} is above max_budget_s={self.max_budget_s}")
        return self

    def solve_limit_s(self, budget_s: float) -> float:
        """When a solve with this budget is stopped from outside."""
        return budget_s + self.solve_grace_s + self.solve_grace_fraction * budget_s

    @property
    def effective_queue_size(self) -> int:
        return 2 * self.workers if self.queue_size is None else self.queue_size


def get_settings(request: Request) -> Settings:
    """The app's settings (given to :func:`api.main.create_app`, else read from the environment)."""
    return request.app.state.settings
