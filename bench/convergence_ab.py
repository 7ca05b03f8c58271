"""What a change to the search costs, in one run: convergence-suite cases tuned warm by this tree and an older one.

    python bench/convergence_ab.py [--rev 3287989] [--every 5] [--out bench/results/convergence_ab.json]

Two warm worker processes (bench/speed_worker.py through tune_speed.SpeedWorker), one per tree (the older one
extracted with ``git archive``; this tree as it is), each with one BLAS thread; every ``--every``-th case of
``bench/convergence.py``'s suite (thesis spec, default effort and budget, seed 0) goes to both, the order
alternating case by case, twice: the first pass builds each process's NLPs, the second is counted. Reported: each
tree's CPU and wall added up, the ratio of the sums and the median per-case CPU ratio, and the cases whose settling
time differs. Nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(ROOT), str(HERE)]

import convergence  # noqa: E402
from tune_speed import SpeedWorker, extract  # noqa: E402

ONE_THREAD = dict.fromkeys(("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"), "1")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rev", default="3287989", help="the older tree (a git revision)")
    ap.add_argument("--every", type=int, default=5)
    ap.add_argument("--out", default=str(HERE / "results" / "convergence_ab.json"))
    a = ap.parse_args()
    cases = convergence.suite()[::a.every]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="convergence_ab_") as tmp:
        old = Path(tmp) / "old"
        old.mkdir()
        sha = extract(a.rev, old)
        workers = {"before": SpeedWorker("before", old, Path(tmp), env=ONE_THREAD),
                   "this tree": SpeedWorker("this tree", ROOT, Path(tmp), env=ONE_THREAD)}
        runs: dict[str, dict[str, Any]] = {n: {} for n in workers}
        try:
            for rnd in range(2):  # the first pass builds the NLPs; the second is counted
                for i, c in enumerate(cases):
                    req = {"cmd": "tune_tf", "num": c["num"], "den": c["den"], "delay_s": c["delay_s"],
                           "structure": c["structure"], "dt": c["dt"], "seed": 0, "time_budget_s": None}
                    for n in (list(workers) if (i + rnd) % 2 == 0 else list(workers)[::-1]):
                        r = workers[n].call(**req)
                        if rnd == 1:
                            runs[n][c["id"]] = r
        finally:
            for w in workers.values():
                w.close()
    ids = [c["id"] for c in cases]
    cpu = {n: sum(r["cpu_s"] for r in rs.values()) for n, rs in runs.items()}
    wall = {n: sum(r["wall_s"] for r in rs.values()) for n, rs in runs.items()}
    per_case = [runs["this tree"][c]["cpu_s"] / runs["before"][c]["cpu_s"] for c in ids]
    differ = {c: [runs["before"][c]["settling_s"], runs["this tree"][c]["settling_s"]] for c in ids
              if runs["before"][c]["settling_s"] != runs["this tree"][c]["settling_s"]}
    doc = {"command": " ".join(["python bench/convergence_ab.py", *sys.argv[1:]]), "before": sha, "cases": len(ids),
           "cpu_s": cpu, "wall_s": wall, "cpu_ratio": cpu["this tree"] / cpu["before"],
           "median_case_cpu_ratio": statistics.median(per_case), "settling_differs": differ,
           "load_average_end": os.getloadavg(), "run_s": time.perf_counter() - t0}
    Path(a.out).write_text(json.dumps(doc, indent=1) + "\n")
    print(f"{len(ids)} cases, second pass: CPU {cpu['this tree']:.1f} s against {cpu['before']:.1f} s "
          f"({doc['cpu_ratio']:.3f}; median case {doc['median_case_cpu_ratio']:.3f}); "
          f"{len(differ)} settling times differ")


if __name__ == "__main__":
    main()
