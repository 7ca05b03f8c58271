"""Stop 49: the filtered designed starts' filter time constants (``tuner.optimize.engine.FILTER_N``), old against new,
case by case, in one process.

    .venv/bin/python bench/filter_n_ab.py PART [--classes C1,C2] [--effort default] [--old 10,3,1] [--new 10,3,1,0.3]
                                             [--shard k/n] [--out FILE.json]

For every case of ``bench/convergence.py``'s suite in part PART (``design``, ``heldout``, ``fresh``, ``fresh2``), the
tune at ``--effort`` (seed 0, thesis spec, diagnosis off) with ``FILTER_N`` = ``--old`` and then ``--new``: each one's
CPU seconds, verified objective and convergence claim; then how many cases each is within 1 % and 2 % of the long
search's reference (``bench/convergence_reference.json``), its false claims ("converged" more than 1 % above the
reference), and on how many cases each is worse than the other by more than 0.1 %. Structures without a derivative
filter do not see ``FILTER_N``: their two results should agree (the last line counts the cases whose gains do). The CPU
figures favour ``new``: it runs second on each case and reuses the NLP shapes ``old`` built. Nothing here asserts.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import convergence as C  # noqa: E402
import quality  # noqa: E402

import tuner.optimize.engine as E  # noqa: E402
from tuner.spec import Spec  # noqa: E402
from tuner.tuning import tune  # noqa: E402


def _ns(s: str) -> tuple[float, ...]:
    return tuple(float(x) for x in s.split(","))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("part")
    ap.add_argument("--classes", default="")
    ap.add_argument("--effort", default="default")
    ap.add_argument("--old", default="10,3,1")
    ap.add_argument("--new", default="10,3,1,0.3")
    ap.add_argument("--shard", default="", help="k/n: every n-th case from the k-th")
    ap.add_argument("--out", default="")
    a = ap.parse_args()
    refs = json.loads((HERE / "convergence_reference.json").read_text())["references"]
    cls = a.classes.split(",") if a.classes else None
    cases = [c for c in C.suite() if C.part_of(c) == a.part and (cls is None or c["class"] in cls)]
    if a.shard:
        k, n = map(int, a.shard.split("/"))
        cases = cases[k::n]
    arms = {"old": _ns(a.old), "new": _ns(a.new)}
    own = E.FILTER_N
    commit = C._commit()  # (the tree the run started on)
    rows = []
    try:
        for c in cases:
            r = {"id": c["id"], "structure": c["structure"], "class": c["class"]}
            for tag, fn in arms.items():
                E.FILTER_N = fn
                t = time.process_time()
                res = tune(quality.plant_of(c), structure=c["structure"], dt=c["dt"], spec=Spec.thesis(), seed=0,
                           diagnose=False, effort=a.effort)
                r[tag] = {"cpu_s": time.process_time() - t,
                          "objective": float(res.objective) if res.meets_spec else math.inf,
                          "claim": C.claim(res.solver), "gains": dict(res.gains)}
            rows.append(r)
            print(c["id"], c["structure"], {k: (round(r[k]["cpu_s"], 3), round(r[k]["objective"], 6), r[k]["claim"])
                                            for k in arms}, flush=True)
            if a.out:
                Path(a.out).write_text(json.dumps({"command": "python bench/filter_n_ab.py " + " ".join(sys.argv[1:]),
                                                   "commit": commit, "arms": arms, "rows": rows}, indent=1,
                                                  allow_nan=True))
    finally:
        E.FILTER_N = own
    if rows:
        print(report(rows, refs))


def _ref(refs: dict, r: dict) -> float | None:
    """The case's reference objective (None: none, or not finite: the long search met the spec nowhere)."""
    ref = refs.get(r["id"], {}).get("objective")
    return None if ref is None or not math.isfinite(ref) else float(ref)


def report(rows: list[dict], refs: dict) -> str:
    rat = [r["new"]["cpu_s"] / r["old"]["cpu_s"] for r in rows]
    out = [f"{len(rows)} cases; CPU ratio new/old: median {statistics.median(rat):.3f}, total "
           f"{sum(r['new']['cpu_s'] for r in rows) / sum(r['old']['cpu_s'] for r in rows):.3f}, max {max(rat):.2f}"]
    for tag, other in (("old", "new"), ("new", "old")):
        n = w1 = w2 = false = 0
        worst = (0.0, None)
        for r in rows:
            ref = _ref(refs, r)
            if ref is None:
                continue
            n += 1
            q = r[tag]["objective"] / ref
            w1 += q <= 1.01
            w2 += q <= 1.02
            false += r[tag]["claim"] == "converged" and q > 1 + C.FALSE_TOL
            worst = max(worst, (q, r["id"]), key=lambda t: t[0])
        if not n:
            out.append(f"{tag}: no case with a reference")
            continue
        worse = [r["id"] for r in rows if r[tag]["objective"] > r[other]["objective"] * 1.001]
        out.append(f"{tag}: {n} with a reference; within 1 %: {w1} ({100 * w1 / max(n, 1):.1f} %); within 2 %: {w2}; "
                   f"worst {worst[0]:.4f} ({worst[1]}); false claims {false}; claims "
                   f"{sum(r[tag]['claim'] == 'converged' for r in rows if _ref(refs, r) is not None)}; worse than "
                   f"{other} by > 0.1 %: "
                   f"{len(worse)} {worse[:12]}")
    same = sum(r["old"]["gains"] == r["new"]["gains"] for r in rows)
    out.append(f"gains identical in both arms: {same} of {len(rows)}")
    return "\n".join(out)


if __name__ == "__main__":
    main()
