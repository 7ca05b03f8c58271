"""Reading ArduPilot DataFlash logs (``.bin``) through pymavlink's ``DFReader``: two message fields onto one grid.

A signal is named ``MESSAGE.FIELD`` (``RATE.R``, ``RATE.ROut``, ``RATE.RDes``, ``PIDR.Tar``, ``SIDD.Targ``), or
``MESSAGE:N.FIELD`` for instance ``N`` of a message with an instance field (``IMU:1.GyrX``). Every message carries
its ``TimeUS`` (µs since boot); the grid, the hold of the input, the interpolation of the output, the gaps and the
flight's stretches are those of a ULog (:func:`tuner.identify.ulog.on_grid`). What was flown is read from ``ARM``
(``ArmState``), the events ``EV`` (10 ARMED, 11 DISARMED, 18 LAND_COMPLETE, 28 NOT_LANDED) and ``MODE``
(``ModeNum``: ArduCopter's 1 ACRO and 25 SYSTEMID make a rate setpoint exogenous), as ArduPilot writes them
(``libraries/AP_Logger/LogStructure.h``, ``ArduCopter/mode.h``, ArduPilot master as of 2024).

Bounded like the ULog reader (issue 42): pymavlink's index pass (``DFReader_binary.init_arrays``) steps one byte at
a time over bytes that hold no message, writing a line for each; a run of :data:`CORRUPT_SPAN_BYTES` such bytes, or
more than :data:`MAX_BAD_SHARE` of the file, stops it at once and the log is refused as damaged, naming the bytes;
so does a FMT whose Length is not its format's size (pymavlink would step by it, by 0 for ever), and a message type
no FMT describes (where pymavlink stops reading) more than :data:`TAIL_BYTES` before the end (nearer, it is noted).
Fields are taken from the file with numpy at the offsets pymavlink indexed (one array per field, not one Python
object per message): memory stays within a few times the file's size.
"""

from __future__ import annotations

import contextlib
import io
import math
import re
import struct
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InvalidDataError, TunerError

__all__ = ["CORRUPT_SPAN_BYTES", "HEAD", "MAX_BAD_SHARE", "MAX_DATAFLASH_BYTES", "ardupilot_flight", "is_dataflash",
           "read_dataflash", "read_dataflash_parameters", "signals"]

#: a DataFlash log starts with its first FMT message: the two header bytes and FMT's type, 128
HEAD = b"\xa3\x95\x80"
MAX_DATAFLASH_BYTES = 2_000_000_000
CORRUPT_SPAN_BYTES = 1 << 16
MAX_BAD_SHARE = 0.25
_BAD = re.compile(r"bad header (?:0x[0-9a-f]+ ?)+at (\d+)")
#: pymavlink's line for a message type no FMT described, where its index pass stops reading the log
_UNKNOWN = re.compile(r"unknown msg type 0x[0-9a-f]+ \((\d+)\) at (\d+)")
#: an unknown message type this close to the end is the end of the log (pymavlink's own allowance for a block
#: log's last page, LogStructure's 256-byte pages less their header, is 528 bytes)
TAIL_BYTES = 528
#: DataFlash format characters -> numpy dtypes and multipliers (pymavlink DFReader.FORMAT_TO_STRUCT)
_NP = {"b": ("<i1", None), "B": ("<u1", None), "h": ("<i2", None), "H": ("<u2", None), "i": ("<i4", None),
       "I": ("<u4", None), "f": ("<f4", None), "d": ("<f8", None), "g": ("<f2", None), "c": ("<i2", 0.01),
       "C": ("<u2", 0.01), "e": ("<i4", 0.01), "E": ("<u4", 0.01), "L": ("<i4", 1e-7), "M": ("<i1", None),
       "q": ("<i8", None), "Q": ("<u8", None), "n": ("S4", None), "N": ("S16", None), "Z": ("S64", None),
       "a": ("S64", None)}


def is_dataflash(head: bytes) -> bool:
    """Whether a file's first bytes are a DataFlash log's (its first FMT message).

    Examples
    --------
    >>> is_dataflash(b"\\xa3\\x95\\x80\\x80Y"), is_dataflash(b"ULog")
    (True, False)
    """
    return head[:3] == HEAD


