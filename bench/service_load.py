"""The service under load, on loopback: a real uvicorn with 2 solver processes (default settings).

    .venv/bin/python bench/service_load.py [--single 30] [--clients 8] [--requests 100] [--workers 2]

1. one client, sequential ``POST /tune`` (the quadrotor roll loop, pid_z at dt 0.04, seeds 0..N-1):
   latency p50 / p99;
2. the load test of issue 6: ``--clients`` clients (each its own loopback address, each sending its next
   request when the last is answered) share ``--requests`` ``POST /tune`` of the yaw loop (pi at dt 0.04,
   budget 10 s): p50 / p99, throughput, non-200 answers;
3. 16 concurrent ``POST /tune`` from 4 clients (127.0.0.1-4) and from 1 client: status codes,
   p50 / p99, total time;
4. 30 concurrent ``GET /tunes/{id}/plot.png`` beside one ``POST /tune``: status codes.

Only loopback addresses are used; every loop is bounded. Nothing here asserts a timing. The functions
(:func:`serve`, :func:`single`, :func:`load_test`) are what ``bench/tune_speed.py`` runs.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx

ROOT = Path(__file__).resolve().parents[1]
ROLL = "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)"
YAW = "0.2843*18.611/(s+18.611)"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def roll(seed: int, budget: float | None = None) -> dict:
    body = {"plant": {"expr": ROLL}, "dt": 0.04, "structure": "pid_z", "options": {"seed": seed}}
    if budget:
        body["options"]["time_budget_s"] = budget
    return body


def yaw_pi(seed: int = 0) -> dict:
    """Issue 6's load-test request."""
    return {"plant": {"expr": YAW}, "dt": 0.04, "structure": "pi", "options": {"seed": seed, "time_budget_s": 10}}


def pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, max(0, round(q / 100 * (len(xs) - 1))))]


def client(i: int, n_clients: int) -> httpx.Client:
    return httpx.Client(transport=httpx.HTTPTransport(local_address=f"127.0.0.{1 + i % n_clients}"), timeout=300)


@contextlib.contextmanager
def serve(workers: int = 2, **settings: str) -> Iterator[str]:
    """A uvicorn on a free loopback port with a fresh SQLite database and ``workers`` solver processes
    (other settings as ``TUNER_*`` keyword arguments); yields its URL once every pool is ready."""
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    with tempfile.TemporaryDirectory() as tmp:
        env = {k: v for k, v in os.environ.items() if not k.startswith("TUNER_")}
        env.update(TUNER_DATABASE_URL=f"sqlite:///{tmp}/tuner.db", TUNER_WORKERS=str(workers),
                   **{f"TUNER_{k.upper()}": str(v) for k, v in settings.items()})
        log = open(Path(tmp) / "server.log", "wb")
        server = subprocess.Popen([sys.executable, "-m", "uvicorn", "api.main:create_app", "--factory", "--host",
                                   "127.0.0.1", "--port", str(port)], cwd=ROOT, env=env, stdout=log,
                                  stderr=subprocess.STDOUT, start_new_session=True)
        try:
            end = time.monotonic() + 180
            while True:
                if server.poll() is not None or time.monotonic() > end:
                    raise RuntimeError("the server did not start:\n"
                                       + (Path(tmp) / "server.log").read_text(errors="replace")[-2000:])
                try:
                    h = httpx.get(f"{url}/health", timeout=2).json()
                    if h["workers"]["ready"] == h["workers"]["size"] and h["plots"]["ready"] == h["plots"]["size"]:
                        break
                except (httpx.HTTPError, KeyError, ValueError):
                    pass
                time.sleep(0.1)
            yield url
        finally:
            server.terminate()
            server.wait(60)
            log.close()


def single(url: str, n: int) -> dict[str, Any]:
    """One client, ``n`` sequential roll pid_z tunes (seeds 0..n-1): latency in seconds."""
    lat = []
    with httpx.Client(timeout=300) as c:
        for i in range(n):
            t0 = time.perf_counter()
            r = c.post(f"{url}/tune", json=roll(i))
            lat.append(time.perf_counter() - t0)
            if r.status_code != 200:
                raise RuntimeError(f"POST /tune answered {r.status_code}: {r.text[:500]}")
        last = r.json()
    return {"requests": n, "p50_s": statistics.median(lat), "p99_s": pct(lat, 99), "min_s": min(lat),
            "max_s": max(lat), "last_solver_wall_s": last["solver"]["wall_time_s"], "last_id": last["id"],
            "latencies_s": lat}


