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
from .response import StepResponse, closed_loop_poles, is_stable, stability, steady_state, step_metrics, step_response

__all__ = ["Metrics", "Analysis", "analyze", "analyze_loop"]


@dataclass(frozen=True)
class Metrics:
    """The verifier's figures of one loop (attributes, units in the names; ``asdict`` for a dict).

    ``inf`` gain margin = no crossing; ``inf`` settling time = not settled within the horizon; ``nan`` = not
    defined (e.g. the step metrics of an unstable loop).

    Attributes
    ----------
    stable : bool
        The closed loop is stable (from its poles).
    phase_margin_deg, crossover_rad_s : float
        The worst phase margin over all gain crossings, and the crossover frequency where it is taken (both
        ``nan`` when a crossing lies beyond 1e-300..1e300 rad/s: unknown, failing a phase-margin limit).
    gain_margin_db, gain_margin_lower_db : float
        Upper gain margin (> 0 dB, ``inf`` if none) and lower gain margin (< 0 dB, ``-inf`` if none).
    disk_margin : float
        Balanced disk margin alpha (0..2).
    ms, mt, mks : float
        Peaks of ``|S|``, ``|T|`` and ``|C S|`` (noise to the actuator).
    bandwidth_rad_s : float
        Closed-loop bandwidth: where ``|T|`` first falls 3 dB below ``|T(0)|``.
    overshoot_pct, settling_time_s, rise_time_s, steady_state_error, control_peak : float
        Of the unit reference step: overshoot, settling time into the spec's band, 10-90 % rise time, final
        error, peak ``|u|``.
    disturbance_rejection_bandwidth_rad_s, disturbance_rejection_peak_db : float
        Where ``|S|`` first rises to -3 dB (0: it is there at w -> 0; inf: never below Nyquist), and ``max |S|`` in
        dB (``20 log10 Ms``), on the loop's exact frequency response (:mod:`tuner.analysis.margins`).
    integral_gain : float
        ``|Ki|``: ``lim s C(s)`` (continuous) or ``lim (z - 1) C(z)/dt`` (at dt), 0 without integral action; the load
        step's IE is ``1/|Ki|``.
    load_iae, load_peak, load_recovery_s : float
        Of a unit step load at the plant input (before its delay) with r = 0, the output between the samples:
        the integral of ``|y|`` over the verifier's horizon, ``max |y|``, and the last time ``|y|`` is above 2 % of
        that peak (``inf`` for both when ``y`` does not return to 0: no integral action against the load).

    Examples
    --------
    >>> import control
    >>> from tuner import analyze
    >>> m = analyze(control.tf([1], [1, 1]), control.tf([2, 2], [1, 0])).metrics  # L = 2/s, T = 2/(s + 2)
    >>> m.stable, round(m.phase_margin_deg, 6), m.gain_margin_db, round(m.bandwidth_rad_s, 4)
    (True, 90.0, inf, 2.0)
    >>> m
    Metrics(stable, PM 90 deg at 2 rad/s, GM inf dB
      Ms 1 | Mt 1 | Mks 2 | bandwidth 2 rad/s | disk margin 2
      step: overshoot 0 % | settling 1.96 s | rise 1.1 s | error 0 | peak |u| 2
      disturbance: rejection bandwidth 2 rad/s | peak 0 dB | load step: IAE 0.5 | peak 0.25 | recovered 5.29 s)

    (``S = s/(s + 2)`` reaches -3 dB at 2 rad/s; the load step's output is ``exp(-t) - exp(-2t)``: peak 1/4 at
    ln 2 s, IAE 1/2, below 2 % of its peak after about 5.3 s.)
    """

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
    disturbance_rejection_bandwidth_rad_s: float = math.nan
    disturbance_rejection_peak_db: float = math.nan
    load_iae: float = math.nan
    load_peak: float = math.nan
    load_recovery_s: float = math.nan
    integral_gain: float = math.nan

    def __repr__(self) -> str:
        from ..text import metrics_repr

        return metrics_repr(self)


