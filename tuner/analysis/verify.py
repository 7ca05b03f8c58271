"""The verifier: everything a user is told about a loop comes from here.

Built on python-control and numpy only (no CasADi, no Optuna): closed-loop
poles from the uncancelled characteristic polynomial, margins from a dense
refined frequency grid (:mod:`tuner.analysis.margins`), step metrics from the continuous
plant output between samples (:mod:`tuner.analysis.response`).

Non-finite values keep their meaning: ``inf`` gain margin = no crossing,
``inf`` settling time = not settled within the horizon, ``nan`` = not defined
(e.g. step metrics of an unstable loop). In JSON they are written as the
strings ``"Infinity"``, ``"-Infinity"`` and ``"NaN"`` (see :func:`tuner.jsonio.jsonable`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ..errors import InvalidControllerError, TunerError
from ..loop import Loop, build_loop
from ..spec import Check, Spec, check_spec
from .margins import Margins, margins
from .response import StepResponse, closed_loop_poles, is_stable, stability, step_metrics, step_response

__all__ = ["Metrics", "Analysis", "analyze", "analyze_loop"]


@dataclass(frozen=True)
class Metrics:
    stable: bool
    phase_margin_deg: float
    crossover_rad_s: float
    gain_margin_db: float
    gain_margin_lower_db: float
    disk_margin: float
    ms: float
    mt: float
    mks: float
    bandwidth_rad_s: float
    overshoot_pct: float
    settling_time_s: float
    rise_time_s: float
    steady_state_error: float
    control_peak: float


@dataclass(frozen=True, eq=False)
class Analysis:
    loop: Loop
    metrics: Metrics
    checks: list[Check]
    poles: np.ndarray
    response: StepResponse | None = field(repr=False)
    margins: Margins | None = field(default=None, repr=False)  # incl. the phase-crossover frequency

    @property
    def meets_spec(self) -> bool:
        return all(c.ok for c in self.checks)

    @property
    def failing(self) -> list[Check]:
        return [c for c in self.checks if not c.ok]

    def __repr__(self) -> str:
        from ..display import analysis_repr

        return analysis_repr(self)

    def _repr_html_(self) -> str:
        from ..display import analysis_html

        return analysis_html(self)

    def plot(self, kind: str = "all", **kw: Any) -> Any:
        """The loop's plots as a :class:`matplotlib.figure.Figure` (no pyplot state, no backend chosen; save it
        with ``fig.savefig``): ``kind`` is ``all``, ``step``, ``bode`` or ``nyquist``; ``kw`` go to
        :func:`tuner.analysis.plots.figure` (``spec``, ``title``)."""
        from .plots import figure

        return figure(self, kind, **kw)

    def to_control(self) -> Any:
        """The controller as a ``control.TransferFunction`` (its ``dt``; 0 = continuous)."""
        from ..interop import controller_to_control

        return controller_to_control(self.loop.controller)

    def loop_tfs(self, *, pade_order: int | None = 6) -> Any:
        """``L``, ``S``, ``T`` as ``control.TransferFunction`` (a named tuple), uncancelled: in ``z`` at ``dt``
        for a sampled-data loop (the plant's zero-order-hold equivalent, its delay as ``z^-d``: exact at the
        samples); in ``s`` for a continuous loop, a delay as a Padé approximation of ``pade_order`` (``None``:
        left out). See :mod:`tuner.interop`."""
        from ..interop import loop_tfs

        return loop_tfs(self.loop, pade_order=pade_order)

    def reference_tfs(self, *, pade_order: int | None = 6) -> Any:
        """``r -> y`` and ``r -> u`` (``Tr, Ur``) as ``control.TransferFunction``: for a 1-DOF controller ``T``
        and ``C S``; for a 2-DOF one (``pid2``) ``C_r G S`` and ``C_r S``, while :meth:`loop_tfs` gives the
        feedback loop ``L = C G``. See :func:`tuner.interop.reference_tfs`."""
        from ..interop import reference_tfs

        return reference_tfs(self.loop, pade_order=pade_order)

    def to_dict(self) -> dict[str, Any]:
        return {
            "metrics": asdict(self.metrics),
            "checks": [c.to_dict() for c in self.checks],
            "meets_spec": self.meets_spec,
        }


def analyze_loop(
    loop: Loop, spec: Spec | None = None, *, horizon_s: float | None = None,
    samples_per_dt: int | None = None, grid_points: int | None = None, poles: np.ndarray | None = None,
) -> Analysis:
    """Verify ``loop`` against ``spec`` (defaults to the thesis spec); ``poles`` if already computed."""
    spec = spec or Spec()
    poles = closed_loop_poles(loop) if poles is None else poles
    stable = is_stable(loop, poles)
    mg = margins(loop, **({} if grid_points is None else {"grid_points": grid_points}))
    resp = None
    if stable:
        kw = {} if samples_per_dt is None else {"samples_per_dt": samples_per_dt}
        resp = step_response(loop, horizon_s=horizon_s, **kw)
        sm = step_metrics(resp, band_pct=spec.settling_band_pct)
        step = (sm.overshoot_pct, sm.settling_time_s, sm.rise_time_s, sm.steady_state_error, sm.control_peak)
    else:
        step = (math.nan, math.inf, math.nan, math.nan, math.nan)
    m = Metrics(
        stable, mg.phase_margin_deg, mg.crossover_rad_s, mg.gain_margin_db, mg.gain_margin_lower_db,
        mg.disk_margin, mg.ms, mg.mt, mg.mks, mg.bandwidth_rad_s, *step,
    )
    return Analysis(loop=loop, metrics=m, checks=check_spec(m, spec), poles=poles, response=resp, margins=mg)


def analyze(
    plant: Any, controller: Any, spec: Spec | None = None, *, delay: float | None = None,
    horizon_s: float | None = None,
) -> Analysis:
    """Verify ``controller`` on ``plant``: stability, margins, step metrics, spec checks.

    Parameters
    ----------
    plant : Plant, control.TransferFunction or control.StateSpace
        The plant, continuous or discrete (a python-control model's ``dt``; ``dt=True`` is refused), see
        :mod:`tuner.interop`.
    controller : ControllerTF, control.TransferFunction or control.StateSpace
        Continuous (a continuous loop) or at a sample time ``dt`` (a sampled-data loop: the controller drives
        a continuous plant through a zero-order hold, or a discrete plant at the same ``dt``).
    spec : Spec, optional
        What is checked; defaults to the thesis spec (see :class:`~tuner.spec.Spec`).
    delay : float, optional
        Input delay of a python-control plant, s (any delay for a continuous model, exact also in a
        sampled-data loop; whole samples for a discrete model). A
        :class:`~tuner.plant.Plant` carries its own delay.
    horizon_s : float, optional
        Length of the simulated step response, s; default: 10 time constants of the slowest closed-loop
        pole (bounded), see :func:`tuner.analysis.response.default_horizon`.

    Returns
    -------
    Analysis
        ``metrics`` (margins, Ms, bandwidth, step metrics), ``checks`` against ``spec``, ``meets_spec``,
        closed-loop ``poles``, the step ``response``; ``.to_control()``, ``.loop_tfs()``, ``.plot()``.

    Raises
    ------
    TunerError
        Bad input, with ``field`` (``("plant", ...)``, ``("controller", ...)``, ``("dt",)``); also a loop
        whose stability double precision cannot decide (``field == ("controller",)``).
    """
    from ..interop import as_controller, as_plant

    try:
        plant = as_plant(plant, delay=delay)
    except TunerError as e:
        raise (e if e.field == ("delay",) else e.at("plant")) from None
    try:
        controller = as_controller(controller)
    except TunerError as e:
        raise e.at("controller") from None
    loop = build_loop(plant, controller)
    poles = closed_loop_poles(loop)
    if stability(loop, poles) is None:
        p = np.abs(poles[np.isfinite(poles)])
        span = f" (closed-loop poles from {p.min():.3g} to {p.max():.3g})" if p.size else ""
        raise InvalidControllerError(
            "the loop's dynamics span too many decades for double precision to tell whether it is stable"
            f"{span}: rescale the controller gain or the plant's time scale", field="controller")
    return analyze_loop(loop, spec, horizon_s=horizon_s, poles=poles)
