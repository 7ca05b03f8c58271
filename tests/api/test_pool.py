"""The bounded solver pool behind the routes: 504 on overrun (the solve really stops), 503 when
full, a crashed worker replaced, library errors from inside the solver answered as 422.

One worker and no queue, so that a single slow request fills the service. Misbehaving
solves are injected with ``dependency_overrides`` (functions in :mod:`api.testing`).
"""

from __future__ import annotations

import os
import threading
import time

import pytest
from quadrotor import DT, ROLL, ROLL_C, YAW

from api import testing
from api.deps import get_analyze_job, get_tune_job
from api.main import create_app
from api.settings import Settings
from api.testing import wait_for_workers

GRACE = 0.5  # s: budget + GRACE is when the service stops a solve
MARGIN = 1.5  # s: what answering may add to that (killing, replying); generous for a loaded CI machine


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    db = tmp_path_factory.mktemp("pool") / "tuner.db"
    settings = Settings(database_url=f"sqlite:///{db}", workers=1, queue_size=0, queue_timeout_s=60,
                        solve_grace_s=GRACE, solve_grace_fraction=0.0, analyze_timeout_s=30,
                        worker_memory_mb=2048)
    return create_app(settings)


@pytest.fixture
def inject(app, client):
    """Make the solver run ``fn`` instead of the tune job, for one test."""

    def apply(fn, dep=get_tune_job):
        app.dependency_overrides[dep] = lambda: fn

    yield apply
    app.dependency_overrides.pop(get_tune_job, None)
    app.dependency_overrides.pop(get_analyze_job, None)
    wait_for_workers(client)  # the next test starts with a warm worker, whatever this one killed


def tune_body(budget: float) -> dict:
    return {"plant": {"expr": YAW}, "dt": DT, "structure": "pi", "options": {"time_budget_s": budget}}


ANALYZE = {"plant": {"expr": ROLL}, "dt": DT, "controller": {"expr": ROLL_C}}


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a killed child not yet reaped is a zombie: not running
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_runaway_solve_is_stopped_and_answered_504_within_budget_plus_grace(app, client, inject):
    inject(testing.spin_job)
    (pid,) = app.state.pool.pids()
    budget = 0.5
    t0 = time.monotonic()
    r = client.post("/tune", json=tune_body(budget))
    elapsed = time.monotonic() - t0
    assert r.status_code == 504, r.text
    detail = r.json()["detail"]
    assert "time budget of 0.5 s" in detail and "stopped" in detail and "Traceback" not in r.text
    assert budget + GRACE <= elapsed + 0.05  # not cut before its limit
    assert elapsed < budget + GRACE + MARGIN  # but at it
    for _ in range(100):  # the runaway process is gone, not left burning a core
        if not alive(pid):
            break
        time.sleep(0.05)
    assert not alive(pid)
    assert app.state.pool.stats()["timeouts"] >= 1


def test_service_answers_again_after_a_504(client, inject):
    inject(testing.spin_job)
    assert client.post("/tune", json=tune_body(0.2)).status_code == 504
    r = client.post("/analyze", json=ANALYZE)  # a fresh worker takes the next request
    assert r.status_code == 200 and r.json()["meets_spec"] in (True, False)


def test_real_solve_past_its_budget_returns_the_best_verified_result(app, client):
    """``tune`` stops itself at its budget (its final verification may run on a little, which the
    default grace of 2 s + 25 % allows); the answer is a verified result, in time."""
    from api.settings import get_settings

    settings = app.state.settings.model_copy(update={"solve_grace_s": 2.0, "solve_grace_fraction": 0.25})
    app.dependency_overrides[get_settings] = lambda: settings
    budget = 1.0
    try:
        t0 = time.monotonic()
        r = client.post("/tune", json={"plant": {"expr": ROLL}, "dt": DT, "structure": "pid_z",
                                       "options": {"time_budget_s": budget}})
        elapsed = time.monotonic() - t0
    finally:
        app.dependency_overrides.pop(get_settings)
    assert r.status_code == 200, r.text
    assert elapsed < settings.solve_limit_s(budget) + MARGIN
    out = r.json()
    assert out["solver"]["wall_time_s"] < settings.solve_limit_s(budget)
    assert out["meets_spec"] == all(c["ok"] for c in out["checks"])
    assert out["failing"] == sorted(c["name"] for c in out["checks"] if not c["ok"])