@dataclass(frozen=True, eq=False)
class Analysis:
    """The verifier's verdict on one loop: what :func:`analyze` returns (and, per plant, a tune).

    Attributes
    ----------
    loop : tuner.loop.Loop
        The loop analysed (plant, controller, sample time, delay).
    metrics : Metrics
        Margins, sensitivity peaks, bandwidth and step metrics.
    checks : list of Check
        Every constraint of the spec, with what was required and what was achieved.
    poles : numpy.ndarray
        The closed-loop poles (in ``s``, or in ``z`` at ``dt``).
    response : StepResponse or None
        The unit reference step (``t``, ``y``, ``u``), None for an unstable loop.
    margins : Margins or None
        The frequency-domain figures, including the phase-crossover frequency.

    Examples
    --------
    >>> import control
    >>> from tuner import analyze
    >>> a = analyze(control.tf([1], [1, 1]), control.tf([2, 2], [1, 0]))
    >>> a.meets_spec, [c.name for c in a.failing]
    (True, [])
    >>> a.metrics.phase_margin_deg > 60
    True
    >>> a.to_dict()["meets_spec"]
    True
    """

    loop: Loop
    metrics: Metrics
    checks: list[Check]
    poles: np.ndarray
    response: StepResponse | None = field(repr=False)
    margins: Margins | None = field(default=None, repr=False)  # incl. the phase-crossover frequency
    #: on an identified plant: the loop on the measured frequency response next to the model's
    #: (:class:`tuner.analysis.measured.MeasuredComparison`), else None
    measured: Any = field(default=None, repr=False)
    #: with actuator limits: the reference step of their amplitude, the output clamped and the integrator handled
    #: as the law does (:class:`tuner.analysis.saturation.SaturatedStep`), else None
    saturated: Any = field(default=None, repr=False)

    @property
    def meets_spec(self) -> bool:
        """True when every check holds."""
        return all(c.ok for c in self.checks)

    @property
    def failing(self) -> list[Check]:
        """The checks that do not hold."""
        return [c for c in self.checks if not c.ok]

    def __repr__(self) -> str:
        from ..text import analysis_repr

        return analysis_repr(self)

    def _repr_html_(self) -> str:
        from .html import analysis_html

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
        """``metrics`` (a dict), ``checks`` (dicts) and ``meets_spec``; :func:`tuner.jsonio.jsonable` for JSON."""
        out = {
            "metrics": asdict(self.metrics),
            "checks": [c.to_dict() for c in self.checks],
            "meets_spec": self.meets_spec,
        }
        if self.measured is not None:
            out["measured"] = self.measured.to_dict()
        if self.saturated is not None:
            out["saturated_step"] = self.saturated.to_dict()
        return out

    def with_saturation(self, actuator: Any, spec: Spec | None = None, *, structure: str | None = None,
                        gains: dict[str, float] | None = None) -> Analysis:
        """This analysis with the saturated step of ``actuator`` (:func:`tuner.analysis.saturation.saturated_step`)
        and its checks: the overshoot limit, and settling (within ``settling_time_max`` when the spec has one), on
        the step the actuator allows. A loop that is unstable has none (its linear verdict stands)."""
        if not self.metrics.stable:
            return self
        from dataclasses import replace

        from .saturation import saturated_step

        spec = spec if spec is not None else Spec()
        st = saturated_step(self.loop, actuator, structure=structure, gains=gains)
        m = st.metrics
        checks = list(self.checks)
        os_ok = bool(m.overshoot_pct <= spec.overshoot_max_pct)
        checks.append(Check("saturated_overshoot_pct", "<=", spec.overshoot_max_pct, m.overshoot_pct, os_ok,
                            0.0 if os_ok else (m.overshoot_pct - spec.overshoot_max_pct
                                               if math.isfinite(m.overshoot_pct) else math.inf)))
        lim = spec.settling_time_max
        ts = m.settling_time_s
        ok = bool(ts <= lim) if lim is not None else bool(math.isfinite(ts))
        checks.append(Check("saturated_settling_time_s", "<=" if lim is not None else "<",
                            lim if lim is not None else math.inf, ts, ok,
                            0.0 if ok else (ts - lim if lim is not None and math.isfinite(ts) else math.inf)))
        return replace(self, saturated=st, checks=checks)


