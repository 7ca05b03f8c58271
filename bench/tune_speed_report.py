"""The Markdown of ``bench/tune_speed.py``'s results (also the speed sections of bench/RESULTS.md), and
issue 12's targets judged on them."""

from __future__ import annotations

from typing import Any

from common import fmt

__all__ = ["markdown", "sections", "ratio_cells", "targets", "QUALITY_TOL", "TARGET_MS", "TARGET_RATIO"]

QUALITY_TOL = 0.02  # "within 2 % or one sample"
TARGET_MS = 100.0  # warm tune median on the attitude loops and the process plants of order <= 4
TARGET_RATIO = 100.0  # against Optuna alone and differential evolution
TARGET_COLD = 3.0  # tuner analyze against python -c "import numpy, scipy.linalg"
TARGET_WORKERS = 1.6  # study run --workers 2 against --workers 1
TARGET_P50_MS = 250.0  # the service's single-client POST /tune
ONE_THREAD = "after_1thread"  # tune_speed's diagnostic worker


def _yn(ok: bool) -> str:
    return "yes" if ok else "**no**"


def _st(s: dict[str, Any]) -> str:
    return f"{fmt(s['median_settling_s'], 4)} / {fmt(s['worst_settling_s'], 4)}" + ("" if s["all_meet_spec"] else " ✗")


