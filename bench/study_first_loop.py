"""A study worker's first loop with the batch's kernels imported only (main before this branch) or also warmed
(``kernels.warm()``, what a worker does at its start now): two forked workers at once, as ``--workers 2`` starts
them, each tuning one loop of ``studies/process.toml`` at the study's 10 s budget.

    .venv/bin/python bench/study_first_loop.py [--rounds 2]

Prints each loop's wall time and ``solver.stop`` / ``cut``. Nothing here asserts a timing (issue 41; see
bench/results/study_workers_issue41.md).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import time


def _tune(warm: bool, name: str) -> None:
    from tuner.optimize import batch
    from tuner.studies.evaluate import tune_loop
    from tuner.studies.schema import load_study

    kernels = batch.preload_kernels()
    if warm and kernels is not None:
        kernels.warm()
    study = load_study("studies/process.toml")
    t0 = time.perf_counter()
    s = tune_loop(study, study.get(name), {})["solver"]
    print(f"{'warmed' if warm else 'imported only':14s} {name:12s} {time.perf_counter() - t0:6.2f} s wall  "
          f"stop {s['stop']}, cut {s['cut'] and s['cut']['step']}", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=2)
    a = ap.parse_args()
    from tuner.studies import cli

    cli._preload_stack()  # what the command imports before it forks its workers
    print(f"load average {os.getloadavg()[0]:.2f}")
    for _ in range(a.rounds):
        for warm in (False, True):
            ps = [mp.get_context("fork").Process(target=_tune, args=(warm, n)) for n in ("fopdt", "oscillatory")]
            for p in ps:
                p.start()
            for p in ps:
                p.join()
    print(f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
