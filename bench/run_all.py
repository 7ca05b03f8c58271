"""All benchmarks in one run on one machine: quality against the best possible, speed against the
alternatives, scaling, batch throughput and a service load test. Writes bench/RESULTS.md.

    bench/run            (= .venv/bin/python bench/run_all.py)

Nothing here asserts a timing: timings are reported, and ratios are measured in the same run.
Every settling time is the verifier's, at full resolution, on the loop's plants (worst case).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

from tuner import Spec, get_structure, make_plant  # noqa: E402
from tuner.optimize.engine import designed_starts  # noqa: E402
from tuner.optimize.scoring import Evaluator  # noqa: E402
from tuner.optimize.space import make_space  # noqa: E402
from tuner.plant import Plant  # noqa: E402
from tuner.studies.evaluate import check_gains_file, evaluate_thesis, loop_plants  # noqa: E402
from tuner.studies.schema import load_study  # noqa: E402
from tuner.tuning import tune  # noqa: E402

REFERENCE_CACHE = HERE / "reference.json"
QUALITY_TOL = 0.02  # "within 2 % (or one sample) of the reference"


@dataclass
class Loop:
    study: str
    name: str
    plants: list[Plant]
    structure: str
    dt: float | None
    spec: Spec
    key: str
    thesis_settling: float | None = None
    tune_kw: dict[str, Any] = field(default_factory=dict)  # the loop's own n_trials / n_starts
    results: dict[str, Any] = field(default_factory=dict)


def machine() -> dict[str, str]:
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import casadi
    import control
    import optuna
    import scipy

    return {"cpu": cpu, "cores": str(os.cpu_count()), "python": platform.python_version(),
            "os": platform.platform(), "numpy": np.__version__, "scipy": scipy.__version__,
            "control": control.__version__, "casadi": casadi.__version__, "optuna": optuna.__version__}


def load_loops() -> list[Loop]:
    loops: list[Loop] = []
    for fname, gains in (("quadrotor.toml", "quadrotor.gains.json"), ("process.toml", None)):
        study = load_study(ROOT / "studies" / fname)
        ctrls = {}
        if gains:
            ctrls = check_gains_file(study, json.loads((ROOT / "studies" / gains).read_text()))
        thesis = evaluate_thesis(study, ctrls) if gains else {}
        for lp in study.order():
            plants = loop_plants(study, lp, ctrls)
            th = thesis.get(lp.name)
            ts = None
            if th is not None:
                ts = max(a.metrics.settling_time_s if a.metrics.stable else math.inf for a in th.analyses)
            key = json.dumps([fname, lp.name, lp.structure, lp.dt, [p.describe() for p in plants],
                              lp.spec.model_dump()], sort_keys=True, default=str)
            kw = {k: v for k, v in (("n_trials", lp.n_trials), ("n_starts", lp.n_starts)) if v is not None}
            loops.append(Loop(study.name, lp.name, plants, lp.structure, lp.dt, lp.spec, key, ts, kw))
    return loops


def verified(ev: Evaluator, x: np.ndarray) -> float:
    """The verifier's settling time at full resolution (worst over the plants); inf if infeasible."""
    s = ev.score(x, full=True)
    return s.score if s.feasible else math.inf


class Budgeted:
    """An objective that records the best search-resolution candidate and can stop at a target."""

    def __init__(self, ev: Evaluator, space, *, target: float | None, cap_s: float, max_evals: int | None):
        self.ev, self.space, self.target, self.cap_s, self.max_evals = ev, space, target, cap_s, max_evals
        self.t0 = time.perf_counter()
        self.n = 0
        self.best = (math.inf, None)
        self.reached_s = math.inf
        self.best_verified = math.inf

    class Stop(Exception):
        pass

    def __call__(self, v: np.ndarray) -> float:
        if time.perf_counter() - self.t0 > self.cap_s or (self.max_evals and self.n >= self.max_evals):
            raise Budgeted.Stop
        self.n += 1
        s = self.ev.score(self.space.params(v)).score
        if s < self.best[0]:
            self.best = (s, np.array(v, dtype=float))
            if self.target is not None and s < 1e3 and s <= self.target * 1.05:
                ts = verified(self.ev, self.space.params(v))
                self.best_verified = min(self.best_verified, ts)
                if ts <= self.target:
                    self.reached_s = time.perf_counter() - self.t0
                    raise Budgeted.Stop
        return s

    def finish(self) -> float:
        if self.best[1] is not None:
            self.best_verified = min(self.best_verified, verified(self.ev, self.space.params(self.best[1])))
        return self.best_verified


