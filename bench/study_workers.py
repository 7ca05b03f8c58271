"""``tuner study run STUDY --workers 1`` against ``--workers 2``, interleaved, repeated.

    .venv/bin/python bench/study_workers.py [--study studies/process.toml] [--repeat 3] [--tree DIR ...]

Each run is a fresh output directory (a fresh SQLite storage: nothing reused). Reported per
worker count: the median wall time and the median CPU time of the run (the command and its
children), and the ratio of the medians; the load average before and after each run is printed,
since the machine may be shared. With ``--tree``, each one-worker run's loops (their own tune walls)
and the most two workers could gain on them if a loop runs on one worker and nothing else cost
anything (:func:`loop_bound`): a study of a few unequal loops cannot reach 2x. Nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("TUNER_NLP_COMPILE", "load")  # (no background compile beside timed runs: README, compiled code)

ROOT = Path(__file__).resolve().parents[1]


LAST_LOOPS: dict[str, float] = {}  # the last run's loops' own tune walls (results.json's wall_time_s), s


def loop_bound(walls: list[float], workers: int = 2) -> float:
    """The most ``workers`` workers can gain over one on loops taking ``walls`` seconds each, when a loop runs on one
    worker and everything else is free: sum / the smallest makespan over every assignment (brute force, 2^(n-1)
    assignments: a study has a few loops). An upper bound: it ignores a cascade's order (its inner loop first). 5
    loops of 0.84, 0.90, 2.54, 1.61, 1.81 s: {2.54, 1.61} against {0.84, 0.90, 1.81}, 7.70 / 4.15 = 1.86.

    >>> round(loop_bound([0.84, 0.90, 2.54, 1.61, 1.81]), 2)
    1.86
    >>> loop_bound([1.0, 1.0])
    2.0
    """
    import itertools

    if not walls:
        return float("nan")
    best = math.inf
    for assign in itertools.product(range(workers), repeat=len(walls) - 1):  # (the first loop on worker 0)
        load = [0.0] * workers
        for w, t in zip((0, *assign), walls):
            load[w] += t
        best = min(best, max(load))
    return sum(walls) / best


def run_once(study: str, workers: int, plots: bool, env: dict[str, str] | None = None,
             root: Path | None = None) -> tuple[float, float]:
    """(wall s, CPU s of the command and its children); ``root``: the source tree whose ``tuner`` runs (this one).
    The loops' own walls are left in :data:`LAST_LOOPS`."""
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "-m", "tuner.cli", "study", "run", study, "--workers", str(workers), "--out", out]
        if not plots:
            cmd.append("--no-plots")
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, cwd=root or ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                              env={**os.environ, **env} if env else None)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if proc.returncode not in (0, 1):  # 1: a loop misses its spec (still a full run)
            raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
        LAST_LOOPS.clear()
        with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
            loops = json.loads((Path(out) / "results.json").read_text())["loops"]
            LAST_LOOPS.update({k: float(v["wall_time_s"]) for k, v in loops.items()})
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def _stats(walls: dict[int, list[float]], cpus: dict[int, list[float]]) -> dict:
    m1, m2 = statistics.median(walls[1]), statistics.median(walls[2])
    return {"wall_s": walls, "cpu_s": cpus, "median_wall_s": {1: m1, 2: m2},
            "median_cpu_s": {w: statistics.median(cpus[w]) for w in (1, 2)}, "speedup": m1 / m2,
            "pairs": [x / y for x, y in zip(walls[1], walls[2])]}


