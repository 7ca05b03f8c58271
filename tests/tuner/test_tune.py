"""tuner.tune end to end: every number it reports is re-derived here.

For each result the tests re-run the verifier independently (``analyze(plant, controller, spec)``)
and require the reported metrics and checks to be equal, rebuild the controller from the
reported gains (``get_structure(s).tf(gains, dt)``), and for the thesis loops also recompute
margins and step metrics a third way with ``tests/reference.py`` (dense Nyquist grid, matrix-
exponential simulation between samples; no ``tuner`` code).

Budgets are generous (``BUDGET``) so the search is never cut short by the clock: results are
deterministic and the tests never assert wall time.
"""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np
import pytest
import reference as ref
from quadrotor import DT, PITCH, ROLL, YAW
from scipy import signal

from tuner.analysis.verify import analyze
from tuner.controllers import get_structure
from tuner.errors import TunerError
from tuner.jsonio import jsonable
from tuner.plant import make_plant, plant_from_expr
from tuner.spec import Spec
from tuner.tuning import tune

THESIS = Spec.thesis()  # this module tests the thesis problem (issue 18's default limits: test_flyable.py)

BUDGET = 120.0  # s; a tune takes a few seconds: the budget is never what stops the search

# raw coefficients of the thesis models (quadrotor.md), for the independent reference computations
RAW = {
    "roll": ([0.2655 * 14.8528**2], [1, 14.195, 14.8528**2]),
    "pitch": ([0.377568 * 3.5184**2], [1, 2 * 0.5006 * 3.5184, 3.5184**2]),
    "yaw": ([0.2843 * 18.611], [1, 18.611]),
}
EXPR = {"roll": ROLL, "pitch": PITCH, "yaw": YAW}
THESIS_SETTLING = {"roll": 0.5, "pitch": 0.5, "yaw": 2.0}  # s, quadrotor.md


def _same(a, b, rel=1e-9):
    """Equal floats (NaN == NaN, inf == inf), or equal other values."""
    if isinstance(a, (float, np.floating)) or isinstance(b, (float, np.floating)):
        a, b = float(a), float(b)
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)
        if math.isinf(a) or math.isinf(b):
            return a == b
        return math.isclose(a, b, rel_tol=rel, abs_tol=1e-12)
    return a == b


def oracle_loop(plant, c):
    """The open loop C*G as num/den by tests/reference.py (ZOH by the matrix exponential, a delay of whole
    samples as z^-k); None for a continuous loop with a delay (no rational form)."""
    dt = c.dt
    if plant.delay_s and dt is None:
        return None
    num, den = ref.open_loop(plant.num, plant.den, c.num, c.den, dt=dt, plant_is_discrete=plant.is_discrete)
    if plant.delay_s:
        k = round(plant.delay_s / dt)
        den = np.polymul(den, np.r_[1.0, np.zeros(k)])
    return num, den


def assert_matches_oracle(metrics, plant, c):
    """Stability, phase and gain margins and Ms of the reported metrics against the independent oracles of
    tests/reference.py (closed-loop roots, a dense Nyquist grid), not against the library's own analyze()."""
    loop = oracle_loop(plant, c)
    if loop is None:
        return
    num, den = loop
    assert metrics.stable == ref.stable_at_gain(num, den, 1.0, c.dt)
    if not metrics.stable:
        return
    m = ref.nyquist_margins(num, den, c.dt)
    assert _same(metrics.phase_margin_deg, m["pm"]) or abs(metrics.phase_margin_deg - m["pm"]) < 0.05, (
        metrics.phase_margin_deg, m["pm"])
    for got, want in ((metrics.gain_margin_db, m["gm_db"]), (metrics.gain_margin_lower_db, m["gml_db"])):
        assert _same(got, want) or abs(got - want) < 0.05, (got, want)
    assert metrics.ms == pytest.approx(ref.ms_bruteforce(m["L"]), rel=1e-3)


