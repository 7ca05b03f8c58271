"""Where a warm ``px4_rate`` tune spends its time (issue 41's target: <= 100 ms warm), and what some options would give.

    OPENBLAS_NUM_THREADS=1 TUNER_NLP_COMPILE=off .venv/bin/python bench/px4_speed.py [--reps 5] [--variant none]

One process: one tune to warm up (imports, NLP builds), then ``--reps`` tunes of 200/((s+2)(0.03s+1)) at dt 0.0025,
seed 0, default effort, each timed (wall and CPU) and split into: the NLP solves (CasADi's calls inside
``_Solves``), the batch's evaluations (by the search and by the load design), the load design as a whole
(``raise_integral``: its batch and its verifier calls) and the rest; and the gains' hash (float.hex, as
bench/gain_hashes.py). ``--variant``, each a measurement, none of them the product's code:

- ``none``: the tree as it is;
- ``kernels``: ``TUNER_KERNELS=on`` (the compiled numba kernels score the batch; figures to ~1e-10, not bitwise);
- ``fast``: ``effort="fast"``;
- ``giveup``: the load design's pattern search drops a level's start once ``GIVEUP_POLLS`` polls have left its best
  candidate failing the spec (the merit still a penalty): a level that fails stops early (gains can change
  wherever a start would have reached the spec later).

``--replay N``: instead, the batch's evaluations of one warm tune recorded and replayed N times (each replay's CPU
time; min and median), with a digest of every figure they return (the same digest: bitwise the same figures); run it
with ``PYTHONPATH=<another tree>`` to time that tree's batch on its own recording.

``--h2h``: instead, the ``giveup`` variant against the code as it is on bench/h2h's airframes (both firmware laws, as
bench/autotune_h2h.py tunes them), one warm process: each tune's wall time both ways and whether the gains are the
same bitwise.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import sys
import time

os.environ.setdefault("TUNER_NLP_COMPILE", "load")  # (no background compile beside timed runs: README, compiled code)

PX4 = "200/((s+2)*(0.03*s+1))"
GIVEUP_POLLS = 4


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--variant", default="none", choices=("none", "kernels", "fast", "giveup"))
    ap.add_argument("--h2h", action="store_true")
    ap.add_argument("--replay", type=int, default=0)
    a = ap.parse_args()
    if a.h2h:
        return _h2h()
    if a.replay:
        return _replay(a.replay)
    if a.variant == "kernels":
        os.environ["TUNER_KERNELS"] = "on"
    from tuner.optimize import batch, setpoint
    from tuner.optimize.nlp import refine
    from tuner.plant import plant_from_expr
    from tuner.tuning import tune

    acc: dict[str, float] = {}

    def add(k: str, v: float) -> None:
        acc[k] = acc.get(k, 0.0) + v

    solve0 = refine._Solves.__call__

    def solve(self, ts, x):
        t = time.perf_counter()
        try:
            return solve0(self, ts, x)
        finally:
            add("nlp_solves_s", time.perf_counter() - t)
            add("nlp_solves", 1)

    ev0 = batch.BatchEvaluator.evaluate
    in_load = [False]

    def evaluate(self, X, **kw):
        t = time.perf_counter()
        try:
            return ev0(self, X, **kw)
        finally:
            add("batch_load_s" if in_load[0] else "batch_search_s", time.perf_counter() - t)

    ri0 = setpoint.raise_integral

    def raise_integral(*args, **kw):
        t = time.perf_counter()
        in_load[0] = True
        try:
            return ri0(*args, **kw)
        finally:
            in_load[0] = False
            add("load_design_s", time.perf_counter() - t)

    refine._Solves.__call__ = solve
    batch.BatchEvaluator.evaluate = evaluate
    setpoint.raise_integral = raise_integral  # (tuner.tuning imports it from the module at each call)
    if a.variant == "giveup":
        _giveup(setpoint)
    effort = "fast" if a.variant == "fast" else "default"

    def one() -> dict:
        acc.clear()
        w0, c0 = time.perf_counter(), time.process_time()
        r = tune(plant_from_expr(PX4), structure="px4_rate", dt=0.0025, seed=0, effort=effort)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        gains = {k: float(v) for k, v in r.gains.items()}
        h = hashlib.sha256(json.dumps({k: v.hex() for k, v in gains.items()}, sort_keys=True).encode()).hexdigest()
        out = {"wall_s": wall, "cpu_s": cpu, **acc, "hash": h[:16], "settling_s":
               max(an.metrics.settling_time_s for an in r.analyses), "meets": bool(r.meets_spec)}
        out["rest_s"] = wall - acc.get("nlp_solves_s", 0) - acc.get("batch_search_s", 0) - acc.get("load_design_s", 0)
        return out

    one()
    runs = [one() for _ in range(a.reps)]
    for r in runs:
        print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()}))
    keys = [k for k in runs[0] if isinstance(runs[0][k], float)]
    print(f"variant {a.variant}, {a.reps} warm tunes, medians: " +
          ", ".join(f"{k} {statistics.median(r.get(k, 0.0) for r in runs):.3f}" for k in keys) +
          f"; hashes {sorted({r['hash'] for r in runs})}")


def _replay(n: int) -> None:
    """``--replay N`` (see the module's docstring)."""
    import numpy as np

    import tuner
    from tuner.optimize import batch
    from tuner.plant import plant_from_expr
    from tuner.tuning import tune

    def go() -> None:
        tune(plant_from_expr(PX4), structure="px4_rate", dt=0.0025, seed=0)

    go()
    calls = []
    ev0 = batch.BatchEvaluator.evaluate

    def record(self, X, **kw):
        calls.append((self, np.array(X, float, copy=True), dict(kw), self.load_recovery))
        return ev0(self, X, **kw)

    batch.BatchEvaluator.evaluate = record
    go()
    batch.BatchEvaluator.evaluate = ev0

    def once() -> tuple[float, str]:
        h = hashlib.sha256()
        c0 = time.process_time()
        for ev, X, kw, lr in calls:
            ev.load_recovery = lr
            r = ev.evaluate(X, **kw)
            ev.load_recovery = False
            for a in (r.score, r.feasible, r.violation, *(m[k] for m in [r.metrics, *r.per_plant] for k in sorted(m))):
                h.update(np.ascontiguousarray(a).tobytes())
        return time.process_time() - c0, h.hexdigest()[:16]

    runs = [once() for _ in range(n)]
    cpu = sorted(r[0] for r in runs)
    print(f"{tuner.__file__}: {len(calls)} evaluate calls, {sum(c[1].shape[0] for c in calls)} rows; replay CPU min "
          f"{cpu[0]:.3f} s, median {statistics.median(cpu):.3f} s over {n}; digests {sorted({r[1] for r in runs})}")


def _h2h() -> None:
    """``--h2h`` (see the module's docstring)."""
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from h2h.airframes import AIRFRAMES
    from h2h.ours import ours

    from tuner.optimize import setpoint

    for name, af in AIRFRAMES.items():
        for law in ("px4_rate", "ardupilot_rate"):
            out = {}
            ours(af, law)  # (warm: this shape's NLPs built)
            for variant in ("none", "giveup", "none", "giveup"):
                setpoint.GIVE_UP_POLLS = None
                if variant == "giveup":
                    _giveup(setpoint)
                r = ours(af, law)
                out.setdefault(variant, []).append(r)
            setpoint.GIVE_UP_POLLS = None
            same = all(r["gains"] == out["none"][0]["gains"] for rs in out.values() for r in rs)
            walls = {v: [round(r["wall_s"], 3) for r in rs] for v, rs in out.items()}
            print(f"{name} {law}: gains {'same' if same else 'DIFFERENT'}, wall s {walls}, settling "
                  f"{out['none'][0]['claimed']['settling_s']:.4g} -> {out['giveup'][0]['claimed']['settling_s']:.4g}, "
                  f"load recovery {out['none'][0]['claimed']['load_recovery_s_2pct']:.4g} -> "
                  f"{out['giveup'][0]['claimed']['load_recovery_s_2pct']:.4g}", flush=True)
            if not same:
                print(f"  none {out['none'][0]['gains']}\n  giveup {out['giveup'][0]['gains']}", flush=True)


def _giveup(setpoint) -> None:
    """The ``giveup`` variant: the load design's pattern search (:func:`tuner.optimize.setpoint._settle_locally`)
    drops a start once ``GIVEUP_POLLS`` polls have left its best merit a penalty (``setpoint.GIVE_UP_POLLS``)."""
    setpoint.GIVE_UP_POLLS = GIVEUP_POLLS


if __name__ == "__main__":
    sys.exit(main())