def test_busy_service_answers_503_with_retry_after(client, inject):
    inject(testing.spin_job)
    first: dict = {}

    def slow():
        first["r"] = client.post("/tune", json=tune_body(2.0))

    t = threading.Thread(target=slow)
    t.start()
    try:
        pool = client.app.state.pool
        for _ in range(200):
            if pool.stats()["busy"] == 1:
                break
            time.sleep(0.02)
        assert pool.stats()["busy"] == 1
        r = client.post("/tune", json=tune_body(0.5))
        assert r.status_code == 503, r.text
        retry = int(r.headers["Retry-After"])
        assert 1 <= retry <= 60
        assert "busy" in r.json()["detail"] and "retry" in r.json()["detail"].lower()
        assert client.post("/analyze", json=ANALYZE).status_code == 503  # every CPU-bound route shares the pool
        assert client.get("/health").status_code == 200  # cheap routes still answer
        assert client.get("/tunes").status_code == 200
    finally:
        t.join(30)
    assert first["r"].status_code == 504


def test_crashed_worker_does_not_take_the_service_down(app, client, inject):
    inject(testing.crash_job)
    r = client.post("/tune", json=tune_body(1.0))
    assert r.status_code == 500
    assert "crashed" in r.json()["detail"] and "Traceback" not in r.text
    assert app.state.pool.stats()["crashes"] >= 1
    app.dependency_overrides.pop(get_tune_job)
    r = client.post("/tune", json=tune_body(0.5))  # waits for the replacement, then is served
    assert r.status_code == 200, r.text
    assert set(r.json()["gains"]) == {"Kp", "Ki"}


def test_library_error_inside_the_solver_is_422(client, inject):
    inject(testing.invalid_plant_job)
    r = client.post("/tune", json=tune_body(0.5))
    assert r.status_code == 422
    assert r.json()["detail"] == [{"loc": ["body", "plant"], "type": "tuner_error",
                                   "msg": "plant cannot be tuned: test rejection raised in the solver"}]


def test_bug_inside_the_solver_is_a_500_without_traceback(client, inject):
    inject(testing.failing_job, dep=get_analyze_job)
    r = client.post("/analyze", json=ANALYZE)
    assert r.status_code == 500
    assert r.json() == {"detail": "internal error in the analysis (ZeroDivisionError); it has been logged"}


def test_worker_killed_while_idle_costs_no_request(app, client):
    """E.g. the kernel's OOM killer took an idle solver: the next request gets a fresh one, not an error."""
    import signal

    (pid,) = app.state.pool.pids()
    os.kill(pid, signal.SIGKILL)  # a solver process this test's app started
    for _ in range(100):
        if not alive(pid):
            break
        time.sleep(0.02)
    r = client.post("/analyze", json=ANALYZE)
    assert r.status_code == 200, r.text
    assert pid not in app.state.pool.pids()


def test_memory_hungry_solve_fails_alone_and_the_next_request_is_served(app, client, inject):
    inject(testing.hog_job)
    (pid,) = app.state.pool.pids()
    r = client.post("/tune", json=tune_body(1.0))
    assert r.status_code == 500
    assert r.json() == {"detail": "the solver ran out of its memory allowance (TUNER_WORKER_MEMORY_MB) and was "
                                  "stopped"}
    app.dependency_overrides.pop(get_tune_job)
    r = client.post("/analyze", json=ANALYZE)
    assert r.status_code == 200
    assert pid not in app.state.pool.pids()  # the process that hit the cap was replaced
