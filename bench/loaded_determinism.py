"""Issue 41, item 3: the same command and seed give the same gains on a loaded machine.

    .venv/bin/python bench/loaded_determinism.py [--runs 10] [--busy 2] [--out bench/results/loaded_determinism]

Starts ``--busy`` CPU-bound processes (``python -c "while 1: pass"``), runs the same ``tuner tune`` command
``--runs`` times beside them (the px4_rate law on 200/((s+2)(0.03 s+1)) at 400 Hz, the issue's identified-model
tune, default budget and seed), then ends the processes it started (by their ids). Reported: each run's gains (as
printed, full precision), stop, claim, what a cap cut, wall time; and whether every run's gains are bitwise the
same. With ``--study FILE``: ``tuner study run FILE --no-plots --workers W`` in place of the tune (a new output
folder each run), each run's loops' gains, stops and cuts, and whether every loop's gains are bitwise the same in
every run (the quadrotor study's position loops ended on their 30 s cap until 63e5864, a machine-dependent answer).
Nothing here asserts anything.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
COMMAND = ["tune", "--plant", "200/((s+2)*(0.03*s+1))", "--structure", "px4_rate", "--dt", "0.0025", "--json"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--busy", type=int, default=2)
    ap.add_argument("--out", default="", help="results path without suffix (default: bench/results/"
                    "loaded_determinism, with --study loaded_determinism_study)")
    ap.add_argument("--study", default="", help="a study file: run the study instead of the tune")
    ap.add_argument("--workers", type=int, default=2, help="with --study: its worker processes")
    ap.add_argument("--budget", type=float, default=None,
                    help="the command's --budget (a hard wall limit in place of the default 60 s cap; default: none)")
    a = ap.parse_args()
    if a.study and a.budget is not None:
        ap.error("--budget applies to the tune, not to --study (a study's budgets are its file's)")
    a.out = a.out or str(HERE / "results" / ("loaded_determinism_study" if a.study else "loaded_determinism"))
    if a.study:
        a.study = str(Path(a.study).resolve())  # (the study runs with the tree's root as its working directory)
    command = COMMAND + ([] if a.budget is None else ["--budget", f"{a.budget:g}"])
    tuner = str(Path(sys.executable).parent / "tuner")
    if a.study:
        return study_runs(a, tuner)
    busy = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(a.busy)]
    runs = []
    try:
        for i in range(a.runs):
            t0 = time.perf_counter()
            p = subprocess.run([tuner, *command], capture_output=True, text=True, cwd=ROOT)
            wall = time.perf_counter() - t0
            if p.returncode != 0:
                runs.append({"run": i, "returncode": p.returncode, "stderr": p.stderr[-2000:], "wall_s": wall})
                continue
            r = json.loads(p.stdout)
            s = r["solver"]
            runs.append({"run": i, "gains": r["gains"], "gains_repr": {k: repr(v) for k, v in r["gains"].items()},
                         "stop": s.get("stop"), "claim": (s.get("optimality") or {}).get("claim"),
                         "cut": s.get("cut"), "restarts": (s.get("optimality") or {}).get("restarts"),
                         "wall_s": wall, "load": os.getloadavg()})
            print(f"run {i}: {runs[-1]['gains_repr']} stop {runs[-1]['stop']} claim {runs[-1]['claim']} "
                  f"cut {runs[-1]['cut']} {wall:.1f} s load {os.getloadavg()[0]:.1f}", flush=True)
    finally:
        for b in busy:  # (only the processes this script started)
            b.kill()
            b.wait()
    gains = [json.dumps(r.get("gains_repr"), sort_keys=True) for r in runs]
    res = {"command": "tuner " + " ".join(command), "busy": a.busy, "runs": runs,
           "identical_gains": len(set(gains)) == 1 and all("gains" in r for r in runs),
           "distinct_gains": len(set(gains))}
    Path(a.out + ".json").write_text(json.dumps(res, indent=1))
    verdict = "identical gains" if res["identical_gains"] else f"{res['distinct_gains']} distinct gain sets"
    md = ["# Loaded determinism (issue 41)", "",
          f"`{res['command']}`, {a.runs} runs beside {a.busy} CPU-bound processes: {verdict}", "",
          "| run | gains | stop | claim | cut | restarts | wall s | load (1 min) |",
          "|---|---|---|---|---|---|---|---|"]
    for r in runs:
        md.append(f"| {r['run']} | {r.get('gains_repr')} | {r.get('stop')} | {r.get('claim')} | {r.get('cut')} | "
                  f"{r.get('restarts')} | {r['wall_s']:.1f} | {r.get('load', [float('nan')])[0]:.1f} |")
    Path(a.out + ".md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


def study_runs(a: argparse.Namespace, tuner: str) -> None:
    """``--study``: the study run ``--runs`` times beside ``--busy`` CPU-bound processes; each loop's gains compared."""
    import tempfile

    command = ["study", "run", a.study, "--no-plots", "--workers", str(a.workers)]
    busy = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(a.busy)]
    runs = []
    try:
        for i in range(a.runs):
            with tempfile.TemporaryDirectory() as out:
                t0 = time.perf_counter()
                p = subprocess.run([tuner, *command, "--out", out], capture_output=True, text=True, cwd=ROOT)
                wall = time.perf_counter() - t0
                try:
                    loops = json.loads((Path(out) / "results.json").read_text())["loops"]
                except (OSError, ValueError, KeyError) as e:
                    runs.append({"run": i, "returncode": p.returncode, "error": repr(e), "stderr": p.stderr[-2000:],
                                 "wall_s": wall})
                    continue
            row = {name: {"gains": {k: repr(v) for k, v in (lp.get("gains") or {}).items()},
                          "stop": (lp.get("solver") or {}).get("stop"), "cut": (lp.get("solver") or {}).get("cut"),
                          "wall_s": lp.get("wall_time_s")} for name, lp in loops.items()}
            runs.append({"run": i, "returncode": p.returncode, "loops": row, "wall_s": wall, "load": os.getloadavg()})
            print(f"run {i}: {wall:.1f} s, load {os.getloadavg()[0]:.1f}, stops "
                  + ", ".join(f"{n} {r['stop']}" + (f" (cut {r['cut']})" if r["cut"] else "") for n, r in row.items()),
                  flush=True)
    finally:
        for b in busy:  # (only the processes this script started)
            b.kill()
            b.wait()
    names = sorted({n for r in runs for n in r.get("loops", {})})
    distinct = {n: len({json.dumps(r.get("loops", {}).get(n, {}).get("gains"), sort_keys=True) for r in runs})
                for n in names}
    ok = all("loops" in r for r in runs) and all(v == 1 for v in distinct.values())
    res = {"command": "tuner " + " ".join(command), "busy": a.busy, "runs": runs, "identical_gains": ok,
           "distinct_gains_per_loop": distinct}
    Path(a.out + ".json").write_text(json.dumps(res, indent=1))
    md = ["# Loaded determinism of a study (issue 41)", "",
          f"`{res['command']}`, {a.runs} runs beside {a.busy} CPU-bound processes: "
          + ("every loop's gains identical in every run" if ok else f"distinct gain sets per loop: {distinct}"), "",
          "| run | wall s | load (1 min) | loops: stop (cut), own wall s |", "|---|---|---|---|"]
    for r in runs:
        cells = "; ".join(f"{n} {v['stop']}" + (f" (cut {v['cut']})" if v["cut"] else "")
                          + (f" {v['wall_s']:.1f}" if v.get("wall_s") is not None else "")
                          for n, v in r.get("loops", {}).items())
        md.append(f"| {r['run']} | {r['wall_s']:.1f} | {r.get('load', [float('nan')])[0]:.1f} | "
                  f"{cells or r.get('error')} |")
    Path(a.out + ".md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
