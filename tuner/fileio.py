"""Reading the user's files: bounded, in chunks, with errors that name the file and the option.

One reader for every file input of the CLI (a CSV log, a result's JSON, a gains file): it reads at
most ``limit`` bytes in chunks of :data:`CHUNK_BYTES` and stops at the limit, so that a huge file or
a device (``/dev/zero``, ``/dev/urandom``) is refused at once instead of filling the memory; text
is decoded as it arrives (UTF-8, a byte-order mark dropped), so binary data is refused at its
first chunk (a NUL byte, or bytes that are not UTF-8). Every error is a
:class:`~tuner.errors.TunerError` with ``field`` = the caller's name for the input.

=====================  ===========  ===================================================
limit                  value        for
=====================  ===========  ===================================================
:data:`MAX_CSV_BYTES`  256 MiB      a CSV log (``tuner identify``)
:data:`MAX_JSON_BYTES` 16 MiB       a JSON document (``tuner export --result``, ``verify --gains``)
:data:`MAX_STUDY_BYTES` 4 MiB       a study file (TOML)
=====================  ===========  ===================================================

The check that a path is a regular file within its limit is made twice: on the path before it is opened (a device is
never opened), and on the opened handle (``fstat``; the open cannot block: a FIFO swapped in between is refused, not
waited on). Outputs (:func:`write_output`) are written the same way: only to a regular file, every byte or an error.
"""

from __future__ import annotations

import codecs
import json
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any, BinaryIO

from .errors import TunerError

__all__ = ["CHUNK_BYTES", "MAX_CSV_BYTES", "MAX_JSON_BYTES", "MAX_NESTING", "MAX_STUDY_BYTES", "check_input",
           "check_output", "nesting_depth", "open_checked", "open_input", "read_head", "read_text", "read_text_from",
           "read_json", "write_output"]

CHUNK_BYTES = 1 << 20
MAX_CSV_BYTES = 256 << 20
MAX_JSON_BYTES = 16 << 20
MAX_STUDY_BYTES = 4 << 20


def _mib(n: int) -> str:
    return f"{n / (1 << 20):g} MiB"


def _kind(mode: int) -> str:
    import stat

    return ("a FIFO or pipe" if stat.S_ISFIFO(mode) else "a character device" if stat.S_ISCHR(mode) else
            "a block device" if stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode) else "a special file")


def _check_stat(st: Any, name: str, limit: int | None, field: str | Sequence[str | int]) -> int:
    import stat

    if stat.S_ISDIR(st.st_mode):
        raise TunerError(f"{name}: a directory, not a file: give the file's path", field=field)
    if not stat.S_ISREG(st.st_mode):
        raise TunerError(f"{name}: not a regular file ({_kind(st.st_mode)}): save the data to a file and give its "
                         "path", field=field)
    if limit is not None and st.st_size > limit:
        raise TunerError(f"{name}: {st.st_size} bytes, larger than {_mib(limit)} (the limit for this input); give "
                         "a smaller file", field=field)
    return int(st.st_size)


def check_input(path: str | Path, *, limit: int | None = None, field: str | Sequence[str | int] = "file",
                label: str | None = None) -> int:
    """The size of ``path``, a regular file within ``limit`` bytes, decided from its metadata before it is opened:
    a directory, a FIFO or pipe, a device (``/dev/zero``) or a socket is refused at once (reading one could hang or
    never end), and so is a file larger than ``limit`` (a 2 GB sparse file is refused without reading a byte).

    Examples
    --------
    >>> from tuner.fileio import check_input
    >>> check_input("/dev/zero")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    tuner.errors.TunerError: /dev/zero: not a regular file (a character device): ...
    """
    import os

    name = label or str(path)
    try:
        st = os.stat(path)
    except OSError as e:
        raise TunerError(f"{name}: cannot read: {e.strerror or e}", field=field) from None
    return _check_stat(st, name, limit, field)


def read_head(path: str | Path, n: int, *, field: str | Sequence[str | int] = "file", label: str | None = None
              ) -> bytes:
    """The first ``n`` bytes of the regular file ``path`` (:func:`open_checked`: nothing that could hang)."""
    with open_input(path, limit=None, field=field, label=label) as f:
        try:
            return f.read(n)
        except OSError as e:
            raise TunerError(f"{label or path}: cannot read: {e.strerror or e}", field=field) from None


def open_checked(path: str | Path, *, limit: int | None, field: str | Sequence[str | int] = "file",
                 label: str | None = None) -> BinaryIO:
    """``path`` opened for reading in binary, a regular file within ``limit`` bytes: checked on the path before it is
    opened (:func:`check_input`), then on the opened handle (``fstat``: the path may have been replaced in between;
    the open does not block, so a FIFO put there is refused, not waited on); the caller closes it (or uses
    :func:`open_input`)."""
    import os

    name = label or str(path)
    check_input(path, limit=limit, field=field, label=label)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except OSError as e:
        raise TunerError(f"{name}: cannot read: {e.strerror or e}", field=field) from None
    try:
        _check_stat(os.fstat(fd), name, limit, field)
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return os.fdopen(fd, "rb")


@contextmanager
def open_input(path: str | Path, *, limit: int | None, field: str | Sequence[str | int] = "file",
               label: str | None = None) -> Iterator[BinaryIO]:
    """``path`` opened once for reading in binary (:func:`open_checked`), closed on leaving: a caller that must look
    at a file's first bytes to know how to read it (a ULog log or a CSV) reads both from this one handle
    (``seek(0)``), never opening it twice."""
    f = open_checked(path, limit=limit, field=field, label=label)
    try:
        yield f
    finally:
        f.close()


