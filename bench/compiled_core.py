"""Issue 41, item 1: the compiled core measured against the old engine (12b6462) in one run.

    .venv/bin/python bench/compiled_core.py [--seeds 7] [--cold 5] [--out bench/results/compiled_core]

Warm: one warm worker process per tree (bench/speed_worker.py): the old engine (12b6462, extracted with ``git
archive``), this tree with the compiled kernels (``TUNER_KERNELS=on``) and this tree on the numpy path
(``TUNER_KERNELS=off``); every worker with one BLAS thread. The loops: the thesis's roll, pitch and yaw models with
``pid_z`` at dt 0.04 (studies/quadrotor.toml), 1/(s+1)^3 with ``pid`` at dt 0.1, and ``px4_rate`` on
200/((s+2)(0.03s+1)) with a 6 ms delay at 400 Hz (this tree only: the old engine has no firmware laws). Each worker
tunes each loop once (imports, builds, kernels loaded), then the seeds 0..N-1, the workers taking turns run by run.
Reported: median wall per loop and effort, the ratio to the old engine, the verifier's settling.

Cold: ``tuner analyze`` (the README's), ``tuner tune`` of the README's roll loop and of the px4_rate loop, each a new
process, taking turns, N times each; the NLP cache warm (run this script twice, or once after a first tune: the
script reports which compiled shapes the cache holds). The kernels' first compile: ``python -m
tuner.optimize.kernels`` into an empty cache folder. The load average at the start and the end of each part (the
machine is shared). Nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from tune_speed import SpeedWorker, extract, load_average  # noqa: E402
from warm_speed import LOOPS, alternate, write  # noqa: E402

PX4 = ("200/((s+2)*(0.03*s+1))", "px4_rate", 0.0025, 0.006)
ROLL = "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)"
ONE_THREAD = dict.fromkeys(("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"), "1")
COLD = {
    "analyze": ["analyze", "--plant", ROLL, "--dt", "0.04", "--controller", "3.868*(z^2-1.305*z+0.5668)/(z*(z-1))"],
    "tune roll": ["tune", "--plant", ROLL, "--dt", "0.04", "--structure", "pid_z"],
    "tune px4_rate": ["tune", "--plant", PX4[0], "--delay", str(PX4[3]), "--dt", str(PX4[2]), "--structure",
                      "px4_rate"],
}


def warm(old: str, seeds: int) -> dict[str, Any]:
    tmp = Path(tempfile.mkdtemp(prefix="compiled_core_"))
    (tmp / "old").mkdir()
    sha = extract(old, tmp / "old")
    off = {**ONE_THREAD, "TUNER_NLP_COMPILE": "off"}  # interpreted NLPs
    workers = {"old": SpeedWorker("old", tmp / "old", tmp, env=ONE_THREAD),
               "kernels": SpeedWorker("kernels", ROOT, tmp, env={**off, "TUNER_KERNELS": "on"}),
               "numpy": SpeedWorker("numpy", ROOT, tmp, env={**off, "TUNER_KERNELS": "off"}),
               # the kernels and the NLPs' compiled code where the cache has it (none compiled here: "load")
               "kernels+nlp": SpeedWorker("kernels+nlp", ROOT, tmp, env={**ONE_THREAD, "TUNER_KERNELS": "on",
                                                                       "TUNER_NLP_COMPILE": "load"})}
    loops = {k: (*v, None) for k, v in LOOPS.items()} | {"px4_rate 6 ms 400 Hz": PX4}
    rows = []
    try:
        for loop, (expr, structure, dt, delay) in loops.items():
            for effort in ("default", "fast"):
                active = [n for n in workers if not (n == "old" and (effort != "default" or delay is not None))]
                req = {"cmd": "tune_expr", "plant": expr, "structure": structure, "dt": dt, "effort": effort,
                       "time_budget_s": 10.0} | ({"delay": delay} if delay is not None else {})
                load0 = load_average()
                runs = alternate(workers, active, req, seeds)
                row = {"loop": loop, "effort": effort, "load_start": load0, "load_end": load_average(),
                       "trees": {n: {"median_wall_ms": 1e3 * statistics.median(r["wall_s"] for r in rs),
                                     "median_cpu_ms": 1e3 * statistics.median(r["cpu_s"] for r in rs),
                                     "median_settling_s": statistics.median(float(r["settling_s"]) for r in rs),
                                     "all_meet": all(r["meets_spec"] for r in rs)} for n, rs in runs.items()}}
                rows.append(row)
                print(f"[compiled_core] {loop} {effort}: " + ", ".join(
                    f"{n} {t['median_wall_ms']:.0f} ms" for n, t in row["trees"].items()), file=sys.stderr, flush=True)
    finally:
        for w in workers.values():
            w.close()
        shutil.rmtree(tmp, ignore_errors=True)
    return {"old": sha, "rows": rows}


def cold(reps: int) -> dict[str, Any]:
    exe = str(Path(sys.executable).with_name("tuner"))
    times: dict[str, list[float]] = {k: [] for k in COLD}
    load0 = load_average()
    for i in range(reps):
        names = list(COLD)
        for name in names[i % len(names):] + names[:i % len(names)]:
            t0 = time.perf_counter()
            # "load": the entries there are, no new compile started (a background gcc would load the machine)
            subprocess.run([exe, *COLD[name]], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT,
                           env={**os.environ, "TUNER_NLP_COMPILE": "load"})
            times[name].append(time.perf_counter() - t0)
    med = {k: statistics.median(v) for k, v in times.items()}
    cache = subprocess.run([sys.executable, "-m", "tuner.optimize.nlp.codecache"], capture_output=True, text=True,
                           cwd=ROOT).stdout
    return {"median_s": med, "all_s": times, "load_start": load0, "load_end": load_average(), "nlp_cache": cache,
            "ratio_to_analyze": {k: med[k] / med["analyze"] for k in med}}


def kernels_first_compile() -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-m", "tuner.optimize.kernels"], capture_output=True, text=True,
                             env={**os.environ, "TUNER_CACHE_DIR": d}, cwd=ROOT)
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "tuner.optimize.kernels"], capture_output=True, text=True,
                       env={**os.environ, "TUNER_CACHE_DIR": d}, cwd=ROOT)
        again = time.perf_counter() - t0
    return {"first_process_s": first, "cached_process_s": again, "said": out.stdout.strip(), "load": load_average()}


def _f(v: float | None) -> str:
    return "—" if v is None else f"{v:.0f}"


def _q(a: float | None, b: float | None) -> str:
    return "—" if a is None or b is None else f"{a / b:.2f}"


def markdown(res: dict[str, Any]) -> str:
    lines = ["# The compiled core (issue 41 item 1)", "", f"`{res['command']}`, old engine {res['warm']['old'][:7]}; "
             "load averages (1, 5, 15 min) as measured: the machine is shared.", "",
             "## Warm medians (ms, in process)", "",
             "Trees: old = the old engine; kernels = this tree, kernels on, NLPs interpreted; numpy = this tree, "
             "numpy path, NLPs interpreted; k+nlp = kernels on and the NLPs' compiled code where the cache holds "
             "the shape (none compiled during the run).", "",
             "| loop | effort | old | kernels | numpy | k+nlp | kernels / old | k+nlp / old | numpy / old "
             "| kernels / numpy | settling old | settling kernels | load |", "|" + "---|" * 13]
    for r in res["warm"]["rows"]:
        t = r["trees"]
        ms = {n: t[n]["median_wall_ms"] if n in t else None for n in ("old", "kernels", "numpy", "kernels+nlp")}
        st = {n: f"{t[n]['median_settling_s']:.4f}" if n in t else "—" for n in ("old", "kernels")}
        lines.append(f"| {r['loop']} | {r['effort']} | {_f(ms['old'])} | {_f(ms['kernels'])} | {_f(ms['numpy'])} | "
                     f"{_f(ms['kernels+nlp'])} | {_q(ms['kernels'], ms['old'])} | {_q(ms['kernels+nlp'], ms['old'])} | "
                     f"{_q(ms['numpy'], ms['old'])} | "
                     f"{_q(ms['kernels'], ms['numpy'])} | {st['old']} | {st['kernels']} | {r['load_start']} |")
    c = res["cold"]
    lines += ["", "## Cold command line (a new process each, NLP cache warm)", "", "| command | median s | / analyze |",
              "|---|---|---|"]
    lines += [f"| {k} | {v:.2f} | {c['ratio_to_analyze'][k]:.2f} |" for k, v in c["median_s"].items()]
    lines += ["", f"load {c['load_start']} -> {c['load_end']}", "", "NLP cache:", "", "```", c["nlp_cache"].strip(),
              "```", "", "## The kernels' first compile", "",
              f"first process {res['kernels']['first_process_s']:.1f} s, a later process "
              f"{res['kernels']['cached_process_s']:.1f} s ({res['kernels']['said']}; load {res['kernels']['load']})",
              ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=7)
    ap.add_argument("--cold", type=int, default=5)
    ap.add_argument("--old", default="12b6462")
    ap.add_argument("--out", default=str(HERE / "results" / "compiled_core"))
    a = ap.parse_args()
    res = {"command": "python bench/compiled_core.py " + " ".join(sys.argv[1:]), "load_start": load_average()}
    res["kernels"] = kernels_first_compile()
    res["cold"] = cold(a.cold)
    res["warm"] = warm(a.old, a.seeds)
    res["load_end"] = load_average()
    write(a.out, res, markdown)


if __name__ == "__main__":
    main()
