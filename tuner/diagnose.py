"""Why a spec was not met, and what would make it feasible.

Two kinds of reason, each with the spec change that would help (``suggest``: Spec field -> value):

* **By definition** (no search needed): a control-peak limit below the steady-state input that zero
  steady-state error requires (a unit step needs ``u(inf) = 1/G(0)``, so ``max |u| >= |1/G(0)|``); an
  Mks limit below ``|C S|(0) = 1/|G(0)|``, which integral action implies; a
  structure without integral action asked for zero steady-state error on a plant without an integrator;
  an ``mt_max`` below 1 with zero steady-state error (``T(0) = 1``) is refused earlier, by the problem.
* **By search**: for each failing limit, the same tune is repeated with that limit relaxed. If the
  relaxed problem is feasible, the limit conflicts with the others and a bisection between the asked
  value and the relaxed design's value gives the tightest value the search found feasible (every
  other constraint held): "phase_margin_deg >= 89 is not reachable with pid on this plant: the
  tightest found feasible is 74.2". If no single relaxation helps, every failing limit is relaxed at
  once; if that does not help either, the structure is the limit (try one with more freedom).

"Tightest found feasible" is what a seeded search found within a small budget, a bound from
below on what is reachable, never a claim of optimality; the wording says so.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

from .design import dc_gain  # re-exported: its name here before tuner.design
from .limits import LIMITS, by_check
from .problem import TuningProblem
from .spec import Spec
from .tolerances import LIMIT_RTOL, SAMPLE_COUNT_TOL

__all__ = ["Reason", "diagnose", "definitional_reasons", "dc_gain"]

# failing check -> (Spec field, direction: +1 = lower bound on the metric (>=), -1 = upper bound, loosest value): every
# limit of the registry (tuner.limits) with a sense, the gain margin's lower side, and the derivative-filter rule
_LIMITS: dict[str, tuple[str, int, Any]] = {
    **{lim.check: (lim.field, lim.sense, lim.loosest) for lim in LIMITS if lim.sense},
    "gain_margin_lower_db": ("gain_margin_min_db", +1, 0.0),
    "filter_n": ("filter_n_max", -1, None),
}
BISECTIONS = 4


def _within(bounds: dict[str, float], v: float) -> bool:
    """Whether ``v`` satisfies a registry entry's pydantic bounds (``ge``, ``gt``, ``le``, ``lt``)."""
    return (v >= bounds.get("ge", -math.inf) and v > bounds.get("gt", -math.inf) and v <= bounds.get("le", math.inf)
            and v < bounds.get("lt", math.inf))


