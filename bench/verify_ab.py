"""The verifier, before and after a change, on every design of the quality suite's references.

Each reference design (``bench/quality_reference.json``, thesis spec; ``bench/quality_reference_defaults.json``,
the default limits) is analysed by the tree this script runs in, through the public API
(``get_structure(structure).tf(gains, dt)``, ``analyze``); the figures are written as JSON. Run it in two trees
and compare the two files with ``--compare``: every figure and every verdict, by case.

    python bench/verify_ab.py --out /tmp/new.json             # in this tree
    (cd <old worktree> && python /path/to/bench/verify_ab.py --out /tmp/old.json)
    python bench/verify_ab.py --compare /tmp/old.json /tmp/new.json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
from pathlib import Path

HERE = Path(__file__).resolve().parent
FILES = ("quality_reference.json", "quality_reference_defaults.json")


def run(out: str) -> None:
    sys.path.insert(0, str(Path.cwd()))
    import numpy as np

    from tuner.analysis.verify import analyze
    from tuner.controllers import get_structure
    from tuner.plant import make_plant
    from tuner.spec import Spec

    cases = {c["id"]: c for c in json.loads((HERE / "quality_suite.json").read_text())["cases"]}
    res: dict[str, dict] = {}
    for name in FILES:
        ref = json.loads((HERE / name).read_text())
        for r in ref["references"]:
            if not r.get("gains"):
                continue
            c = cases[r["id"]]
            spec = Spec(**ref["spec"]) if ref.get("spec") else Spec.thesis()
            for lim in r.get("limits", []):
                spec = spec.model_copy(update={lim["field"]: lim["value"]})
            plant = make_plant(np.array(c["num"]), np.array(c["den"]), delay=float(c["delay_s"]))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                an = analyze(plant, get_structure(c["structure"]).tf(r["gains"], c["dt"]), spec)
            res[f"{name}:{r['id']}"] = {"meets_spec": an.meets_spec,
                                        "checks": [[k.name, bool(k.ok)] for k in an.checks],
                                        **{k: float(v) for k, v in vars(an.metrics).items()}}
    Path(out).write_text(json.dumps(res, indent=1))
    print(f"{len(res)} designs analysed -> {out}")


def compare(a: str, b: str) -> int:
    old, new = json.loads(Path(a).read_text()), json.loads(Path(b).read_text())
    diff = []
    for key in sorted(set(old) | set(new)):
        o, n = old.get(key), new.get(key)
        if o is None or n is None:
            diff.append((key, "missing"))
            continue
        for f in sorted(set(o) | set(n)):
            x, y = o.get(f), n.get(f)
            same = x == y or (isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y))
            if not same:
                diff.append((key, f, x, y))
    verdicts = sum(old[k]["meets_spec"] for k in old), sum(new[k]["meets_spec"] for k in new)
    print(f"{len(old)} / {len(new)} designs; meeting the spec: {verdicts[0]} before, {verdicts[1]} after; "
          f"{len(diff)} figures differ")
    for d in diff[:40]:
        print("  ", *d)
    return 1 if diff else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out")
    ap.add_argument("--compare", nargs=2)
    a = ap.parse_args()
    if a.compare:
        return compare(*a.compare)
    run(a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
