"""The service as deployed: a real uvicorn process on 127.0.0.1, started with the documented command.

16 concurrent ``POST /tune`` from 4 clients (4 loopback addresses) on a pool of 2 solver
processes, with the default queue settings: every one answered 200 (no 5xx), each result
re-verified through ``/analyze``; then the process is stopped, a new one started on the same
SQLite file, and every result read back. And ``kill -9`` of uvicorn while a solve runs: nothing
of the service is left running.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import pytest
from numpy.testing import assert_allclose
from quadrotor import DT, ROLL, YAW
from uvicorn_server import Server

pytestmark = pytest.mark.slow

N = 16


def body(i: int) -> dict:
    if i % 2:
        return {"plant": {"expr": YAW}, "structure": "pi", "options": {"seed": i, "time_budget_s": 0.3}}
    return {"plant": {"expr": ROLL}, "dt": DT, "structure": "pid_z", "options": {"seed": i, "time_budget_s": 0.3}}


CLIENTS = 4  # requests i, i + 4, ... come from 127.0.0.(1 + i % 4): each client holds at most one solver


def client_for(i: int) -> httpx.Client:
    return httpx.Client(transport=httpx.HTTPTransport(local_address=f"127.0.0.{1 + i % CLIENTS}"), timeout=180)


def test_16_concurrent_tunes_then_restart_and_read_back(tmp_path):
    env = {"TUNER_DATABASE_URL": f"sqlite:///{tmp_path / 'tuner.db'}", "TUNER_WORKERS": "2",
           "TUNER_SOLVE_GRACE_S": "3"}  # the default queue (16 per solver) and queue timeout (30 s)
    server = Server(tmp_path, env)
    try:
        server.wait_ready()

        def post(i: int) -> httpx.Response:
            with client_for(i) as c:
                return c.post(f"{server.url}/tune", json=body(i))

        with ThreadPoolExecutor(N) as ex:
            responses = list(ex.map(post, range(N)))
        assert [r.status_code for r in responses] == [200] * N, [r.text[:300] for r in responses]
        results = [r.json() for r in responses]
        assert len({r["id"] for r in results}) == N
        for i, out in enumerate(results):
            b = body(i)
            assert out["structure"] == b["structure"] and out["solver"]["seed"] == i
            assert out["controller"]["dt"] == b.get("dt")
            assert out["meets_spec"] == all(c["ok"] for c in out["checks"])

        def verify(i: int) -> httpx.Response:  # correct = what the independent verifier says of the controller
            c = results[i]["controller"]
            return httpx.post(f"{server.url}/analyze", timeout=60, json={
                "plant": body(i)["plant"], "dt": body(i).get("dt"), "controller": {"num": c["num"], "den": c["den"]}})

        with ThreadPoolExecutor(4) as ex:
            checks = list(ex.map(verify, range(N)))
        for out, check in zip(results, checks):
            assert check.status_code == 200
            for k, v in out["metrics"].items():
                if isinstance(v, float):
                    assert_allclose(check.json()["metrics"][k], v, rtol=1e-9, atol=1e-12, err_msg=k)
                else:
                    assert check.json()["metrics"][k] == v
        health = httpx.get(f"{server.url}/health", timeout=5).json()
        assert health["workers"]["crashes"] == 0 and health["workers"]["timeouts"] == 0
    finally:
        clean = server.stop()
    log = server.output()
    assert " 500 " not in log and " 503 " not in log and " 504 " not in log
    assert "Traceback" not in log, log[-3000:]
    assert clean and "Application shutdown complete" in log  # solver processes stopped with the server

    again = Server(tmp_path, env)  # same database file, new process
    try:
        again.wait_ready(timeout_s=120, workers=False)  # reading needs no solver
        listed = httpx.get(f"{again.url}/tunes", params={"limit": 100}, timeout=10).json()
        assert listed["total"] == N
        assert {i["id"] for i in listed["items"]} == {r["id"] for r in results}
        for out in results:
            got = httpx.get(f"{again.url}/tunes/{out['id']}", timeout=10).json()
            got.pop("request")
            assert got == out
    finally:
        again.stop()


def test_kill_9_of_the_service_leaves_no_solver_running(tmp_path):
    """A solve that runs for a long time (20 s budget on an order-10 plant at a fine sample time);
    uvicorn is killed with SIGKILL mid-solve: every process of the service's session goes too."""
    env = {"TUNER_DATABASE_URL": f"sqlite:///{tmp_path / 'tuner.db'}", "TUNER_WORKERS": "1"}
    server = Server(tmp_path, env)
    box: dict = {}

    def long_solve() -> None:
        try:
            box["r"] = httpx.post(f"{server.url}/tune", timeout=120, json={
                "plant": {"expr": "1/(s+1)^10"}, "dt": 0.001, "structure": "pid", "options": {"time_budget_s": 20}})
        except httpx.HTTPError as e:  # the server dies under it
            box["r"] = e

    try:
        server.wait_ready()
        t = threading.Thread(target=long_solve)
        t.start()
        end = time.monotonic() + 60
        while httpx.get(f"{server.url}/health", timeout=5).json()["workers"]["busy"] != 1:
            assert time.monotonic() < end, "the solve never started"
            time.sleep(0.05)
        assert _session_alive(server.proc.pid, besides=server.proc.pid)  # the solver (and forkserver) run
        server.proc.kill()
        server.proc.wait(10)
        end = time.monotonic() + 30  # a bound against a hang, not a timing claim
        while _session_alive(server.proc.pid):
            assert time.monotonic() < end, "processes of the killed service still run"
            time.sleep(0.05)
        t.join(30)
        assert isinstance(box["r"], httpx.HTTPError)
    finally:
        server.stop()


def _session_alive(sid: int, *, besides: int | None = None) -> bool:
    """Is any process (zombies aside) of session ``sid`` running, other than ``besides``?"""
    for d in Path("/proc").iterdir():
        if not d.name.isdigit() or int(d.name) == besides:
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError, IndexError):
            continue
        if fields[0] != "Z" and int(fields[3]) == sid:  # state, ppid, pgrp, session
            return True
    return False
