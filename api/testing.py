"""Job functions for tests of the pool's failure handling (used through ``dependency_overrides``).

They are ordinary module-level functions so that a solver process can import
them; nothing in the service calls them.
"""

from __future__ import annotations

import os
import time
from typing import Any

__all__ = ["spin_job", "spin_marked", "crash_job", "sleep_job", "invalid_plant_job", "unverified_job", "failing_job",
           "capped_tune_job", "wait_for_workers", "wait_until", "hog_job"]


def spin_job(payload: Any) -> None:
    """A runaway solve: burns CPU and ignores every budget (first creating ``payload["started_file"]``,
    if given, so that a test knows it runs)."""
    if isinstance(payload, dict) and payload.get("started_file"):
        with open(payload["started_file"], "w") as f:
            f.write(str(os.getpid()))
    x = 0
    while True:
        x += 1


def spin_marked(started_file: str, payload: Any) -> None:
    """:func:`spin_job` that writes its pid to ``started_file`` first (bind it with functools.partial)."""
    spin_job({"started_file": started_file})


def crash_job(payload: Any) -> None:
    """The worker process dies mid-job (as on a segfault)."""
    os._exit(1)


def sleep_job(payload: Any) -> dict[str, Any]:
    """Sleeps ``payload["time_budget_s"]`` (or 1 s) and returns a stub."""
    seconds = payload.get("time_budget_s", 1.0) if isinstance(payload, dict) else 1.0
    time.sleep(seconds)
    return {"slept_s": seconds}


def sleep_marked(started_file: str, seconds: float) -> int:
    """Writes its pid to ``started_file``, sleeps ``seconds`` and returns the pid (bind the file with
    functools.partial): a job a test can see running, on a solver it can name."""
    with open(started_file, "w") as f:
        f.write(str(os.getpid()))
    time.sleep(seconds)
    return os.getpid()


def invalid_plant_job(payload: Any) -> None:
    """The library rejects the input inside the solver (as ``tune`` may, e.g. for an unusable plant)."""
    from tuner.errors import InvalidPlantError

    raise InvalidPlantError("plant cannot be tuned: test rejection raised in the solver", field=("plants", 0))


def unverified_job(payload: Any) -> None:
    """The library found nothing it could verify within the budget (a TunerError that is a TimeoutError)."""
    from tuner.errors import TunerError

    class NothingVerifiedError(TunerError, TimeoutError):
        pass

    raise NothingVerifiedError("no candidate could be verified within the budget (test)")


def failing_job(payload: Any) -> None:
    """A bug inside the solver (an exception that is not a TunerError)."""
    raise ZeroDivisionError("division by zero in a test job")


def capped_tune_job(payload: dict[str, Any]) -> Any:
    """The real tune, made quick for fuzzing many requests: budget <= 0.15 s, few trials, one local start."""
    from tuner.tuning import tune

    result = tune(payload["problem"], seed=payload["seed"], time_budget_s=min(0.15, payload["time_budget_s"]),
                  n_trials=6, n_starts=1)
    return result.to_json()


def wait_until(cond: Any, *, timeout_s: float = 60.0, what: str = "condition") -> None:
    """Poll ``cond()`` until it is true: a wait for an event, the bound only there so that a bug cannot
    hang a test suite (no test asserts how long it took)."""
    end = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < end, f"{what}: not within {timeout_s:g} s"
        time.sleep(0.02)


def wait_for_workers(client: Any, *, timeout_s: float = 120.0, headers: dict[str, str] | None = None) -> None:
    """Poll ``/health`` until every solver and plot process is up (their start is no job's time)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        h = client.get("/health", headers=headers or {}).json()
        if all(w["ready"] + w["busy"] >= w["size"] for w in (h["workers"], h["plots"])):
            return
        time.sleep(0.1)
    raise TimeoutError("solver processes did not start")


def nlp_cache_job(payload: Any) -> float:
    """The solver's bound on its NLP build cache, MB."""
    from tuner.optimize.nlp import transcribe

    return transcribe.CACHE_MB


def hog_job(payload: Any) -> None:
    """Asks for far more memory than any solve should (8 GiB at once)."""
    block = bytearray(8 * 1024**3)
    return len(block)


# -- issue 11: the hand-found hostile requests (each answered < 500) --------------------------------------
# Used by tests/api/test_schemathesis.py (explicit cases) and bench/hostile.py (the campaign).

