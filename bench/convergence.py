"""Issue 30, item 2: does "converged" hold? The convergence suite, its long-search references, and the claims.

    python bench/convergence.py reference [--jobs 1] [--cap-s S]   # bench/convergence_reference.json (resumable)
    python bench/convergence.py run --effort default               # bench/results/convergence_default.json
    python bench/convergence.py report                             # bench/results/convergence.md

**The suite** (:func:`suite`, 320 plants): the quality suite's 280 cases (``bench/quality_suite.json``: lag chains,
underdamped, integrating, unstable, non-minimum-phase, whole- and fractional-sample dead time, 2-DOF PID) and a class
added here for the false claims issue 30 found, ``lagdelay``: lag chains of order 2-4 whose dead time is 10-40 whole
samples (a held-out lag with a 29-sample delay settled 15 % later than a design ``--effort thorough`` found while
the default claimed convergence). Seeded (``LAGDELAY_SEED``): the same cases every time. Every case on the thesis
spec (``Spec.thesis()``), as the quality suite's references.

**The references** (:func:`reference_case`): the best verified objective of (a) a much longer search than any effort
runs, our engine at the effort ``LONG`` below (8 refinements in round 0, 256 space-filling points, 5 restarts of 256
Sobol points and 3 refinements each that must all find nothing better, Optuna's sampler asked in every restart, the
sharp polish, 8 finalists verified) with two seeds (0 and 1) and a 60 s budget each, and (b) the quality suite's own
independent reference (scipy's differential evolution, CMA-ES and Nelder-Mead on the batch scorer, verified and
checked without tuner: ``bench/quality_reference.json``) where it passed its independent check. Every objective is
the verifier's (``tune``'s verified result; a design that does not meet the spec is not a reference). A reference
is an upper bound of the optimum: a default result better than it (ratio < 1) counts as within 1 %.

**The claims** (:func:`cmd_run`): each case tuned once at the effort asked (seed 0, the library's default budget:
10 s of search, the NLP builds not counted, at most 60 s); its
ratio to the reference, its ``stop`` and whether its optimality summary claims convergence. A *false claim* is a
result that says "converged" while more than 1 % above its reference. Nothing here asserts anything; the report
states the rates.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import quality  # noqa: E402  (the quality suite: its plants, references and independent check)

from tuner.optimize.engine import EFFORTS, Effort  # noqa: E402
from tuner.spec import Spec  # noqa: E402
from tuner.tuning import tune  # noqa: E402

REFERENCE = HERE / "convergence_reference.json"
RESULTS = HERE / "results"
LAGDELAY_SEED = 20261204
LAGDELAY_N = 40
#: issue 41's classes, where the stopping rule of issue 30 claimed convergence falsely on another suite (see
#: :func:`issue41_cases`); their own seeded stream, appended after the others (no earlier case changes)
ISSUE41_SEED = 20261205
ISSUE41_N = 20  # per class
ISSUE41_CLASSES = ("nmpneg", "nmpfast", "unstslow", "intdelay4")
#: a fresh held-out part (stop 46): the same generator, its own seed drawn before any of its cases was tuned, and
#: only the classes whose references are feasible (``unstslow``'s long searches met the spec in none of its cases);
#: measured once at 67b11b7 (default and thorough). It is no longer fresh for default: its two misses showed the
#: cause (the polish's resolution) of the change f39d2ed made, checked on the design part; a later held-out claim
#: needs a new seed
FRESH_SEED = 20261206
FRESH_N = 10  # per class
FRESH_CLASSES = ("nmpneg", "nmpfast", "intdelay4")
#: a second fresh held-out part (stop 49): its seed set before any of its cases was generated or tuned, its references
#: computed in a separate tree at 9823da7 (the engine before the stop's one change to the search, FILTER_N = (10, 3,
#: 1)) before that change was measured on it; ids ``<class>-g<i>``, part ``fresh2``
FRESH2_SEED = 20261207
REFERENCE_SEEDS = (0, 1)
REFERENCE_BUDGET_S = 60.0
#: the references' search: far longer than thorough (which refines 5 starts, confirms over 3 restarts of 128 points)
LONG = Effort("long", n_starts=8, design_points=256, confirm=5, restart_points=256, restart_refines=3, verify=8,
              optuna=True, detail=2)
FALSE_TOL = 0.01  # a claim of convergence more than this above the reference is false


def suite() -> list[dict[str, Any]]:
    """The quality suite's cases and the ``lagdelay`` class (see the module docstring)."""
    cases = list(quality.load_suite())
    rng = np.random.default_rng(LAGDELAY_SEED)
    for i in range(LAGDELAY_N):
        K = float(10 ** rng.uniform(-0.5, 0.7))
        T = float(10 ** rng.uniform(-1, 1.3))
        n = 2 + i % 3
        taus = [T] + [T * float(rng.uniform(0.1, 0.8)) for _ in range(n - 1)]
        samples = int(rng.integers(10, 41))
        # dt from the delay: 0.3-2 tau of dead time in `samples` whole samples
        delay = float(rng.uniform(0.3, 2.0)) * T
        dt = float(f"{delay / samples:.4g}")
        structure = ("pi", "pid", "pid_z")[i % 3]
        cases.append({"id": f"lagdelay-{i:02d}", "class": "lagdelay", "structure": structure, "num": [K],
                      "den": quality._poly(*[[t, 1.0] for t in taus]), "delay_s": float(f"{samples * dt:.10g}"),
                      "dt": dt, "tau_dom": T, "order": n})
    return (cases + issue41_cases() + issue41_cases(FRESH_SEED, FRESH_N, FRESH_CLASSES, fresh="f")
            + issue41_cases(FRESH2_SEED, FRESH_N, FRESH_CLASSES, fresh="g"))


