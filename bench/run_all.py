"""All benchmarks in one run on one machine: quality against the best possible, then everything
``bench/tune_speed.py`` measures (before/after per loop, speed against the alternatives, cold start,
scaling, the service, study workers). Writes bench/RESULTS.md.

    bench/run            (= .venv/bin/python bench/run_all.py)
    bench/run --reuse-speed bench/results/tune_speed.json     # the speed part of an earlier run
    bench/run --speed-args "--quick --parts before_after,cold"

Nothing here asserts a timing: timings are reported, and ratios are measured in the same run.
Every settling time is the verifier's, at full resolution, on the loop's plants (worst case).
Our settling time per loop is the worst seed of tune_speed's ``after`` runs.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import tune_speed  # noqa: E402
from common import Loop, canonical_key, fmt, load_loops, run_de, run_optuna  # noqa: E402
from tune_speed_report import QUALITY_TOL, sections  # noqa: E402

REFERENCE_CACHE = HERE / "reference.json"


def reference(lp: Loop, cache: dict[str, Any], evals: int, *, refresh: bool = False) -> float:
    """Brute-force reference: a long differential evolution (cached: computed once, or again on ``refresh``)."""
    if lp.key in cache and not refresh:
        return float(cache[lp.key]["settling_s"])
    t0 = time.perf_counter()
    best = min(run_de(lp, seed=s, target=None, cap_s=1e9, max_evals=evals // 2).best_verified for s in (0, 1))
    cache[lp.key] = {"loop": lp.label, "settling_s": best, "evaluations": evals, "seconds": time.perf_counter() - t0}
    REFERENCE_CACHE.write_text(json.dumps(cache, indent=1, default=str))
    return best


def quality(loops: list[Loop], ours: dict[str, float], a: argparse.Namespace) -> None:
    """Per loop: the reference, and Optuna and DE with a fixed budget; ``ours`` = our worst-seed settling."""
    cache = {canonical_key(k): v for k, v in json.loads(REFERENCE_CACHE.read_text()).items()} \
        if REFERENCE_CACHE.exists() else {}
    for lp in loops:
        if lp.label not in ours:
            continue
        print(f"[bench] quality {lp.label}", file=sys.stderr, flush=True)
        ref = reference(lp, cache, a.reference_evals, refresh=lp.label in a.refresh_reference.split(","))
        fixed_o = run_optuna(lp, seed=0, target=None, cap_s=1e9, max_evals=a.fixed_evals)
        fixed_d = run_de(lp, seed=0, target=None, cap_s=1e9, max_evals=a.fixed_evals)
        lp.results = {"ours_settling_s": ours[lp.label], "ref_settling_s": ref,
                      "optuna_fixed_settling_s": fixed_o.best_verified, "de_fixed_settling_s": fixed_d.best_verified}


def quality_md(loops: list[Loop], a: argparse.Namespace) -> list[str]:
    L = ["## Quality: settling time (s) and ratio to the reference", "",
         "Reference = the best of two long differential-evolution runs "
         f"({a.reference_evals} verifier evaluations in all, cached in `bench/reference.json`), judged by the "
         "same verifier at full resolution. Ours = the worst seed of the before/after table's `after` runs. Optuna "
         f"and DE with a fixed budget of {a.fixed_evals} evaluations. Ratios below 1 are better than the reference.",
         "", "| loop | thesis as printed | reference | ours | ours/ref | Optuna (fixed) | Optuna/ref | DE (fixed) "
         "| DE/ref | target met |", "|---|---|---|---|---|---|---|---|---|---|"]
    miss = []
    for lp in loops:
        r = lp.results
        ref = r["ref_settling_s"]

        def ratio(x: float, ref: float = ref) -> float:
            return x / ref if math.isfinite(ref) and ref > 0 and math.isfinite(x) else math.inf

        ours = r["ours_settling_s"]
        ok = ours <= max(ref * (1 + QUALITY_TOL), ref + (lp.dt or 0)) if math.isfinite(ref) else math.isfinite(ours)
        if not ok:
            miss.append(lp.label)
        L.append(f"| {lp.label} | {fmt(lp.thesis_settling)} | {fmt(ref)} | {fmt(ours)} | {fmt(ratio(ours), 2)} | "
                 f"{fmt(r['optuna_fixed_settling_s'])} | {fmt(ratio(r['optuna_fixed_settling_s']), 2)} | "
                 f"{fmt(r['de_fixed_settling_s'])} | {fmt(ratio(r['de_fixed_settling_s']), 2)} | "
                 f"{'yes' if ok else '**no**'} |")
    return L + ["", "Quality target (within 2 % or one sample of the reference, or better): "
                + ("met on every loop." if not miss else f"**missed on {', '.join(miss)}**."), ""]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reference-evals", type=int, default=20000)
    ap.add_argument("--fixed-evals", type=int, default=500)
    ap.add_argument("--refresh-reference", default="", metavar="LOOPS",
                    help="comma-separated study/name whose cached reference is computed again")
    ap.add_argument("--speed-args", default="", help="options for bench/tune_speed.py, in one string")
    ap.add_argument("--reuse-speed", default=None, metavar="JSON",
                    help="take the speed results from an earlier tune_speed run instead of measuring")
    ap.add_argument("--no-quality", action="store_true")
    a = ap.parse_args()
    if a.reuse_speed:
        ts = json.loads(Path(a.reuse_speed).read_text())
    else:
        sa = tune_speed.parse_args(shlex.split(a.speed_args))
        ts = tune_speed.measure(sa)
        tune_speed.save(ts, sa.out)
    loops = load_loops(attitude_pid=True)
    ours = {r["loop"]: float(r["after"]["worst_settling_s"]) for r in ts.get("before_after", {}).get("loops", [])}
    if not a.no_quality:
        quality(loops, ours, a)
    m = ts["machine"]
    L = ["# Benchmark results", "", f"Written by `bench/run` on {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; "
         f"the speed sections are `bench/tune_speed.py`'s run of {ts['when_utc']} (tree {ts.get('after_commit', '?')}, "
         f"load average {ts['load_average_start']} at its start, {ts.get('load_average_end')} at its end).", "",
         "## Machine", ""] + [f"- {k}: {v}" for k, v in m.items()] + [""]
    done = [lp for lp in loops if lp.results]
    if done:
        L += quality_md(done, a)
    text = "\n".join(L + sections(ts)) + "\n"
    (HERE / "RESULTS.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