_P1 = {"expr": "1/(s+1)"}
_DEG80 = "(s+1)^40*(s+1)^40/((s+2)^40*(s+2)^40)"
HOSTILE_REQUESTS: list[tuple[str, str, dict[str, Any]]] = [
    # gains above ~1e155 and plant x controller products that overflow (500 before)
    *[("gain_" + f"{g:g}", "/analyze", {"plant": _P1, "controller": {"num": [g], "den": [1.0]}})
      for g in (1e155, 1e156, 1e200, 1e300, -1e300)],
    *[("pi_gain_" + f"{g:g}", "/analyze",
       {"plant": _P1, "controller": {"structure": "pi", "gains": {"Kp": g, "Ki": g}}})
      for g in (1e150, 1e200, 1e300)],
    ("pid_z_gain_1e300", "/analyze", {"plant": _P1, "dt": 0.1,
                                      "controller": {"structure": "pid_z", "gains": {"K": 1e300, "a1": -1, "a2": 0}}}),
    ("expr_gain_1e200", "/analyze", {"plant": _P1, "controller": {"expr": "1e200"}}),
    ("product_overflow", "/analyze", {"plant": {"num": [1e100], "den": [1e-100, 1.0]},
                                      "controller": {"num": [1e100, 1e100], "den": [1e-100, 1.0]}}),
    ("product_overflow_z", "/analyze", {"plant": {"num": [1e100], "den": [1e-100, 1.0]}, "dt": 0.01,
                                        "controller": {"num": [1e100, -1e100], "den": [1.0, -1.0]}}),
    # a degree-80 controller expression (accepted, then 500), and the coefficient form at the limit
    ("controller_expr_deg80", "/analyze", {"plant": _P1, "controller": {"expr": _DEG80}}),
    ("controller_coeffs_deg40", "/analyze", {"plant": _P1, "controller": {"num": [1.0], "den": [1.0] + [0.5] * 40}}),
    # inverted search bounds: lead/lag/leadlag at a large dt
    *[(f"{s}_dt{dt:g}", "/tune", {"plant": _P1, "dt": dt, "structure": s, "options": {"time_budget_s": 1}})
      for s in ("lead", "lag", "leadlag") for dt in (100.0, 1000.0, 10000.0)],
    ("lag_dt1000_slow_plant", "/tune", {"plant": {"expr": "1/(1000*s+1)"}, "dt": 1000, "structure": "lag",
                                        "options": {"time_budget_s": 1}}),
    # cost: slow plant with a tiny delay, long discrete delays, order 20, fine dt
    *[(f"slow_delay_{d:g}_{r}", r, {"plant": {"expr": "1/(1000*s+1)", "delay": d},
                                    **({"structure": "pi", "options": {"time_budget_s": 1}} if r == "/tune" else
                                       {"controller": {"structure": "pi", "gains": {"Kp": 1.0, "Ki": 0.001}}})})
      for d in (1e-6, 1e-5, 1e-3) for r in ("/analyze", "/tune")],
    ("delay_1e10_samples", "/tune", {"plant": {"expr": "1/(s+1)", "delay": 1e4}, "dt": 1e-6, "structure": "pi",
                                     "options": {"time_budget_s": 1}}),
    ("delay_201_samples", "/analyze", {"plant": {"expr": "1/(s+1)", "delay": 2.01}, "dt": 0.01,
                                       "controller": {"structure": "pi", "gains": {"Kp": 0.1, "Ki": 0.05}}}),
    ("order20_delay3", "/tune", {"plant": {"expr": "1/(s+1)^20", "delay": 3}, "structure": "pid",
                                 "options": {"time_budget_s": 1}}),
    ("order20_delay3_x3", "/tune", {"plant": {"expr": "1/(s+1)^20", "delay": 3}, "structure": "pid",
                                    "plants": [{"expr": "1/(1.1*s+1)^20", "delay": 3},
                                               {"expr": "1/(0.9*s+1)^20", "delay": 3}],
                                    "options": {"time_budget_s": 1}}),
    ("order20_dt0.001", "/tune", {"plant": {"expr": "1/(s+1)^20"}, "dt": 0.001, "structure": "pid_z",
                                  "options": {"time_budget_s": 0.5}}),
    ("order10_dt0.001", "/tune", {"plant": {"expr": "1/(s+1)^10"}, "dt": 0.001, "structure": "pid_z",
                                  "options": {"time_budget_s": 1}}),
    ("dt_min_order10", "/analyze", {"plant": {"expr": "1/(s+1)^10"}, "dt": 1e-6,
                                    "controller": {"structure": "pid_z", "gains": {"K": 1e-3, "a1": -1.9, "a2": 0.9}}}),
    ("dt_below_min", "/analyze", {"plant": _P1, "dt": 1e-9, "controller": {"expr": "1"}}),
    ("coeff_extremes", "/analyze", {"plant": {"num": [1e-100], "den": [1e100, 1e-100, 1e100]},
                                    "controller": {"num": [1e100, 1e-100], "den": [1e-100, 1e100]}}),
    ("pure_delay", "/analyze", {"plant": {"expr": "1", "delay": 1}, "dt": 0.1,
                                "controller": {"structure": "pi", "gains": {"Kp": 0.2, "Ki": 1.0}}}),
]
