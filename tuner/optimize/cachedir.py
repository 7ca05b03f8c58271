"""Where the tuner keeps what it compiles, shared by the command line, the service and the study workers:
``$TUNER_CACHE_DIR``, else ``$XDG_CACHE_HOME/tuner``, else ``~/.cache/tuner`` (``numba/``: the batch's kernels,
:mod:`tuner.optimize.kernels`; ``nlp/``: the NLPs' compiled code, :mod:`tuner.optimize.nlp.codecache`;
``nlp-graph/``: their serialized graphs, :mod:`tuner.optimize.nlp.graphcache`). Light: it imports neither numba nor
CasADi.

The root is created private (mode 0o700). Compiled code, serialized graphs and pickled jobs are loaded only from a
root that :func:`trusted_root` accepts (owned by the current user, not writable by group or others): from any other,
the NLP code and graph caches behave as if they were off (:mod:`tuner.optimize.nlp.codecache`,
:mod:`tuner.optimize.nlp.graphcache`), silently, and the tune builds its NLPs and runs them interpreted; the batch's
kernels are neither loaded from it nor compiled into it (a process that asks for them compiles them into a private
folder of its own; the service's and study workers' preload stays on numpy)."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

__all__ = ["cache_root", "trusted_root", "trusted_dir", "private", "kernels_ready_mark"]


def cache_root() -> Path:
    """The tuner's on-disk cache: ``$TUNER_CACHE_DIR``, else ``$XDG_CACHE_HOME/tuner``, else ``~/.cache/tuner``."""
    env = os.environ.get("TUNER_CACHE_DIR", "").strip()
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    return (Path(xdg) if xdg else Path.home() / ".cache") / "tuner"


def trusted_root() -> Path | None:
    """:func:`cache_root`, created with mode 0o700 if it is not there, if it is safe to load code from: a directory
    owned by the current user and not writable by group or others. None otherwise (or if it cannot be created):
    then nothing compiled or pickled is loaded from it."""
    return trusted_dir(cache_root())


def trusted_dir(path: Path | str) -> Path | None:
    """``path`` (created with mode 0o700 if it is not there) if it is a directory of this user's that no one else can
    write (:func:`private`), else None (also where it cannot be created)."""
    path = Path(path)
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
        st = path.stat()
    except OSError:
        return None
    return path if private(st) else None


def private(st: os.stat_result, *, regular: bool = False) -> bool:
    """``st`` (a directory's, or ``regular``: a regular file's) is owned by the current user and not writable by group
    or others: safe to load code from."""
    import stat

    kind = stat.S_ISREG if regular else stat.S_ISDIR
    return bool(kind(st.st_mode)) and not st.st_mode & 0o022 and \
        (not hasattr(os, "getuid") or st.st_uid == os.getuid())


def kernels_ready_mark() -> Path:
    """The file that says the kernels of this source of :mod:`tuner.optimize.kernels` are compiled in the cache
    (written by :func:`tuner.optimize.kernels.warm` when every kernel compiled)."""
    src = (Path(__file__).parent / "kernels.py").read_bytes()
    return cache_root() / "numba" / f"ready-{hashlib.sha256(src).hexdigest()[:16]}"