def read_text(path: str | Path, *, limit: int, field: str | Sequence[str | int] = "file", label: str | None = None,
              hint: str = "") -> str:
    """The UTF-8 text of ``path``, read in chunks, refused past ``limit`` bytes or at the first binary chunk.

    ``label`` starts every message (default: the path); ``hint`` ends the messages about
    content (e.g. what file was expected).
    """
    with open_input(path, limit=limit, field=field, label=label) as f:
        return read_text_from(f, name=label or str(path), limit=limit, field=field, hint=hint)


def read_text_from(f: BinaryIO, *, name: str, limit: int, field: str | Sequence[str | int] = "file",
                   hint: str = "") -> str:
    """The UTF-8 text of the open binary file ``f`` from where it stands, as :func:`read_text` reads a path."""
    tail = f"; {hint}" if hint else ""
    dec = codecs.getincrementaldecoder("utf-8-sig")()
    parts: list[str] = []
    size = 0
    try:
        while True:
            chunk = f.read(CHUNK_BYTES)
            if not chunk:
                break
            size += len(chunk)
            if size > limit:
                raise TunerError(f"{name}: larger than {_mib(limit)} (the limit for this input); give a "
                                 f"smaller file{tail}", field=field)
            if b"\0" in chunk:
                raise TunerError(f"{name}: a binary file (NUL bytes), not text{tail}", field=field)
            parts.append(dec.decode(chunk))
        parts.append(dec.decode(b"", final=True))
    except OSError as e:
        raise TunerError(f"{name}: cannot read: {e.strerror or e}", field=field) from None
    except UnicodeDecodeError as e:
        raise TunerError(f"{name}: not a UTF-8 text file ({e.reason}){tail}", field=field) from None
    return "".join(parts)


def read_json(path: str | Path, *, limit: int = MAX_JSON_BYTES, field: str | Sequence[str | int] = "file",
              label: str | None = None, hint: str = "") -> Any:
    """A JSON document from ``path`` (bounded like :func:`read_text`; nesting too deep for the parser refused)."""
    name = label or str(path)
    tail = f"; {hint}" if hint else ""
    text = read_text(path, limit=limit, field=field, label=label, hint=hint)
    try:
        out = json.loads(text)
    except json.JSONDecodeError as e:
        raise TunerError(f"{name}: not valid JSON ({e.msg} at line {e.lineno}){tail}", field=field) from None
    except RecursionError:
        raise TunerError(f"{name}: JSON nested too deeply to read{tail}", field=field) from None
    if nesting_depth(out) > MAX_NESTING:
        raise TunerError(f"{name}: JSON nested more than {MAX_NESTING} levels deep{tail}", field=field)
    return out


#: the deepest nesting a JSON or TOML input may have (a result's JSON is a few levels deep)
MAX_NESTING = 64


def nesting_depth(obj: Any, level: int = 0) -> int:
    """How deep ``obj`` nests (iteratively: a hostile document cannot exhaust the stack here)."""
    deepest, stack = level, [(obj, level)]
    while stack:
        o, d = stack.pop()
        deepest = max(deepest, d)
        if d > MAX_NESTING:
            return d
        if isinstance(o, dict):
            stack.extend((v, d + 1) for v in o.values())
        elif isinstance(o, list):
            stack.extend((v, d + 1) for v in o)
    return deepest


def check_output(path: str | Path, *, field: str | Sequence[str | int] = "out", label: str | None = None) -> None:
    """Refuse, before any work, an output path :func:`write_output` would refuse by what is there now: a directory,
    a FIFO or pipe, a device or a socket (a path that does not exist yet is fine)."""
    import os

    name = label or str(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return
    except OSError as e:
        raise TunerError(f"{name}: cannot write: {e.strerror or e}", field=field) from None
    _refuse_output(st, name, field)


def _refuse_output(st: Any, name: str, field: str | Sequence[str | int]) -> None:
    import stat

    if stat.S_ISDIR(st.st_mode):
        raise TunerError(f"{name}: a directory: give a file's path", field=field)
    if not stat.S_ISREG(st.st_mode):
        raise TunerError(f"{name}: not a regular file ({_kind(st.st_mode)}): give a file's path (nothing is written to "
                         "a pipe or a device)", field=field)


def write_output(path: str | Path, data: bytes | str, *, field: str | Sequence[str | int] = "out",
                 label: str | None = None) -> None:
    """Write ``data`` (text as UTF-8) to ``path``, a regular file (made, or replaced): a directory, a FIFO or pipe, a
    device (``/dev/full``, ``/dev/null``) or a socket is refused, on the path and on the opened handle (the open does
    not block: a FIFO is refused, not waited on); every byte is written and the file closed, or a
    :class:`~tuner.errors.TunerError` says why (a full disk: "No space left on device") and the partial file is
    removed. Nothing is said to have been written that was not.

    Examples
    --------
    >>> from tuner.fileio import write_output
    >>> write_output("/dev/full", b"x")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    tuner.errors.TunerError: /dev/full: not a regular file (a character device): ...
    """
    import os

    name = label or str(path)
    buf = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    check_output(path, field=field, label=label)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC, 0o666)
    except OSError as e:
        import errno

        why = "a FIFO or pipe with no reader" if e.errno == errno.ENXIO else (e.strerror or str(e))
        raise TunerError(f"{name}: cannot write: {why}", field=field) from None
    try:
        _refuse_output(os.fstat(fd), name, field)
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    try:
        try:
            view = memoryview(buf)
            while view:
                view = view[os.write(fd, view):]
        finally:
            os.close(fd)
    except OSError as e:
        with suppress(OSError):
            os.unlink(path)
        raise TunerError(f"{name}: cannot write: {e.strerror or e}", field=field) from None

