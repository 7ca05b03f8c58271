"""Time-domain records: validation, sample rate, detrending, the fit/holdout split.

Every check raises :class:`~tuner.errors.InvalidDataError` with ``field`` set to the input it is
about (``"input"``, ``"output"``, ``"time"``, ``"rate_hz"``, ``"band"``, ``"holdout"``) and a
message that says what to change.

Record-length rules (Tischler & Remple, *Aircraft and Rotorcraft System Identification*, ch. 7):
spectra are averaged over windows of at most half the record, and a window resolves
frequencies down to two periods in it, so the lowest identifiable frequency of a record of
``T`` seconds is ``2 * 2*pi / (T/2) = 8*pi/T`` rad/s.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InvalidDataError
from ..tolerances import CONSTANT_SIGNAL_RTOL

__all__ = ["MAX_ABS", "MAX_SAMPLES", "MIN_ABS", "MIN_SAMPLES", "TIME_JITTER", "TIME_UNITS", "Record",
           "lowest_frequency_rad_s", "make_record"]

MIN_SAMPLES = 128
MAX_SAMPLES = 2_000_000  # a record's samples: a CSV's rows, a ULog's grid, the service's arrays (one limit); 83 min
# at 400 Hz; identification holds about 270 bytes a sample at its peak (bench/inputs.py), the service parses a JSON
# array of this many numbers within its workers' memory
TIME_JITTER = 0.01  # sample intervals may differ from the mean by this fraction
MAX_ABS = 1e60  # larger samples would overflow the spectra (the coherence has fourth powers of samples)
MIN_ABS = 1e-60  # a signal whose samples are all smaller would underflow them (a record of zeros is "constant")
#: the units a time column may be read in (seconds a unit); "auto": seconds, but a column whose steps look like another
#: unit is refused until the unit is said (see :func:`make_record`)
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}


def lowest_frequency_rad_s(duration_s: float) -> float:
    """Lowest frequency a record of ``duration_s`` resolves (two periods in half the record)."""
    return 8.0 * np.pi / duration_s


@dataclass(frozen=True, eq=False)
class Record:
    """A uniformly sampled input/output record (``u``, ``y`` as logged, ``dt`` in s, ``t0`` the first time)."""

    u: np.ndarray
    y: np.ndarray
    dt: float
    t0: float = 0.0

    @property
    def n(self) -> int:
        """The number of samples."""
        return int(self.u.size)

    @property
    def duration_s(self) -> float:
        """The record's length, s (``n * dt``)."""
        return self.n * self.dt

    @property
    def nyquist_rad_s(self) -> float:
        """The Nyquist frequency ``pi/dt``, rad/s."""
        return float(np.pi / self.dt)

    def detrended(self) -> Record:
        """Both signals minus their least-squares straight line (trim and slow drift removed)."""
        from scipy.signal import detrend

        return Record(u=detrend(self.u, type="linear"), y=detrend(self.y, type="linear"), dt=self.dt, t0=self.t0)

    def split(self, holdout: float) -> tuple[Record, Record | None]:
        """The first ``1 - holdout`` of the record (for the fit) and the rest (for the check)."""
        if holdout <= 0:
            return self, None
        k = round(self.n * (1.0 - holdout))
        fit = Record(u=self.u[:k], y=self.y[:k], dt=self.dt, t0=self.t0)
        rest = Record(u=self.u[k:], y=self.y[k:], dt=self.dt, t0=self.t0 + k * self.dt)
        return fit, rest


def _signal(values: Any, field: str) -> np.ndarray:
    try:
        a = np.asarray(values, dtype=float)
    except (TypeError, ValueError) as e:
        raise InvalidDataError(f"{field} must be a list of numbers", field=field) from e
    if a.ndim != 1:
        raise InvalidDataError(f"{field} must be a one-dimensional list of numbers, got shape {a.shape}", field=field)
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        i = int(bad[0])
        raise InvalidDataError(f"{field}[{i}] is {float(a[i])!r} ({bad.size} non-finite samples in all): remove or "
                               "interpolate them before identification", field=field)
    return a


def _rate_from_time(t: np.ndarray, n: int) -> tuple[float, float]:
    if t.size != n:
        raise InvalidDataError(f"time has {t.size} samples but input and output have {n}", field="time")
    d = np.diff(t)
    bad = np.flatnonzero(d <= 0)
    if bad.size:
        i = int(bad[0])
        raise InvalidDataError(f"time is not strictly increasing: time[{i + 1}] = {float(t[i + 1])!r} after "
                               f"time[{i}] = {float(t[i])!r}", field="time")
    dt = float((t[-1] - t[0]) / (n - 1))
    worst = int(np.argmax(np.abs(d - dt)))
    if abs(d[worst] - dt) > TIME_JITTER * dt:
        raise InvalidDataError(
            f"time is not uniformly sampled: the interval after time[{worst}] is {d[worst]:.6g} s, the mean "
            f"interval {dt:.6g} s (more than {TIME_JITTER:.0%} apart); resample the log to a uniform rate first",
            field="time")
    return dt, float(t[0])