def integral_gain(c: Any) -> float:
    """``|Ki|`` of controller ``c``: ``lim s C(s)`` (continuous) or ``lim (z - 1) C(z)/dt``, from its factors (the
    root at DC divided out, the rest evaluated there); 0 without a pole at DC."""
    from ..tolerances import ROOT_AT_DC_TOL

    zk = c.zpk
    at = 1.0 if c.dt else 0.0
    poles = np.asarray(zk.poles)
    dc = np.abs(poles - at) < ROOT_AT_DC_TOL
    if not dc.any():
        return 0.0
    if dc.sum() > 1:
        return math.inf  # a double integrator
    rest = poles[~dc]
    with np.errstate(all="ignore"):
        v = zk.gain * np.prod(at - np.asarray(zk.zeros)) / np.prod(at - rest)
    return float(abs(v.real) / (c.dt or 1.0))


LOAD_RECOVERY_SHARE = 0.02  # load_recovery_s: the last time |y| is above this share of its peak
#: the plant's gain factors at which a 2-DOF loop's zero steady-state error is checked too: a separate setpoint path
#: (a feed-forward, a setpoint weight) can give zero error at the nominal gain alone, a rate loop's control
#: effectiveness moves this much with battery voltage and payload (issue 39), and integral action passes at any gain
GAIN_VARIATION = (0.8, 1.25)


def gain_varied_error(loop: Loop) -> float:
    """The largest steady-state error of the unit reference step at the plant's gain and at its gain times each factor
    of :data:`GAIN_VARIATION` (the exact steady state of each loop; ``nan`` if one is not defined). A loop whose zero
    error rests on a feed-forward or a setpoint weight matched to the nominal plant has an error here; integral
    action in the controller or the plant has none.

    Examples
    --------
    >>> from tuner import make_plant, get_structure
    >>> from tuner.analysis.verify import gain_varied_error
    >>> from tuner.loop import build_loop
    >>> st = get_structure("pid2")  # Ki = 0: b = 1.5 matches the nominal plant 2/(s + 1) exactly
    >>> c = st.tf({"Kp": 1.0, "Ki": 0.0, "Kd": 0.0, "Tf": 0.0, "b": 1.5, "c": 0.0}, 0.01)
    >>> round(gain_varied_error(build_loop(make_plant([2.0], [1.0, 1.0]), c)), 4)  # 1 - 1.5*1.6/2.6 at 0.8x
    0.0769
    """
    c = loop.controller.without_dc_cancellation()
    worst = 0.0
    for k in (1.0, *GAIN_VARIATION):
        try:
            yk, _ = steady_state(build_loop(loop.plant.scaled(k), c))
        except (TunerError, np.linalg.LinAlgError, ValueError):
            return math.nan
        e = abs(1.0 - yk)
        if not math.isfinite(e):
            return math.nan
        worst = max(worst, e)
    return worst


def load_metrics(loop: Loop, horizon_s: float, **kw: Any) -> tuple[float, float, float]:
    """``(load_iae, load_peak, load_recovery_s)`` of a unit step load at the plant input with r = 0, over
    ``horizon_s`` (the reference step's horizon: the integral objective ``iae`` is this very number), the output
    between the samples; IAE and recovery are ``inf`` when the output does not return to 0 (its exact final value
    above ``LOAD_RECOVERY_SHARE`` of the peak: no integral action against the load)."""
    d = step_response(loop, horizon_s=horizon_s, load=True, **kw)
    y = np.abs(np.asarray(d.y, float))
    if y.size == 0 or not np.all(np.isfinite(y)):
        return math.nan, math.nan, math.nan
    peak = float(np.max(y))
    iae = float(np.trapezoid(y, d.t))
    if peak <= 0:
        return iae, peak, 0.0
    if abs(d.y_final) > LOAD_RECOVERY_SHARE * peak:
        return math.inf, peak, math.inf
    out = np.flatnonzero(y > LOAD_RECOVERY_SHARE * peak)
    j = int(out[-1])
    if j + 1 >= y.size:
        return iae, peak, math.inf  # not back within the horizon
    # interpolated between the last point above and the next (as the settling time)
    t0, t1, e0, e1 = float(d.t[j]), float(d.t[j + 1]), float(y[j]), float(y[j + 1])
    thr = LOAD_RECOVERY_SHARE * peak
    rec = t0 + (e0 - thr) / (e0 - e1) * (t1 - t0) if e0 > e1 else t1
    return iae, peak, rec