class _Damaged(Exception):
    def __init__(self, start: int, end: int) -> None:
        super().__init__(start, end)
        self.start, self.end = start, end


class _Cut(Exception):
    """pymavlink met a message type no FMT described at ``at`` and stopped indexing there."""

    def __init__(self, mtype: int, at: int) -> None:
        super().__init__(mtype, at)
        self.mtype, self.at = mtype, at


class _BadFormat(Exception):
    """A FMT message whose Length is not the size of its format."""


class _Watch(io.TextIOBase):
    """pymavlink's stderr while it indexes: counts the bytes it steps over (its "bad header ... at N" lines) and
    stops it (:class:`_Damaged`) on a run of CORRUPT_SPAN_BYTES of them, or beyond MAX_BAD_SHARE of the file; a
    message type no FMT described (its "unknown msg type ... at N" line, where it stops reading) more than
    :data:`TAIL_BYTES` before the end stops it too (:class:`_Cut`); nearer the end, the bytes not read are noted
    (:func:`_unread`)."""

    def __init__(self, size: int) -> None:
        self.size, self.bad, self.run_start, self.last = size, 0, -2, -2

    def write(self, text: str) -> int:
        for m in _UNKNOWN.finditer(text):
            mtype, at = int(m.group(1)), int(m.group(2))
            if self.size - at > TAIL_BYTES:
                raise _Cut(mtype, at)
        for m in _BAD.finditer(text):
            at = int(m.group(1))
            self.bad += 1
            if at != self.last + 1:
                self.run_start = at
            self.last = at
            if at - self.run_start >= CORRUPT_SPAN_BYTES or self.bad > MAX_BAD_SHARE * self.size + CORRUPT_SPAN_BYTES:
                raise _Damaged(self.run_start, at)
        return len(text)


@contextlib.contextmanager
def _path_of(src: str | Path | bytes) -> Iterator[tuple[str, str]]:
    """``(path, name)``: pymavlink reads a path (it maps the file); an upload's bytes go to a temporary file."""
    if isinstance(src, bytes):
        if len(src) > MAX_DATAFLASH_BYTES:
            raise InvalidDataError(f"the upload holds more than {MAX_DATAFLASH_BYTES} bytes (cut the log)",
                                   field="file")
        with tempfile.NamedTemporaryFile(suffix=".bin") as f:
            f.write(src)
            f.flush()
            yield f.name, "the upload"
        return
    from ..fileio import check_input

    try:
        check_input(Path(src), field="file")
    except TunerError as e:
        raise InvalidDataError(str(e), field="file") from None
    size = Path(src).stat().st_size
    if size > MAX_DATAFLASH_BYTES:
        raise InvalidDataError(f"{src}: {size} bytes, larger than {MAX_DATAFLASH_BYTES} (cut the log)", field="file")
    yield str(src), str(src)


class _Formats(dict):  # type: ignore[type-arg]
    """pymavlink's formats by message type, each FMT checked as pymavlink's index pass adds it: its Length must be the
    3 header bytes and its fields' size, or pymavlink steps by a wrong length (by 0 for ever) and the fields would be
    read from the next message's bytes."""

    def __setitem__(self, mtype: int, fmt: Any) -> None:
        try:
            size = 3 + struct.calcsize(fmt.msg_struct)
        except struct.error as e:
            raise _BadFormat(f"the FMT of message type {mtype} ({fmt.name!r}) has format {fmt.format!r}: {e}") from None
        if fmt.len != size:
            raise _BadFormat(f"the FMT of message type {mtype} ({fmt.name!r}) declares a Length of {fmt.len} bytes, "
                             f"but its format {fmt.format!r} takes {size} (3 header bytes and its fields)")
        super().__setitem__(mtype, fmt)


