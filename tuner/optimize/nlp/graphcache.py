"""The NLPs' expression graphs, on disk: what a cold process would otherwise build again (the command line's second
``tuner tune`` of a loop, a new service or study worker), kept across processes without a compiler.

A shape's build (:func:`tuner.optimize.nlp.transcribe.get_problem`) writes its entry (:func:`save`): the NLP's
``(x, p) -> (f, g)`` and the step-response Function, each in CasADi's own serialization (``Function.serialize``),
with the constraint bounds. A later process loads the entry (:func:`load`) and makes the solver of the deserialized
``(f, g)`` Function (``nlpsol``: CasADi derives the solver's derivative Function, the Jacobian, again, which is
faster than deserializing it: px4_rate's K = 1536 shape's whole serialized solver, 146 MB, deserializes in 1.47 s,
its ``(f, g)`` in 0.26 s and ``nlpsol`` of it takes 0.55 s). The loaded problem's graph is the built one's node for
node, so the solver answers bitwise as the built one (tests/tuner/test_graphcache.py).

Measured (the solver's ``build_s``, one process each, 2-core machine; before f39d2ed made default's polish sharp, a
larger shape for some loops): the README's roll loop's four shapes load in
0.10 s (0.04 s of it deserializing); px4_rate's six build in 3.6 s and load in 1.6 s (0.6 s deserializing, 0.85 s
``nlpsol``), where they took 5.3 s and 2.8 s while the SQP also made CasADi's ``nlp_grad``
(:func:`tuner.optimize.nlp.transcribe.sqp_options`).

The same rules as the compiled-code cache (:mod:`tuner.optimize.nlp.codecache`): only in a root that
:func:`tuner.optimize.cachedir.trusted_root` accepts (a deserialized CasADi Function can name a shared library to
load: it is code), under ``nlp-graph/``; each entry is one file, written to a temporary name and moved into place by
one rename, whose first line is the SHA-256 of the rest; the key holds the hash of the sources that write the NLP
(as codecache's), CasADi's version and :data:`FORMAT`; an entry whose checksum does not match, or that does not
deserialize to the NLP's signature, is deleted and built again, never used. The entries are bounded by
:data:`CACHE_MB` (``TUNER_NLP_GRAPH_MB``), the least recently used removed first. ``TUNER_NLP_GRAPHS=off`` turns
it off (every shape built)."""

from __future__ import annotations

import hashlib
import io
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from ..cachedir import cache_root, private, trusted_root
from .codecache import shape_digest

__all__ = ["enabled", "entry_path", "load", "save", "CACHE_MB", "FORMAT"]

FORMAT = 1  # the entry's layout (a change here: bump it)
CACHE_MB = 2048.0  # the entries' total, at most (px4_rate's shapes: 70 MB; the roll loop's: 5 MB)


def enabled() -> bool:
    """The graph cache is on (``TUNER_NLP_GRAPHS`` not ``off``) and its root is safe to load from."""
    if os.environ.get("TUNER_NLP_GRAPHS", "on").strip().lower() in ("off", "0", "no", "false"):
        return False
    return trusted_root() is not None


def _cache_mb() -> float:
    try:
        mb = float(os.environ.get("TUNER_NLP_GRAPH_MB", "") or CACHE_MB)
    except ValueError:
        return CACHE_MB
    return mb if mb >= 0 else CACHE_MB


def _digest(key: Any, space: Any) -> str:
    # the code that writes the NLP (and this file's format): a change makes new entries
    return shape_digest(key, space, (FORMAT,), 32)


def entry_path(key: Any, space: Any) -> Path:
    """The cache file of the problem shape ``key`` (search space ``space``)."""
    return cache_root() / "nlp-graph" / f"{_digest(key, space)}.npz"


