"""Issue 30, item 1: warm in-process ``tune()`` medians, old engine, main before this work and this tree, in one run.

    .venv/bin/python bench/warm_speed.py [--seeds 9] [--revs 12b6462,5565a8d] [--out bench/results/warm_speed]

One warm worker process per tree (each tree extracted with ``git archive``; this tree as it is), the README's
loops: the thesis roll, pitch and yaw models with ``pid_z`` at dt 0.04, and 1/(s+1)^3 with ``pid`` at dt 0.1,
each tree's default spec and effort (``fast`` too where the tree has efforts). Each worker first tunes every loop
once (imports, NLP builds), then the seeds 0..N-1; the workers take turns run by run (the order rotating), so that
the machine's load falls on all alike. Each tune gets freshly built plants. Reported: the median wall and CPU
time per loop and effort, the ratio to the first tree's (the old engine, 12b6462) and to main before this work,
and the verifier's settling times. Nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

os.environ.setdefault("TUNER_NLP_COMPILE", "load")  # (no background compile beside timed runs: README, compiled code)

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from tune_speed import SpeedWorker, extract, load_average  # noqa: E402

LOOPS = {  # name: (plant expression, structure, dt)
    "roll": ("0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)", "pid_z", 0.04),
    "pitch": ("0.377568*3.5184^2/(s^2+2*0.5006*3.5184*s+3.5184^2)", "pid_z", 0.04),
    "yaw": ("0.2843*18.611/(s+18.611)", "pid_z", 0.04),
    "1/(s+1)^3": ("1/(s+1)^3", "pid", 0.1),
    # issue 41: the firmware rate law on an identified-like roll model at 400 Hz
    "px4_rate": ("200/((s+2)*(0.03*s+1))", "px4_rate", 0.0025),
}

def measure(revs: list[str], seeds: int, loops: list[str] | None = None, budget: float | None = 10.0,
            effort_names: tuple[str, ...] = ("default", "fast")) -> dict[str, Any]:
    tmp = Path(tempfile.mkdtemp(prefix="warm_speed_"))
    trees: dict[str, Path] = {}
    commits: dict[str, str] = {}
    for rev in revs:
        (tmp / rev).mkdir()
        commits[rev] = extract(rev, tmp / rev)
        trees[rev] = tmp / rev
    trees["this tree"] = ROOT
    workers = {name: SpeedWorker(name, tree, tmp) for name, tree in trees.items()}
    efforts = {}
    for name, w in workers.items():  # (each tree's own tuner, and whether it has efforts)
        hello = w.call(cmd="hello")
        if Path(hello["tuner_file"]).resolve().parents[1] != trees[name].resolve():
            raise SystemExit(f"{name}: imported tuner from {hello['tuner_file']}, not from {trees[name]}")
        efforts[name] = hello["efforts"]
    names = list(workers)
    rows = []
    try:
        for loop, (expr, structure, dt) in LOOPS.items():
            if loops and loop not in loops:
                continue
            for effort in effort_names:
                active = [n for n in names if effort == "default" or efforts[n]]
                req = {"cmd": "tune_expr", "plant": expr, "structure": structure, "dt": dt, "effort": effort,
                       "time_budget_s": budget}
                load0 = load_average()
                runs = alternate(workers, active, req, seeds)
                row = {"loop": loop, "structure": structure, "dt": dt, "effort": effort, "load_start": load0,
                       "trees": {n: {"median_wall_ms": 1e3 * statistics.median(r["wall_s"] for r in rs),
                                     "median_cpu_ms": 1e3 * statistics.median(r["cpu_s"] for r in rs),
                                     "median_settling_s": statistics.median(float(r["settling_s"]) for r in rs),
                                     "all_meet": all(r["meets_spec"] for r in rs),
                                     "claims": sorted({str(r.get("claim")) for r in rs}),
                                     "stops": sorted({str(r.get("stop")) for r in rs}),
                                     "median_nlp_solves": statistics.median(r.get("nlp_solves") or 0 for r in rs),
                                     # seed by seed: the same gains as this tree's, bitwise
                                     "same_gains": sum(r.get("gains") == m.get("gains") for r, m in
                                                       zip(rs, runs.get("this tree", rs)))}
                                 for n, rs in runs.items()}}
                rows.append(row)
                done = ", ".join(f"{n} {t['median_wall_ms']:.0f} ms ({t['median_settling_s']:.4g} s)"
                                 for n, t in row["trees"].items())
                print(f"[warm_speed] {loop} {effort}: {done}", file=sys.stderr, flush=True)
    finally:
        for w in workers.values():
            w.close()
        shutil.rmtree(tmp, ignore_errors=True)
    return {"command": "python bench/warm_speed.py " + " ".join(sys.argv[1:]), "revs": commits, "seeds": seeds,
            "machine": {"cores": os.cpu_count(), "python": platform.python_version(), "cpu": platform.processor()},
            "load_end": load_average(), "rows": rows}


def markdown(res: dict[str, Any]) -> str:
    revs = list(res["revs"])
    names = revs + ["this tree"]
    lines = ["# Warm tune medians", "", f"`{res['command']}`: {res['seeds']} seeds per loop and effort, "
             f"the trees taking turns; load average at the end {res['load_end']}. Ratios: this tree's median wall "
             f"over each older tree's (below 1: faster). Settling: the verifier's median, s.", "",
             "| loop | effort | " + " | ".join(f"{n} ms" for n in names) + " | " +
             " | ".join(f"ratio to {r}" for r in revs) + " | " + " | ".join(f"{n} CPU ms" for n in names) + " | "
             + " | ".join(f"CPU ratio to {r}" for r in revs) + " | " + " | ".join(f"{n} settling" for n in names)
             + " | " + " | ".join(f"{n} claims" for n in names) + " | "
             + " | ".join(f"{n} NLP solves" for n in names) + " | "
             + " | ".join(f"seeds with this tree's gains ({r})" for r in revs) + " |",
             "|" + "---|" * (2 + 5 * len(names) + 3 * len(revs))]
    for row in res["rows"]:
        t = row["trees"]
        me = t["this tree"]["median_wall_ms"]
        cell = lambda n, k, f, t=t: (f.format(t[n][k]) if n in t else "—")
        lines.append(f"| {row['loop']} {row['structure']} dt {row['dt']} | {row['effort']} | "
                     + " | ".join(cell(n, "median_wall_ms", "{:.0f}") for n in names) + " | "
                     + " | ".join(f"{me / t[r]['median_wall_ms']:.2f}" if r in t else "—" for r in revs) + " | "
                     + " | ".join(cell(n, "median_cpu_ms", "{:.0f}") for n in names) + " | "
                     + " | ".join(f"{t['this tree']['median_cpu_ms'] / t[r]['median_cpu_ms']:.2f}" if r in t else "—"
                                  for r in revs) + " | "
                     + " | ".join(cell(n, "median_settling_s", "{:.4f}") for n in names) + " | "
                     + " | ".join(", ".join(t[n].get("claims", [])) if n in t else "—" for n in names) + " | "
                     + " | ".join(cell(n, "median_nlp_solves", "{:.0f}") if "median_nlp_solves" in t.get(n, {})
                                  else "—" for n in names) + " | "
                     + " | ".join(f"{t[r]['same_gains']}/{res['seeds']}" if "same_gains" in t.get(r, {}) else "—"
                                  for r in revs) + " |")
    return "\n".join(lines) + "\n"


def alternate(workers: dict[str, Any], active: list[str], req: dict[str, Any], seeds: int) -> dict[str, list[dict]]:
    """Each active tree's runs of ``req`` at seeds 0..seeds-1, after one warm-up run each (imports, NLP builds),
    the trees taking turns in a rotating order (so that a change in the machine's load falls on all of them)."""
    for n in active:
        workers[n].call(seed=1000, **req)
    runs: dict[str, list[dict]] = {n: [] for n in active}
    for seed in range(seeds):
        for n in active[seed % len(active):] + active[:seed % len(active)]:
            runs[n].append(workers[n].call(seed=seed, **req))
    return runs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=9)
    ap.add_argument("--revs", default="12b6462,5565a8d", help="older trees, comma-separated (the first: baseline)")
    ap.add_argument("--out", default=str(HERE / "results" / "warm_speed"))
    ap.add_argument("--loops", default="", help="comma-separated loop names (default: all)")
    ap.add_argument("--budget", default="10", help="time_budget_s, or 'default' (the library's default budget)")
    ap.add_argument("--efforts", default="default,fast")
    a = ap.parse_args()
    budget = None if a.budget == "default" else float(a.budget)
    write(a.out, measure(a.revs.split(","), a.seeds, [x for x in a.loops.split(",") if x], budget,
                         tuple(a.efforts.split(","))), markdown)


def write(out: str, res: dict[str, Any], markdown: Any) -> None:
    """``out``.json (the results) and ``out``.md (``markdown(res)``, printed too)."""
    Path(out + ".json").write_text(json.dumps(res, indent=1))
    md = markdown(res)
    Path(out + ".md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
