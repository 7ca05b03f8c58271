"""Reading PX4 flight logs (ULog, ``.ulg``) through pyulog: two topic fields onto one uniform grid.

A signal is named ``TOPIC.FIELD`` (``vehicle_angular_velocity.xyz[0]``), ``TOPIC:N.FIELD`` for
instance ``N`` of a multi-instance topic (default 0); nested fields keep pyulog's dotted names.
Each topic has its own ``timestamp`` (µs; for the output, its ``timestamp_sample`` when the topic has
one: the instant of the measurement, not of the publication): topics are asynchronous, so both signals are put onto
one uniform grid at ``rate_hz`` (default: the slower topic's median rate), over the time both
cover, starting on an input sample:

* the **input** (an actuator command or a torque/attitude setpoint) by **zero-order hold**: the
  value last published at or before each grid time. That is what the plant saw: the mixer and
  the ESCs hold a command until the next one arrives, so interpolating it would invent values
  that were never applied (and hide up to one publication interval of delay);
* the **output** (a measured rate or angle, a sample of a continuous signal) by **linear
  interpolation** between the two samples around each grid time (error of order
  ``dt^2 * y''/8``; no delay). Neither is low-pass filtered: choose ``rate_hz`` at or below the
  slower topic's rate, since faster content aliases as in any resampling by point evaluation.

**Gaps**: an interval between a topic's samples longer than :data:`GAP_FACTOR` times its median
interval (and than two grid steps), or a logged dropout (ULog ``O`` message), splits the record.
The grid stops before and restarts after every gap, in either signal; each piece long enough
(:data:`~tuner.identify.data.MIN_SAMPLES` grid samples) becomes one record, and the records are
fitted together (their spectra averaged, as CIFER combines sweeps); shorter pieces are dropped
and reported. A log with no piece long enough is refused, naming the gaps.

Every error is an :class:`~tuner.errors.InvalidDataError` whose ``field`` is the role
(``"input"``, ``"output"``, ``"file"``, ``"rate_hz"``); a wrong topic lists the topics in the
log, a wrong field the fields of the topic.
"""

from __future__ import annotations

import collections
import contextlib
import io
import math
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from ..errors import InvalidDataError, TunerError
from ..tolerances import SAMPLE_COUNT_TOL
from .data import MAX_SAMPLES, MIN_SAMPLES

__all__ = ["CORRUPT_SPAN_MESSAGES", "GAP_FACTOR", "MAX_READS_OVER", "MAX_ULOG_BYTES", "MIN_BYTES_PER_MESSAGE",
           "ULogRecords", "is_ulog", "parse_signal", "read_parameters", "read_ulog", "read_vehicle_log", "signals"]

GAP_FACTOR = 5.0
MAX_ULOG_BYTES = 2_000_000_000
MAGIC = b"ULog\x01\x12\x35"
_SIGNAL = re.compile(r"^(?P<topic>[A-Za-z0-9_]+)(?::(?P<inst>\d{1,3}))?\.(?P<field>[A-Za-z0-9_.\[\]]+)$")


@dataclass(frozen=True)
class ULogRecords:
    """The signals on the grid: one ``(input, output)`` pair per piece between gaps, and what was done."""

    inputs: list[np.ndarray]
    outputs: list[np.ndarray]
    rate_hz: float
    t_starts_s: list[float]  # the first grid time of each piece, s from the log's start
    gaps: list[tuple[float, float]] = field(default_factory=list)  # (from, to), s
    dropped: list[tuple[float, float]] = field(default_factory=list)  # pieces too short to use, s
    references: list[np.ndarray] | None = None  # the reference signal on the same grid (held), when asked for
    parameters: dict[str, float] = field(default_factory=dict)  # the parameters the log stores
    #: what the log says was flown (:func:`flown_edges`): the firmware, the armed and airborne time used, the
    #: modes, what was seen, notes, and ``reference_biased`` (why a rate setpoint given as the reference is not
    #: exogenous, or "")
    flight: dict[str, Any] = field(default_factory=dict)

    def describe(self) -> str:
        """One line: the records, their samples and rate, and where the log was split."""
        n = sum(u.size for u in self.inputs)
        s = f"{len(self.inputs)} record(s), {n} samples at {self.rate_hz:.4g} Hz"
        if self.gaps:
            s += f"; split at {len(self.gaps)} gap(s): " + ", ".join(f"{a:.3f}-{b:.3f} s" for a, b in self.gaps[:5])
        if self.dropped:
            s += f"; {len(self.dropped)} piece(s) too short dropped"
        return s