def load(key: Any, space: Any) -> tuple[Any, Any, np.ndarray, np.ndarray, int] | None:
    """The stored parts of ``key``'s problem: ``(fg, step, lbg, ubg, n_v)`` (``fg``: the Function ``(x, p) -> (f,
    g)`` to make the solver of), or None (not there, off, or corrupt: then deleted, to be built again)."""
    if not enabled():
        return None
    path = entry_path(key, space)
    blob = _read_own(path)
    if blob is None:
        return None
    try:
        head, _, body = blob.partition(b"\n")
        if hashlib.sha256(body).hexdigest().encode() != head:
            raise ValueError("checksum")
        with np.load(io.BytesIO(body), allow_pickle=False) as z:
            fg_s, step_s = bytes(z["fg"]).decode(), bytes(z["step"]).decode()
            lbg, ubg, nv = np.array(z["lbg"], float), np.array(z["ubg"], float), int(z["n_v"])
        import casadi as cs

        fg, step = cs.Function.deserialize(fg_s), cs.Function.deserialize(step_s)
        if (fg.name_in(), fg.name_out()) != (["x", "p"], ["f", "g"]) or step.n_in() != 2:
            raise ValueError("signature")
        if fg.size1_out(1) != lbg.size or ubg.size != lbg.size:
            raise ValueError("bounds")
    except Exception:  # a corrupt or foreign entry: never used, built again
        try:
            path.unlink(missing_ok=True)
        except OSError:  # (a cache folder that cannot be written, e.g. a read-only image: the build goes on)
            pass
        return None
    try:
        os.utime(path)  # (used: the last to be removed)
    except OSError:
        pass
    return fg, step, lbg, ubg, nv


def _read_own(path: Path) -> bytes | None:
    """The bytes of the entry ``path``, or None, read only if the entry and its folder are what this process wrote: a
    deserialized CasADi Function can load a shared library, so a file someone else could have placed or changed is
    never read (the root's own check, :func:`trusted_root`, is on the path; here the folder and the file are checked
    on what is opened: no symlink followed, a directory / regular file owned by this user, writable by no one else)."""
    try:
        dfd = os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return None
    try:
        if not private(os.fstat(dfd)):
            return None
        try:
            # (non-blocking: a FIFO placed there must not hold the open before the check below refuses it)
            fd = os.open(path.name, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0), dir_fd=dfd)
        except OSError:
            return None
        with os.fdopen(fd, "rb") as f:
            st = os.fstat(f.fileno())
            if not private(st, regular=True) or st.st_size > _cache_mb() * 2 ** 20:
                return None  # (an entry larger than the whole cache may hold is none this process wrote)
            return f.read(st.st_size + 1)
    finally:
        os.close(dfd)


def save(key: Any, space: Any, fg: Any, step: Any, lbg: np.ndarray, ubg: np.ndarray, n_v: int) -> bool:
    """Store the parts of ``key``'s built problem (whole: a temporary file renamed into place); then the least
    recently used entries beyond :data:`CACHE_MB` removed. True if written."""
    if not enabled():
        return False
    path = entry_path(key, space)
    if path.exists():
        return False
    buf = io.BytesIO()
    try:
        np.savez(buf, fg=np.frombuffer(fg.serialize().encode(), np.uint8),
                 step=np.frombuffer(step.serialize().encode(), np.uint8),
                 lbg=np.asarray(lbg, float), ubg=np.asarray(ubg, float), n_v=np.int64(n_v))
    except Exception:  # (a graph CasADi cannot serialize, or no memory for it: the tune goes on, nothing stored)
        return False
    body = buf.getvalue()
    tmp = None
    try:
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=path.stem + ".", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "wb") as f:
            f.write(hashlib.sha256(body).hexdigest().encode() + b"\n")
            f.write(body)
        os.replace(tmp, path)  # whole or not at all
    except OSError:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        return False
    _trim(path.parent)
    return True


def _trim(root: Path) -> None:
    """Remove the least recently used entries while they total more than :data:`CACHE_MB` (and what a killed
    writer left: temporary files older than an hour)."""
    import time

    for p in root.glob("*.tmp"):
        try:
            if time.time() - p.stat().st_mtime > 3600:
                p.unlink()
        except OSError:
            pass
    entries = []
    for p in root.glob("*.npz"):
        try:
            st = p.stat()
        except OSError:
            continue
        entries.append((st.st_mtime, st.st_size, p))
    total, cap = sum(e[1] for e in entries), _cache_mb() * 2**20
    for _, size, p in sorted(entries):
        if total <= cap:
            break
        try:
            p.unlink(missing_ok=True)
        except OSError:
            continue
        total -= size
