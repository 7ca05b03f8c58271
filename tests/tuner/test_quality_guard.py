"""The quality guard: a fixed slice of bench/quality.py's suite, each default tune within 2 % of its stored
reference optimum (quality, not time); and a few loops whose optimum sits at an edge (the overshoot at the band,
the overshoot limit, settling within a sample), each ``effort="thorough"`` tune within 0.5 % of it.

The references (bench/quality_reference.json) were computed once by independent global searches
(differential evolution, CMA-ES, Nelder-Mead polish; none of the engine's starts or rounds) and verified by
``tuner.analyze`` and by tests/reference.py; ``python bench/quality.py reference`` recomputes them. A change
that makes the search stop early, lose a start family or a restart shows here as a ratio above 1.02.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from tuner import Spec, tune
from tuner.plant import Plant

BENCH = Path(__file__).resolve().parents[2] / "bench"
# three or four per class, over the structures; loops that settle in tens of samples (about a second each)
GUARD = ["lag-00", "lag-01", "lag-02", "lag-03", "underdamped-01", "underdamped-02", "underdamped-03",
         "integrating-00", "integrating-02", "integrating-04", "unstable-00", "unstable-02", "nmp-00", "nmp-01",
         "nmp-04", "delay-00", "delay-01", "delay-03", "underdamped-00", "delay-02",
         # the vanishing-integral PI, pid_z on an unstable plant, fractional delays (pi, pid, pid_z), pid2
         "integrating-03", "unstable-05", "fracdelay-00", "fracdelay-09", "fracdelay-10", "twodof-00", "twodof-04"]
TOLERANCE = 1.02
# effort="thorough" on optima at an edge the NLP's grid does not hold: the overshoot at the 2 % band, the band entered
# between the grid's points (underdamped-00 pid, integrating-28 pd: 1.0052, 1.0056 before the sharp polish), within
# the first sample (lag-30 pid: 1.0050), the overshoot limit on an unstable plant, peaking at a sample instant
# (unstable-30 pi: 1.0092)
THOROUGH = ["underdamped-00", "integrating-28", "lag-30", "unstable-30"]
THOROUGH_TOLERANCE = 1.005


def _load():
    cases = {c["id"]: c for c in json.loads((BENCH / "quality_suite.json").read_text())["cases"]}
    ref = json.loads((BENCH / "quality_reference.json").read_text())
    # the references are the thesis spec's (no default design limits: issue 18's limits came later)
    # every stored field as it is now, and any field added since (a limit of the registry) unset
    now = Spec.thesis().model_dump(mode="json")
    # (the gain-variation members' phase margin acts only with gain_variation set, which the thesis lifts)
    inert = {"gain_variation_pm_min_deg"} if now.get("gain_variation") is None else set()
    assert all(now[k] == v for k, v in ref["spec"].items()) and \
        all(now[k] is None for k in now.keys() - ref["spec"].keys() - inert), \
        "the stored references are for another spec"
    return cases, {r["id"]: r for r in ref["references"]}


CASES, REFS = _load()
SPEC = Spec.thesis()


def _check(cid: str, tolerance: float, **kw) -> None:
    c, r = CASES[cid], REFS[cid]
    assert r["feasible"] and r["independent_ok"], f"{cid}: the guard's reference must be verified twice"
    plant = Plant(np.array(c["num"], float), np.array(c["den"], float), delay_s=float(c["delay_s"]))
    # a budget the search never reaches (it converges in seconds), so that the machine's load cannot cut it
    res = tune(plant, structure=c["structure"], dt=c["dt"], seed=0, spec=SPEC, diagnose=False, time_budget_s=120,
               **kw)
    assert res.meets_spec, f"{cid}: no design that meets the spec (the reference has {r['objective']:.5g})"
    ratio = res.objective / r["objective"]
    assert math.isfinite(ratio) and ratio <= tolerance, (
        f"{cid} ({c['structure']}): {res.objective:.5g} is {100 * (ratio - 1):.2f} % above the reference "
        f"{r['objective']:.5g} (gains {res.gains}; reference {r['gains']})")


@pytest.mark.slow
@pytest.mark.parametrize("cid", GUARD)
def test_default_tune_is_within_two_percent_of_the_reference(cid):
    _check(cid, TOLERANCE)


@pytest.mark.slow
@pytest.mark.parametrize("cid", THOROUGH)
def test_thorough_tune_is_within_half_a_percent_of_the_reference(cid):
    _check(cid, THOROUGH_TOLERANCE, effort="thorough")