def _indexed_class() -> Any:
    from pymavlink.DFReader import DFReader_binary

    class Indexed(DFReader_binary):  # type: ignore[misc]
        """pymavlink's reader, indexed only: its clock (``init_clock``) is not worked out, since the fields are read
        with their own TimeUS; on a log without GPS time it parses every message in Python (20 s for 43 MB). Every
        FMT is checked before pymavlink uses it (:class:`_Formats`)."""

        def init_arrays(self, progress_callback: Any = None) -> None:
            self.formats = _Formats(self.formats)
            super().init_arrays(progress_callback=progress_callback)

        def init_arrays_fast(self, progress_callback: Any = None) -> None:  # never asked for (_python_indexer)
            self.init_arrays(progress_callback=progress_callback)

        def init_clock(self) -> None:
            self.clock = None

    return Indexed


def _indexed(path: str, **kw: Any) -> Any:
    return _indexed_class()(path, **kw)


@contextlib.contextmanager
def _python_indexer() -> Iterator[None]:
    """pymavlink's Python index pass (``init_arrays``), not its compiled one (which writes a line for every byte it
    steps over from C, where :class:`_Watch` cannot stop it); 0.8 s for a 43 MB log."""
    import os

    old = os.environ.get("PYMAVLINK_FAST_INDEX")
    os.environ["PYMAVLINK_FAST_INDEX"] = "0"
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("PYMAVLINK_FAST_INDEX", None)
        else:
            os.environ["PYMAVLINK_FAST_INDEX"] = old


@contextlib.contextmanager
def _open(src: str | Path | bytes) -> Iterator[tuple[Any, str]]:
    """pymavlink's ``DFReader_binary`` of the log, indexed, bounded; closed after use."""
    with _path_of(src) as (path, name):
        size = Path(path).stat().st_size
        if size < 3:
            raise InvalidDataError(f"{name}: {size} bytes: not a DataFlash log", field="file")
        with open(path, "rb") as f:
            if not is_dataflash(f.read(3)):
                raise InvalidDataError(f"{name}: not a DataFlash log (it does not start with a FMT message)",
                                       field="file")
        watch = _Watch(size)
        try:
            with contextlib.redirect_stderr(watch), contextlib.redirect_stdout(io.StringIO()), _python_indexer():
                r = _indexed(path, zero_time_base=False)
        except _Damaged as e:
            raise InvalidDataError(f"{name}: a damaged DataFlash log: no readable message in bytes {e.start}-{e.end} "
                                   f"({watch.bad} bytes stepped over); it is not read further", field="file") from None
        except _Cut as e:
            raise InvalidDataError(f"{name}: a damaged DataFlash log: at byte {e.at} of {size}, a message of type "
                                   f"{e.mtype}, which no FMT describes (a damaged byte?); the {size - e.at} bytes from "
                                   "there would not be read", field="file") from None
        except _BadFormat as e:
            raise InvalidDataError(f"{name}: a damaged DataFlash log: {e}", field="file") from None
        except Exception as e:  # pymavlink's own errors for a file it cannot parse
            raise InvalidDataError(f"{name}: not a readable DataFlash log ({type(e).__name__}: {e})",
                                   field="file") from None
        r.tuner_notes = _unread(r, size)
        try:
            yield r, name
        finally:
            with contextlib.suppress(Exception):
                r.data_map.close()
                r.filehandle.close()


def _unread(r: Any, size: int) -> list[str]:
    """A note of the log's last bytes that hold no whole message pymavlink indexed (its index pass stops without a
    word at a message type no FMT describes, or a message cut short, in the last :data:`TAIL_BYTES`), or none."""
    end = max((offs[-1] + r.formats[t].len for t, offs in enumerate(r.offsets) if offs and t in r.formats),
              default=0)
    end = min(end, size)
    if end >= size:
        return []
    return [f"the log's last {size - end} bytes (from byte {end}) hold no whole message of a type the log describes: "
            "they are not read"]


