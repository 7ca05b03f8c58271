"""What "good" means: constraints and the objective, validated.

Defaults are the quadrotor thesis's: phase margin >= 60 deg, gain margin >= 6 dB
(upper, and the lower gain margin <= -6 dB where the loop has one), overshoot
<= 10 %, zero steady-state error, settling band 2 %, objective = settling time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, create_model, field_validator

from .limits import CROSSOVER_TOL, LIMITS, SSE_TOL
from .limits import OBJECTIVES as _OBJECTIVES
from .objectives import OBJECTIVE_DEFINITIONS, ROBUST_NOTE

__all__ = ["Spec", "Check", "check_spec", "resolved_objective", "OBJECTIVES", "AUTO", "SSE_TOL", "CROSSOVER_TOL"]

OBJECTIVES = tuple(o.name for o in _OBJECTIVES)
#: ``Spec.objective``'s default: the structure decides (see :func:`resolved_objective`)
AUTO = "auto"
#: the plant-gain factors a firmware rate law's default design holds too (``Spec.gain_variation = "auto"``): a rate
#: loop's control effectiveness moves this much with battery voltage and payload (issue 39)
FIRMWARE_GAIN_VARIATION = (0.8, 1.25)

# The default design limits (on unless lifted; ``Spec.thesis()`` or ``--no-default-limits`` lift all three):
FILTER_N_MAX = 20.0  # derivative filter: N = Td/Tf <= 20 (Astrom & Hagglund, Advanced PID Control, 2006: N in 2..20)
NOISE_GAIN_MAX = 10.0  # noise budget: Mks <= 10 K0, K0 = the plant's ultimate gain (see Spec.noise_gain_max)
DEFAULT_LIMITS = ("filter_n_max", "filter_nyquist", "noise_gain_max", "gain_variation")


class _SpecCore(BaseModel):
    """A tuning specification. Optional limits are ``None`` when not requested.

    A frozen pydantic model: every field is validated on construction (a bad value raises
    ``pydantic.ValidationError`` naming the field); ``model_copy(update=...)`` derives another,
    ``model_dump()`` gives the dict. The fields, their units and defaults are listed in
    ``Spec.model_fields`` (each with its ``description``).

    Examples
    --------
    >>> from tuner import Spec
    >>> spec = Spec()  # PM >= 60 deg, GM >= 6 dB, overshoot <= 10 %, zero steady-state error
    >>> spec.phase_margin_min_deg, spec.gain_margin_min_db, spec.objective  # auto: the structure decides
    (60.0, 6.0, 'auto')
    >>> Spec(ms_max=1.4, objective="iae").ms_max
    1.4
    >>> Spec.thesis().filter_n_max is None  # the default design limits lifted
    True
    >>> Spec(phase_margin_min_deg=120)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    pydantic_core._pydantic_core.ValidationError: 1 validation error for Spec
    phase_margin_min_deg
    ...
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    zero_steady_state_error: bool = Field(True, description="require zero steady-state error to a step")
    settling_band_pct: float = Field(2.0, gt=0, le=20, description="settling band, % of the final value")
    objective: Literal[(*OBJECTIVES, AUTO)] = Field(  # type: ignore[valid-type]
        AUTO, description="what is optimised (tuner.objectives): " + "; ".join(
            f"{k}: {v}" for k, v in OBJECTIVE_DEFINITIONS.items()) + ". " + ROBUST_NOTE + " auto (the default): "
        "the structure decides: settling_time for the one-degree-of-freedom structures; for a law with its own "
        "setpoint path (pid2, px4_rate, ardupilot_rate) the feedback is designed for the load (iae), then the setpoint "
        "path alone (px4_rate's and ardupilot_rate's FF, pid2's b and c) for the settling time (Astrom & Hagglund, "
        "Advanced PID Control, 2006, ch. 7)")
    # -- the default design limits (a design an engineer would fly); None / false lifts each ------------------
    filter_n_max: float | None = Field(
        FILTER_N_MAX, gt=0, description="derivative filter rule for pd, pid, pid2 and pid_mf2: N = Td/Tf = "
        "Kd/(Kp Tf) <= this (default 20: Astrom & Hagglund, Advanced PID Control, 2006, give N in 2..20; the "
        "controller's high-frequency gain is then at most Kp (1 + N)); null lifts it")
    filter_nyquist: bool = Field(
        True, description="at a sample time dt, a derivative or measurement filter no faster than the sampling "
        "supports: its corner 1/Tf at most the Nyquist frequency pi/dt, i.e. Tf >= dt/pi (a faster corner filters "
        "nothing); false lifts it (Tf >= 1e-3 dt)")
    noise_gain_max: float | None = Field(
        NOISE_GAIN_MAX, gt=0, description="noise budget: Mks = max |C/(1+L)| <= this times K0, the nominal plant's "
        "gain scale 1/|G(j w0)| (w0: where its phase, hold and delay included, reaches -180 deg: its ultimate "
        "gain; a plant whose phase never gets there: where it reaches -135 deg), or 1/|G(0)| when that is larger. "
        "A Ziegler-Nichols PID (Kp = 0.6 Ku) with N = 10..20 has a high-frequency gain of 6.6..12.6 Ku: 10 "
        "is that classic aggressive design's noise gain; the tighter of this and mks_max applies; null lifts it")

    gain_variation: Literal[AUTO] | tuple[float, float] | None = Field(
        AUTO, description="the plant-gain factors [lo, hi] the design must also hold at: the nominal plant's gain "
        "times lo and times hi are added to the plant set, every constraint of the spec on each (the phase margin "
        "gain_variation_pm_min_deg) and the objective "
        "their worst case (a rate loop's control effectiveness moves with battery voltage and payload); auto (the "
        "default): [0.8, 1.25] for the firmware rate laws px4_rate and ardupilot_rate, none otherwise; null lifts it")

    gain_variation_pm_min_deg: float = Field(
        45.0, ge=0, le=90, description="the phase margin each gain-variation member keeps (at most the spec's own): "
        "the nominal plant keeps phase_margin_min_deg; a member's gain margin is the nominal's less the gain change "
        "itself, which the nominal's implies; every other limit holds on the members as on the nominal. 45 deg: what a "
        "rate loop keeps at the ends of its control effectiveness's range (issue 39's figure)")

    @field_validator("gain_variation")
    @classmethod
    def _gain_range(cls, v: Any) -> Any:
        if v is None or v == AUTO:
            return v
        lo, hi = (float(x) for x in v)
        if not (math.isfinite(lo) and math.isfinite(hi) and 0.1 <= lo <= 1.0 <= hi <= 10.0 and lo < hi):
            raise ValueError(f"gain_variation is [lo, hi] with 0.1 <= lo <= 1 <= hi <= 10 and lo < hi, got {[lo, hi]}")
        return (lo, hi)

    @classmethod
    def thesis(cls, **kw: Any) -> Spec:
        """The pure thesis spec: ``Spec(**kw)`` with the default design limits (derivative filter rule, Nyquist
        filter rule, noise budget, a firmware law's gain variation) lifted, and its objective, the settling time,
        for every structure."""
        return cls(**{"filter_n_max": None, "filter_nyquist": False, "noise_gain_max": None, "gain_variation": None,
                      "objective": "settling_time", **kw})

    def without_default_limits(self) -> Spec:
        """This spec with the default design limits lifted (what ``--no-default-limits`` does)."""
        return self.model_copy(update={"filter_n_max": None, "filter_nyquist": False, "noise_gain_max": None,
                                       "gain_variation": None})