@dataclass(frozen=True)
class Reason:
    """One reason a spec is not met; ``suggest``: a spec change that would make it feasible (by definition) or
    that a re-tune found feasible."""

    constraints: tuple[str, ...]
    message: str
    suggest: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The reason as a dict (``constraints``, ``message``, ``suggest``)."""
        return {"constraints": list(self.constraints), "message": self.message, "suggest": dict(self.suggest)}


def definitional_reasons(problem: TuningProblem) -> list[Reason]:
    """Reasons that hold whatever the gains (see the module docstring)."""
    sp, st = problem.spec, problem.structure
    out: list[Reason] = []
    for i, p in enumerate(problem.plants):
        where = "" if len(problem.plants) == 1 else f" (plant #{i + 1})"
        g0 = dc_gain(p)
        if sp.mks_max is not None and st.integrating and 0 < g0 < math.inf and sp.mks_max < 1.0 / g0 * (1 - LIMIT_RTOL):
            k = _budget_scale(problem)
            sug = {"noise_gain_max": _outward(1.0 / g0 * 1.001 / k, -1)} if k else \
                {"mks_max": _outward(1.0 / g0 * 1.001, -1)}
            what = f"the noise budget mks <= {sp.mks_max:.4g}" if k else f"mks <= {sp.mks_max:g}"
            out.append(Reason(("mks",), f"{what} is below |C S| at zero frequency, 1/G(0) = "
                              f"{1.0 / g0:.4g}, which every controller with integral action has{where}: "
                              "allow at least that", sug))
        if not sp.zero_steady_state_error:
            continue
        if sp.control_peak_max is not None and 0 < g0 < math.inf and sp.control_peak_max < 1.0 / g0 * (1 - LIMIT_RTOL):
            out.append(Reason(("control_peak",), f"control_peak <= {sp.control_peak_max:g} is below the steady-state "
                              f"input 1/G(0) = {1.0 / g0:.4g} that zero steady-state error to a unit step needs"
                              f"{where}: allow at least that, or drop zero_steady_state_error",
                              {"control_peak_max": _outward(1.0 / g0 * 1.001, -1)}))
        if g0 < math.inf and not st.integrating:
            out.append(Reason(("steady_state_error",), f"{st.name} has no integral action and the plant{where} no "
                              "integrator: zero steady-state error is out of reach; use a structure with an integrator "
                              "(pi, pid, pid2, pid_z, pid_mf2) or set zero_steady_state_error = false",
                              {"zero_steady_state_error": False}))
        if g0 == 0.0:
            out.append(Reason(("steady_state_error",), f"the plant{where} has a zero at s = 0 (G(0) = 0): no "
                              "controller gives zero steady-state error to a step; set zero_steady_state_error = false",
                              {"zero_steady_state_error": False}))
    return out


def _budget_scale(problem: TuningProblem) -> float | None:
    """The gain the default noise budget is relative to, when the budget is the Mks limit in force (else None)."""
    from .problem import noise_scale

    if any(lim["field"] == "mks_max" for lim in problem.limits):
        return noise_scale(problem.plants, problem.scale)
    return None


def _relaxed(spec: Spec, changes: dict[str, Any]) -> Spec:
    return Spec.model_validate({**spec.model_dump(), **changes})  # validated: a suggestion is always a valid spec


def _field_value(res: Any, check: str) -> float:
    """The value of the limit's spec field that the re-tuned design ``res`` just meets, worst over the plants:
    the metric itself, except for the lower gain margin (``gain_margin_lower_db <= -gm``: gm = -value) and the
    derivative filter's N (from the design's parameters)."""
    fld, sign, _ = _LIMITS[check]
    if check == "gain_margin_lower_db":
        return min(-a.metrics.gain_margin_lower_db for a in res.analyses)
    if check == "filter_n":
        from .controllers import get_structure
        from .rules import filter_n

        st = get_structure(res.structure)
        return filter_n(st, st.vector(res.gains))
    vals = [getattr(a.metrics, check) for a in res.analyses]
    return min(vals) if sign > 0 else max(vals)


def _outward(x: float, sign: int) -> float:
    """Four significant digits, rounded to the feasible side (down for a lower bound, up for an upper one), as the
    shortest float of those digits (1.001, never 1.0010000000000001)."""
    if not math.isfinite(x) or x == 0:
        return x
    e = math.floor(math.log10(abs(x))) - 3
    q = x / 10.0 ** e
    k = math.floor(q + SAMPLE_COUNT_TOL) if sign > 0 else math.ceil(q - SAMPLE_COUNT_TOL)
    return float(f"{k}e{e}")


def diagnose(problem: TuningProblem, failing: list[str], *, tune_fn: Any, seed: int, budget_s: float,
             min_tune_s: float = 0.05, found: list | None = None, analyses: Any = ()) -> list[Reason]:
    """Reasons for ``failing`` (check names of the best design); ``tune_fn(problem, seed, budget)`` re-tunes.

    ``min_tune_s``: what one re-tune needs at least (its final verification included); a re-tune is started
    only if the longest one so far (or ``min_tune_s`` before the first) still fits in what is left of
    ``budget_s``, so the diagnosis ends within it. ``analyses``: the best design's (what a target crossover
    reached); ``found``: every re-tuned result is appended to it (the caller may adopt one that meets the spec)."""
    reasons = definitional_reasons(problem)
    explained = {c for r in reasons for c in r.constraints}
    todo = [c for c in dict.fromkeys(failing) if c in _LIMITS and c not in explained]
    if problem.asked_spec.settling_time_max is None and "settling_time_s" in todo:
        todo.remove("settling_time_s")  # "settles at all" (< inf): no limit to relax
    if "crossover_rad_s" in failing and "crossover_rad_s" not in explained:
        wc = [a.metrics.crossover_rad_s for a in analyses]
        got = ", ".join(f"{w:.4g}" for w in wc if math.isfinite(w)) or "none"
        reasons.append(Reason(("crossover_rad_s",), f"the target crossover crossover_rad_s = "
                              f"{problem.spec.crossover_rad_s:g} rad/s was not reached with {problem.structure.name} "
                              f"together with the other constraints (the best design found crosses at {got} rad/s): "
                              "choose another target, or relax the margins and peaks"))
    if "gain_margin_db" in todo and "gain_margin_lower_db" in todo:
        todo.remove("gain_margin_lower_db")
    if not todo:
        if "stable" in failing and not explained:
            reasons.append(Reason(("stable",), f"no stabilising {problem.structure.name} was found for this plant: "
                                  "try a structure with more freedom (pid, pid2, pid_mf2, leadlag) or a shorter dt"))
        return reasons
    if budget_s <= 0:
        return reasons
    end = time.perf_counter() + budget_s
    each = max(min_tune_s, budget_s / (len(todo) * (BISECTIONS + 1) + 1))
    longest = [min_tune_s]
    sp, name = problem.asked_spec, problem.structure.name
    k_budget = _budget_scale(problem)

    def changes_for(check: str, value: Any) -> dict[str, Any]:
        """The spec change that sets ``check``'s limit to ``value``: the noise budget, where it is the Mks limit
        in force, is lifted and the value given as mks_max."""
        fld = _LIMITS[check][0]
        if check == "mks" and k_budget:
            return {"noise_gain_max": None, "mks_max": value}
        return {fld: value}

    def suggestion(check: str, shown: float) -> dict[str, Any]:
        if check == "mks" and k_budget:
            return {"noise_gain_max": _outward(shown / k_budget, -1)}
        lim = by_check(check)  # a value the field's bounds refuse (a DRB of 0 for a limit > 0) is no suggestion
        if lim is not None and not _within(lim.bounds, shown):
            return {}
        return {_LIMITS[check][0]: shown}

    def attempt(changes: dict[str, Any]) -> Any:
        if time.perf_counter() + max(longest[0], each) > end:
            return None
        prob = TuningProblem.build(list(problem.given_plants), structure=problem.structure, spec=_relaxed(sp, changes),
                                   dt=problem.dt)
        t0 = time.perf_counter()
        out = tune_fn(prob, seed, each)
        longest[0] = max(longest[0], time.perf_counter() - t0)
        if found is not None and out is not None:
            found.append(out)  # the caller re-verifies it against the asked spec: a re-tune may meet it
        return out

    single_ok = False
    for check in todo:
        fld, sign, loosest = _LIMITS[check]
        asked_v = getattr(sp, fld)
        if asked_v is None:  # a limit the problem resolved (the noise budget as mks_max)
            asked_v = getattr(problem.spec, fld)
        if asked_v is None or isinstance(asked_v, bool):
            continue
        res = attempt(changes_for(check, loosest))
        if res is None or not res.meets_spec:
            continue
        single_ok = True
        asked = float(asked_v)
        got = _field_value(res, check)  # the relaxed design meets every other constraint, and this limit at `got`
        op = ">=" if sign > 0 else "<="
        if not math.isfinite(got) or (got >= asked if sign > 0 else got <= asked):
            reasons.append(Reason((check,), f"{check}: a re-tune with this limit relaxed met {fld} {op} {asked:g} "
                                  "as well: the first search did not find that design (budget or a missed basin); "
                                  "retry with a larger time_budget_s or another seed"))
            continue
        best = got
        lo, hi = (best, asked) if sign > 0 else (asked, best)  # for >=: feasible at lo, not found at hi
        for _ in range(BISECTIONS):
            mid = 0.5 * (lo + hi)
            r = attempt(changes_for(check, mid))
            if r is None:
                break
            if r.meets_spec:
                best = max(mid, _field_value(r, check)) if sign > 0 else min(mid, _field_value(r, check))
                lo, hi = (best, hi) if sign > 0 else (lo, best)
            else:
                lo, hi = (lo, mid) if sign > 0 else (mid, hi)
        shown = _outward(best, sign)
        if (shown >= asked) if sign > 0 else (shown <= asked):  # never tighter than the limit that failed
            reasons.append(Reason((check,), f"{check}: a re-tune met {fld} {op} {asked:g} as well: the first search "
                                  "did not find that design (budget or a missed basin); retry with a larger "
                                  "time_budget_s or another seed"))
            continue
        sug = suggestion(check, shown)
        said = ", ".join(f"{k} = {v:g}" for k, v in sug.items()) or \
            f"{check} = {shown:g}, a value the limit's field does not take (no value of it is met)"
        lim = by_check(check)
        hint = ("; " + lim.binds.format(value=asked)) if lim is not None and lim.binds else ""
        reasons.append(Reason((check,), f"{check} {op} {asked:.4g} was not met with {name} on this plant together "
                              f"with the other constraints; the tightest a search found feasible is {said}{hint}", sug))
    if not single_ok:
        changes = {}
        for c in todo:
            changes.update(changes_for(c, _LIMITS[c][2]))
        res = attempt(changes)
        if res is not None and res.meets_spec:
            # suggest what the relaxed design achieves (rounded to the feasible side), never the lifted limits
            got = {}
            for c in todo:
                v = _outward(_field_value(res, c), _LIMITS[c][1])
                if math.isfinite(v):
                    got.update(suggestion(c, v))
            achieved = ", ".join(f"{k} = {v:g}" for k, v in got.items())
            reasons.append(Reason(tuple(todo), f"{', '.join(todo)} were not met together with {name} on this plant: "
                                  "no re-tune with a single one relaxed was found feasible, one with all of them "
                                  f"relaxed was: it achieves {achieved}", got))
        elif res is not None:
            reasons.append(Reason(tuple(todo), f"even with {', '.join(todo)} relaxed, no {name} meeting the rest of "
                                  "the spec was found: try a structure with more freedom (pid, pid2, pid_mf2, "
                                  "leadlag) or relax the remaining limits"))
    if not any(set(r.constraints) & set(todo) for r in reasons):
        reasons.append(Reason(tuple(todo), f"{', '.join(todo)}: not explained within the time the diagnosis had "
                              f"({budget_s:.2g} s of the budget): a larger time_budget_s gives it more; no re-tune "
                              "with these limits relaxed was found feasible in that time"))
    return reasons
