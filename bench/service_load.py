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

Issue 42's run instead (``--mixed S``): for S seconds, ``--clients`` clients send a mix of ``POST /tune`` (the yaw
pi, budget 2 s), ``POST /identify`` (the API's example record) and ``POST /ulog/signals`` (a 60 s two-topic log, 0.7
MB), while a poller times ``GET /health`` every 0.2 s and ``--slow-clients N`` connections each send half a request's
headers and then nothing (``--tree DIR``: another checkout's service, e.g. the commit before the fixes):

    .venv/bin/python bench/service_load.py --mixed 60 --slow-clients 300 [--tree DIR] [--out FILE]

It reports /health p50/p99/max, every request's answer (a status, or the client's timeout: 120 s), and for the slow
connections how many the server answered or closed, when, and how many were still open at the end (the run waits
for them at most 60 s after the load).

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
def serve(workers: int = 2, *, tree: Path = ROOT, **settings: str) -> Iterator[str]:
    """A uvicorn on a free loopback port with a fresh SQLite database and ``workers`` solver processes
    (other settings as ``TUNER_*`` keyword arguments), running the code of ``tree`` (default this one); yields its
    URL once every pool is ready."""
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    with tempfile.TemporaryDirectory() as tmp:
        env = {k: v for k, v in os.environ.items() if not k.startswith("TUNER_")}
        env.update(TUNER_DATABASE_URL=f"sqlite:///{tmp}/tuner.db", TUNER_WORKERS=str(workers), PYTHONPATH=str(tree),
                   **{f"TUNER_{k.upper()}": str(v) for k, v in settings.items()})
        log = open(Path(tmp) / "server.log", "wb")
        # the documented start (python -m api: uvicorn with a header deadline and a connection cap); a tree from
        # before it (no api/server.py) as it was started then
        start = (["-m", "api"] if (tree / "api" / "server.py").exists() else
                 ["-m", "uvicorn", "api.main:create_app", "--factory"])
        server = subprocess.Popen([sys.executable, *start, "--host", "127.0.0.1", "--port", str(port)], cwd=tree,
                                  env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
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


def _ulog_body() -> dict[str, Any]:
    """A 60 s pitch sweep logged at 250 Hz as a ULog (tests/flight.py, tests/ulog_writer.py), base64."""
    import base64

    import numpy as np

    sys.path.insert(0, str(ROOT / "tests"))
    from flight import AXES, fly
    from ulog_writer import Topic, write_ulog

    fl = fly(*AXES["pitch"], seed=8, duration_s=60.0, log_hz=250.0)
    t = 5_000_000 + np.round(fl.t * 1e6).astype(np.int64)
    vec = lambda x: np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    xyz = [("float", "xyz", 3)]
    with tempfile.TemporaryDirectory() as d:
        p = write_ulog(Path(d) / "f.ulg", [Topic("vehicle_torque_setpoint", xyz, t, {"xyz": vec(fl.u)}),
                                           Topic("vehicle_angular_velocity", xyz, t + 100, {"xyz": vec(fl.y)})])
        return {"data": base64.b64encode(p.read_bytes()).decode()}


def _slow_clients(url: str, n: int, stop: threading.Event, out: dict[str, Any]) -> None:
    """``n`` connections that send half a request's headers, then nothing; when the server answers or closes each."""
    import selectors

    host, port = url.rsplit("//", 1)[1].split(":")
    sel = selectors.DefaultSelector()
    opened, t0 = {}, time.monotonic()
    for i in range(n):
        try:
            s = socket.create_connection((host, int(port)), timeout=10)
        except OSError as e:
            out.setdefault("connect_errors", collections.Counter())[type(e).__name__] += 1
            continue
        s.sendall(b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
        s.setblocking(False)
        sel.register(s, selectors.EVENT_READ, i)
        opened[i] = time.monotonic()
    out["opened"] = len(opened)
    closed: dict[int, tuple[float, str]] = {}
    while opened.keys() - closed.keys() and not (stop.is_set() and time.monotonic() > out.get("stop_by", 1e18)):
        for key, _ in sel.select(timeout=0.5):
            s = key.fileobj
            try:
                data = s.recv(4096)
            except OSError:
                data = b""
            first = data.split(b"\r\n", 1)[0].decode("latin-1") if data else "closed"
            if key.data not in closed:
                closed[key.data] = (time.monotonic() - opened[key.data], first)
            if not data:
                sel.unregister(s)
                s.close()
    still = opened.keys() - closed.keys()
    for key in list(sel.get_map().values()):
        key.fileobj.close()
    waits = sorted(w for w, _ in closed.values())
    out.update(answered_or_closed=len(closed), still_open_at_end=len(still),
               first_lines=dict(collections.Counter(f for _, f in closed.values())),
               closed_after_s=({"min": waits[0], "median": statistics.median(waits), "max": waits[-1]} if waits
                               else None),
               wall_s=time.monotonic() - t0)


def mixed(url: str, seconds: float, clients: int, slow: int) -> dict[str, Any]:
    """Issue 42's load: a mix of tune, identify and ulog/signals, /health timed, ``slow`` half-header connections."""
    sys.path.insert(0, str(ROOT))
    from api.schemas_identify import IDENTIFY_EXAMPLE

    bodies = {"/tune": {"plant": {"expr": YAW}, "dt": 0.04, "structure": "pi", "options": {"time_budget_s": 2}},
              "/identify": IDENTIFY_EXAMPLE, "/ulog/signals": _ulog_body()}
    stop, lock = threading.Event(), threading.Lock()
    answers: collections.Counter = collections.Counter()
    lat: dict[str, list[float]] = collections.defaultdict(list)
    health: list[float] = []
    slow_out: dict[str, Any] = {}

    def client_loop(i: int) -> None:
        routes = list(bodies)
        k = i
        with client(i, max(1, clients)) as c:
            while not stop.is_set():
                route = routes[k % len(routes)]
                k += 1
                t0 = time.perf_counter()
                try:
                    code = str(c.post(f"{url}{route}", json=bodies[route], timeout=120).status_code)
                except httpx.TimeoutException:
                    code = "client timeout (120 s)"
                except httpx.HTTPError as e:
                    code = type(e).__name__
                with lock:
                    answers[(route, code)] += 1
                    lat[route].append(time.perf_counter() - t0)

    def poll() -> None:
        with httpx.Client(timeout=60) as c:
            while not stop.is_set():
                t0 = time.perf_counter()
                try:
                    code = c.get(f"{url}/health").status_code
                except httpx.HTTPError as e:
                    code = type(e).__name__
                dt = time.perf_counter() - t0
                with lock:
                    health.append(dt)
                    answers[("/health", str(code))] += 1
                time.sleep(max(0.0, 0.2 - dt))

    threads = [threading.Thread(target=client_loop, args=(i,)) for i in range(clients)]
    threads.append(threading.Thread(target=poll))
    slow_thread = threading.Thread(target=_slow_clients, args=(url, slow, stop, slow_out)) if slow else None
    t0 = time.perf_counter()
    if slow_thread:
        slow_thread.start()
    for t in threads:
        t.start()
    time.sleep(seconds)
    stop.set()
    slow_out["stop_by"] = time.monotonic() + 60.0  # the slow connections: at most 60 s more
    for t in threads:
        t.join()
    if slow_thread:
        slow_thread.join()
    return {"seconds": seconds, "clients": clients, "wall_s": time.perf_counter() - t0,
            "health": {"n": len(health), "p50_s": statistics.median(health), "p99_s": pct(health, 99),
                       "max_s": max(health)} if health else None,
            "answers": {f"{r} {c}": n for (r, c), n in sorted(answers.items())},
            "latency_p50_s": {r: statistics.median(v) for r, v in lat.items()},
            "slow_clients": {k: v for k, v in slow_out.items() if k != "stop_by"},
            "load_average": os.getloadavg()[0]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--single", type=int, default=30, help="sequential requests of one client")
    ap.add_argument("--clients", type=int, default=8, help="clients of the load test")
    ap.add_argument("--requests", type=int, default=100, help="requests of the load test")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--mixed", type=float, default=None, metavar="S", help="issue 42's mixed load for S seconds")
    ap.add_argument("--slow-clients", type=int, default=0, metavar="N", help="with --mixed: half-header connections")
    ap.add_argument("--tree", type=Path, default=ROOT, help="the source tree whose service runs (--mixed)")
    ap.add_argument("--out", type=Path, default=None, help="--mixed: write the JSON here too")
    a = ap.parse_args(argv)
    if a.mixed is not None:
        import json

        seconds, slow = min(max(a.mixed, 5.0), 600.0), min(max(a.slow_clients, 0), 1000)
        with serve(a.workers, tree=a.tree.resolve()) as url:
            r = mixed(url, seconds, min(max(a.clients, 1), 32), slow)
        r["tree"] = str(a.tree)
        print(json.dumps(r, indent=2))
        if a.out:
            a.out.write_text(json.dumps(r, indent=2) + "\n")
        return 0
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