def resolved_objective(objective: str, structure: Any) -> str:
    """The objective a tune optimises: ``objective`` itself, or for ``"auto"`` the structure's default (``structure``: a
    :class:`~tuner.controllers.Structure`, or a bool: whether it has its own setpoint path):

    * ``settling_time`` for a one-degree-of-freedom structure;
    * ``iae`` for one whose setpoint weights can take back what a strong integrator does to the reference step (pid2,
      ``b`` below 1): the feedback is designed for the load step, then its setpoint weights for the reference step
      (:func:`tuner.optimize.setpoint.shape_setpoint`);
    * ``ie`` for a firmware rate law, whose setpoint path is a feed-forward ``FF >= 0`` alone: the fastest reference
      step, then its integral gain raised as far as the reference step allows
      (:func:`tuner.optimize.setpoint.raise_integral`).

    Examples
    --------
    >>> from tuner import get_structure
    >>> from tuner.spec import resolved_objective
    >>> [resolved_objective("auto", get_structure(n)) for n in ("pid", "pid2", "px4_rate")]
    ['settling_time', 'iae', 'ie']
    >>> resolved_objective("itae", get_structure("px4_rate"))
    'itae'
    """
    if objective != AUTO:
        return objective
    if isinstance(structure, bool):
        return "ie" if structure else "settling_time"
    if not structure.two_dof:
        return "settling_time"
    kinds = dict(zip(structure.params, structure.kinds))
    return "iae" if any(kinds[p] == "weight" for p in structure.setpoint) else "ie"


def _limit_field(lim: Any) -> tuple[Any, Any]:
    """A limit's Spec field, from its registry entry (:mod:`tuner.limits`)."""
    desc = lim.help + (f" (default {lim.default:g}: {lim.source})" if lim.default is not None and lim.source else "")
    if lim.default is None:
        return (float | None, Field(None, description=desc, **lim.bounds))
    return (float, Field(lim.default, description=desc, **lim.bounds))


