"""A minimal ULog writer for the tests, following the published "ULog File Format" (PX4 docs).

Independent of ``tuner`` and of pyulog (which must read what this writes): a 16-byte header
(``'ULog'`` + ``0x01 0x12 0x35``, the version byte, a uint64 µs timestamp), the definitions
section (a flag-bits ``B`` message, ``F`` formats, ``I`` info), then ``A`` subscriptions and ``D``
data messages in time order across topics, and optionally ``O`` dropouts. Every message is
``uint16 msg_size, uint8 msg_type, payload``, little endian. No binary fixture is kept: tests
write their logs here.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["Topic", "write_ulog"]

_TYPES = {"uint64_t": "Q", "uint32_t": "I", "int32_t": "i", "uint8_t": "B", "float": "f", "double": "d",
          "bool": "?", "int16_t": "h", "uint16_t": "H", "int8_t": "b"}


@dataclass
class Topic:
    """One topic instance: ``fields`` as ``[(type, name, array_len or 0), ...]`` (timestamp first is added),
    ``timestamps_us`` and ``values`` (``{name: (n,) or (n, k) array}``)."""

    name: str
    fields: list[tuple[str, str, int]]
    timestamps_us: Sequence[int]
    values: dict[str, np.ndarray]
    multi_id: int = 0
    msg_id: int = field(default=-1)


def _msg(kind: str, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), ord(kind)) + payload


def write_ulog(path: str | Path, topics: list[Topic], *, start_us: int = 0,
               dropouts: Sequence[tuple[int, int]] = (), info: dict[str, str] | None = None,
               params: dict[str, float | int] | None = None,
               changed: Sequence[tuple[int, str, float | int]] = ()) -> Path:
    """Write ``topics`` to ``path``; ``dropouts`` are ``(timestamp_us, duration_ms)`` written after the last
    data message at or before that time; ``params`` as parameter (``P``) messages in the definitions section (an
    ``int`` as int32_t, a ``float`` as float); ``changed``: ``(timestamp_us, name, value)`` parameter messages in the
    data section (a change in flight), after the data messages at or before that time."""
    out = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", start_us))
    out += _msg("B", bytes(8) + bytes(8) + struct.pack("<3Q", 0, 0, 0))
    formats: dict[str, str] = {}
    for tp in topics:
        spec = "".join(f"{t}[{n}] {name};" if n else f"{t} {name};" for t, name, n in tp.fields)
        formats[tp.name] = f"{tp.name}:uint64_t timestamp;{spec}"
    for text in formats.values():
        out += _msg("F", text.encode())
    for k, v in (info or {"sys_name": "tuner-tests"}).items():
        key = f"char[{len(v)}] {k}".encode()
        out += _msg("I", bytes([len(key)]) + key + v.encode())
    def param(k: str, v: float | int) -> bytes:
        typ, val = ("int32_t", struct.pack("<i", v)) if isinstance(v, int) else ("float", struct.pack("<f", v))
        key = f"{typ} {k}".encode()
        return _msg("P", bytes([len(key)]) + key + val)

    for k, v in (params or {}).items():
        out += param(k, v)
    events = []
    for i, tp in enumerate(topics):
        tp.msg_id = i
        out += _msg("A", struct.pack("<BH", tp.multi_id, i) + tp.name.encode())
        fmt = "<Q" + "".join((_TYPES[t] * n if n else _TYPES[t]) for t, _, n in tp.fields)
        for j, ts in enumerate(tp.timestamps_us):
            vals = []
            for _, name, n in tp.fields:
                v = tp.values[name][j]
                vals += list(np.ravel(v)) if n else [v]
            events.append((int(ts), i, struct.pack("<H", i) + struct.pack(fmt, int(ts), *vals)))
    events.sort(key=lambda e: (e[0], e[1]))
    drops = sorted(dropouts)
    changes = sorted(changed, key=lambda c: c[0])
    for ts, _, payload in events:
        while drops and drops[0][0] < ts:
            out += _msg("O", struct.pack("<H", drops.pop(0)[1]))
        while changes and changes[0][0] < ts:
            out += param(*changes.pop(0)[1:])
        out += _msg("D", payload)
    for _, k, v in changes:
        out += param(k, v)
    for _, ms in drops:
        out += _msg("O", struct.pack("<H", ms))
    p = Path(path)
    p.write_bytes(bytes(out))
    return p