def analyze_loop(
    loop: Loop, spec: Spec | None = None, *, horizon_s: float | None = None,
    samples_per_dt: int | None = None, grid_points: int | None = None, poles: np.ndarray | None = None,
) -> Analysis:
    """Verify ``loop`` against ``spec`` (default ``Spec()``); ``poles`` if already computed.

    The core of :func:`analyze`, on a built :class:`tuner.loop.Loop` (no input conversion, no checks of it).

    Examples
    --------
    >>> from tuner import controller_from_coeffs, make_plant
    >>> from tuner.analysis import analyze_loop
    >>> from tuner.loop import build_loop
    >>> loop = build_loop(make_plant([1.0], [1.0, 1.0]), controller_from_coeffs([2.0, 2.0], [1.0, 0.0], dt=None))
    >>> analyze_loop(loop).meets_spec
    True
    """
    spec = spec or Spec()
    poles = closed_loop_poles(loop) if poles is None else poles
    stable = is_stable(loop, poles)
    mg = margins(loop, **({} if grid_points is None else {"grid_points": grid_points}))
    resp = None
    if stable:
        kw = {} if samples_per_dt is None else {"samples_per_dt": samples_per_dt}
        resp = step_response(loop, horizon_s=horizon_s, **kw)
        sm = step_metrics(resp, band_pct=spec.settling_band_pct)
        sse = sm.steady_state_error
        if loop.controller.two_dof and spec.zero_steady_state_error:  # (see gain_varied_error)
            varied = gain_varied_error(loop)
            sse = varied if math.isnan(sse) or math.isnan(varied) or varied > abs(sse) else sse
        step = (sm.overshoot_pct, sm.settling_time_s, sm.rise_time_s, sse, sm.control_peak)
        load = load_metrics(loop, float(resp.t[-1]), **kw)
    else:
        step = (math.nan, math.inf, math.nan, math.nan, math.nan)
        load = (math.nan, math.nan, math.nan)
    drp = 20.0 * math.log10(mg.ms) if stable and mg.ms > 0 and math.isfinite(mg.ms) else math.nan
    m = Metrics(
        stable, mg.phase_margin_deg, mg.crossover_rad_s, mg.gain_margin_db, mg.gain_margin_lower_db,
        mg.disk_margin, mg.ms, mg.mt, mg.mks, mg.bandwidth_rad_s, *step,
        mg.drb_rad_s if stable else math.nan, drp, *load, integral_gain(loop.controller),
    )
    return Analysis(loop=loop, metrics=m, checks=check_spec(m, spec), poles=poles, response=resp, margins=mg)


