"""Where a ``tuner study run`` spends its time: a timeline of the parent and of every worker, in CPU terms.

    .venv/bin/python bench/study_timeline.py [--study studies/process.toml] [--workers 1 2] [--repeat 1]

Each run is a fresh interpreter (``python -m tuner.cli study run`` with hooks added, see ``_child``) on a fresh
output directory. The hooks record, per process (the parent, each worker, each report process): its start, the
worker's kernels and study loaded, every loop's tune (start, end, CPU seconds), the report's phases, its exit;
each with the wall clock and the process's CPU time. From them: per-loop CPU, the CPU per process, the critical
path in CPU terms (the parent's serial CPU plus the busiest worker's CPU, against the whole run's CPU), and the
loop-to-worker assignment. Wall times are printed too, with the load average, but on a shared machine only the
CPU figures compare. Nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import json
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


def _child(events_path: str, argv: list[str]) -> int:
    """Run ``tuner`` with ``argv`` in this process, recording the timeline's events to ``events_path``."""
    t_start = time.time()
    import functools

    def rec(event: str, **kw) -> None:
        line = json.dumps({"pid": os.getpid(), "ppid": os.getppid(), "event": event, "wall": time.time(),
                           "cpu": time.process_time(), **kw})
        with open(events_path, "a") as f:  # one write per line: lines of several processes do not interleave
            f.write(line + "\n")

    rec("interpreter", wall0=t_start)
    from tuner import cli as tcli
    from tuner.optimize import batch
    from tuner.studies import cli, evaluate, runner

    rec("imported")

    def wrap(mod, name, before, after=None):
        real = getattr(mod, name)

        @functools.wraps(real)
        def w(*a, **k):
            before(a, k)
            try:
                return real(*a, **k)
            finally:
                if after is not None:
                    after(a, k)
        setattr(mod, name, w)

    wrap(cli, "_worker_entry", lambda a, k: rec("worker_start"), lambda a, k: rec("worker_exit"))
    wrap(batch, "preload_kernels", lambda a, k: rec("kernels_start"), lambda a, k: rec("kernels_done"))
    wrap(runner, "work", lambda a, k: rec("work_start"), lambda a, k: rec("work_done"))
    wrap(evaluate, "tune_loop", lambda a, k: rec("loop_start", loop=a[1].name),
         lambda a, k: rec("loop_end", loop=a[1].name))
    wrap(cli, "run_study", lambda a, k: rec("run_study_start"), lambda a, k: rec("run_study_done"))
    wrap(cli, "write_outputs", lambda a, k: rec("outputs_start"), lambda a, k: rec("outputs_done"))
    wrap(cli, "_evaluate_and_plot", lambda a, k: rec("evaluate_start", loop=a[1].name),
         lambda a, k: rec("evaluate_end", loop=a[1].name))
    wrap(cli, "_print_summary", lambda a, k: rec("summary_start"))
    if hasattr(cli, "_create_tables"):
        wrap(cli, "_create_tables", lambda a, k: rec("tables_start"), lambda a, k: rec("tables_done"))
    if hasattr(cli, "_draw_figure"):
        wrap(cli, "_draw_figure", lambda a, k: rec("figure_start", loop=a[1].name, kind=a[3]),
             lambda a, k: rec("figure_end", loop=a[1].name, kind=a[3]))
    try:
        return tcli.main(argv)
    finally:
        rec("parent_exit")


def run_once(study: str, workers: int, plots: bool = True, tree: str | None = None) -> dict:
    """One run in a fresh interpreter: its events, wall time and CPU (the command and its children)."""
    with tempfile.TemporaryDirectory() as tmp:
        events = Path(tmp) / "events.jsonl"
        out = Path(tmp) / "out"
        argv = ["study", "run", study, "--workers", str(workers), "--out", str(out)] + ([] if plots else ["--no-plots"])
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        load0 = os.getloadavg()[0]
        t0 = time.time()
        proc = subprocess.run([sys.executable, __file__, "--child", str(events), *argv], cwd=ROOT,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                              env={**os.environ, "STUDY_TIMELINE_TREE": tree or str(ROOT)})
        wall = time.time() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if proc.returncode not in (0, 1):
            raise SystemExit(f"run failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
        evs = [json.loads(line) for line in events.read_text().splitlines()]
        results = json.loads((out / "results.json").read_text())
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"workers": workers, "wall_s": wall, "cpu_s": cpu, "t0": t0, "events": evs, "load_before": load0,
            "load_after": os.getloadavg()[0],
            "gains": {n: r.get("gains") for n, r in results["loops"].items()},
            "stop": {n: (r.get("solver") or {}).get("stop") for n, r in results["loops"].items()},
            "solver": {n: {k: (r.get("solver") or {}).get(k) for k in ("stop", "cut", "wall_time_s", "build_s")}
                       for n, r in results["loops"].items()}}


