"""The service under load, on loopback: a real uvicorn with 2 solver processes (default settings).

    .venv/bin/python bench/service_load.py [--single 30] [--workers 2]

1. one client, sequential ``POST /tune`` (the quadrotor roll loop, pid_z at dt 0.04, seeds 0..N-1):
   latency p50 / p99;
2. 16 concurrent ``POST /tune`` from 4 clients (127.0.0.1-4) and from 1 client: status codes,
   p50 / p99, total time;
3. 30 concurrent ``GET /tunes/{id}/plot.png`` beside one ``POST /tune``: status codes.

Only loopback addresses are used; every loop is bounded. Nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import collections
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

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


def pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, max(0, round(q / 100 * (len(xs) - 1))))]


def client(i: int, n_clients: int) -> httpx.Client:
    return httpx.Client(transport=httpx.HTTPTransport(local_address=f"127.0.0.{1 + i % n_clients}"), timeout=300)


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
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args(argv)
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    with tempfile.TemporaryDirectory() as tmp:
        env = {k: v for k, v in os.environ.items() if not k.startswith("TUNER_")}
        env.update(TUNER_DATABASE_URL=f"sqlite:///{tmp}/tuner.db", TUNER_WORKERS=str(a.workers))
        log = open(Path(tmp) / "server.log", "wb")
        server = subprocess.Popen([sys.executable, "-m", "uvicorn", "api.main:create_app", "--factory", "--host",
                                   "127.0.0.1", "--port", str(port)], cwd=ROOT, env=env, stdout=log,
                                  stderr=subprocess.STDOUT, start_new_session=True)
        try:
            end = time.monotonic() + 180
            while True:
                assert server.poll() is None and time.monotonic() < end, "the server did not start"
                try:
                    h = httpx.get(f"{url}/health", timeout=2).json()
                    if h["workers"]["ready"] == h["workers"]["size"] and h["plots"]["ready"] == h["plots"]["size"]:
                        break
                except httpx.HTTPError:
                    pass
                time.sleep(0.1)
            print(f"uvicorn, {a.workers} solver processes; load average {os.getloadavg()[0]:.2f}")

            lat = []
            with httpx.Client(timeout=300) as c:
                for i in range(a.single):
                    t0 = time.perf_counter()
                    r = c.post(f"{url}/tune", json=roll(i))
                    lat.append(time.perf_counter() - t0)
                    assert r.status_code == 200, r.text
                last = r.json()
            print(f"single client, {a.single} sequential roll pid_z tunes: p50 {1000 * statistics.median(lat):.0f} ms, "
                  f"p99 {1000 * pct(lat, 99):.0f} ms (min {1000 * min(lat):.0f}, max {1000 * max(lat):.0f}); "
                  f"solver wall time of the last: {1000 * last['solver']['wall_time_s']:.0f} ms")

            for n_clients in (4, 1):
                codes, times, total = burst(url, 16, n_clients)
                print(f"16 concurrent tunes from {n_clients} client(s): {dict(codes)}; p50 "
                      f"{statistics.median(times):.2f} s, p99 {pct(times, 99):.2f} s, all answered in {total:.2f} s "
                      f"(load average {os.getloadavg()[0]:.2f})")

            with ThreadPoolExecutor(31) as ex:
                tune = ex.submit(lambda: httpx.post(f"{url}/tune", json=roll(999), timeout=300).status_code)
                plots = list(ex.map(lambda i: httpx.get(f"{url}/tunes/{last['id']}/plot.png", timeout=300).status_code,
                                    range(30)))
                print(f"30 concurrent plots beside a tune: plots {dict(collections.Counter(plots))}, "
                      f"tune {tune.result()}; plot cache {httpx.get(f'{url}/health').json()['plots']}")
        finally:
            server.terminate()
            server.wait(60)
            log.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