def issue41_cases(seed: int = ISSUE41_SEED, n: int = ISSUE41_N, classes: tuple[str, ...] = ISSUE41_CLASSES,
                  fresh: str = "") -> list[dict[str, Any]]:
    """Issue 41's classes (20 each, seeded by ``ISSUE41_SEED``), PI, PID and ``pid_z`` round-robin:

    * ``nmpneg``: a non-minimum-phase plant with a negative DC gain, -K (1 - b s) / ((T s + 1)(T2 s + 1)), its
      right-half-plane zero 1/b within a factor 0.7-1.4 of its faster pole 1/T2 (T2 = 0.2-1 T);
    * ``nmpfast``: the same with a positive DC gain, K (1 - b s) / ((T s + 1)(T2 s + 1));
    * ``unstslow``: an open-loop unstable plant K / ((T s - 1)(L s + 1)) (L = 0-0.3 T) sampled slowly: 2-5 samples
      per unstable time constant T (the quality suite's unstable class has 5-50);
    * ``intdelay4``: an integrator with lag, K / (s (T s + 1)), and a dead time of exactly 4 samples.

    Elsewhere as the quality suite: K = 10^U(-0.5, 0.7), T = 10^U(-1, 1.3) s, dt = T / U(5, 50) (log-uniform).

    With ``fresh`` (a letter): a fresh held-out part's cases from ``seed``, ids ``<class>-<fresh><i>``: part
    ``fresh`` for ``"f"``, ``fresh2`` for ``"g"``."""
    rng = np.random.default_rng(seed)
    cases = []
    for cls in classes:
        for i in range(n):
            K = float(10 ** rng.uniform(-0.5, 0.7))
            T = float(10 ** rng.uniform(-1, 1.3))
            k = float(10 ** rng.uniform(math.log10(5), math.log10(50)))
            delay = 0.0
            if cls in ("nmpneg", "nmpfast"):
                T2 = T * float(rng.uniform(0.2, 1.0))
                b = T2 * float(rng.uniform(0.7, 1.4))
                sign = -1.0 if cls == "nmpneg" else 1.0
                num, den = quality._poly([-sign * K * b, sign * K]), quality._poly([T, 1.0], [T2, 1.0])
            elif cls == "unstslow":
                L = float(rng.uniform(0.0, 0.3)) * T
                k = float(rng.uniform(2.0, 5.0))
                num, den = [K], quality._poly([T, -1.0], *([[L, 1.0]] if i % 2 else []))
            else:
                num, den = [K], quality._poly([1.0, 0.0], [T, 1.0])
            dt = float(f"{T / k:.4g}")
            if cls == "intdelay4":
                delay = float(f"{4 * dt:.10g}")
            cases.append({"id": f"{cls}-{fresh}{i:02d}", "class": cls,
                          "structure": ("pi", "pid", "pid_z")[i % 3],
                          "num": num, "den": den, "delay_s": delay, "dt": dt, "tau_dom": T, "order": len(den) - 1,
                          "part": {"f": "fresh", "g": "fresh2"}[fresh] if fresh else "heldout" if i % 2 else "design"})
    return cases