def analyse(run: dict) -> dict:
    """Per process and per loop figures from a run's events."""
    evs = run["events"]
    parent = next(e["pid"] for e in evs if e["event"] == "interpreter")
    procs: dict[int, dict] = {}
    for e in evs:
        p = procs.setdefault(e["pid"], {"events": []})
        p["events"].append(e)
    loops: dict[str, dict] = {}
    figures: dict[str, dict] = {}
    for pid, p in procs.items():
        starts = {}
        for e in p["events"]:
            if e["event"] == "loop_start":
                starts[e["loop"]] = e
            elif e["event"] == "loop_end":
                s = starts.pop(e["loop"])
                loops[e["loop"]] = {"pid": pid, "cpu_s": e["cpu"] - s["cpu"], "wall_s": e["wall"] - s["wall"],
                                    "start_s": s["wall"] - run["t0"], "end_s": e["wall"] - run["t0"]}
        fstarts = {}
        for e in p["events"]:
            if e["event"] == "figure_start":
                fstarts[(e["loop"], e["kind"])] = e
            elif e["event"] == "figure_end":
                s0 = fstarts.pop((e["loop"], e["kind"]))
                figures[f"{e['loop']}_{e['kind']}"] = {"pid": pid, "cpu_s": e["cpu"] - s0["cpu"],
                                                       "start_s": s0["wall"] - run["t0"],
                                                       "end_s": e["wall"] - run["t0"]}
        p["cpu_s"] = max(e["cpu"] for e in p["events"])  # a forked process's CPU starts at 0
        p["loops_cpu_s"] = sum(v["cpu_s"] for v in loops.values() if v["pid"] == pid)
    first = {e["event"]: e for e in procs[parent]["events"] if e["pid"] == parent}
    par = procs[parent]
    out = {"loops": loops, "figures": figures, "parent_pid": parent}
    t0 = run["t0"]
    # the parent's phases (CPU): interpreter start to its imports, to run_study, the run (its own loops when it tunes),
    # the outputs, the summary
    ev = {k: first[k] for k in first}
    out["parent"] = {
        "python_start_wall_s": ev["interpreter"]["wall0"] - t0,
        "imports_cpu_s": ev["imported"]["cpu"],
        "before_run_study_cpu_s": ev["run_study_start"]["cpu"],
        "run_study_cpu_s": ev["run_study_done"]["cpu"] - ev["run_study_start"]["cpu"],
        "outputs_cpu_s": ev["outputs_done"]["cpu"] - ev["outputs_start"]["cpu"],
        "after_outputs_cpu_s": ev["parent_exit"]["cpu"] - ev["outputs_done"]["cpu"],
        "total_cpu_s": par["cpu_s"],
        "run_study_wall_s": (ev["run_study_start"]["wall"] - t0, ev["run_study_done"]["wall"] - t0),
        "outputs_wall_s": (ev["outputs_start"]["wall"] - t0, ev["outputs_done"]["wall"] - t0),
        "exit_wall_s": ev["parent_exit"]["wall"] - t0,
    }
    workers = {}
    for pid, p in procs.items():
        names = [e["event"] for e in p["events"]]
        if "worker_start" in names:
            e = {x["event"]: x for x in p["events"]}
            workers[pid] = {"start_s": e["worker_start"]["wall"] - t0,
                            "kernels_cpu_s": e["kernels_done"]["cpu"] - e["kernels_start"]["cpu"]
                            if "kernels_done" in e else 0.0,
                            "ready_s": e["work_start"]["wall"] - t0, "ready_cpu_s": e["work_start"]["cpu"],
                            "exit_s": e["worker_exit"]["wall"] - t0, "cpu_s": p["cpu_s"],
                            "loops": [n for n, v in loops.items() if v["pid"] == pid]}
    out["workers"] = workers
    helpers = {pid for pid, p in procs.items() if any(e["event"] == "tables_start" for e in p["events"])}
    out["helper_cpu_s"] = sum(procs[pid]["cpu_s"] for pid in helpers)
    out["report_processes"] = {pid: p["cpu_s"] for pid, p in procs.items()
                               if pid != parent and pid not in workers and pid not in helpers}
    loop_cpu = sum(v["cpu_s"] for v in loops.values())
    # the critical path in CPU terms: the parent's serial CPU (its total less the loops it tuned itself) plus the
    # busiest tuner (a worker, or the parent when it tunes); the report's parallel part is counted in the parent's
    # serial part only as far as the parent does it
    tuners = {pid: sum(v["cpu_s"] for v in loops.values() if v["pid"] == pid)
              for pid in {v["pid"] for v in loops.values()}}
    worker_overhead = {pid: w["cpu_s"] - tuners.get(pid, 0.0) for pid, w in workers.items()}
    par_serial = par["cpu_s"] - tuners.get(parent, 0.0)
    # the critical path in CPU terms: the parent's whole CPU (its start and end, and the loops it tunes itself) and the
    # busiest worker's (the helper that creates the tables runs beside the parent's imports; the report's processes
    # beside each other)
    max_worker = max((w["cpu_s"] for w in workers.values()), default=0.0)
    out["summary"] = {"loops_cpu_s": loop_cpu, "max_tuner_cpu_s": max(tuners.values()),
                      "critical_cpu_s": par["cpu_s"] + max_worker, "max_worker_cpu_s": max_worker,
                      "helper_cpu_s": out["helper_cpu_s"],
                      "parent_serial_cpu_s": par_serial, "worker_overhead_cpu_s": worker_overhead,
                      "report_processes_cpu_s": sum(out["report_processes"].values()),
                      "total_cpu_s": run["cpu_s"], "wall_s": run["wall_s"]}
    return out


