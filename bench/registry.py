"""Issue 29's measurements: the registry, its contract, the mks knob and the disturbance figures.

    .venv/bin/python bench/registry.py [--before-rev REV]

1. Files a limit touches: the files of ``tuner/`` and ``api/`` (tests excluded) that name an optional limit's field
   or flag, at ``--before-rev`` (the tree before the registry) and here; and the files the ``--drb-min`` change
   touched (its field, flag or metric named in them).
2. The contract (tests/tuner/test_registry_contract.py): loops x limits x evaluators compared, mismatches.
3. The mks knob on 1/(s+1)^3: pid with settling <= 3 s and pi with settling <= 8 s; each checked against the
   trade-off (a settling-time tune with Mks limited 1 % below the answer must settle later than the limit, or fail).
4. DRB, DRP and the load step's IAE/peak/recovery on MATLAB's pidtune PI for 1/(s+1)^3, the thesis roll loop with
   its printed controller, and a PI with a fractional delay (the figures tests/tuner/test_disturbance_figures.py
   checks against first principles).

Prints Markdown. Nothing here asserts.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the package itself first: tests/tuner must not shadow it
sys.path.append(str(ROOT / "tests"))
sys.path.append(str(ROOT / "tests" / "tuner"))


def _files_naming(rev: str | None, words: list[str]) -> list[str]:
    args = ["git", "-C", str(ROOT), "grep", "-l", "-E", "|".join(words)]
    if rev:
        args.append(rev)
    args += ["--", "tuner", "api"]
    out = subprocess.run(args, capture_output=True, text=True).stdout.split()
    return sorted({o.split(":", 1)[1] if rev else o for o in out})


def files_touched(before: str) -> None:
    print("## 1. Files a limit touches\n")
    for name, words in (("bandwidth_min_rad_s (an optional limit)", ["bandwidth_min_rad_s", "--bandwidth\\b"]),
                        ("mks_max", ["mks_max", "\"--mks\""])):
        b, a = _files_naming(before, words), _files_naming(None, words)
        print(f"- `{name}`: named in {len(b)} files before ({', '.join(b)}), {len(a)} now ({', '.join(a)})")
    drb = _files_naming(None, ["drb_min", "drb-min", "disturbance_rejection_bandwidth", "\"drb\"", "drbmask"])
    print(f"- `--drb-min` (added through the registry): {len(drb)} files: {', '.join(drb)}\n")


def contract() -> None:
    import test_registry_contract as t

    print("## 2. The contract\n")
    c, n, bad = t._contract(t._loops(60, seed=2))
    print(f"- batch vs verifier: {c} loops, {n} comparisons (limits and objectives), {len(bad)} mismatches outside "
          f"the known categories, {len(t.KNOWN_SEEN)} in them")
    for b in t.KNOWN_SEEN:
        print(f"  - known: {b.splitlines()[0][:200]}")
    c2, bad2 = t._nlp_contract(t._loops(50, seed=4))
    errs = np.array(t.CONTINUOUS_NLP_ERR)
    print(f"- NLP step vs verifier: {c2} loops; sampled loops exact at the samples (<= 1e-6), continuous loops' "
          f"largest differences: median {np.median(errs):.3g}, max {errs.max():.3g} of the step ({len(bad2)} beyond "
          "0.1)\n")


def mks_knob() -> None:
    from quadrotor import PITCH

    from tuner import Spec, plant_from_expr, tune

    print("## 3. The mks knob on 1/(s+1)^3 (and the thesis pitch model)\n")
    third = plant_from_expr("1/(s+1)^3")
    pitch = plant_from_expr(PITCH)
    fastest = tune(pitch, structure="pid").analyses[0].metrics.settling_time_s
    for P, st, ts in ((third, "pid", 3.0), (third, "pi", 8.0), (pitch, "pid", round(1.2 * fastest, 4)),
                      (pitch, "pid", round(2.0 * fastest, 4))):
        r = tune(P, structure=st, spec=Spec(objective="mks", settling_time_max=ts))
        m = r.analyses[0].metrics
        check = tune(P, structure=st, spec=Spec(mks_max=m.mks * 0.99))
        cm = check.analyses[0].metrics
        print(f"- {P.describe()[:40]}: {st}, settling <= {ts:g} s: Mks {m.mks:.4g} at {m.settling_time_s:.4g} s "
              f"({r.solver['stop']}, {r.solver['optimality']['summary']}); gains "
              + ", ".join(f"{k} {v:.4g}" for k, v in r.gains.items()))
        print(f"  - trade-off check: the fastest {st} with Mks <= {m.mks * 0.99:.4g} settles in "
              f"{cm.settling_time_s:.4g} s (meets: {check.meets_spec}): "
              + ("above the limit, so no design 1 % less noisy meets it" if cm.settling_time_s > ts or not
                 check.meets_spec else "WITHIN the limit: the knob's answer is not on the curve"))
        if st == "pi":
            print(f"  - Mks >= 1/|G(0)| = 1 for any PI with integral action on this plant: {m.mks:.6g}")
    print()


def figures() -> None:
    import control
    from quadrotor import DT, ROLL, ROLL_C

    from tuner import analyze, controller_from_expr, plant_from_expr

    print("## 4. Disturbance figures\n")
    print("| loop | DRB [rad/s] | DRP [dB] | load IAE | load peak | recovery [s] |")
    print("| --- | --- | --- | --- | --- | --- |")
    G = control.tf([1], [1, 3, 3, 1])
    rows = [("pidtune PI 1.14 + 0.454/s on 1/(s+1)^3", analyze(G, control.tf([1.14, 0.454], [1, 0]))),
            ("thesis roll, printed pid_z at 0.04 s",
             analyze(plant_from_expr(ROLL), controller_from_expr(ROLL_C, dt=DT))),
            ("PI 0.5 + 0.2/s on 1/(s+1)^3, delay 0.37 s", analyze(G, control.tf([0.5, 0.2], [1, 0]), delay=0.37)),
            ("the same at dt 0.1 (3.7 samples)", analyze(G, control.tf([0.52, -0.5], [1, -1], 0.1), delay=0.37))]
    for name, a in rows:
        m = a.metrics
        print(f"| {name} | {m.disturbance_rejection_bandwidth_rad_s:.4g} | {m.disturbance_rejection_peak_db:.4g} | "
              f"{m.load_iae:.4g} | {m.load_peak:.4g} | {m.load_recovery_s:.4g} |")
    print()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--before-rev", default="78a71e3")
    a = ap.parse_args()
    files_touched(a.before_rev)
    contract()
    mks_knob()
    figures()


if __name__ == "__main__":
    main()
