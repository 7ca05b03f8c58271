"""The speed/robustness trade-off curve: verified optima from the fastest design to the most robust.

The PID Tuner app's response-time/robustness slider, with every point an optimum of its own problem and
verified: point ``k`` is the minimum-settling-time design of the spec with the noise limit ``y <= m_k``
(``y`` = ``mks`` or ``control_peak``). The first point is the spec's own optimum (``m_0`` = its achieved
``y``); the limits then fall geometrically towards the floor that no design of the structure can pass,

    m_k = floor + (m_0 - floor) * 0.1 ** (k / (N - 1)),   k = 0 .. N - 1,

with ``floor`` = ``1/|G(0)|`` where integral action (or zero steady-state error for the control peak)
implies ``y >= 1/|G(0)|``, else 0. So the last point is 10 % of the way from the floor to the fastest
design's ``y``: far enough to show the cost of robustness, never the degenerate zero-gain end. Every point is
tuned with the same problem structure, so the NLP is built once and the later tunes are warm. A point is kept
only if it meets the spec and its ``y`` is strictly lower than the point before it (a limit that does not bind
gives the same design again: it is left out); a point at least as fast as an earlier one removes that one (it
dominates it: the search had missed it), so the settling time increases strictly along the curve.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

from .errors import TunerError
from .jsonio import jsonable
from .spec import Spec

__all__ = ["tradeoff", "TradeoffResult", "Y_AXES", "MAX_POINTS"]

Y_AXES = {"mks": "mks_max", "control_peak": "control_peak_max"}
MAX_POINTS = 20
FLOOR_SHARE = 0.1


@dataclass(frozen=True)
class TradeoffResult:
    """The verified points (``TuneResult`` each), fastest first; ``y`` the robustness axis."""

    structure: str
    x: str
    y: str
    points: tuple[Any, ...]
    limits: tuple[float | None, ...]  # the y limit each point was tuned with (None: the spec's own optimum)
    skipped: tuple[dict[str, Any], ...] = field(default=())  # limits that gave no new point, and why
    wall_time_s: float = 0.0
    reasons: tuple[Any, ...] = ()  # when the spec itself is not met (no point): why (tuner.diagnose.Reason)

    @property
    def meets_spec(self) -> bool:
        """Whether the spec is met at all (then every point meets it)."""
        return bool(self.points)

    def values(self) -> list[tuple[float, float]]:
        """``(settling time, y)`` of each point (worst over the plants)."""
        return [(_settling(r), _y(r, self.y)) for r in self.points]

    def __repr__(self) -> str:
        pts = ", ".join(f"({x:.4g} s, {y:.4g})" for x, y in self.values())
        return (f"TradeoffResult({self.structure}: {len(self.points)} verified points (settling time, {self.y}) "
                f"from fastest to most robust: {pts})")

    def to_dict(self) -> dict[str, Any]:
        """The curve as a dict: each point's values, limit, gains, verdict and full result."""
        return {
            "structure": self.structure, "x": self.x, "y": self.y, "wall_time_s": self.wall_time_s,
            "points": [{"settling_time_s": x, self.y: y, "limit": lim, "gains": r.gains,
                        "meets_spec": r.meets_spec, "result": r.to_dict()}
                       for (x, y), lim, r in zip(self.values(), self.limits, self.points)],
            "skipped": [dict(s) for s in self.skipped],
            "meets_spec": self.meets_spec,
            "reasons": [r.to_dict() for r in self.reasons],
        }

    def to_json(self) -> dict[str, Any]:
        """:meth:`to_dict` made JSON-ready (:func:`tuner.jsonio.jsonable`)."""
        return jsonable(self.to_dict())


def _settling(r: Any) -> float:
    return max(a.metrics.settling_time_s for a in r.analyses)


def _y(r: Any, y: str) -> float:
    return max(getattr(a.metrics, y) for a in r.analyses)


def _floor(problem: Any, y: str) -> float:
    from .diagnose import dc_gain

    st, sp = problem.structure, problem.spec
    if (y == "mks" and st.integrating) or (y == "control_peak" and sp.zero_steady_state_error):
        inv = [1.0 / g for g in (dc_gain(p) for p in problem.plants) if 0 < g < math.inf]
        return max(inv) if inv else 0.0
    return 0.0


