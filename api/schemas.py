"""Request and response bodies (pydantic), kept apart from the library's types.

The request's ``spec`` is the library's :class:`tuner.spec.Spec` itself (it is a
pydantic model already). Responses are described here for the OpenAPI document;
non-finite numbers are written as the strings ``"Infinity"``, ``"-Infinity"``,
``"NaN"`` (see :func:`tuner.analysis.jsonable`).
"""

from __future__ import annotations

import datetime as _dt
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from pydantic_core import InitErrorDetails, PydanticCustomError

from tuner.controllers import DEPRECATED_STRUCTURES, MAX_CONTROLLER_ORDER, STRUCTURES
from tuner.limits import EFFORT_NAMES
from tuner.plant import MAX_DT_S, MAX_ORDER, MIN_DT_S
from tuner.problem import MAX_PLANTS
from tuner.spec import Spec

__all__ = [
    "PlantIn", "ControllerIn", "TuneOptions", "TuneRequest", "AnalyzeRequest", "TuneResponse", "TuneRecordOut",
    "TuneList", "TuneSummaryOut", "AnalyzeResponse", "HealthOut", "NlpCodeOut", "ErrorOut", "ValidationErrorOut",
    "TradeoffRequest", "TradeoffResponse", "AtBoundOut", "LimitOut",
    "ROLL_EXAMPLE", "ROLL_ANALYZE_EXAMPLE", "MAX_EXPR_CHARS", "MAX_COEFF", "VehicleIn", "MAX_PARAMS_CHARS",
    "ActuatorIn",
]

MAX_EXPR_CHARS = 1000
MAX_COEFF = 1e100  # |coefficient| bound: far beyond any physical model, far from float overflow
MAX_DELAY_S = 1e4

Coeff = Annotated[float, Field(allow_inf_nan=False, ge=-MAX_COEFF, le=MAX_COEFF)]
SampleTime = Annotated[float, Field(allow_inf_nan=False, ge=MIN_DT_S, le=MAX_DT_S)]
# the structures, and the deprecated names still accepted for one release (pidf2 = pid_mf2; the result says so)
StructureName = Literal[tuple(STRUCTURES) + tuple(DEPRECATED_STRUCTURES)]  # type: ignore[valid-type]

ROLL = "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)"
ROLL_EXAMPLE: dict[str, Any] = {
    "plant": {"expr": ROLL},
    "dt": 0.04,
    "structure": "pid_z",
    "spec": {"phase_margin_min_deg": 60, "gain_margin_min_db": 6, "overshoot_max_pct": 10},
    "options": {"seed": 0, "time_budget_s": 10},
}
ROLL_ANALYZE_EXAMPLE: dict[str, Any] = {
    "plant": {"expr": ROLL},
    "dt": 0.04,
    "controller": {"expr": "3.868*(z^2-1.305*z+0.5668)/(z*(z-1))"},
}


class _In(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)


def _at(field: str, msg: str, value: Any = None, *, kind: str = "value_error") -> ValidationError:
    """A check across a model's fields that is about one of them, located there (``loc`` ending in ``field``, not the
    model: the page shows a 422 at the field it names); raised from a model validator."""
    return ValidationError.from_exception_data("request", [InitErrorDetails(
        type=PydanticCustomError(kind, msg), loc=(field,), input=value)])


class PlantIn(_In):
    """A plant: ``expr`` (in ``s``, or in ``z`` with ``dt``), or coefficients ``num``/``den``."""

    num: list[Coeff] | None = Field(
        None, min_length=1, max_length=MAX_ORDER + 1, description="numerator, highest power first")
    den: list[Coeff] | None = Field(
        None, min_length=1, max_length=MAX_ORDER + 1,
        description=f"denominator, highest power first; order <= {MAX_ORDER}")
    expr: str | None = Field(
        None, min_length=1, max_length=MAX_EXPR_CHARS, description="e.g. 0.2843*18.611/(s+18.611)")
    dt: SampleTime | None = Field(None, description="sample time of a plant given in z; null for a plant in s")
    delay: float = Field(0.0, ge=0, le=MAX_DELAY_S, allow_inf_nan=False, description="input delay, s")

    @model_validator(mode="after")
    def _one_form(self) -> PlantIn:
        coeffs = self.num is not None or self.den is not None
        if self.expr is not None and coeffs:
            raise ValueError("give either expr or num and den, not both")
        if self.expr is None and (self.num is None) != (self.den is None):  # one of the two: the other is missing
            raise _at("den" if self.den is None else "num", "give both num and den (or expr)", kind="missing")
        if self.expr is None and (self.num is None or self.den is None):
            raise ValueError("give expr, or both num and den")
        return self


