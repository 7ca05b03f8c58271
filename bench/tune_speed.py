"""Issue 12's measurements, side by side in one run on one machine.

    .venv/bin/python bench/tune_speed.py [--quick] [--parts before_after,alternatives,cold,scaling,service,studies]

1. ``before_after``: every loop of studies/quadrotor.toml and studies/process.toml (and roll, pitch and yaw
   again with ``pid``) in two warm worker processes, ``before`` = the tree of ``--before-rev`` (extracted with
   ``git archive``, run with PYTHONPATH on it, same venv) and ``after`` = this tree: one warm-up tune per loop,
   then ``--seeds`` seeds, the two workers taking turns run by run (ABBA) so that the machine's load falls on
   both alike. Wall and CPU time per tune, the verifier's settling time, meets_spec.
2. ``alternatives``: Optuna alone and scipy's differential evolution, on the same verifier, until they reach
   our (worst-seed) settling time or ``--cap-s``; ratio of their time to our median.
3. ``cold``: ``tuner analyze`` (the README's roll example), ``tuner --help``, ``tuner tune`` and ``python -c
   "import tuner"`` against ``python -c "import numpy, scipy.linalg"``: interleaved runs, medians and ratios
   (hyperfine as a cross-check when installed; it runs each command's runs back to back).
4. ``scaling``: tune time and settling against plant order (1/(s+1)^n, pid) and horizon (1/(tau s+1)^2).
5. ``service``: single-client ``POST /tune`` p50/p99 (roll pid_z) and issue 6's load test (bench/service_load.py).
6. ``studies``: ``tuner study run studies/process.toml`` with 1 and 2 workers (bench/study_workers.py).

Prints Markdown; writes bench/results/tune_speed.json and .md (``--quick``: tune_speed_quick.*). The machine
may be shared: the load average is recorded beside each part. Nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("TUNER_NLP_COMPILE", "load")  # (no background compile beside timed runs: README, compiled code)

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import common  # noqa: E402
from common import ROOT, STUDIES, Loop, fmt, load_average  # noqa: E402
from tune_speed_report import QUALITY_TOL, markdown, ratio_cells  # noqa: E402

__all__ = ["PARTS", "parse_args", "measure", "save", "scaling", "ours_in_process"]

PARTS = ("before_after", "alternatives", "cold", "scaling", "service", "studies")
BEFORE_REV = "0cf62bb"  # the last landing before issue 12's work
WARM_SEED = 1000  # the warm-up tune's seed, apart from the measured seeds 0..N-1
ROLL = "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)"
ROLL_CONTROLLER = "3.868*(z^2-1.305*z+0.5668)/(z*(z-1))"


def log(msg: str) -> None:
    print(f"[tune_speed] {msg}", file=sys.stderr, flush=True)


def within(after: float, before: float, dt: float | None) -> bool:
    """After's settling time within 2 % or one sample of before's (or better)."""
    if not math.isfinite(before):
        return True
    return after <= max(before * (1 + QUALITY_TOL), before + (dt or 0.0))


def in_target(study: str, name: str, order: int) -> bool:
    """Issue 12's time target: the quadrotor attitude loops and the process plants of order <= 4."""
    base = name.split(" ")[0]
    return (study == "quadrotor" and base in common.ATTITUDE_PID) or (study == "process" and order <= 4)


def _num(x: Any) -> float:
    return float(x) if not isinstance(x, str) else float(x.replace("Infinity", "inf"))


# ---------------------------------------------------------------------------------------------- 1. before/after


class SpeedWorker:
    """A warm tuning process on one tree (bench/speed_worker.py), spoken to in JSON lines."""

    def __init__(self, name: str, tree: Path, logdir: Path, env: dict[str, str] | None = None) -> None:
        self.name, self.tree = name, tree
        self.stderr_path = logdir / f"{name}.stderr"
        env = {**os.environ, **(env or {}), "PYTHONPATH": str(tree)}
        self.proc = subprocess.Popen([sys.executable, str(HERE / "speed_worker.py")], cwd=tree, env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                     stderr=open(self.stderr_path, "w"))

    def call(self, **req: Any) -> dict[str, Any]:
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"{self.name} worker died:\n{self.stderr_path.read_text(errors='replace')[-3000:]}")
        ans = json.loads(line)
        if "error" in ans:
            raise RuntimeError(f"{self.name} worker: {ans['error']}\n{ans['traceback']}")
        return ans

    def close(self) -> None:
        try:
            self.proc.stdin.write('{"cmd": "quit"}\n')
            self.proc.stdin.flush()
            self.proc.wait(30)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()