def assert_reported_is_verified(result, plants, spec=None):
    """The result's numbers are the verifier's: an independent analyze() of the reported controller on
    every plant gives the same metrics and checks, the controller is the structure's TF of the gains, and
    stability, margins and Ms agree with the oracles of tests/reference.py (no tuner code)."""
    spec = spec or Spec()
    plants = plants if isinstance(plants, (list, tuple)) else [plants]
    c = result.controller
    rebuilt = get_structure(result.structure).tf(result.gains, c.dt)
    np.testing.assert_allclose(c.num, rebuilt.num, rtol=1e-12, atol=0)
    np.testing.assert_allclose(c.den, rebuilt.den, rtol=1e-12, atol=0)
    assert c.dt == rebuilt.dt
    assert set(result.gains) == set(get_structure(result.structure).params)
    assert len(result.analyses) == len(plants)
    indep = [analyze(p, c, spec) for p in plants]
    for got, want in zip(result.analyses, indep):
        gm, wm = asdict(got.metrics), asdict(want.metrics)
        bad = {k: (gm[k], wm[k]) for k in wm if not _same(gm[k], wm[k])}
        assert not bad, f"reported metrics differ from an independent analyze(): {bad}"
        assert [(ch.name, ch.ok) for ch in got.checks] == [(ch.name, ch.ok) for ch in want.checks]
        for g, w in zip(got.checks, want.checks):
            assert _same(g.achieved, w.achieved) and _same(g.violation, w.violation), (g, w)
    for p, got in zip(plants, result.analyses):
        assert_matches_oracle(got.metrics, p, c)
    # meets_spec is the conjunction of the independent judgements, and to_dict says the same
    assert result.meets_spec == all(a.meets_spec for a in indep)
    d = result.to_dict()
    assert d["meets_spec"] == result.meets_spec
    assert d["failing"] == sorted({ch.name for a in indep for ch in a.failing})
    assert d["gains"] == result.gains
    assert d["controller"] == {"num": list(map(float, c.num)), "den": list(map(float, c.den)), "dt": c.dt}
    nominal = indep[0].to_dict()
    assert jsonable(d["metrics"]) == jsonable(nominal["metrics"])
    if len(plants) > 1:
        assert [p["meets_spec"] for p in d["plants"]] == [a.meets_spec for a in indep]
    return indep


def reference_loop_figures(raw, controller, dt, horizon_s=5.0, n_per_sample=20):
    """PM, GM, stability, overshoot and 2 % settling time of the sampled-data loop, without tuner.

    The control sequence comes from the closed loop C/(1 + C G_zoh) (scipy lfilter); the plant output
    between samples from the matrix exponential of the continuous plant driven by that staircase.
    """
    gnum, gden = raw
    ln, ld = ref.open_loop(gnum, gden, controller.num, controller.den, dt=dt)
    nm = ref.nyquist_margins(ln, ld, dt)
    stable = ref.stable_at_gain(ln, ld, 1.0, dt)
    _, gzd = ref.zoh(gnum, gden, dt)
    u_num = np.polymul(controller.num, gzd)
    cp = np.polyadd(ld, ln)
    u_num = np.concatenate([np.zeros(cp.size - u_num.size), u_num])
    k = int(round(horizon_s / dt))
    u = signal.lfilter(u_num, cp, np.ones(k))
    t, y = ref.fine_step(gnum, gden, u, dt, n_per_sample)
    yf = 1.0  # zero steady-state error (integrating structures)
    return {"pm": nm["pm"], "gm_db": nm["gm_db"], "gml_db": nm["gml_db"], "stable": stable,
            "overshoot_pct": 100 * max(0.0, float(np.max(y)) - yf), "settling_s": ref.settling_time(t, y, yf),
            "u_final": float(u[-1])}


# -- the thesis loops: meet the spec, 3x faster than the thesis -----------------------------------

AXES = [("roll", "pid"), ("roll", "pid_z"), ("pitch", "pid"), ("pitch", "pid_z"), ("yaw", "pid"), ("yaw", "pid_z")]