def compare(study: str, repeat: int, *, plots: bool = True, log=print, variant_env: dict[str, str] | None = None
            ) -> dict:
    """``repeat`` interleaved pairs of runs (workers 1, then workers 2): wall and CPU per run, medians, ratio.
    ``variant_env``: each repeat also runs the pair with these environment variables (under ``"variant"``)."""
    variants = [None, variant_env] if variant_env else [None]
    walls = [{1: [], 2: []} for _ in variants]
    cpus = [{1: [], 2: []} for _ in variants]
    loads: list[float] = []
    for i in range(repeat):
        for k, env in enumerate(variants):
            for w in (1, 2):
                load0 = os.getloadavg()[0]
                wall, cpu = run_once(study, w, plots, env)
                walls[k][w].append(wall)
                cpus[k][w].append(cpu)
                loads.append(load0)
                log(f"  run {i + 1} workers {w}{' ' + str(env) if env else ''}: {wall:6.2f} s wall, {cpu:6.2f} s CPU "
                    f"(load average {load0:.2f} before, {os.getloadavg()[0]:.2f} after)")
    out = {"study": study, "repeat": repeat, "plots": plots, **_stats(walls[0], cpus[0]), "load_before_runs": loads}
    if variant_env:
        out["variant"] = {"env": variant_env, **_stats(walls[1], cpus[1])}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", default="studies/process.toml")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-plots", action="store_true")
    ap.add_argument("--tree", nargs="+", default=None,
                    help="source trees to compare, alternating within each repeat (e.g. a worktree of main and this "
                         "one): the medians and ratio per tree")
    a = ap.parse_args(argv)
    if a.tree:
        return _trees(a)
    print(f"{a.study}, {a.repeat} x (workers 1, workers 2), interleaved; {os.cpu_count()} CPUs")
    r = compare(a.study, a.repeat, plots=not a.no_plots, log=lambda m: print(m, flush=True))
    print()
    print("| workers | median wall [s] | median CPU [s] | runs (wall) |")
    print("|---|---|---|---|")
    for w in (1, 2):
        print(f"| {w} | {r['median_wall_s'][w]:.2f} | {r['median_cpu_s'][w]:.2f} | "
              + ", ".join(f"{x:.2f}" for x in r["wall_s"][w]) + " |")
    print(f"\nspeed-up of 2 workers (ratio of the medians): {r['speedup']:.2f}x; per interleaved pair: "
          + ", ".join(f"{p:.2f}" for p in r["pairs"]))
    return 0


def _trees(a: argparse.Namespace) -> int:
    """``--tree``: each repeat runs (workers 1, workers 2) in every tree in turn (the trees see the same load)."""
    trees = [Path(t).resolve() for t in a.tree]
    study = str(Path(a.study).resolve())
    res = {t: {1: [], 2: []} for t in trees}
    bounds: dict[Path, list[float]] = {t: [] for t in trees}
    print(f"{a.study}, {a.repeat} x (workers 1, workers 2) per tree, alternating; {os.cpu_count()} CPUs")
    for i in range(a.repeat):
        for t in trees:
            for w in (1, 2):
                load0 = os.getloadavg()[0]
                wall, cpu = run_once(study, w, not a.no_plots, root=t)
                res[t][w].append((wall, cpu))
                loops = dict(LAST_LOOPS)
                if w == 1 and loops:
                    bounds[t].append(loop_bound(list(loops.values())))
                print(f"  run {i + 1} {t} workers {w}: {wall:6.2f} s wall, {cpu:6.2f} s CPU (load average "
                      f"{load0:.2f} before, {os.getloadavg()[0]:.2f} after); loops "
                      + ", ".join(f"{k} {v:.2f}" for k, v in loops.items())
                      + (f" s (their sum {sum(loops.values()):.2f} s, loop-level bound on 2 workers "
                         f"{bounds[t][-1]:.2f}x)" if w == 1 and loops else " s"), flush=True)
    print("\n| tree | median wall 1 worker [s] | 2 workers [s] | ratio | median CPU 1 worker [s] | 2 workers [s] | "
          "ratio per pair | loop-level bound (median) |")
    print("|---|---|---|---|---|---|---|---|")
    for t in trees:
        mw = {w: statistics.median(x[0] for x in res[t][w]) for w in (1, 2)}
        mc = {w: statistics.median(x[1] for x in res[t][w]) for w in (1, 2)}
        pairs = ", ".join(f"{x[0] / y[0]:.2f}" for x, y in zip(res[t][1], res[t][2]))
        bound = statistics.median(bounds[t]) if bounds[t] else float("nan")
        print(f"| {t} | {mw[1]:.2f} | {mw[2]:.2f} | {mw[1] / mw[2]:.2f} | {mc[1]:.2f} | {mc[2]:.2f} | {pairs} | "
              f"{bound:.2f}x |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
