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
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from ..errors import InvalidDataError, TunerError
from ..fileio import MAX_CSV_BYTES, open_checked
from .data import MAX_SAMPLES

__all__ = ["MAX_ROWS", "SNIFF_CHARS", "read_columns"]

MAX_ROWS = MAX_SAMPLES  # the record limit (tuner.identify.data.MAX_SAMPLES), the same for the CLI and the service


#: the delimiter is sniffed on at most this many characters of the header and the first rows: csv.Sniffer's
#: regular expressions take time quadratic in a line's length (a 64 kB line of '",' held it 19 s; 4096 characters:
#: 0.15 s at worst, bench/hostile.py --files), and a log's header and first rows fit many times over
SNIFF_CHARS = 4096


def _dialect(lines: list[str]) -> type[csv.Dialect] | csv.Dialect:
    """The dialect of the header and first rows, sniffed on their first whole lines within SNIFF_CHARS characters
    (a longer header: its first SNIFF_CHARS characters)."""
    sample, n = [], 0
    for ln in lines:
        if n + len(ln) > SNIFF_CHARS:
            if not sample:
                sample.append(ln[:SNIFF_CHARS])
            break
        sample.append(ln)
        n += len(ln)
    try:
        return csv.Sniffer().sniff("".join(sample), delimiters=",;\t")
    except csv.Error:
        return csv.excel


def read_columns(path: str | Path, columns: Mapping[str, str], *, handle: BinaryIO | None = None
                 ) -> dict[str, np.ndarray]:
    """The named columns of a CSV log as float arrays, keyed by role: ``{"input": "pitch_cmd", ...}``; ``handle``:
    the file already opened (:func:`tuner.identify.ulog.open_log`), read from it instead of opening ``path``.

    The text is decoded and parsed as it streams in (a regular file within :data:`~tuner.fileio.MAX_CSV_BYTES`):
    nothing but the columns' float arrays (8 bytes a value) grows with the file."""
    p = Path(path)
    if handle is not None:
        return _read(p, handle, columns)
    try:
        f = open_checked(p, limit=MAX_CSV_BYTES, field="file")
    except TunerError as e:
        raise InvalidDataError(str(e), field="file") from None
    with f:
        return _read(p, f, columns)


_HINT = "give a CSV log with a header row"


MAX_LINE_CHARS = 1 << 20  # a CSV line longer than this is no log's (a binary file without newlines): refused


class _NoNul(io.RawIOBase):
    """The handle's bytes as they are read, refused at the first chunk that holds a NUL byte (binary data is
    refused before a line of it is gathered)."""

    def __init__(self, f: BinaryIO, p: Path) -> None:
        self.f, self.p = f, p

    def readable(self) -> bool:
        return True

    def readinto(self, b: Any) -> int:
        n = self.f.readinto(b)
        if n and bytes(memoryview(b)[:n]).find(b"\0") >= 0:
            raise InvalidDataError(f"{self.p}: a binary file (NUL bytes), not text; {_HINT}", field="file")
        return n or 0


def _read(p: Path, f: BinaryIO, columns: Mapping[str, str]) -> dict[str, np.ndarray]:
    text = io.TextIOWrapper(io.BufferedReader(_NoNul(f, p)), encoding="utf-8-sig", newline="")
    try:
        return _parse(p, _lines(p, text), columns)
    except UnicodeDecodeError as e:
        raise InvalidDataError(f"{p}: not a UTF-8 text file ({e.reason}); {_HINT}", field="file") from None
    except csv.Error as e:  # e.g. a cell longer than csv.field_size_limit() (131,072 characters)
        raise InvalidDataError(f"{p}: not a readable CSV log ({e}); {_HINT}", field="file") from None
    except OSError as e:
        raise InvalidDataError(f"{p}: cannot read: {e.strerror or e}", field="file") from None


def _lines(p: Path, text: io.TextIOWrapper) -> Iterator[str]:
    """The lines of the text as it streams in, each at most MAX_LINE_CHARS, and refused past the limit (a file that
    grows while it is read)."""
    size = 0
    while True:
        line = text.readline(MAX_LINE_CHARS)
        if not line:
            return
        if len(line) >= MAX_LINE_CHARS and not line.endswith(("\n", "\r")):
            raise InvalidDataError(f"{p}: a line longer than {MAX_LINE_CHARS} characters: not a CSV log; {_HINT}",
                                   field="file")
        size += len(line)
        if size > MAX_CSV_BYTES:
            raise InvalidDataError(f"{p}: larger than {MAX_CSV_BYTES >> 20} MiB (the limit for a CSV log); give a "
                                   "shorter record", field="file")
        yield line


def _parse(p: Path, lines: Iterator[str], columns: Mapping[str, str]) -> dict[str, np.ndarray]:
    """The columns as float arrays, parsed line by line as the lines arrive (no list of them, no Python floats kept:
    8 bytes a value)."""
    from array import array

    first = 0
    head: list[str] = []
    for raw in lines:  # comments and blank lines before the header
        if raw.strip() and not raw.lstrip().startswith("#"):
            head.append(raw)
            break
        first += 1
    if not head:
        raise InvalidDataError(f"{p}: empty (no header row)", field="file")
    ahead = list(itertools.islice(lines, 19))  # the sniffer's sample: the header and 19 rows
    reader = csv.reader(itertools.chain(head, ahead, lines), _dialect(head + ahead))
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
                if "_" in cell or not cell.isascii():  # float() takes '1_5' as 15 (and other scripts' digits)
                    raise ValueError(cell)
                v = float(cell)
            except ValueError:
                what = "empty" if not cell else f"not a number: {cell!r}"
                raise InvalidDataError(f"{p}, line {line}, column {header[i]!r}: {what}", field=role) from None
            if not math.isfinite(v):
                raise InvalidDataError(f"{p}, line {line}, column {header[i]!r}: {cell} (non-finite); remove or "
                                       "interpolate such samples", field=role)
            data[role].append(v)
    return {role: np.frombuffer(v, dtype=float).copy() if len(v) else np.zeros(0) for role, v in data.items()}
