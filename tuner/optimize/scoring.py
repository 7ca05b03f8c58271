"""Scoring a candidate controller with the verifier, over one plant or a set.

The score is what the global search minimises and what decides between local
solutions: for a candidate that meets every constraint on every plant it is the
objective (worst case over the plants); otherwise it is a penalty above every
feasible value, graded by how far the candidate is from feasibility so the
search can climb out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..analysis.response import step_response
from ..analysis.verify import Analysis, analyze_loop
from ..controllers import ControllerTF, Structure
from ..errors import TunerError
from ..limits import INFEASIBLE as _INFEASIBLE
from ..limits import objective
from ..loop import build_loop
from ..plant import Plant
from ..spec import Spec
from ..tolerances import ROOT_AT_DC_TOL
from . import rules

__all__ = ["Evaluator", "Scored", "objective_value", "violation", "INFEASIBLE"]

INFEASIBLE = _INFEASIBLE  # every infeasible score is above this; feasible scores are below (tuner.limits)
UNSTABLE = 1e5



@dataclass(frozen=True)
class Scored:
    """A candidate's score (what the search minimises), whether it is feasible, and its analyses."""

    score: float
    feasible: bool
    analyses: tuple[Analysis, ...]


def objective_value(a: Analysis, spec: Spec) -> float:
    """The spec's objective for one verified analysis (smaller is better)."""
    m = a.metrics
    from ..spec import resolved_objective

    # ("auto": the structure decides; from an analysis alone, its controller: a 2-DOF one's load design's IE)
    name = resolved_objective(spec.objective, bool(a.loop.controller.two_dof))
    o = objective(name)
    if o.metric is not None:  # a verifier figure (the registry names it)
        v = getattr(m, o.metric)
        if not math.isfinite(v):
            return math.inf
        return -v if o.sense == "max" else v
    r = a.response
    if r is None:
        return math.inf
    if name == "itae":  # of the reference step
        return float(np.trapezoid(r.t * np.abs(1.0 - r.y), r.t))
    if name == "iae":  # over the horizon (Metrics.load_iae where the output returns to 0; finite here even
        # where it does not, so that the search and the verifier rank such designs alike, as the batch does)
        d = step_response(a.loop, horizon_s=float(r.t[-1]), load=True)
        return float(np.trapezoid(np.abs(d.y), d.t))
    # ie: |the signed integral| after the load step (= 1/Ki for a loop with integral action once settled: MIGO
    # maximises Ki)
    at_dc = 1.0 if a.loop.dt else 0.0
    if not np.any(np.abs(a.loop.controller.zpk.poles - at_dc) < ROOT_AT_DC_TOL):
        return math.inf  # without integral action the load step is never rejected
    d = step_response(a.loop, horizon_s=float(r.t[-1]), load=True)
    return abs(float(np.trapezoid(d.y, d.t)))


# how a violation is normalised: by the requirement, except where the requirement is no scale
_UNIT = {"steady_state_error": 1.0}  # the reference step is 1


def _violation(a: Analysis) -> float:
    """Sum of normalised constraint violations (0 when all hold), graded so the search can tell
    how far from feasible a candidate is."""
    total = 0.0
    for c in a.checks:
        if c.ok or c.name == "stable":
            continue
        v = c.violation
        if not math.isfinite(v):
            total += 10.0
            continue
        scale = _UNIT.get(c.name)
        if scale is None:
            req = c.required if isinstance(c.required, (int, float)) and not isinstance(c.required, bool) else 1.0
            scale = abs(req) if math.isfinite(req) and req != 0 else 1.0
        total += min(v / scale, 10.0)
    return total


def violation(a: Analysis) -> float:
    """How far ``a`` is from meeting its spec: the sum of its failing checks' violations, each normalised by its
    requirement and capped at 10 (a non-finite violation counts 10); 0 when every check holds. The search's
    grading of infeasibility, and how :attr:`tuner.TuneResult.worst` ranks failing plants."""
    return _violation(a)


class Evaluator:
    """The verifier's scoring of structure parameters against a plant set, at full resolution: the final choice
    between candidates (the search itself scores batches with :class:`~tuner.optimize.batch.BatchEvaluator`)."""

    def __init__(self, plants: Sequence[Plant], structure: Structure, dt: float | None, spec: Spec, *,
                 w0: float | None = None, specs: Sequence[Spec] | None = None) -> None:
        self.plants = tuple(plants)
        self.structure = structure
        self.dt = dt
        self.spec = spec
        #: the spec each plant is judged by (a gain-variation member's margins: TuningProblem.plant_spec)
        self.specs = tuple(specs) if specs is not None else (spec,) * len(self.plants)
        self.n_evals = 0
        self.w0 = w0  # the plant's characteristic frequency (the search space's), for the caller
        # what was verified already, by parameter vector: the search verifies the ray's best points and then its
        # finalists, which are often the same vectors (the verifier is deterministic)
        self._memo: dict[bytes, Scored] = {}

    def controller(self, x: np.ndarray) -> ControllerTF:
        """The controller of the structure at parameter vector ``x`` (at the loop's ``dt``)."""
        return self.structure.tf(x, self.dt)

    def _with_rules(self, an: tuple[Analysis, ...], x: np.ndarray) -> tuple[Analysis, ...]:
        """The analyses with the checks of the rules on the parameters (the derivative filter's N)."""
        extra = rules.checks(self.structure, self.spec, x, self.dt)
        if not extra:
            return an
        return tuple(replace(a, checks=[*a.checks, *extra]) for a in an)

    def score(self, x: np.ndarray) -> Scored:
        """Score ``x`` on every plant with the full verifier: the objective (worst case) if feasible, else a graded
        penalty above every feasible score (:data:`INFEASIBLE`). A vector scored before is not scored again."""
        key = np.asarray(x, dtype=float).tobytes()
        hit = self._memo.get(key)
        if hit is None:
            hit = self._memo[key] = self._score(x)
        return hit

    def _score(self, x: np.ndarray) -> Scored:
        self.n_evals += 1
        try:
            ctrl = self.controller(x)
            an = tuple(analyze_loop(build_loop(p, ctrl), sp) for p, sp in zip(self.plants, self.specs))
        except (TunerError, ValueError, np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError):
            return Scored(UNSTABLE * 10, False, ())
        an = self._with_rules(an, x)
        if any(not a.metrics.stable for a in an):
            return Scored(UNSTABLE, False, an)
        viol = sum(_violation(a) for a in an)
        if viol > 0:
            return Scored(INFEASIBLE * (1.0 + viol), False, an)
        obj = max(objective_value(a, self.spec) for a in an)
        if not math.isfinite(obj):
            return Scored(INFEASIBLE, False, an)
        return Scored(obj, True, an)
