"""Issue 30, item 1: where a warm ``tune()`` spends its time, and what a compiled NLP would give back.

    .venv/bin/python bench/warm_phases.py [--seeds 5] [--revs 12b6462] [--jit=-O0,-O1] [--out bench/results/warm_phases]

For the README's loops (``bench/warm_speed.py``'s LOOPS) at each effort, in this process (warm: every seed tuned once
before it is timed, and the NLP builds while timed counted; each tune on freshly built plants):

* the median wall of a tune, and per tune the time in each of the engine's phases (round 0, the fine polish, the
  restart, the ray, the scan, the batch scorings, the refinements, the final verification; the phases nest, so the
  shares do not add up) and in the CasADi NLP solves themselves (``_Solves.__call__``);
* **outside the NLP**: the median of (wall - NLP solve time) per tune, what the tune would cost with a local solver
  that took no time at all;
* with ``--revs``: each older tree's median wall on the same loops in a warm worker (``bench/speed_worker.py``),
  the runs alternating seed by seed, and every figure above as a ratio to the first tree's (the old engine, whose
  figures issue 30's targets were set against: 27 / 29 / 24 / 51 ms for roll / pitch / yaw / 1/(s+1)^3; targets
  40 / 40 / 40 / 60 ms default, 15 ms fast, so the target ratios below are target / the issue's old-engine figure).

With ``--jit``: one default tune of each loop (seed 0) is recorded (every NLP it built and every solve's arguments)
and its solves replayed (twice; the second pass timed) on CasADi's virtual machine and on the same NLP compiled by
CasADi's JIT with gcc at each of the given optimisation flags: the compile time, the replay's time, and whether every
solution is bitwise the same.
Nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import platform
import shlex
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))

from tune_speed import SpeedWorker, extract, load_average  # noqa: E402
from warm_speed import LOOPS, write  # noqa: E402

ISSUE_OLD_MS = {"roll": 27.0, "pitch": 29.0, "yaw": 24.0, "1/(s+1)^3": 51.0}  # issue 30's table, 12b6462
TARGET_MS = {"default": {"roll": 40.0, "pitch": 40.0, "yaw": 40.0, "1/(s+1)^3": 60.0},
             "fast": {"roll": 15.0, "pitch": 15.0, "yaw": 15.0, "1/(s+1)^3": 15.0}}
PHASES = ("run", "_round0", "_refine", "_polish", "_restart", "_ray", "_scan", "_score", "verify_best")


class Timers:
    """Wall time per phase, summed over the tunes timed (the engine's methods and the NLP solves wrapped)."""

    def __init__(self) -> None:
        self.t: dict[str, float] = collections.defaultdict(float)
        self.n: collections.Counter = collections.Counter()
        self.on = False

    def wrap(self, owner: Any, name: str, label: str | None = None) -> None:
        f, label = getattr(owner, name), label or name

        def timed(*a: Any, **k: Any) -> Any:
            if not self.on:
                return f(*a, **k)
            t0 = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                self.t[label] += time.perf_counter() - t0
                self.n[label] += 1

        setattr(owner, name, timed)


def _install() -> Timers:
    import tuner.optimize.engine as engine
    import tuner.optimize.nlp.refine as refine

    timers = Timers()
    for name in PHASES:
        timers.wrap(engine.Engine, name)
    timers.wrap(refine._Solves, "__call__", "nlp_solve")
    return timers


def phases(seeds: int, revs: list[str]) -> dict[str, Any]:
    import tuner.optimize.nlp.transcribe as transcribe
    from tuner import plant_from_expr, tune

    timers = _install()
    tmp = Path(tempfile.mkdtemp(prefix="warm_phases_"))
    workers = {}
    for rev in revs:
        (tmp / rev).mkdir()
        extract(rev, tmp / rev)
        workers[rev] = SpeedWorker(rev, tmp / rev, tmp)
    rows = []
    try:
        for loop, (expr, structure, dt) in LOOPS.items():
            for effort in ("default", "fast"):
                kw = {"structure": structure, "dt": dt, "time_budget_s": 10.0}
                old = {rev: {"cmd": "tune_expr", "plant": expr, "effort": effort, **kw} for rev in workers}
                # warm-up: every seed timed below, once first, in every process (a seed's search can need an NLP no
                # other seed built: its build would land in the figures)
                for seed in range(seeds):
                    tune(plant_from_expr(expr), seed=seed, effort=effort, **kw)
                    for rev, w in workers.items():
                        w.call(seed=seed, **old[rev])
                walls, outside, per = [], [], collections.defaultdict(list)
                old_walls: dict[str, list[float]] = {rev: [] for rev in workers}
                settle = []
                builds0 = transcribe.BUILDS["count"]
                for seed in range(seeds):
                    for rev, w in workers.items():
                        old_walls[rev].append(w.call(seed=seed, **old[rev])["wall_s"])
                    p = plant_from_expr(expr)
                    timers.t.clear()
                    timers.n.clear()
                    timers.on = True
                    t0 = time.perf_counter()
                    r = tune(p, seed=seed, effort=effort, **kw)
                    wall = time.perf_counter() - t0
                    timers.on = False
                    walls.append(wall)
                    outside.append(wall - timers.t["nlp_solve"])
                    settle.append(float(r.metrics.settling_time_s))
                    for k in (*PHASES, "nlp_solve"):
                        per[k].append(timers.t[k])
                        per[k + "#"].append(timers.n[k])
                row = {"loop": loop, "structure": structure, "dt": dt, "effort": effort,
                       "median_wall_ms": 1e3 * statistics.median(walls), "mean_wall_ms": 1e3 * statistics.mean(walls),
                       # the NLP solves' share of the tunes' time (their sum over the walls' sum)
                       "nlp_share": sum(per["nlp_solve"]) / sum(walls),
                       "builds_while_timed": transcribe.BUILDS["count"] - builds0,
                       "median_outside_nlp_ms": 1e3 * statistics.median(outside),
                       "median_settling_s": statistics.median(settle),
                       "phases_ms": {k: 1e3 * statistics.mean(per[k]) for k in (*PHASES, "nlp_solve")},
                       "calls": {k: statistics.mean(per[k + "#"]) for k in (*PHASES, "nlp_solve")},
                       "old_median_wall_ms": {rev: 1e3 * statistics.median(v) for rev, v in old_walls.items()},
                       "target_ms": TARGET_MS[effort][loop], "issue_old_ms": ISSUE_OLD_MS[loop]}
                rows.append(row)
                print(f"[warm_phases] {loop} {effort}: {row['median_wall_ms']:.0f} ms, outside the NLP "
                      f"{row['median_outside_nlp_ms']:.0f} ms, old {row['old_median_wall_ms']}", file=sys.stderr,
                      flush=True)
    finally:
        for w in workers.values():
            w.close()
        shutil.rmtree(tmp, ignore_errors=True)
    return {"rows": rows}


class _Recorder:
    """While on: every NLP the tune builds (by its key) and every solve's arguments (with the NLP's key)."""

    def __init__(self) -> None:
        import tuner.optimize.nlp.refine as refine
        import tuner.optimize.nlp.transcribe as transcribe

        self.refine, self.transcribe = refine, transcribe
        self.nlps: dict[Any, dict] = {}
        self.calls: list[tuple[Any, dict]] = []
        self.solver, self.solve = transcribe._solver, refine._Solves.__call__

    def __enter__(self) -> _Recorder:
        rec, solver, solve = self, self.solver, self.solve

        def recording_solver(key: Any, nlp: dict) -> Any:
            rec.nlps[key] = nlp
            return solver(key, nlp)

        def recording_solve(s: Any, ts: float, x_init: np.ndarray) -> Any:
            rec.calls.append((s.prob.key, {"x0": np.array(x_init, float), "p": np.array(s._params(ts), float).ravel(),
                                           "lbx": s.lbx, "ubx": s.ubx, "lbg": s.prob.lbg, "ubg": s.prob.ubg}))
            return solve(s, ts, x_init)

        self.transcribe._CACHE.clear()  # (every NLP of the tune built while recording, so recorded)
        self.transcribe._solver, self.refine._Solves.__call__ = recording_solver, recording_solve
        return self

    def __exit__(self, *exc: Any) -> None:
        self.transcribe._solver, self.refine._Solves.__call__ = self.solver, self.solve


def jit(flags: list[str]) -> list[dict[str, Any]]:
    """Replay one default tune's NLP solves per loop on the virtual machine and compiled (see the module)."""
    from tuner import plant_from_expr, tune

    out = []
    work = Path(tempfile.mkdtemp(prefix="warm_phases_jit_"))  # (CasADi's JIT writes its sources in the cwd)
    here = Path.cwd()
    os.chdir(work)
    try:
        for loop, (expr, structure, dt) in LOOPS.items():
            with _Recorder() as rec:
                tune(plant_from_expr(expr), structure=structure, dt=dt, seed=0, time_budget_s=60.0)
            for key, nlp in rec.nlps.items():
                mine = [c for k, c in rec.calls if k == key]
                if mine:
                    out.append(_replay_nlp(loop, key, nlp, mine, flags))
    finally:
        os.chdir(here)
        shutil.rmtree(work, ignore_errors=True)
    return out


def _replay_nlp(loop: str, key: Any, nlp: dict, calls: list[dict], flags: list[str]) -> dict[str, Any]:
    """One NLP's recorded solves on the virtual machine and compiled at each of ``flags``."""
    import casadi as cs

    import tuner.optimize.nlp.transcribe as transcribe

    ref, vm_s = _replay(transcribe._solver(key, nlp), calls)
    entry = {"loop": loop, "K": key.K, "N": key.N, "head": key.head, "rows": int(nlp["g"].shape[0]),
             "solves": len(calls), "vm_ms": 1e3 * vm_s, "compiled": {}}
    for flag in flags:
        opts = dict(transcribe.sqp_options(), jit=True, compiler="shell",
                    jit_options={"flags": [flag], "verbose": False})
        t0 = time.perf_counter()
        compiled = cs.nlpsol("jit_replay", "sqpmethod", nlp, opts)
        compile_s = time.perf_counter() - t0
        got, run_s = _replay(compiled, calls)
        entry["compiled"][flag] = {"compile_s": compile_s, "ms": 1e3 * run_s, "speedup": vm_s / run_s,
                                   "bitwise_equal": all(np.array_equal(a, b) for a, b in zip(ref, got))}
    print(f"[warm_phases] jit {loop} K={key.K} N={key.N}: {entry}", file=sys.stderr, flush=True)
    return entry


def machine_speed() -> float:
    """Seconds a pure-Python loop of 10^7 additions takes here (the machine's speed, recorded with the results)."""
    t0 = time.perf_counter()
    total = 0
    for i in range(10**7):
        total += i
    return time.perf_counter() - t0


def _replay(solver: Any, calls: list[dict]) -> tuple[list[np.ndarray], float]:
    """Every solve of ``calls`` on ``solver``, twice (the first pass loads and allocates): the second pass's solutions
    and seconds."""
    for c in calls:
        solver(**c)
    t0 = time.perf_counter()
    xs = [np.array(solver(**c)["x"]).ravel() for c in calls]
    return xs, time.perf_counter() - t0


def markdown(res: dict[str, Any]) -> str:
    revs = res["revs"]
    speed = res.get("python_loop_s")
    lines = ["# Where a warm tune's time goes (issue 30, item 1)", "",
             f"`{res['command']}`; load average at the end {res['load_end']}"
             + (f"; a pure-Python loop of 10^7 additions took {speed[0]:.2f} s before and {speed[-1]:.2f} s after"
                if speed else "") + ".", ""]
    if res["phases"]:
        lines += [f"{res['seeds']} seeds per loop and effort, each tuned once before (warm: "
                  f"{sum(r.get('builds_while_timed', 0) for r in res['phases'])} NLP builds while timed). ms per tune "
                  "(phases: mean; wall and outside the NLP: median). *Outside the NLP*: the wall less the CasADi "
                  "solves, what a tune would cost if the local solver took no time; *NLP share*: the solves' time "
                  "over the tunes'. Ratios: to " + (revs[0] if revs else "the old engine") + " in this run; the target "
                  "ratio is the issue's target over its old-engine figure.", ""]
        lines += _phase_table(res)
    if res.get("jit"):
        lines += ["", "## One default tune's NLP solves replayed, compiled", "",
                  "One default tune (seed 0) of each loop, its solves replayed twice per solver, the second pass "
                  "timed; the speed-up is the virtual machine's time over the compiled one's.", "",
                  "| loop | K | N | head | rows | solves | VM ms | " +
                  " | ".join(f"{f}: compile s, ms, speed-up, bitwise" for f in res["jit_flags"]) + " |",
                  "|" + "---|" * (7 + len(res["jit_flags"]))]
        for e in res["jit"]:
            lines.append(f"| {e['loop']} | {e['K']} | {e['N']} | {e['head']} | {e['rows']} | {e['solves']} | "
                         f"{e['vm_ms']:.1f} | " + " | ".join(
                             "{compile_s:.1f}, {ms:.1f}, {speedup:.2f}, {bitwise_equal}".format(**e["compiled"][f])
                             for f in res["jit_flags"]) + " |")
    return "\n".join(lines) + "\n"


def _phase_table(res: dict[str, Any]) -> list[str]:
    revs, lines = res["revs"], []
    head = ["loop", "effort", "wall", "NLP solves (n)", "NLP share", "outside the NLP"] + \
        [f"{r} wall" for r in revs] + \
        ([f"wall / {revs[0]}", f"outside / {revs[0]}", "target ratio"] if revs else []) + \
        ["round 0", "polish", "restart", "ray", "scan", "scorings", "verify", "settling s"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in res["phases"]:
        ph = r["phases_ms"]
        cells = [f"{r['loop']} {r['structure']}", r["effort"], f"{r['median_wall_ms']:.0f}",
                 f"{ph['nlp_solve']:.0f} ({r['calls']['nlp_solve']:.0f})",
                 f"{100 * r['nlp_share']:.0f} %" if "nlp_share" in r else "—", f"{r['median_outside_nlp_ms']:.0f}"]
        cells += [f"{r['old_median_wall_ms'][v]:.0f}" for v in revs]
        if revs:
            old = r["old_median_wall_ms"][revs[0]]
            cells += [f"{r['median_wall_ms'] / old:.2f}", f"{r['median_outside_nlp_ms'] / old:.2f}",
                      f"{r['target_ms'] / r['issue_old_ms']:.2f}"]
        cells += [f"{ph[k]:.0f}" for k in ("_round0", "_polish", "_restart", "_ray", "_scan", "_score",
                                           "verify_best")]
        cells.append(f"{r['median_settling_s']:.4f}")
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--revs", default="12b6462", help="older trees, comma-separated (the first: the old engine); "
                    "'' for none")
    ap.add_argument("--jit", default="", help="gcc flags to compile the replayed NLPs with, comma-separated "
                    "(e.g. --jit=-O0,-O1); '' (default): no replay")
    ap.add_argument("--no-phases", action="store_true", help="only the replay")
    ap.add_argument("--out", default=str(HERE / "results" / "warm_phases"))
    ap.add_argument("--report", action="store_true", help="only write --out's markdown again from its JSON")
    a = ap.parse_args()
    if a.report:
        res = json.loads(Path(a.out + ".json").read_text())
        Path(a.out + ".md").write_text(markdown(res))
        return
    revs = [r for r in a.revs.split(",") if r]
    flags = [f for f in a.jit.split(",") if f]
    res: dict[str, Any] = {"command": shlex.join(["python", "bench/warm_phases.py", *sys.argv[1:]]), "seeds": a.seeds,
                           "revs": revs, "jit_flags": flags,
                           "machine": {"cores": os.cpu_count(), "python": platform.python_version()}}
    res["python_loop_s"] = [machine_speed()]
    res["phases"] = [] if a.no_phases else phases(a.seeds, revs)["rows"]
    res["jit"] = jit(flags) if flags else []
    res["load_end"] = load_average()
    res["python_loop_s"].append(machine_speed())
    write(a.out, res, markdown)


if __name__ == "__main__":
    main()