@pytest.fixture(scope="module")
def tuned():
    """tuned(axis, structure) -> (plant, result); each tune runs once per module (and worker)."""
    cache = {}

    def get(name, structure):
        if (name, structure) not in cache:
            plant = plant_from_expr(EXPR[name])
            cache[name, structure] = plant, tune(plant, structure=structure, dt=DT, seed=0, time_budget_s=BUDGET,
                                                 spec=THESIS)
        return cache[name, structure]

    return get


@pytest.mark.parametrize("name,structure", AXES)
def test_thesis_axis_meets_spec_three_times_faster(tuned, name, structure):
    plant, res = tuned(name, structure)
    indep = assert_reported_is_verified(res, plant)
    m = indep[0].metrics
    assert res.meets_spec, f"{name}/{structure} fails {[c.name for c in indep[0].failing]}"
    # the spec, read off the independent analysis
    assert m.stable and m.phase_margin_deg >= 60 and m.gain_margin_db >= 6 and m.overshoot_pct <= 10
    assert abs(m.steady_state_error) <= 1e-6
    # at least 3x faster than the thesis (roll, pitch 0.5 s -> 0.1667 s; yaw 2 s -> 0.6667 s);
    # at the time of writing: roll 0.118 s (pid, pid_z), pitch 0.138 s (pid, pid_z), yaw 0.039 s (pid) and
    # 0.122 s (pid_z; 0.039 s with 60 global trials, see test_pid_z_reaches_what_pid_reaches)
    limit = THESIS_SETTLING[name] / 3
    assert m.settling_time_s <= limit, (
        f"{name}/{structure}: settling {m.settling_time_s:.4f} s > {limit:.4f} s (thesis/3); gains {res.gains}")


@pytest.mark.parametrize("name,structure", AXES)
def test_thesis_axis_figures_agree_with_an_independent_simulation(tuned, name, structure):
    """PM/GM from a 250k-point Nyquist evaluation, overshoot and settling from a matrix-exponential
    simulation between samples (20 points per sample), all outside the library."""
    _, res = tuned(name, structure)
    m = res.analyses[0].metrics
    r = reference_loop_figures(RAW[name], res.controller, DT)
    assert r["stable"] == m.stable is True
    assert r["pm"] == pytest.approx(m.phase_margin_deg, abs=0.05)
    assert r["gm_db"] == pytest.approx(m.gain_margin_db, abs=0.05)
    assert r["overshoot_pct"] == pytest.approx(m.overshoot_pct, abs=0.1)
    assert r["settling_s"] == pytest.approx(m.settling_time_s, abs=DT / 20)
    # u settles at 1/G(0): zero steady-state error through the integrator
    assert r["u_final"] == pytest.approx(RAW[name][1][-1] / RAW[name][0][-1], rel=1e-4)


@pytest.mark.parametrize("name,structure", AXES)
def test_solver_information(tuned, name, structure):
    _, res = tuned(name, structure)
    s = res.solver
    assert s["method"] == "optuna+casadi-sqp"
    assert s["seed"] == 0
    assert s["starts_tried"] >= 1 and s["nlp_iterations"] > 0 and s["nlp_evaluations"] > 0
    assert s["global_evaluations"] > 0 and s["wall_time_s"] > 0
    assert s["budget_exhausted"] is False  # the budget did not stop the search
    assert s["stop"] in ("converged", "work") and s["rounds"] >= 1 and s["cut"] is None
    # the search ended on its evidence rule or its work budget; the claim is "converged" only where the restarts'
    # evidence holds (issue 41), and otherwise the line says why and what would check it
    o = s["optimality"]
    assert o["claim"] in ("converged", "not confirmed") and s["converged"] is (o["claim"] == "converged")
    if o["claim"] == "not confirmed":
        assert "not confirmed: " in o["summary"] and "thorough effort" in o["summary"]
    else:
        assert o["evidence"]["holds"] and o["restarts"] >= 4 and "Bayesian rule" in o["summary"]
    assert res.structure == structure and res.spec == THESIS