def _columns(r: Any, name: str, fields: list[str] | None = None) -> dict[str, np.ndarray]:
    """Every field (or ``fields``) of message ``name`` as numpy arrays, from the bytes at pymavlink's offsets."""
    mid = r.name_to_id.get(name)
    if mid is None:
        return {}
    fmt = r.formats[mid]
    offs = np.asarray(r.offsets[mid], dtype=np.int64)
    # pymavlink records every header it saw; a message cut by the end of the file is not a message
    offs = offs[offs + fmt.len <= r.data_len]
    buf = np.frombuffer(r.data_map, dtype=np.uint8)
    out: dict[str, np.ndarray] = {}
    pos = 3
    for col, ch in zip(fmt.columns, fmt.format):
        if ch not in _NP:
            raise InvalidDataError(f"message {name}: format character {ch!r} is not a DataFlash type", field="file")
        dt, mult = _NP[ch]
        width = np.dtype(dt).itemsize
        if pos + width > fmt.len:
            raise InvalidDataError(f"a damaged DataFlash log: message {name}'s field {col!r} ends at byte "
                                   f"{pos + width}, past the {fmt.len} bytes its FMT declares", field="file")
        if fields is None or col in fields:
            idx = offs[:, None] + (pos + np.arange(width))[None, :]
            raw = buf[idx].copy().view(dt).reshape(-1)
            out[col] = raw.astype(np.float64) * mult if mult else raw
        pos += width
    return out


def _series(r: Any, role: str, spec: str) -> tuple[np.ndarray, np.ndarray]:
    from .ulog import parse_signal, timed_samples

    msg, inst, fld = parse_signal(spec, role)
    if msg not in r.name_to_id or not r.counts[r.name_to_id[msg]]:
        have = sorted(n for n, i in r.name_to_id.items() if r.counts[i])
        what = "is described but never logged" if msg in r.name_to_id else "is not in the log"
        raise InvalidDataError(f"{role} {spec!r}: message {msg!r} {what}; messages logged: {have}", field=role)
    fmt = r.formats[r.name_to_id[msg]]
    if fld not in fmt.columns or fld in ("TimeUS", "TimeMS"):
        raise InvalidDataError(f"{role} {spec!r}: message {msg!r} has no field {fld!r}; fields: "
                               f"{[c for c in fmt.columns if c not in ('TimeUS', 'TimeMS')]}", field=role)
    clock = "TimeUS" if "TimeUS" in fmt.columns else ("TimeMS" if "TimeMS" in fmt.columns else None)
    if clock is None:
        raise InvalidDataError(f"{role} {spec!r}: message {msg!r} has no time field (TimeUS)", field=role)
    inst_field = getattr(fmt, "instance_field", None)
    d = _columns(r, msg, [clock, fld] + ([inst_field] if inst_field else []))
    t = d[clock].astype(np.float64) * (1e-6 if clock == "TimeUS" else 1e-3)
    x = d[fld]
    if x.dtype.kind not in "fiu":
        raise InvalidDataError(f"{role} {spec!r}: field {fld!r} is text, not a number", field=role)
    x = x.astype(np.float64)
    if inst_field:
        keep = d[inst_field].astype(np.int64) == inst
        if not keep.any():
            raise InvalidDataError(f"{role} {spec!r}: message {msg!r} has instances "
                                   f"{sorted(set(d[inst_field].astype(int).tolist()))}, not {inst}", field=role)
        t, x = t[keep], x[keep]
    elif inst:
        raise InvalidDataError(f"{role} {spec!r}: message {msg!r} has no instances (name it {msg}.{fld})",
                               field=role)
    return timed_samples(t, x, role, spec)


def _parameters(r: Any, history: bool = False) -> Any:
    """The PARM messages' values by name, the last logged (ArduPilot logs every parameter at the start and each
    change after); ``history``: ``(the first value of each, [(t_s, NAME, value), ...] the later ones in order)``."""
    d = _columns(r, "PARM", ["TimeUS", "Name", "Value"])
    first: dict[str, float] = {}
    later: list[tuple[float, str, float]] = []
    for t, n, v in zip(d.get("TimeUS", ()), d.get("Name", ()), d.get("Value", ())):
        name = bytes(n).split(b"\0", 1)[0].decode("ascii", "replace")
        if not math.isfinite(float(v)):
            continue
        if name in first:
            later.append((float(t) * 1e-6, name, float(v)))
        else:
            first[name] = float(v)
    if history:
        return first, later
    return first | {name: v for _, name, v in later}


