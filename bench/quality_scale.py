"""The quality suite as a study on 1 and on 2 workers sharing one PostgreSQL storage, measured in one run.

    python bench/quality_scale.py [--every 9] [--url postgresql+psycopg://postgres@127.0.0.1:5432/test]

Each worker is a separate ``tuner study run`` process that shares nothing with the other but the storage URL and
the study file (as a worker on a second host would). The same slice of the suite (every ``--every``-th case,
over all classes and structures) is run first by one worker, then, under a fresh study name, by two; the walls
and their ratio go to bench/results/quality_scale.json. Nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(ROOT), str(HERE)]

import quality  # noqa: E402


def _workers(study: Path, url: str, n: int, out: Path) -> tuple[float, list[float], dict[str, int]]:
    """Wall of the whole run, CPU seconds of each worker (os.wait4), loops tuned by each worker."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    procs = [subprocess.Popen([sys.executable, "-m", "tuner.cli", "study", "run", str(study), "--storage", url,
                               "--out", str(out / f"w{i}"), "--no-plots"], cwd=ROOT, env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for i in range(n)]
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
    for r in doc["loops"].values():
        per[str(r.get("worker"))] = per.get(str(r.get("worker")), 0) + 1
    return wall, cpu, per


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--every", type=int, default=9, help="every N-th case of the suite (1: all of it)")
    ap.add_argument("--url", default="postgresql+psycopg://postgres@127.0.0.1:5432/test")
    ap.add_argument("--effort", default="default")
    ap.add_argument("--budget", type=float, default=10.0)
    a = ap.parse_args()
    from tuner.studies.runner import delete_study_records, open_storage

    cases = quality.load_suite()[::a.every]
    storage = open_storage(a.url)  # Optuna's tables exist before the workers start
    walls, cpus, split = {}, {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for n in (1, 2):
            name = f"quality_scale_{n}_{uuid.uuid4().hex[:8]}"
            f = Path(tmp) / f"{name}.toml"
            f.write_text(quality.study_toml(cases, name=name, budget=a.budget, effort=a.effort))
            try:
                walls[n], cpus[n], split[n] = _workers(f, a.url, n, Path(tmp) / name)
            finally:
                delete_study_records(storage, name)
            print(f"{n} worker(s): {walls[n]:.1f} s for {len(cases)} loops; CPU s per worker "
                  f"{[round(c, 1) for c in cpus[n]]}; loops per worker {sorted(split[n].values())}", flush=True)
    load = os.getloadavg()
    doc = {"command": "python bench/quality_scale.py " + " ".join(sys.argv[1:]), "loops": len(cases),
           "cases": [c["id"] for c in cases], "walls_s": walls, "speedup": walls[1] / walls[2],
           "cpu_s_per_worker": cpus, "loops_per_worker": split,
           # what the wall ratio would be with a free core per worker: the one worker's CPU over the busier
           # of the two (the load of others on the shared machine does not enter)
           "cpu_bound_speedup": sum(cpus[1]) / max(cpus[2]),
           "load_average_end": load, "cores": os.cpu_count()}
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "quality_scale.json").write_text(json.dumps(doc, indent=1))
    print(f"speed-up 2 vs 1 workers: {doc['speedup']:.2f}x wall (load average at the end {load[0]:.1f}); "
          f"CPU-bound {doc['cpu_bound_speedup']:.2f}x")


if __name__ == "__main__":
    main()
