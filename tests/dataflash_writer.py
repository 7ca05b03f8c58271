"""A minimal ArduPilot DataFlash (``.bin``) writer for the tests, from ArduPilot's
``libraries/AP_Logger/LogStructure.h``
(ArduPilot master, 2024): every message is the two header bytes ``0xA3 0x95``, a message type (uint8) and its fields,
little endian, packed; type 128 is ``FMT`` (``Type`` uint8, ``Length`` uint8 (the whole message, header included),
``Name`` char[4], ``Format`` char[16], ``Columns`` char[64]), which describes every type, itself first.

Independent of ``tuner`` and of pymavlink (which must read what this writes). No binary fixture is kept: tests write
their logs here.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["Message", "arm", "events", "modes", "parameters", "rate_message", "write_dataflash"]

HEAD = b"\xa3\x95"
#: DataFlash format characters -> struct codes (LogStructure.h's table)
_STRUCT = {"b": "b", "B": "B", "h": "h", "H": "H", "i": "i", "I": "I", "f": "f", "d": "d", "q": "q", "Q": "Q",
           "M": "B", "n": "4s", "N": "16s", "Z": "64s", "c": "h", "C": "H", "e": "i", "E": "I", "L": "i"}


@dataclass
class Message:
    """One message type: ``format`` (DataFlash characters, ``Q`` first for ``TimeUS``), ``columns`` and ``rows``
    (``{column: (n,) array}``, strings as bytes)."""

    name: str
    format: str
    columns: Sequence[str]
    rows: dict[str, Sequence]


def parameters(values: dict[str, float], time_us: int = 1000) -> Message:
    """PARM messages (``TimeUS,Name,Value``), one per parameter."""
    names = sorted(values)
    return Message("PARM", "QNf", ["TimeUS", "Name", "Value"],
                   {"TimeUS": [time_us] * len(names), "Name": [n.encode() for n in names],
                    "Value": [float(values[n]) for n in names]})


def events(items: Sequence[tuple[int, int]]) -> Message:
    """EV messages ``(TimeUS, Id)``: 10 ARMED, 11 DISARMED, 18 LAND_COMPLETE, 28 NOT_LANDED."""
    return Message("EV", "QB", ["TimeUS", "Id"], {"TimeUS": [t for t, _ in items], "Id": [i for _, i in items]})


def arm(items: Sequence[tuple[int, int]]) -> Message:
    """ARM messages ``(TimeUS, ArmState)`` (ArmChecks, Forced, Method zero)."""
    n = len(items)
    return Message("ARM", "QBIBB", ["TimeUS", "ArmState", "ArmChecks", "Forced", "Method"],
                   {"TimeUS": [t for t, _ in items], "ArmState": [s for _, s in items], "ArmChecks": [0] * n,
                    "Forced": [0] * n, "Method": [0] * n})


def modes(items: Sequence[tuple[int, int]]) -> Message:
    """MODE messages ``(TimeUS, ModeNum)`` (ArduCopter: 0 STABILIZE, 1 ACRO, 25 SYSTEMID)."""
    return Message("MODE", "QMBB", ["TimeUS", "Mode", "ModeNum", "Rsn"],
                   {"TimeUS": [t for t, _ in items], "Mode": [m for _, m in items],
                    "ModeNum": [m for _, m in items], "Rsn": [0] * len(items)})


def _fmt(type_id: int, name: str, fmt: str, columns: str) -> bytes:
    body = struct.pack("<BB4s16s64s", type_id, 3 + struct.calcsize("<" + "".join(_STRUCT[c] for c in fmt)),
                       name.encode(), fmt.encode(), columns.encode())
    return HEAD + bytes([128]) + body


def write_dataflash(path: str | Path, messages: Sequence[Message], *, msg: str = "ArduCopter V4.5.0") -> Path:
    """Write ``messages`` to ``path``: FMT for FMT, a FMT per type, a MSG naming the firmware, then every message in
    TimeUS order across types."""
    out = bytearray(_fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns"))
    all_msgs = [Message("MSG", "QZ", ["TimeUS", "Message"], {"TimeUS": [1], "Message": [msg.encode()]}),
                *messages]
    rows = []
    for i, m in enumerate(all_msgs):
        tid = 129 + i
        out += _fmt(tid, m.name, m.format, ",".join(m.columns))
        st = struct.Struct("<" + "".join(_STRUCT[c] for c in m.format))
        cols = [np.asarray(m.rows[c]) if not isinstance(m.rows[c][0], bytes) else list(m.rows[c])
                for c in m.columns]
        n = len(cols[0])
        for j in range(n):
            vals = []
            for c, ch in zip(cols, m.format):
                v = c[j]
                vals.append(v if isinstance(v, bytes) else (float(v) if ch in "fd" else int(v)))
            rows.append((int(vals[0]), tid, HEAD + bytes([tid]) + st.pack(*vals)))
    rows.sort(key=lambda r: (r[0], r[1]))
    for _, _, b in rows:
        out += b
    p = Path(path)
    p.write_bytes(bytes(out))
    return p


def rate_message(t_us: np.ndarray, des: np.ndarray, actual: np.ndarray, out: np.ndarray) -> Message:
    """RATE (``TimeUS,RDes,R,ROut,PDes,P,POut,YDes,Y,YOut,ADes,A,AOut``): the roll axis given, the rest zero."""
    z = np.zeros(len(t_us))
    cols = ["TimeUS", "RDes", "R", "ROut", "PDes", "P", "POut", "YDes", "Y", "YOut", "ADes", "A", "AOut"]
    vals = [t_us, des, actual, out] + [z] * 9
    return Message("RATE", "Q" + "f" * 12, cols, dict(zip(cols, vals)))