def tradeoff(plant_or_plants: Any, *, structure: str | None = None, spec: Spec | None = None, dt: float | None = None,
             delay: Any = None, x: str = "settling_time", y: str = "mks", points: int = 8, seed: int = 0,
             time_budget_s: float = 30.0) -> TradeoffResult:
    """``points`` verified designs of ``structure`` from the fastest (the spec's optimum) to the most robust
    (see the module docstring), each meeting the rest of ``spec``; ``y``: ``"mks"`` or ``"control_peak"``.

    Examples
    --------
    >>> import control
    >>> from tuner.tradeoff import tradeoff
    >>> t = tradeoff(control.tf([58.57], [1, 14.195, 220.6]), structure="pid", dt=0.04, points=4)  # doctest: +SKIP
    >>> [p.meets_spec for p in t.points]  # doctest: +SKIP
    [True, True, True, True]
    """
    from .interop import as_plants
    from .problem import TuningProblem
    from .tuning import check_budget, tune

    if x != "settling_time":
        raise TunerError(f"x must be 'settling_time' (the speed axis), got {x!r}", field="x")
    if y not in Y_AXES:
        raise TunerError(f"y must be one of {sorted(Y_AXES)}, got {y!r}", field="y")
    if not (isinstance(points, int) and not isinstance(points, bool) and 2 <= points <= MAX_POINTS):
        raise TunerError(f"points must be an integer from 2 to {MAX_POINTS}, got {points!r}", field="points")
    check_budget(time_budget_s)
    spec = spec if spec is not None else Spec()
    if spec.objective == "auto":  # the curve's speed axis is the settling time, whatever the structure
        spec = spec.model_copy(update={"objective": "settling_time"})
    if spec.objective != "settling_time":
        raise TunerError("the trade-off curve's speed axis is the settling time: leave spec.objective at "
                         "settling_time", field=("spec", "objective"))
    t0 = time.perf_counter()
    end = t0 + float(time_budget_s)
    if isinstance(plant_or_plants, TuningProblem):  # validated already (the service): its own spec and dt
        problem = plant_or_plants
        plants, spec = list(problem.given_plants), problem.asked_spec
        if spec.objective == "auto":
            spec = spec.model_copy(update={"objective": "settling_time"})
            problem = TuningProblem.build(plants, structure=problem.structure, spec=spec, dt=problem.dt)
        if spec.objective != "settling_time":
            raise TunerError("the trade-off curve's speed axis is the settling time: leave spec.objective at "
                             "settling_time", field=("spec", "objective"))
    else:
        plants = as_plants(plant_or_plants, delay=delay)
        problem = TuningProblem.build(plants, structure=structure, spec=spec, dt=dt)
    each = float(time_budget_s) / (points + 1)
    first = tune(problem, seed=seed, time_budget_s=each)
    if not first.meets_spec:  # no fastest point: say why, as tune does
        return TradeoffResult(structure=problem.structure.name, x=x, y=y, points=(), limits=(),
                              skipped=({"limit": None, "why": "the spec itself is not met"},),
                              wall_time_s=time.perf_counter() - t0, reasons=tuple(first.reasons))
    fld = Y_AXES[y]
    asked = problem.asked_spec
    m0, floor = _y(first, y), _floor(problem, y)
    kept, limits, skipped = [first], [None], []
    for k in range(1, points):
        m = floor + (m0 - floor) * FLOOR_SHARE ** (k / (points - 1))
        left = end - time.perf_counter()
        if left <= 0:
            skipped.append({"limit": m, "why": "the time budget ran out"})
            continue
        cur = getattr(asked, fld)
        sp = asked.model_copy(update={fld: m if cur is None else min(m, cur)})
        prob = TuningProblem.build(plants, structure=problem.structure, spec=sp, dt=problem.dt)
        r = tune(prob, seed=seed, time_budget_s=max(min(each, left), 1e-3), diagnose=False)
        if not r.meets_spec:
            skipped.append({"limit": m, "why": "no design meeting the spec was found at this limit"})
            continue
        if _y(r, y) >= _y(kept[-1], y):
            skipped.append({"limit": m, "why": "the same trade-off as the point before (the limit does not bind)"})
            continue
        while kept and _settling(r) <= _settling(kept[-1]):  # r is as fast and more robust: those are dominated
            skipped.append({"limit": limits.pop(), "why": "dominated by a later point (as fast, more robust): "
                            "the search had missed it"})
            kept.pop()
        kept.append(r)
        limits.append(m)
    return TradeoffResult(structure=problem.structure.name, x=x, y=y, points=tuple(kept), limits=tuple(limits),
                          skipped=tuple(skipped), wall_time_s=time.perf_counter() - t0)
