"""Tuning and verifying the loops of a study, cascades included.

Every figure here comes from the verifier (:func:`tuner.analysis.analyze`); a cascade
also gets an exact sampled-data simulation of the whole cascade
(:func:`tuner.analysis.cascade.simulate_cascade`) for its output between samples.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ..analysis.cascade import EXACT_NOTE, HELD_NOTE, SKIPPED_NOTE, CascadeResponse, outer_plants, simulate_cascade
from ..analysis.verify import Analysis, analyze
from ..controllers import ControllerTF
from ..errors import TunerError
from ..jsonio import jsonable
from ..plant import Plant
from ..tolerances import SAME_DT_RTOL
from .schema import (
    InvalidStudyError,
    LoopDef,
    StudyDef,
    base_plants,
    controller_of,
    identified,
    loop_key,
    thesis_controller_of,
    true_plant_of,
    vehicle_of,
)

__all__ = ["LoopEval", "loop_plants", "evaluate_loop", "evaluate_gains", "evaluate_thesis", "tune_loop",
           "gains_entry", "check_gains_file", "identification_summary", "uncertainty_checks"]


@dataclass(frozen=True, eq=False)
class LoopEval:
    """A controller on a loop, verified: one analysis per plant (nominal first)."""

    loop: LoopDef
    controller: ControllerTF
    analyses: tuple[Analysis, ...]
    cascade: CascadeResponse | None = None  # exact simulation of the whole cascade (nominal plants)
    cascade_note: str | None = None
    inner_bandwidth_rad_s: float | None = None

    @property
    def nominal(self) -> Analysis:
        """The nominal plant's analysis."""
        return self.analyses[0]

    def __repr__(self) -> str:
        from ..display import loop_eval_repr

        return loop_eval_repr(self)

    @property
    def cascade_ok(self) -> bool:
        """Between samples, the cascade's output keeps the overshoot limit and settles."""
        if self.cascade is None:
            return True
        m = self.cascade.metrics
        return bool(m.overshoot_pct <= self.loop.spec.overshoot_max_pct and math.isfinite(m.settling_time_s))

    @property
    def meets_spec(self) -> bool:
        """Every plant meets the spec, and the cascade between samples too."""
        return all(a.meets_spec for a in self.analyses) and self.cascade_ok

    @property
    def failing(self) -> list[str]:
        """The names of the failing checks over every plant (``cascade_between_samples`` for the cascade)."""
        names = sorted({c.name for a in self.analyses for c in a.failing})
        if not self.cascade_ok:
            names.append("cascade_between_samples")
        return names

    def cascade_dict(self) -> dict[str, Any] | None:
        """The cascade's figures (bandwidths, their ratio, the between-samples check), None for a single loop."""
        if self.loop.inner is None:
            return None
        outer_bw = self.nominal.metrics.bandwidth_rad_s
        inner_bw = self.inner_bandwidth_rad_s
        ratio = inner_bw / outer_bw if inner_bw is not None and outer_bw > 0 else math.nan
        out: dict[str, Any] = {"inner": self.loop.inner, "inner_bandwidth_rad_s": inner_bw,
                               "outer_bandwidth_rad_s": outer_bw, "bandwidth_ratio": ratio,
                               "evaluation": self.cascade_note}
        if self.cascade is not None:
            m = self.cascade.metrics
            out["between_samples"] = {"overshoot_pct": m.overshoot_pct, "settling_time_s": m.settling_time_s,
                                      "ok": self.cascade_ok}
        return out

    @property
    def verdict(self) -> str:
        """The verdict in words (:func:`tuner.text.verdict`; a data loop's on the measured response and its
        identification's rating too), and the cascade's between samples."""
        from ..text import verdict, verdict_met

        text = verdict(self.analyses)
        if not self.cascade_ok:
            cascade = "the cascade's output between samples fails its overshoot or settling"
            text = f"does NOT meet the spec: {cascade}" if verdict_met(self.analyses) else f"{text}; and {cascade}"
        return text

    def to_dict(self) -> dict[str, Any]:
        """The nominal plant's metrics and checks, the verdict, the controller; ``plants``, ``measured`` (a data
        loop's loop on the measured response) and ``cascade``."""
        from ..text import verdict_basis

        d = self.nominal.to_dict()
        out: dict[str, Any] = {"metrics": d["metrics"], "checks": d["checks"], "meets_spec": self.meets_spec,
                               "verdict": self.verdict, "basis": verdict_basis(self.analyses),
                               "failing": self.failing, "controller": self.controller.to_dict()}
        if "measured" in d:
            out["measured"] = d["measured"]
        if len(self.analyses) > 1:
            out["plants"] = [a.to_dict() for a in self.analyses]
        c = self.cascade_dict()
        if c is not None:
            out["cascade"] = c
        return out