def _vehicle(r: Any) -> str:
    """The firmware's name from its MSG or VER text (``ArduCopter``, ``ArduPlane``, ...), or ""."""
    d = _columns(r, "MSG", ["Message"])
    for m in d.get("Message", [])[:50]:
        text = bytes(m).split(b"\0", 1)[0].decode("ascii", "replace")
        for v in ("ArduCopter", "ArduPlane", "ArduRover", "ArduSub", "Blimp", "Rover"):
            if v in text:
                return v
    return ""


def ardupilot_flight(r: Any, t_end: float) -> Any:
    """What an ArduPilot log says was flown (:class:`tuner.identify.flight.Flight`)."""
    from .flight import COPTER_ACRO, COPTER_MODES, COPTER_SYSTEMID, Flight, intersect, steps_to_intervals, union

    def ts(d: Mapping[str, np.ndarray]) -> np.ndarray:
        return np.asarray(d["TimeUS"], dtype=np.float64) * 1e-6

    def from_start(t: np.ndarray, on: np.ndarray) -> Any:
        """A state's intervals from the log's start: before its first record it was the opposite of what that
        record says (a record is written when the state changes: a log that begins armed or in the air has a disarm
        or a landing first)."""
        on = np.asarray(on, dtype=bool)
        if t[0] <= 0:
            return steps_to_intervals(t, on, t_end)
        return steps_to_intervals(np.r_[0.0, t], np.r_[not on[0], on], t_end)

    arm, ev, mode = (_columns(r, n) for n in ("ARM", "EV", "MODE"))
    seen: list[str] = []
    notes: list[str] = []
    armed = None
    evid = ev["Id"].astype(int) if ev and "Id" in ev and "TimeUS" in ev else np.zeros(0, dtype=int)
    evt = ts(ev) if evid.size else np.zeros(0)
    if arm and "ArmState" in arm and "TimeUS" in arm and arm["ArmState"].size:
        armed = from_start(ts(arm), arm["ArmState"] != 0)
        seen.append(f"ARM.ArmState {sorted(set(arm['ArmState'].astype(int).tolist()))}")
    elif np.isin(evid, (10, 11)).any():
        sel = np.isin(evid, (10, 11))
        armed = from_start(evt[sel], evid[sel] == 10)
    if evid.size:
        seen.append(f"events {sorted(set(evid.tolist()))} (10 armed, 11 disarmed, 18 landed, 28 took off)")
    sel = np.isin(evid, (18, 28))
    # the vehicle starts on the ground (ArduCopter's land_complete is set at boot), unless logging began in the air
    air = from_start(evt[sel], evid[sel] == 28) if sel.any() else None
    if armed is None and air is None:
        return Flight("ardupilot", None, notes=["the log records no arming (no ARM message, no EV 10/11) and no "
                                                "take-off: every stretch is taken as flown"], seen="; ".join(seen))
    if armed is None:  # logging began after arming (LOG_DISARMED 0): the take-off and landing say it
        flown = air
        notes.append("the log records no arming (it began armed): the stretches between take-off (EV 28) and "
                     "landing (EV 18) are taken")
    elif air is None:
        flown = armed
        notes.append("the log records no take-off or landing (EV 28, 18): the armed stretches are taken as airborne")
    else:
        flown = intersect(armed, air)
    vehicle = _vehicle(r)
    copter = vehicle in ("ArduCopter", "")
    modes, exo, why = [], [], ""
    if mode and "ModeNum" in mode and "TimeUS" in mode:
        num = mode["ModeNum"].astype(int)
        names = [COPTER_MODES.get(int(n), f"mode {int(n)}") if copter else f"mode {int(n)}" for n in num]
        modes = sorted(set(names))
        seen.append("modes " + ", ".join(modes))
        if copter:
            mt = np.r_[0.0, ts(mode)]
            rate = steps_to_intervals(mt, np.r_[False, num == COPTER_ACRO], t_end)
            sid = steps_to_intervals(mt, np.r_[False, num == COPTER_SYSTEMID], t_end)
            exo = union(rate, sid)
            why = " and ".join(w for w, iv in (("a rate (ACRO) mode", rate), ("SystemID mode's injected chirp", sid))
                               if iv)
    return Flight("ardupilot", flown, exogenous=exo, exogenous_why=why, modes=modes, seen="; ".join(seen),
                  notes=notes)