def run_optuna(lp: Loop, *, seed: int, target: float | None, cap_s: float, max_evals: int | None) -> Budgeted:
    import optuna

    from tuner.optimize.search import default_sampler

    st = get_structure(lp.structure)
    space = make_space(st, lp.plants[0], lp.dt)
    b = Budgeted(Evaluator(lp.plants, st, lp.dt, lp.spec), space, target=target, cap_s=cap_s, max_evals=max_evals)
    study = optuna.create_study(direction="minimize", sampler=default_sampler(seed, len(space.names)))
    dists = {n: optuna.distributions.FloatDistribution(float(a), float(z))
             for n, a, z in zip(space.names, space.lo, space.hi)}
    for v in designed_starts(space, lp.plants[0], lp.dt):
        study.enqueue_trial(dict(zip(space.names, map(float, v))))
    try:
        while True:
            tr = study.ask(dists)
            study.tell(tr, b(np.array([tr.params[n] for n in space.names])))
    except Budgeted.Stop:
        pass
    b.finish()
    return b


def run_de(lp: Loop, *, seed: int, target: float | None, cap_s: float, max_evals: int | None,
           popsize: int = 15) -> Budgeted:
    from scipy.optimize import differential_evolution

    st = get_structure(lp.structure)
    space = make_space(st, lp.plants[0], lp.dt)
    b = Budgeted(Evaluator(lp.plants, st, lp.dt, lp.spec), space, target=target, cap_s=cap_s, max_evals=max_evals)
    try:
        differential_evolution(b, list(zip(space.lo, space.hi)), seed=seed, popsize=popsize, maxiter=100000,
                               tol=0, atol=0, polish=False, init="sobol")
    except Budgeted.Stop:
        pass
    b.finish()
    return b


