"""Request and response bodies of ``POST /identify`` and the stored identifications.

Samples are JSON numbers (non-finite values are refused by the schema, with the index in
``loc``); a record has at most :data:`MAX_SAMPLES` samples. Responses write non-finite numbers
as the strings ``"Infinity"``, ``"-Infinity"``, ``"NaN"`` (e.g. the bound of a parameter the
data cannot determine).
"""

from __future__ import annotations

import datetime as _dt
import math
import random
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from tuner.identify import MAX_POLES
from tuner.identify.data import MAX_SAMPLES as LIB_MAX_SAMPLES
from tuner.identify.data import MIN_SAMPLES

from .schemas import Number

__all__ = [
    "IDENTIFY_EXAMPLE",
    "MAX_SAMPLES",
    "IdentificationData",
    "IdentificationList",
    "IdentificationRecordOut",
    "IdentificationSummaryOut",
    "IdentifyOptions",
    "IdentifyRequest",
    "IdentifyResponse",
    "ULogUpload",
    "VerifyRecord",
]

# the record limit: the library's, the same as the command line's (a CSV's rows, a ULog's grid samples): 2e6 samples;
# a JSON body is capped in bytes as well (TUNER_MAX_IDENTIFY_BODY_BYTES, 24 MB), and its 413 says how to send more
MAX_SAMPLES = LIB_MAX_SAMPLES

Sample = Annotated[float, Field(allow_inf_nan=False)]
Samples = Annotated[list[Sample], Field(min_length=MIN_SAMPLES, max_length=MAX_SAMPLES)]
Positive = Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)]



def _example(n: int = 1500, rate_hz: float = 50.0) -> dict[str, Any]:
    """A 30 s exponential sweep (1 -> 30 rad/s) through 10/(s+10) with a 40 ms delay at 50 Hz
    (simulated exactly for an input linear between samples), plus sensor noise."""
    dt, p, t_end = 1.0 / rate_hz, 10.0, n / rate_hz
    u, theta = [], 0.0
    for k in range(n):
        u.append(math.sin(theta))
        theta += dt * (1.0 + 29.0 * 0.0187 * (math.exp(4.0 * k * dt / t_end) - 1.0))
    ud = [0.0, 0.0] + u[:-2]
    a = math.exp(-p * dt)
    noise = random.Random(0)
    y, x = [], 0.0
    for k in range(n):
        y.append(x + noise.gauss(0.0, 0.02))
        nxt = ud[k + 1] if k + 1 < n else ud[k]
        x = a * x + (1.0 - a) * ud[k] + (nxt - ud[k]) * (1.0 - (1.0 - a) / (p * dt))
    return {"input": [round(v, 4) for v in u], "output": [round(v, 4) for v in y], "rate_hz": rate_hz,
            "poles": 1, "zeros": 0, "delay": "auto", "delay_step": 0.02, "holdout": 0.0}


IDENTIFY_EXAMPLE: dict[str, Any] = _example()


class _In(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)


class IdentifyOptions(_In):
    """What to fit, and how (the options of :func:`tuner.identify`)."""

    poles: int = Field(ge=1, le=MAX_POLES, description="number of poles of the model")
    zeros: int = Field(0, ge=0, le=MAX_POLES, description="number of zeros (at most poles)")
    delay: Literal["auto"] | Annotated[float, Field(ge=0, le=1e4, allow_inf_nan=False)] | None = Field(
        "auto", description='"auto" estimates an equivalent time delay; a number fixes it (s); null: none')
    delay_step: Positive | None = Field(
        None, description="optional: restrict the delay to whole multiples of this (s); by default the delay "
                    "is fitted freely (the tuner takes any delay exactly, also in a sampled-data loop)")
    band: Annotated[list[Positive], Field(min_length=2, max_length=2)] | None = Field(
        None, description="fit band [w_min, w_max], rad/s (default: where the coherence >= coherence_min)")
    holdout: Literal["auto"] | Annotated[float, Field(ge=0, le=0.5, allow_inf_nan=False)] = Field(
        "auto", description='what the time-domain check runs on: "auto" (the last 20 % if it excites the band and '
                            "is not the top of the sweep, else the fitted record; nothing with verify), a fraction "
                            "held out at the end, or 0 (no check)")
    coherence_min: float = Field(0.6, gt=0, lt=1, allow_inf_nan=False)
    hold: Literal["auto", "zoh", "none"] = Field(
        "auto", description="how the plant saw the input between samples: zoh (a controller's output, held: the "
                            "model put back at the rate with a zero-order hold reproduces the measured response), none "
                            "(a sampled continuous signal, e.g. a stick); auto: zoh for a ulog, none for samples")
    n_points: int = Field(25, ge=8, le=200, description="log-spaced fit frequencies in the band")
    seed: int = Field(0, ge=0, le=2**32 - 1, description="seeds the fit's random starts")


class VerifyRecord(_In):
    """A separate verification record (e.g. doublets): the time-domain check runs on it."""

    input: Samples
    output: Samples
    time: Samples | None = Field(None, description="sample times, s; or rate_hz; neither: the fitted record's rate")
    rate_hz: Positive | None = None