class LogHandle:
    """A log file opened once by :func:`open_log`: its reads, seeks and name; ``close`` does nothing (pyulog closes
    what it parses: the handle's owner, ``open_log``, closes the file). :func:`read_ulog` parses such a handle
    in place; any other file object (an upload) is read into bytes within the limit."""

    def __init__(self, f: BinaryIO, name: str) -> None:
        self._f, self.name = f, name

    def read(self, n: int = -1) -> bytes:
        """Up to ``n`` bytes (all that is left with -1)."""
        return self._f.read(n)

    def readinto(self, b: Any) -> int:
        """Bytes into the buffer ``b``; how many."""
        return self._f.readinto(b)

    def seek(self, pos: int, whence: int = 0) -> int:
        """Move to ``pos`` (from ``whence``); the new position."""
        return self._f.seek(pos, whence)

    def tell(self) -> int:
        """The position."""
        return self._f.tell()

    def close(self) -> None:
        """Nothing: ``open_log`` closes the file."""


@contextlib.contextmanager
def open_log(path: str | Path) -> Iterator[tuple[str, LogHandle]]:
    """``("ulog" | "dataflash" | "csv", handle)``: the log file opened once (a regular file within the larger of the
    two limits, :func:`tuner.fileio.open_input`), its kind told from its name (``.ulg``, ``.bin``) or its first
    bytes (the ULog magic, a DataFlash FMT message),
    the handle back at its start; a CSV beyond :data:`~tuner.fileio.MAX_CSV_BYTES` refused at once, from its size.
    The caller reads it from that handle (:func:`read_ulog`, :func:`tuner.identify.csvlog.read_columns`)."""
    import os

    from ..fileio import MAX_CSV_BYTES, open_checked

    p = Path(path)
    try:
        f = open_checked(p, limit=max(MAX_ULOG_BYTES, MAX_CSV_BYTES), field="file")
    except TunerError as e:
        raise InvalidDataError(str(e), field="file") from None
    try:  # (the caller's errors pass through this as they are)
        head = f.read(len(MAGIC))
        f.seek(0)
        h = LogHandle(f, str(p.resolve()))
        if p.suffix.lower() == ".ulg" or head == MAGIC:
            yield "ulog", h
            return
        if p.suffix.lower() == ".bin" or head[:3] == b"\xa3\x95\x80":  # an ArduPilot DataFlash log (its first FMT)
            yield "dataflash", h
            return
        size = os.fstat(f.fileno()).st_size
        if size > MAX_CSV_BYTES:
            raise InvalidDataError(f"{p}: {size} bytes, larger than {MAX_CSV_BYTES >> 20} MiB (the limit for a CSV "
                                   "log); give a shorter record", field="file")
        yield "csv", h
    finally:
        f.close()


def is_ulog(path: str | Path) -> bool:
    """Whether the file is named ``.ulg`` or starts with the ULog magic bytes. A path that is no regular file (a
    FIFO, a device, a directory) is refused, on the path and on the opened handle (it could hang or never end)."""
    from ..fileio import check_input, read_head

    p = Path(path)
    try:
        check_input(p, field="file")
        return p.suffix.lower() == ".ulg" or read_head(p, len(MAGIC), field="file") == MAGIC
    except TunerError as e:
        raise InvalidDataError(str(e), field="file") from None


def parse_signal(text: str, role: str) -> tuple[str, int, str]:
    """``"topic:1.xyz[0]"`` -> ``("topic", 1, "xyz[0]")``."""
    m = _SIGNAL.match(text.strip())
    if m is None:
        raise InvalidDataError(f"{role} {text!r}: name a ULog signal as TOPIC.FIELD, TOPIC:INSTANCE.FIELD, e.g. "
                               "vehicle_angular_velocity.xyz[0] or actuator_controls_0:1.control[1]", field=role)
    return m["topic"], int(m["inst"] or 0), m["field"]


#: a damaged log: over a span of this many messages (pyulog's reads of a 3-byte message header) pyulog's position
#: advanced by less than MIN_BYTES_PER_MESSAGE bytes a message. A real log's messages are 50-90 bytes on average
#: (pyulog's sample logs), a data message at least 13 (a header, a topic id and a timestamp); in a region that holds
#: no valid message pyulog steps one byte at a time and takes each byte for a header (about 1 s per 2 MB: a 100 MB
#: log of zeros held it for a minute). Such a region is refused within CORRUPT_SPAN_MESSAGES bytes (64 KiB, 0.05 s),
#: and pyulog's work is bounded by the log's size: at most one message per 12 bytes, and every byte read at most
#: MAX_READS_OVER times (a real log's once; where pyulog searches for a sync sequence after corrupt data, twice).
CORRUPT_SPAN_MESSAGES = 1 << 16
MIN_BYTES_PER_MESSAGE = 12
MAX_READS_OVER = 4
_BLOCK = CORRUPT_SPAN_MESSAGES >> 4  # the span is checked every _BLOCK messages, over the last 16 blocks


