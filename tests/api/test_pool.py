"""The bounded solver pool behind the routes: 504 on overrun (the solve really stops), 503 when
full, a crashed worker replaced, library errors from inside the solver answered as 422, solvers
that end with the service.

One worker and no queue, so that a single slow request fills the service. Misbehaving
solves are injected with ``dependency_overrides`` (functions in :mod:`api.testing`). No test
asserts a duration: each waits for events (a process gone, a file written, a counter moved) with
generous bounds.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import pytest
from quadrotor import DT, ROLL, ROLL_C, YAW

from api import testing
from api.deps import get_analyze_job, get_tune_job
from api.main import create_app
from api.settings import Settings
from api.testing import wait_for_workers, wait_until

GRACE = 0.5  # s: budget + GRACE is when the service stops a solve
ROOT = Path(__file__).resolve().parents[2]


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
    except (FileNotFoundError, ProcessLookupError):  # reaped between the two looks (opened, then gone: ESRCH)
        return False


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_runaway_solve_is_stopped_and_answered_504(app, client, inject, tmp_path):
    started = tmp_path / "started"
    inject(_with_marker(started))
    body = tune_body(0.5)
    timeouts = app.state.pool.stats()["timeouts"]
    r = client.post("/tune", json=body)
    assert r.status_code == 504, r.text
    detail = r.json()["detail"]
    assert "time budget of 0.5 s" in detail and "stopped" in detail and "Traceback" not in r.text
    pid = int(started.read_text())  # the process that ran the runaway job
    assert not alive(pid)  # pebble stops (and reaps) the process before it answers the timeout
    assert app.state.pool.stats()["timeouts"] == timeouts + 1


def _with_marker(path):
    """The spin job, told to write its pid to ``path`` first (a partial is picklable by reference)."""
    import functools

    return functools.partial(testing.spin_marked, str(path))


def test_a_job_inside_its_limit_is_not_cut(client, inject):
    inject(testing.sleep_job)  # sleeps its budget, 0.2 s, well inside budget + grace
    r = client.post("/tune", json=tune_body(0.2))
    assert r.status_code == 200, r.text
    assert r.json()["slept_s"] == 0.2


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_service_answers_again_after_a_504(client, inject):
    from tuner.analysis.verify import analyze
    from tuner.controllers import ControllerTF
    from tuner.plant import plant_from_expr
    from tuner.spec import Spec

    inject(testing.spin_job)
    assert client.post("/tune", json=tune_body(0.2)).status_code == 504
    r = client.post("/analyze", json=ANALYZE)  # a fresh worker takes the next request
    assert r.status_code == 200, r.text
    out = r.json()
    ctrl = out["controller"]
    import numpy as np

    direct = analyze(plant_from_expr(ROLL, dt=DT), ControllerTF(num=np.array(ctrl["num"]), den=np.array(ctrl["den"]),
                                                               dt=ctrl["dt"]), Spec())
    assert out["meets_spec"] == direct.meets_spec
    assert out["metrics"]["phase_margin_deg"] == pytest.approx(direct.metrics.phase_margin_deg, rel=1e-9)


def test_real_solve_with_a_budget_returns_a_verified_result(app, client):
    """``tune`` stops itself at its budget with its best verified result (its final verification may run
    on a little, which the default grace of 2 s + 25 % allows): 200, a result the verifier confirms."""
    from api.settings import get_settings

    settings = app.state.settings.model_copy(update={"solve_grace_s": 2.0, "solve_grace_fraction": 0.25})
    app.dependency_overrides[get_settings] = lambda: settings
    try:
        r = client.post("/tune", json={"plant": {"expr": ROLL}, "dt": DT, "structure": "pid_z",
                                       "options": {"time_budget_s": 1.0}})
    finally:
        app.dependency_overrides.pop(get_settings)
    assert r.status_code == 200, r.text
    out = r.json()
    assert isinstance(out["solver"]["budget_exhausted"], bool)
    c = out["controller"]
    check = client.post("/analyze", json={"plant": {"expr": ROLL}, "dt": DT,
                                          "controller": {"num": c["num"], "den": c["den"]}})
    assert check.status_code == 200, check.text
    assert check.json()["meets_spec"] == out["meets_spec"]
    assert check.json()["metrics"]["settling_time_s"] == pytest.approx(out["metrics"]["settling_time_s"], rel=1e-9)
    assert out["failing"] == sorted(c["name"] for c in out["checks"] if not c["ok"])


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_busy_service_answers_503_with_retry_after(client, inject):
    inject(testing.spin_job)
    first: dict = {}

    def slow():
        first["r"] = client.post("/tune", json=tune_body(2.0))

    t = threading.Thread(target=slow)
    t.start()
    try:
        pool = client.app.state.pool
        wait_until(lambda: pool.stats()["busy"] == 1, what="the first request on the solver")
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
    crashes = app.state.pool.stats()["crashes"]
    r = client.post("/tune", json=tune_body(1.0))
    assert r.status_code == 500
    assert "crashed" in r.json()["detail"] and "Traceback" not in r.text
    assert app.state.pool.stats()["crashes"] == crashes + 1
    app.dependency_overrides.pop(get_tune_job)
    r = client.post("/analyze", json=ANALYZE)  # waits for the replacement, then is served
    assert r.status_code == 200, r.text
    assert r.json()["controller"]["dt"] == DT


def test_library_error_inside_the_solver_is_422(client, inject):
    inject(testing.invalid_plant_job)
    r = client.post("/tune", json=tune_body(0.5))
    assert r.status_code == 422
    assert r.json()["detail"] == [{"loc": ["body", "plant"], "type": "tuner_error",
                                   "msg": "plant cannot be tuned: test rejection raised in the solver"}]


def test_nothing_verified_within_the_budget_is_504(client, inject):
    inject(testing.unverified_job)
    r = client.post("/tune", json=tune_body(0.5))
    assert r.status_code == 504, r.text
    assert "nothing could be verified within the time budget of 0.5 s" in r.json()["detail"]


def test_bug_inside_the_solver_is_a_500_without_traceback(client, inject):
    inject(testing.failing_job, dep=get_analyze_job)
    r = client.post("/analyze", json=ANALYZE)
    assert r.status_code == 500
    assert r.json() == {"detail": "internal error in the analysis (ZeroDivisionError); it has been logged"}


def test_worker_killed_while_idle_costs_no_request(app, client):
    """E.g. the kernel's OOM killer took an idle solver: the next request gets a fresh one, not an error."""
    (pid,) = app.state.pool.pids()
    os.kill(pid, signal.SIGKILL)  # a solver process this test's app started
    wait_until(lambda: not alive(pid), what="the killed solver gone")
    r = client.post("/analyze", json=ANALYZE)
    assert r.status_code == 200, r.text
    assert pid not in app.state.pool.pids()


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_a_job_no_solver_starts_is_run_on_fresh_solvers_not_waited_for(tmp_path):
    """A job is handed to pebble only when a solver is free, so it starts at once. Once in a fast-lane run the
    previous test's request waited 300 s: a solver gone that pebble neither replaced nor declared broken. Here the
    only solver is stopped (SIGSTOP: alive to pebble, taking nothing): the job is not started within the pool's
    start timeout, so fresh solvers are started and the job runs there."""
    from fastapi.testclient import TestClient

    settings = Settings(database_url=f"sqlite:///{tmp_path / 'tuner.db'}", workers=1, queue_size=0,
                        worker_start_timeout_s=3.0, analyze_timeout_s=30)
    app = create_app(settings)
    with TestClient(app) as c:
        wait_for_workers(c)
        (pid,) = app.state.pool.pids()
        os.kill(pid, signal.SIGSTOP)
        try:
            r = c.post("/analyze", json=ANALYZE)
            assert r.status_code == 200, r.text
            assert app.state.pool.rebuilds == 1 and pid not in app.state.pool.pids()
            assert app.state.pool.crashes == 0  # nothing crashed: a solver was stuck
        finally:
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
    wait_until(lambda: not alive(pid), what="the stopped solver gone")


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_a_job_not_started_beside_a_running_one_is_refused_and_the_running_one_finishes(tmp_path):
    """Two solvers: one runs a job, the other is stopped. A job handed to the pool is not started within the start
    timeout; rebuilding the pool would kill the running job (pebble then leaves its future running forever), so
    the new job is refused (PoolBusy, a 503 with Retry-After) and the running job ends with its own result."""
    import asyncio
    import functools

    from api.pool import PoolBusy, WorkerPool

    marker = tmp_path / "running"

    async def main() -> None:
        pool = WorkerPool(size=2, queue_size=0, start_timeout_s=2.0, max_running_per_client=2)
        await pool.start()
        assert await pool.wait_ready(120)
        running = asyncio.create_task(pool.run(functools.partial(testing.sleep_marked, str(marker)), 6.0,
                                               timeout_s=60))
        for _ in range(600):
            if marker.exists() and marker.read_text():
                break
            await asyncio.sleep(0.1)
        busy = int(marker.read_text())
        (idle,) = [p for p in pool.pids() if p != busy]
        os.kill(idle, signal.SIGSTOP)
        try:
            with pytest.raises(PoolBusy, match="no solver process started the job"):
                await asyncio.wait_for(pool.run(testing.sleep_job, {"time_budget_s": 0.1}, timeout_s=30), 60)
            assert await asyncio.wait_for(running, 60) == busy  # its solver was not stopped under it
            assert pool.rebuilds == 0 and pool.crashes == 0
        finally:
            if alive(idle):
                os.kill(idle, signal.SIGKILL)
            await pool.close()

    asyncio.run(main())


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