#: the tuning specification: the core fields above and one field per limit of the registry (:data:`tuner.limits.LIMITS`)
Spec = create_model("Spec", __base__=_SpecCore, __module__=__name__,
                    **{lim.field: _limit_field(lim) for lim in LIMITS})  # type: ignore[call-overload]
Spec.__doc__ = _SpecCore.__doc__
Spec.__qualname__ = "Spec"


@dataclass(frozen=True)
class Check:
    """One constraint: ``achieved op required``; ``violation`` is how far from ok (0 when ok).

    Attributes
    ----------
    name : str
        The metric checked (a :class:`~tuner.analysis.Metrics` field, e.g. ``phase_margin_deg``), or a rule
        (``stable``, ``filter_n``).
    op : str
        ``">="``, ``"<="``, ``"=="`` or ``"<"``.
    required, achieved
        The limit and the verified value.
    ok : bool
        The constraint holds.
    violation : float
        How far from ok, in the metric's unit (0 when ok, ``inf`` when the value is not defined).

    Examples
    --------
    >>> import control
    >>> from tuner import Spec, analyze
    >>> a = analyze(control.tf([1], [1, 1]), control.tf([2, 2], [1, 0]), Spec(settling_time_max=1.0))
    >>> a.checks[1]
    Check(phase_margin_deg 90 >= 60: ok)
    >>> c = a.failing[0]
    >>> c
    Check(settling_time_s 1.956 <= 1: FAILS by 0.956)
    >>> c.name, c.ok, round(c.achieved, 3)  # settling into 2 % of 2/(s + 2): ln(50)/2 s
    ('settling_time_s', False, 1.956)
    """

    name: str
    op: str
    required: Any
    achieved: Any
    ok: bool
    violation: float

    def to_dict(self) -> dict[str, Any]:
        """The check as a dict (``name``, ``op``, ``required``, ``achieved``, ``ok``, ``violation``)."""
        return {"name": self.name, "op": self.op, "required": self.required, "achieved": self.achieved,
                "ok": self.ok, "violation": self.violation}

    def __repr__(self) -> str:
        from .text import check_repr

        return check_repr(self)


def _ge(name: str, value: float, req: float) -> Check:
    ok = bool(value >= req) if not math.isnan(value) else False
    viol = 0.0 if ok else (req - value if math.isfinite(value) else math.inf)
    return Check(name, ">=", req, value, ok, viol)


def _le(name: str, value: float, req: float) -> Check:
    ok = bool(value <= req) if not math.isnan(value) else False
    viol = 0.0 if ok else (value - req if math.isfinite(value) else math.inf)
    return Check(name, "<=", req, value, ok, viol)


def check_spec(metrics: Any, spec: Spec) -> list[Check]:
    """Checks of ``metrics`` (an object with the metric attributes) against ``spec``: stability, then every limit of
    the registry (:data:`tuner.limits.LIMITS`) that ``spec`` sets, in the registry's order (the gain margin's lower
    side with it; zero steady-state error after the overshoot), the settling time last (``< inf`` without a limit:
    the step must settle)."""
    m = metrics
    checks = [Check("stable", "==", True, bool(m.stable), bool(m.stable), 0.0 if m.stable else math.inf)]
    for lim in LIMITS:
        value = getattr(spec, lim.field)
        if lim.field == "settling_time_max":
            continue  # last (below)
        if value is None:
            continue
        got = getattr(m, lim.check)
        if lim.op == ">=":
            checks.append(_ge(lim.check, got, value))
        elif lim.op == "<=":
            checks.append(_le(lim.check, got, value))
        else:  # a target, within CROSSOVER_TOL
            err = abs(got - value) / value if math.isfinite(got) else math.inf
            ok = bool(err <= CROSSOVER_TOL)
            checks.append(Check(lim.check, "==", value, got, ok, 0.0 if ok else err - CROSSOVER_TOL))
        if lim.field == "gain_margin_min_db":
            checks.append(_le("gain_margin_lower_db", m.gain_margin_lower_db, -value))
        if lim.field == "overshoot_max_pct" and spec.zero_steady_state_error:
            sse = abs(m.steady_state_error) if not math.isnan(m.steady_state_error) else math.nan
            checks.append(_le("steady_state_error", sse, SSE_TOL))
    if spec.settling_time_max is not None:
        checks.append(_le("settling_time_s", m.settling_time_s, spec.settling_time_max))
    else:
        checks.append(Check("settling_time_s", "<", math.inf, m.settling_time_s,
                            bool(m.settling_time_s < math.inf), 0.0 if m.settling_time_s < math.inf else math.inf))
    return checks