class _Damaged(Exception):
    """Raised from inside pyulog by :class:`_Bounded` (an exception of its own: pyulog takes ValueError, IndexError,
    KeyError, OverflowError and struct.error for corruption it steps over); ``start``: where the damage begins (the
    end of the last block of messages that advanced as a log's do), ``end``: where pyulog was."""

    def __init__(self, start: int, end: int) -> None:
        super().__init__(start, end)
        self.start, self.end = start, end


class _Bounded:
    """The reader pyulog parses: the file's reads and seeks, and two checks that bound pyulog's work by the log's
    size, whatever its bytes: over the last CORRUPT_SPAN_MESSAGES message headers it read, the position must have
    advanced MIN_BYTES_PER_MESSAGE bytes a header (no region of the log holds pyulog byte by byte), and the bytes it
    read stay within MAX_READS_OVER times the log's size (:class:`_Damaged` otherwise)."""

    __slots__ = ("_f", "_headers", "_check_at", "_marks", "_read", "_budget")

    def __init__(self, f: Any, size: int) -> None:
        self._f = f
        self._headers = 0
        self._check_at = _BLOCK
        self._marks = collections.deque([f.tell()], maxlen=17)  # the position every _BLOCK headers
        self._read = 0
        self._budget = MAX_READS_OVER * size + (1 << 20)

    def read(self, n: int = -1) -> bytes:
        """Up to ``n`` bytes (all that is left with -1); :class:`_Damaged` when a check fails."""
        if n == 3:  # a message header (uint16 size, uint8 type): the checks, every _BLOCK headers
            self._headers += 1
            if self._headers >= self._check_at:
                self._check_at += _BLOCK
                m = self._marks
                m.append(self._f.tell())
                if (len(m) == m.maxlen and m[-1] - m[0] < MIN_BYTES_PER_MESSAGE * CORRUPT_SPAN_MESSAGES) \
                        or self._read > self._budget:
                    raise _Damaged(self._damage_start(), m[-1])
        b = self._f.read(n)
        self._read += len(b)
        return b

    def _damage_start(self) -> int:
        m = list(self._marks)
        for i in range(len(m) - 2, -1, -1):  # the end of the newest block that advanced as a log's messages do
            if m[i + 1] - m[i] >= MIN_BYTES_PER_MESSAGE * _BLOCK:
                return m[i + 1]
        return m[0]

    def seek(self, pos: int, whence: int = 0) -> int:
        """Move to ``pos`` (from ``whence``); the new position."""
        return self._f.seek(pos, whence)

    def tell(self) -> int:
        """The position."""
        return self._f.tell()

    def close(self) -> None:
        """Nothing: the file is closed by whoever opened it."""


@contextlib.contextmanager
def _reader(src: str | Path | bytes | LogHandle) -> Iterator[tuple[_Bounded, str]]:
    """``(reader, name)``: the log as pyulog will parse it, from its start, bounded (:class:`_Bounded`)."""
    import os

    if isinstance(src, LogHandle):  # a log file opened once by the caller (open_log): parsed from it
        size = src.seek(0, os.SEEK_END)
        src.seek(0)
        yield _Bounded(src._f, size), src.name  # (its file: pyulog's reads through one Python layer, not two)
        return
    if isinstance(src, bytes):
        yield _Bounded(io.BytesIO(src), len(src)), "the upload"
        return
    from ..fileio import open_checked

    try:  # a regular file within the limit, checked on the opened file (nothing that could hang)
        f = open_checked(src, limit=MAX_ULOG_BYTES, field="file")
    except TunerError as e:
        raise InvalidDataError(str(e), field="file") from None
    with f:
        yield _Bounded(f, os.fstat(f.fileno()).st_size), str(src)


