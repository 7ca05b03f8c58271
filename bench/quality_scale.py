"""The quality suite as a study on 1 and on 2 workers sharing one PostgreSQL storage, measured in one run.

    python bench/quality_scale.py [--every 9] [--rounds 3] [--fork] [--workers 1,2,4]
                                  [--url postgresql+psycopg://postgres@127.0.0.1:5432/test]

Each worker is a separate ``tuner study run`` process that shares nothing with the other but the storage URL and
the study file (as a worker on a second host would); with ``--fork``, one ``tuner study run --workers N`` command
(its workers forked from it, as on one machine). The same slice of the suite (every ``--every``-th case, over all
classes and structures) is run first by one worker, then, under a fresh study name, by two (``--workers``: the
counts; ``--rounds`` times, alternating); the walls and their ratios go to bench/results/quality_scale.json
(``--fork``: quality_scale_fork.json; ``--every N`` other than 1: ..._everyN.json). Nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(ROOT), str(HERE)]

import quality  # noqa: E402


def _workers(study: Path, url: str, n: int, out: Path, fork: bool = False
             ) -> tuple[float, list[float], dict[str, int], dict[str, float], dict[str, list[Any]]]:
    """Wall of the whole run, CPU seconds of each worker (os.wait4; ``fork``: of the one command and its workers),
    loops tuned by each worker, the walls of its loops' tunes added up (what is left of the worker's wall went to
    claims, storage and waiting), each loop's worker and tune wall."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "tuner.cli", "study", "run", str(study), "--storage", url, "--no-plots"]
    procs = [subprocess.Popen(cmd + ["--out", str(out / "w0"), "--workers", str(n)], cwd=ROOT, env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)] if fork else \
        [subprocess.Popen(cmd + ["--out", str(out / f"w{i}")], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                          stderr=subprocess.DEVNULL) for i in range(n)]
    cpu = []
    for p in procs:
        _, status, ru = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
        if p.returncode not in (0, 1):
            raise SystemExit(f"worker failed ({p.returncode})")
        cpu.append(ru.ru_utime + ru.ru_stime)
    wall = time.perf_counter() - t0
    doc = json.loads((out / "w0" / "results.json").read_text())
    per: dict[str, int] = {}
    tuning: dict[str, float] = {}
    loops: dict[str, list[Any]] = {}
    for name, r in doc["loops"].items():
        w = str(r.get("worker"))
        loops[name] = [w, r.get("wall_time_s")]
        per[w] = per.get(w, 0) + 1
        tuning[w] = tuning.get(w, 0.0) + float(r.get("wall_time_s") or 0.0)
    return wall, cpu, per, tuning, loops


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--every", type=int, default=9, help="every N-th case of the suite (1: all of it)")
    ap.add_argument("--url", default="postgresql+psycopg://postgres@127.0.0.1:5432/test")
    ap.add_argument("--effort", default="default")
    ap.add_argument("--budget", type=float, default=10.0)
    ap.add_argument("--rounds", type=int, default=1, help="1 then 2 workers, this many times (the median ratio)")
    ap.add_argument("--fork", action="store_true",
                    help="one `tuner study run --workers N` command (workers forked from it) instead of N commands")
    ap.add_argument("--workers", default="1,2", help="the worker counts of a round, after 1 (e.g. 1,2,4)")
    a = ap.parse_args()
    counts = sorted({1, *(int(x) for x in a.workers.split(","))})
    from tuner.studies.runner import delete_study_records, open_storage

    cases = quality.load_suite()[::a.every]
    storage = open_storage(a.url)  # Optuna's tables exist before the workers start
    runs: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for rnd in range(a.rounds):
            for n in counts:  # alternating: a slower or faster spell of the shared machine falls on both
                name = f"quality_scale_{n}_{uuid.uuid4().hex[:8]}"
                f = Path(tmp) / f"{name}.toml"
                f.write_text(quality.study_toml(cases, name=name, budget=a.budget, effort=a.effort))
                try:
                    wall, cpu, split, tuning, loops = _workers(f, a.url, n, Path(tmp) / name, fork=a.fork)
                finally:
                    delete_study_records(storage, name)
                runs.append({"round": rnd, "workers": n, "wall_s": wall, "cpu_s_per_worker": cpu,
                             "loops_per_worker": split, "tuning_s_per_worker": tuning,
                             "loop_worker_and_tune_s": loops})
                print(f"round {rnd + 1}, {n} worker(s): {wall:.1f} s for {len(cases)} loops; CPU s per worker "
                      f"{[round(c, 1) for c in cpu]}; loops per worker {sorted(split.values())}; "
                      f"tuning s per worker {sorted(round(t, 1) for t in tuning.values())}", flush=True)
    load = os.getloadavg()
    by = {(r["round"], r["workers"]): r for r in runs}
    ratios = {n: [by[(k, 1)]["wall_s"] / by[(k, n)]["wall_s"] for k in range(a.rounds)] for n in counts if n > 1}
    speedups = ratios.get(2, [])
    # what the wall ratio would be with a free core per worker: the one worker's CPU over the busier of the two
    # (separate commands only: a forked run's CPU is the command's and its workers' together)
    cpu_bound = [] if a.fork or 2 not in counts else \
        [sum(by[(k, 1)]["cpu_s_per_worker"]) / max(by[(k, 2)]["cpu_s_per_worker"]) for k in range(a.rounds)]
    # the loops' own tunes: the workers' added up over the one worker's (1: more cores cost the tunes nothing; what
    # is above 1 is what a tune loses when the cores are busy and to builds another worker made)
    tune_sum = {n: [sum(by[(k, n)]["tuning_s_per_worker"].values()) / max(
        1e-9, sum(by[(k, 1)]["tuning_s_per_worker"].values())) for k in range(a.rounds)] for n in ratios}
    doc = {"command": "python bench/quality_scale.py " + " ".join(sys.argv[1:]), "loops": len(cases),
           "mode": "one command, --workers N" if a.fork else "N commands", "cases": [c["id"] for c in cases],
           "runs": runs, "speedup_per_round": speedups, "speedup": statistics.median(speedups) if speedups else None,
           "speedup_by_workers": {str(n): {"per_round": r, "median": statistics.median(r)} for n, r in ratios.items()},
           "cpu_bound_speedup_per_round": cpu_bound,
           "two_workers_tune_s_over_one": tune_sum.get(2, []),
           "tune_s_over_one_by_workers": {str(n): t for n, t in tune_sum.items()},
           "load_average_end": load, "cores": os.cpu_count()}
    (HERE / "results").mkdir(exist_ok=True)
    name = "quality_scale" + ("_fork" if a.fork else "") + (f"_every{a.every}" if a.every != 1 else "") + ".json"
    (HERE / "results" / name).write_text(json.dumps(doc, indent=1))
    for n, r in ratios.items():
        print(f"speed-up {n} vs 1 workers: {', '.join(f'{x:.2f}x' for x in r)} (median {statistics.median(r):.2f}x); "
              f"the workers' tunes over one's {', '.join(f'{x:.3f}' for x in tune_sum[n])}")
    if cpu_bound:
        print(f"CPU-bound 2 vs 1: {', '.join(f'{x:.2f}x' for x in cpu_bound)}")
    print(f"load average at the end {load[0]:.1f}; {os.cpu_count()} cores -> bench/results/{name}")


if __name__ == "__main__":
    main()