def model(one: dict, two: dict) -> dict:
    """The 2-worker run's critical path priced at the 1-worker run's CPU per unit of work (each loop's tune, each
    figure, a worker's start, the parent's own CPU): what the schedule of ``two`` would take on two cores that
    nothing else loads, where a unit costs what it costs alone. On a shared machine a process's CPU for the same work
    grows with the load beside it (the loops' CPU in one 2-worker run here: 10.4 s against 8.1 s at 1 worker, for
    the same work), so the measured CPU of a 2-worker run overstates its critical path."""
    a1, a2 = one["analysis"], two["analysis"]
    w1 = next(iter(a1["workers"].values()))
    fig1 = a1["figures"]
    per_fig = statistics.median(v["cpu_s"] for v in fig1.values()) if fig1 else 0.0
    # a worker's own CPU beyond its loops and figures (start, kernels, storage reads, matplotlib's import): the
    # 1-worker run's, paid by each worker
    start1 = w1["cpu_s"] - sum(v["cpu_s"] for v in a1["loops"].values()) - sum(v["cpu_s"] for v in fig1.values())
    per_worker = {}
    for pid, w in a2["workers"].items():
        loops = sum(a1["loops"][n]["cpu_s"] for n in w["loops"])
        figs = sum(fig1.get(k, {"cpu_s": per_fig})["cpu_s"] for k, v in a2["figures"].items() if v["pid"] == pid)
        per_worker[pid] = start1 + loops + figs
    parent = a1["parent"]["total_cpu_s"]
    crit2 = parent + max(per_worker.values())
    crit1 = parent + w1["cpu_s"]
    return {"parent_cpu_s": parent, "worker_start_cpu_s": start1, "per_worker_cpu_s": list(per_worker.values()),
            "critical_1_cpu_s": crit1, "critical_2_cpu_s": crit2, "ratio": crit1 / crit2}


def ideal(one: dict, workers: int = 2) -> dict:
    """The best a ``workers``-worker run could do with the 1-worker run ``one``'s work, in its CPU: the serial part
    (the parent's CPU, the worker's own start: everything that is not a loop's tune or a figure, each paid once per
    worker where a worker pays it) plus the parallel part split as evenly as the loops allow (the best partition of
    the loops over the workers, found by trying every one, with the figures then filling the lighter workers as
    water, which they can only approach: a figure is drawn after its loop is tuned). A lower bound of the makespan
    on ``workers`` free cores, where each unit costs what it cost alone; its ratio to the 1-worker run's critical
    path is the speed-up no schedule can beat on this work."""
    import itertools

    a1 = one["analysis"]
    w1 = next(iter(a1["workers"].values()))
    loops = {n: v["cpu_s"] for n, v in a1["loops"].items()}
    figs = sum(v["cpu_s"] for v in a1["figures"].values())
    start = w1["cpu_s"] - sum(loops.values()) - figs  # a worker's own CPU beyond its loops and figures
    parent = a1["parent"]["total_cpu_s"]
    names = list(loops)
    best = None
    for assign in itertools.product(range(workers), repeat=len(names)):
        load = [0.0] * workers
        for n, k in zip(names, assign):
            load[k] += loops[n]
        # the figures fill the lighter workers first (water-filling; divisible, as a lower bound)
        left, level = figs, sorted(load)
        for i in range(workers):
            nxt = level[i + 1] if i + 1 < workers else float("inf")
            room = (nxt - level[i]) * (i + 1)
            if left <= room:
                top = level[i] + left / (i + 1)
                break
            left -= room
        span = max(max(load), top)
        if best is None or span < best[0]:
            best = (span, {names[j]: k for j, k in enumerate(assign)}, load)
    crit1 = parent + w1["cpu_s"]
    crit2 = parent + start + best[0]
    return {"parent_cpu_s": parent, "worker_start_cpu_s": start, "loops_cpu_s": loops, "figures_cpu_s": figs,
            "best_split": best[1], "best_loads_cpu_s": best[2], "parallel_span_cpu_s": best[0],
            "critical_1_cpu_s": crit1, f"ideal_{workers}_cpu_s": crit2, "ratio": crit1 / crit2,
            "serial_share": (parent + start) / crit1}


