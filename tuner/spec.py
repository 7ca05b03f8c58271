"""What "good" means: constraints and the objective, validated.

Defaults are the quadrotor thesis's: phase margin >= 60 deg, gain margin >= 6 dB
(upper, and the lower gain margin <= -6 dB where the loop has one), overshoot
<= 10 %, zero steady-state error, settling band 2 %, objective = settling time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from .objectives import OBJECTIVE_DEFINITIONS, ROBUST_NOTE

__all__ = ["Spec", "Check", "check_spec", "OBJECTIVES"]

OBJECTIVES = ("settling_time", "itae", "iae", "ie", "bandwidth")
SSE_TOL = 1e-6


class Spec(BaseModel):
    """A tuning specification. Optional limits are ``None`` when not requested."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    phase_margin_min_deg: float = Field(60.0, ge=0, le=90, description="minimum phase margin, degrees")
    gain_margin_min_db: float = Field(6.0, ge=0, le=40, description="minimum gain margin (upper and lower), dB")
    overshoot_max_pct: float = Field(10.0, ge=0, le=100, description="maximum step overshoot, %")
    zero_steady_state_error: bool = Field(True, description="require zero steady-state error to a step")
    settling_band_pct: float = Field(2.0, gt=0, le=20, description="settling band, % of the final value")
    objective: Literal["settling_time", "itae", "iae", "ie", "bandwidth"] = Field(
        "settling_time", description="what is optimised (tuner.objectives): " + "; ".join(
            f"{k}: {v}" for k, v in OBJECTIVE_DEFINITIONS.items()) + ". " + ROBUST_NOTE)
    control_peak_max: float | None = Field(None, gt=0, description="maximum |u| after a unit reference step")
    ms_max: float | None = Field(None, ge=1, description="maximum sensitivity peak Ms = max |1/(1+L)| (>= 1)")
    mt_max: float | None = Field(None, gt=0, description="maximum complementary sensitivity peak Mt = max |L/(1+L)| "
                                 "(>= 1 with zero steady-state error, since T(0) = 1; a tune refuses less)")
    mks_max: float | None = Field(None, gt=0, description="maximum noise sensitivity Mks = max |C/(1+L)|: how much "
                                  "sensor noise reaches the actuator")
    disk_margin_min: float | None = Field(None, gt=0, lt=2, description="minimum balanced disk margin alpha (0..2)")
    bandwidth_min_rad_s: float | None = Field(None, gt=0, description="minimum closed-loop bandwidth, rad/s")


@dataclass(frozen=True)
class Check:
    """One constraint: ``achieved op required``; ``violation`` is how far from ok (0 when ok)."""

    name: str
    op: str
    required: Any
    achieved: Any
    ok: bool
    violation: float

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "op": self.op, "required": self.required, "achieved": self.achieved,
                "ok": self.ok, "violation": self.violation}


def _ge(name: str, value: float, req: float) -> Check:
    ok = bool(value >= req) if not math.isnan(value) else False
    viol = 0.0 if ok else (req - value if math.isfinite(value) else math.inf)
    return Check(name, ">=", req, value, ok, viol)


def _le(name: str, value: float, req: float) -> Check:
    ok = bool(value <= req) if not math.isnan(value) else False
    viol = 0.0 if ok else (value - req if math.isfinite(value) else math.inf)
    return Check(name, "<=", req, value, ok, viol)


def check_spec(metrics: Any, spec: Spec) -> list[Check]:
    """Checks of ``metrics`` (an object with the metric attributes) against ``spec``."""
    m = metrics
    checks = [Check("stable", "==", True, bool(m.stable), bool(m.stable), 0.0 if m.stable else math.inf)]
    checks.append(_ge("phase_margin_deg", m.phase_margin_deg, spec.phase_margin_min_deg))
    checks.append(_ge("gain_margin_db", m.gain_margin_db, spec.gain_margin_min_db))
    checks.append(_le("gain_margin_lower_db", m.gain_margin_lower_db, -spec.gain_margin_min_db))
    checks.append(_le("overshoot_pct", m.overshoot_pct, spec.overshoot_max_pct))
    if spec.zero_steady_state_error:
        sse = abs(m.steady_state_error) if not math.isnan(m.steady_state_error) else math.nan
        checks.append(_le("steady_state_error", sse, SSE_TOL))
    if spec.control_peak_max is not None:
        checks.append(_le("control_peak", m.control_peak, spec.control_peak_max))
    if spec.ms_max is not None:
        checks.append(_le("ms", m.ms, spec.ms_max))
    if spec.mt_max is not None:
        checks.append(_le("mt", m.mt, spec.mt_max))
    if spec.mks_max is not None:
        checks.append(_le("mks", m.mks, spec.mks_max))
    if spec.disk_margin_min is not None:
        checks.append(_ge("disk_margin", m.disk_margin, spec.disk_margin_min))
    if spec.bandwidth_min_rad_s is not None:
        checks.append(_ge("bandwidth_rad_s", m.bandwidth_rad_s, spec.bandwidth_min_rad_s))
    checks.append(Check("settling_time_s", "<", math.inf, m.settling_time_s,
                        bool(m.settling_time_s < math.inf), 0.0 if m.settling_time_s < math.inf else math.inf))
    return checks
