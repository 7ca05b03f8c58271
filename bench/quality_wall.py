"""Wall time of the default tune on the quality suite, against a baseline tree measured in the same run.

    git worktree add /tmp/tuner-base 12b6462            # any earlier commit: the baseline
    python bench/quality_wall.py --baseline /tmp/tuner-base [--every 3] [--rounds 2]

Each tree is run in its own process (``PYTHONPATH=<tree>``), one after the other and alternating (A B A B ... for
``--rounds``), each process tuning the same cases (every ``--every``-th case of ``bench/quality_suite.json`` with
plant order <= 4; thesis spec, ``effort=default``, seed 0, budget 10 s, no diagnosis) **twice**: the first pass is
"cold" (the process builds every NLP it meets, as a fresh service would), the second "warm" (every NLP of these
loops built: a service that has tuned such loops before). Reported per tree: the median and 90th percentile of the
per-case wall (each case's best over the rounds), and the ratio to the baseline. The first tune of each process
(imports, CasADi's first use) is excluded. Results: ``bench/results/quality_wall.json``.
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


def _worker(ids: list[str], passes: int) -> None:
    """Runs in the tree under test (``PYTHONPATH``): tune each case ``passes`` times, print JSON."""
    import numpy as np

    from tuner import Spec, tune
    from tuner.plant import Plant

    cases = {c["id"]: c for c in json.loads((HERE / "quality_suite.json").read_text())["cases"]}
    spec = Spec.thesis() if hasattr(Spec, "thesis") else Spec()

    def one(c: dict) -> tuple[float, float, bool]:
        plant = Plant(np.array(c["num"], float), np.array(c["den"], float), delay_s=float(c["delay_s"]))
        t0, c0 = time.perf_counter(), time.process_time()
        res = tune(plant, structure=c["structure"], dt=c["dt"], spec=spec, seed=0, time_budget_s=10.0,
                   diagnose=False)
        return time.perf_counter() - t0, time.process_time() - c0, bool(res.meets_spec)

    one(cases[ids[0]])  # imports and CasADi's first use: not a tune's cost
    out = []
    for p in range(passes):
        for i in ids:
            w, cpu, ok = one(cases[i])
            out.append({"pass": p, "id": i, "wall_s": w, "cpu_s": cpu, "meets": ok})
    print(json.dumps(out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", required=False, help="a checkout of the baseline commit")
    ap.add_argument("--every", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", default=str(HERE / "results" / "quality_wall.json"))
    ap.add_argument("--worker", default="", help=argparse.SUPPRESS)
    ap.add_argument("--passes", type=int, default=2, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker:
        _worker(a.worker.split(","), a.passes)
        return
    import numpy as np

    cases = json.loads((HERE / "quality_suite.json").read_text())["cases"]
    ids = [c["id"] for k, c in enumerate(cases) if c["order"] <= 4 and k % a.every == 0]
    trees = {"current": str(ROOT)}
    if a.baseline:
        trees = {"baseline": str(Path(a.baseline).resolve()), **trees}
    runs: dict[str, list[list[dict]]] = {k: [] for k in trees}
    for r in range(a.rounds):
        for name, tree in trees.items():
            env = {**os.environ, "PYTHONPATH": tree}
            t0 = time.perf_counter()
            p = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--worker", ",".join(ids)], env=env,
                               capture_output=True, text=True, check=True)
            runs[name].append(json.loads(p.stdout.strip().splitlines()[-1]))
            print(f"round {r} {name}: {time.perf_counter() - t0:.1f} s", flush=True)
    summary: dict[str, dict] = {}
    for name, rr in runs.items():
        s = {}
        for p, label in ((0, "cold"), (1, "warm")):
            best = {i: min(row["wall_s"] for run in rr for row in run if row["pass"] == p and row["id"] == i)
                    for i in ids}
            cpu = {i: min(row["cpu_s"] for run in rr for row in run if row["pass"] == p and row["id"] == i)
                   for i in ids}
            w = np.array(list(best.values())) * 1e3
            s[label] = {"median_ms": float(np.median(w)), "p90_ms": float(np.quantile(w, 0.9)),
                        "median_cpu_ms": float(np.median(list(cpu.values()))) * 1e3, "per_case_ms": best}
        summary[name] = s
    load = os.getloadavg()
    doc = {"command": "python bench/quality_wall.py " + " ".join(sys.argv[1:]), "cases": ids,
           "machine": f"{os.cpu_count()} cores, load average at the end {load[0]:.1f}/{load[1]:.1f}/{load[2]:.1f}",
           "summary": summary}
    for label in ("cold", "warm"):
        line = " | ".join(f"{n}: median {summary[n][label]['median_ms']:.0f} ms (p90 {summary[n][label]['p90_ms']:.0f})"
                          for n in trees)
        if "baseline" in trees:
            doc[f"ratio_{label}"] = summary["current"][label]["median_ms"] / summary["baseline"][label]["median_ms"]
            line += f" | current/baseline {doc[f'ratio_{label}']:.2f}"
        print(f"{label}: {line}  ({len(ids)} cases)")
    Path(a.out).parent.mkdir(exist_ok=True)
    Path(a.out).write_text(json.dumps(doc, indent=1))
    print(f"-> {a.out}")


if __name__ == "__main__":
    main()