def loop_plants(study: StudyDef, lp: LoopDef, controllers: Mapping[str, ControllerTF]) -> list[Plant]:
    """The plants the loop's controller sees: its own, or for a cascade the composite plants
    around the inner loop closed with ``controllers[inner]``."""
    own = base_plants(lp)
    if lp.inner is None:
        return own
    if lp.inner not in controllers:
        raise InvalidStudyError(f"loop {lp.name!r}: needs the controller of its inner loop {lp.inner!r}")
    inner = loop_plants(study, study.get(lp.inner), controllers)
    try:
        return outer_plants(inner, controllers[lp.inner], own)
    except TunerError as e:
        raise type(e)(f"loop {lp.name!r}: {e}") from e


def evaluate_loop(
    study: StudyDef, lp: LoopDef, controller: ControllerTF, controllers: Mapping[str, ControllerTF], *,
    analyses: tuple[Analysis, ...] | None = None, inner_bandwidth_rad_s: float | None = None,
) -> LoopEval:
    """Verify ``controller`` on every plant of the loop (``analyses`` if already verified); a data loop's nominal
    plant also on the identification's measured response, with its checks
    (:func:`tuner.analysis.measured.with_measured`: the verdict includes the airframe)."""
    if analyses is None:
        plants = loop_plants(study, lp, controllers)
        analyses = tuple(analyze(p, controller, lp.spec) for p in plants)
        if lp.inner is None:  # a firmware law's gain-variation members, judged as tune judges them
            from ..controllers import get_structure
            from ..problem import gain_variation, member_spec

            ks = gain_variation(lp.spec, get_structure(lp.structure))
            analyses += tuple(analyze(plants[0].scaled(k), controller, member_spec(lp.spec, k)) for k in ks)
    if lp.data is not None and lp.inner is None:  # (a cascade's outer plant is not what the log measured)
        from ..analysis.measured import with_measured

        analyses = (with_measured(analyses[0], identified(lp), lp.spec), *analyses[1:])
    if lp.inner is None:
        return LoopEval(loop=lp, controller=controller, analyses=analyses)
    inner = study.get(lp.inner)
    sim, note = None, HELD_NOTE
    own, inner_own = base_plants(lp)[0], base_plants(inner)[0]
    if inner.inner is None and not inner_own.is_discrete and not own.is_discrete:
        note = EXACT_NOTE
        r = analyses[0].response
        if r is not None:
            sim = simulate_cascade(inner_own, controllers[lp.inner], own, controller, horizon_s=float(r.t[-1]),
                                   band_pct=lp.spec.settling_band_pct, y_final=r.y_final)
        if sim is None:  # (a plant with a delay, an unstable loop, controllers at other sample times): say so
            note = SKIPPED_NOTE
    return LoopEval(loop=lp, controller=controller, analyses=analyses, cascade=sim, cascade_note=note,
                    inner_bandwidth_rad_s=inner_bandwidth_rad_s)


def _inner_bw(evals: Mapping[str, LoopEval], lp: LoopDef) -> float | None:
    if lp.inner is None or lp.inner not in evals:
        return None
    return evals[lp.inner].nominal.metrics.bandwidth_rad_s


def gains_entry(lp: LoopDef, gains: Mapping[str, float]) -> dict[str, Any]:
    """One loop's entry of a gains file."""
    return {"structure": lp.structure, "gains": {k: float(v) for k, v in gains.items()}, "dt": lp.dt}


def check_gains_file(study: StudyDef, data: Any, *, source: str = "gains") -> dict[str, ControllerTF]:
    """Controllers from a gains file ``{loop: {structure, gains, dt}}``, checked against the study."""
    if not isinstance(data, dict):
        raise InvalidStudyError(f"{source}: expected an object {{loop name: {{structure, gains, dt}}}}")
    unknown = sorted(set(data) - {lp.name for lp in study.loop})
    if unknown:
        raise InvalidStudyError(f"{source}: loops not in study {study.name!r}: {unknown}")
    out: dict[str, ControllerTF] = {}
    for lp in study.order():
        e = data.get(lp.name)
        if not isinstance(e, dict) or not isinstance(e.get("gains"), dict):
            raise InvalidStudyError(f"{source}: loop {lp.name!r}: missing, or without a gains object")
        if e.get("structure", lp.structure) != lp.structure:
            raise InvalidStudyError(f"{source}: loop {lp.name!r}: structure is {e.get('structure')!r}, "
                                    f"the study says {lp.structure!r}")
        dt = e.get("dt", lp.dt)
        if dt is not None and (isinstance(dt, bool) or not isinstance(dt, (int, float))):
            raise InvalidStudyError(f"{source}: loop {lp.name!r}: dt must be a number of seconds (or null), "
                                    f"got {dt!r}")
        if (dt is None) != (lp.dt is None) or (dt is not None and abs(float(dt) - lp.dt) > SAME_DT_RTOL * lp.dt):
            raise InvalidStudyError(f"{source}: loop {lp.name!r}: dt is {dt}, the study says {lp.dt}")
        try:
            out[lp.name] = controller_of(lp, e["gains"])
        except TunerError as err:
            raise InvalidStudyError(f"{source}: loop {lp.name!r}: gains: {err}") from None
    return out


