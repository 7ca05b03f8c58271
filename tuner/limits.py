"""The registry: one declarative statement of every limit and every objective.

Each :class:`Limit` says, once, what a limit is: its name (the :class:`~tuner.spec.Spec` field, which is also the
API's and the study files' field), unit, sense, default and bounds, the command-line flag, the page's label, the
metric the verifier checks (a :class:`~tuner.analysis.Metrics` attribute), how the batched search computes it
(``batch``: the key of :meth:`tuner.optimize.batch.BatchEvaluator` figures, and how far inside the limit the search
keeps), how the NLP states it (``nlp``: its frequency-grid rows are switched on from here; the rows' forms are
written in :mod:`tuner.optimize.nlp.transcribe`), and what the diagnosis says when it binds. Each
:class:`Objective` says what is optimised and where each evaluator computes it.

Who reads it: :class:`~tuner.spec.Spec` (its limit fields are generated from :data:`LIMITS`), the verifier's checks
(:func:`tuner.spec.check_spec`), the batched search (:mod:`tuner.optimize.batch`), the NLP
(:mod:`tuner.optimize.nlp`), the diagnosis (:mod:`tuner.diagnose`), the command line's flags and ``--help``
(:mod:`tuner.cli`), the API schema (the request's ``spec`` is the Spec), the study files (the same) and the page
(its limit inputs come from :func:`page_limits` through the page's configuration).

Adding a limit: an entry here, its formula in the evaluators that compute the metric (the verifier's
:class:`~tuner.analysis.Metrics` field; the batch's figure when it has one; the NLP's rows when it states it), and a
test (``tests/tuner/test_registry_contract.py`` checks every entry's evaluators against the verifier). Nothing else:
the flag, the field, the check, the page's input and the diagnosis follow from the entry.

Bottom layer: imports nothing of the package (the command line's ``--help`` reads it without numpy or pydantic).

Examples
--------
>>> from tuner.limits import LIMITS, limit
>>> limit("drb_min_rad_s").flag, limit("drb_min_rad_s").check, limit("drb_min_rad_s").op
('--drb-min', 'disturbance_rejection_bandwidth_rad_s', '>=')
>>> [l.field for l in LIMITS if l.default is not None]
['phase_margin_min_deg', 'gain_margin_min_db', 'overshoot_max_pct']
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ["Limit", "Objective", "LIMITS", "OBJECTIVES", "limit", "objective", "by_check", "page_limits",
           "INFEASIBLE", "SSE_TOL", "CROSSOVER_TOL", "EFFORT_NAMES"]

EFFORT_NAMES = ("fast", "default", "thorough")
"""The efforts a tune can be asked for (what each does: :data:`tuner.optimize.engine.EFFORTS`); the CLI, the API,
study files and the page list these."""

INFEASIBLE = 1e3
"""Every infeasible search score is above this, every feasible one below (the batch, the verifier's scoring, the
engine's convergence tests read this one number)."""
SSE_TOL = 1e-6
"""Zero steady-state error holds when ``|e(inf)| <= SSE_TOL`` (the reference step is 1)."""
CROSSOVER_TOL = 0.01
"""A target crossover is met within +-1 %."""


@dataclass(frozen=True)
class Limit:
    """One limit (see the module docstring).

    ``op``: ``">="`` (a minimum), ``"<="`` (a maximum) or ``"=="`` (a target, met within a tolerance). ``bounds``:
    pydantic's ``ge``/``gt``/``le``/``lt`` of the value. ``batch``: the batched search's figure (None: the batch does
    not compute it; the verifier of the finalists still checks it). ``guard``: how far inside the limit the search
    keeps (the search's grids are coarser than the verifier's): ``("add", a)`` adds ``a`` in the limit's sense,
    ``("mul", f)`` with ``f <= 1``: a maximum times ``f``, a minimum divided by it.
    ``nlp``: how the NLP states it (``"margin"``, ``"grid"``, ``"step"``, ``"envelope"``, ``"target"``; None: not in
    the NLP, the batch and the verifier hold it). ``loosest``: the value that lifts it (the diagnosis relaxes a
    failing limit to this; None: the field is removed). ``binds``: what the diagnosis says when it binds (formatted
    with ``value``, the limit asked)."""

    field: str
    check: str
    op: str
    unit: str
    flag: str
    label: str
    help: str
    default: float | None = None
    bounds: dict[str, float] = field(default_factory=dict)
    metavar: str | None = None
    batch: str | None = None
    guard: tuple[str, float] = ("mul", 1.0)
    nlp: str | None = None
    loosest: float | None = None
    binds: str = ""
    source: str = ""
    page: str = "limits"  # the page's row for its input: "limits", or "speed" (the response-time knob's)

    @property
    def sense(self) -> int:
        """+1 for a minimum (``>=``), -1 for a maximum (``<=``), 0 for a target."""
        return {">=": 1, "<=": -1}.get(self.op, 0)

    def search_limit(self, value: float) -> float:
        """The value the batched search holds (a little inside ``value``, by ``guard``)."""
        kind, a = self.guard
        if kind == "add":
            return value + a * self.sense * (value > 0) if self.sense else value
        return value * a if self.sense < 0 else value / a


@dataclass(frozen=True)
class Objective:
    """One objective: ``sense`` ``"min"`` or ``"max"``; ``metric``: the :class:`~tuner.analysis.Metrics` attribute
    (None: computed from the responses by :func:`tuner.optimize.scoring.objective_value`); ``batch``: the batched
    search's figure; ``nlp``: the NLP states it exactly; ``robust``: a robustness objective (optimised "as robust as
    possible at this speed": the fastest design leads its search)."""

    name: str
    sense: str
    definition: str
    metric: str | None = None
    batch: str | None = None
    nlp: bool = True
    robust: bool = False


_HORIZON = ("T is the verifier's simulation horizon (10 time constants of the slowest closed-loop pole plus twice "
            "the delay, bounded)")

LIMITS: tuple[Limit, ...] = (
    Limit("phase_margin_min_deg", "phase_margin_deg", ">=", "deg", "--pm", "phase margin ≥ [deg]",
          "minimum phase margin, degrees", default=60.0, bounds={"ge": 0, "le": 90}, metavar="DEG", batch="pm",
          guard=("add", 0.01), nlp="margin", loosest=0.0, source="the quadrotor thesis"),
    Limit("gain_margin_min_db", "gain_margin_db", ">=", "dB", "--gm", "gain margin ≥ [dB]",
          "minimum gain margin (upper, and the lower gain margin <= -this where the loop has one), dB", default=6.0,
          bounds={"ge": 0, "le": 40}, metavar="DB", batch="gm", guard=("add", 0.002), nlp="margin", loosest=0.0,
          source="the quadrotor thesis"),
    Limit("overshoot_max_pct", "overshoot_pct", "<=", "%", "--overshoot", "overshoot ≤ [%]",
          "maximum step overshoot, %", default=10.0, bounds={"ge": 0, "le": 100}, metavar="PCT",
          batch="overshoot_pct", guard=("mul", 0.99), nlp="step", loosest=100.0, source="the quadrotor thesis"),
    Limit("control_peak_max", "control_peak", "<=", "", "--control-peak", "control peak |u| ≤",
          "maximum |u| after a unit reference step", bounds={"gt": 0}, metavar="U", batch="control_peak",
          nlp="step"),
    Limit("ms_max", "ms", "<=", "", "--ms", "Ms ≤", "maximum sensitivity peak Ms = max |1/(1+L)| (>= 1)",
          bounds={"ge": 1}, metavar="MS", batch="ms", nlp="grid"),
    Limit("mt_max", "mt", "<=", "", "--mt", "Mt ≤",
          "maximum complementary sensitivity peak Mt = max |L/(1+L)| (>= 1 with zero steady-state error, since "
          "T(0) = 1; a tune refuses less)", bounds={"gt": 0}, metavar="MT", batch="mt", nlp="grid"),
    Limit("mks_max", "mks", "<=", "", "--mks", "Mks ≤",
          "maximum noise sensitivity Mks = max |C/(1+L)|: how much sensor noise reaches the actuator",
          bounds={"gt": 0}, metavar="MKS", batch="mks", nlp="grid"),
    Limit("disk_margin_min", "disk_margin", ">=", "", "--disk-margin", "disk margin ≥",
          "minimum balanced disk margin alpha (0..2)", bounds={"gt": 0, "lt": 2}, metavar="ALPHA", batch="dm",
          nlp="grid"),
    Limit("bandwidth_min_rad_s", "bandwidth_rad_s", ">=", "rad/s", "--bandwidth", "bandwidth ≥ [rad/s]",
          "minimum closed-loop bandwidth, rad/s", bounds={"gt": 0}, metavar="RAD_S", batch="bw"),
    Limit("drb_min_rad_s", "disturbance_rejection_bandwidth_rad_s", ">=", "rad/s", "--drb-min",
          "disturbance rejection bandwidth ≥ [rad/s]",
          "minimum disturbance rejection bandwidth, rad/s: |S| = |1/(1+L)| stays below -3 dB up to this frequency "
          "(on the exact sampled loop at dt); no default (ADS-33E-PRF and the rotorcraft literature give figures per "
          "vehicle class and axis, none general)", bounds={"gt": 0}, metavar="RAD_S", batch="drb", nlp="grid",
          binds="|S| reaches -3 dB below {value:g} rad/s: more loop gain at low frequency (integral action, a "
                "higher crossover) or a lower drb_min_rad_s"),
    Limit("ki_min", "integral_gain", ">=", "", "--ki-min", "integral gain |Ki| ≥",
          "minimum integral gain |Ki| (Ki = lim s C(s), or lim (z - 1) C(z)/dt): demands integral action, and bounds "
          "the load step's IE = 1/|Ki| (a constant load at the plant input, a CG offset or a weak motor, is rejected "
          "with IE <= 1/ki_min); no default", bounds={"gt": 0}, metavar="KI", batch="ki", nlp="ki",
          binds="the integral gain reaches only what the other limits leave: relax them (a control peak, Mks, the "
                "settling time), or give a lower ki_min"),
    Limit("settling_time_max", "settling_time_s", "<=", "s", "--settling-max", "settling time ≤ [s]",
          "maximum 2 % settling time (the settling band) of the unit reference step, s: the response-time knob "
          "(with objective mks or disk_margin: the most robust design at that speed)", bounds={"gt": 0},
          metavar="S", batch="settling_time_s", guard=("mul", 0.995), nlp="envelope", page="speed"),
    Limit("crossover_rad_s", "crossover_rad_s", "==", "rad/s", "--wc", "crossover wc = [rad/s]",
          "target gain-crossover frequency wc, rad/s (as pidtune(G, type, wc)): the loop must cross over within "
          "+-1 % of it", bounds={"gt": 0}, metavar="RAD_S", batch="wc", nlp="target", page="speed"),
)

OBJECTIVES: tuple[Objective, ...] = (
    Objective("settling_time", "min",
              "minimise the settling time of the unit reference step: the last time the plant output y(t) "
              "(continuous, between the samples too) is outside |y - y_final| <= band*|y_final| (settling band, "
              "default 2 %), interpolated linearly between the fine instants", metric="settling_time_s",
              batch="settling_time_s"),
    Objective("itae", "min",
              "minimise the ITAE of the unit reference step: the integral over [0, T] of t*|1 - y(t)| dt (trapezoid "
              f"rule on the fine grid of the continuous output); {_HORIZON}", batch="itae"),
    Objective("iae", "min",
              "minimise the IAE after a unit step load disturbance added at the plant input (the plant gets u + 1, "
              "before its delay) with r = 0: the integral over [0, T] of |e(t)| dt = |y(t)| dt, e = r - y; T as for "
              "itae (the verifier's load_iae where y returns to 0; load_iae reports inf where it does not)",
              batch="iae"),
    Objective("ie", "min",
              "minimise the IE after that unit load step, |integral over [0, inf) of e(t) dt| = 1/Ki for a stable "
              "loop with integral action, Ki = lim s->0 of s*C(s) (continuous) or lim z->1 of (z - 1)*C(z)/dt "
              "(discrete): Ki is maximised (MIGO); infinite without integral action", batch="ie"),
    Objective("bandwidth", "max",
              "maximise the closed-loop bandwidth: the lowest frequency where |T(jw)| falls below |T(0)|/sqrt(2) "
              "(T = L/(1 + L); T(0) = 1 with integral action), found on the verifier's frequency grid (up to the "
              "Nyquist frequency pi/dt at dt) and refined by root finding", metric="bandwidth_rad_s", batch="bw",
              nlp=False),
    Objective("mks", "min",
              "minimise the noise sensitivity Mks = max over w of |C/(1 + L)| (how much sensor noise reaches the "
              "actuator), on the verifier's frequency grid and w -> inf: with --settling-max or --wc, the most "
              "noise-robust design at that speed", metric="mks", batch="mks", robust=True),
    Objective("disk_margin", "max",
              "maximise the balanced disk margin alpha = min over w of 2|1 + L|/|1 - L| (the largest simultaneous "
              "gain and phase variation the loop tolerates): with --settling-max or --wc, the most robust design "
              "at that speed", metric="disk_margin", batch="dm", robust=True),
)

_BY_FIELD = {lim.field: lim for lim in LIMITS}
_BY_CHECK = {lim.check: lim for lim in LIMITS}
_OBJ = {o.name: o for o in OBJECTIVES}


def limit(name: str) -> Limit:
    """The limit of Spec field ``name``."""
    return _BY_FIELD[name]


def by_check(check: str) -> Limit | None:
    """The limit whose verifier check is ``check`` (``gain_margin_lower_db``: the gain margin's), else None."""
    return _BY_CHECK.get("gain_margin_db" if check == "gain_margin_lower_db" else check)


def objective(name: str) -> Objective:
    """The objective called ``name``."""
    return _OBJ[name]


def page_limits() -> list[dict[str, Any]]:
    """The page's inputs of the optional limits (those without a default; the thesis's have sliders): field,
    label, op, unit, help, the row they go in, and the smallest value (``min``) where the bounds give one."""
    out = []
    for lim in LIMITS:
        if lim.default is not None:
            continue
        lo = lim.bounds.get("ge", lim.bounds.get("gt"))
        out.append({"field": lim.field, "label": lim.label, "op": lim.op, "unit": lim.unit, "help": lim.help,
                    "row": lim.page, **({"min": lo} if lo is not None else {})})
    return out
