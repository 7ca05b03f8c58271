"""Reading flight logs from CSV files (the stdlib :mod:`csv` module; no pandas).

A log has a header row naming its columns; lines starting with ``#`` before the header are
comments; the delimiter (comma, semicolon, tab) is detected. Every error names the file, the
line and the column, and carries ``field`` = the role of the column (``"input"``, ``"output"``,
``"time"``) so the caller can point at the option that chose it. The file is read in chunks and
refused beyond :data:`~tuner.fileio.MAX_CSV_BYTES` (256 MiB) or at its first binary chunk.
"""

from __future__ import annotations

import csv
import io
import itertools
import math
from collections.abc import Mapping
from pathlib import Path
from typing import BinaryIO

import numpy as np

from ..errors import InvalidDataError, TunerError
from ..fileio import MAX_CSV_BYTES, read_text, read_text_from

__all__ = ["MAX_ROWS", "read_columns"]

MAX_ROWS = 10_000_000


def _dialect(sample: str) -> type[csv.Dialect] | csv.Dialect:
    try:
        return csv.Sniffer().sniff(sample, delimiters=",;\t")
    except csv.Error:
        return csv.excel


def read_columns(path: str | Path, columns: Mapping[str, str], *, handle: BinaryIO | None = None
                 ) -> dict[str, np.ndarray]:
    """The named columns of a CSV log as float arrays, keyed by role: ``{"input": "pitch_cmd", ...}``; ``handle``:
    the file already opened (:func:`tuner.identify.ulog.open_log`), read from it instead of opening ``path``."""
    p = Path(path)
    hint = "give a CSV log with a header row"
    try:
        text = read_text(p, limit=MAX_CSV_BYTES, field="file", hint=hint) if handle is None else \
            read_text_from(handle, name=str(p), limit=MAX_CSV_BYTES, field="file", hint=hint)
    except TunerError as e:
        raise InvalidDataError(str(e), field="file") from None
    try:
        return _parse(p, text, columns)
    except csv.Error as e:  # e.g. a cell longer than csv.field_size_limit() (131,072 characters)
        raise InvalidDataError(f"{p}: not a readable CSV log ({e}); give a CSV log with a header row",
                               field="file") from None


def _parse(p: Path, text: str, columns: Mapping[str, str]) -> dict[str, np.ndarray]:
    """The columns as float arrays, parsed line by line from the text (no list of its lines, no Python floats
    kept: 8 bytes a value; the text itself is the largest thing held)."""
    from array import array

    buf = io.StringIO(text)
    first = 0
    head: list[str] = []
    for raw in buf:  # comments and blank lines before the header
        if raw.strip() and not raw.lstrip().startswith("#"):
            head.append(raw)
            break
        first += 1
    if not head:
        raise InvalidDataError(f"{p}: empty (no header row)", field="file")
    at = buf.tell()
    sample = head[0] + "".join(buf.readline() for _ in range(19))
    buf.seek(at)
    reader = csv.reader(itertools.chain(head, buf), _dialect(sample))
    header = [h.strip() for h in next(reader)]
    idx: dict[str, int] = {}
    for role, name in columns.items():
        if name not in header:
            raise InvalidDataError(f"{p}: no column {name!r} (for the {role}); columns: {header}", field=role)
        idx[role] = header.index(name)
    data: dict[str, array] = {role: array("d") for role in columns}
    lead = next(iter(columns))
    for k, row in enumerate(reader):
        line = first + 2 + k
        if not row or (len(row) == 1 and not row[0].strip()):
            continue
        if len(data[lead]) >= MAX_ROWS:
            raise InvalidDataError(f"{p}: more than {MAX_ROWS} rows (the record limit, the same for the command "
                                   "line and the service): decimate the log (keep every k-th row) or cut it",
                                   field="file")
        for role, i in idx.items():
            cell = row[i].strip() if i < len(row) else ""
            try:
                v = float(cell)
            except ValueError:
                what = "empty" if not cell else f"not a number: {cell!r}"
                raise InvalidDataError(f"{p}, line {line}, column {header[i]!r}: {what}", field=role) from None
            if not math.isfinite(v):
                raise InvalidDataError(f"{p}, line {line}, column {header[i]!r}: {cell} (non-finite); remove or "
                                       "interpolate such samples", field=role)
            data[role].append(v)
    return {role: np.frombuffer(v, dtype=float).copy() if len(v) else np.zeros(0) for role, v in data.items()}
