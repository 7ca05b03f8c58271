"""The hostile-user campaign of issue 11, on loopback: hand-made and generated requests, faults, read-back.

Starts the service as deployed (``python -m api`` on 127.0.0.1, 2 solvers) on
SQLite and on PostgreSQL (a schema of its own, created and dropped here; the server itself is never
touched), and for each database:

1. sends the hand-made hostile requests (:data:`api.testing.HOSTILE_REQUESTS`) and ``--generated``
   requests drawn from a seeded grammar (plants in three forms, extreme coefficients, gains up to
   1e300, dt 1e-6..1e4, delays, orders to 22, every structure; bounded in count), one at a time;
2. counts the answers: 2xx, 4xx, 5xx, and hangs (an answer later than the request's limit + 5 s:
   ``time_budget_s`` + the service's grace for /tune, ``TUNER_ANALYZE_TIMEOUT_S`` for /analyze);
3. injects faults: ``kill -9`` of uvicorn while a /tune is running (``--kills`` times), restarts it,
   reads back every stored id, and checks that the killed server's solver processes are gone;
4. runs the service's 16-concurrent-/tune load test (``bench/service_load.py``).

Loopback only; every loop is bounded in count and time and stops by itself. Prints one JSON line per
database and a summary table; ``--out FILE`` writes the JSON too.

    .venv/bin/python bench/hostile.py                      # SQLite and PostgreSQL, 150 generated
    .venv/bin/python bench/hostile.py --db sqlite --generated 30 --kills 1

Issue 42's hostile files instead (``bench/hostile_cases.py``: damaged ULogs, CSV sniffer and clock cases, crafted
results, outputs to FIFOs and devices, parameter files, a study's free text), through the command line of a source
tree (``--tree``, default this one; e.g. an export of the commit before the fixes), each case's exit code and time:

    .venv/bin/python bench/hostile.py --files [--tree DIR] [--small] [--only TEXT] [--out FILE]

and the service's side (``--ulog-service``): damaged ULog uploads to ``/identify`` and ``/ulog/signals`` (17 MB
under the default body cap; 100 MB with the cap raised), time to the answer, on a uvicorn of the tree.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from api.testing import HOSTILE_REQUESTS  # noqa: E402

PG_URL = "postgresql+psycopg://postgres@127.0.0.1:5432/test"
GRACE_S, GRACE_FRACTION, ANALYZE_TIMEOUT_S = 2.0, 0.25, 10.0  # the service's defaults (api/settings.py)
HANG_SLACK_S = 5.0
STRUCTURES = ["p", "pi", "pd", "pid", "pid_z", "lead", "lag", "leadlag"]


# -- generated requests ---------------------------------------------------------------------------------

def _mag(rng: random.Random, lo: float, hi: float) -> float:
    return float(10.0 ** rng.uniform(lo, hi))


def _signed(rng: random.Random, lo: float, hi: float) -> float:
    return rng.choice([1.0, -1.0]) * _mag(rng, lo, hi)


def _plant(rng: random.Random) -> dict[str, Any]:
    delay = rng.choice([0.0, 0.0, _mag(rng, -6, 3), 1e-5, 1e-3, 3.0])
    form = rng.choice(["expr", "coeffs"])
    if form == "expr":
        k = _signed(rng, -100, 100) if rng.random() < 0.3 else _signed(rng, -2, 2)
        factors = []
        for _ in range(rng.randint(1, 3)):
            a = _mag(rng, -4, 4)
            kind = rng.choice(["first", "power", "second", "integrator"])
            if kind == "first":
                factors.append(f"(s+{a!r})")
            elif kind == "power":
                factors.append(f"({a!r}*s+1)^{rng.randint(2, 22)}")
            elif kind == "second":
                factors.append(f"(s^2+{2 * rng.uniform(-0.5, 2) * a!r}*s+{a * a!r})")
            else:
                factors.append("s")
        return {"expr": f"{k!r}/(" + "*".join(factors) + ")", "delay": delay}
    n = rng.randint(1, 20)
    den = [1.0] + [_signed(rng, -100, 100) if rng.random() < 0.2 else _mag(rng, -3, 3) for _ in range(n)]
    num = [_signed(rng, -100, 100) if rng.random() < 0.2 else _signed(rng, -3, 3) for _ in range(rng.randint(1, n))]
    return {"num": num, "den": den, "delay": delay}


def _controller(rng: random.Random, dt: float | None) -> dict[str, Any]:
    form = rng.choice(["structure", "expr", "coeffs"])
    if form == "structure":
        s = rng.choice([x for x in STRUCTURES if dt is not None or x != "pid_z"])
        params = {"p": ["Kp"], "pi": ["Kp", "Ki"], "pd": ["Kp", "Kd", "Tf"], "pid": ["Kp", "Ki", "Kd", "Tf"],
                  "pid_z": ["K", "a1", "a2"], "lead": ["K", "wz", "wp"], "lag": ["K", "wz", "wp"],
                  "leadlag": ["K", "wz1", "wp1", "wz2", "wp2"]}[s]
        gains = {}
        for p in params:
            if p.startswith("w"):
                gains[p] = _mag(rng, -4, 4)
            elif p == "Tf":
                gains[p] = _mag(rng, -4, 1)
            elif p in ("a1", "a2"):
                gains[p] = rng.uniform(-3, 3)
            else:
                gains[p] = _signed(rng, -300, 300) if rng.random() < 0.3 else _signed(rng, -2, 2)
        return {"structure": s, "gains": gains}
    v = "z" if dt is not None else "s"
    if form == "expr":
        k = _signed(rng, -300, 300) if rng.random() < 0.3 else _signed(rng, -2, 2)
        deg = rng.choice([0, 1, 2, 40, 41])
        return {"expr": f"{k!r}" if deg == 0 else f"{k!r}*({v}+0.5)^{deg}/({v}+0.9)^{deg}"}
    n = rng.choice([0, 1, 2, 40])
    return {"num": [_signed(rng, -100, 100) for _ in range(rng.randint(1, n + 1))],
            "den": [1.0] + [_signed(rng, -3, 3) for _ in range(n)]}


def generated(n: int, seed: int) -> list[tuple[str, str, dict[str, Any]]]:
    rng = random.Random(seed)
    out = []
    for i in range(n):
        dt = rng.choice([None, None, _mag(rng, -6, 4), 0.001, 0.04, 1000.0])
        if rng.random() < 0.4:
            body: dict[str, Any] = {"plant": _plant(rng), "structure": rng.choice(STRUCTURES),
                                    "options": {"seed": rng.randint(0, 9), "time_budget_s": rng.choice([0.3, 1.0])}}
            if rng.random() < 0.2:
                body["plants"] = [_plant(rng) for _ in range(rng.randint(1, 3))]
            path = "/tune"
        else:
            body, path = {"plant": _plant(rng), "controller": _controller(rng, dt)}, "/analyze"
        if dt is not None:
            body["dt"] = dt
        out.append((f"gen{i}", path, body))
    return out


# -- the service ----------------------------------------------------------------------------------------

def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Service:
    def __init__(self, db_url: str, log_dir: Path) -> None:
        self.db_url, self.log_dir = db_url, log_dir
        self.proc: subprocess.Popen | None = None
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.starts = 0

    def start(self, timeout_s: float = 180.0) -> float:
        env = {k: v for k, v in os.environ.items() if not k.startswith("TUNER_")}
        env.update(TUNER_DATABASE_URL=self.db_url, TUNER_WORKERS="2", TUNER_QUEUE_SIZE="16",
                   TUNER_QUEUE_TIMEOUT_S="120")
        self.starts += 1
        log = open(self.log_dir / f"uvicorn-{self.port}-{self.starts}.log", "wb")
        t0 = time.monotonic()
        self.proc = subprocess.Popen([sys.executable, "-m", "api", "--host", "127.0.0.1", "--port", str(self.port)],
                                     cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        while time.monotonic() - t0 < timeout_s:
            if self.proc.poll() is not None:
                raise RuntimeError(f"uvicorn exited with {self.proc.returncode}; see {log.name}")
            try:
                w = httpx.get(f"{self.url}/health", timeout=2).json()["workers"]
                if w["ready"] + w.get("busy", 0) >= w["size"]:
                    return time.monotonic() - t0
            except (httpx.HTTPError, ValueError, KeyError):
                pass
            time.sleep(0.2)
        raise TimeoutError("the service did not become ready")

    def descendants(self) -> list[int]:
        """Every process below uvicorn (solvers, the forkserver), from /proc."""
        assert self.proc is not None
        kids: dict[int, list[int]] = {}
        for d in Path("/proc").iterdir():
            if d.name.isdigit():
                try:
                    ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
                except (OSError, IndexError, ValueError):
                    continue
                kids.setdefault(ppid, []).append(int(d.name))
        out, todo = [], [self.proc.pid]
        while todo:
            for c in kids.get(todo.pop(), []):
                out.append(c)
                todo.append(c)
        return out

    def kill9(self) -> list[int]:
        assert self.proc is not None
        below = self.descendants()
        os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait(10)
        return below

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(10)


def _alive(pids: list[int]) -> list[int]:
    out = []
    for p in pids:
        try:
            state = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            out.append(p)
    return out


def limit_s(path: str, body: dict[str, Any]) -> float:
    if path == "/tune":
        b = float((body.get("options") or {}).get("time_budget_s") or 10.0)
        return b + GRACE_S + GRACE_FRACTION * b
    return ANALYZE_TIMEOUT_S


# -- the campaign ---------------------------------------------------------------------------------------

def send_all(svc: Service, requests: list[tuple[str, str, dict[str, Any]]], stats: dict[str, Any],
             ids: list[str], deadline: float) -> None:
    with httpx.Client(base_url=svc.url, timeout=None) as client:
        for name, path, body in requests:
            if time.monotonic() > deadline:
                stats["skipped_for_time"] += 1
                continue
            lim = limit_s(path, body)
            t0 = time.monotonic()
            try:
                r = client.post(path, json=body, timeout=lim + 60.0)
                code = r.status_code
            except httpx.TimeoutException:
                code = None
            took = time.monotonic() - t0
            stats["tried"] += 1
            if code is None or took > lim + HANG_SLACK_S:
                stats["hangs"] += 1
                stats["hang_cases"].append({"case": name, "took_s": round(took, 2), "limit_s": lim})
            if code is None:
                continue
            klass = f"{code // 100}xx"
            stats[klass] = stats.get(klass, 0) + 1
            stats["by_status"][str(code)] = stats["by_status"].get(str(code), 0) + 1
            if code >= 500:
                stats["5xx_cases"].append({"case": name, "path": path, "status": code, "body": body,
                                           "answer": r.text[:300]})
            if path == "/tune" and code == 200:
                ids.append(r.json()["id"])


def faults(svc: Service, kills: int, ids: list[str], stats: dict[str, Any]) -> None:
    body = {"plant": {"expr": "1/(s+1)^4"}, "structure": "pid", "options": {"time_budget_s": 3}}
    for _ in range(kills):
        import threading

        result: dict[str, Any] = {}

        def post(result: dict[str, Any] = result) -> None:
            try:
                result["status"] = httpx.post(f"{svc.url}/tune", json=body, timeout=30).status_code
            except httpx.HTTPError as e:
                result["error"] = type(e).__name__

        th = threading.Thread(target=post)
        th.start()
        time.sleep(1.0)  # the solve is running
        below = svc.kill9()
        th.join(35)
        end = time.monotonic() + 15
        left = _alive(below)
        while left and time.monotonic() < end:
            time.sleep(0.2)
            left = _alive(below)
        restart_s = svc.start()
        missing = []
        with httpx.Client(base_url=svc.url, timeout=30) as client:
            for i in ids:
                r = client.get(f"/tunes/{i}")
                if r.status_code != 200 or r.json().get("id") != i:
                    missing.append(i)
        stats["faults"].append({"fault": "kill -9 uvicorn mid-/tune", "client_saw": result,
                                "solvers_left_after_15s": len(left), "restart_s": round(restart_s, 2),
                                "ids_read_back": len(ids) - len(missing), "ids_missing": missing})


def load_test() -> dict[str, Any]:
    cand = ROOT / "bench" / "service_load.py"  # 16 concurrent /tune from 4 clients and from 1, on 2 solvers
    if cand.exists():
        p = subprocess.run([sys.executable, str(cand), "--single", "10"], cwd=ROOT, capture_output=True, text=True,
                           timeout=1200)
        return {"script": str(cand.relative_to(ROOT)), "rc": p.returncode, "tail": p.stdout[-1500:]}
    return {"script": None, "note": "bench/service_load.py is not there"}


def pg_schema() -> tuple[str, Any]:
    """A schema of our own on the shared server (dropped at the end), reached through search_path."""
    import psycopg

    name = f"hostile_{uuid.uuid4().hex[:8]}"
    conn = psycopg.connect("postgresql://postgres@127.0.0.1:5432/test", autocommit=True)
    conn.execute(f'CREATE SCHEMA "{name}"')
    return name, conn


def campaign(db: str, n_generated: int, kills: int, seed: int, time_limit_s: float, log_dir: Path) -> dict[str, Any]:
    conn = schema = None
    if db == "sqlite":
        url = f"sqlite:///{log_dir / 'hostile.db'}"
    else:
        schema, conn = pg_schema()
        url = f"{PG_URL}?options=-csearch_path%3D{schema}"
    stats: dict[str, Any] = {"db": db, "tried": 0, "2xx": 0, "4xx": 0, "5xx": 0, "hangs": 0, "by_status": {},
                             "5xx_cases": [], "hang_cases": [], "faults": [], "skipped_for_time": 0}
    svc = Service(url, log_dir)
    t0 = time.monotonic()
    try:
        stats["start_s"] = round(svc.start(), 2)
        ids: list[str] = []
        reqs = list(HOSTILE_REQUESTS) + generated(n_generated, seed)
        stats["hand_made"], stats["generated"] = len(HOSTILE_REQUESTS), n_generated
        send_all(svc, reqs, stats, ids, t0 + time_limit_s)
        stats["stored_ids"] = len(ids)
        faults(svc, kills, ids, stats)
    finally:
        svc.stop()
        if conn is not None:
            conn.execute(f'DROP SCHEMA "{schema}" CASCADE')
            conn.close()
    stats["wall_s"] = round(time.monotonic() - t0, 1)
    return stats


def ulog_service(tree: Path, work: Path) -> list[dict[str, Any]]:
    """Damaged ULog uploads (a valid header, then zeros) to a uvicorn of ``tree``: the time to each answer."""
    import base64

    sys.path.insert(0, str(ROOT / "bench"))
    from service_load import serve

    hdr = b"ULog\x01\x12\x35\x01" + bytes(8)
    rows = []
    # the worker's share alone: the jobs a solver runs, on 100 MB (past the request limits: a body of 24 MB, 18 MB
    # of log), in a process of the tree's code (bench/hostile_cases.py: worker_share)
    env = {k: v for k, v in os.environ.items() if not k.startswith("TUNER_")}
    env["PYTHONPATH"] = str(tree)
    code = (f"import sys; sys.path.insert(0, {str(ROOT / 'bench')!r}); import hostile_cases; "
            "hostile_cases.worker_share()")
    try:
        p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=1800, cwd=tree,
                           env=env)
        rows += [json.loads(ln) for ln in p.stdout.splitlines() if ln.startswith("{")]
    except subprocess.TimeoutExpired:
        rows.append({"case": "100 MB in-process", "answer": "(no answer within 1800 s)"})
    for r in rows:
        print(json.dumps(r), flush=True)
    for mb, settings in ((17, {}), (100, {}), (100, {"max_identify_body_bytes": "200000000",
                                                      "identify_timeout_s": "600"})):
        b64 = base64.b64encode(hdr + bytes(mb * 1_000_000)).decode()
        bodies = {"/ulog/signals": {"data": b64},
                  "/identify": {"ulog": {"data": b64, "input": "a.b[0]", "output": "c.d[0]"}, "poles": 2}}
        with serve(2, tree=tree, **settings) as url:
            for path, body in bodies.items():
                t0 = time.perf_counter()
                try:
                    r = httpx.post(f"{url}{path}", json=body, timeout=700)
                    code, msg = r.status_code, r.text[:300]
                except httpx.HTTPError as e:
                    code, msg = None, type(e).__name__
                row = {"case": f"{mb} MB header + zeros to {path}", "settings": settings, "status": code,
                       "wall_s": round(time.perf_counter() - t0, 2), "answer": msg}
                print(json.dumps(row), flush=True)
                rows.append(row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--db", choices=["sqlite", "postgres", "both"], default="both")
    ap.add_argument("--generated", type=int, default=150, help="generated requests per database (150)")
    ap.add_argument("--kills", type=int, default=2, help="kill -9 of uvicorn per database (2)")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--time-limit", type=float, default=1200.0, help="seconds of requests per database (1200)")
    ap.add_argument("--no-load", action="store_true", help="skip the 16-concurrent load test")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--files", action="store_true", help="issue 42's hostile files through the command line instead")
    ap.add_argument("--ulog-service", action="store_true", help="issue 42's damaged ULog uploads to a service instead")
    ap.add_argument("--tree", type=Path, default=ROOT, help="the source tree whose code runs (--files, --ulog-service)")
    ap.add_argument("--small", action="store_true", help="--files: skip the 100 MB logs")
    ap.add_argument("--only", default=None, help="--files: the cases whose name holds this text")
    a = ap.parse_args()
    if a.files or a.ulog_service:
        import hostile_cases

        with tempfile.TemporaryDirectory(prefix="tuner-hostile42-") as tmp:
            rows = (hostile_cases.run(a.tree.resolve(), Path(tmp), big=not a.small, only=a.only) if a.files else
                    ulog_service(a.tree.resolve(), Path(tmp)))
        if a.out:
            a.out.write_text(json.dumps({"tree": str(a.tree), "cases": rows}, indent=2) + "\n")
        return
    a.generated, a.kills = max(0, min(a.generated, 2000)), max(0, min(a.kills, 10))
    results = []
    with tempfile.TemporaryDirectory(prefix="tuner-hostile-") as tmp:
        for db in (["sqlite", "postgres"] if a.db == "both" else [a.db]):
            r = campaign(db, a.generated, a.kills, a.seed, a.time_limit, Path(tmp))
            print(json.dumps(r), flush=True)
            results.append(r)
    load = None if a.no_load else load_test()
    summary = {"databases": results, "load": load}
    print(f"{'db':<9}{'tried':>7}{'2xx':>6}{'4xx':>6}{'5xx':>6}{'hangs':>7}{'faults':>8}{'ids ok':>8}")
    for r in results:
        ok = all(not f["ids_missing"] and f["solvers_left_after_15s"] == 0 for f in r["faults"])
        ids_ok = min((f["ids_read_back"] for f in r["faults"]), default=r.get("stored_ids", 0))
        print(f"{r['db']:<9}{r['tried']:>7}{r['2xx']:>6}{r['4xx']:>6}{r['5xx']:>6}{r['hangs']:>7}"
              f"{(str(len(r['faults'])) + (' ok' if ok else ' BAD')):>8}{ids_ok:>8}")
    print("load:", json.dumps(load))
    if a.out:
        a.out.write_text(json.dumps(summary, indent=2, default=lambda x: None if isinstance(x, float)
                                    and not math.isfinite(x) else str(x)) + "\n")


if __name__ == "__main__":
    main()