def _unit_of(t: np.ndarray, step: float) -> None:
    """Refuse a time column (read in seconds) whose steps say it is in another unit: whole-number steps of 100 and
    more are a timestamp in microseconds (PX4's CSV exports: 4000 at 250 Hz, read as seconds the model's time
    constants come out a million times too slow); steps of 0.1 to 1 a kHz log in milliseconds (or a 1-10 Hz log in
    seconds: it cannot be told, so the unit must be said)."""
    if step >= 100.0 and bool(np.all(t == np.floor(t))):
        raise InvalidDataError(f"the time column steps by {step:.6g} in whole numbers: a timestamp in microseconds "
                               f"(as PX4 logs one: {1e6 / step:.4g} Hz)? say which unit it is: 'us' to read it so, "
                               f"or 's' if the samples are {step:.6g} s apart", field="time_unit")
    if 0.1 <= step < 1.0:
        raise InvalidDataError(f"the time column steps by {step:.6g}: milliseconds (a {1e3 / step:.4g} Hz log)? say "
                               f"which unit it is: 'ms' to read it so, or 's' if the samples are {step:.6g} s apart "
                               f"(a {1 / step:.4g} Hz log)", field="time_unit")


def make_record(input: Sequence[float], output: Sequence[float], *, time: Sequence[float] | None = None,
                rate_hz: float | None = None, time_unit: str = "auto") -> Record:
    """Validate a logged record: equal lengths, finite values, a varying input, a uniform time base.

    Give exactly one of ``time`` (strictly increasing, uniform within 1 %) or ``rate_hz``. ``time_unit`` is the
    time column's unit (:data:`TIME_UNITS`: ``"s"``, ``"ms"``, ``"us"``); ``"auto"`` reads seconds, and refuses a
    column whose steps say it is in another unit (whole numbers of 100 and more: microseconds; 0.1 to 1: a kHz log
    in milliseconds) until the unit is said.
    """
    if time_unit != "auto" and time_unit not in TIME_UNITS:
        raise InvalidDataError(f"time_unit must be 'auto', 's', 'ms' or 'us', got {time_unit!r}", field="time_unit")
    u = _signal(input, "input")
    y = _signal(output, "output")
    if u.size != y.size:
        raise InvalidDataError(f"input has {u.size} samples but output has {y.size}: give equal-length "
                               "records", field="output")
    if u.size < MIN_SAMPLES:
        raise InvalidDataError(f"{u.size} samples given; identification needs at least {MIN_SAMPLES}",
                               field="input")
    if u.size > MAX_SAMPLES:
        raise InvalidDataError(f"{u.size} samples given; at most {MAX_SAMPLES} (decimate the log)", field="input")
    if (time is None) == (rate_hz is None):
        raise InvalidDataError("give exactly one of time (a time column, s) or rate_hz (the sample rate)",
                               field="time" if time is not None else "rate_hz")
    if time is not None:
        t = _signal(time, "time")
        if time_unit == "auto":
            dt, t0 = _rate_from_time(t, u.size)
            _unit_of(t, dt)
        else:
            dt, t0 = _rate_from_time(t * TIME_UNITS[time_unit], u.size)
    else:
        try:
            r = float(rate_hz)  # type: ignore[arg-type]
        except (TypeError, ValueError) as e:
            raise InvalidDataError(f"rate_hz must be a number, got {rate_hz!r}", field="rate_hz") from e
        if not np.isfinite(r) or r <= 0:
            raise InvalidDataError(f"rate_hz must be finite and > 0, got {rate_hz!r}", field="rate_hz")
        dt, t0 = 1.0 / r, 0.0
    from ..plant import MAX_DT_S, MIN_DT_S

    if not MIN_DT_S <= dt <= MAX_DT_S:  # a model of such a record could never be tuned (nor stored to be)
        where = "time" if time is not None else "rate_hz"
        what = f"the time column's interval is {dt:.3g} s" if time is not None else f"rate_hz = {1 / dt:.3g} Hz"
        raise InvalidDataError(f"{what}: the sample interval must be {MIN_DT_S:g} to {MAX_DT_S:g} s (the tuner's range"
                               "); check the units (seconds, hertz)", field=where)
    for a, field in ((u, "input"), (y, "output")):
        big = float(np.max(np.abs(a)))
        if big > MAX_ABS:
            i = int(np.argmax(np.abs(a)))
            raise InvalidDataError(f"{field}[{i}] is {float(a[i]):.6g}: values beyond {MAX_ABS:g} in magnitude would "
                                   "overflow the spectra (their fourth powers); rescale the signal (other units)",
                                   field=field)
        if 0.0 < big < MIN_ABS:
            raise InvalidDataError(f"{field} is at most {big:.6g} in magnitude: values below {MIN_ABS:g} underflow the "
                                   "spectra (their fourth powers); rescale the signal (other units)", field=field)
        spread = float(np.ptp(a))
        if spread <= CONSTANT_SIGNAL_RTOL * big:  # relative: a signal's scale (its units) does not matter
            what = "nothing excites the plant" if field == "input" else "the output does not respond"
            raise InvalidDataError(f"{field} is constant ({a[0]:.6g}): {what}; a frequency sweep is needed",
                                   field=field)
    if np.array_equal(u, y):
        raise InvalidDataError("output is the same signal as input (the same column twice?): identification needs "
                               "the plant's input and its measured response", field="output")
    return Record(u=u, y=y, dt=dt, t0=t0)