def extract(rev: str, dest: Path) -> str:
    """``git archive rev | tar -x -C dest``; returns the full commit id."""
    sha = subprocess.run(["git", "-C", str(ROOT), "rev-parse", rev], check=True, capture_output=True,
                         text=True).stdout.strip()
    archive = subprocess.Popen(["git", "-C", str(ROOT), "archive", sha], stdout=subprocess.PIPE)
    subprocess.run(["tar", "-x", "-C", str(dest)], stdin=archive.stdout, check=True)
    archive.stdout.close()
    if archive.wait() != 0:
        raise RuntimeError(f"git archive {rev} failed")
    return sha


def _same_loop(b: dict, a: dict) -> list[str]:
    """Where the two trees' definitions of a loop differ (the spec on the fields both know)."""
    diff = [k for k in ("structure", "dt", "tune_kw") if b[k] != a[k]]
    rb, ra = np.asarray(b["response"]), np.asarray(a["response"])
    if rb.shape != ra.shape or not np.allclose(rb, ra, rtol=1e-6, atol=1e-12):
        diff.append("plants")
    common_keys = set(b["spec"]) & set(a["spec"])
    diff += [f"spec.{k}" for k in sorted(common_keys) if b["spec"][k] != a["spec"][k]]
    diff += [f"spec.{k} (after only: {a['spec'][k]})" for k in sorted(set(a["spec"]) - common_keys)
             if a["spec"][k] is not None]
    return diff


def _summary(runs: list[dict]) -> dict[str, Any]:
    ts = [_num(r["settling_s"]) if r["meets_spec"] else math.inf for r in runs]
    return {"median_wall_ms": 1000 * statistics.median(r["wall_s"] for r in runs),
            "median_cpu_ms": 1000 * statistics.median(r["cpu_s"] for r in runs),
            "max_wall_ms": 1000 * max(r["wall_s"] for r in runs),
            "median_settling_s": statistics.median(ts), "worst_settling_s": max(ts),
            "all_meet_spec": all(r["meets_spec"] for r in runs)}


THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")
ONE_THREAD = "after_1thread"  # diagnostic: this tree with one BLAS thread (as the service's solver processes run)


def before_after(a: argparse.Namespace) -> dict[str, Any]:
    tmp = Path(tempfile.mkdtemp(prefix="tune_speed_"))
    before_tree = tmp / "before"
    before_tree.mkdir()
    sha = extract(a.before_rev, before_tree)
    workers = {"before": SpeedWorker("before", before_tree, tmp), "after": SpeedWorker("after", ROOT, tmp)}
    if a.one_thread:
        workers[ONE_THREAD] = SpeedWorker(ONE_THREAD, ROOT, tmp, env=dict.fromkeys(THREAD_VARS, "1"))
    names = list(workers)
    try:
        defs: dict[str, dict] = {}
        for name, w in workers.items():
            studies = [[str(w.tree / "studies" / f), str(w.tree / "studies" / g) if g else None] for f, g in STUDIES]
            ans = w.call(cmd="loops", studies=studies, attitude_pid=list(common.ATTITUDE_PID) if a.attitude_pid else [])
            if Path(ans["tuner_file"]).resolve().parents[1] != w.tree.resolve():
                raise RuntimeError(f"the {name} worker imported tuner from {ans['tuner_file']}, not from {w.tree}")
            defs[name] = {f"{d['study']}/{d['name']}": d for d in ans["loops"]}
            log(f"{name} worker: tuner from {ans['tuner_file']}")
        labels = [k for k in defs["after"] if k in defs["before"] and _selected(a, k)]
        out: list[dict[str, Any]] = []
        for label in labels:
            load0 = load_average()
            for name in names:  # warm-up: imports, NLP builds, caches
                workers[name].call(cmd="tune", id=defs[name][label]["id"], seed=WARM_SEED, time_budget_s=a.budget_s)
            runs: dict[str, list[dict]] = {n: [] for n in names}
            for seed in range(a.seeds):  # the workers take turns: the order rotates seed by seed
                for name in names[seed % len(names):] + names[:seed % len(names)]:
                    runs[name].append({"seed": seed, **workers[name].call(
                        cmd="tune", id=defs[name][label]["id"], seed=seed, time_budget_s=a.budget_s)})
            out.append(_row(label, defs["before"][label], defs["after"][label], runs, load0))
            r = out[-1]
            log(f"{label}: before {r['before']['median_wall_ms']:.0f} ms ({fmt(r['before']['worst_settling_s'], 4)} "
                f"s), after {r['after']['median_wall_ms']:.0f} ms ({fmt(r['after']['worst_settling_s'], 4)} s); "
                f"quality {'ok' if r['quality_ok'] else 'WORSE'}; load {load0[0]}")
    finally:
        for w in workers.values():
            w.close()
        shutil.rmtree(tmp, ignore_errors=True)
    return {"before_rev": a.before_rev, "before_commit": sha, "seeds": a.seeds, "warm_seed": WARM_SEED,
            "budget_s": a.budget_s, "workers": names, "loops": out}