def analyze(
    plant: Any, controller: Any, spec: Spec | None = None, *, delay: float | None = None,
    horizon_s: float | None = None, dt: float | None = None, actuator: Any = None, structure: str | None = None,
    gains: dict[str, float] | None = None,
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
        What is checked; default ``Spec()``: the thesis constraints (PM >= 60 deg, GM >= 6 dB, overshoot
        <= 10 %, zero steady-state error) and the limits it states in absolute terms (``ms_max``, ``mks_max``,
        ...). The default design limits of a tune (the filter rules, the noise budget relative to the plant)
        are rules on a structure's parameters and are not checked here (see :class:`~tuner.spec.Spec`).
    delay : float, optional
        Input delay of a python-control plant, s (any delay for a continuous model, exact also in a
        sampled-data loop; whole samples for a discrete model). A
        :class:`~tuner.plant.Plant` carries its own delay.
    horizon_s : float, optional
        Length of the simulated step response, s; default: 10 time constants of the slowest closed-loop
        pole (bounded), see :func:`tuner.analysis.response.default_horizon`.
    dt : float, optional
        The controller's sample time, s, as ``tuner analyze --dt``: the loop is sampled-data at ``dt`` (or
        discrete, with a plant in ``z`` at the same ``dt``). The controller carries its own sample time (a
        :class:`ControllerTF` built with ``dt=``, a python-control model's ``dt``), so ``dt`` states it: it
        must agree, else :class:`TunerError` with ``field == ("dt",)`` (a continuous controller with ``dt``
        given: discretise it first, e.g. ``control.c2d(C, dt, "tustin")``). ``None``: the controller's own.
    actuator : tuner.analysis.saturation.Actuator, optional
        The actuator's limits and a step amplitude: the result then also holds the step with the output clamped
        and the integrator handled as the law does (``saturated``, JSON ``saturated_step``), and its checks
        (``saturated_overshoot_pct``, ``saturated_settling_time_s``). Needs a sampled-data loop.
    structure : str, optional
        With ``actuator``: the law the controller is (``px4_rate``, ``ardupilot_rate``, ``pid2``), run as the
        firmware (or tuner's export) runs it; other controllers run as their exported difference equation.
    gains : dict, optional
        With ``structure``: its gains (a firmware law's fixed values among them).

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

    Examples
    --------
    A PI controller ``2(s + 1)/s`` on ``1/(s + 1)``, continuous (the loop is ``2/s``: PM 90 deg):

    >>> import control
    >>> from tuner import analyze
    >>> a = analyze(control.tf([1], [1, 1]), control.tf([2, 2], [1, 0]))
    >>> a.meets_spec, round(a.metrics.phase_margin_deg, 1), a.metrics.overshoot_pct < 1e-6
    (True, 90.0, True)

    The same controller discretised at 0.05 s, driving the plant through a zero-order hold:

    >>> c = control.c2d(control.tf([2, 2], [1, 0]), 0.05, "tustin")
    >>> a = analyze(control.tf([1], [1, 1]), c, dt=0.05)
    >>> a.loop.dt, a.meets_spec
    (0.05, True)
    >>> analyze(control.tf([1], [1, 1]), c, dt=0.1)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    tuner.errors.InvalidControllerError: dt = 0.1 s but the controller's sample time is 0.05 s: ...

    A tighter spec:

    >>> from tuner import Spec
    >>> a = analyze(control.tf([1], [1, 1]), control.tf([2, 2], [1, 0]), Spec(settling_time_max=1.0))
    >>> [c.name for c in a.failing]
    ['settling_time_s']
    """
    from .._lazy import is_instance_of
    from ..interop import as_controller, as_plant

    ident = plant if is_instance_of(plant, "tuner.identify.result", "IdentifyResult") else None
    try:
        plant = as_plant(plant, delay=delay)
    except TunerError as e:
        raise (e if e.field == ("delay",) else e.at("plant")) from None
    try:
        controller = as_controller(controller)
    except TunerError as e:
        raise e.at("controller") from None
    _check_controller_dt(controller, dt)
    loop = build_loop(plant, controller)
    poles = closed_loop_poles(loop)
    if stability(loop, poles) is None:
        p = np.abs(poles[np.isfinite(poles)])
        span = f" (closed-loop poles from {p.min():.3g} to {p.max():.3g})" if p.size else ""
        raise InvalidControllerError(
            "the loop's dynamics span too many decades for double precision to tell whether it is stable"
            f"{span}: rescale the controller gain or the plant's time scale", field="controller")
    res = analyze_loop(loop, spec, horizon_s=horizon_s, poles=poles)
    if actuator is not None:
        res = res.with_saturation(actuator, spec, structure=structure, gains=gains)
    if ident is not None:  # the loop on the measured response too, next to the model's, and its checks
        from .measured import with_measured

        res = with_measured(res, ident, spec)
    return res


def _check_controller_dt(controller: Any, dt: Any) -> None:
    """``analyze(..., dt=)``: a given sample time must be the controller's own (field ``dt``)."""
    if dt is None:
        return
    from ..plant import check_dt

    want = check_dt(dt)
    have = controller.dt
    if have is None:
        raise InvalidControllerError(
            f"dt = {want:g} s but the controller is continuous: give the controller in z at dt = {want:g} s (e.g. "
            f"control.c2d(C, {want:g}, 'tustin'), or controller_from_coeffs(num, den, dt={want:g})), or drop dt",
            field="dt")
    if abs(have - want) > 1e-9 * max(abs(have), abs(want)):
        raise InvalidControllerError(
            f"dt = {want:g} s but the controller's sample time is {have:g} s: give the controller at dt = {want:g} "
            "s, or drop dt", field="dt")
