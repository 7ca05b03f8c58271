"""What two workers taking halves of a study spend on NLP builds, in file order and in the claim order
(tuner.studies.runner.claim_order), without the noise of a timed run.

    python bench/claim_order_builds.py [--every 7]

Each loop of the quality suite's slice (every ``--every``-th case: the 40 loops of bench/quality_scale.py) is tuned
once in a fresh build cache, recording the problems it requests and what each build cost; then the builds one worker
(every loop, one cache) and two workers (a half of the order each, a cache each, nothing dropped) would make are
added up at those costs, for the file's order and the claim order, splitting at the middle and two loops either side;
the figures go to bench/results/claim_order_builds.json (about a minute: one default-effort tune per loop, every one
building its problems from cold). Nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(ROOT), str(HERE)]

import quality  # noqa: E402


def main() -> None:
    from tuner.optimize.nlp import refine, transcribe
    from tuner.studies.evaluate import tune_loop
    from tuner.studies.runner import claim_order
    from tuner.studies.schema import load_study

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--every", type=int, default=7)
    cases = quality.load_suite()[::ap.parse_args().every]
    tmp = Path(tempfile.mkdtemp(prefix="claim_order_builds_"))
    f = tmp / "slice.toml"
    f.write_text(quality.study_toml(cases, name="slice", budget=10.0, effort="default"))
    study = load_study(str(f))
    shutil.rmtree(tmp, ignore_errors=True)
    transcribe.CACHE_MB = float("inf")
    req: dict[str, set[Any]] = {}
    cost: dict[Any, float] = {}
    real_build, real_get = transcribe._build, refine.get_problem
    cur = [""]

    def build(key: Any, st: Any, space: Any) -> Any:
        t = time.perf_counter()
        r = real_build(key, st, space)
        cost[key] = time.perf_counter() - t
        return r

    def get(key: Any, st: Any, space: Any) -> Any:
        req[cur[0]].add(key)
        return real_get(key, st, space)

    transcribe._build, refine.get_problem = build, get
    for lp in study.order():  # each loop in a fresh cache: what it requests on its own
        cur[0] = lp.name
        req[lp.name] = set()
        transcribe._CACHE.clear()
        tune_loop(study, lp, {})

    def builds(names: list[str]) -> float:
        seen: set[Any] = set()
        s = 0.0
        for n in names:
            for k in req[n] - seen:
                seen.add(k)
                s += cost[k]
        return s

    doc: dict[str, Any] = {"command": "python bench/claim_order_builds.py " + " ".join(sys.argv[1:]),
                           "loops": len(req), "problems": len(cost), "orders": {}}
    for label, order in (("file", [lp.name for lp in study.order()]),
                         ("claim", [lp.name for lp in claim_order(study)])):
        h = len(order) // 2
        one = builds(order)
        splits = {str(k): (builds(order[:k]) + builds(order[k:])) / one for k in (h - 2, h, h + 2)}
        doc["orders"][label] = {"order": order, "one_worker_build_s": one,
                                "halves_build_s": [builds(order[:h]), builds(order[h:])],
                                "two_workers_over_one_by_split": splits}
        print(f"{label} order: one worker {one:.2f} s of builds; two workers taking halves "
              f"{splits[str(h)]:.3f} of one (splitting at {h - 2}: {splits[str(h - 2)]:.3f}, at {h + 2}: "
              f"{splits[str(h + 2)]:.3f})")
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "claim_order_builds.json").write_text(json.dumps(doc, indent=1))


if __name__ == "__main__":
    main()