def evaluate_gains(study: StudyDef, controllers: Mapping[str, ControllerTF],
                   loops: Sequence[LoopDef] | None = None) -> dict[str, LoopEval]:
    """Verify every loop of the study (``loops``: these, e.g. a :meth:`~StudyDef.chain`) with the given controllers,
    inner loops first, each outer one with the bandwidth of the loop it wraps."""
    evals: dict[str, LoopEval] = {}
    for lp in study.order() if loops is None else loops:
        evals[lp.name] = evaluate_loop(study, lp, controllers[lp.name], controllers,
                                       inner_bandwidth_rad_s=_inner_bw(evals, lp))
    return evals


def evaluate_thesis(study: StudyDef, tuned: Mapping[str, ControllerTF]) -> dict[str, LoopEval]:
    """The printed controllers, verified as printed. A cascade's printed outer controller is
    evaluated around its inner loop's printed controller (the tuned one if none is printed)."""
    ctrls = dict(tuned)
    printed = {lp.name: c for lp in study.loop if (c := thesis_controller_of(lp)) is not None}
    ctrls.update(printed)
    evals: dict[str, LoopEval] = {}
    for lp in study.order():
        if lp.name in printed and all(i.name in ctrls for i in study.chain(lp.name)):
            evals[lp.name] = evaluate_loop(study, lp, printed[lp.name], ctrls,
                                           inner_bandwidth_rad_s=_inner_bw(evals, lp))
    return evals


def tune_loop(study: StudyDef, lp: LoopDef, controllers: Mapping[str, ControllerTF]) -> dict[str, Any]:
    """Tune one loop (its inner loops' controllers given) and return its JSON-ready result."""
    from ..tuning import tune

    plants = loop_plants(study, lp, controllers)
    vehicle = vehicle_of(lp)
    extra = {} if vehicle is None else {"vehicle": vehicle}
    if lp.actuator is not None:
        extra["actuator"] = lp.actuator.to_actuator()
    res = tune(plants, structure=lp.structure, spec=lp.spec, dt=lp.dt, **extra,
               seed=study.seed if lp.seed is None else lp.seed,
               time_budget_s=study.time_budget_s if lp.time_budget_s is None else lp.time_budget_s,
               n_trials=lp.n_trials, **({} if lp.n_starts is None else {"n_starts": lp.n_starts}),
               effort=lp.effort or study.effort)
    inner_bw = None
    if lp.inner is not None:
        inner = evaluate_loop(study, study.get(lp.inner), controllers[lp.inner], controllers)
        inner_bw = inner.nominal.metrics.bandwidth_rad_s
    ev = evaluate_loop(study, lp, res.controller, {**controllers, lp.name: res.controller},
                       analyses=res.analyses, inner_bandwidth_rad_s=inner_bw)
    out = {"loop": lp.name, "key": loop_key(study, lp.name), "structure": lp.structure,
           "gains": dict(res.gains), "dt": lp.dt, **ev.to_dict(), "solver": dict(res.solver),
           "spec": lp.spec.model_dump(), "plant": [p.describe() for p in plants]}
    if res.analyses[0].saturated is not None:  # the step the actuator allows
        out["saturated_step"] = res.analyses[0].saturated.to_dict()
    if res.vehicle is not None:  # the vehicle's current tune next to the proposed one
        d = res.to_dict()
        out["vehicle"] = d["vehicle"]
        out["current"] = d["current"]
    if lp.data is not None:
        out["identification"] = identification_summary(lp)
        out.update(uncertainty_checks(lp, res.controller, seed=study.seed if lp.seed is None else lp.seed))
    return jsonable(out)


def uncertainty_checks(lp: LoopDef, controller: ControllerTF, *, seed: int = 0) -> dict[str, Any]:
    """A data loop's controller judged beyond the identified model: the Monte Carlo check on draws from the
    identified covariance (``robust`` / ``monte_carlo``, :mod:`tuner.robust`) and the verifier on the
    ``true_plant`` the log was made from."""
    from ..robust import MONTE_CARLO_DRAWS, monte_carlo, plant_set

    out: dict[str, Any] = {}
    ident = identified(lp)
    if lp.robust is not None:
        out["robust"] = plant_set(ident, lp.robust, dt=lp.dt)[1].to_dict()
    n = lp.monte_carlo if lp.monte_carlo is not None else (MONTE_CARLO_DRAWS if lp.robust is not None else 0)
    if n:
        out["monte_carlo"] = monte_carlo(ident, controller, lp.spec, n=n, seed=seed).to_dict()
    true = true_plant_of(lp)
    if true is not None:
        a = analyze(true, controller, lp.spec)
        out["true_plant"] = {"plant": true.describe(), **a.to_dict()}
    return out


def identification_summary(lp: LoopDef) -> dict[str, Any]:
    """What the study records about a data loop's identification (the full response is in the plot)."""
    d = identified(lp).to_dict()
    val = d["validation"]
    if val is not None:
        val = {k: v for k, v in val.items() if k != "series"}
    keep = ("model", "cost", "quality", "check", "verdict", "warnings", "band_rad_s", "uncertainty", "rate_hz",
            "n_samples", "fit_duration_s", "closed_loop")
    return {"file": lp.data.file if lp.data else None, **{k: d[k] for k in keep}, "validation": val,
            "plant": identified(lp).describe()}