def _load(src: str | Path | bytes | LogHandle, topics: list[str] | None, *, header_only: bool = False) -> Any:
    """pyulog's ``ULog`` of the log (only ``topics``' data; with ``header_only`` its definitions section: formats,
    info and parameters), read through :class:`_Bounded`: a damaged region is refused as such, at once."""
    from pyulog import ULog

    with _reader(src) as (reader, name):
        try:
            with contextlib.redirect_stdout(io.StringIO()):  # pyulog prints its corruption notices
                return ULog(reader, message_name_filter_list=topics, parse_header_only=header_only)
        except _Damaged as e:
            where = ("after its header (the rest is not a log's data)" if e.start <= 16 else
                     f"from about byte {e.start} (the log was written over there; a copy of its first {e.start} bytes "
                     "is readable, if they hold the flight)")
            raise InvalidDataError(f"{name}: a damaged ULog file: no readable message in bytes {e.start}-{e.end}, "
                                   f"{where}; it is not read further", field="file") from None
        except Exception as e:  # pyulog raises its own and struct/value errors for a file it cannot parse
            raise InvalidDataError(f"{name}: not a readable ULog file ({type(e).__name__}: {e})",
                                   field="file") from None


def read_parameters(src: str | Path | bytes | LogHandle, *, field: str = "file") -> dict[str, float]:
    """The parameters a ULog stores (its definitions section only: the data are not read), finite numbers by name;
    a damaged log refused as :func:`read_ulog` refuses it (``field``: the caller's name for the file)."""
    try:
        ul = _load(src, [], header_only=True)
    except InvalidDataError as e:
        raise InvalidDataError(str(e), field=field) from None
    return {str(k): float(v) for k, v in dict(getattr(ul, "initial_parameters", {}) or {}).items()
            if isinstance(v, (int, float)) and math.isfinite(float(v))}


def read_vehicle_log(src: str | Path | bytes | LogHandle, *, field: str = "file") -> dict[str, Any]:
    """What a ULog says of the vehicle's rate loop (issue 40): ``parameters`` (the definitions section's),
    ``changes`` (pyulog's ``changed_parameters``: ``(t_s, NAME, value)`` set in flight, in order), ``gyro_rate_hz``
    (the median of ``vehicle_imu_status.gyro_rate_hz`` of the first instance logged with a positive rate, or None;
    PX4's rate loop runs on every ``vehicle_angular_velocity``, which the gyro's rate drives, at most
    ``IMU_GYRO_RATEMAX``), ``gyro_instances`` (each instance's median) and ``logged_gyro_hz`` (the rate of
    ``sensor_combined`` as logged, from the median interval of its timestamps, or None: older logs' only trace of
    the gyro's rate, a lower bound where the logger thinned the topic), ``gyro_raw_rate_hz`` (that instance's
    ``vehicle_imu_status.gyro_raw_rate_hz``, the raw FIFO sample rate, where logged, else None) and
    ``ver_sw_release`` (the ULog info ``ver_sw_release``, ``0xMMmmppTT``: major, minor, patch, type; None if
    absent or 0). Only those topics' data are parsed, through the bounded reader."""
    try:
        ul = _load(src, ["vehicle_imu_status", "sensor_combined"])
    except InvalidDataError as e:
        raise InvalidDataError(str(e), field=field) from None
    params = {str(k): float(v) for k, v in dict(getattr(ul, "initial_parameters", {}) or {}).items()
              if isinstance(v, (int, float)) and math.isfinite(float(v))}
    changes = [(float(t) * 1e-6, str(n), float(v)) for t, n, v in getattr(ul, "changed_parameters", ()) or ()
               if isinstance(v, (int, float)) and math.isfinite(float(v))]
    rates, raw_rates, logged = {}, {}, None
    for d in sorted(ul.data_list, key=lambda d: d.multi_id):
        if d.name == "sensor_combined":
            dts = np.diff(np.asarray(d.data.get("timestamp", ()), dtype=float)) * 1e-6
            dts = dts[dts > 0]
            logged = logged or (1.0 / float(np.median(dts)) if dts.size >= 10 else None)
            continue
        r = np.asarray(d.data.get("gyro_rate_hz", ()), dtype=float)
        r = r[np.isfinite(r) & (r > 0)]
        if r.size:
            rates[int(d.multi_id)] = float(np.median(r))
        r = np.asarray(d.data.get("gyro_raw_rate_hz", ()), dtype=float)  # the raw (FIFO) rate, newer logs
        r = r[np.isfinite(r) & (r > 0)]
        if r.size:
            raw_rates[int(d.multi_id)] = float(np.median(r))
    first = next(iter(rates), None)
    info = dict(getattr(ul, "msg_info_dict", {}) or {})
    release = info.get("ver_sw_release")
    return {"parameters": params, "changes": changes, "gyro_rate_hz": next(iter(rates.values()), None),
            "gyro_instances": rates, "logged_gyro_hz": logged,
            "gyro_raw_rate_hz": raw_rates.get(first) if first is not None else None,
            "ver_sw_release": int(release) if isinstance(release, (int, float)) and release > 0 else None}


