"""Whether a change keeps the tuned gains bitwise the same: the gains of px4_rate (default and fast effort, seeds
0-4) and of the README's roll pid_z and 1/(s+1)^3 pid (seeds 0-2) hashed, beside the verifier's worst settling time,
load recovery and margins over the plants, and each tune's CPU time; one warm process per tree.

    .venv/bin/python bench/gain_hashes.py OUT.json                          # this tree
    PYTHONPATH=/tmp/base-X .venv/bin/python bench/gain_hashes.py BASE.json  # another tree (git worktree add)
    .venv/bin/python bench/gain_hashes.py --compare BASE.json OUT.json

A hash is of the gains' exact binary values (float.hex); the figures are the verifier's, as the result reports them.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import time

os.environ.setdefault("TUNER_NLP_COMPILE", "load")  # (no background compile beside timed runs: README, compiled code)

PX4 = "200/((s+2)*(0.03*s+1))"
CASES = ([(PX4, "px4_rate", 0.0025, s, e) for e in ("default", "fast") for s in range(5)]
         + [c for s in range(3) for c in (("0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)", "pid_z", 0.04, s, "default"),
                                          ("1/(s+1)^3", "pid", 0.1, s, "default"))])


def run(out: str) -> None:
    from tuner.plant import plant_from_expr
    from tuner.tuning import tune

    res = {}
    for expr, st, dt, seed, effort in CASES:
        c0 = time.process_time()
        r = tune(plant_from_expr(expr), structure=st, dt=dt, seed=seed, effort=effort, time_budget_s=600)
        cpu = time.process_time() - c0
        gains = {k: float(v) for k, v in r.gains.items()}
        h = hashlib.sha256(json.dumps({k: v.hex() for k, v in gains.items()}, sort_keys=True).encode()).hexdigest()
        M = [a.metrics for a in r.analyses]
        res[f"{st} {effort} {seed}"] = {
            "hash": h[:16], "gains": gains, "meets": bool(r.meets_spec), "cpu_s": cpu,
            "settling_s": max(m.settling_time_s for m in M), "load_recovery_s": max(m.load_recovery_s for m in M),
            "pm_deg": min(m.phase_margin_deg for m in M), "gm_db": min(m.gain_margin_db for m in M)}
        print(f"{st} {effort} {seed}: {res[f'{st} {effort} {seed}']}", file=sys.stderr, flush=True)
    with open(out, "w") as f:
        json.dump(res, f, indent=1)


def compare(base: str, new: str) -> None:
    a, b = json.load(open(base)), json.load(open(new))
    for k in a:
        x, y = a[k], b[k]
        moved = {m: f"{y[m] - x[m]:+.3g}" for m in ("settling_s", "load_recovery_s", "pm_deg", "gm_db") if x[m] != y[m]}
        print(f"{k}: gains {'same' if x['hash'] == y['hash'] else 'DIFFERENT'}, meets {x['meets']} -> {y['meets']}, "
              f"CPU {x['cpu_s']:.2f} -> {y['cpu_s']:.2f} s, figures moved {moved or 'none'}")


if __name__ == "__main__":
    if not sys.argv[1:] or sys.argv[1] in ("-h", "--help"):  # (not an output file named --help)
        print(__doc__)
    elif sys.argv[1:2] == ["--compare"]:
        compare(sys.argv[2], sys.argv[3])
    else:
        run(sys.argv[1])
