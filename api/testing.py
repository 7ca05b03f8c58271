"""Job functions for tests of the pool's failure handling (used through ``dependency_overrides``).

They are ordinary module-level functions so that a solver process can import
them; nothing in the service calls them.
"""

from __future__ import annotations

import os
import time
from typing import Any

__all__ = ["spin_job", "crash_job", "sleep_job", "invalid_plant_job", "failing_job", "capped_tune_job",
           "wait_for_workers", "hog_job"]


def spin_job(payload: Any) -> None:
    """A runaway solve: burns CPU and ignores every budget."""
    x = 0
    while True:
        x += 1


def crash_job(payload: Any) -> None:
    """The worker process dies mid-job (as on a segfault)."""
    os._exit(1)


def sleep_job(payload: Any) -> dict[str, Any]:
    """Sleeps ``payload["time_budget_s"]`` (or 1 s) and returns a stub."""
    seconds = payload.get("time_budget_s", 1.0) if isinstance(payload, dict) else 1.0
    time.sleep(seconds)
    return {"slept_s": seconds}


def invalid_plant_job(payload: Any) -> None:
    """The library rejects the input inside the solver (as ``tune`` may, e.g. for an unusable plant)."""
    from tuner.errors import InvalidPlantError

    raise InvalidPlantError("plant cannot be tuned: test rejection raised in the solver", field=("plants", 0))


def failing_job(payload: Any) -> None:
    """A bug inside the solver (an exception that is not a TunerError)."""
    raise ZeroDivisionError("division by zero in a test job")


def capped_tune_job(payload: dict[str, Any]) -> Any:
    """The real tune, made quick for fuzzing many requests: budget <= 0.15 s, few trials, one local start."""
    from tuner.tuning import tune

    result = tune(payload["problem"], seed=payload["seed"], time_budget_s=min(0.15, payload["time_budget_s"]),
                  n_trials=6, n_starts=1)
    return result.to_json()


def wait_for_workers(client: Any, *, timeout_s: float = 120.0, headers: dict[str, str] | None = None) -> None:
    """Poll ``/health`` until every solver process is up (their start is not part of any time budget)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        w = client.get("/health", headers=headers or {}).json()["workers"]
        if w["ready"] + w["busy"] >= w["size"]:
            return
        time.sleep(0.1)
    raise TimeoutError("solver processes did not start")


def hog_job(payload: Any) -> None:
    """Asks for far more memory than any solve should (8 GiB at once)."""
    block = bytearray(8 * 1024**3)
    return len(block)