@pytest.mark.parametrize("name", ["roll", "pitch", "yaw"])
def test_pid_reaches_what_pid_z_reaches(tuned, name):
    """pid at Tf = 0 contains the pid_z family: K(z^2 + a1 z + a2)/(z(z-1)) is the backward-Euler PID
    with Kd = K a2 dt, Kp = -K (a1 + 2 a2), Ki = K (1 + a1 + a2)/dt. pid's designed starts are pid_z's
    (Tf at its documented lower bound 1e-3 dt), so it must not end worse than pid_z by more than one sample
    (issue 10)."""
    _, pid = tuned(name, "pid")
    _, z = tuned(name, "pid_z")
    K, a1, a2 = z.gains["K"], z.gains["a1"], z.gains["a2"]
    as_pid = {"Kp": -K * (a1 + 2 * a2), "Ki": K * (1 + a1 + a2) / DT, "Kd": K * a2 * DT, "Tf": 0.0}
    c = get_structure("pid").tf(as_pid, DT)  # the pid_z design, written as a pid
    np.testing.assert_allclose(c.num, z.controller.num, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(c.den, z.controller.den, rtol=1e-9, atol=1e-12)
    ts_pid = pid.analyses[0].metrics.settling_time_s
    ts_z = z.analyses[0].metrics.settling_time_s
    assert ts_pid <= ts_z + DT, f"{name}: pid {ts_pid:.4f} s vs pid_z {ts_z:.4f} s (pid gains {pid.gains})"


@pytest.mark.parametrize("name", ["roll", "pitch", "yaw"])
def test_pid_z_reaches_what_pid_reaches(tuned, name):
    """The other direction: the pid design with its (tiny) derivative filter Tf set to 0 is a pid_z
    controller, K = Kp + Ki dt + Kd/dt, a1 = -(Kp + 2 Kd/dt)/K, a2 = Kd/(dt K). Verified here to meet
    the spec; the pid_z tune must then be no slower, up to the local-optimum slack (yaw measured
    2026-11-22: pid_z 0.0528 s against the projected pid design's 0.0395 s; one sample is 0.04 s, so the
    slack is one sample). A pid design whose filter is not negligible (the search starts filters at Td/N
    too: yaw's pid optimum has Tf = 0.2 s) is no pid_z controller; then the pid_z tune must be no slower
    than the pid tune itself, up to the same slack."""
    plant, pid = tuned(name, "pid")
    _, z = tuned(name, "pid_z")
    g = pid.gains
    ts_z = z.analyses[0].metrics.settling_time_s
    if g["Tf"] > 0.01 * DT:
        ts_pid = pid.analyses[0].metrics.settling_time_s
        assert pid.meets_spec and ts_z <= ts_pid + DT, f"{name}: pid_z {ts_z:.4f} s, pid {ts_pid:.4f} s ({g})"
        return
    K = g["Kp"] + g["Ki"] * DT + g["Kd"] / DT
    proj = {"K": K, "a1": -(g["Kp"] + 2 * g["Kd"] / DT) / K, "a2": g["Kd"] / DT / K}
    a = analyze(plant, get_structure("pid_z").tf(proj, DT))
    assert a.meets_spec, f"precondition: the pid design {g} with Tf = 0 should meet the spec"
    ts_proj = a.metrics.settling_time_s
    assert ts_z <= ts_proj + DT, (
        f"{name}: pid_z tuned to {ts_z:.4f} s ({z.gains}) but the pid_z controller {proj} settles in {ts_proj:.4f} s")


# -- determinism ---------------------------------------------------------------------------------

def test_same_seed_same_gains():
    plant = plant_from_expr(PITCH)
    r1 = tune(plant, structure="pid_z", dt=DT, seed=7, time_budget_s=BUDGET, spec=THESIS)
    r2 = tune(plant_from_expr(PITCH), structure="pid_z", dt=DT, seed=7, time_budget_s=BUDGET, spec=THESIS)
    assert r1.gains == r2.gains
    assert r1.solver["seed"] == r2.solver["seed"] == 7
    assert r1.solver["global_evaluations"] == r2.solver["global_evaluations"]
    assert r1.solver["nlp_iterations"] == r2.solver["nlp_iterations"]
    assert not r1.solver["budget_exhausted"] and not r2.solver["budget_exhausted"]
    np.testing.assert_array_equal(r1.controller.num, r2.controller.num)


# -- robust tuning -------------------------------------------------------------------------------

def roll_variant(gain=1.0, wn=1.0):
    """Roll with the gain scaled and the natural frequency scaled (damping ratio kept)."""
    k, w, c1 = 0.2655 * gain, 14.8528 * wn, 14.195 * wn
    return make_plant([k * w * w], [1, c1, w * w])


# nominal first; +-20 % gain and +-20 % natural frequency. The nominal-only design loses its phase
# margin on the slow member (wn x 0.8): at the time of writing PM 44.9 deg, overshoot 17.4 %.
ROBUST_SET = [(1.0, 1.0), (0.8, 1.0), (1.2, 1.0), (1.0, 0.8), (1.0, 1.2)]


@pytest.fixture(scope="module")
def robust():
    plants = [roll_variant(*m) for m in ROBUST_SET]
    rob = tune(plants, structure="pid_z", dt=DT, seed=0, time_budget_s=BUDGET, spec=THESIS)
    nom = tune(plants[0], structure="pid_z", dt=DT, seed=0, time_budget_s=BUDGET, spec=THESIS)
    return plants, rob, nom


@pytest.mark.slow
def test_robust_tune_meets_the_spec_on_every_member(robust):
    plants, rob, _ = robust
    indep = assert_reported_is_verified(rob, plants)
    for m, a in zip(ROBUST_SET, indep):
        assert a.meets_spec, f"member {m} fails {[(c.name, c.achieved) for c in a.failing]}"
    assert rob.meets_spec
    d = rob.to_dict()
    assert len(d["plants"]) == len(plants)
    # the objective is the worst case: the result's deciding analysis is the slowest member
    worst = max(a.metrics.settling_time_s for a in indep)
    assert rob.worst.metrics.settling_time_s == pytest.approx(worst, rel=1e-12)
    # at the time of writing: worst member 0.368 s (gain x 0.8)
    assert worst < 1.0


@pytest.mark.slow
def test_nominal_design_fails_on_the_plant_set(robust):
    plants, _, nom = robust
    assert_reported_is_verified(nom, plants[0])
    assert nom.meets_spec
    verdicts = [analyze(p, nom.controller) for p in plants]
    assert verdicts[0].meets_spec
    failing = {m: [c.name for c in a.failing] for m, a in zip(ROBUST_SET, verdicts) if not a.meets_spec}
    assert failing, "the nominal design should fail on some member of the set"
    for m, names in failing.items():
        a = verdicts[ROBUST_SET.index(m)]
        assert names and all(c.violation > 0 for c in a.failing)
        assert set(names) <= {c.name for c in a.checks} - {"settling_time_s"}
    # the slow member (wn x 0.8) is the one: its phase margin is below 60 deg
    slow = verdicts[ROBUST_SET.index((1.0, 0.8))]
    assert "phase_margin_deg" in [c.name for c in slow.failing]
    assert slow.metrics.phase_margin_deg < 60


# -- infeasible specifications -------------------------------------------------------------------

@pytest.fixture(scope="module")
def infeasible_peak():
    # Infeasible by construction: with zero steady-state error (pid_z has an integrator, so every
    # stable loop has it) the control settles at u(inf) = 1/G(0) = 1/0.2655 = 3.766, so
    # max |u| >= 3.766 > 1 for every controller that meets the other constraints.
    spec = Spec.thesis(control_peak_max=1.0)
    plant = plant_from_expr(ROLL)
    return plant, spec, tune(plant, structure="pid_z", dt=DT, spec=spec, seed=0, time_budget_s=BUDGET)


def test_infeasible_spec_is_reported_not_raised(infeasible_peak):
    plant, spec, res = infeasible_peak
    indep = assert_reported_is_verified(res, plant, spec)
    d = res.to_dict()
    assert d["meets_spec"] is False and res.meets_spec is False
    assert "control_peak" in d["failing"]
    failing = [c for c in d["checks"] if not c["ok"]]
    assert sorted(c["name"] for c in failing) == d["failing"]
    assert all(c["violation"] > 0 for c in failing)
    peak = next(c for c in d["checks"] if c["name"] == "control_peak")
    # by how much: at least 1/G(0) - 1 (see the fixture); the best found reaches that bound. The
    # verifier's peak is the max over a finite horizon, where u is still approaching 1/G(0) from
    # below (3.76620 vs 3.76648 at the time of writing): hence the 1e-3 relative slack.
    bound = 1 / 0.2655 - 1.0
    assert peak["violation"] >= bound * (1 - 1e-3)
    assert peak["violation"] == pytest.approx(peak["achieved"] - 1.0, rel=1e-12)
    assert peak["violation"] <= 1.05 * bound  # it found (close to) the smallest possible peak
    assert indep[0].metrics.stable
    jsonable(res.to_json())  # serialisable


@pytest.fixture(scope="module")
def infeasible_sse():
    # Infeasible by construction: a P controller on the type-0 plant 1/(s+1) leaves the steady-state
    # error 1/(1 + Kp) != 0 for every finite Kp. Every other constraint holds for any Kp > 0
    # (first-order loop: no overshoot, PM > 90 deg, no phase crossover), so the error shrinks
    # monotonically with Kp and the least-violating P controller is the largest gain the box allows.
    plant = make_plant([1], [1, 1])
    return plant, tune(plant, structure="p", seed=0, time_budget_s=BUDGET, spec=THESIS)


def test_infeasible_steady_state_error_names_the_constraint(infeasible_sse):
    plant, res = infeasible_sse
    assert_reported_is_verified(res, plant)
    d = res.to_dict()
    assert d["meets_spec"] is False
    assert d["failing"] == ["steady_state_error"]
    sse = next(c for c in d["checks"] if c["name"] == "steady_state_error")
    kp = res.gains["Kp"]
    assert sse["achieved"] == pytest.approx(abs(1 / (1 + kp)), rel=1e-6)  # re-derived from the gain
    assert sse["violation"] == pytest.approx(sse["achieved"] - 1e-6, rel=1e-9)
    assert sse["violation"] > 0


def test_infeasible_result_is_the_least_violating(infeasible_sse):
    """'Return the best found ... and by how much': Kp = 10 is inside the search box and meets every
    other constraint with a steady-state error of 1/11; the returned P controller must do no worse."""
    plant, res = infeasible_sse
    ref10 = analyze(plant, get_structure("p").tf({"Kp": 10.0}, None))
    assert [c.name for c in ref10.failing] == ["steady_state_error"]
    got = abs(res.analyses[0].metrics.steady_state_error)
    assert got <= abs(ref10.metrics.steady_state_error), (
        f"returned Kp = {res.gains['Kp']:.4g} with steady-state error {got:.4g}; Kp = 10 gives 1/11")


# -- any submitted plant must work ---------------------------------------------------------------

@pytest.fixture(scope="module")
def roll_signs():
    pos = plant_from_expr(ROLL)
    neg = plant_from_expr(f"-({ROLL})")
    return (pos, tune(pos, structure="pid_z", dt=DT, seed=0, time_budget_s=BUDGET, spec=THESIS),
            neg, tune(neg, structure="pid_z", dt=DT, seed=0, time_budget_s=BUDGET, spec=THESIS))


def test_negative_gain_plant(roll_signs):
    pos, rp, neg, rn = roll_signs
    np.testing.assert_allclose(neg.num, -pos.num)
    assert_reported_is_verified(rn, neg)
    assert rn.meets_spec and rp.meets_spec
    assert np.sign(rn.gains["K"]) == -np.sign(rp.gains["K"]) != 0
    # (-C)(-G) = C G: the same loop, so the same optimum (0.118 s at the time of writing)
    assert rn.analyses[0].metrics.settling_time_s == pytest.approx(rp.analyses[0].metrics.settling_time_s, rel=0.05)


SPECIAL = {
    # name: (plant builder, structure, dt, settling at the time of writing)
    "first_order_delay_ct": (lambda: make_plant([1], [1, 1], delay=0.2), "pi", None),  # 0.79 s
    "integrating": (lambda: make_plant([1], [1, 1, 0]), "pid", 0.05),  # 0.25 s (2.55 s before fb4fa71)
    "non_minimum_phase": (lambda: make_plant([-0.5, 1], [0.5, 1.5, 1]), "pi", 0.05),  # 6.25 s
    "open_loop_unstable": (lambda: make_plant([1], [1, -1]), "pid", 0.02),  # 0.37 s
    "roll_continuous_pid": (lambda: plant_from_expr(ROLL), "pid", None),  # 0.016 s
}


@pytest.fixture(scope="module", params=sorted(SPECIAL))
def special(request):
    build, structure, dt = SPECIAL[request.param]
    plant = build()
    # the delay loop is slow to verify (fine-step closed-loop poles): a larger budget
    budget = 600.0 if plant.delay_s else BUDGET
    return request.param, plant, dt, tune(plant, structure=structure, dt=dt, seed=0, time_budget_s=budget,
                                          spec=THESIS)


@pytest.mark.slow
def test_special_plants_are_tuned_and_verified(special):
    name, plant, dt, res = special
    indep = assert_reported_is_verified(res, plant)
    assert res.controller.dt == dt
    m = indep[0].metrics
    assert m.stable, f"{name}: unstable result {res.gains}"
    assert res.meets_spec, f"{name}: fails {[(c.name, c.achieved) for c in indep[0].failing]} with {res.gains}"
    assert math.isfinite(m.settling_time_s)


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_open_loop_unstable_plant_is_stabilised_independently():
    """1/(s-1) with a PID at dt = 0.02: closed-loop roots of den + num of C(z) ZOH[G](z) computed here."""
    plant = make_plant([1], [1, -1])
    res = tune(plant, structure="pid", dt=0.02, seed=0, time_budget_s=BUDGET, spec=THESIS)
    ln, ld = ref.open_loop([1], [1, -1], res.controller.num, res.controller.den, dt=0.02)
    roots = ref.closed_loop_roots(ln, ld)
    assert np.max(np.abs(roots)) < 1.0
    nm = ref.nyquist_margins(ln, ld, 0.02)
    m = res.analyses[0].metrics
    assert nm["pm"] == pytest.approx(m.phase_margin_deg, abs=0.05)
    assert nm["gm_db"] == pytest.approx(m.gain_margin_db, abs=0.05)
    # an unstable plant has a lower gain margin: reducing the gain enough destabilises it
    assert nm["gml_db"] == pytest.approx(m.gain_margin_lower_db, abs=0.05) and nm["gml_db"] <= -6


# -- bad input -----------------------------------------------------------------------------------

def test_bad_input_raises_tuner_errors():
    plant = plant_from_expr(ROLL)
    with pytest.raises(TunerError):
        tune(plant, structure="nope", dt=DT, spec=THESIS)
    with pytest.raises(TunerError):
        tune(plant, structure="pid_z", spec=THESIS)  # discrete structure without dt
    with pytest.raises(TunerError):
        tune([], structure="pid", dt=DT, spec=THESIS)
    with pytest.raises(TunerError):
        tune(plant, structure="pid", dt=-1.0, spec=THESIS)
    with pytest.raises(TunerError):
        tune([plant_from_expr("0.04/(z-1)", dt=0.04), plant_from_expr("0.05/(z-1)", dt=0.05)],
             structure="pi")  # discrete plants at different sample times
    with pytest.raises(TunerError):
        tune(plant, structure="pid", dt=DT, nlp_solver="nope", spec=THESIS)