def part_of(c: dict[str, Any]) -> str:
    """``heldout``: issue 41's odd-numbered cases; ``design``: the rest (the quality suite, ``lagdelay`` and issue 41's
    even-numbered cases). The held-out part is no longer fresh: it was measured under the first two claim rules
    (fe869d3, 7a72fa4, a303295), and the Bayesian multistart rule's diagnosis (issue 41, item 1) looked at its
    nmpfast-19, nmpfast-07 and intdelay4-17 by name. That rule's constants were not fitted to it: the estimate and
    its 0.2 level are the literature's and the previous rule's, the draw's reduced sample (a quarter) was set before
    any run, and its design runs were on issue 41's even-numbered cases (``--part design``) alone. ``fresh``: the
    held-out part of stop 46 (``FRESH_SEED``), generated after the engine's last change to its search and claims and
    measured once as it stood (its references, then default and thorough at 67b11b7); no longer fresh for default
    (see ``FRESH_SEED``). ``fresh2``: stop 49's held-out part (``FRESH2_SEED``), its references computed before the
    stop's one change to the search (``engine.FILTER_N``, chosen on the design part) was committed, then measured
    with it (default and thorough)."""
    return c.get("part", "design")


def _selected(c: dict[str, Any], a: argparse.Namespace) -> bool:
    """Whether ``--only``, ``--classes`` and ``--part`` keep case ``c``."""
    return (not a.only or c["id"] in a.only.split(",")) and \
        (not getattr(a, "classes", "") or c["class"] in a.classes.split(",")) and \
        (not getattr(a, "part", "") or part_of(c) == a.part)


def _tune(c: dict[str, Any], *, effort: str, seed: int, budget: float | None, **kw: Any) -> dict[str, Any]:
    t0 = time.perf_counter()
    res = tune(quality.plant_of(c), structure=c["structure"], dt=c["dt"], spec=Spec.thesis(), seed=seed,
               time_budget_s=budget, diagnose=False, effort=effort, **kw)
    opt = res.solver.get("optimality") or {}
    return {"objective": float(res.objective) if res.meets_spec else math.inf, "meets": bool(res.meets_spec),
            "wall_s": time.perf_counter() - t0, "gains": dict(res.gains), "stop": res.solver.get("stop"),
            "cut": res.solver.get("cut"),
            "summary": opt.get("summary"), "claim": claim(res.solver),
            "optimality": {k: v for k, v in opt.items() if k != "summary"}}


def claim(solver: dict[str, Any]) -> str:
    """What the result claims about convergence: ``converged``, ``not confirmed`` or ``budget``."""
    opt = solver.get("optimality") or {}
    return opt.get("claim") or ("converged" if solver.get("stop") == "converged" else str(solver.get("stop")))


def reference_case(c: dict[str, Any], de: dict[str, Any] | None) -> dict[str, Any]:
    EFFORTS.setdefault(LONG.name, LONG)
    runs = {f"long seed {s}": _tune(c, effort=LONG.name, seed=s, budget=REFERENCE_BUDGET_S) for s in REFERENCE_SEEDS}
    out = {"id": c["id"], "runs": {k: {"objective": v["objective"], "wall_s": v["wall_s"], "gains": v["gains"]}
                                   for k, v in runs.items()}}
    cands = [(v["objective"], k) for k, v in runs.items() if v["meets"]]
    if de is not None and de.get("feasible") and de.get("independent_ok"):
        out["independent"] = float(de["objective"])
        cands.append((float(de["objective"]), "independent (quality_reference.json)"))
    best = min(cands, default=(math.inf, None))
    out["objective"], out["source"] = best
    return out


def _load(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text()) if path.exists() else {}