def _topics_in(src: str | Path | bytes | LogHandle) -> list[str]:
    """Every ``topic:instance`` logged, for the error message (a log read from a handle: parsed again from it, on
    this error's path only: the first parse kept only the topics asked for)."""
    ul = _load(src, None)
    return sorted({f"{d.name}:{d.multi_id}" if d.multi_id else d.name for d in ul.data_list})


def _series(ul: Any, src: Any, role: str, spec: str) -> tuple[np.ndarray, np.ndarray]:
    topic, inst, fld = parse_signal(spec, role)
    found = [d for d in ul.data_list if d.name == topic]
    data = next((d for d in found if d.multi_id == inst), None)
    if data is None:
        if found:
            insts = sorted(d.multi_id for d in found)
            raise InvalidDataError(f"{role} {spec!r}: topic {topic!r} has instances {insts}, not {inst}",
                                   field=role)
        if not ul.data_list or getattr(ul, "file_corruption", False):  # not the name's fault: say what the log is
            what = "holds no data" if not ul.data_list else "is damaged (pyulog skipped corrupt data)"
            raise InvalidDataError(f"{role} {spec!r}: no topic {topic!r} in the log, which {what}; topics: "
                                   f"{_topics_in(src)}", field=role if ul.data_list else "file")
        raise InvalidDataError(f"{role} {spec!r}: no topic {topic!r} in the log; topics: {_topics_in(src)}",
                               field=role)
    if fld not in data.data or fld in ("timestamp", "timestamp_sample"):
        fields = [k for k in data.data if k not in ("timestamp", "timestamp_sample") and not k.startswith("_padding")]
        raise InvalidDataError(f"{role} {spec!r}: topic {topic!r} has no field {fld!r}; fields: {fields}",
                               field=role)
    # the output at the instant it was measured (PX4's timestamp_sample, when the topic has it); the input at
    # its publication, when it was applied
    clock = "timestamp_sample" if role == "output" and "timestamp_sample" in data.data else "timestamp"
    t = np.asarray(data.data[clock], dtype=np.float64) * 1e-6
    x = np.asarray(data.data[fld], dtype=np.float64)
    return timed_samples(t, x, role, spec)


def timed_samples(t: np.ndarray, x: np.ndarray, role: str, spec: str) -> tuple[np.ndarray, np.ndarray]:
    """A logged signal's samples in time order (a log's or a DataFlash log's): a zero timestamp is no sample
    (pyulog's convention), a repeated timestamp keeps its last value, a non-finite value is refused naming the
    signal (``role``: its field)."""
    keep = t > 0
    t, x = t[keep], x[keep]
    if t.size < 2:
        raise InvalidDataError(f"{role} {spec!r}: {t.size} samples in the log", field=role)
    order = np.argsort(t, kind="stable")
    t, x = t[order], x[order]
    last = np.r_[t[1:] != t[:-1], True]  # a repeated timestamp: its last value
    t, x = t[last], x[last]
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        raise InvalidDataError(f"{role} {spec!r}: {bad.size} non-finite samples (first at {t[bad[0]]:.6f} s); "
                               "remove or interpolate them", field=role)
    return t, x


def _gaps(t: np.ndarray, grid_dt: float) -> list[tuple[float, float]]:
    d = np.diff(t)
    lim = max(GAP_FACTOR * float(np.median(d)), 2.0 * grid_dt)
    return [(float(t[i]), float(t[i + 1])) for i in np.flatnonzero(d > lim)]


def _merge(gaps: list[tuple[float, float]]) -> list[tuple[float, float]]:
    out: list[list[float]] = []
    for a, b in sorted(gaps):
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return [(a, b) for a, b in out]


