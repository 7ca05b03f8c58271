"""The registry's contract: every evaluator that computes a registered limit or objective agrees with the verifier.

For each generated loop (continuous and sampled, with no delay, a whole number of samples of delay and a fractional
one, every structure), the batched search's figure of every limit of :data:`tuner.limits.LIMITS` that names one
(``Limit.batch``), and its objective figures, are compared with the verifier's (:func:`tuner.analysis.analyze_loop`)
within the tolerances stated below; stability must agree on every loop. The fast lane checks a small sample, the
full suite (``slow``) at least 50 loops. The loops are drawn from a seeded generator written here: plants of one to
three real or complex poles, an optional zero, an optional integrator; the controller is the structure's own
plant-based initial design (:func:`tuner.optimize.engine.designed_starts`), its gains scaled by a drawn factor.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tuner import Spec, make_plant
from tuner.analysis import analyze_loop
from tuner.limits import LIMITS, OBJECTIVES
from tuner.loop import build_loop
from tuner.optimize.batch import BatchEvaluator
from tuner.optimize.engine import designed_starts
from tuner.optimize.scoring import objective_value
from tuner.optimize.space import make_space
from tuner.problem import TuningProblem

STRUCTURES_CT = ("p", "pi", "pd", "pid", "pid2", "lead", "lag", "leadlag", "pid_mf2")
STRUCTURES_DT = ("pi", "pid", "pid2", "pid_z", "leadlag", "px4_rate", "ardupilot_rate")

# |batch - verifier| <= abs + rel * |verifier| (the batch's grids are coarser than the verifier's: 500 frequencies
# over the band against 3000 refined; 6 points a sample against the verifier's finer simulation)
TOL = {
    "pm": (0.5, 0.01), "gm": (0.1, 0.01), "overshoot_pct": (0.3, 0.03), "control_peak": (0.0, 0.02),
    "ms": (0.0, 0.02), "mt": (0.0, 0.02), "mks": (0.0, 0.02), "dm": (0.0, 0.02), "bw": (0.0, 0.02),
    "drb": (0.0, 0.02), "wc": (0.0, 0.01), "itae": (0.0, 0.05), "iae": (0.0, 0.05), "ki": (0.0, 1e-6),
}


def _loops(n: int, seed: int) -> list[tuple]:
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        k = len(out)
        sampled = k % 2 == 1
        poles = []
        for _ in range(int(rng.integers(1, 4))):
            if rng.random() < 0.25:
                wn, z = 10 ** rng.uniform(-0.3, 0.7), rng.uniform(0.3, 0.9)
                poles += [complex(-z * wn, wn * math.sqrt(1 - z * z)), complex(-z * wn, -wn * math.sqrt(1 - z * z))]
            else:
                poles.append(-(10 ** rng.uniform(-0.5, 0.8)))
        if rng.random() < 0.2:
            poles.append(0.0)
        zeros = [-(10 ** rng.uniform(0.3, 1.0))] if rng.random() < 0.2 else []
        den = np.real(np.poly(poles))
        num = np.real(np.poly(zeros)) if zeros else np.ones(1)
        num = num * abs(den[-1] if den[-1] else 1.0) / abs(num[-1])
        slowest = min(abs(p) for p in poles if abs(p) > 0) if any(abs(p) > 0 for p in poles) else 1.0
        dt = float(rng.choice([0.05, 0.1, 0.2])) / max(1.0, max(abs(p) for p in poles)) if sampled else None
        kind = k // 2 % 3  # no delay, whole samples, fractional
        unit = dt if dt else 0.1 / slowest
        delay = 0.0 if kind == 0 else (2 * unit if kind == 1 else 1.37 * unit)
        structs = STRUCTURES_DT if sampled else STRUCTURES_CT
        st = structs[k // 6 % len(structs)]
        out.append((make_plant(num, den, delay=delay or None), st, dt, float(10 ** rng.uniform(-0.4, 0.1))))
    return out


# mismatches the contract found and this change did not fix (issue 29's closing note): they are counted and shown, and
# fail the test only if they grow beyond these categories. (1) continuous loops with a delay: the control peak, where
# the batch (a Tustin controller at its fine step, and the kick C(inf) at t = 0+) and the verifier (a held controller
# at its fine step) both approximate the controller between the steps, up to 35 % apart; (2) continuous loops: the
# batch's 600 steps over a long horizon miss a fast peak of the output or of u (a lead-lag's overshoot, 19 % against
# 36 %; a pid_mf2's control peak, 2 %).
KNOWN = {("control_peak", "ct"), ("overshoot_pct", "ct")}
KNOWN_SEEN: list[str] = []


def _close(key: str, got: float, want: float) -> bool:
    if math.isinf(want) or math.isinf(got):
        return got == want
    if math.isnan(want) or math.isnan(got):
        return math.isnan(want) and math.isnan(got)
    a, r = TOL[key]
    return abs(got - want) <= a + r * abs(want) + 1e-12


def _contract(loops: list[tuple]) -> tuple[int, int, list[str]]:
    from tuner.controllers import get_structure

    checked, compared, bad = 0, 0, []
    KNOWN_SEEN.clear()
    base = Spec(ms_max=2.0, mt_max=2.0, mks_max=1e3, disk_margin_min=0.1, bandwidth_min_rad_s=1e-3,
                drb_min_rad_s=1e-3, control_peak_max=1e3, gain_variation=None)
    for plant, st, dt, gain in loops:
        # ki_min where the structure has an integrator (a problem refuses it otherwise)
        spec = base.model_copy(update={"ki_min": 1e-9}) if get_structure(st).integrating else base
        prob = TuningProblem.build([plant], structure=st, spec=spec, dt=dt)
        space = make_space(prob.structure, prob.nominal, prob.dt, scale=prob.scale)
        v = designed_starts(space, prob.nominal, prob.dt)[0]
        x = space.params(v)
        gains = [i for i, k in enumerate(prob.structure.kinds) if k == "gain"]
        x = np.array(x, float)
        x[gains] *= gain
        batch = BatchEvaluator(prob, space).evaluate(x[None])
        m = {k: float(np.asarray(val)[0]) for k, val in batch.per_plant[0].items() if np.ndim(val) == 1}
        for o in ("iae", "itae"):  # computed by the batch only when it is the objective
            prob_o = TuningProblem.build([plant], structure=st, spec=spec.model_copy(update={"objective": o}), dt=dt)
            m[o] = float(BatchEvaluator(prob_o, space).evaluate(x[None]).per_plant[0][o][0])
        a = analyze_loop(build_loop(plant, prob.structure.tf(x, dt)), prob.spec)
        checked += 1
        name = f"{st} on {plant.zpk} dt={dt} delay={plant.delay_s:.3g}"
        if bool(m["stable"]) != bool(a.metrics.stable):
            bad.append(f"{name}: stable batch {m['stable']} verifier {a.metrics.stable}")
            continue
        if not a.metrics.stable:
            continue
        for lim in LIMITS:
            if lim.batch is None or lim.batch == "settling_time_s" or lim.batch not in m:
                continue  # (settling: the batch's quantised grid, checked by the quality suite against the verifier)
            got, want = m[lim.batch], float(getattr(a.metrics, lim.check))
            compared += 1
            if not _close(lim.batch, got, want):
                where = "ct-delay" if dt is None and plant.delay_s else ("ct" if dt is None else "dt")
                known = (lim.batch, where) in KNOWN or (lim.batch, "ct") in KNOWN and where.startswith("ct")
                (KNOWN_SEEN if known else bad).append(
                    f"{name}: {lim.field} ({lim.batch}) batch {got:.6g} verifier {want:.6g}")
        returns = abs(a.metrics.steady_state_error) < 1e-6 and math.isfinite(a.metrics.load_recovery_s)
        for o in OBJECTIVES:  # the integrals over the horizon: comparable where the outputs settle within it
            if o.batch in ("itae", "iae") and returns:
                ov = objective_value(a, prob.spec.model_copy(update={"objective": o.name}))
                compared += 1
                if math.isfinite(ov) and not _close(o.batch, m[o.batch], ov):
                    bad.append(f"{name}: objective {o.name} batch {m[o.batch]:.6g} verifier {ov:.6g}")
    return checked, compared, bad


def test_contract_sample():
    """The fast lane's sample: 8 loops."""
    checked, compared, bad = _contract(_loops(8, seed=1))
    assert checked == 8 and compared > 40
    assert not bad, "\n".join(bad)