def test_a_solvers_nlp_cache_stays_within_a_quarter_of_its_memory_cap(monkeypatch):
    """A solver lives for many jobs, each plant building problems of its own: the build cache is bounded well inside
    the address-space cap (unbounded, a hundred or so plants reached it)."""
    import asyncio

    from api.pool import WorkerPool

    monkeypatch.delenv("TUNER_NLP_CACHE_MB", raising=False)

    async def main() -> float:
        pool = WorkerPool(size=1, queue_size=0, memory_mb=2048)
        await pool.start()
        try:
            return await pool.run(testing.nlp_cache_job, None, timeout_s=60)
        finally:
            await pool.close()

    assert asyncio.run(main()) == 512


SERVICE_THEN_KILLED = textwrap.dedent("""
    import asyncio, sys
    from api import testing
    from api.pool import WorkerPool

    async def main(started):
        pool = WorkerPool(size=1, queue_size=0)
        await pool.start()
        await pool.run(testing.spin_job, {"started_file": started}, timeout_s=600)

    asyncio.run(main(sys.argv[1]))
""")


@pytest.mark.slow
def test_a_busy_solver_ends_with_the_service(tmp_path):
    """kill -9 of the service while its solver runs a (runaway) job: the solver goes too, at once
    (PR_SET_PDEATHSIG through the forkserver), instead of running its job to the end."""
    started = tmp_path / "started"
    service = subprocess.Popen([sys.executable, "-c", SERVICE_THEN_KILLED, str(started)], cwd=ROOT)
    try:
        wait_until(lambda: started.exists() and started.read_text().strip(), timeout_s=180,
                   what="the solver running its job")
        solver = int(started.read_text())
        assert alive(solver)
        service.kill()
        service.wait(30)
        wait_until(lambda: not alive(solver), timeout_s=30, what="the solver gone after its service")
    finally:
        if service.poll() is None:
            service.kill()
            service.wait()