def read_dataflash(src: str | Path | bytes, columns: Mapping[str, str], *, rate_hz: float | None = None) -> Any:
    """The ``columns`` (``{"input": "RATE.ROut", "output": "RATE.R"}``, optionally ``"reference"``) of a DataFlash
    log on a uniform grid, as :func:`tuner.identify.ulog.read_ulog` returns a ULog's (``ULogRecords``)."""
    from .ulog import on_grid

    roles = ("input", "output", "reference") if "reference" in columns else ("input", "output")
    if set(columns) != set(roles):
        raise InvalidDataError("a DataFlash log needs input and output signals (MESSAGE.FIELD, e.g. RATE.ROut and "
                               "RATE.R), and optionally a reference", field="input")
    with _open(src) as (r, name):
        u = _series(r, "input", columns["input"])
        y = _series(r, "output", columns["output"])
        ref = _series(r, "reference", columns["reference"]) if "reference" in columns else (None, None)
        params = _parameters(r)
        t_end = max(u[0][-1], y[0][-1])
        flight = ardupilot_flight(r, t_end)
        flight.notes.extend(r.tuner_notes)
    return on_grid(u, y, ref, columns, rate_hz=rate_hz, t0=0.0, dropouts=[], flight=lambda _t: flight, name=name,
                   parameters=params)


def read_dataflash_parameters(src: str | Path | bytes, *, field: str = "file", history: bool = False) -> Any:
    """The parameters a DataFlash log stores (its PARM messages, the last value of each), a damaged log refused as
    :func:`read_dataflash` refuses it (``field``: the caller's name for the file); ``history``: ``(the values at the
    log's start, [(t_s, NAME, value), ...] the changes in flight in order)``
    (:func:`tuner.firmware.params.change_notes` applies and says them)."""
    try:
        with _open(src) as (r, name):
            params = _parameters(r, history)
    except InvalidDataError as e:
        raise InvalidDataError(str(e), field=field) from None
    if not (params[0] if history else params):
        raise InvalidDataError(f"{name}: the log stores no parameters (no PARM messages)", field=field)
    return params


def signals(src: str | Path | bytes) -> dict[str, Any]:
    """What a DataFlash log offers, as :func:`tuner.identify.ulog.signals` says a ULog's: every numeric
    ``MESSAGE.FIELD`` with its median rate, the rate law's parameters as a Mission Planner ``.parm`` text
    (``params_text``), the loop rate they name (``SCHED_LOOP_RATE``), and ``firmware`` ``"ardupilot"``."""
    from .ulog import _LAW_PARAMS, _PARAM_NAME

    out = []
    with _open(src) as (r, _name):
        for msg, mid in sorted(r.name_to_id.items()):
            if not r.counts[mid] or msg in ("FMT", "FMTU", "UNIT", "MULT", "PARM", "MSG"):
                continue
            fmt = r.formats[mid]
            rate = None
            if "TimeUS" in fmt.columns:
                t = _columns(r, msg, ["TimeUS"])["TimeUS"].astype(np.float64)
                d = np.diff(np.unique(t[t > 0]))
                rate = float(1e6 / np.median(d)) if d.size > 1 and np.median(d) > 0 else None
            for col, ch in zip(fmt.columns, fmt.format):
                if col not in ("TimeUS", "TimeMS") and ch in _NP and _NP[ch][0][0] != "S":
                    out.append({"name": f"{msg}.{col}", "rate_hz": rate})
        params = _parameters(r)
    law = {k: v for k, v in params.items() if _PARAM_NAME.fullmatch(k) and k.startswith(_LAW_PARAMS)}
    text = "".join(f"{k},{v!r}\n" for k, v in sorted(law.items()))
    return {"signals": out, "params_text": text, "loop_hz": law.get("SCHED_LOOP_RATE"),
            "loop_from": "SCHED_LOOP_RATE" if law.get("SCHED_LOOP_RATE") else None, "firmware": "ardupilot",
            "kind": "dataflash"}

