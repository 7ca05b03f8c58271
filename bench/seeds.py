"""The same answer on every seed (issue 10): seeds 0-4 on every loop of studies/quadrotor.toml and
studies/process.toml.

    .venv/bin/python bench/seeds.py [--quick] [--budget 120] [--seeds 0 1 2 3 4]

Loops are loaded as bench/run_all.py loads them (``load_loops``: the study files through
``tuner.studies``; a cascade's outer loop sees its inner loop closed with the committed
studies/quadrotor.gains.json, so every seed of an outer loop tunes the same plant). Each tune gets the
loop's own n_trials / n_starts and a budget of max(--budget, 4 x the study's) seconds, and the table says
whether the search stopped by convergence or by the budget. Settling time = the verifier's, worst over the
loop's plants (infinite if the spec is not met). Target: max/min <= 1.02 or max - min <= one sample (dt).

Nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from loadstep import fmt, table, write_results  # noqa: E402
from run_all import load_loops  # noqa: E402

from tuner import tune  # noqa: E402
from tuner.studies.schema import load_study  # noqa: E402

RATIO = 1.02
QUICK = ("quadrotor/roll", "process/fopdt")


def study_budgets() -> dict[str, float]:
    out = {}
    for fname in ("quadrotor.toml", "process.toml"):
        st = load_study(HERE.parent / "studies" / fname)
        for lp in st.loop:
            out[f"{st.name}/{lp.name}"] = float(lp.time_budget_s or st.time_budget_s)
    return out


def run_loop(lp, seeds: list[int], budget: float) -> dict:
    runs = []
    for seed in seeds:
        r = tune(lp.plants, structure=lp.structure, spec=lp.spec, dt=lp.dt, seed=seed, time_budget_s=budget,
                 **lp.tune_kw)
        ts = max(a.metrics.settling_time_s for a in r.analyses) if r.meets_spec else math.inf
        runs.append({"seed": seed, "settling_s": ts, "meets_spec": r.meets_spec, "gains": r.gains,
                     **{k: r.solver[k] for k in ("stop", "budget_exhausted", "wall_time_s", "rounds")}})
        print(f"  seed {seed}: {ts:.6g} s ({r.solver['stop']}, {r.solver['wall_time_s']:.1f} s)", flush=True)
    ts = [x["settling_s"] for x in runs]
    lo, hi = min(ts), max(ts)
    ratio = hi / lo if lo > 0 and math.isfinite(hi) else math.inf
    spread = hi - lo if math.isfinite(hi) else math.inf
    dt = lp.dt or 0.0
    ok = bool(math.isfinite(hi) and (ratio <= RATIO or spread <= dt * (1 + 1e-9)))
    return {"loop": f"{lp.study}/{lp.name}", "structure": lp.structure, "dt": lp.dt, "budget_s": budget,
            "runs": runs, "min_s": lo, "max_s": hi, "ratio": ratio, "spread_s": spread, "spread_samples":
            spread / dt if dt else math.nan, "target_met": ok}


def markdown(rows: list[dict], a: argparse.Namespace) -> str:
    L = ["# Seeds (issue 10)", "",
         f"`bench/seeds.py`: seeds {', '.join(map(str, a.seeds))} on every loop of studies/quadrotor.toml and "
         "studies/process.toml; settling time (s) of the verified result, worst over the loop's plants. Target: "
         f"max/min ≤ {RATIO} or max − min ≤ dt.", ""]
    head = ["loop", "structure", "dt", "budget s"] + [f"seed {s}" for s in a.seeds] + [
        "max/min", "max−min (samples)", "target met", "stops", "rounds", "budget exhausted", "wall s (max)"]
    body = []
    for r in rows:
        stops = sorted({x["stop"] for x in r["runs"]})
        body.append([r["loop"], r["structure"], r["dt"], r["budget_s"], *[x["settling_s"] for x in r["runs"]],
                     r["ratio"], r["spread_samples"], r["target_met"], "/".join(stops),
                     "/".join(str(n) for n in sorted({x["rounds"] for x in r["runs"]})),
                     str(any(x["budget_exhausted"] for x in r["runs"])), max(x["wall_time_s"] for x in r["runs"])])
    L.append(table(head, body))
    miss = [r["loop"] for r in rows if not r["target_met"]]
    L += ["", "rounds = 1: the search converged in its deterministic round 0 (plant-based starts, a fixed "
          "space-filling set, the NLP), before any seeded sampling; the seed cannot change such a result.", ""]
    L += ["", f"Target met on {len(rows) - len(miss)} of {len(rows)} loops. Missed: "
          + (", ".join(f"{m} (max/min {fmt(r['ratio'])})" for m in miss for r in rows if r["loop"] == m)
             if miss else "none") + ".", ""]
    return "\n".join(L) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help=f"loops {', '.join(QUICK)}, seeds 0-1, short budget")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--budget", type=float, default=120.0, help="at least this time_budget_s per tune")
    a = ap.parse_args()
    loops = load_loops()
    budgets = study_budgets()
    if a.quick:
        loops = [lp for lp in loops if f"{lp.study}/{lp.name}" in QUICK]
        a.seeds, a.budget = a.seeds[:2], min(a.budget, 30.0)
    rows = []
    for lp in loops:
        key = f"{lp.study}/{lp.name}"
        budget = a.budget if a.quick else max(a.budget, 4 * budgets.get(key, 10.0))
        print(f"[seeds] {key} (budget {budget:.0f} s)", flush=True)
        rows.append(run_loop(lp, a.seeds, budget))
    md = markdown(rows, a)
    print(md)
    js, mdp = write_results("seeds", {"seeds": a.seeds, "loops": rows}, md, quick=a.quick)
    print(f"wrote {js} and {mdp}")


if __name__ == "__main__":
    main()
