"""Stop 46: the default effort's polish at detail 1 against detail 2 (``Effort.polish_detail``), case by case.

    .venv/bin/python bench/polish_detail_ab.py PART [CLASSES]    # e.g. design ""  or  design nmpneg,nmpfast,intdelay4

For every case of ``bench/convergence.py``'s suite in part PART (and CLASSES, comma-separated; "" for all), the
default tune (seed 0, thesis spec, diagnosis off) with the polish at detail 1 (``pd0``: the effort's own detail, as
before stop 46) and then at detail 2 (``pd2``), in one process: each one's CPU seconds and verified objective, then
how many cases are within 1 % and 2 % of the long search's reference (bench/convergence_reference.json) and how
many cases each is worse than the other on by more than 0.1 %. The CPU figures favour ``pd2``: it runs second on
each case and reuses the NLP shapes ``pd0`` built (the warm comparison is bench/warm_speed.py's). Nothing here
asserts anything.
"""

from __future__ import annotations

import dataclasses
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


def main() -> None:
    part = sys.argv[1]
    cls = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else None
    refs = json.loads((HERE / "convergence_reference.json").read_text())["references"]
    cases = [c for c in C.suite() if C.part_of(c) == part and (cls is None or c["class"] in cls)]
    own = E.EFFORTS["default"]
    efforts = {"pd0": dataclasses.replace(own, polish_detail=1), "pd2": dataclasses.replace(own, polish_detail=2)}
    rows = []
    try:
        for c in cases:
            r = {}
            for tag, eff in efforts.items():
                E.EFFORTS["default"] = eff
                t = time.process_time()
                res = tune(quality.plant_of(c), structure=c["structure"], dt=c["dt"], spec=Spec.thesis(), seed=0,
                           diagnose=False, effort="default")
                r[tag] = (time.process_time() - t, float(res.objective) if res.meets_spec else math.inf)
            rows.append((c["id"], r))
            print(c["id"], {k: (round(v[0], 3), round(v[1], 5)) for k, v in r.items()},
                  round(r["pd2"][0] / r["pd0"][0], 2), flush=True)
    finally:
        E.EFFORTS["default"] = own
    if not rows:
        return
    rat = [r["pd2"][0] / r["pd0"][0] for _, r in rows]
    print("CPU ratio pd2/pd0: median", round(statistics.median(rat), 3), "total",
          round(sum(r["pd2"][0] for _, r in rows) / sum(r["pd0"][0] for _, r in rows), 3), "max", round(max(rat), 2))

    def within(tag: str, tol: float) -> tuple[int, int]:
        n = k = 0
        for cid, r in rows:
            ref = refs.get(cid, {}).get("objective")
            if ref is None or not math.isfinite(ref):
                continue
            n += 1
            k += r[tag][1] <= ref * (1 + tol)
        return k, n

    for tag, other in (("pd0", "pd2"), ("pd2", "pd0")):
        print(tag, "within 1 %:", within(tag, 0.01), "within 2 %:", within(tag, 0.02), "worse than", other,
              "by > 0.1 %:", sum(r[tag][1] > r[other][1] * 1.001 for _, r in rows))


if __name__ == "__main__":
    main()