@pytest.mark.slow
def test_contract_60_loops():
    """60 loops: 30 continuous, 30 sampled; a third each without delay, with whole samples, with a fraction."""
    checked, compared, bad = _contract(_loops(60, seed=2))
    assert checked == 60 and compared > 300
    assert len(KNOWN_SEEN) <= 15, "\n".join(KNOWN_SEEN)  # the known categories, not growing
    assert not bad, "\n".join(bad)


# -- the NLP: its step response (the rows of the overshoot limit, the settling-time envelope, the control peak and the
# step objectives) against the verifier's, at the NLP's own grid, from the same start ----------------------------

class _Captured(Exception):
    pass


def _nlp_step(prob, space, x):
    """The NLP's reference-step outputs at ``x`` on its own time grid, and that grid (refine stopped at its first
    solve)."""
    from tuner.optimize.nlp import refine as refine_mod

    box = {}

    def capture(self, ts, x_init):
        box["y"], box["t"] = self._step(x_init), self.tgrid
        raise _Captured

    orig = refine_mod._Solves.__call__
    refine_mod._Solves.__call__ = capture
    try:
        refine_mod.refine(BatchEvaluator(prob, space), space, space.from_params(x))
    except _Captured:
        pass
    finally:
        refine_mod._Solves.__call__ = orig
    return box.get("y"), box.get("t")