def load_test(url: str, clients: int, requests: int) -> dict[str, Any]:
    """Issue 6's load test: ``clients`` clients (one loopback address each) share ``requests`` tunes."""
    lat: list[float] = []
    errors: collections.Counter = collections.Counter()
    lock = threading.Lock()
    todo = list(range(requests))

    def run(i: int) -> None:
        with client(i, clients) as c:
            while True:
                with lock:
                    if not todo:
                        return
                    seed = todo.pop()
                t0 = time.perf_counter()
                try:
                    code = str(c.post(f"{url}/tune", json=yaw_pi(seed)).status_code)
                except httpx.HTTPError as e:
                    code = type(e).__name__
                with lock:
                    lat.append(time.perf_counter() - t0)
                    if code != "200":
                        errors[code] += 1

    t0 = time.perf_counter()
    threads = [threading.Thread(target=run, args=(i,)) for i in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    wall = time.perf_counter() - t0
    return {"clients": clients, "requests": requests, "wall_s": wall, "throughput_rps": requests / wall,
            "p50_s": statistics.median(lat), "p99_s": pct(lat, 99), "errors": dict(errors)}


def burst(url: str, n: int, n_clients: int) -> tuple[collections.Counter, list[float], float]:
    def post(i: int) -> tuple[int, float]:
        with client(i, n_clients) as c:
            t0 = time.perf_counter()
            r = c.post(f"{url}/tune", json=roll(100 + i))
            return r.status_code, time.perf_counter() - t0

    t0 = time.perf_counter()
    with ThreadPoolExecutor(n) as ex:
        out = list(ex.map(post, range(n)))
    return collections.Counter(s for s, _ in out), [t for _, t in out], time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--single", type=int, default=30, help="sequential requests of one client")
    ap.add_argument("--clients", type=int, default=8, help="clients of the load test")
    ap.add_argument("--requests", type=int, default=100, help="requests of the load test")
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args(argv)
    with serve(a.workers) as url:
        print(f"uvicorn, {a.workers} solver processes; load average {os.getloadavg()[0]:.2f}")
        s = single(url, a.single)
        print(f"single client, {a.single} sequential roll pid_z tunes: p50 {1000 * s['p50_s']:.0f} ms, "
              f"p99 {1000 * s['p99_s']:.0f} ms (min {1000 * s['min_s']:.0f}, max {1000 * s['max_s']:.0f}); "
              f"solver wall time of the last: {1000 * s['last_solver_wall_s']:.0f} ms")
        ld = load_test(url, a.clients, a.requests)
        print(f"load test, {a.clients} clients, {a.requests} yaw pi tunes: p50 {ld['p50_s']:.2f} s, p99 "
              f"{ld['p99_s']:.2f} s, {ld['throughput_rps']:.2f} req/s, non-200: {ld['errors'] or 'none'} "
              f"(load average {os.getloadavg()[0]:.2f})")
        for n_clients in (4, 1):
            codes, times, total = burst(url, 16, n_clients)
            print(f"16 concurrent tunes from {n_clients} client(s): {dict(codes)}; p50 "
                  f"{statistics.median(times):.2f} s, p99 {pct(times, 99):.2f} s, all answered in {total:.2f} s "
                  f"(load average {os.getloadavg()[0]:.2f})")
        with ThreadPoolExecutor(31) as ex:
            tune = ex.submit(lambda: httpx.post(f"{url}/tune", json=roll(999), timeout=300).status_code)
            plots = list(ex.map(lambda i: httpx.get(f"{url}/tunes/{s['last_id']}/plot.png", timeout=300).status_code,
                                range(30)))
            print(f"30 concurrent plots beside a tune: plots {dict(collections.Counter(plots))}, "
                  f"tune {tune.result()}; plot cache {httpx.get(f'{url}/health').json()['plots']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