def read_ulog(src: str | Path | bytes | BinaryIO, columns: Mapping[str, str], *,
              rate_hz: float | None = None) -> ULogRecords:
    """The ``columns`` (``{"input": "topic.field", "output": "topic.field"}``) of a ULog log on a uniform grid.

    ``src`` is a path, the file's bytes, or a binary file object (an upload). See the module's notes on the
    interpolation (input held, output linear) and on gaps.
    """
    roles = ("input", "output", "reference") if "reference" in columns else ("input", "output")
    if set(columns) != set(roles):
        raise InvalidDataError("a ULog log needs input and output signals (TOPIC.FIELD), and optionally a reference",
                               field="input")
    specs = {role: parse_signal(columns[role], role) for role in roles}
    if not isinstance(src, (str, Path, bytes, LogHandle)):  # an upload's file object: its bytes
        src = src.read(MAX_ULOG_BYTES + 1)
        if len(src) > MAX_ULOG_BYTES:
            raise InvalidDataError(f"the upload holds more than {MAX_ULOG_BYTES} bytes (cut the log)", field="file")
    from .flight import PX4_STATE_TOPICS

    ul = _load(src, sorted({s[0] for s in specs.values()} | set(PX4_STATE_TOPICS)))
    (tu, xu), (ty, xy) = (_series(ul, src, role, columns[role]) for role in ("input", "output"))
    tr, xr = _series(ul, src, "reference", columns["reference"]) if "reference" in columns else (None, None)
    t0 = float(ul.start_timestamp) * 1e-6  # times are reported from the logger's start
    drops = [(float(d.timestamp) * 1e-6, float(d.duration) * 1e-3)  # the logger's own dropout notices
             for d in getattr(ul, "dropouts", []) or []]
    from .flight import px4_flight

    params = {str(k): float(v) for k, v in dict(getattr(ul, "initial_parameters", {}) or {}).items()
              if isinstance(v, (int, float)) and math.isfinite(float(v))}
    return on_grid((tu, xu), (ty, xy), (tr, xr), columns, rate_hz=rate_hz, t0=t0, dropouts=drops,
                   flight=lambda t_end: px4_flight(ul, t_end), name=src_name(src), parameters=params)


def on_grid(u: tuple[np.ndarray, np.ndarray], y: tuple[np.ndarray, np.ndarray], r: tuple[Any, Any],
            columns: Mapping[str, str], *, rate_hz: Any, t0: float, dropouts: list[tuple[float, float]],
            flight: Any, name: str, parameters: dict[str, float]) -> ULogRecords:
    """A log's signals (times in s on the log's clock, values) on one uniform grid, split at gaps and dropouts
    (``(start s, duration s)``), cut to the armed, airborne stretches ``flight(t_end)`` says were flown: the part
    every log reader (ULog, DataFlash) shares."""
    (tu, xu), (ty, xy), (tr, xr) = u, y, r
    held = {"input": tu, **({"reference": tr} if tr is not None else {})}
    rate_hz = grid_rate(rate_hz, held, ty, columns)
    dt = 1.0 / rate_hz
    gaps = _gaps(tu, dt) + _gaps(ty, dt)
    for a, d in dropouts:
        gaps.append((a, a + d))
    gaps = _merge(gaps)
    lo, hi = max(tu[0], ty[0]), min(tu[-1], ty[-1])
    if tr is not None:
        lo, hi = max(lo, tr[0]), min(hi, tr[-1])
    if not hi - lo > dt:
        raise InvalidDataError(f"input ({tu[0] - t0:.3f}-{tu[-1] - t0:.3f} s) and output ({ty[0] - t0:.3f}-"
                               f"{ty[-1] - t0:.3f} s) do not overlap in time", field="output")
    for tt, role in ((tu, "input"), (ty, "output")):  # a clock that jumps: corrupt timestamps, not a long log
        covered = float(np.median(np.diff(tt))) * tt.size
        if tt[-1] - tt[0] > 100.0 * covered:
            j = int(np.argmax(np.diff(tt)))
            raise InvalidDataError(f"{role} {columns[role]!r}: corrupt timestamps: its {tt.size} samples at their "
                                   f"median interval cover {covered:.3g} s but they span {tt[-1] - tt[0]:.3g} s "
                                   f"(a jump of {tt[j + 1] - tt[j]:.3g} s after sample {j}); repair or cut the log",
                                   field=role)
    if (hi - lo) * rate_hz > MAX_SAMPLES:
        raise InvalidDataError(f"{(hi - lo) * rate_hz:.0f} grid samples at {rate_hz:g} Hz; at most {MAX_SAMPLES}: "
                               "resample at a lower rate, or cut the log", field="rate_hz")
    # the pieces between gaps: [lo, a1], [b1, a2], ... within [lo, hi]
    edges, start = [], lo
    for a, b in gaps:
        if b <= lo or a >= hi:
            continue
        edges.append((start, min(a, hi)))
        start = max(b, lo)
    edges.append((start, hi))
    if tr is not None:  # the reference held like the input (a setpoint is a command)
        gaps = _merge(gaps + _gaps(tr, dt))
    edges, summary = flown_edges(edges, flight(max(tu[-1], ty[-1])), t0, name, columns, lo, hi)
    inputs, outputs, refs, starts, dropped = [], [], [], [], []
    for a0, b in edges:
        i0 = int(np.searchsorted(tu, a0 - 1e-9))  # the grid starts on an input sample: held values are exact
        a = float(tu[i0]) if i0 < tu.size else b + 1.0
        n = int(math.floor((b - a) / dt + SAMPLE_COUNT_TOL)) + 1 if a <= b else 0
        if n < MIN_SAMPLES:
            if b > a0:
                dropped.append((a0 - t0, b - t0))
            continue
        tg = a + dt * np.arange(n)
        iu = np.searchsorted(tu, tg + 1e-9, side="right") - 1  # zero-order hold: last published at or before
        inputs.append(xu[np.clip(iu, 0, xu.size - 1)])
        outputs.append(np.interp(tg, ty, xy))
        if tr is not None:
            ir = np.searchsorted(tr, tg + 1e-9, side="right") - 1
            refs.append(xr[np.clip(ir, 0, xr.size - 1)])
        starts.append(a - t0)
    rel = [(a - t0, b - t0) for a, b in gaps if lo < b and a < hi]
    if not inputs:
        where = ", ".join(f"{a:.3f}-{b:.3f} s" for a, b in rel[:8]) or "none"
        raise InvalidDataError(
            f"no stretch of the log between gaps holds {MIN_SAMPLES} samples at {rate_hz:g} Hz (gaps: {where}; "
            f"common span {lo - t0:.3f}-{hi - t0:.3f} s); log longer sweeps without dropouts", field="input")
    params = parameters
    summary["used_s"] = sum(u.size for u in inputs) / rate_hz
    return ULogRecords(inputs=inputs, outputs=outputs, rate_hz=rate_hz, t_starts_s=starts, gaps=rel, dropped=dropped,
                       references=refs if tr is not None else None, parameters=params, flight=summary)