def _row(label: str, b: dict, af: dict, runs: dict[str, list[dict]], load0: list[float]) -> dict[str, Any]:
    sb, sa = _summary(runs["before"]), _summary(runs["after"])
    quality = (within(sa["worst_settling_s"], sb["worst_settling_s"], af["dt"])
               and within(sa["median_settling_s"], sb["median_settling_s"], af["dt"])
               and (sa["all_meet_spec"] or not sb["all_meet_spec"]))
    row = {"loop": label, "study": af["study"], "name": af["name"], "structure": af["structure"], "dt": af["dt"],
           "order": af["order"], "definition_differs": _same_loop(b, af),
           "before": {**sb, "runs": runs["before"]}, "after": {**sa, "runs": runs["after"]},
           "speedup_wall": sb["median_wall_ms"] / sa["median_wall_ms"],
           "speedup_cpu": sb["median_cpu_ms"] / sa["median_cpu_ms"], "quality_ok": quality,
           "in_target": in_target(af["study"], af["name"], af["order"]), "load_average": load0}
    if ONE_THREAD in runs:
        row[ONE_THREAD] = {**_summary(runs[ONE_THREAD]), "runs": runs[ONE_THREAD]}
    return row


def _selected(a: argparse.Namespace, label: str) -> bool:
    if not a.loops:
        return True
    names = set(a.loops.split(","))
    return label in names or label.split("/", 1)[1] in names


# ---------------------------------------------------------------------------------------------- 2. alternatives


def ours_in_process(lp: Loop, seeds: int, budget_s: float) -> dict[str, Any]:
    """Our tune of ``lp`` in this (warm) process: one warm-up, then seeds 0..seeds-1, each on freshly built
    plants (as in the worker processes)."""
    from tuner.tuning import tune

    def once(seed: int) -> dict[str, Any]:
        plants = lp.new_plants()
        c0, t0 = time.process_time(), time.perf_counter()
        r = tune(plants, structure=lp.structure, spec=lp.spec, dt=lp.dt, seed=seed, time_budget_s=budget_s,
                 **lp.tune_kw)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        return {"seed": seed, "wall_s": wall, "cpu_s": cpu, "meets_spec": r.meets_spec,
                "settling_s": max(x.metrics.settling_time_s for x in r.analyses)}

    once(WARM_SEED)
    return _summary([once(s) for s in range(seeds)])


