"""The facade: ``tune(plant_or_plants, *, structure, spec, ...) -> TuneResult``.

The search (:mod:`tuner.optimize.engine`) runs rounds until it has converged or the budget is
used: a deterministic first round (plant-based starts, a fixed space-filling set, a contained
structure's answer) scored by the batched verifier, the best distinct candidates refined by the
CasADi NLP on the exact problem; then restarts (a scrambled Sobol set, refinements outside the basins found, scans;
Optuna's seeded sampler too at the fast and thorough efforts, or when ``n_trials`` or ``sampler`` is given).
The finalists are re-verified by :mod:`tuner.analysis` at full resolution on every plant; only
verified numbers are reported, and the best verified candidate wins. When none meets the spec,
the least-violating one is returned with ``meets_spec: false`` and the failing constraints.
"""

from __future__ import annotations

import contextvars
import logging
import math
import time
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np

from .analysis.verify import Analysis, Metrics
from .bounds import describe
from .controllers import ControllerTF
from .errors import TunerError
from .jsonio import jsonable
from .limits import OBJECTIVES
from .problem import MAX_PLANTS, TuningProblem
from .spec import Check, Spec

__all__ = ["TuneResult", "tune", "MAX_PLANTS"]

log = logging.getLogger(__name__)

@dataclass(frozen=True, eq=False)
class TuneResult:
    """What :func:`tune` returns: the gains, the controller and the verifier's analysis of every plant.

    Every number in it comes from the verifier (:mod:`tuner.analysis`), at full resolution, on every plant
    of the set (nominal first); none is the optimiser's own estimate.

    Attributes
    ----------
    structure : str
        The controller structure (a key of :data:`tuner.controllers.STRUCTURES`).
    gains : dict of str to float
        The tuned parameters by name (e.g. ``{"Kp": ..., "Ki": ...}``).
    controller : ControllerTF
        The controller's transfer function (continuous, or at ``dt``).
    analyses : tuple of Analysis
        The verifier's analysis of the loop on each plant, nominal first.
    solver : dict
        The search's record: ``method``, ``seed``, ``stop``, ``converged``, ``wall_time_s``, counts.
    spec : Spec
        The specification tuned for.
    reasons : tuple of tuner.diagnose.Reason
        When the spec is not met: why, and what would make it feasible.
    at_bounds : tuple of dict
        Parameters on a search bound or a default design limit (:mod:`tuner.bounds`).
    limits : tuple of dict
        The default design limits in force (``field``, ``value``, ``rule``).

    See Also
    --------
    tune, analyze, Analysis, Metrics

    Examples
    --------
    >>> import control
    >>> from tuner import tune
    >>> res = tune(control.tf([1], [1, 1]), structure="pi", time_budget_s=1)  # a tiny budget (default: fitted)
    >>> res.meets_spec
    True
    >>> sorted(res.gains)
    ['Ki', 'Kp']
    >>> bool(res.metrics.phase_margin_deg >= res.spec.phase_margin_min_deg)
    True
    >>> res.worst is res.analyses[0]  # one plant: it is the one that limits the design
    True
    >>> d = res.to_dict()
    >>> d["meets_spec"], d["objective"]["name"]
    (True, 'settling_time')
    """

    structure: str
    gains: dict[str, float]
    controller: ControllerTF
    analyses: tuple[Analysis, ...]  # the verifier's, one per plant (nominal first)
    solver: dict[str, Any]
    spec: Spec
    reasons: tuple[Any, ...] = ()  # tuner.diagnose.Reason: why the spec is not met, what would make it feasible
    at_bounds: tuple[dict[str, Any], ...] = ()  # parameters on a search bound or a default limit (tuner.bounds)
    limits: tuple[dict[str, Any], ...] = ()  # the default design limits in force (field, value, rule)
    robust: Any = None  # tuner.robust.RobustDesign: a design from an identification (plant set, Monte Carlo)
    #: a firmware law tuned for a vehicle (``vehicle=``): what its parameters fixed (tuner.firmware.bind.vehicle_dict)
    vehicle: dict[str, Any] | None = None
    #: the vehicle's current gains (``vehicle["current_gains"]`` with the law's fixed values) analysed on every
    #: plant, next to the proposed design's ``analyses`` (empty without a vehicle)
    current: tuple[Analysis, ...] = ()
    #: a firmware law's axis (``roll``, ``pitch``, ``yaw``): the one whose documented ranges the search kept to, and
    #: whose parameter names an export writes (None for the generic structures)
    axis: str | None = None
    #: a name for each plant of ``analyses`` (``nominal``, ``plant #2``, ``nominal x0.8`` for a gain-variation
    #: member: :attr:`tuner.problem.TuningProblem.labels`); empty: ``nominal``, ``plant #2``, ...
    plant_labels: tuple[str, ...] = ()
    #: a design from an identification: its rating and fit (``quality``, ``cost``, ``check``, ``band_rad_s``,
    #: ``verdict``), None otherwise
    identification: dict[str, Any] | None = None

    def label(self, i: int) -> str:
        """The name of plant ``i`` of the set (``nominal``, ``plant #2``, ``nominal x1.25``)."""
        if i < len(self.plant_labels):
            return self.plant_labels[i]
        return "nominal" if i == 0 else f"plant #{i + 1}"

    @property
    def meets_spec(self) -> bool:
        """True when every check holds on every plant of the set (from an identification, the checks on the measured
        response and of the identification's rating too: :mod:`tuner.analysis.measured`)."""
        return all(a.meets_spec for a in self.analyses)

    @property
    def verdict(self) -> str:
        """The verdict in words (:func:`tuner.text.verdict`): what holds on the model, on the measured response, and
        whether the identification lets it count for the airframe (``on the model only``)."""
        from .text import verdict

        return verdict(self.analyses)

    @property
    def basis(self) -> str:
        """What the verdict rests on: ``model`` (no flight data), ``model and measured response`` (an identification
        rated good or acceptable), ``model only`` (an identification rated below acceptable)."""
        from .text import verdict_basis

        return verdict_basis(self.analyses)

    @property
    def metrics(self) -> Metrics:
        """The nominal plant's metrics (``analyses[0].metrics``): ``res.metrics.phase_margin_deg``; every
        plant's are in ``[a.metrics for a in res.analyses]``, the limiting plant's in ``res.worst.metrics``."""
        return self.analyses[0].metrics

    @property
    def checks(self) -> list[Check]:
        """The nominal plant's checks against the spec (``analyses[0].checks``)."""
        return self.analyses[0].checks

    @property
    def failing(self) -> list[Check]:
        """The failing checks on every plant (a check failing on several plants is listed once per plant)."""
        return [c for a in self.analyses for c in a.failing]

    @property
    def worst(self) -> Analysis:
        """The analysis of the plant that limits the design.

        * If some plant fails the spec: the failing plant that fails worst, i.e. an unstable loop first, then
          the largest sum of normalised violations (each failing check's ``violation`` divided by its
          requirement, as the search grades infeasibility: :func:`tuner.optimize.scoring.violation`).
        * Else (every plant meets the spec): the plant with the worst value of the spec's objective
          (:func:`tuner.optimize.scoring.objective_value`: the largest settling time for ``settling_time``,
          the smallest disk margin for ``disk_margin``, ...); its value is :attr:`objective`.

        Ties go to the earlier plant (the nominal first). With one plant it is ``analyses[0]``.
        """
        from .optimize.scoring import objective_value, violation

        failing = [a for a in self.analyses if not a.meets_spec]
        if failing:
            return max(failing, key=lambda a: (not a.metrics.stable, violation(a)))
        values = [objective_value(a, self.spec) for a in self.analyses]
        worst = max(range(len(values)), key=lambda i: math.inf if math.isnan(values[i]) else values[i])
        return self.analyses[worst]

    @cached_property
    def objective(self) -> float:
        """The spec's objective, worst case over the plants, as the verifier computes it (see
        :class:`~tuner.spec.Spec`, ``objective``; for ``bandwidth`` it is minus the bandwidth)."""
        from .optimize.scoring import objective_value

        return max(objective_value(a, self.spec) for a in self.analyses)

    def __repr__(self) -> str:
        from .display import tune_repr

        return tune_repr(self)

    def _repr_html_(self) -> str:
        from .display import tune_html

        return tune_html(self)

    def plot(self, kind: str = "all", **kw: Any) -> Any:
        """Every plant's loop as a :class:`matplotlib.figure.Figure` (no pyplot state, no backend chosen; save it
        with ``fig.savefig``): ``kind`` is ``all``, ``step``, ``bode`` or ``nyquist``; ``kw`` go to
        :func:`tuner.analysis.plots.figure` (``title``, ``labels``)."""
        from .analysis.plots import figure

        kw.setdefault("title", f"{self.structure}: " + ", ".join(f"{k} = {v:.4g}" for k, v in self.gains.items()))
        return figure(self, kind, **kw)

    def to_control(self) -> Any:
        """The controller as a ``control.TransferFunction`` with its ``dt`` (0 = continuous)."""
        from .interop import controller_to_control

        return controller_to_control(self.controller)

    def loop_tfs(self, plant: int = 0, *, pade_order: int | None = 6) -> Any:
        """``L``, ``S``, ``T`` of the loop with plant ``plant`` (0 = nominal) as python-control objects; see
        :meth:`tuner.analysis.Analysis.loop_tfs`."""
        if not (isinstance(plant, int) and 0 <= plant < len(self.analyses)):
            raise TunerError(f"plant must be an index from 0 to {len(self.analyses) - 1}, got {plant!r}",
                             field="plant")
        return self.analyses[plant].loop_tfs(pade_order=pade_order)

    def export(self, format: str = "c", *, name: str = "controller", dt: float | None = None,
               method: str = "tustin", u_min: float | None = None, u_max: float | None = None) -> str:
        """The controller as C99, a Python class or text: :func:`tuner.export.export_controller`."""
        from .export import export_controller

        return export_controller(self, format=format, name=name, dt=dt, method=method, u_min=u_min, u_max=u_max)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (after :func:`~tuner.jsonio.jsonable`): the analyze fields + gains, controller, solver.

        ``metrics`` and ``checks`` are the nominal plant's; with several plants,
        ``plants`` holds every plant's metrics and checks and ``meets_spec`` is
        true only if all pass.
        """
        nominal = self.analyses[0].to_dict()
        out: dict[str, Any] = {
            "structure": self.structure,
            "gains": dict(self.gains),
            "controller": self.controller.to_dict(),
            "metrics": nominal["metrics"],
            "checks": nominal["checks"],
            "meets_spec": self.meets_spec,
            "verdict": self.verdict,
            "basis": self.basis,
            "objective": {"name": self.spec.objective, "value": self.objective},
            "reasons": [r.to_dict() for r in self.reasons],
            "at_bounds": [dict(e, text=describe(e)) for e in self.at_bounds],
            "limits": [dict(e) for e in self.limits],
            "failing": sorted({c.name for a in self.analyses for c in a.failing}),
            "solver": dict(self.solver),
            "spec": self.spec.model_dump(),
        }
        if self.axis is not None:
            out["axis"] = self.axis
        if len(self.analyses) > 1:
            out["plants"] = [{"label": self.label(i), **a.to_dict()} for i, a in enumerate(self.analyses)]
        if self.robust is not None:
            out["robust"] = self.robust.to_dict()
        if "measured" in nominal:
            out["measured"] = nominal["measured"]
        if "saturated_step" in nominal:
            out["saturated_step"] = nominal["saturated_step"]
        if self.identification is not None:
            out["identification"] = dict(self.identification)
        if self.vehicle is not None:
            out["vehicle"] = dict(self.vehicle)
        if self.current:
            from .text import verdict

            cur = self.current[0].to_dict()
            out["current"] = {"gains": dict(self.vehicle["current_gains_law"]) if self.vehicle else {},
                              "metrics": cur["metrics"], "checks": cur["checks"],
                              "meets_spec": all(a.meets_spec for a in self.current),
                              "verdict": verdict(self.current)}
            for k in ("measured", "saturated_step"):
                if k in cur:
                    out["current"][k] = cur[k]
        return out

    def to_json(self) -> dict[str, Any]:
        """:meth:`to_dict` made JSON-ready (:func:`tuner.jsonio.jsonable`: non-finite numbers as strings)."""
        return jsonable(self.to_dict())


def tune(
    plant_or_plants: Any,
    *,
    structure: str | None = None,
    spec: Spec | None = None,
    dt: float | None = None,
    delay: float | Sequence[float] | None = None,
    seed: int = 0,
    time_budget_s: float | None = None,
    n_trials: int | None = None,
    n_starts: int | None = None,
    sampler: Any = None,
    storage: Any = None,
    local: bool = True,
    nlp_solver: str = "sqp",
    diagnose: bool = True,
    robust: float | None = None,
    monte_carlo: int | None = None,
    effort: str = "default",
    vehicle: Any = None,
    actuator: Any = None,
    axis: str | None = None,
) -> TuneResult:
    """Tune ``structure`` on a plant (or a set of plants: every constraint on every plant).

    Parameters
    ----------
    plant_or_plants : Plant, control.TransferFunction, control.StateSpace, a sequence, TuningProblem, IdentifyResult
        The plant; for robust tuning the whole set, nominal first (one controller, every constraint on every
        plant). A python-control model may be continuous or discrete (its ``dt``; ``dt=True`` is refused: give
        the number), see :mod:`tuner.interop`. A :class:`~tuner.problem.TuningProblem` already holds the
        structure, spec and dt. An :class:`~tuner.identify.IdentifyResult` (from :func:`tuner.identify`) is
        its fitted model with the delay as fitted (any delay is exact in a sampled-data loop).
    structure : str
        One of :data:`tuner.controllers.STRUCTURES`: ``p``, ``pi``, ``pd``, ``pid``, ``pid_z`` (discrete only),
        ``pid2`` (2-DOF PID with setpoint weights ``b``, ``c``), ``pid_mf2`` (``pidf2``, its deprecated name),
        ``lead``, ``lag``, ``leadlag``, and the autopilots' rate laws ``px4_rate`` and ``ardupilot_rate``
        (discrete; computed as the firmware computes them, :mod:`tuner.firmware.laws`).
    spec : Spec, optional
        Defaults to ``Spec()``: the thesis spec (PM >= 60 deg, GM >= 6 dB, overshoot <= 10 %, zero steady-state
        error, minimum 2 % settling time) with the default design limits (derivative filter N <= 20, Tf >= dt/pi,
        noise budget Mks <= 10 K0; ``Spec.thesis()`` lifts them). ``Spec.objective`` says what is minimised.
    dt : float, optional
        Controller sample time, s; ``None`` = continuous (or the plants' dt if discrete).
    delay : float or sequence of float, optional
        Input delay of python-control plants, s (one for all, or one per plant; whole samples of a discrete
        plant). A :class:`~tuner.plant.Plant` carries its own delay.
    seed : int
        Seeds the global search beyond the deterministic first round: same seed, same gains.
    time_budget_s : float, optional
        Wall-time budget, a cap checked between the search's steps (a started step, such as an NLP build, is not
        interrupted, so a run can overrun it by a step). Default (None): the search counts work, not seconds: it
        stops on its evidence rule (``solver["stop"] == "converged"``) or when the restarts its effort affords
        have run (``"work"``), the same steps, and so bitwise the same gains for a seed, on an idle and on a
        loaded machine, for every run the cap did not cut (a cut run's gains depend on where it was cut);
        ``AUTO_WALL_CAP_S`` (60 s, NLP builds included) is only a cap. Where a cap (that one, or a
        number given here) ends the search, ``solver["stop"]`` is ``"budget"`` and ``solver["cut"]`` says which
        step it cut and how many restarts had run; ``solver["build_s"]`` says how long the NLP builds took.
    n_trials : int, optional
        Optuna points asked per restart (default 24). The default effort's restarts do not ask Optuna (a scrambled
        Sobol set, refinements and scans find the basins; ``effort="fast"`` and ``"thorough"`` ask it); giving
        ``n_trials`` or a ``sampler`` makes every restart ask Optuna too, at any effort.
    n_starts : int, optional
        How many distinct candidates the local NLP refines in the first round (default: the effort's).
    sampler, storage
        Optuna sampler and storage (in-memory TPE by default; a storage URL is accepted): the restarts' Optuna step
        (see ``n_trials``) uses the sampler, seeded by ``seed`` and told every point scored before it; the storage
        records every point the tune scored as a trial (it does not change the search).
    local : bool
        Run the CasADi local stage (``False`` = global search only, for comparison).
    nlp_solver : str
        ``"sqp"`` (default: CasADi SQP, limited-memory Hessian, DAQP) or ``"ipopt"``; same problem.
    diagnose : bool
        When the spec is not met, say why in ``reasons`` (:mod:`tuner.diagnose`: limits that are
        impossible by definition, and for each failing limit the tightest value a short re-tune with it
        relaxed found feasible), within what is left of the budget.
    robust : float, optional
        With an identification result: design for the plant set spanned by the identified parameters'
        ``robust``-sigma Cramér–Rao bounds (the nominal, the corners of the dominant parameters, +-K sigma of
        the others; :mod:`tuner.robust`), then check the controller on ``monte_carlo`` draws from the
        parameters' covariance. Reported in ``result.robust``.
    monte_carlo : int, optional
        Draws of the Monte Carlo check (seeded by ``seed``); default 200 with ``robust``, else none (give a
        number to check a nominal design from an identification too).
    effort : str
        How hard to search (:data:`tuner.optimize.engine.EFFORTS`): ``"fast"`` is the first round alone
        (it stops when two refinements agree; without an independent restart it never claims convergence),
        ``"default"`` adds 4 independent space-filling restarts (its work budget; multistart's Bayesian stopping rule
        cannot hold before the fourth: Boender and Rinnooy Kan 1987: after n restart draws reached w distinct optima,
        counted by value, the posterior expected share of the regions of attraction not reached, w (w + 1) / (n (n -
        1)), is at most 0.2: it needs at least 4 draws, all in one optimum; it estimates what the draws leave
        unexplored, it does not bound whether a better design exists), ``"thorough"`` more (4 to 8, three refinements
        each), more starts and points and a sharper polish (twice the grid detail, the settling time between the
        grid's points, each step confirmed by the verifier); measured costs in bench/QUALITY.md. "converged" (the
        ``claim`` of ``solver["optimality"]``, and ``solver["converged"]``) only where that estimate, which
        ``solver["optimality"]["evidence"]`` holds with the figures behind it, is at most 0.2 and at least 2 (thorough
        3) restarts' draws re-found the answer's value (:meth:`tuner.optimize.engine.Engine.evidence`); otherwise "not
        confirmed" (bench/convergence.py measures the claim).
    vehicle : tuner.firmware.VehicleParams, optional
        With ``px4_rate`` or ``ardupilot_rate``: what the vehicle fixes (loop rate, filters, PX4's ``K``, the
        integrator limit; :func:`tuner.firmware.read_params` reads them from a ``.params``, ``.parm`` or ULog
        file). The loop's ``dt`` defaults to the vehicle's loop rate (a contradicting ``dt`` is refused); the
        tuner chooses ``P``, ``I``, ``D``, ``FF``; the vehicle's current gains are analysed too
        (``result.current``), next to the proposed ones.
    actuator : tuner.analysis.saturation.Actuator, optional
        The actuator's limits and a step amplitude: the verifier also runs that step with the output clamped and
        the integrator handled as the law does, on every plant (``analyses[i].saturated``, JSON
        ``saturated_step``), and its overshoot and settling are checked (they count in ``meets_spec``). The
        search itself designs the linear loop. Needs a sample time.
    axis : str, optional
        With ``px4_rate`` or ``ardupilot_rate``: the axis (``roll``, ``pitch``, ``yaw``) whose documented parameter
        ranges the search stays inside (:func:`tuner.firmware.names.law_ranges`: what the vehicle's parameter file
        can hold); default the vehicle's axis, else ``roll``.

    Returns
    -------
    TuneResult
        The gains, the controller, the verifier's analysis of every plant (``meets_spec``, ``failing``),
        the solver's record; ``.to_control()``, ``.loop_tfs()``, ``.plot()``, ``.export(...)``.

    Raises
    ------
    TunerError
        Bad input, with ``field`` naming it (e.g. ``("plants", 1, "delay")``, ``("dt",)``, ``("structure",)``).

    Examples
    --------
    >>> import control
    >>> from tuner import tune
    >>> res = tune(control.tf([1], [1, 1]), structure="pi", time_budget_s=1)  # a tiny budget (default: fitted)
    >>> res.meets_spec
    True
    >>> bool(res.metrics.overshoot_pct <= 10.0)  # the default spec: overshoot <= 10 %
    True

    A sampled-data loop (the controller at ``dt`` drives the continuous plant through a hold):

    >>> res = tune(control.tf([4.0], [1.0, 2.0, 4.0]), structure="pi", dt=0.05, time_budget_s=1)
    >>> res.controller.dt, res.meets_spec
    (0.05, True)
    """
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or not 0 <= int(seed) < 2**32:
        raise TunerError(f"seed must be an integer from 0 to 2**32 - 1, got {seed!r}", field="seed")
    auto = time_budget_s is None
    if not auto:
        check_budget(time_budget_s)
    from .optimize.engine import EFFORTS

    if effort not in EFFORTS:
        raise TunerError(f"effort must be one of {', '.join(EFFORTS)}, got {effort!r}", field="effort")
    if n_starts is not None and not (isinstance(n_starts, (int, np.integer)) and not isinstance(n_starts, bool)
                                     and 1 <= n_starts <= 50):
        raise TunerError(f"n_starts must be an integer from 1 to 50, got {n_starts!r}", field="n_starts")
    if nlp_solver not in ("ipopt", "sqp"):
        raise TunerError(f"nlp_solver must be 'ipopt' or 'sqp', got {nlp_solver!r}", field="nlp_solver")
    from .optimize.builds import build_seconds

    t0, built0 = time.perf_counter(), build_seconds()

    # the default budget counts work, not seconds (issue 41): the search ends on its evidence rule or its work budget
    # of restarts (Effort.max_restarts), the same steps on an idle and on a loaded machine; the wall clock is only a
    # cap, AUTO_WALL_CAP_S builds included, checked between steps (a started step can overrun it), which says what
    # it cut when it binds (solver["cut"]). A tune nested
    # in such a tune (a robustness objective's fastest design, a diagnosis's relaxed re-tune) stays within the outer
    # cap; one with its own budget does not count builds against it
    outer = _OUTER_CAP.get()
    cap = (t0 + AUTO_WALL_CAP_S if outer is None else min(t0 + AUTO_WALL_CAP_S, outer)) if auto else outer
    cap_token = _OUTER_CAP.set(cap)
    if local:
        import casadi  # noqa: F401 - loaded before the limit, so that its OpenMP runtime is limited too
    # one BLAS/OpenMP thread for the whole tune, the plant's discretisation included (its matrices are tiny: a 3x3
    # expm costs 10 us on one thread and 3-12 ms with OpenBLAS's default pool of two); scoped, so the caller's own
    # threading is left as it was
    if local:  # the NLPs this tune builds stay in the build cache until it ends
        from .optimize.nlp.transcribe import working_set
    try:
        with _one_thread(), (working_set() if local else nullcontext()):
            plant_or_plants, ident, design, n_mc = _from_identification(plant_or_plants, robust, monte_carlo, dt,
                                                                        delay)
            plant_or_plants, vehicle, delay = _typed_plants(plant_or_plants, vehicle, ident, delay)
            problem, current_gains, structure = _problem(plant_or_plants, structure, spec, dt, delay, vehicle, axis)
            _check_actuator(actuator, problem)
            # the default budget: the hard cap is the deadline (builds included), nothing moves it
            budget = cap - t0 if auto else float(time_budget_s)
            opts = _Opts(seed=int(seed), budget_s=budget, deadline=t0 + budget, t0=t0, n_starts=n_starts,
                         n_trials=n_trials, sampler=sampler, storage=storage, local=local, nlp_solver=nlp_solver,
                         diagnose=diagnose, effort=effort, build_cap=None if auto else cap, built0=built0,
                         auto=auto)
            run = _search(problem, opts)
            res = _verified(run, problem, opts, structure)
            res = _diagnosed(res, run, problem, opts)
            res = _annotated(res, problem, ident, actuator, vehicle, current_gains, design, n_mc, int(seed))
            return res
    finally:
        _OUTER_CAP.reset(cap_token)


@dataclass(frozen=True)
class _Opts:
    """How one tune runs (what :func:`tune` was given, checked)."""

    seed: int
    budget_s: float
    deadline: float
    t0: float
    n_starts: int | None
    n_trials: int | None
    sampler: Any
    storage: Any
    local: bool
    nlp_solver: str
    diagnose: bool
    effort: str
    build_cap: float | None = None  # the default budget's wall-clock cap (the NLP builds not counted before it)
    built0: float = 0.0  # the build clock when the tune began (what nested tunes build is not the search's time)
    auto: bool = False  # the default budget (time_budget_s=None)


@dataclass
class _Run:
    """A search and what its verification needs: the engine, the problem it searched (the asked one, or with the
    limits no gains can meet set as the reasons by definition suggest), those reasons, the fastest design of a
    robustness objective, the time share kept for the verification."""

    eng: Any
    searched: TuningProblem
    decided: list[Any]
    fast: TuneResult | None
    reserve: float
    stop: Any = None
    t_verify: float = 0.0
    load: dict[str, Any] | None = None  # the load design's record: the fastest settling time and the limit it set


def check_budget(time_budget_s: Any) -> None:
    """A time budget, s, as ``tune`` and ``tradeoff`` take it: a finite number > 0 (not a bool: True is an int, 1 s);
    a :class:`TunerError` at ``time_budget_s`` otherwise."""
    if not (isinstance(time_budget_s, (int, float)) and not isinstance(time_budget_s, bool)
            and math.isfinite(time_budget_s) and time_budget_s > 0):
        raise TunerError(f"time_budget_s must be a finite number > 0, got {time_budget_s!r}", field="time_budget_s")


def _from_identification(plant_or_plants: Any, robust: float | None, monte_carlo: int | None, dt: float | None,
                         delay: Any) -> tuple[Any, Any, Any, int]:
    """An identification's plant set (its nominal model, or the ``robust``-sigma set), the identification, the robust
    design record and the Monte Carlo draws; other inputs as they are (:mod:`tuner.robust` not imported for them: a
    cold ``tuner tune`` of a model never needs it)."""
    from ._lazy import is_identification

    if is_identification(plant_or_plants):
        from .robust import MC_SIGMA, check_draws, check_spread, plant_set

        if delay is not None:
            raise TunerError("an identification carries its fitted delay: leave delay out", field="delay")
        ident = plant_or_plants
        plants, design = plant_set(ident, robust, dt=dt)
        n_mc = check_draws(200 if (monte_carlo is None and robust is not None) else (monte_carlo or 0))
        if n_mc:  # draws from bounds too wide are no plants of this airframe: refused before the tune
            check_spread(ident, MC_SIGMA, dt=dt, field="monte_carlo")
        return plants, ident, design, n_mc
    if robust is not None or monte_carlo is not None:
        raise TunerError("robust= and monte_carlo= need an identification result: tune(identify(...), robust=2)",
                         field="robust" if robust is not None else "monte_carlo")
    return plant_or_plants, None, None, 0


def _problem(plant_or_plants: Any, structure: Any, spec: Spec | None, dt: float | None, delay: Any, vehicle: Any,
             axis: str | None = None) -> tuple[TuningProblem, dict[str, float] | None, Any]:
    """The validated problem, the vehicle's current gains (a firmware law bound to its parameters), and the
    structure as given (a firmware law's, bound to the vehicle and to the axis's documented ranges)."""
    current_gains = None
    if axis is not None:
        from .firmware.names import AXES

        if axis not in AXES:
            raise TunerError(f"axis must be one of {', '.join(AXES)}, got {axis!r}", field="axis")
        v_axis = getattr(vehicle, "axis", None)
        if vehicle is not None and v_axis and v_axis != axis:
            raise TunerError(f"axis {axis!r} contradicts the vehicle's parameters, read for the {v_axis} axis: "
                             "leave axis out, or read the parameters for that axis", field="axis")
        if structure is not None and not isinstance(plant_or_plants, TuningProblem):
            from .controllers import Structure, get_structure

            st = structure if isinstance(structure, Structure) else get_structure(structure)
            if st.firmware:
                structure = st.with_ranges(axis)
                if vehicle is None:  # the axis's own defaults (ArduPilot's yaw FLTE 2.5 Hz, PX4's yaw low-pass 2 Hz)
                    from .firmware.laws import axis_fixed

                    structure = structure.with_fixed(axis_fixed(st.firmware, axis, structure.fixed_values))
    if vehicle is not None:
        from .firmware.bind import bind_law

        if isinstance(plant_or_plants, TuningProblem):  # its structure bound already: the current gains
            _, _, current_gains = bind_law(plant_or_plants.structure, vehicle, plant_or_plants.dt, field="vehicle")
        else:
            if structure is None:
                from .firmware.registry import structures

                raise TunerError("give the firmware law, structure=" + " or ".join(repr(s) for s in structures()),
                                 field="structure")
            structure, dt, current_gains = bind_law(structure, vehicle, dt, field="vehicle")
    if isinstance(plant_or_plants, TuningProblem):
        if structure is not None or spec is not None or dt is not None or delay is not None:
            raise TunerError("a TuningProblem already holds the plants, structure, spec and dt: do not pass them "
                             "again", field="structure")
        return plant_or_plants, current_gains, structure
    if structure is None:
        raise TunerError("give the controller structure, e.g. structure='pid'", field="structure")
    from .interop import as_plants

    problem = TuningProblem.build(as_plants(plant_or_plants, delay=delay), structure=structure, spec=spec, dt=dt)
    return problem, current_gains, structure


def _typed_plants(plants: Any, vehicle: Any, ident: Any, delay: Any) -> tuple[Any, Any, Any]:
    """Typed plants (no identification) tuned for a vehicle: its gyro low-pass added to each, and said in the
    vehicle's record (:func:`tuner.firmware.bind.typed_plant`); anything else as it is. Returns the plants, the
    vehicle and the delay still to apply (None once the plants carry it)."""
    if vehicle is None or ident is not None or isinstance(plants, TuningProblem) or not hasattr(vehicle, "firmware"):
        return plants, vehicle, delay
    import dataclasses

    from ._lazy import is_instance_of
    from .firmware.bind import typed_plant
    from .interop import as_plants

    items = plants if isinstance(plants, (list, tuple)) else [plants]
    if getattr(vehicle, "typed_plant", None) is not None or any(  # (added by the caller; an identified model)
            is_instance_of(p, "tuner.identify.result", "IdentifyResult") for p in items):
        return plants, vehicle, delay
    out, rec = [], None
    for p in as_plants(plants, delay=delay):
        q, rec = typed_plant(p, vehicle)
        out.append(q)
    if rec is None:
        return plants, vehicle, delay
    return out, dataclasses.replace(vehicle, typed_plant=rec, notes=(*vehicle.notes, rec["note"])), None


def _check_actuator(actuator: Any, problem: TuningProblem) -> None:
    if actuator is None:
        return
    from .analysis.saturation import Actuator

    if not isinstance(actuator, Actuator):
        raise TunerError("actuator must be a tuner.analysis.saturation.Actuator (Actuator.of(u_max=..., "
                         "step_size=...))", field="actuator")
    if problem.dt is None:
        raise TunerError("the saturated step runs the law at its sample time: give dt", field="dt")


def _search(problem: TuningProblem, o: _Opts) -> _Run:
    """The search: the limits no gains can meet set aside (judged, not searched), a robustness objective's fastest
    design first (it leads the search and is a candidate), then the engine's rounds."""
    from .diagnose import definitional_reasons
    from .optimize.engine import Engine

    decided = definitional_reasons(problem) if o.diagnose else []
    searched = _searchable(problem, decided)  # a limit no gains can meet: searched without it, judged with it
    # keep a share of the budget for the final verification at full resolution
    # (and, when a diagnosis may follow, its share: an infeasible spec's search would otherwise use it all)
    reserve = (_RESERVE + (DIAGNOSIS_SHARE if o.diagnose else 0.0)) * o.budget_s
    # "as robust as possible at this speed": the fastest design meeting the spec leads the search (its refinements
    # then start from a point that meets the settling-time limit; the robustness objectives' landscape is flat
    # where the settling time's is not) and is a candidate itself
    fast = None
    load = None
    if problem.spec.objective in ROBUSTNESS_OBJECTIVES and o.diagnose:
        fast_problem = replace(problem, spec=problem.spec.model_copy(update={"objective": "settling_time"}))
        fast = tune(fast_problem, seed=o.seed, time_budget_s=None if o.auto else FAST_SHARE * o.budget_s,
                    n_starts=o.n_starts,
                    nlp_solver=o.nlp_solver, local=o.local, diagnose=False, effort=o.effort)
    elif load_design(problem):
        # "auto" on a law with its own setpoint path: the search finds the fastest reference step; the load stage then
        # raises its integral action as far as the reference step allows (tuner.optimize.setpoint.raise_integral)
        try:
            searched = TuningProblem.build(list(searched.given_plants), structure=searched.structure, dt=searched.dt,
                                           spec=searched.asked_spec.model_copy(update={"objective": "settling_time"}))
            load = {}
        except TunerError:
            load = None
    seeds = [np.array([fast.gains[k] for k in problem.structure.params], float)] \
        if fast is not None and fast.meets_spec else None
    eng = Engine(searched, seed=o.seed, deadline=o.deadline, solver=o.nlp_solver, local=o.local, n_starts=o.n_starts,
                 n_trials=o.n_trials, sampler=o.sampler, storage=o.storage, reserve_s=reserve, effort=o.effort,
                 seeds=seeds, build_cap=o.build_cap, built0=o.built0)
    run = _Run(eng=eng, searched=searched, decided=decided, fast=fast, reserve=reserve, load=load)
    run.stop = eng.run()
    return run


def load_design(problem: TuningProblem) -> bool:
    """Whether ``problem`` gets the load design of ``objective="auto"``: a law with its own setpoint path (pid2,
    px4_rate, ardupilot_rate) whose objective the structure chose (:func:`tuner.spec.resolved_objective`)."""
    return problem.structure.two_dof and problem.asked_spec.objective == "auto" and problem.spec.objective == "ie"


def _result(run: _Run, problem: TuningProblem, x: np.ndarray, scored: Any, info: dict[str, Any]) -> TuneResult:
    from .bounds import at_bounds

    st = problem.structure
    return TuneResult(structure=st.name, gains=st.named(x), controller=run.eng.ev.controller(x),
                      analyses=scored.analyses, solver=info, spec=problem.spec,
                      at_bounds=tuple(at_bounds(problem, run.eng.space, x, scored.analyses)), limits=problem.limits,
                      axis=st.axis, plant_labels=problem.labels)


def _verified(run: _Run, problem: TuningProblem, o: _Opts, structure: Any) -> TuneResult:
    """The best of the search's finalists as the full verifier judges it against the asked spec, the solver's
    record, and the fastest design where it is better."""
    eng, stop = run.eng, run.stop
    t_verify = time.perf_counter()
    best_x, best = eng.verify_best()
    if run.searched is not problem:  # the verifier's verdict on the asked spec (the impossible limit fails)
        from .optimize.scoring import Evaluator

        eng.ev = Evaluator(list(problem.plants), problem.structure, problem.dt, problem.spec, w0=eng.space.w0,
                           specs=problem.specs)
        best = eng.ev.score(best_x)
    run.t_verify = time.perf_counter() - t_verify
    info: dict[str, Any] = {
        "method": f"optuna+casadi-{o.nlp_solver}" if eng.local else "optuna", "seed": o.seed,
        "stop": stop.stop, "rounds": stop.rounds,
        "budget_exhausted": stop.stop == "budget" or time.perf_counter() > eng.deadline - run.reserve,
        # what the time cap (the default budget's AUTO_WALL_CAP_S, or time_budget_s) cut: None if it cut nothing
        "cut": None if stop.stop != "budget" else {"step": stop.cut, "cap_s": o.budget_s,
                                                   "restarts_done": eng.restarts,
                                                   "restarts_max": eng.optimality()["max_restarts"]},
        "budget_s": o.budget_s, "budget_auto": o.auto, "build_s": eng.build_s,
        "wall_time_s": time.perf_counter() - o.t0, "global_evaluations": stop.batch_evaluations,
        "starts_tried": stop.starts_refined, "nlp_solves": stop.nlp_solves, "nlp_iterations": stop.nlp_iterations,
        "nlp_evaluations": stop.nlp_evaluations, "nlp_solves_ok": stop.nlp_solves_ok, "seeded_from": stop.seeded_from,
        "verifier_evaluations": eng.ev.n_evals, "candidates_verified": eng.verified,
        "effort": o.effort, "optimality": eng.optimality(),
    }
    from .controllers import deprecation_note
    from .display import optimality_line

    note = deprecation_note(structure) if isinstance(structure, str) else None
    if note or stop.notes:
        info["notes"] = list(dict.fromkeys(([note] if note else []) + list(stop.notes)))
    # "converged" is the claim the evidence supports (Engine.optimality), not the stopping rule alone (``stop``)
    info["converged"] = info["optimality"]["claim"] == "converged"
    info["optimality"]["summary"] = optimality_line(info)
    if run.load is not None and best.feasible:
        # the fastest reference step found: its integral action raised for the load, the reference step held
        from .optimize.setpoint import raise_integral

        raised = raise_integral(problem, eng, best_x)
        if raised is not None:
            best_x, stage, best = raised
            info["load_design"] = stage.to_dict()
    elif problem.structure.setpoint and problem.spec.objective in SETPOINT_AFTER and best.feasible:
        # the feedback designed for the load: the setpoint path after it, for the fastest reference step
        from .optimize.setpoint import shape_setpoint

        shaped = shape_setpoint(eng, best_x)
        if shaped is not None:
            best_x, stage, best = shaped
            info["setpoint_stage"] = stage.to_dict()
    res = _result(run, problem, best_x, best, info)
    if run.fast is not None and run.fast.meets_spec:
        pick = _adopt(eng, problem, [run.fast])
        if pick is not None and (not best.feasible or pick[1].score < best.score):
            res = _result(run, problem, *pick, info)
            info["from_fastest_design"] = True
    return res


def _diagnosed(res: TuneResult, run: _Run, problem: TuningProblem, o: _Opts) -> TuneResult:
    """An unmet spec with its reasons (:mod:`tuner.diagnose`, within what is left of the budget), and a relaxed
    re-tune's design where it meets the asked spec after all."""
    if res.meets_spec or not o.diagnose:
        return res
    from .bounds import range_reason
    from .diagnose import diagnose as _diagnose

    if problem.structure.ranges:  # a gain held on an end of its documented range: the first reason
        why = range_reason(problem.structure, list(res.at_bounds), problem.scale[0])
        if why:
            from .diagnose import Reason

            # (the search-based diagnosis relaxes the spec's limits within the same ranges: its re-tunes would end
            # on the same edge, and its advice (another structure) would not be the reason)
            return replace(res, reasons=(Reason(tuple(sorted({c.name for a in res.analyses for c in a.failing})),
                                                why, {}),))

    failing = [c.name for a in res.analyses for c in a.failing]
    left = min(DIAGNOSIS_SHARE * o.budget_s, run.eng.deadline - time.perf_counter())  # within the budget
    found: list[TuneResult] = []
    reasons = _diagnose(problem, failing, seed=o.seed, budget_s=0.0 if run.decided else left,
                        min_tune_s=3 * run.t_verify + 0.02, found=found, analyses=res.analyses,
                        tune_fn=lambda prob, s, b: tune(prob, seed=s, time_budget_s=b, n_starts=1,
                                                        nlp_solver=o.nlp_solver, local=o.local, diagnose=False))
    res = replace(res, reasons=tuple(res.reasons) + tuple(reasons))
    better = _adopt(run.eng, problem, found)  # a relaxed re-tune's design that meets the asked spec after all
    if better is not None:
        res = _result(run, problem, *better, res.solver)  # (it meets the spec: no reasons)
        res.solver["found_by_diagnosis"] = True
    res.solver["wall_time_s"] = time.perf_counter() - o.t0
    res.solver["budget_exhausted"] = res.solver["budget_exhausted"] or time.perf_counter() > run.eng.deadline
    return res


def _annotated(res: TuneResult, problem: TuningProblem, ident: Any, actuator: Any, vehicle: Any,
               current_gains: dict[str, float] | None, design: Any, n_mc: int, seed: int) -> TuneResult:
    """What the user should know beside the design: integral action lost, the loop on the measured response, the
    saturated step, the vehicle's current tune, the robust record and its Monte Carlo check."""
    st = problem.structure
    from .design import dt_note

    slip = dt_note(problem.nominal, problem.dt)  # a sample time implausible for the plant: the likely unit slip
    if slip:
        res.solver.setdefault("notes", []).insert(0, slip)
    for note in (_integral_note(res, problem), _derivative_note(res, problem)):
        if note:
            res.solver.setdefault("notes", []).append(note)
    if ident is not None:  # the nominal loop on the measured response too, next to the model's, and its checks
        res = _with_measured(res, ident)
        res = replace(res, identification=identification_summary(ident))
        note = _measured_note(res)
        if note:
            res.solver.setdefault("notes", []).append(note)
        if getattr(ident, "unreliable_feedback", False):
            res.solver.setdefault("notes", []).insert(0, (
                "the identification was flown under feedback and fitted without a reference (quality "
                "'closed-loop'): its model may be the controller's inverse, not the plant; this design is tuned "
                "on that model. Identify again with the exogenous signal as the reference"))
    if actuator is not None:  # the step the actuator allows, as the law runs it (every plant)
        res = replace(res, analyses=tuple(a.with_saturation(actuator, problem.spec, structure=st.name,
                                                            gains=res.gains) for a in res.analyses))
        sat = [c for a in res.analyses for c in a.failing if c.name.startswith("saturated_")]
        if sat:
            s0 = res.analyses[0].saturated
            frac = 100 * s0.saturated_fraction if s0 is not None else math.nan
            res.solver.setdefault("notes", []).append(
                f"the search designs the linear loop; a step of {actuator.step_size:g} with "
                f"{actuator.u_min:g} <= u <= {actuator.u_max:g} saturates {frac:.0f} % of the step and fails "
                f"{', '.join(sorted({c.name for c in sat}))}: a smaller step, wider limits, or a slower design "
                "(a settling-time limit, a lower control peak) fits the actuator")
    if current_gains is not None:
        res = _with_current(res, problem, vehicle, current_gains, ident, actuator)
    if ident is not None:
        if n_mc:
            from .robust import monte_carlo as _mc

            design = replace(design, monte_carlo=_mc(ident, res.controller, problem.spec, n=n_mc, seed=seed))
        res = replace(res, robust=design)
    return res


#: an integral gain below this fraction of the loop's scale K0 w0 is "no integral action" (the search box's gains start
#: at 1e-3 of their unit: tuner.optimize.space.DECADES_BELOW)
INTEGRAL_NONE = 1e-3


def _integral_note(res: TuneResult, problem: TuningProblem) -> str | None:
    """A note when a structure with integral action ends with almost none (the settling-time optimum of a plant that
    integrates itself needs none): what it costs on a vehicle, and how to keep it."""
    st = problem.structure
    if not st.integrating or st.integral is None or st.integral not in res.gains:
        return None
    c = res.controller
    one = 1.0 if c.dt is not None else 0.0
    q, rem = np.polydiv(c.den, [1.0, -one])
    qv = float(np.polyval(q, one))
    if abs(float(rem[-1])) > 1e-9 * float(np.max(np.abs(c.den))) or qv == 0:
        return None
    ki = float(np.polyval(c.num, one)) / qv / (c.dt or 1.0)  # lim (z - 1) C(z)/dt, or lim s C(s)
    unit = problem.scale[0] * problem.scale[1]
    if not (math.isfinite(ki) and abs(ki) < INTEGRAL_NONE * unit):
        return None
    return (f"no integral action: {st.integral} = {res.gains[st.integral]:.3g} (the loop's integral gain {ki:.3g}, "
            f"below {INTEGRAL_NONE:g} of its scale K0 w0 = {unit:.3g}); the {problem.spec.objective} optimum on this "
            "plant does not need it, but a constant load at the plant input (a CG offset, a weak motor, a steady "
            "wind) is then never rejected: it leaves a steady error. To keep integral action demand it, ki_min = "
            f"{INTEGRAL_NONE * 10 * unit:.3g} (CLI --ki-min; the load step's IE is then at most 1/ki_min), or tune "
            "for the load response (objective iae)")


#: the structure a PID-family structure is without its derivative term (what a vanishing D leaves)
WITHOUT_D = {"pid": "pi", "pd": "p", "pid_mf2": "pi", "pid2": "a 2-DOF PI (pid2 with Kd = 0: its b still weights r)"}
#: a limit counts as what drove D away when the answer is within this of it (relative)
BINDING = 0.02


def _derivative_note(res: TuneResult, problem: TuningProblem) -> str | None:
    """A note when a structure with a derivative gain ends with almost none: the design is the structure without it
    (a first-order lag needs no phase lead; a control-peak limit or the noise budget can make D's high-frequency
    gain too dear, and those that are active at the answer are named)."""
    st = problem.structure
    units = st.gain_units or ()
    names = [q for q, k, u in zip(st.params, st.kinds, units) if k == "gain" and u == -1]
    if len(names) != 1 or names[0] not in res.gains:
        return None
    kd = float(res.gains[names[0]])
    unit = problem.scale[0] / problem.scale[1]  # K0 / w0: a derivative gain's unit (gain_units -1)
    if not (math.isfinite(kd) and abs(kd) < INTEGRAL_NONE * unit):
        return None
    spec = problem.spec
    active = []
    for field_, metric in (("control_peak_max", "control_peak"), ("mks_max", "mks")):
        lim = getattr(spec, field_)
        worst = max((float(getattr(a.metrics, metric)) for a in res.analyses), default=math.nan)
        if lim is not None and math.isfinite(worst) and worst >= (1 - BINDING) * lim:
            active.append(f"{field_} ({worst:.3g} of {lim:.3g})")
    why = (f": {' and '.join(active)} {'is' if len(active) == 1 else 'are'} at the limit, and D's high-frequency gain "
           "is what such limits price" if active else ": no limit on the control effort holds it back, so this plant "
           "needs no phase lead")
    without = WITHOUT_D.get(st.name, f"{st.name} with {names[0]} = 0")
    fix = ("to let D act, loosen the limit at work (--control-peak, --mks, --noise-gain)" if active else
           "nothing is lost by flying it without D")
    return (f"no derivative action: {names[0]} = {kd:.3g} (below {INTEGRAL_NONE:g} of its scale K0/w0 = {unit:.3g}); "
            f"the {spec.objective} optimum under this spec does not use it{why}. The loop has no phase lead from D: "
            f"the design is {without}, which flies the same loop with fewer parameters; {fix}")


def _with_measured(res: TuneResult, ident: Any) -> TuneResult:
    """``res`` with its nominal analysis' loop also on the identification's measured frequency response, and the
    verdict's checks on the airframe (:func:`tuner.analysis.measured.with_measured`: the measured margins by the
    worst end of their error range, the identification's rating)."""
    from .analysis.measured import with_measured

    a0 = res.analyses[0]
    return replace(res, analyses=(with_measured(a0, ident, res.spec), *res.analyses[1:]))


def identification_summary(ident: Any) -> dict[str, Any]:
    """What a result records of the identification it was designed on: its rating (``quality``), CIFER's ``cost``
    J, the time-domain ``check``, the coherent band and its one-line ``verdict``."""
    out: dict[str, Any] = {}
    for k in ("quality", "cost", "check", "verdict", "rate_hz"):
        v = getattr(ident, k, None)
        if v is not None:
            out[k] = v
    band = getattr(ident, "band_rad_s", None)
    if band is not None:
        out["band_rad_s"] = [float(x) for x in band]
    return out


def _measured_note(res: TuneResult) -> str | None:
    """Why a design that meets the spec on the model fails on the measured response (the search designs on the
    model; the data say the airframe differs where the margins are taken), and what would help."""
    a0 = res.analyses[0]
    bad = [c for c in a0.failing if c.name.startswith("measured_")]
    model_ok = all(c.ok for a in res.analyses for c in a.checks
                   if not c.name.startswith("measured_") and c.name != "identification_quality")
    if not bad or not model_ok:
        return None
    unmeasured = [c.name for c in bad if isinstance(c.achieved, float) and math.isnan(c.achieved)]
    lo, hi = a0.measured.band_rad_s if a0.measured is not None else (math.nan, math.nan)
    parts = []
    if len(unmeasured) < len(bad):
        parts.append("the measured response gives margins below the spec: the model is not the airframe near the "
                     "crossover (a mode, a delay or a gain it misses); identify again with more poles or a longer, "
                     "richer excitation there, and tune on that")
    if unmeasured:
        parts.append(f"{', '.join(unmeasured)}: the crossing lies outside the coherent data ({lo:.3g}-{hi:.3g} "
                     "rad/s): excite the loop there (a sweep over that range) so the data can confirm it, or ask for "
                     "a crossover inside the band (--wc)")
    return "the design meets the spec on the model but not on the measured response: " + "; ".join(parts)


#: a change of the crossover or a gain by more than this factor against the vehicle's current tune is said in words
BIG_CHANGE = 3.0


def big_changes(current: dict[str, float], proposed: dict[str, float], params: Sequence[str],
                wc_current: float = math.nan, wc_proposed: float = math.nan) -> list[str]:
    """Each change of the crossover or of a gain of ``params`` by more than :data:`BIG_CHANGE` (either way), in words;
    a gain the vehicle flies at 0 that the proposal sets, or the reverse, counts (an unbounded factor).

    Examples
    --------
    >>> from tuner.tuning import big_changes
    >>> for line in big_changes({"P": 0.14, "I": 0.1, "FF": 0.0}, {"P": 0.15, "I": 0.0284, "FF": 0.27},
    ...                         ["P", "I", "FF"], 0.443, 0.0109):
    ...     print(line)
    crossover 0.443 -> 0.0109 rad/s (41x lower)
    I 0.1 -> 0.0284 (3.5x lower)
    FF 0 -> 0.27 (the vehicle flies without it)
    """
    def one(name: str, a: float, b: float, unit: str = "") -> str | None:
        if not (math.isfinite(a) and math.isfinite(b)) or a == b:
            return None
        if a == 0:
            return f"{name} 0 -> {b:.3g}{unit} (the vehicle flies without it)"
        if b == 0:
            return f"{name} {a:.3g} -> 0{unit} (removed)"
        r = abs(b / a)
        if r > BIG_CHANGE:
            return f"{name} {a:.3g} -> {b:.3g}{unit} ({r:.2g}x higher)"
        if r < 1.0 / BIG_CHANGE:
            return f"{name} {a:.3g} -> {b:.3g}{unit} ({1 / r:.2g}x lower)"
        return None

    out = [one("crossover", float(wc_current), float(wc_proposed), " rad/s")]
    out += [one(k, float(current[k]), float(proposed[k])) for k in params if k in current and k in proposed]
    return [x for x in out if x]


def _with_current(res: TuneResult, problem: TuningProblem, vehicle: Any, gains: dict[str, float],
                  ident: Any = None, actuator: Any = None) -> TuneResult:
    """``res`` with the vehicle's record and its current gains analysed on every plant (the same spec)."""
    from .analysis.verify import analyze
    from .firmware.bind import vehicle_dict

    ctrl = problem.structure.tf(gains, problem.dt)
    current = tuple(analyze(p, ctrl, sp, actuator=actuator, structure=problem.structure.name, gains=gains)
                    for p, sp in zip(problem.plants, problem.specs))
    if ident is not None:
        from .analysis.measured import with_measured

        current = (with_measured(current[0], ident, problem.spec), *current[1:])
    st = problem.structure
    proposed = dict(res.gains)
    if st.firmware is not None:  # the values the vehicle would store (a gain at the optimum's zero is 0 there)
        from .firmware.names import stored_value

        for k in st.params:
            try:
                proposed[k] = stored_value(st.firmware, st.axis or "roll", k, proposed[k])
            except ValueError:
                pass
    changes = big_changes(gains, proposed, st.params, current[0].metrics.crossover_rad_s,
                          res.analyses[0].metrics.crossover_rad_s)
    return replace(res, vehicle={**vehicle_dict(vehicle), "current_gains_law": dict(gains), "changes": changes},
                   current=current)


_POOLS: dict[str, Any] = {"controller": None, "builds": -1}


def _one_thread() -> Any:
    """A scope with one BLAS/OpenMP thread. threadpoolctl's controller (the scan of the process's loaded libraries: a
    few milliseconds, most of a warm tune's fixed cost) is made once and again only after an NLP build, which loads
    CasADi's solver plugins and the libraries they bring."""
    from threadpoolctl import ThreadpoolController

    from .optimize.nlp.transcribe import BUILDS

    if _POOLS["controller"] is None or _POOLS["builds"] != BUILDS["count"]:
        _POOLS["controller"], _POOLS["builds"] = ThreadpoolController(), BUILDS["count"]
    return _POOLS["controller"].limit(limits=1)


def _searchable(problem: TuningProblem, decided: list[Any]) -> TuningProblem:
    """The problem the search solves: ``problem`` itself, or, when some of its limits cannot be met by any gains
    (``decided``: :func:`tuner.diagnose.definitional_reasons`), the same with those limits set as the reasons
    suggest, so that the result is the best design meeting everything else (and the answer comes as fast as a
    feasible tune's) while the verifier still judges it against the asked spec."""
    changes: dict[str, Any] = {}
    for r in decided:  # (not zero steady-state error: without it a settling time is won by a loop settling near 0)
        changes.update({k: v for k, v in r.suggest.items() if k != "zero_steady_state_error"})
    if not changes:
        return problem
    try:
        spec = Spec.model_validate({**problem.asked_spec.model_dump(), **changes})
        return TuningProblem.build(list(problem.given_plants), structure=problem.structure, spec=spec, dt=problem.dt)
    except TunerError:
        return problem


def _adopt(eng: Any, problem: TuningProblem, found: list[TuneResult]) -> tuple[np.ndarray, Any] | None:
    """The best of the diagnosis's re-tuned designs that the verifier finds meeting the asked spec (the re-tunes
    relaxed one limit; their design may meet it anyway: the first search had missed it), or None."""
    best = None
    for r in found:
        try:
            x = problem.structure.vector(r.gains)
        except TunerError:
            continue
        s = eng.ev.score(x)
        if s.feasible and (best is None or s.score < best[1].score):
            best = (x, s)
    return best


ROBUSTNESS_OBJECTIVES = tuple(o.name for o in OBJECTIVES if o.robust)  # (the registry says which)
#: the load objectives after which a 2-DOF design's setpoint path is shaped for the reference step
#: (:mod:`tuner.optimize.setpoint`): they do not depend on it, so the search leaves it to chance
SETPOINT_AFTER = ("iae", "ie")

#: the default budget's cap of the tune running on this thread/task (nested tunes inherit it; see tune)
_OUTER_CAP: contextvars.ContextVar[float | None] = contextvars.ContextVar("tuner_build_cap", default=None)
AUTO_WALL_CAP_S = 60.0  # the default budget's hard wall-clock cap, builds included (the search itself counts work)
FAST_SHARE = 0.3  # of the budget: the fastest design, a candidate of the robustness objectives
_RESERVE = 0.1  # share of the budget kept for the final full-resolution verification
# the diagnosis of an unmet spec (tuner.diagnose): short tunes with limits relaxed, in what is left of the
# budget, at most this share of it (the reasons by definition need no time)
DIAGNOSIS_SHARE = 0.25