class ControllerIn(_In):
    """A controller: ``expr``, coefficients ``num``/``den``, or ``structure`` with ``gains``.

    Its sample time is the request's top-level ``dt`` (null: continuous).
    """

    expr: str | None = Field(None, min_length=1, max_length=MAX_EXPR_CHARS,
                             description="e.g. 3.868*(z^2-1.305*z+0.5668)/(z*(z-1))")
    num: list[Coeff] | None = Field(None, min_length=1, max_length=MAX_CONTROLLER_ORDER + 1,
                                    description="numerator, highest power first")
    den: list[Coeff] | None = Field(None, min_length=1, max_length=MAX_CONTROLLER_ORDER + 1,
                                    description=f"denominator, highest power first; order <= {MAX_CONTROLLER_ORDER} "
                                                "(also for expr)")
    structure: StructureName | None = None
    gains: dict[str, Annotated[float, Field(allow_inf_nan=False)]] | None = Field(
        None, max_length=16, description="named parameters of the structure, e.g. {K, a1, a2} for pid_z")

    @model_validator(mode="after")
    def _one_form(self) -> ControllerIn:
        forms = [self.expr is not None, self.num is not None or self.den is not None,
                 self.structure is not None or self.gains is not None]
        if sum(forms) != 1:
            raise ValueError("give exactly one of: expr; num and den; structure and gains")
        if forms[1] and (self.num is None or self.den is None):
            raise _at("den" if self.den is None else "num", "give both num and den", kind="missing")
        if forms[2] and (self.structure is None or self.gains is None):
            raise _at("gains" if self.gains is None else "structure", "give both structure and gains", kind="missing")
        return self


MAX_PARAMS_CHARS = 2_000_000  # a vehicle's parameter file (a full PX4 .params is about 60 kB)


class VehicleIn(_In):
    """What the vehicle fixes for a firmware rate law (``px4_rate``, ``ardupilot_rate``): loop rate, filters, PX4's K,
    the integrator limit, and its current gains, analysed next to the proposed ones."""

    params: str | None = Field(None, min_length=1, max_length=MAX_PARAMS_CHARS,
                               description="the text of the vehicle's parameter file: a QGroundControl .params "
                                           "(PX4) or a Mission Planner .parm (ArduPilot)")
    from_identification: bool = Field(False, description="instead of params: the parameters stored in the ULog the "
                                      "identification (identification_id) was made from")
    axis: Literal["roll", "pitch", "yaw"] = Field("roll", description="the axis whose rate law")

    @model_validator(mode="after")
    def _one_source(self) -> VehicleIn:
        if (self.params is None) == (not self.from_identification):
            raise ValueError("give params (the text of a .params or .parm file) or from_identification: true, "
                             "not both")
        return self


class ActuatorIn(_In):
    """The actuator's limits and a reference step's amplitude: that step is simulated with the output clamped and
    the integrator handled as the law does (``saturated_step`` in the answer, its overshoot and settling checked)."""

    u_max: float | None = Field(None, allow_inf_nan=False, description="upper output limit (alone: |u| <= u_max)")
    u_min: float | None = Field(None, allow_inf_nan=False, description="lower output limit")
    step_size: float = Field(1.0, allow_inf_nan=False, description="amplitude of the reference step (non-zero)")

    @model_validator(mode="after")
    def _limits(self) -> ActuatorIn:
        if self.u_min is None and self.u_max is None:
            raise _at("u_max", "give the actuator's limit: u_max (and u_min; u_max alone is symmetric)", kind="missing")
        hi = self.u_max if self.u_max is not None else -self.u_min
        lo = self.u_min if self.u_min is not None else -hi
        if not lo < hi:
            raise _at("u_min" if self.u_min is not None else "u_max", f"u_min ({lo:g}) must be below u_max ({hi:g})",
                      self.u_min if self.u_min is not None else self.u_max)
        if self.step_size == 0:
            raise _at("step_size", "step_size must be non-zero", self.step_size)
        return self

    def to_actuator(self) -> Any:
        from tuner.analysis.saturation import Actuator

        return Actuator.of(u_min=self.u_min, u_max=self.u_max, step_size=self.step_size)


