"""Issue 20: the best answer, not the first; what a result knows about its optimality; the effort setting.

The hard cases of issues 18 and 20, each checked against figures derived here: the unstable PI against the
published grid point and an independent simulation (tests/reference.py), the constrained IAE against the
overshoot it must keep, the effort ladder against itself (more effort never worse).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import reference as ref

from tuner import Spec, analyze, plant_from_expr, tune
from tuner.cli import main
from tuner.errors import TunerError
from tuner.plant import Plant
from tuner.text import optimality_line

PITCH = "4.674/(s^2+3.523*s+12.38)"


def _independent(plant_num, plant_den, res, spec: Spec, horizon_s: float = 20.0, delay_samples: int = 0
                 ) -> dict[str, float]:
    """Margins (dense Nyquist grid) and the step (matrix-exponential simulation over ``horizon_s``) of the loop,
    without tuner (``delay_samples``: the plant's dead time, whole samples: z^-d)."""
    c = res.controller
    dt = c.dt
    gn, gd = ref.zoh(plant_num, plant_den, dt)
    gd = np.polymul(gd, np.r_[1.0, np.zeros(delay_samples)])
    num, den = np.polymul(c.num, gn), np.polymul(c.den, gd)
    assert np.all(np.abs(np.roots(np.polyadd(den, num))) < 1)
    m = ref.nyquist_margins(num, den, dt, n=60_000)
    t, y = ref.closed_loop_step(plant_num, plant_den, c.num, c.den, dt, samples=int(horizon_s / dt),
                                delay_samples=delay_samples)
    return {"pm": m["pm"], "gm": m["gm_db"], "gml": m["gml_db"], "overshoot": (float(np.max(y)) - 1) * 100,
            "settling": ref.settling_time(t, y, 1.0, band=spec.settling_band_pct / 100)}


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_unstable_pi_meets_the_spec_on_every_seed(seed):
    """Issue 18 part 6: PI on 1/(s - 1) at dt 0.04. A 28 x 28 grid finds Kp 19.25, Ki 20: settling 1.60 s; the
    tuner must meet the spec at <= 1.65 s on every seed (it used to return 26 % overshoot, FAIL)."""
    spec = Spec()
    res = tune(plant_from_expr("1/(s-1)"), structure="pi", dt=0.04, seed=seed, diagnose=False)
    assert res.meets_spec
    assert res.objective <= 1.65
    # the published grid point, as the verifier sees it: what the tuner must not be worse than
    grid = analyze(plant_from_expr("1/(s-1)"), res.controller.__class__(
        num=np.array([19.2476 + 0.8, -19.2476]), den=np.array([1.0, -1.0]), dt=0.04), spec)
    assert grid.meets_spec and res.objective <= grid.metrics.settling_time_s + 0.5 * 0.04
    ind = _independent([1.0], [1.0, -1.0], res, spec)
    assert ind["pm"] >= 60 - 0.05 and ind["gm"] >= 6 - 0.02 and ind["gml"] <= -6 + 0.02
    assert ind["overshoot"] <= 10 + 0.02
    assert ind["settling"] == pytest.approx(res.objective, abs=0.04 / 10)


@pytest.mark.slow
def test_oscillatory_process_loop_reaches_the_long_de_optimum():
    """studies/process.toml's `oscillatory` (1/(s^2+0.2s+1), pid, dt 0.1) under the thesis spec: <= 0.353 s
    (it was 0.371 s; a long differential evolution reaches 0.350 s), checked independently."""
    spec = Spec.thesis()
    res = tune(plant_from_expr("1/(s^2+0.2s+1)"), structure="pid", dt=0.1, seed=0, spec=spec, diagnose=False)
    assert res.meets_spec and res.objective <= 0.353
    ind = _independent([1.0], [1.0, 0.2, 1.0], res, spec)
    assert ind["pm"] >= 60 - 0.05 and ind["overshoot"] <= 10 + 0.02
    assert ind["settling"] == pytest.approx(res.objective, abs=0.01)


@pytest.mark.slow
def test_constrained_iae_is_not_missed():
    """Pitch at dt 0.04, pid, IAE with PM/GM off, Ms <= 1.4, Mks <= 20, overshoot <= 10 %: the design must be
    near the unconstrained-overshoot one (IAE 0.071 at 11.5 %), not at 0.251 (the old answer); a differential
    evolution on the same problem (bench/quality.py's reference method) reaches 0.0716 at 9.89 %."""
    spec = Spec.thesis(objective="iae", phase_margin_min_deg=0, gain_margin_min_db=0, ms_max=1.4, mks_max=20)
    res = tune(plant_from_expr(PITCH), structure="pid", dt=0.04, spec=spec, seed=0, diagnose=False)
    assert res.meets_spec
    assert res.objective <= 0.075
    a = res.analyses[0]
    assert a.metrics.overshoot_pct <= 10 and a.metrics.ms <= 1.4 and a.metrics.mks <= 20


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_optimality_is_reported_in_the_result_and_json():
    res = tune(plant_from_expr("1/(s+1)^2"), structure="pi", dt=0.1, seed=0, diagnose=False)
    o = res.solver["optimality"]
    for k in ("effort", "basins", "alternative", "gap", "restarts", "restart_improved", "round0_gap", "summary"):
        assert k in o
    assert o["effort"] == "default" and o["restarts"] >= 1 and o["basins"] >= 1
    assert res.solver["stop"] in ("converged", "work") and o["evidence"]["refinements"] >= 2
    assert "optimality" in repr(res) and o["summary"] in repr(res)
    assert json.loads(json.dumps(res.to_json()))["solver"]["optimality"]["restarts"] == o["restarts"]
    if o["gap"] is not None:
        assert o["gap"] >= -1e-9  # the alternative is never better than the answer (it is the best elsewhere)


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_fast_effort_needs_no_restart_and_is_never_better_than_default():
    p = plant_from_expr("1/(s+1)^3")
    fast = tune(p, structure="pid", dt=0.1, seed=0, effort="fast", diagnose=False)
    default = tune(p, structure="pid", dt=0.1, seed=0, diagnose=False)
    # fast stopped on round 0's own agreement; default ran its restarts (at least the 2 its evidence rule needs),
    # stopping by that rule or when its work budget of restarts was spent, never on the clock
    assert fast.solver["stop"] == "converged" and default.solver["stop"] in ("converged", "work")
    assert fast.solver["optimality"]["restarts"] == 0 and default.solver["optimality"]["restarts"] >= 2
    assert fast.solver["global_evaluations"] < default.solver["global_evaluations"]
    assert default.objective <= fast.objective * (1 + 1e-3)


def test_a_larger_budget_returns_the_same_converged_answer():
    """The search is deterministic and ends on its own (its evidence rule or its work budget of restarts) well within
    the budget: more budget, the same answer. (Both
    budgets are far above what the search uses even at -n 8 on 2 cores: the engine cuts a batch or skips an NLP
    build by the time left, so a budget the load makes tight is a different search, not a worse-budget test.)"""
    p = plant_from_expr("2/((s+1)*(0.3s+1))")
    a = tune(p, structure="pid", dt=0.05, seed=1, time_budget_s=120, diagnose=False)
    b = tune(p, structure="pid", dt=0.05, seed=1, time_budget_s=600, diagnose=False)
    assert a.solver["stop"] == b.solver["stop"] and a.solver["stop"] in ("converged", "work")
    assert b.objective == a.objective and b.gains == a.gains


def test_bad_effort_is_refused_with_its_field():
    with pytest.raises(TunerError) as e:
        tune(plant_from_expr("1/(s+1)"), structure="pi", effort="max")
    assert e.value.field == ("effort",) or e.value.field == "effort" or "effort" in str(e.value.field)


def test_cli_effort_and_the_optimality_line(capsys):
    assert main(["tune", "--plant", "1/(s+1)^2", "--dt", "0.1", "--structure", "pi", "--effort", "fast"]) == 0
    out = capsys.readouterr().out
    line = [x for x in out.splitlines() if x.startswith("optimality")]
    assert len(line) == 1 and "fast effort" in line[0]
    with pytest.raises(SystemExit) as e:
        main(["tune", "--plant", "1/(s+1)", "--structure", "pi", "--effort", "max"])
    assert e.value.code == 2
    assert "--effort" in capsys.readouterr().err


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_thorough_is_never_worse_than_default():
    p = plant_from_expr("1/(s^2+0.4s+1)")
    d = tune(p, structure="pid", dt=0.1, seed=0, diagnose=False, time_budget_s=120)
    t = tune(p, structure="pid", dt=0.1, seed=0, effort="thorough", diagnose=False,
             time_budget_s=120)
    assert t.meets_spec and d.meets_spec
    assert t.objective <= d.objective * (1 + 1e-3)
    assert t.solver["optimality"]["restarts"] >= 3
    assert math.isfinite(t.objective)


@pytest.mark.slow
def test_pi_on_a_slow_integrating_plant_is_a_p_with_a_vanishing_integral():
    """bench/quality.py's integrating-19: PI on 0.4546/(s (6.115 s + 1)) at dt 0.2235, thesis spec. The loop has zero
    steady-state error without an integral, and a PI zero near the crossover costs phase and leaves a slow tail out
    of the band: the optimum is a P with a vanishing integral (the reference's long DE + CMA-ES: Kp 0.146, Ki 6.5e-10,
    34.61 s). The tuner used to return 245 s (no start had its zero far below the crossover; the NLP's integral
    crossed zero to an unstable slow pole; the settling time's jump where the overshoot reaches the band was not
    crossed back). The bar is a brute force over P controllers here (the PI's infimum as Ki -> 0), each loop's
    margins on a dense Nyquist grid and its step by tests/reference.py's matrix-exponential simulation."""
    num, den, dt = [0.4545825701696426], [6.114957039808562, 1.0, 0.0], 0.2235
    spec = Spec.thesis()
    best = math.inf
    for kp in np.linspace(0.13, 0.16, 61):  # around the overshoot-at-the-band edge (P loops: PM 70 to 67 deg)
        m = ref.nyquist_margins(*ref.open_loop(num, den, [kp], [1.0], dt), dt, n=20_000)
        t, y = ref.closed_loop_step(num, den, [kp], [1.0], dt, n_per_sample=10, samples=600)
        if m["pm"] >= 60 and m["gm_db"] >= 6 and (np.max(y) - 1) * 100 < 10:
            best = min(best, ref.settling_time(t, y, 1.0))
    assert 34.0 < best < 35.2  # the stored reference (34.61 s) is on this plateau
    res = tune(Plant(np.array(num), np.array(den)), structure="pi", dt=dt, seed=0, spec=spec, diagnose=False,
               time_budget_s=120)
    assert res.meets_spec
    assert res.objective <= 1.01 * best
    ki = res.gains["Ki"]
    assert 0 < ki < 1e-3 * res.gains["Kp"]  # a vanishing integral of the stabilising sign
    c = res.controller
    gn, gd = ref.zoh(num, den, dt)
    assert np.all(np.abs(np.roots(np.polyadd(np.polymul(c.den, gd), np.polymul(c.num, gn)))) < 1)
    m = ref.nyquist_margins(*ref.open_loop(num, den, c.num, c.den, dt), dt, n=60_000)
    assert m["pm"] >= 60 - 0.05 and m["gm_db"] >= 6 - 0.02 and m["gml_db"] <= -6 + 0.02
    # the slow pole's tail (residue about Ki / (K Kp^2)) stays inside the band: over 335 s (ten settling times)
    # the independent simulation settles where the verifier does
    t, y = ref.closed_loop_step(num, den, c.num, c.den, dt, n_per_sample=10, samples=1500)
    assert (np.max(y) - 1) * 100 <= 10 + 0.02
    assert ref.settling_time(t, y, 1.0) == pytest.approx(res.objective, abs=dt / 10)


def _suite_case(cid: str):
    from pathlib import Path

    bench = Path(__file__).resolve().parents[2] / "bench"
    cases = {c["id"]: c for c in json.loads((bench / "quality_suite.json").read_text())["cases"]}
    refs = {r["id"]: r for r in json.loads((bench / "quality_reference.json").read_text())["references"]}
    return cases[cid], refs[cid]


@pytest.mark.slow
@pytest.mark.parametrize("cid", ["integrating-03", "integrating-11", "integrating-00", "integrating-04",
                                 "integrating-24", "integrating-10", "integrating-18"])
def test_integrating_plants_reach_their_references(cid):
    """K/(s (tau s + 1)) under the thesis spec, default effort: within 1 % of the stored reference (long DE + CMA-ES,
    verified twice; bench/quality_reference.json). PI (03, 11): the vanishing-integral plateau (they were 24.5 and
    21.4 times the reference); PD and PID (00, 04, 24, 10, 18): the loop gain where the overshoot reaches the band
    (they were 1.1-1.9 % above it)."""
    c, r = _suite_case(cid)
    assert r["feasible"] and r["independent_ok"]
    plant = Plant(np.array(c["num"], float), np.array(c["den"], float), delay_s=float(c["delay_s"]))
    res = tune(plant, structure=c["structure"], dt=c["dt"], seed=0, spec=Spec.thesis(), diagnose=False,
               time_budget_s=120)
    assert res.meets_spec
    assert res.objective <= 1.01 * r["objective"], f"{cid}: {res.objective:.5g} vs {r['objective']:.5g}"


@pytest.mark.slow
def test_the_nlp_keeps_a_vanishing_integral_stabilising():
    """A refinement from a P with a vanishing integral (PI on 0.4546/(s (6.115 s + 1)), dt 0.2235): Ki of the other
    sign puts a closed-loop pole outside the unit circle (the characteristic polynomial's value at z = 1 is Ki dt
    n_p(1)), too slow for the NLP's horizon to show; every candidate keeps Ki > 0 (the sign) and at least 1e-3 of
    the start's."""
    from tuner.optimize.batch import BatchEvaluator
    from tuner.optimize.nlp.refine import refine
    from tuner.optimize.space import make_space
    from tuner.problem import TuningProblem

    num, den, dt = [0.4545825701696426], [6.114957039808562, 1.0, 0.0], 0.2235
    prob = TuningProblem.build([Plant(np.array(num), np.array(den))], structure="pi", spec=Spec.thesis(), dt=dt)
    space = make_space(prob.structure, prob.nominal, dt, scale=prob.scale)
    batch = BatchEvaluator(prob, space)
    ki0 = 1e-6
    res = refine(batch, space, space.from_params(np.array([0.13, ki0])), fine=True)
    assert res.candidates
    for v in res.candidates:
        kp, ki = space.params(v)
        assert ki >= 1e-3 * ki0 * (1 - 1e-9)
    # and the refinement is of use: a candidate meets the spec at the search's resolution (it used to end with
    # every candidate's integral at or below zero: unstable, or marginal at Ki = 0)
    assert np.min(batch.evaluate(np.array([space.params(v) for v in res.candidates])).score) < 1e3

BENCH = Path(__file__).resolve().parents[2] / "bench"


@pytest.mark.slow
@pytest.mark.parametrize("cid", ["unstable-05", "unstable-17", "unstable-25"])
def test_unstable_plants_reach_the_reference(cid):
    """bench/quality.py's unstable cases that missed (thesis spec, seed 0): pid_z on 2.734/(0.803 s^2 + 1.467 s - 1)
    at dt 0.04346 (unstable-05: the loop crosses over at wc dt = 0.5 yet settles in ~50 samples; the NLP held the
    overshoot at the samples and its solutions peaked above 10 % between them: 5.89 s), pid_z on
    1.521/(0.0156 s^2 + 0.520 s - 1) at dt 0.01418 (unstable-17: poles +1.8 and -35 rad/s; every designed start
    overshot 12-60 %: no design met the spec), PID on 3.503/(28.74 s^2 + 7.93 s - 1) at dt 0.33 (unstable-25: the
    overshoot limit active at the polish's answer, which the NLP kept 0.5 % inside the batch's: 1.4 % above the
    reference). Each within 1 % of the stored reference (differential evolution
    + CMA-ES, verified independently), and the loop checked here: margins on a dense Nyquist grid, the step
    simulated at 20 points a sample (the peak between the samples)."""
    cases = {c["id"]: c for c in json.loads((BENCH / "quality_suite.json").read_text())["cases"]}
    refs = {r["id"]: r for r in json.loads((BENCH / "quality_reference.json").read_text())["references"]}
    c, r = cases[cid], refs[cid]
    assert r["feasible"] and r["independent_ok"]
    spec = Spec.thesis()
    plant = Plant(np.array(c["num"], float), np.array(c["den"], float), delay_s=float(c["delay_s"]))
    res = tune(plant, structure=c["structure"], dt=c["dt"], spec=spec, seed=0, diagnose=False, time_budget_s=120)
    assert res.meets_spec, f"{cid}: no design meets the spec (the reference has {r['objective']:.5g})"
    assert res.objective <= 1.01 * r["objective"], (cid, res.objective, r["objective"], res.gains, r["gains"])
    ind = _independent(c["num"], c["den"], res, spec, horizon_s=max(20.0, 10 * r["objective"]))
    assert ind["pm"] >= 60 - 0.05 and ind["gm"] >= 6 - 0.02 and ind["gml"] <= -6 + 0.02
    assert ind["overshoot"] <= 10 + 0.02
    assert ind["settling"] == pytest.approx(res.objective, abs=c["dt"] / 10)


@pytest.mark.slow
def test_pi_on_a_lightly_damped_plant_stays_in_its_basin():
    """bench/quality.py's underdamped-10: PI on 4.090/(s^2 + 1.543 s + 4.925) (zeta 0.35) at dt 0.01009, thesis
    spec. Two basins: Kp > 0 (the stored reference, differential evolution + CMA-ES: Kp 0.586, Ki 1.084, 5.697 s)
    and Kp < 0 (5.80 s). The designed start in the first (Kp 0.50, Ki 1.13, settling 6.69 s) left it on the
    refinement's first solve; the tune must be within 1 % of the reference, checked here independently."""
    refs = {r["id"]: r for r in json.loads((BENCH / "quality_reference.json").read_text())["references"]}
    r = refs["underdamped-10"]
    assert r["feasible"] and r["independent_ok"] and r["objective"] == pytest.approx(5.697, abs=1e-3)
    spec = Spec.thesis()
    num, den = [4.09020001982652], [1.0, 1.5432062230171781, 4.92474199765871]
    res = tune(Plant(np.array(num), np.array(den)), structure="pi", dt=0.01009, spec=spec, seed=0, diagnose=False,
               time_budget_s=120)
    assert res.meets_spec and res.objective <= 1.01 * r["objective"], (res.objective, res.gains)
    ind = _independent(num, den, res, spec)
    assert ind["pm"] >= 60 - 0.05 and ind["gm"] >= 6 - 0.02 and ind["overshoot"] <= 10 + 0.02
    assert ind["settling"] == pytest.approx(res.objective, abs=0.01009 / 10)


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_the_convergence_claim_rests_on_restart_evidence():
    """Issue 41: "converged" on a principle, not a suite: multistart's Bayesian stopping rule (Boender and Rinnooy Kan
    1987). After n restart draws reached w distinct optima, the posterior expected relative volume of the regions of
    attraction not reached is w (w + 1) / (n (n - 1)); the claim needs it at most UNSEEN_LEVEL and Effort.refind draws
    that reached the answer's value (the restart that first found it does not count); optima are counted by value,
    so two draws close in the box with different scores are two optima; a cut search claims nothing. Each condition
    is set here on a finished search's own record, the estimate counted by hand."""
    import copy
    import time as _time

    from tuner.optimize.engine import UNSEEN_LEVEL, Engine
    from tuner.problem import TuningProblem

    problem = TuningProblem.build(plant_from_expr("1/(s+1)^2"), structure="pi", spec=Spec.thesis(), dt=0.1)
    eng = Engine(problem, seed=0, deadline=_time.perf_counter() + 120)
    eng.run()
    assert eng.info.stop in ("converged", "work") and eng.restarts >= eng.effort.refind == 2
    b, v = eng.best.score, eng.best.v
    assert b < 1e3  # (feasible: its optima are counted by value)
    span = eng.space.hi - eng.space.lo
    far1 = np.where(v > 0.5 * (eng.space.lo + eng.space.hi), eng.space.lo, eng.space.hi)  # another corner
    far2 = np.clip(v + 0.3 * span * np.sign(0.5 * (eng.space.lo + eng.space.hi) - v + 1e-9), eng.space.lo,
                   eng.space.hi)

    def with_ends(ends, *, stop="converged", round0=None):
        e = copy.copy(eng)
        e.info = copy.copy(eng.info)
        e.info.stop = stop
        e.restart_ends = [t if len(t) == 4 else (*t, True) for t in ends]  # (resolved unless said)
        if round0 is not None:
            e.refined, e._round0_refined = round0, len(round0)
        return e

    near = v + 1e-3 * span  # the same basin (0.1 % of the box away)
    # four draws all reached the answer's value: w = 1, n = 4: 1 * 2 / (4 * 3) = 1/6 <= 0.2
    ok = with_ends([(1, b, near), (2, b * 1.0001, v), (3, b, v), (4, b, near)], round0=[(b, v)])
    o = ok.optimality()
    assert o["evidence"] == {"refinements": 4, "basins": 1, "refound": 4, "singletons": 0, "good_turing": 0.0,
                             "unseen": pytest.approx(1 / 6), "level": UNSEEN_LEVEL, "refind": 2, "holds": True}
    assert o["claim"] == "converged"
    assert "unreached-basin estimate 0.17" in optimality_line({"optimality": o, "stop": "converged"})
    # three draws in one optimum are not enough (1 * 2 / (3 * 2) = 1/3), nor is one draw (unknown: 1)
    three = with_ends([(1, b, near), (2, b, v), (3, b, v)], round0=[(b, v)])
    assert three.optimality()["evidence"]["unseen"] == pytest.approx(1 / 3)
    assert three.optimality()["claim"] == "not confirmed"
    assert with_ends([(1, b, v)], round0=[(b, v)]).optimality()["evidence"]["unseen"] == 1.0
    # the same four and two other optima reached (worse, elsewhere): w = 3, n = 6: 3 * 4 / (6 * 5) = 0.4
    wide = with_ends([(1, b, near), (2, b, v), (3, b, v), (4, b, near), (5, 3 * b, far1), (6, 5 * b, far2)],
                     round0=[(b, v)])
    o = wide.optimality()
    assert (o["evidence"]["basins"], o["evidence"]["singletons"], o["evidence"]["refinements"]) == (3, 2, 6)
    assert o["evidence"]["unseen"] == pytest.approx(0.4) and o["claim"] == "not confirmed"
    res_line = optimality_line({"optimality": o, "stop": "converged"})
    assert "not confirmed" in res_line and "not reached is 0.4" in res_line and "3 optima reached by 6" in res_line
    # a draw beside the answer (0.1 % of the box away) whose value is 2 % worse reached another optimum: counted apart
    close = with_ends([(1, b, near), (2, b, v), (3, b, v), (4, 1.02 * b, near)], round0=[(b, v)])
    o = close.optimality()
    assert o["evidence"]["basins"] == 2 and o["evidence"]["refound"] == 3 and o["claim"] == "not confirmed"
    # one draw re-found the answer's value: not enough, whatever the estimate
    one = with_ends([(1, b, near)] + [(k, 3 * b, far1) for k in range(2, 9)], round0=[(b, v)])
    o = one.optimality()
    assert o["evidence"]["refound"] == 1 and o["evidence"]["unseen"] == pytest.approx(2 * 3 / (8 * 7))
    assert o["claim"] == "not confirmed"
    assert "1 restart re-found the answer's basin, of the 2" in optimality_line({"optimality": o})
    # the optimum first found by restart 1 (round 0 never reached it): restarts 2-4 re-found it, restart 1 did not
    first = with_ends([(1, b, v), (2, b, near), (3, b, v), (4, b, v)], round0=[(3 * b, far1)])
    assert first.optimality()["evidence"]["refound"] == 3 and first.optimality()["claim"] == "converged"
    assert with_ends([(1, b, v), (2, b, near)], round0=[(3 * b, far1)]).optimality()["evidence"]["refound"] == 1
    # draws cut above the incumbent's value (Effort.draw_cutoff): each an optimum of its own, never merged with another
    # draw's (not even one of equal score, resolved or not) and never a re-find, whatever its score says: w = 5 here
    # (the answer's; each cut draw; the resolved draw at 3 b, which a cut draw at that score does not absorb), not 2
    cut = with_ends([(1, b, near), (2, b, v), (3, 3 * b, far1, False), (4, 3 * b, far1, False),
                     (5, 3 * b, far1), (6, b, v, False)], round0=[(b, v)])
    ev = cut.optimality()["evidence"]
    assert (ev["basins"], ev["refound"], ev["refinements"]) == (5, 2, 6)
    assert ev["unseen"] == 1.0 and cut.optimality()["claim"] == "not confirmed"
    resolved = with_ends([(1, b, near), (2, b, v), (3, 3 * b, far1), (4, 3 * b, far1), (5, 3 * b, far1), (6, b, v)],
                         round0=[(b, v)]).optimality()["evidence"]
    assert (resolved["basins"], resolved["refound"]) == (2, 3)  # (the same draws resolved: two optima)
    # a search the cap cut claims nothing, whatever its evidence
    assert with_ends(ok.restart_ends, stop="budget", round0=[(b, v)]).optimality()["claim"] == "budget"
    # fast: round 0's own agreement, no restart: not confirmed, and says why
    res = tune(plant_from_expr("1/(s+1)^2"), structure="pi", dt=0.1, seed=0, effort="fast", diagnose=False)
    assert res.solver["stop"] == "converged" and res.solver["converged"] is False
    assert "not confirmed: no independent restart ran" in res.solver["optimality"]["summary"]


def test_a_restart_refines_the_candidate_farthest_from_what_was_refined():
    """Issue 30: a restart's lone refinement (default effort) goes to the one of the best distinct candidates farthest
    from every refined point (Effort.restart_spread), not to the best-scoring one beside a start already refined, and
    never to one that fails the spec while the best meets it; with no spread (thorough) the best-scoring one.
    Candidates placed by hand in a PID's box: ``near`` beside the refined start, ``far`` a little worse and far from
    it, ``mid`` much worse, ``bad`` farthest of all but failing the spec (a score above INFEASIBLE)."""
    import time as _time

    from tuner.limits import INFEASIBLE
    from tuner.optimize.engine import EFFORTS, Engine
    from tuner.problem import TuningProblem

    assert EFFORTS["default"].restart_spread > 0 and EFFORTS["thorough"].restart_spread == 0
    problem = TuningProblem.build(plant_from_expr("1/(s+1)^3"), structure="pid", spec=Spec.thesis(), dt=0.1)
    eng = Engine(problem, seed=0, deadline=_time.perf_counter() + 60)
    lo, hi = eng.space.lo, eng.space.hi
    refined = lo + 0.3 * (hi - lo)
    near = refined + 0.06 * (hi - lo) * np.eye(lo.size)[0]  # distinct (> 0.05 of the span), but beside it
    far = lo + 0.8 * (hi - lo)
    mid = lo + 0.5 * (hi - lo)
    eng.pool = [(1.0, refined, True), (1.5, near, False), (1.6, far, False), (9.0, mid, False)]
    assert np.array_equal(eng._distinct(1)[0], near)  # the best-scoring one
    assert np.array_equal(eng._distinct(1, spread=3)[0], far)  # the farthest of the best four
    # two of the best three, greedily: the farthest, then the one farthest from it and the refined start
    assert [v.tolist() for v in eng._distinct(2, spread=1)] == [far.tolist(), mid.tolist()]
    assert [v.tolist() for v in eng._distinct(2, spread=0)] == [near.tolist(), far.tolist()]
    bad = lo + 0.99 * (hi - lo)
    eng.pool = [(1.0, refined, True), (1.5, near, False), (10 * INFEASIBLE, bad, False), (1.6, far, False)]
    assert np.array_equal(eng._distinct(1, spread=3)[0], far)  # not the farther one that fails the spec
    eng.pool = [(1.0, refined, True), (1.5, near, False), (10 * INFEASIBLE, bad, False)]
    assert np.array_equal(eng._distinct(1, spread=3)[0], near)  # the best, when no other candidate meets the spec
    assert np.array_equal(eng._distinct(1, spread=0)[0], near)


def _long_search_reference(cid: str, structure: str, dt: float, num, den, delay_samples: int = 0,
                           horizon_s: float = 40.0) -> tuple[float, dict[str, float]]:
    """The long search's design for a convergence-suite case (bench/convergence_reference.json: the engine at an
    effort far beyond thorough, two seeds, 60 s each): its controller's transfer function (the structure's, from
    tuner), then the loop checked here without tuner: its margins on a dense Nyquist grid and its step simulated
    between the samples; returns that settling time and the gains."""
    from types import SimpleNamespace

    from tuner.controllers import get_structure

    refs = json.loads((BENCH / "convergence_reference.json").read_text())["references"]
    gains = refs[cid]["runs"][refs[cid]["source"]]["gains"]
    spec = Spec.thesis()
    ctrl = get_structure(structure).tf(gains, dt)
    ind = _independent(num, den, SimpleNamespace(controller=ctrl), spec, horizon_s=horizon_s,
                       delay_samples=delay_samples)
    assert ind["pm"] >= 60 - 0.05 and ind["gm"] >= 6 - 0.02 and ind["gml"] <= -6 + 0.02, ind
    assert ind["overshoot"] <= 10 + 0.02, ind
    return ind["settling"], gains


@pytest.mark.slow
def test_pi_on_a_lightly_damped_third_order_plant_finds_the_negative_proportional_basin():
    """bench/convergence.py's underdamped-31: PI on 0.2430/(0.4838 s^3 + 1.182 s^2 + 0.6050 s + 0.4734) at dt
    0.03506, thesis spec. The optimum is an integral controller with Kp < 0 (the long search: Kp -0.527, Ki 0.198,
    21.92 s, on the edge of a margin: a few thousandths of Kp or Ki away it settles in 28.8 s or fails the spec, so
    no grid finds it); the designed starts with Kp > 0 refine to 23.19 s, where the default effort claimed
    convergence (5.8 % short) before the PI's starts included Kp flipped. The default tune must be within 1 % of the
    long search's design, and its loop is checked here too."""
    num, den, dt = [0.24301464336737416], [0.4837881732493822, 1.181895326149685, 0.6049859008731137,
                                           0.47335708583230707], 0.03506
    ref_s, ref_g = _long_search_reference("underdamped-31", "pi", dt, num, den)
    assert ref_g["Kp"] < 0 and ref_s < 22.0, (ref_s, ref_g)
    res = tune(Plant(np.array(num), np.array(den)), structure="pi", dt=dt, spec=Spec.thesis(), seed=0, diagnose=False)
    assert res.meets_spec and res.gains["Kp"] < 0
    assert res.objective <= 1.01 * ref_s, (res.objective, res.gains, ref_s)
    ind = _independent(num, den, res, Spec.thesis(), horizon_s=40.0)
    assert ind["pm"] >= 60 - 0.05 and ind["gm"] >= 6 - 0.02 and ind["overshoot"] <= 10 + 0.02, ind
    assert ind["settling"] == pytest.approx(res.objective, abs=dt / 10)


@pytest.mark.slow
def test_pid_on_a_non_minimum_phase_plant_finds_the_lag_filter_basin():
    """bench/convergence.py's nmp-19: PID on (-0.1789 s + 2.494)/(0.005868 s^2 + 0.1963 s + 1) at dt 0.02033, thesis
    spec. The optimum's derivative filter is slower than its derivative time (the long search: Tf 0.107 s, Td = Kd /
    Kp 0.039 s, 0.2679 s); the textbook filters' starts (Tf = Td / 10 ... Td / 3) refine to 0.2838 s, where the
    default effort stopped (5.9 % short) before its restart refined the start with Tf = Td. The default tune must be
    within 1 % of the long search's design, and its loop is checked here too."""
    num, den, dt = [-0.1788840154643558, 2.4943532667996986], [0.005867887276756524, 0.19629370854256195, 1.0], \
        0.02033
    ref_s, ref_g = _long_search_reference("nmp-19", "pid", dt, num, den)
    assert ref_g["Tf"] > ref_g["Kd"] / ref_g["Kp"] and ref_s < 0.275, (ref_s, ref_g)
    res = tune(Plant(np.array(num), np.array(den)), structure="pid", dt=dt, spec=Spec.thesis(), seed=0, diagnose=False)
    assert res.meets_spec and res.gains["Tf"] > res.gains["Kd"] / res.gains["Kp"]
    assert res.objective <= 1.01 * ref_s, (res.objective, res.gains, ref_s)
    ind = _independent(num, den, res, Spec.thesis())
    assert ind["pm"] >= 60 - 0.05 and ind["gm"] >= 6 - 0.02 and ind["overshoot"] <= 10 + 0.02, ind
    assert ind["settling"] == pytest.approx(res.objective, abs=dt / 10)


@pytest.mark.slow
def test_pid_on_a_slow_non_minimum_phase_plant_finds_the_filter_slower_than_its_derivative_time():
    """bench/convergence.py's nmpfast-19 (issue 41's held-out part, no longer held out: this case named the change):
    PID on 1.034 (1 - 17.62 s)/(239.3 s^2 + 30.98 s + 1) at dt 0.6466, thesis spec, its right-half-plane zero
    (0.057 rad/s) near its poles (0.061 and 0.068 rad/s). The optimum's derivative filter is twice its derivative
    time (the long search: Kd 11.0, Kp 0.408, Td 27 s, Tf 56 s; 66.33 s), a lead-lag the filtered starts
    (Tf = Td / N, N = 10, 3, 1) did not refine into: the default effort ended at 69.04 s (4.1 % short, "not
    confirmed") with Tf at its floor. The starts' filters on a half-decade grid down to N = 0.3 (Tf = 3.3 Td,
    engine.FILTER_N) reach it. The default tune must be within 1 % of the long search's design, checked without
    tuner as its own loop is."""
    num, den, dt = [-18.227571466264397, 1.034412596976189], [239.3483880055146, 30.980318893774754, 1.0], 0.6466
    ref_s, ref_g = _long_search_reference("nmpfast-19", "pid", dt, num, den, horizon_s=400.0)
    assert ref_g["Tf"] > ref_g["Kd"] / ref_g["Kp"] and ref_s < 67.0, (ref_s, ref_g)
    res = tune(Plant(np.array(num), np.array(den)), structure="pid", dt=dt, spec=Spec.thesis(), seed=0, diagnose=False)
    assert res.meets_spec and res.gains["Tf"] > res.gains["Kd"] / res.gains["Kp"], res.gains
    assert res.objective <= 1.01 * ref_s, (res.objective, res.gains, ref_s)
    ind = _independent(num, den, res, Spec.thesis(), horizon_s=400.0)
    assert ind["pm"] >= 60 - 0.05 and ind["gm"] >= 6 - 0.02 and ind["overshoot"] <= 10 + 0.02, ind
    assert ind["settling"] == pytest.approx(res.objective, abs=dt / 10)


@pytest.mark.slow
def test_default_resolves_the_optimum_to_within_one_percent_on_an_integrator_with_four_samples_of_delay():
    """bench/convergence.py's intdelay4-02 (design part): ``pid_z`` on 0.8103/(s (1.2034 s + 1)) with 4 samples of
    dead time at dt 0.086, thesis spec. The default search reaches the optimum's basin, but its polish at the grid's
    plain detail resolved the settling time to about 1 % only and stopped at 1.442 s, 1.8 % above the long search's
    1.4169 s (the same basin: K 23.1 a1 -1.942 a2 0.942); ``Effort.polish_detail`` 2 (the sharp polish) resolves it.
    The default tune must be within 1 % of the long search's design (checked here without tuner, its delay too), and
    its own loop is checked the same way."""
    num, den, dt, d = [0.810310177507416], [1.203407723185006, 1.0, 0.0], 0.086, 4
    ref_s, ref_g = _long_search_reference("intdelay4-02", "pid_z", dt, num, den, delay_samples=d)
    assert ref_s < 1.43, (ref_s, ref_g)
    res = tune(Plant(np.array(num), np.array(den), delay_s=d * dt), structure="pid_z", dt=dt, spec=Spec.thesis(),
               seed=0, diagnose=False)
    assert res.meets_spec
    assert res.objective <= 1.01 * ref_s, (res.objective, res.gains, ref_s)
    ind = _independent(num, den, res, Spec.thesis(), horizon_s=40.0, delay_samples=d)
    assert ind["pm"] >= 60 - 0.05 and ind["gm"] >= 6 - 0.02 and ind["overshoot"] <= 10 + 0.02, ind
    assert ind["settling"] == pytest.approx(res.objective, abs=dt / 10)
