"""Issue 3 measurement: wall time of one tune of the roll model (pid, dt 0.04) in a warm process,
against an Optuna-only search with the same verifier that must reach the same settling time.

    .venv/bin/python bench/tune_speed.py [--repeats 10] [--optuna-cap-s 120]

Prints a Markdown table; writes bench/results/tune_speed.json. Timings are ratios measured in the
same run; nothing here is asserted.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from pathlib import Path

import numpy as np

from tuner import Spec, get_structure, plant_from_expr
from tuner.optimize.engine import designed_starts
from tuner.optimize.scoring import Evaluator
from tuner.optimize.space import make_space
from tuner.tuning import tune

ROLL = "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)"


def pct(xs: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(xs), q))


def optuna_until(plant, structure: str, dt: float, target: float, *, seed: int, cap_s: float,
                 check_every: int = 25) -> tuple[float, float, int]:
    """Optuna TPE alone (same starts, same verifier) until the full verifier confirms a settling
    time <= target, or the cap. Returns (seconds, best verified settling, trials)."""
    import optuna

    from tuner.optimize.search import default_sampler

    st = get_structure(structure)
    space = make_space(st, plant, dt)
    ev = Evaluator([plant], st, dt, Spec())
    study = optuna.create_study(direction="minimize", sampler=default_sampler(seed, len(space.names)))
    dists = {n: optuna.distributions.FloatDistribution(float(lo), float(hi))
             for n, lo, hi in zip(space.names, space.lo, space.hi)}
    for v in designed_starts(space, plant, dt):
        study.enqueue_trial(dict(zip(space.names, map(float, v))))
    t0 = time.perf_counter()
    best_verified = math.inf
    n = 0
    while time.perf_counter() - t0 < cap_s:
        tr = study.ask(dists)
        v = np.array([tr.params[k] for k in space.names])
        study.tell(tr, ev.score(space.params(v)).score)
        n += 1
        if n % check_every == 0 and study.best_value < 1e3:
            v = np.array([study.best_params[k] for k in space.names])
            full = ev.score(space.params(v), full=True)
            if full.feasible:
                best_verified = min(best_verified, full.score)
            if best_verified <= target:
                return time.perf_counter() - t0, best_verified, n
    return math.inf, best_verified, n


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--optuna-cap-s", type=float, default=120.0)
    ap.add_argument("--optuna-runs", type=int, default=3)
    ap.add_argument("--structure", default="pid")
    a = ap.parse_args()
    plant = plant_from_expr(ROLL)
    tune(plant, structure=a.structure, dt=0.04, seed=0, time_budget_s=60)  # warm-up: builds the NLP
    times, settles = [], []
    for seed in range(a.repeats):
        t0 = time.perf_counter()
        r = tune(plant, structure=a.structure, dt=0.04, seed=seed, time_budget_s=60)
        times.append(time.perf_counter() - t0)
        settles.append(r.analyses[0].metrics.settling_time_s if r.meets_spec else math.inf)
    ours_ts = max(settles)
    target = ours_ts * 1.02  # "equal quality": within 2 % of our worst settling time over the repeats
    opt = [optuna_until(plant, a.structure, 0.04, target, seed=s, cap_s=a.optuna_cap_s)
           for s in range(a.optuna_runs)]
    o_times = [t for t, _, _ in opt]
    out = {
        "structure": a.structure,
        "ours": {"median_s": statistics.median(times), "p95_s": pct(times, 95), "runs": len(times),
                 "settling_s": settles},
        "optuna_only": {"target_settling_s": target, "cap_s": a.optuna_cap_s,
                        "runs": [{"seconds": t, "best_verified_settling_s": b, "trials": n} for t, b, n in opt]},
    }
    reached = [t for t in o_times if math.isfinite(t)]
    o_med = statistics.median(o_times) if len(reached) == len(o_times) else math.inf
    out["ratio_optuna_over_ours"] = (o_med / out["ours"]["median_s"]) if math.isfinite(o_med) else (
        f">= {a.optuna_cap_s / out['ours']['median_s']:.0f} (Optuna-only did not reach the target in "
        f"{len(o_times) - len(reached)} of {len(o_times)} runs within the cap)")
    Path(__file__).with_name("results").mkdir(exist_ok=True)
    Path(__file__).with_name("results").joinpath("tune_speed.json").write_text(json.dumps(out, indent=2, default=str))
    print("| method | median s | p95 s | settling s |\n|---|---|---|---|")
    print(f"| tuner ({a.structure}) | {out['ours']['median_s']:.3f} | {out['ours']['p95_s']:.3f} | "
          f"{min(settles):.4f}-{max(settles):.4f} |")
    for t, b, n in opt:
        print(f"| Optuna TPE only | {t:.3f} | | best {b:.4f} after {n} trials |")
    print(f"ratio Optuna-only / tuner (median): {out['ratio_optuna_over_ours']}")


if __name__ == "__main__":
    main()