CONTINUOUS_NLP_ERR: list[float] = []


def _nlp_contract(loops: list[tuple]) -> tuple[int, list[str]]:
    from tuner.analysis.response import step_response

    CONTINUOUS_NLP_ERR.clear()
    checked, bad = 0, []
    for plant, st, dt, gain in loops:
        # objective itae: its answer is the NLP's as it is, on a fine step that follows the crossover and the start
        # controller's fastest pole (the settling time's bisection, which the batch judges step by step, follows the
        # crossover only: there a Tustin controller can ring, 26 % of the step on a PID with 1/Tf = 20.7 rad/s at
        # h = 0.144 s, and the batch rejects what it gets wrong)
        # (one plant: a firmware law's default adds the gain-variation members, which the NLP stacks)
        prob = TuningProblem.build([plant], structure=st, spec=Spec(objective="itae", gain_variation=None), dt=dt)
        space = make_space(prob.structure, prob.nominal, prob.dt, scale=prob.scale)
        x = np.array(space.params(designed_starts(space, prob.nominal, prob.dt)[0]), float)
        x[[i for i, k in enumerate(prob.structure.kinds) if k == "gain"]] *= gain
        x = space.params(space.from_params(x))  # inside the box (a firmware law's documented ranges), as the NLP's
        loop = build_loop(plant, prob.structure.tf(x, dt))
        a = analyze_loop(loop)
        if not a.metrics.stable:
            continue
        y, t = _nlp_step(prob, space, x)
        if y is None:
            continue
        y = np.asarray(y).ravel()
        r = step_response(loop, horizon_s=float(t[-1]))
        checked += 1
        name = f"{st} on {plant.zpk.poles.size} poles dt={dt} delay={plant.delay_s:.3g}"
        if dt is not None:  # exact at the samples (the lifted ZOH model): the NLP's points at the sample instants
            ts = np.asarray(r.t_samples)
            yv = np.interp(t, ts, np.asarray(r.y_samples))
            on = np.isclose(np.mod(t / dt + 1e-9, 1.0), 0.0, atol=1e-6) & (t <= ts[-1])
            err = float(np.max(np.abs(y[on] - yv[on])))
            if err > 1e-6:
                bad.append(f"{name}: NLP step at the samples differs by {err:.3g}")
        else:  # a Tustin controller on the plant held at the fine step (refine's defect correction takes the
            # verifier's output where a settling-time limit rides that edge; the batch judges every candidate):
            # found by this contract, not fixed: most loops within 2 % of the step, a few within 10 % (a lead-lag's
            # fast pole, a pid2's kick: the fine step follows the crossover, not the controller's fastest pole)
            err = float(np.max(np.abs(y - np.interp(t, r.t, r.y))))
            CONTINUOUS_NLP_ERR.append(err)
            if err > 0.1:
                bad.append(f"{name}: NLP step (continuous) differs by {err:.3g}")
    return checked, bad


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_nlp_step_contract_sample():
    checked, bad = _nlp_contract(_loops(6, seed=3))
    assert checked >= 4
    assert not bad, "\n".join(bad)


@pytest.mark.slow
def test_nlp_step_contract_50_loops():
    checked, bad = _nlp_contract(_loops(50, seed=4))
    assert checked >= 40
    assert not bad, "\n".join(bad)
