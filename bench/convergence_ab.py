"""What a change to the search costs, in one run: convergence-suite cases tuned warm by this tree and an older one.

    python bench/convergence_ab.py [--rev 3287989] [--every 5] [--out bench/results/convergence_ab.json]

Two worker processes, one per tree (the older one extracted with ``git archive``; this tree as it is), each with one
BLAS thread; every ``--every``-th case of ``bench/convergence.py``'s suite (thesis spec, default effort and budget,
seed 0) goes to both, the order alternating case by case, twice: the first pass builds each process's NLPs, the
second is counted. Reported: each tree's CPU and wall added up, the ratio of the sums and the median per-case CPU
ratio, and the cases whose objective differs. Nothing here asserts a timing.
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
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(ROOT), str(HERE)]

WORKER = """
import json, sys, time
sys.path.insert(0, sys.argv[1] + "/bench")
import convergence, quality
from tuner.spec import Spec
from tuner.tuning import tune
cases = {c["id"]: c for c in convergence.suite()}
for line in sys.stdin:
    c = cases[line.strip()]
    plant = quality.plant_of(c)
    t, c0 = time.perf_counter(), time.process_time()
    r = tune(plant, structure=c["structure"], dt=c["dt"], spec=Spec.thesis(), seed=0, diagnose=False)
    print(json.dumps({"id": c["id"], "wall": time.perf_counter() - t, "cpu": time.process_time() - c0,
                      "objective": float(r.objective), "meets": bool(r.meets_spec)}), flush=True)
"""


def _worker(tree: Path, script: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    return subprocess.Popen([sys.executable, str(script), str(tree)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True, env=env, cwd=tree)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rev", default="3287989", help="the older tree (a git revision)")
    ap.add_argument("--every", type=int, default=5)
    ap.add_argument("--out", default=str(HERE / "results" / "convergence_ab.json"))
    a = ap.parse_args()
    import convergence
    from tune_speed import extract

    ids = [c["id"] for c in convergence.suite()][::a.every]
    with tempfile.TemporaryDirectory(prefix="convergence_ab_") as tmp:
        old = Path(tmp) / "old"
        old.mkdir()
        sha = extract(a.rev, old)
        script = Path(tmp) / "worker.py"
        script.write_text(WORKER)
        workers = {"before": _worker(old, script), "this tree": _worker(ROOT, script)}
        runs: dict[str, dict[str, Any]] = {n: {} for n in workers}
        t0 = time.perf_counter()
        try:
            for rnd in range(2):
                for i, cid in enumerate(ids):
                    names = list(workers) if (i + rnd) % 2 == 0 else list(workers)[::-1]
                    for n in names:
                        w = workers[n]
                        w.stdin.write(cid + "\n")
                        w.stdin.flush()
                        r = json.loads(w.stdout.readline())
                        if rnd == 1:
                            runs[n][cid] = r
        finally:
            for w in workers.values():
                w.stdin.close()
                w.wait(timeout=60)
    cpu = {n: sum(r["cpu"] for r in rs.values()) for n, rs in runs.items()}
    wall = {n: sum(r["wall"] for r in rs.values()) for n, rs in runs.items()}
    per_case = [runs["this tree"][c]["cpu"] / runs["before"][c]["cpu"] for c in ids]
    differ = {c: [runs["before"][c]["objective"], runs["this tree"][c]["objective"]] for c in ids
              if runs["before"][c]["objective"] != runs["this tree"][c]["objective"]}
    doc = {"command": "python bench/convergence_ab.py " + " ".join(sys.argv[1:]), "before": sha, "cases": len(ids),
           "cpu_s": cpu, "wall_s": wall, "cpu_ratio": cpu["this tree"] / cpu["before"],
           "median_case_cpu_ratio": statistics.median(per_case), "objective_differs": differ,
           "load_average_end": os.getloadavg(), "run_s": time.perf_counter() - t0}
    Path(a.out).write_text(json.dumps(doc, indent=1) + "\n")
    print(f"{len(ids)} cases, second pass: CPU {cpu['this tree']:.1f} s against {cpu['before']:.1f} s "
          f"({doc['cpu_ratio']:.3f}; median case {doc['median_case_cpu_ratio']:.3f}); "
          f"{len(differ)} objectives differ")


if __name__ == "__main__":
    main()