def alternatives(a: argparse.Namespace, done: dict[str, Any]) -> dict[str, Any]:
    measured = {r["loop"]: r["after"] for r in done.get("before_after", {}).get("loops", [])}
    out = []
    for lp in common.load_loops(attitude_pid=a.attitude_pid):
        if not _selected(a, lp.label):
            continue
        ours = measured.get(lp.label) or ours_in_process(lp, a.seeds, a.budget_s)
        target = ours["worst_settling_s"]
        row: dict[str, Any] = {"loop": lp.label, "ours_median_ms": ours["median_wall_ms"], "target_settling_s": target,
                               "cap_s": a.cap_s, "load_average": load_average()}
        for name, run in (("optuna", common.run_optuna), ("de", common.run_de)):
            if not math.isfinite(target):
                row[name] = None
                continue
            b = run(lp, seed=0, target=target, cap_s=a.cap_s, max_evals=None)
            row[name] = {"to_equal_s": b.reached_s, "best_verified_s": b.best_verified, "evaluations": b.n,
                         "ratio": b.reached_s / (ours["median_wall_ms"] / 1000) if math.isfinite(b.reached_s)
                         else None, "ratio_at_least": a.cap_s / (ours["median_wall_ms"] / 1000)}
        out.append(row)
        log(f"alternatives {lp.label}: target {fmt(target, 4)} s; Optuna {ratio_cells(row['optuna'])[1]}, "
            f"DE {ratio_cells(row['de'])[1]}")
    return {"cap_s": a.cap_s, "loops": out}


# ---------------------------------------------------------------------------------------------- 3. cold start


def _tuner_cmd() -> list[str]:
    exe = Path(sys.executable).with_name("tuner")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "tuner.cli"]


def cold_commands() -> dict[str, list[str]]:
    py, tn = sys.executable, _tuner_cmd()
    return {
        "python -c 'import numpy, scipy.linalg'": [py, "-c", "import numpy, scipy.linalg"],
        "python -c 'import tuner'": [py, "-c", "import tuner"],
        "tuner --help": [*tn, "--help"],
        "tuner analyze (README roll example)": [*tn, "analyze", "--plant", ROLL, "--dt", "0.04", "--controller",
                                                ROLL_CONTROLLER],
        "tuner tune (roll pid_z)": [*tn, "tune", "--plant", ROLL, "--dt", "0.04", "--structure", "pid_z"],
    }


def _timed(cmd: list[str]) -> tuple[float, float, int]:
    """(wall s, CPU s of the process and its children, exit code)."""
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    p.returncode = os.waitstatus_to_exitcode(status)
    return wall, ru.ru_utime + ru.ru_stime, p.returncode


def cold(a: argparse.Namespace) -> dict[str, Any]:
    cmds = cold_commands()
    names = list(cmds)
    for n in names:  # one untimed round: the page cache, .pyc files
        _, _, rc = _timed(cmds[n])
        if rc not in (0, 1):
            raise RuntimeError(f"{n} exited with {rc}: {shlex.join(cmds[n])}")
    wall: dict[str, list[float]] = {n: [] for n in names}
    cpu: dict[str, list[float]] = {n: [] for n in names}
    load0 = load_average()
    for r in range(a.cold_runs):
        for n in names[r % len(names):] + names[:r % len(names)]:  # rotate the order round by round
            w, c, _ = _timed(cmds[n])
            wall[n].append(w)
            cpu[n].append(c)
    base = names[0]
    rows = {n: {"command": shlex.join(cmds[n]), "median_wall_s": statistics.median(wall[n]),
                "median_cpu_s": statistics.median(cpu[n]), "wall_s": wall[n],
                "ratio": statistics.median(wall[n]) / statistics.median(wall[base])} for n in names}
    out = {"runs": a.cold_runs, "baseline": base, "commands": rows, "load_average": [load0, load_average()]}
    if shutil.which("hyperfine") and not a.no_hyperfine:
        out["hyperfine"] = _hyperfine(cmds, a.cold_runs)
    return out


def _hyperfine(cmds: dict[str, list[str]], runs: int) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "h.json"
        subprocess.run(["hyperfine", "-N", "-i", "--warmup", "1", "--runs", str(runs), "--export-json", str(f),
                        *[shlex.join(c) for c in cmds.values()]], cwd=ROOT, check=True, capture_output=True)
        res = json.loads(f.read_text())["results"]
    return {n: r["median"] for n, r in zip(cmds, res)}


# ---------------------------------------------------------------------------------------------- 4. scaling