def reference(lp: Loop, cache: dict[str, Any], evals: int) -> float:
    """Brute-force reference: a long differential evolution (cached: computed once)."""
    if lp.key in cache:
        return float(cache[lp.key]["settling_s"])
    t0 = time.perf_counter()
    best = min(run_de(lp, seed=s, target=None, cap_s=1e9, max_evals=evals // 2).best_verified for s in (0, 1))
    cache[lp.key] = {"loop": f"{lp.study}/{lp.name}", "settling_s": best, "evaluations": evals,
                     "seconds": time.perf_counter() - t0}
    REFERENCE_CACHE.write_text(json.dumps(cache, indent=1, default=str))
    return best


def ours(lp: Loop, repeats: int) -> tuple[list[float], float]:
    tune(lp.plants, structure=lp.structure, spec=lp.spec, dt=lp.dt, seed=0, time_budget_s=120, **lp.tune_kw)  # warm
    times, settles = [], []
    for seed in range(repeats):
        t0 = time.perf_counter()
        r = tune(lp.plants, structure=lp.structure, spec=lp.spec, dt=lp.dt, seed=seed, time_budget_s=120,
                 **lp.tune_kw)
        times.append(time.perf_counter() - t0)
        settles.append(max(a.metrics.settling_time_s for a in r.analyses) if r.meets_spec else math.inf)
    return times, max(settles)


def fmt(x: float, d: int = 3) -> str:
    if x is None:
        return "—"
    if isinstance(x, str):
        return x
    if math.isinf(x):
        return "∞"
    return f"{x:.{d}f}"


def quality_and_speed(loops: list[Loop], a: argparse.Namespace) -> None:
    cache = json.loads(REFERENCE_CACHE.read_text()) if REFERENCE_CACHE.exists() else {}
    for lp in loops:
        print(f"[bench] {lp.study}/{lp.name}", flush=True)
        times, ts = ours(lp, a.repeats)
        ref = reference(lp, cache, a.reference_evals)
        best = min(ref, ts)
        fixed_o = run_optuna(lp, seed=0, target=None, cap_s=1e9, max_evals=a.fixed_evals)
        fixed_d = run_de(lp, seed=0, target=None, cap_s=1e9, max_evals=a.fixed_evals)
        eq_o = run_optuna(lp, seed=0, target=ts, cap_s=a.cap_s, max_evals=None) if math.isfinite(ts) else None
        eq_d = run_de(lp, seed=0, target=ts, cap_s=a.cap_s, max_evals=None) if math.isfinite(ts) else None
        lp.results = {
            "ours_settling_s": ts, "ours_median_s": statistics.median(times),
            "ours_p95_s": float(np.percentile(times, 95)), "ref_settling_s": ref, "best_known_s": best,
            "optuna_fixed_settling_s": fixed_o.best_verified, "optuna_fixed_s": time.perf_counter() - fixed_o.t0,
            "de_fixed_settling_s": fixed_d.best_verified,
            "optuna_to_equal_s": eq_o.reached_s if eq_o else math.inf,
            "de_to_equal_s": eq_d.reached_s if eq_d else math.inf,
        }
        print(f"        ours {ts:.4f} s in {statistics.median(times):.2f} s; reference {ref:.4f}; "
              f"optuna->equal {fmt(lp.results['optuna_to_equal_s'], 1)} s; "
              f"de->equal {fmt(lp.results['de_to_equal_s'], 1)} s",
              flush=True)


def scaling(a: argparse.Namespace) -> tuple[list[tuple[int, float, float]], list[tuple[float, float, float]]]:
    orders = []
    for n in range(1, 11):
        p = make_plant([1.0], np.poly(-np.ones(n)))
        dt = 0.1 if n <= 4 else 0.2
        tune(p, structure="pid", dt=dt, time_budget_s=120)
        t0 = time.perf_counter()
        r = tune(p, structure="pid", dt=dt, time_budget_s=120)
        orders.append((n, time.perf_counter() - t0, r.analyses[0].metrics.settling_time_s))
    horizons = []
    for tau in (0.1, 0.3, 1.0, 3.0):
        p = make_plant([1.0], np.polymul([tau, 1.0], [tau, 1.0]))
        tune(p, structure="pid", dt=0.05, time_budget_s=120)
        t0 = time.perf_counter()
        r = tune(p, structure="pid", dt=0.05, time_budget_s=120)
        horizons.append((tau, time.perf_counter() - t0, r.analyses[0].metrics.settling_time_s))
    return orders, horizons


def batch(workers: int) -> tuple[float, int]:
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "tuner.cli", "study", "run", str(ROOT / "studies" / "process.toml"),
                        "--workers", str(workers), "--out", d], check=True, cwd=ROOT,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        n = len(json.loads((Path(d) / "results.json").read_text())["loops"])
    return wall, n


def service_load(clients: int, requests: int) -> dict[str, Any]:
    """POST /tune on loopback: `clients` concurrent clients, `requests` in all (bounded, stops itself)."""
    import socket
    import threading

    import httpx

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with tempfile.TemporaryDirectory() as d:
        env = {**os.environ, "TUNER_DATABASE_URL": f"sqlite:///{d}/load.db", "TUNER_WORKERS": "2",
               "TUNER_QUEUE_SIZE": str(clients * 2)}
        proc = subprocess.Popen([sys.executable, "-m", "uvicorn", "api.main:create_app", "--factory",
                                 "--host", "127.0.0.1", "--port", str(port)], cwd=ROOT, env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            base = f"http://127.0.0.1:{port}"
            for _ in range(200):
                try:
                    if httpx.get(base + "/health", timeout=1).status_code == 200:
                        break
                except httpx.HTTPError:
                    time.sleep(0.1)
            body = {"plant": {"expr": "0.2843*18.611/(s+18.611)"}, "dt": 0.04, "structure": "pi",
                    "options": {"seed": 0, "time_budget_s": 10}}
            lat: list[float] = []
            errors: dict[str, int] = {}
            lock = threading.Lock()
            todo = list(range(requests))

            def client() -> None:
                with httpx.Client(base_url=base, timeout=60) as c:
                    while True:
                        with lock:
                            if not todo:
                                return
                            todo.pop()
                        t0 = time.perf_counter()
                        try:
                            r = c.post("/tune", json=body)
                            code = str(r.status_code)
                        except httpx.HTTPError as e:
                            code = type(e).__name__
                        with lock:
                            lat.append(time.perf_counter() - t0)
                            if code != "200":
                                errors[code] = errors.get(code, 0) + 1

            t0 = time.perf_counter()
            threads = [threading.Thread(target=client) for _ in range(clients)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            wall = time.perf_counter() - t0
        finally:
            proc.terminate()
            proc.wait(10)
    return {"clients": clients, "requests": requests, "wall_s": wall, "throughput_rps": requests / wall,
            "p50_s": float(np.percentile(lat, 50)), "p99_s": float(np.percentile(lat, 99)), "errors": errors}


def write_results(m: dict[str, str], loops: list[Loop], orders, horizons, batches, load, a) -> str:
    when = time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())
    L: list[str] = ["# Benchmark results", "", f"Written by `bench/run` on {when}.", ""]
    L += ["## Machine", ""] + [f"- {k}: {v}" for k, v in m.items()] + [""]
    L += ["## Quality: settling time (s) and ratio to the reference", "",
          "Reference = the best of two long differential-evolution runs "
          f"({a.reference_evals} verifier evaluations in all, cached in `bench/reference.json`), judged by the "
          "same verifier at full resolution. Optuna and DE with a fixed budget of "
          f"{a.fixed_evals} evaluations. Ratios below 1 are better than the reference.", "",
          "| loop | thesis as printed | reference | ours | ours/ref | Optuna (fixed) | Optuna/ref | DE (fixed) "
          "| DE/ref | target met |",
          "|---|---|---|---|---|---|---|---|---|---|"]
    miss = []
    for lp in loops:
        r = lp.results
        ref = r["ref_settling_s"]
        def ratio(x: float, ref: float = ref) -> float:
            return x / ref if math.isfinite(ref) and ref > 0 and math.isfinite(x) else math.inf

        ours = r["ours_settling_s"]
        ok = ours <= max(ref * (1 + QUALITY_TOL), ref + (lp.dt or 0)) if math.isfinite(ref) else math.isfinite(ours)
        if not ok:
            miss.append(f"{lp.study}/{lp.name}")
        L.append(f"| {lp.study}/{lp.name} | {fmt(lp.thesis_settling)} | {fmt(ref)} | {fmt(r['ours_settling_s'])} | "
                 f"{fmt(ratio(r['ours_settling_s']), 2)} | {fmt(r['optuna_fixed_settling_s'])} | "
                 f"{fmt(ratio(r['optuna_fixed_settling_s']), 2)} | {fmt(r['de_fixed_settling_s'])} | "
                 f"{fmt(ratio(r['de_fixed_settling_s']), 2)} | {'yes' if ok else '**no**'} |")
    L += ["", "Quality target (within 2 % or one sample of the reference, or better): "
          + ("met on every loop." if not miss else f"**missed on {', '.join(miss)}**."), ""]
    L += ["## Speed: wall time per tune and time for the alternatives to reach our settling time", "",
          f"Ours: median and p95 over {a.repeats} seeds in a warm process. Alternatives: one seeded run each until the "
          f"full verifier confirms a settling time <= ours, capped at {a.cap_s:.0f} s (∞ = not reached).", "",
          "| loop | ours median s | ours p95 s | Optuna to equal s | Optuna/ours | DE to equal s | DE/ours |",
          "|---|---|---|---|---|---|---|"]
    for lp in loops:
        r = lp.results
        med = r["ours_median_s"]

        def rt(x: float, med: float = med) -> str:
            return f"≥ {a.cap_s / med:.0f}" if not math.isfinite(x) else f"{x / med:.1f}"

        L.append(f"| {lp.study}/{lp.name} | {fmt(med, 2)} | {fmt(r['ours_p95_s'], 2)} | "
                 f"{fmt(r['optuna_to_equal_s'], 1)} | "
                 f"{rt(r['optuna_to_equal_s'])} | {fmt(r['de_to_equal_s'], 1)} | {rt(r['de_to_equal_s'])} |")
    small = [lp.results["ours_median_s"] for lp in loops if max(p.order for p in lp.plants) <= 4]
    L += ["", f"Median tune time over loops with plant order <= 4: {statistics.median(small):.2f} s "
          f"(target < 0.5 s: {'met' if statistics.median(small) < 0.5 else '**missed**'}).", ""]
    L += ["## Scaling", "", "Plant 1/(s+1)^n, structure pid (dt 0.1 for n <= 4, else 0.2), one warm tune each:", "",
          "| order | tune s | settling s |", "|---|---|---|"]
    L += [f"| {n} | {t:.2f} | {fmt(ts)} |" for n, t, ts in orders]
    L += ["", "Response horizon: plant 1/(tau s+1)^2 at dt 0.05 (slower plant = longer horizon in samples):", "",
          "| tau s | tune s | settling s |", "|---|---|---|"]
    L += [f"| {tau} | {t:.2f} | {fmt(ts)} |" for tau, t, ts in horizons]
    L += ["", "## Batch throughput (`tuner study run studies/process.toml`, fresh storage, process start included)", "",
          "| workers | loops | wall s | loops/s |", "|---|---|---|---|"]
    L += [f"| {w} | {n} | {t:.1f} | {n / t:.2f} |" for w, (t, n) in batches.items()]
    if load:
        L += ["", "## Service load test (`POST /tune`, loopback, 2 pool workers)", "",
              "| clients | requests | wall s | req/s | p50 s | p99 s | errors |", "|---|---|---|---|---|---|---|",
              f"| {load['clients']} | {load['requests']} | {load['wall_s']:.1f} | {load['throughput_rps']:.2f} | "
              f"{load['p50_s']:.2f} | {load['p99_s']:.2f} | {sum(load['errors'].values())} {load['errors'] or ''} |"]
    return "\n".join(L) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--reference-evals", type=int, default=20000)
    ap.add_argument("--fixed-evals", type=int, default=500)
    ap.add_argument("--cap-s", type=float, default=60.0)
    ap.add_argument("--clients", type=int, default=8)
    ap.add_argument("--requests", type=int, default=200)
    ap.add_argument("--only", default=None, help="comma-separated loop names (quick runs)")
    ap.add_argument("--skip", default="", help="comma-separated parts to skip: quality,scaling,batch,service")
    a = ap.parse_args()
    skip = set(filter(None, a.skip.split(",")))
    m = machine()
    loops = load_loops()
    if a.only:
        loops = [lp for lp in loops if lp.name in a.only.split(",")]
    if "quality" not in skip:
        quality_and_speed(loops, a)
    orders, horizons = scaling(a) if "scaling" not in skip else ([], [])
    batches = {w: batch(w) for w in (1, 2)} if "batch" not in skip else {}
    load = service_load(a.clients, a.requests) if "service" not in skip else None
    text = write_results(m, [lp for lp in loops if lp.results], orders, horizons, batches, load, a)
    (HERE / "RESULTS.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