def cmd_reference(a: argparse.Namespace) -> None:
    doc = _load(REFERENCE) or {"command": "python bench/convergence.py reference", "spec": "Spec.thesis()",
                               "long_effort": LONG.__dict__, "seeds": list(REFERENCE_SEEDS),
                               "budget_s": REFERENCE_BUDGET_S, "references": {}}
    de = quality.load_reference(quality.REFERENCE)
    t_start = time.perf_counter()
    cases = suite()
    if a.shard:
        k, n = map(int, a.shard.split("/"))
        cases = cases[k::n]
    for c in cases:
        if c["id"] in doc["references"] or not _selected(c, a):
            continue
        if a.cap_s and time.perf_counter() - t_start > a.cap_s:
            break
        r = reference_case(c, de.get(c["id"]))
        print(f"{c['id']:14s} {c['structure']:6s} {r['objective']:.6g} ({r['source']}) "
              f"{sum(v['wall_s'] for v in r['runs'].values()):.1f} s", flush=True)
        with open(REFERENCE.with_suffix(".lock"), "w") as lock:  # shards write the same file: one at a time
            fcntl.flock(lock, fcntl.LOCK_EX)
            fresh = _load(REFERENCE) or doc  # (merge what the others stored)
            fresh["references"][c["id"]] = r
            doc = fresh
            tmp = REFERENCE.with_suffix(f".tmp{os.getpid()}")
            tmp.write_text(json.dumps(doc, indent=1, allow_nan=True))
            os.replace(tmp, REFERENCE)


def cmd_run(a: argparse.Namespace) -> None:
    if a.cap_s:
        # the default budget counts work (issue 41): its wall-clock cap only cuts; a larger one lets a loaded machine
        # give what an idle one gives (the same steps), where the 60 s cap would cut a slow case
        import tuner.tuning as tuning_mod

        tuning_mod.AUTO_WALL_CAP_S = a.cap_s
    refs = _load(REFERENCE).get("references", {})
    commit = _commit()  # (the tree the run started on)
    out = Path(a.out) if a.out else RESULTS / f"convergence_{a.effort}.json"
    rows = []
    for c in suite():
        if not _selected(c, a):
            continue
        t = _tune(c, effort=a.effort, seed=a.seed, budget=a.budget,
                  **({"n_starts": a.n_starts} if a.n_starts else {}))
        ref = refs.get(c["id"], {}).get("objective")
        t["ratio"] = None if ref is None or not math.isfinite(ref) else (t["objective"] / ref if t["meets"]
                                                                         else math.inf)
        t |= {"id": c["id"], "class": c["class"], "structure": c["structure"], "part": part_of(c)}
        rows.append(t)
        print(f"{c['id']:14s} {c['structure']:6s} ratio {t['ratio']} {t['claim']} {t['wall_s'] * 1e3:.0f} ms",
              flush=True)
        out.write_text(json.dumps({"command": "python bench/convergence.py " + " ".join(sys.argv[1:]),
                                   "effort": a.effort, "seed": a.seed, "commit": commit, "rows": rows}, indent=1,
                                  allow_nan=True))
    print(summary(rows, a.effort))


def _commit() -> str:
    import subprocess

    p = subprocess.run(["git", "-C", str(HERE), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "-C", str(HERE), "status", "--porcelain", "--", "../tuner"], capture_output=True,
                           text=True).stdout.strip()
    return p.stdout.strip() + (" (tuner/ modified)" if dirty else "")


def summary(rows: list[dict[str, Any]], effort: str) -> str:
    rs = [r for r in rows if r["ratio"] is not None]
    n = len(rs)
    if not n:
        return f"{effort}: no case with a reference"
    within = lambda tol: sum(r["ratio"] <= 1 + tol for r in rs)
    claims = [r for r in rs if r["claim"] == "converged"]
    false = [r for r in claims if r["ratio"] > 1 + FALSE_TOL]
    worst = max(rs, key=lambda r: r["ratio"])
    walls = sorted(r["wall_s"] for r in rows)
    lines = [f"{effort}: {n} cases with a reference",
             f"  within 1 %: {within(0.01)} ({100 * within(0.01) / n:.1f} %); within 2 %: {within(0.02)} "
             f"({100 * within(0.02) / n:.1f} %); worst {worst['ratio']:.4f} ({worst['id']})",
             f"  claims of convergence: {len(claims)}; false (> 1 % short): {len(false)} "
             f"({100 * len(false) / max(len(claims), 1):.2f} % of the claims)"
             + (": " + ", ".join(f"{r['id']} {r['ratio']:.4f}" for r in false) if false else ""),
             "  claims: " + ", ".join(f"{k} {sum(r['claim'] == k for r in rs)}"
                                       for k in sorted({r['claim'] for r in rs})),
             f"  wall: median {1e3 * walls[len(walls) // 2]:.0f} ms, total {sum(walls):.0f} s"]
    lines.append("  per class (cases, within 1 %, claims, false claims): " + "; ".join(
        f"{cls} {len(g)}, {sum(r['ratio'] <= 1.01 for r in g)}, {sum(r['claim'] == 'converged' for r in g)}, "
        f"{sum(r['claim'] == 'converged' and r['ratio'] > 1 + FALSE_TOL for r in g)}"
        for cls in dict.fromkeys(r["class"] for r in rs) for g in [[r for r in rs if r["class"] == cls]]))
    short = sorted((r for r in rs if r["ratio"] > 1 + FALSE_TOL), key=lambda r: -r["ratio"])
    if short:
        lines.append("  more than 1 % short: " + ", ".join(f"{r['id']} {r['ratio']:.4f} ({r['claim']})"
                                                        for r in short))
    return "\n".join(lines)