def src_name(src: Any) -> str:
    """The log's name for a message: its path, or "the upload"."""
    return src.name if isinstance(src, LogHandle) else ("the upload" if isinstance(src, bytes) else str(src))


#: a grid may be this much faster than a held signal's median logging rate (a jittery 250 Hz topic at 250 Hz)
GRID_OVER_LOGGED = 1.05


def grid_rate(rate_hz: Any, held: Mapping[str, np.ndarray], ty: np.ndarray, columns: Mapping[str, str]) -> float:
    """The identification grid's rate: the one given (checked: a number, and no faster than every held signal, the
    input and the reference, is logged), or by default the slowest signal's median rate."""
    rates = {role: float(1.0 / np.median(np.diff(t))) for role, t in held.items()}
    if rate_hz is None:
        rate_hz = float(min([*rates.values(), 1.0 / np.median(np.diff(ty))]))
        return float(f"{rate_hz:.3g}")  # 249.8 Hz of a jittery 250 Hz topic -> 250
    try:
        rate_hz = float(rate_hz)
    except (TypeError, ValueError):
        raise InvalidDataError(f"rate_hz must be a number, got {rate_hz!r}", field="rate_hz") from None
    if not (math.isfinite(rate_hz) and 0 < rate_hz <= 1e5):
        raise InvalidDataError(f"rate_hz must be in (0, 1e5] Hz, got {rate_hz!r}", field="rate_hz")
    for role, r in rates.items():
        if rate_hz > GRID_OVER_LOGGED * r:
            topic = columns[role].split(".", 1)[0]
            raise InvalidDataError(
                f"the grid's rate {rate_hz:g} Hz is faster than the {role} {columns[role]} is logged: {topic} at "
                f"{r:.3g} Hz (median interval). Held onto the faster grid, each logged value would repeat about "
                f"{rate_hz / r:.1f} times and nothing above {r / 2:.3g} Hz would be the {role}'s; give a rate of at "
                f"most {r:.3g} Hz, or log {topic} faster (PX4: SDLOG_PROFILE bit 3, system identification; "
                "ArduPilot: LOG_BITMASK attitude fast)", field="rate_hz")
    return rate_hz