def before_after_md(r: dict[str, Any]) -> list[str]:
    one = ONE_THREAD in r.get("workers", ())
    L = [f"## Before / after, per loop (warm process, {r['seeds']} seeds)", "",
         f"before = `{r['before_rev']}` ({r['before_commit'][:10]}), after = this tree. Two warm worker processes "
         f"(one warm-up tune per loop, seed {r['warm_seed']}), then seeds 0..{r['seeds'] - 1}, the workers taking "
         f"turns run by run (ABBA); each tune gets freshly built plants; `time_budget_s` {r['budget_s']:g}. "
         "Times are medians over the seeds: wall (CPU = `time.process_time`, all threads). Settling: the "
         "verifier's, median / worst over the seeds (✗: a seed misses the spec). Quality: after's median and worst "
         "within 2 % or one sample of before's (or better), every check passing wherever before's did. "
         f"Target: median ≤ {TARGET_MS:.0f} ms on the attitude loops and the process plants of order ≤ 4.", "",
         "| loop | structure | before ms | after ms | ratio | before CPU ms | after CPU ms | before settling s "
         "| after settling s | quality | ≤ 100 ms | load |" + (" after, 1 thread: ms (CPU ms) |" if one else ""),
         "|---|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if one else "")]
    for x in r["loops"]:
        b, a = x["before"], x["after"]
        tgt = _yn(a["median_wall_ms"] <= TARGET_MS) if x["in_target"] else "—"
        L.append(f"| {x['loop']} | {x['structure']} | {b['median_wall_ms']:.0f} | {a['median_wall_ms']:.0f} | "
                 f"{x['speedup_wall']:.1f}× | {b['median_cpu_ms']:.0f} | {a['median_cpu_ms']:.0f} | {_st(b)} | "
                 f"{_st(a)} | {_yn(x['quality_ok'])} | {tgt} | {x['load_average'][0]:.1f} |"
                 + (_one(x[ONE_THREAD], a) if one else ""))
    if one:
        L += ["", "The last column is a diagnostic, not a target: this tree again in a third worker (taking its turn "
              "with the other two) with `OMP_NUM_THREADS`, `OPENBLAS_NUM_THREADS`, `MKL_NUM_THREADS` and "
              "`NUMEXPR_NUM_THREADS` set to 1, as the service's solver processes run (`api/worker.py`); "
              "(≠: its settling times differ from after's)."]
    diffs = [f"{x['loop']}: {', '.join(x['definition_differs'])}" for x in r["loops"] if x["definition_differs"]]
    if diffs:
        L += ["", "Loop definitions that differ between the trees: " + "; ".join(diffs) + "."]
    return L + [""]


def _times(x: float) -> str:
    return f"{x:.1f}" if x < 10 else f"{x:.0f}"


def _one(o: dict[str, Any], a: dict[str, Any]) -> str:
    same = [r["settling_s"] for r in o["runs"]] == [r["settling_s"] for r in a["runs"]]
    return f" {o['median_wall_ms']:.0f} ({o['median_cpu_ms']:.0f}){'' if same else ' ≠'} |"


def ratio_cells(v: dict[str, Any] | None) -> tuple[str, str]:
    """(time to equal, ratio to ours) of one alternative's run, as table cells."""
    if v is None:
        return "—", "— (we miss the spec)"
    if v["ratio"] is not None:
        return f"{v['to_equal_s']:.2f}", _times(v["ratio"])
    return f"not reached in {fmt(v['best_verified_s'], 4)}", f"≥ {v['ratio_at_least']:.0f} (not reached)"


def alternatives_md(r: dict[str, Any]) -> list[str]:
    L = ["## Against Optuna alone and differential evolution, at equal settling time", "",
         "Each alternative (seed 0, the same verifier, Optuna with our plant-based starts enqueued first, scipy's "
         f"`differential_evolution` Sobol-initialised) runs until the full verifier confirms a settling time ≤ ours "
         f"(our worst seed), or {r['cap_s']:g} s; ratio = its time / our median tune time (≥ cap/ours where not "
         "reached: then the column before gives the best it verified).", "",
         "| loop | ours ms | target s | Optuna to equal s | Optuna/ours | DE to equal s | DE/ours |",
         "|---|---|---|---|---|---|---|"]
    for x in r["loops"]:
        (ot, orr), (dt, dr) = ratio_cells(x["optuna"]), ratio_cells(x["de"])
        L.append(f"| {x['loop']} | {x['ours_median_ms']:.0f} | {fmt(x['target_settling_s'], 4)} | {ot} | {orr} | "
                 f"{dt} | {dr} |")
    return L + [""]


def cold_md(r: dict[str, Any]) -> list[str]:
    hf = r.get("hyperfine")
    base = r["baseline"]
    L = ["## Cold start", "",
         f"Median of {r['runs']} runs per command, interleaved (the order rotated round by round) after one untimed "
         f"round; ratio to `{base}`. Load average {r['load_average'][0][0]:.2f} before, {r['load_average'][1][0]:.2f} "
         "after." + (" hyperfine (`-N`, 1 warm-up, each command's runs back to back) as a cross-check." if hf else ""),
         "", "| command | median wall s | median CPU s | ratio" + (" | hyperfine median s | hyperfine ratio |" if hf
                                                                  else " |"),
         "|---|---|---|---|" + ("---|---|" if hf else "")]
    for n, c in r["commands"].items():
        row = f"| {n} | {c['median_wall_s']:.3f} | {c['median_cpu_s']:.3f} | {c['ratio']:.2f} |"
        if hf:
            row += f" {hf[n]:.3f} | {hf[n] / hf[base]:.2f} |"
        L.append(row)
    return L + [""]


def scaling_md(r: dict[str, Any]) -> list[str]:
    def table(rows: list[dict], key: str, head: str) -> list[str]:
        out = [f"| {head} | dt | median ms | median CPU ms | settling s (median / worst) |", "|---|---|---|---|---|"]
        return out + [f"| {x[key]} | {x['dt']} | {x['median_wall_ms']:.0f} | {x['median_cpu_ms']:.0f} | {_st(x)} |"
                      for x in rows]

    return (["## Scaling", "", "Plant 1/(s+1)^n, structure pid (dt 0.1 for n ≤ 4, else 0.2), warm process, median "
             "over the seeds after one warm-up:", ""] + table(r["orders"], "order", "order")
            + ["", "Response horizon: plant 1/(tau s+1)^2, pid, dt 0.05 (a slower plant = a longer horizon in "
               "samples):", ""] + table(r["horizons"], "tau_s", "tau s") + [""])


def service_md(r: dict[str, Any]) -> list[str]:
    s, ld = r["single"], r["load"]
    return ["## Service (`POST /tune`, uvicorn on loopback, 2 solver processes, default settings)", "",
            "| test | requests | p50 s | p99 s | min s | max s | req/s | non-200 |",
            "|---|---|---|---|---|---|---|---|",
            f"| one client, sequential, roll pid_z | {s['requests']} | {s['p50_s']:.3f} | {s['p99_s']:.3f} | "
            f"{s['min_s']:.3f} | {s['max_s']:.3f} | | 0 |",
            f"| issue 6's load test: {ld['clients']} clients (one address each), yaw pi | {ld['requests']} | "
            f"{ld['p50_s']:.3f} | {ld['p99_s']:.3f} | | | {ld['throughput_rps']:.2f} | "
            f"{sum(ld['errors'].values())} {ld['errors'] or ''} |",
            "", f"Load average {r['load_average'][0][0]:.2f} before, {r['load_average'][1][0]:.2f} after.", ""]


def studies_md(r: dict[str, Any]) -> list[str]:
    L = [f"## Study workers (`tuner study run {r['study']}`, fresh storage, plots on, process start included)", "",
         f"{r['repeat']} interleaved repeats (workers 1, then workers 2).", "",
         "| workers | median wall s | median CPU s | runs (wall s) |", "|---|---|---|---|"]
    v = r.get("variant")
    for tag, x in (("", r), (", 1 thread", v)) if v else (("", r),):
        for w in ("1", "2"):
            L.append(f"| {w}{tag} | {x['median_wall_s'][w]:.2f} | {x['median_cpu_s'][w]:.2f} | "
                     + ", ".join(f"{t:.2f}" for t in x["wall_s"][w]) + " |")
    L += ["", f"Speed-up of 2 workers: {r['speedup']:.2f}× (per pair: " + ", ".join(f"{p:.2f}" for p in r["pairs"])
          + ")."]
    if v:
        L += ["", f"Diagnostic (not the target): with {', '.join(f'`{k}=1`' for k in v['env'])} in the command's "
              f"environment (each repeat runs these pairs too), 2 workers: {v['speedup']:.2f}× (per pair: "
              + ", ".join(f"{p:.2f}" for p in v["pairs"]) + "); 2 workers with one thread against 1 worker as it "
              f"runs by default: {r['median_wall_s']['1'] / v['median_wall_s']['2']:.2f}×."]
    return L + [""]


def targets(res: dict[str, Any]) -> list[tuple[str, bool | None, str]]:
    """(target, met?, the numbers) for each of issue 12's targets measured in ``res``."""
    out: list[tuple[str, bool | None, str]] = []
    if "before_after" in res:
        rows = [x for x in res["before_after"]["loops"] if x["in_target"]]
        slow = [f"{x['loop']} {x['after']['median_wall_ms']:.0f} ms" for x in rows
                if x["after"]["median_wall_ms"] > TARGET_MS]
        cpu_ok = [x["loop"] for x in rows if x["after"]["median_wall_ms"] > TARGET_MS
                  and x["after"]["median_cpu_ms"] <= TARGET_MS]
        note = "over: " + ", ".join(slow) if slow else f"all {len(rows)} loops"
        if cpu_ok:
            note += f" (CPU median ≤ {TARGET_MS:.0f} ms on {', '.join(cpu_ok)}: the wall time waited for the CPU)"
        out.append((f"warm tune median ≤ {TARGET_MS:.0f} ms (attitude loops, process order ≤ 4)", not slow, note))
        worse = [f"{x['loop']} {fmt(x['before']['worst_settling_s'], 4)} → {fmt(x['after']['worst_settling_s'], 4)} s"
                 for x in res["before_after"]["loops"] if not x["quality_ok"]]
        out.append(("unchanged verified quality (within 2 % or one sample, every check)", not worse,
                    "worse: " + ", ".join(worse) if worse else "every loop"))
    if "alternatives" in res:
        for name, label in (("optuna", "Optuna alone"), ("de", "differential evolution")):
            short, undecided = [], []
            for x in res["alternatives"]["loops"]:
                v = x[name]
                if v is None:
                    continue
                if v["ratio"] is not None and v["ratio"] < TARGET_RATIO:
                    short.append(f"{x['loop']} {_times(v['ratio'])}×")
                elif v["ratio"] is None and v["ratio_at_least"] < TARGET_RATIO:
                    undecided.append(f"{x['loop']} ≥ {v['ratio_at_least']:.0f}×")
            note = "; ".join(filter(None, ["below: " + ", ".join(short) if short else "",
                                           "cap too short to tell: " + ", ".join(undecided) if undecided else ""]))
            out.append((f"≥ {TARGET_RATIO:.0f}× faster than {label} at equal settling time",
                        None if undecided and not short else not short, note or "every loop"))
    if "cold" in res:
        c = res["cold"]["commands"]
        an, hp = c["tuner analyze (README roll example)"]["ratio"], c["tuner --help"]["ratio"]
        out.append((f"cold `tuner analyze` ≤ {TARGET_COLD:g}× numpy + scipy.linalg", an <= TARGET_COLD, f"{an:.2f}×"))
        out.append(("cold `tuner --help` faster than `tuner analyze`", hp < an, f"{hp:.2f}×"))
    if "studies" in res:
        sp = res["studies"]["speedup"]
        out.append((f"study run --workers 2 ≥ {TARGET_WORKERS}× faster than --workers 1", sp >= TARGET_WORKERS,
                    f"{sp:.2f}×"))
    if "service" in res:
        p50 = 1000 * res["service"]["single"]["p50_s"]
        out.append((f"service single-client p50 ≤ {TARGET_P50_MS:.0f} ms", p50 <= TARGET_P50_MS, f"{p50:.0f} ms"))
    return out


def targets_md(res: dict[str, Any]) -> list[str]:
    rows = targets(res)
    if not rows:
        return []
    mark = {True: "met", False: "**missed**", None: "undecided"}
    return (["## Issue 12's targets", "", "| target | met | measured |", "|---|---|---|"]
            + [f"| {t} | {mark[ok]} | {note} |" for t, ok, note in rows] + [""])


def sections(res: dict[str, Any]) -> list[str]:
    """The measured sections (no title): what bench/RESULTS.md includes."""
    L: list[str] = []
    for part, fn in (("before_after", before_after_md), ("alternatives", alternatives_md), ("cold", cold_md),
                     ("scaling", scaling_md), ("service", service_md), ("studies", studies_md)):
        if part in res:
            L += fn(res[part])
    return L + targets_md(res)


def markdown(res: dict[str, Any]) -> str:
    m = res["machine"]
    la0, la1 = res["load_average_start"], res.get("load_average_end", ["?"])
    parts = [p for p in ("before_after", "alternatives", "cold", "scaling", "service", "studies") if p in res]
    took = sum(res[p].get("part_wall_s", 0) for p in parts)
    head = ["# Tune speed (issue 12)", "",
            f"`bench/tune_speed.py{' --quick' if res['args'].get('quick') else ''}` on {res['when_utc']}, tree "
            f"{res.get('after_commit', '?')}: {m['cpu']}, {m['cores']} cores, Python {m['python']}, numpy "
            f"{m['numpy']}, scipy {m['scipy']}, casadi {m['casadi']}, optuna {m['optuna']}. The machine is shared: "
            f"load average (1, 5, 15 min) {la0} at the start, {la1} at the end; {took / 60:.0f} min in all. "
            "Nothing here is asserted; ratios are measured in the same run.", ""]
    return "\n".join(head + sections(res)) + "\n"