def scaling(seeds: int = 3, budget_s: float = 120.0, orders=range(1, 11),
            taus=(0.1, 0.3, 1.0, 3.0)) -> dict[str, list[dict[str, Any]]]:
    """Tune time (median over ``seeds`` after one warm-up) and settling against plant order (1/(s+1)^n,
    pid, dt 0.1 for n <= 4 else 0.2) and horizon (1/(tau s+1)^2, pid, dt 0.05)."""
    from tuner import make_plant

    def row(num: list[float], den: np.ndarray, dt: float) -> dict[str, Any]:
        def fresh() -> list:
            return [make_plant(num, den)]

        lp = Loop("scaling", "", fresh(), "pid", dt, common.Spec(), "", fresh=fresh)
        s = ours_in_process(lp, seeds, budget_s)
        return {"dt": dt, "median_wall_ms": s["median_wall_ms"], "median_cpu_ms": s["median_cpu_ms"],
                "median_settling_s": s["median_settling_s"], "worst_settling_s": s["worst_settling_s"],
                "all_meet_spec": s["all_meet_spec"]}

    out: dict[str, list[dict[str, Any]]] = {"orders": [], "horizons": []}
    for n in orders:
        out["orders"].append({"order": n, **row([1.0], np.poly(-np.ones(n)), 0.1 if n <= 4 else 0.2)})
        log(f"scaling order {n}: {out['orders'][-1]['median_wall_ms']:.0f} ms")
    for tau in taus:
        out["horizons"].append({"tau_s": tau, **row([1.0], np.polymul([tau, 1.0], [tau, 1.0]), 0.05)})
        log(f"scaling tau {tau}: {out['horizons'][-1]['median_wall_ms']:.0f} ms")
    return out


# ---------------------------------------------------------------------------------------------- 5. service, 6. studies


def service(a: argparse.Namespace) -> dict[str, Any]:
    import service_load

    with service_load.serve(2) as url:
        load0 = load_average()
        s = service_load.single(url, a.single)
        log(f"service single client: p50 {1000 * s['p50_s']:.0f} ms")
        ld = service_load.load_test(url, a.clients, a.requests)
        log(f"service load test: p50 {ld['p50_s']:.2f} s, p99 {ld['p99_s']:.2f} s, errors {ld['errors']}")
    s.pop("last_id")
    return {"solver_processes": 2, "single": s, "load": ld, "load_average": [load0, load_average()]}


def studies(a: argparse.Namespace) -> dict[str, Any]:
    import study_workers

    r = study_workers.compare("studies/process.toml", a.study_repeat, log=log,
                              variant_env=dict.fromkeys(THREAD_VARS, "1") if a.one_thread else None)
    return json.loads(json.dumps(r))  # worker counts as strings, as in the JSON file


# ---------------------------------------------------------------------------------------------- the run


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a short run (fewer seeds, runs and requests)")
    ap.add_argument("--parts", default=",".join(PARTS), help=f"comma-separated, of {','.join(PARTS)}")
    ap.add_argument("--loops", default="", help="comma-separated loop names or study/name (default: all)")
    ap.add_argument("--before-rev", default=BEFORE_REV)
    ap.add_argument("--seeds", type=int, default=None, help="measured seeds per loop (5; quick 2)")
    ap.add_argument("--budget-s", type=float, default=10.0, help="time_budget_s of each tune (the studies' 10)")
    ap.add_argument("--no-attitude-pid", dest="attitude_pid", action="store_false",
                    help="do not add roll, pitch and yaw with pid")
    ap.add_argument("--no-one-thread", dest="one_thread", action="store_false",
                    help="do not add the diagnostic worker: this tree with one BLAS/OpenMP thread")
    ap.add_argument("--cap-s", type=float, default=None, help="cap of Optuna and DE per loop (30; quick 5)")
    ap.add_argument("--cold-runs", type=int, default=None, help="interleaved runs per command (9; quick 3)")
    ap.add_argument("--no-hyperfine", action="store_true")
    ap.add_argument("--scaling-seeds", type=int, default=None, help="(3; quick 1)")
    ap.add_argument("--scaling-budget-s", type=float, default=120.0)
    ap.add_argument("--single", type=int, default=None, help="sequential single-client requests (30; quick 5)")
    ap.add_argument("--clients", type=int, default=8)
    ap.add_argument("--requests", type=int, default=None, help="load-test requests (100; quick 16)")
    ap.add_argument("--study-repeat", type=int, default=None, help="interleaved pairs of study runs (3; quick 1)")
    ap.add_argument("--profile", default=None, metavar="LOOP",
                    help="instead of measuring: cProfile of --seeds warm tunes of one loop (study/name), in-process")
    ap.add_argument("--out", default=None, help="output path without suffix (bench/results/tune_speed[_quick])")
    a = ap.parse_args(argv)
    q = a.quick
    for k, full, quick in (("seeds", 5, 2), ("cap_s", 30.0, 5.0), ("cold_runs", 9, 3), ("scaling_seeds", 3, 1),
                           ("single", 30, 5), ("requests", 100, 16), ("study_repeat", 3, 1)):
        if getattr(a, k) is None:
            setattr(a, k, quick if q else full)
    a.parts = [p for p in a.parts.split(",") if p]
    bad = sorted(set(a.parts) - set(PARTS))
    if bad:
        ap.error(f"--parts: unknown {', '.join(bad)}; choose from {','.join(PARTS)}")
    if a.out is None:
        a.out = str(HERE / "results" / ("tune_speed_quick" if q else "tune_speed"))
    return a