def flown_edges(edges: list[tuple[float, float]], flight: Any, t0: float, name: str, columns: Mapping[str, str],
                lo: float, hi: float) -> tuple[list[tuple[float, float]], dict[str, Any]]:
    """The pieces between gaps cut to the armed, airborne stretches the log records
    (:class:`tuner.identify.flight.Flight`), a log with none refused saying what was seen; and the summary
    :class:`ULogRecords` keeps (``flight``)."""
    from .flight import intersect, setpoint_reference, total

    summary: dict[str, Any] = {"firmware": flight.firmware, "seen": flight.seen, "modes": list(flight.modes),
                               "notes": list(flight.notes), "reference_biased": ""}
    if flight.flown is not None:
        cut = intersect(edges, flight.flown)
        if not cut:
            when = ("never armed and airborne" if not flight.flown else
                    "armed and airborne only at " + ", ".join(f"{a - t0:.1f}-{b - t0:.1f} s" for a, b in
                                                             flight.flown[:4]) +
                    f", outside the signals' common span {lo - t0:.1f}-{hi - t0:.1f} s")
            raise InvalidDataError(f"{name}: the log shows no flight to identify from: the vehicle was {when} "
                                   f"({flight.seen or 'no state recorded'}); identify from a log of a flight",
                                   field="file")
        off = total(edges) - total(cut)
        if off > 0:
            summary["notes"].append(f"{off:.3g} s of the log on the ground or disarmed left out (identified "
                                    f"from the {total(cut):.3g} s armed and airborne)")
        edges = cut
    ref = columns.get("reference")
    if ref is not None and setpoint_reference(ref):
        exo = total(intersect(edges, flight.exogenous)) if flight.exogenous else 0.0
        share = exo / max(total(edges), 1e-12)
        if share < 0.999:
            modes = ", ".join(flight.modes) or "a mode the log does not record"
            summary["reference_biased"] = (
                f"the reference {ref} is a rate setpoint, exogenous only in a rate (acro) mode or with an injected "
                f"excitation, and {100 * (1 - share):.0f} % of the identified stretches were flown otherwise "
                f"(modes: {modes}): there it is the attitude loop's output, which feeds back the measured "
                "attitude, so the joint estimate is biased by the outer loop")
        elif flight.exogenous_why:
            summary["notes"].append(f"the reference {ref} is exogenous: flown in {flight.exogenous_why}")
    return edges, summary


#: a name a parameter file may hold (PX4's and ArduPilot's: upper case, digits and '_', at most 16 characters): a
#: log's other names (a tab or a newline in one added lines to the .params text) are not passed on
_PARAM_NAME = re.compile(r"[A-Z][A-Z0-9_]{0,15}")
#: the parameters of the rate laws a page passes on (the vehicle of a tune), by prefix
_LAW_PARAMS = ("MC_ROLLRATE_", "MC_PITCHRATE_", "MC_YAWRATE_", "MC_RR_", "MC_PR_", "MC_YR_", "MC_ROLL_P",
               "MC_PITCH_P", "MC_YAW_P", "IMU_GYRO_", "IMU_DGYRO_", "ATC_RAT_", "ATC_ANG_", "SCHED_LOOP_RATE",
               "INS_GYRO_FILTER")


def signals(src: str | Path | bytes) -> dict[str, Any]:
    """What a log offers: every numeric ``TOPIC[:N].FIELD`` with its median rate (Hz), the rate law's parameters it
    stores as a QGroundControl ``.params`` text (``params_text``, empty without), and the loop rate they name.

    Examples
    --------
    >>> import io, struct
    >>> from tuner.identify.ulog import signals
    >>> signals(b"ULog")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    tuner.errors.InvalidDataError: the upload: not a readable ULog file ...
    """
    ul = _load(src, None)
    out = []
    for d in sorted(ul.data_list, key=lambda d: (d.name, d.multi_id)):
        t = np.asarray(d.data.get("timestamp", []), dtype=np.float64)
        t = t[t > 0]
        rate = float(1e6 / np.median(np.diff(t))) if t.size > 2 and np.median(np.diff(t)) > 0 else None
        name = f"{d.name}:{d.multi_id}" if d.multi_id else d.name
        for k, v in d.data.items():
            if k in ("timestamp", "timestamp_sample") or k.startswith("_padding"):
                continue
            if np.asarray(v).dtype.kind in "fiu":
                out.append({"name": f"{name}.{k}", "rate_hz": rate})
    params = {str(k): v for k, v in dict(getattr(ul, "initial_parameters", {}) or {}).items()
              if _PARAM_NAME.fullmatch(str(k)) and str(k).startswith(_LAW_PARAMS) and isinstance(v, (int, float))
              and not isinstance(v, bool) and math.isfinite(float(v))}
    lines = [f"1\t1\t{k}\t{v!r}\t{6 if isinstance(v, int) else 9}" for k, v in sorted(params.items())]
    loop_from = next((k for k in ("IMU_GYRO_RATEMAX", "SCHED_LOOP_RATE") if params.get(k)), None)
    loop = params.get(loop_from) if loop_from else None
    return {"signals": out, "params_text": "\n".join(lines) + ("\n" if lines else ""), "loop_hz": loop,
            "loop_from": loop_from,
            "firmware": "px4" if any(k.startswith("MC_") for k in params) else
            ("ardupilot" if any(k.startswith("ATC_") for k in params) else None)}
