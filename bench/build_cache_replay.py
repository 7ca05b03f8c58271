"""What the NLP build cache keeps and what a worker's share of a study costs in builds: record the requests the
quality suite's tunes make of the cache, then replay them under other bounds, policies and splits.

    python bench/build_cache_replay.py record [--part 0 --parts 2]   # one process per part, both at once
    python bench/build_cache_replay.py replay                        # the tables, from the recorded parts

``record`` tunes the suite's loops of one part (consecutive, as ``tuner study run`` would: default effort, the
study file's spec) in one process with nothing dropped from the cache, and writes each request (the problem's
key, digested; its estimated size, tuner.optimize.nlp.transcribe.BYTES_PER_NODE per estimated node; whether it
was built and how long that took) to ``bench/results/build_cache_trace_<part>.json``. ``replay`` counts, per
part, the seconds of building under a bound (least recently used out, the running tune's problems kept), under a
two-segment policy (what was used twice kept apart from what was used once), with nothing kept between tunes,
and with the part's tunes split between two workers (at random, alternately, in halves). A replayed build costs
what the recorded one did. Nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import random
import sys
import tempfile
import time
from collections import OrderedDict
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(ROOT), str(HERE)]

GB = 2**30


def record(part: int, parts: int) -> None:
    import quality

    from tuner.optimize.nlp import refine, transcribe
    from tuner.studies.evaluate import tune_loop
    from tuner.studies.schema import load_study

    transcribe.CACHE_MB = float("inf")
    cases = quality.load_suite()
    f = Path(tempfile.mkdtemp()) / "suite.toml"
    f.write_text(quality.study_toml(cases, name="replay", budget=10.0, effort="default"))
    study = load_study(str(f))
    loops = study.order()
    n = len(loops)
    mine = loops[part * n // parts:(part + 1) * n // parts]
    trace: list[Any] = []
    real = refine.get_problem

    def recording(key: Any, st: Any, space: Any) -> Any:
        t = time.perf_counter()
        built = not transcribe.is_built(key)
        prob = real(key, st, space)
        trace.append([hashlib.sha1(repr(key).encode()).hexdigest()[:16],
                      transcribe.BYTES_PER_NODE * transcribe._estimated_nodes(key, len(st.params)), built,
                      time.perf_counter() - t])
        return prob

    refine.get_problem = recording
    for lp in mine:
        trace.append(["tune", lp.name])
        tune_loop(study, lp, {})
    out = HERE / "results" / f"build_cache_trace_{part}.json"
    out.write_text(json.dumps({"command": "python bench/build_cache_replay.py " + " ".join(sys.argv[1:]),
                               "loops": [lp.name for lp in mine], "trace": trace}))
    print(f"part {part}: {len(mine)} loops, {sum(1 for t in trace if t[0] != 'tune' and t[2])} builds -> {out}")


def simulate(trace: list[Any], cost: dict[str, float], budget: float, policy: str = "lru") -> float:
    """Seconds of building for ``trace`` under ``budget`` bytes (the running tune's problems always kept)."""
    hot: OrderedDict[str, float] = OrderedDict()  # lru: everything; 2q: used twice
    cold: OrderedDict[str, float] = OrderedDict()  # 2q: used once
    pinned: set[str] = set()
    spent = 0.0

    def trim(seg: OrderedDict[str, float], cap: float) -> None:
        total = sum(seg.values())
        for k in list(seg)[:-1]:
            if total <= cap:
                break
            if k not in pinned:
                total -= seg.pop(k)

    for t in trace:
        if t[0] == "tune":
            pinned = set()
            continue
        key, size = t[0], t[1]
        pinned.add(key)
        if key in hot:
            hot.move_to_end(key)
            continue
        if policy == "2q" and key in cold:
            hot[key] = cold.pop(key)
        else:
            spent += cost[key]
            (cold if policy == "2q" else hot)[key] = size
        if policy == "2q":
            trim(hot, 0.75 * budget)
            trim(cold, 0.25 * budget)
        else:
            trim(hot, budget)
    return spent


def split(trace: list[Any], assign: Any) -> list[list[Any]]:
    parts: list[list[Any]] = [[], []]
    cur = 0
    i = -1
    for t in trace:
        if t[0] == "tune":
            i += 1
            cur = assign(i)
        parts[cur].append(t)
    return parts


def _two(trace: list[Any], cost: dict[str, float], assign: Any) -> float:
    """Seconds of building with the tunes split between two workers as ``assign`` (tune index -> 0 or 1) says."""
    return sum(simulate(p, cost, 2 * GB) for p in split(trace, assign))


def _random_worker(seed: int) -> Any:
    rng = random.Random(seed)
    return lambda i: rng.randrange(2)


def replay() -> None:
    files = sorted((HERE / "results").glob("build_cache_trace_*.json"))
    if not files:
        raise SystemExit("no recorded parts: run `record` first")
    print("| part | loops | nothing dropped | 4 GB | 2 GB | 1 GB | 0.5 GB | 2 GB two-segment | nothing kept between "
          "tunes | 2 workers at random (5 draws) | alternately | in halves |")
    print("| --- " * 12 + "|")
    for f in files:
        doc = json.loads(f.read_text())
        trace = doc["trace"]
        cost = {t[0]: t[3] for t in trace if t[0] != "tune" and t[2]}
        n = sum(1 for t in trace if t[0] == "tune")

        def s(x: float) -> str:
            return f"{x:.1f} s"

        rnd = [_two(trace, cost, _random_worker(seed)) for seed in range(5)]
        cells = [s(simulate(trace, cost, float("inf")))] + [s(simulate(trace, cost, g * GB)) for g in (4, 2, 1, 0.5)]
        cells += [s(simulate(trace, cost, 2 * GB, "2q")), s(simulate(trace, cost, 0.0)),
                  f"{min(rnd):.1f}-{max(rnd):.1f} s", s(_two(trace, cost, lambda i: i % 2)),
                  s(_two(trace, cost, lambda i, half=n // 2: int(i >= half)))]
        print(f"| {f.stem.rsplit('_', 1)[1]} | {n} | " + " | ".join(cells) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("--part", type=int, default=0)
    r.add_argument("--parts", type=int, default=2)
    sub.add_parser("replay")
    a = ap.parse_args()
    if a.cmd == "record":
        record(a.part, a.parts)
    else:
        replay()


if __name__ == "__main__":
    main()