def measure(a: argparse.Namespace) -> dict[str, Any]:
    head = subprocess.run(["git", "-C", str(ROOT), "describe", "--always", "--dirty", "--exclude", "*"],
                          capture_output=True, text=True).stdout.strip()
    res: dict[str, Any] = {"when_utc": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "machine": common.machine(),
                           "after_commit": head, "args": dict(vars(a)), "load_average_start": load_average()}
    runners: dict[str, Callable[[], dict[str, Any]]] = {
        "before_after": lambda: before_after(a), "alternatives": lambda: alternatives(a, res),
        "cold": lambda: cold(a),
        "scaling": lambda: scaling(a.scaling_seeds, a.scaling_budget_s,
                                   *(((1, 2, 4, 10), (0.1, 3.0)) if a.quick else ())),
        "service": lambda: service(a), "studies": lambda: studies(a)}
    for part in PARTS:
        if part in a.parts:
            log(f"part {part} (load average {load_average()})")
            t0 = time.perf_counter()
            res[part] = runners[part]()
            res[part]["part_wall_s"] = time.perf_counter() - t0
    res["load_average_end"] = load_average()
    return res


def save(res: dict[str, Any], out: str) -> str:
    """Write ``out``.json and ``out``.md; returns the Markdown."""
    md = markdown(res)
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.with_suffix(".json").write_text(json.dumps(res, indent=1, default=str) + "\n")
    path.with_suffix(".md").write_text(md)
    return md


def profile(a: argparse.Namespace) -> None:
    """cProfile of ``a.seeds`` warm tunes of one loop (two warm-ups first, fresh plants each), sorted by own time
    and by cumulative time. Run it with ``OPENBLAS_NUM_THREADS=1`` to see what the BLAS threads cost."""
    import cProfile
    import pstats

    from tuner.tuning import tune

    (lp,) = [x for x in common.load_loops(attitude_pid=True) if x.label == a.profile] or [None]
    if lp is None:
        raise SystemExit(f"--profile: no loop {a.profile!r}; give study/name, e.g. process/lag4")

    def once(seed: int) -> None:
        tune(lp.new_plants(), structure=lp.structure, spec=lp.spec, dt=lp.dt, seed=seed, time_budget_s=a.budget_s,
             **lp.tune_kw)

    for s in (WARM_SEED, WARM_SEED + 1):
        once(s)
    prof = cProfile.Profile()
    c0, t0 = time.process_time(), time.perf_counter()
    prof.runcall(lambda: [once(s) for s in range(a.seeds)])
    print(f"{lp.label}: {a.seeds} tunes under cProfile, per tune {1000 * (time.perf_counter() - t0) / a.seeds:.0f} ms "
          f"wall, {1000 * (time.process_time() - c0) / a.seeds:.0f} ms CPU")
    for key in ("tottime", "cumulative"):
        pstats.Stats(prof).sort_stats(key).print_stats(25)


def main(argv: list[str] | None = None) -> int:
    a = parse_args(argv)
    if a.profile:
        profile(a)
        return 0
    print(save(measure(a), a.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