MAX_ULOG_BASE64 = 24_000_000  # characters (18 MB of log); the body cap TUNER_MAX_IDENTIFY_BODY_BYTES applies too


class ULogUpload(_In):
    """A flight log, base64-encoded: a PX4 ULog (``.ulg``) or an ArduPilot DataFlash log (``.bin``, told by its first
    bytes), and the two signals to take from it."""

    data: str = Field(min_length=16, max_length=MAX_ULOG_BASE64, description="the .ulg or .bin file, base64 "
                      "(standard alphabet, padded)")
    input: str = Field(min_length=3, max_length=200, description="TOPIC[:INSTANCE].FIELD of the plant input "
                       "(held between its samples), e.g. vehicle_torque_setpoint.xyz[0]; DataFlash: MESSAGE.FIELD, "
                       "e.g. RATE.ROut")
    output: str = Field(min_length=3, max_length=200, description="TOPIC[:INSTANCE].FIELD of the plant output "
                        "(interpolated linearly), e.g. vehicle_angular_velocity.xyz[0]; DataFlash: e.g. RATE.R")
    reference: str | None = Field(None, min_length=3, max_length=200, description="data flown under feedback: "
                                  "TOPIC[:INSTANCE].FIELD of the exogenous signal (an injected excitation, or the rate "
                                  "setpoint flown in a rate mode, e.g. vehicle_rates_setpoint.roll), held")


class IdentifyRequest(IdentifyOptions):
    model_config = ConfigDict(extra="forbid", strict=True,
                              json_schema_extra={"examples": [IDENTIFY_EXAMPLE]})

    input: Samples | None = Field(None, description="plant input samples (e.g. the command); or ulog")
    output: Samples | None = Field(None, description="plant output samples (e.g. the angle), as many as input")
    reference: Samples | None = Field(None, description="data flown under feedback: the exogenous signal's samples "
                                      "(an injected excitation, or the setpoint), as many as input; the response is "
                                      "then the joint estimate S_ry/S_ru")
    time: Samples | None = Field(None, description="sample times, in time_unit (strictly increasing, uniform); or "
                                 "rate_hz")
    time_unit: Literal["auto", "s", "ms", "us"] = Field(
        "auto", description="the unit of time (and of verify.time): s, ms, or us (a microsecond timestamp, as PX4's "
                            "CSV exports have); auto: seconds, and times whose steps look like another unit (whole "
                            "numbers of 100 and more, or 0.1 to 1) are refused (422 at time_unit) until it is given")
    rate_hz: Positive | None = Field(None, description="sample rate, Hz; or time. With ulog: the grid the topics "
                                     "are resampled onto (default: the slower topic's rate)")
    ulog: ULogUpload | None = Field(None, description="a PX4 ULog or ArduPilot DataFlash log instead of "
                                    "input/output/time; a log split "
                                    "by gaps is fitted as several records")
    verify: VerifyRecord | None = Field(None, description="a separate verification record for the time-domain "
                                        "check (nothing is then held out)")


class _Out(BaseModel):
    model_config = ConfigDict(extra="allow")


class ModelOut(_Out):
    num: list[float]
    den: list[float]
    delay: float
    poles: int
    zeros: int
    parameters: dict[str, float]


class FrequencyResponseOut(_Out):
    w: list[float]
    mag_db: list[Number]
    phase_deg: list[Number]
    coherence: list[float]


class UncertaintyOut(_Out):
    value: float
    cr_bound: Number
    cr_bound_pct: Number
    insensitivity: Number
    insensitivity_pct: Number


class IdentifyResponse(_Out):
    id: str
    created_at: _dt.datetime
    model: ModelOut
    cost: float = Field(description="CIFER's J over the band (<= 50 good, <= 100 acceptable)")
    quality: Literal["good", "acceptable", "poor", "closed-loop"] = Field(
        description="J's verdict (CIFER's guideline); closed-loop: flown under feedback and fitted without a "
                    "reference, never good or acceptable (the fit may be of the controller's inverse)")
    closed_loop: dict[str, Any] = Field(default_factory=dict, description="what tells the data were flown under "
                                        "feedback: detected, signs, estimate (direct or joint), message")
    check: Literal["good", "fair", "noise-limited", "poor", "none"] = Field(
        "none", description="the time-domain check's verdict, beside J's (see validation)")
    verdict: str
    warnings: list[str]
    band_rad_s: list[float]
    frequency_response: FrequencyResponseOut
    fit_points: dict[str, list[Number]]
    uncertainty: dict[str, UncertaintyOut]
    validation: dict[str, Any] | None
    rate_hz: float
    n_samples: int


class IdentificationRecordOut(IdentifyResponse):
    request: dict[str, Any] = Field(description="the options as validated (the samples: GET .../data)")


class IdentificationSummaryOut(_Out):
    id: str
    created_at: _dt.datetime
    poles: int
    zeros: int
    cost: Number
    quality: str
    n_samples: int


class IdentificationList(_Out):
    items: list[IdentificationSummaryOut]
    total: int
    limit: int
    offset: int


class IdentificationData(_Out):
    input: list[float]
    output: list[float]
    time: list[float] | None = None
    rate_hz: float | None = None