def _table(runs: list[dict]) -> None:
    """The medians per tree and worker count: CPU critical path and the ratio it allows."""
    print("\n| tree | workers | runs | wall [s] | CPU [s] | loops CPU [s] | busiest tuner CPU [s] | serial CPU [s] "
          "| critical path CPU [s] |")
    print("|---|---|---|---|---|---|---|---|---|")
    keys = sorted({(r["tree"], r["workers"]) for r in runs}, key=lambda k: (k[0], k[1]))
    for tree, w in keys:
        rs = [r["analysis"]["summary"] for r in runs if (r["tree"], r["workers"]) == (tree, w)]
        med = {k: statistics.median(s[k] for s in rs) for k in ("wall_s", "total_cpu_s", "loops_cpu_s",
                                                                 "max_tuner_cpu_s", "parent_serial_cpu_s",
                                                                 "critical_cpu_s")}
        print(f"| {tree} | {w} | {len(rs)} | {med['wall_s']:.2f} | {med['total_cpu_s']:.2f} | "
              f"{med['loops_cpu_s']:.2f} | {med['max_tuner_cpu_s']:.2f} | {med['parent_serial_cpu_s']:.2f} | "
              f"{med['critical_cpu_s']:.2f} |")
    crit = {k: statistics.median(r["analysis"]["summary"]["critical_cpu_s"] for r in runs
                                 if (r["tree"], r["workers"]) == k) for k in keys}
    for tree in dict.fromkeys(t for t, _ in keys):
        if (tree, 1) in crit and (tree, 2) in crit:
            print(f"{tree}: critical path 1 worker / 2 workers (CPU) = {crit[(tree, 1)] / crit[(tree, 2)]:.2f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", default="studies/process.toml")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--no-plots", action="store_true")
    ap.add_argument("--json", default=None, help="write every run's events and analysis here")
    ap.add_argument("--from-json", default=None, help="analyse the runs a --json file holds instead of running")
    ap.add_argument("--tree", nargs="+", default=[str(ROOT)],
                    help="source trees whose tuner/ to run, alternating (e.g. a `git archive` of the baseline)")
    a = ap.parse_args(argv)
    runs = []
    saved = json.loads(Path(a.from_json).read_text()) if a.from_json else None
    if saved:
        a.tree = list(dict.fromkeys(r["tree"] for r in saved))
        a.workers = sorted({r["workers"] for r in saved})
        a.repeat = max(sum(1 for r in saved if (r["tree"], r["workers"]) == (t, w)) for t in a.tree for w in a.workers)
    todo = iter(saved or [])
    for i in range(a.repeat):
        for tree, w in ((t, w) for t in a.tree for w in a.workers):
            r = next(todo) if saved else run_once(a.study, w, plots=not a.no_plots, tree=tree)
            r["analysis"] = an = analyse(r)
            r["tree"] = tree
            runs.append(r)
            s = an["summary"]
            print(f"## run {i + 1}, {tree}, workers {w}: {s['wall_s']:.2f} s wall, {s['total_cpu_s']:.2f} s CPU "
                  f"(load average {r['load_before']:.2f} before, {r['load_after']:.2f} after)")
            par = an["parent"]
            print(f"parent: imports {par['imports_cpu_s']:.2f} s CPU, "
                  f"until run_study {par['before_run_study_cpu_s']:.2f}, "
                  f"run_study {par['run_study_cpu_s']:.2f}, outputs {par['outputs_cpu_s']:.2f}, "
                  f"after {par['after_outputs_cpu_s']:.2f}; total {par['total_cpu_s']:.2f} s CPU; "
                  f"run_study wall {par['run_study_wall_s'][0]:.2f}-{par['run_study_wall_s'][1]:.2f} s, "
                  f"outputs {par['outputs_wall_s'][0]:.2f}-{par['outputs_wall_s'][1]:.2f} s, "
                  f"exit {par['exit_wall_s']:.2f}")
            for pid, wk in an["workers"].items():
                print(f"worker {pid}: start {wk['start_s']:.2f} s, kernels {wk['kernels_cpu_s']:.2f} s CPU, ready "
                      f"{wk['ready_s']:.2f} s ({wk['ready_cpu_s']:.2f} s CPU), exit {wk['exit_s']:.2f} s, "
                      f"{wk['cpu_s']:.2f} s CPU, loops {wk['loops']}")
            print("| loop | process | CPU [s] | wall [s] | start-end [s] | stop |")
            print("|---|---|---|---|---|---|")
            for n, v in sorted(an["loops"].items(), key=lambda kv: kv[1]["start_s"]):
                who = "parent" if v["pid"] == an["parent_pid"] else str(v["pid"])
                print(f"| {n} | {who} | {v['cpu_s']:.2f} | {v['wall_s']:.2f} | {v['start_s']:.2f}-{v['end_s']:.2f} | "
                      f"{r['stop'][n]} |")
            print(f"loops {s['loops_cpu_s']:.2f} s CPU, busiest tuner {s['max_tuner_cpu_s']:.2f}, parent serial "
                  f"{s['parent_serial_cpu_s']:.2f}, workers' own overhead "
                  f"{', '.join(f'{v:.2f}' for v in s['worker_overhead_cpu_s'].values()) or '-'}, report processes "
                  f"{s['report_processes_cpu_s']:.2f}, table helper {s['helper_cpu_s']:.2f}; critical path "
                  f"{s['critical_cpu_s']:.2f} s CPU (parent + busiest worker {s['max_worker_cpu_s']:.2f})\n",
                  flush=True)
    for tree in a.tree:
        ones = [r for r in runs if r["tree"] == tree and r["workers"] == 1]
        twos = [r for r in runs if r["tree"] == tree and r["workers"] == 2]
        for i, (r1, r2) in enumerate(zip(ones, twos)):
            if not r1["analysis"]["workers"]:
                continue  # (a tree whose single worker tunes in the parent: no per-worker start to price)
            m = model(r1, r2)
            r2["model"] = m
            print(f"{tree} pair {i + 1}: the 2-worker schedule at the 1-worker run's CPU per unit: parent "
                  f"{m['parent_cpu_s']:.2f} + busiest worker {max(m['per_worker_cpu_s']):.2f} (workers "
                  f"{', '.join(f'{x:.2f}' for x in m['per_worker_cpu_s'])}) = {m['critical_2_cpu_s']:.2f} s CPU "
                  f"against {m['critical_1_cpu_s']:.2f} at 1 worker: {m['ratio']:.2f}x")
    for tree in a.tree:
        for i, r1 in enumerate(r for r in runs if r["tree"] == tree and r["workers"] == 1):
            if not r1["analysis"]["workers"]:
                continue
            b = r1["ideal"] = ideal(r1)
            per_loop = ", ".join(f"{n} {v:.2f}" for n, v in b["loops_cpu_s"].items())
            print(f"{tree} 1-worker run {i + 1}, the ideal 2-worker run of its work: serial {b['parent_cpu_s']:.2f} "
                  f"(parent) + {b['worker_start_cpu_s']:.2f} (a worker's start) + parallel span "
                  f"{b['parallel_span_cpu_s']:.2f} (loops {per_loop}; best split "
                  f"{', '.join(f'{x:.2f}' for x in b['best_loads_cpu_s'])}; figures {b['figures_cpu_s']:.2f}) = "
                  f"{b['ideal_2_cpu_s']:.2f} s CPU against {b['critical_1_cpu_s']:.2f}: at most {b['ratio']:.2f}x "
                  f"(serial share {100 * b['serial_share']:.0f} %)")
    ref = runs[0]["gains"]
    for tree, w in ((t, w) for t in a.tree for w in a.workers):
        rs = [r for r in runs if r["workers"] == w and r["tree"] == tree]
        same = all(r["gains"] == ref for r in rs)
        print(f"gains of {tree} at {w} worker(s) bitwise those of the first run: {same}")
    _table(runs)
    if a.json:
        Path(a.json).write_text(json.dumps(runs, indent=1))
    return 0


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        sys.path.insert(0, os.environ.get("STUDY_TIMELINE_TREE", str(ROOT)))
        raise SystemExit(_child(sys.argv[2], sys.argv[3:]))
    raise SystemExit(main())
