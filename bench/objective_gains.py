"""Whether a change keeps every objective's tuned gains bitwise the same (for the objectives other than the settling
time a refinement's answer is its solve's x, kept where the SQP's f is finite, and ranked by the batch): the gains
(float.hex), objective and verdict of pid on 1/(s+1)^3 at dt 0.1, pid_z on the README's roll loop at dt 0.04 and pi
on 1/(s(0.5s+1)) (continuous), for each objective and seeds 0 and 1, in one process.

    .venv/bin/python bench/objective_gains.py OUT.json                       # this tree
    PYTHONPATH=/other/tree .venv/bin/python bench/objective_gains.py B.json  # another tree
    .venv/bin/python bench/objective_gains.py --compare A.json B.json
"""

from __future__ import annotations

import json
import sys

LOOPS = (("1/(s+1)^3", "pid", 0.1), ("0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)", "pid_z", 0.04),
         ("1/(s*(0.5*s+1))", "pi", None))
OBJECTIVES = ("itae", "iae", "ie", "mks", "disk_margin", "bandwidth", "settling_time")


def run(out: str) -> None:
    from tuner.plant import plant_from_expr
    from tuner.spec import Spec
    from tuner.tuning import tune

    res: dict[str, object] = {}
    for expr, st, dt in LOOPS:
        for obj in OBJECTIVES:
            for seed in (0, 1):
                name = f"{st} {obj} {seed}"
                try:
                    r = tune(plant_from_expr(expr), structure=st, dt=dt, seed=seed, spec=Spec(objective=obj),
                             time_budget_s=600)
                    res[name] = [{k: float(v).hex() for k, v in r.gains.items()},
                                 r.objective if r.objective == r.objective else None, r.meets_spec]
                except Exception as e:  # (recorded: the same error in both trees is the same answer)
                    res[name] = repr(e)
                print(name, res[name], file=sys.stderr, flush=True)
    with open(out, "w") as f:
        json.dump(res, f, indent=1)


def compare(a: str, b: str) -> None:
    x, y = json.load(open(a)), json.load(open(b))
    same = [k for k in x if x[k] == y.get(k)]
    print(f"{len(same)} of {len(x)} the same; different: {[k for k in x if k not in same] or 'none'}")


if __name__ == "__main__":
    if sys.argv[1:2] == ["--compare"]:
        compare(sys.argv[2], sys.argv[3])
    else:
        run(sys.argv[1])