def cmd_report(a: argparse.Namespace) -> None:
    parts = ["# Convergence claims (issue 30)", "",
             "`bench/convergence.py`: the suite, its references and the definition of a false claim are in its "
             "docstring.", ""]
    refs = _load(REFERENCE).get("references", {})
    files = [f for f in sorted(RESULTS.glob("convergence_*.json")) if "rows" in _load(f)]
    # the best known objective of each case: its reference, or any verified result stored here that beats it
    best: dict[str, float] = {k: v["objective"] for k, v in refs.items() if math.isfinite(v.get("objective", math.inf))}
    for f in files:
        for r in _load(f).get("rows", []):
            if r.get("meets") and r["id"] in best:
                best[r["id"]] = min(best[r["id"]], r["objective"])
    for f in files:
        d = _load(f)
        for r in d["rows"]:  # (a reference computed after the run: its ratio from the stored objective)
            ref = refs.get(r["id"], {}).get("objective")
            if r.get("ratio") is None and ref is not None and math.isfinite(ref):
                r["ratio"] = r["objective"] / ref if r["meets"] else math.inf
        parts += [f"## {f.name}", "", f"`{d.get('command')}`" + (f" at {d['commit']}" if d.get("commit") else ""),
                  "", "```", summary(d["rows"], d["effort"]), "```", ""]
        if any(r.get("part") in ("heldout", "fresh", "fresh2") for r in d["rows"]):
            rows = [dict(r, ratio=(r["objective"] / best[r["id"]] if r["meets"] else math.inf))
                    for r in d["rows"] if r["id"] in best]
            parts += ["Against the best known (the reference, or a better verified result of any run stored here):",
                      "", "```", summary(rows, d["effort"]), "```", ""]
    (RESULTS / "convergence.md").write_text("\n".join(parts))
    print("\n".join(parts))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("reference", help="the long-search references (resumable)")
    r.add_argument("--only", default="")
    r.add_argument("--classes", default="", help="comma-separated classes (e.g. nmpneg,nmpfast,unstslow,intdelay4)")
    r.add_argument("--part", default="", choices=("", "design", "heldout", "fresh", "fresh2"))
    r.add_argument("--cap-s", type=float, default=0.0)
    r.add_argument("--shard", default="", help="k/n: every n-th case from the k-th (several processes)")
    u = sub.add_parser("run", help="tune every case at an effort and compare with the references")
    u.add_argument("--effort", default="default")
    u.add_argument("--seed", type=int, default=0)
    u.add_argument("--budget", type=float, default=None, help="seconds (default: the library's default budget)")
    u.add_argument("--only", default="")
    u.add_argument("--classes", default="")
    u.add_argument("--part", default="", choices=("", "design", "heldout", "fresh", "fresh2"))
    u.add_argument("--out", default="")
    u.add_argument("--n-starts", type=int, default=0, help="tune(n_starts=) (0: the effort's)")
    u.add_argument("--cap-s", type=float, default=0.0, help="the default budget's wall-clock cap (0: the library's)")
    sub.add_parser("report", help="bench/results/convergence.md from the stored runs")
    a = ap.parse_args()
    {"reference": cmd_reference, "run": cmd_run, "report": cmd_report}[a.cmd](a)


if __name__ == "__main__":
    main()