class TuneOptions(_In):
    seed: int = Field(0, ge=0, le=2**32 - 1, description="seeds the global search: same seed, same gains")
    time_budget_s: float | None = Field(
        None, gt=0, le=60, allow_inf_nan=False,
        description="wall-time budget of the solve (default 10 s; the server may set a lower maximum). "
                    "Past it the best verified result so far is returned, or 504 if the solver overruns.")
    effort: Literal[EFFORT_NAMES] = Field(  # type: ignore[valid-type]
        "default", description="how hard to search: fast (the first round alone), default (plus an independent "
                               "restart that must find nothing better), thorough (three in a row, more starts); "
                               "solver.optimality says what the search knows about how close the answer is")


class TuneRequest(_In):
    model_config = ConfigDict(extra="forbid", strict=True, json_schema_extra={"examples": [ROLL_EXAMPLE]})

    plant: PlantIn | None = Field(None, description="the nominal plant (or identification_id)")
    plants: list[PlantIn] | None = Field(
        None, max_length=MAX_PLANTS - 1,
        description="more plants for robust tuning: every constraint must hold on each of them")
    identification_id: str | None = Field(
        None, min_length=1, max_length=64,
        description="instead of plant: the id of a stored identification (POST /identify); its fitted model "
                    "with the delay as fitted")
    robust: float | None = Field(
        None, gt=0, le=10, allow_inf_nan=False,
        description="with identification_id: one controller for the plant set spanned by the identified "
                    "parameters' robust-sigma Cramér–Rao bounds, then a Monte Carlo check (result.robust)")
    monte_carlo: int | None = Field(
        None, ge=0, le=2000, description="with identification_id: draws of the Monte Carlo check from the "
                                         "parameters' covariance (default 200 with robust, else 0)")
    dt: SampleTime | None = Field(None, description="controller sample time, s; null = continuous controller")
    structure: StructureName = Field(description="controller structure; pid2 is the 2-DOF PID u = Kp(b r - y) + "
                                     "Ki/s (r - y) + Kd s/(Tf s+1)(c r - y); pidf2 is the deprecated name of pid_mf2")
    spec: Spec | None = Field(None, description="defaults: PM >= 60 deg, GM >= 6 dB, overshoot <= 10 %, ...")
    options: TuneOptions = Field(default_factory=TuneOptions)
    actuator: ActuatorIn | None = Field(None, description="the actuator's limits: a step of step_size is also "
                                        "simulated with the output clamped, as the law runs it (needs dt)")
    vehicle: VehicleIn | None = Field(None, description="px4_rate / ardupilot_rate: the vehicle's parameters (loop "
                                      "rate, filters, K, integrator limit, current gains); dt defaults to its loop "
                                      "rate; the response adds `vehicle` and `current` (its current tune analysed)")


class TradeoffRequest(TuneRequest):
    model_config = ConfigDict(extra="forbid", strict=True, json_schema_extra={"examples": [
        {"plant": {"expr": "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)"}, "dt": 0.04, "structure": "pid",
         "y": "mks", "points": 8}]})

    x: Literal["settling_time"] = Field("settling_time", description="the speed axis")
    y: Literal["mks", "control_peak"] = Field("mks", description="the robustness axis")
    points: int = Field(8, ge=2, le=20, description="how many verified points, fastest first")


class AnalyzeRequest(_In):
    model_config = ConfigDict(extra="forbid", strict=True, json_schema_extra={"examples": [ROLL_ANALYZE_EXAMPLE]})

    plant: PlantIn | None = Field(None, description="the plant (or identification_id)")
    identification_id: str | None = Field(
        None, min_length=1, max_length=64,
        description="instead of plant: the id of a stored identification (POST /identify): the controller is judged "
                    "on its fitted model and on its measured frequency response (the margins by the worst end of "
                    "their error range), and the identification's rating is part of the verdict")
    dt: SampleTime | None = Field(None, description="controller sample time, s; null = continuous controller")
    controller: ControllerIn
    spec: Spec | None = None
    actuator: ActuatorIn | None = Field(None, description="the actuator's limits: a step of step_size is also "
                                        "simulated with the output clamped, as the law runs it (needs dt)")
    vehicle: VehicleIn | None = Field(None, description="with controller {structure: px4_rate or ardupilot_rate, "
                                      "gains}: the vehicle's parameters (its fixed values; gains left out are its "
                                      "current ones, so gains {} analyses the loop it flies)")


# -- responses ---------------------------------------------------------------------------

Number = float | Literal["Infinity", "-Infinity", "NaN"]


class _Out(BaseModel):
    model_config = ConfigDict(extra="allow")


