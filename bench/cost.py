"""What the worst accepted inputs cost: wall time and peak memory of one analysis and one tune.

Each case runs in its own process under ``/usr/bin/time -v`` (maximum resident set size) with a timer,
so one case's memory does not hide another's. Measures, never asserts (see README "Limits").

    .venv/bin/python bench/cost.py            # every case
    .venv/bin/python bench/cost.py --case slow_delay_1e-5
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time

# name -> (plants: [(expr, delay)], dt, structure, budget_s)
CASES: dict[str, tuple[list[tuple[str, float]], float | None, str, float]] = {
    "slow_delay_1e-5": ([("1/(1000*s+1)", 1e-5)], None, "pi", 1.0),
    "slow_delay_1e-3": ([("1/(1000*s+1)", 1e-3)], None, "pi", 1.0),
    "order20_delay3": ([("1/(s+1)^20", 3.0)], None, "pid", 1.0),
    "20x_order20_delay3": ([(f"1/({1 + 0.01 * i}*s+1)^20", 3.0) for i in range(20)], None, "pid", 1.0),
    "order10_dt0.001": ([("1/(s+1)^10", 0.0)], 0.001, "pid_z", 1.0),
    "order20_dt0.001": ([("1/(s+1)^20", 0.0)], 0.001, "pid_z", 0.5),
    "delay_200_samples": ([("1/(s+1)", 2.0)], 0.01, "pi", 1.0),
    "lag_dt1000": ([("1/(s+1)", 0.0)], 1000.0, "lag", 1.0),
}

CHILD = r"""
import json, sys, time
from tuner import TuningProblem, analyze, plant_from_expr, tune
from tuner.optimize.design import initial_guess
plants, dt, structure, budget = json.loads(sys.argv[1])
t0 = time.perf_counter()
ps = [plant_from_expr(e, delay=d) for e, d in plants]
prob = TuningProblem.build(ps, structure=structure, dt=dt)
t1 = time.perf_counter()
g = initial_guess(prob.structure, ps[0], dt, scale=prob.scale)
an = analyze(ps[0], prob.structure.tf(g, dt))
t2 = time.perf_counter()
res = tune(prob, time_budget_s=budget)
t3 = time.perf_counter()
print(json.dumps({"build_s": t1 - t0, "analyze_s": t2 - t1, "tune_s": t3 - t2, "budget_s": budget,
                  "meets_spec": res.meets_spec, "budget_exhausted": res.solver.get("budget_exhausted")}))
"""


def run_case(name: str) -> dict:
    plants, dt, structure, budget = CASES[name]
    cmd = ["/usr/bin/time", "-v", sys.executable, "-c", CHILD, json.dumps([plants, dt, structure, budget])]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    wall = time.perf_counter() - t0
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr)
    out = {"case": name, "wall_s": round(wall, 2), "max_rss_mb": int(rss.group(1)) // 1024 if rss else None}
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if p.returncode == 0 and lines:
        out.update({k: (round(v, 2) if isinstance(v, float) else v) for k, v in json.loads(lines[-1]).items()})
    else:
        out["error"] = (p.stderr.strip().splitlines() or ["?"])[-1][:200] if p.returncode else "no output"
        err = [ln for ln in p.stderr.splitlines() if "Error" in ln]
        out["error"] = err[-1][:200] if err else out["error"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", action="append", choices=sorted(CASES))
    a = ap.parse_args()
    for name in a.case or CASES:
        print(json.dumps(run_case(name)), flush=True)


if __name__ == "__main__":
    main()