class MetricsOut(_Out):
    stable: bool
    phase_margin_deg: Number
    crossover_rad_s: Number
    gain_margin_db: Number
    gain_margin_lower_db: Number
    disk_margin: Number
    ms: Number
    mt: Number
    mks: Number
    bandwidth_rad_s: Number
    overshoot_pct: Number
    settling_time_s: Number
    rise_time_s: Number
    steady_state_error: Number
    control_peak: Number


class CheckOut(_Out):
    name: str
    op: str
    required: Any
    achieved: Any
    ok: bool
    violation: Number


class ControllerOut(_Out):
    num: list[float] = Field(description="C (the feedback, acting on e = r - y; for pid2 on -y), highest power first")
    den: list[float]
    dt: float | None
    num_r: list[float] | None = Field(None, description="2-DOF (pid2): the reference path C_r = num_r/den acting "
                                      "on r (u = C_r r - C y); absent for a 1-DOF controller")


class AnalysisOut(_Out):
    metrics: MetricsOut
    checks: list[CheckOut]
    meets_spec: bool


class AnalyzeResponse(AnalysisOut):
    controller: ControllerOut


class ObjectiveOut(_Out):
    name: str
    value: Number = Field(description="the spec's objective as the verifier computes it (worst over the plants; "
                          "bandwidth: minus the bandwidth)")


class ReasonOut(_Out):
    constraints: list[str]
    message: str
    suggest: dict[str, Any] = Field(description="spec fields and values that the search found feasible")


class AtBoundOut(_Out):
    param: str | None = Field(description="the parameter on a bound (null: a limit on the loop, e.g. the noise "
                              "budget)")
    value: Number
    bound: Literal["lower", "upper"]
    limit: Number
    rule: str = Field(description="what sets the bound, in words")
    text: str = Field(description="one sentence for people: 'Tf is at its lower bound 0.0127: ... decides'")


class LimitOut(_Out):
    field: str = Field(description="the spec field of a default design limit in force")
    value: Number
    rule: str


class TuneResponse(_Out):
    id: str
    created_at: _dt.datetime
    structure: str
    gains: dict[str, float]
    controller: ControllerOut
    metrics: MetricsOut
    checks: list[CheckOut]
    meets_spec: bool
    failing: list[str]
    objective: ObjectiveOut | None = None
    reasons: list[ReasonOut] = Field(default_factory=list, description="why the spec is not met and what would "
                                     "make it feasible (empty when it is met)")
    at_bounds: list[AtBoundOut] = Field(default_factory=list, description="parameters that sit on a search bound "
                                        "or a default limit, with the rule that decides them")
    limits: list[LimitOut] = Field(default_factory=list, description="the default design limits in force "
                                   "(derivative filter, Nyquist filter rule, noise budget); spec.filter_n_max = "
                                   "null, filter_nyquist = false, noise_gain_max = null lift them")
    solver: dict[str, Any]
    spec: dict[str, Any]
    plants: list[AnalysisOut] | None = None


class TradeoffResponse(_Out):
    structure: str
    x: str
    y: str
    wall_time_s: float
    points: list[dict[str, Any]] = Field(description="fastest first: settling_time_s, the y value, the limit it was "
                                         "tuned with, gains, and the whole verified result")
    skipped: list[dict[str, Any]]


class TuneRecordOut(TuneResponse):
    request: dict[str, Any] = Field(description="the request as validated (defaults filled in)")


class TuneSummaryOut(_Out):
    id: str
    created_at: _dt.datetime
    structure: str
    meets_spec: bool


class TuneList(_Out):
    items: list[TuneSummaryOut]
    total: int
    limit: int
    offset: int


class NlpCodeOut(_Out):
    """The NLPs' compiled code (tuner.optimize.nlp.codecache.status): the mode (``off`` also where the cache is off:
    no compiler, or a cache root that is not private), the background compiles waiting or running, the shapes
    compiled, and those marked not to compile (too large, or their compile failed: they stay interpreted); where the
    cache folder cannot be read, the counts are null and ``error`` says so (the status code never depends on it)."""
    mode: Literal["auto", "load", "off"]
    pending: int | None
    compiled: int | None
    marked: int | None
    error: str | None = None


class HealthOut(_Out):
    status: Literal["ok", "degraded"]
    database: Literal["ok", "unreachable"]
    workers: dict[str, int]
    plots: dict[str, int]
    nlp_code: NlpCodeOut
    versions: dict[str, str]


class ErrorOut(_Out):
    detail: str


class ValidationItem(_Out):
    loc: list[str | int]
    msg: str
    type: str


class ValidationErrorOut(_Out):
    detail: list[ValidationItem]
