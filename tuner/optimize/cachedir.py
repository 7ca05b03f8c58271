"""Where the tuner keeps what it compiles, shared by the command line, the service and the study workers:
``$TUNER_CACHE_DIR``, else ``$XDG_CACHE_HOME/tuner``, else ``~/.cache/tuner`` (``numba/``: the batch's kernels,
:mod:`tuner.optimize.kernels`; ``nlp/``: the NLPs' compiled code, :mod:`tuner.optimize.nlp.codecache`). Light: it
imports neither numba nor CasADi."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

__all__ = ["cache_root", "kernels_ready_mark"]


def cache_root() -> Path:
    """The tuner's on-disk cache: ``$TUNER_CACHE_DIR``, else ``$XDG_CACHE_HOME/tuner``, else ``~/.cache/tuner``."""
    env = os.environ.get("TUNER_CACHE_DIR", "").strip()
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    return (Path(xdg) if xdg else Path.home() / ".cache") / "tuner"


def kernels_ready_mark() -> Path:
    """The file that says the kernels of this source of :mod:`tuner.optimize.kernels` are compiled in the cache
    (written by :func:`tuner.optimize.kernels.warm` when every kernel compiled)."""
    src = (Path(__file__).parent / "kernels.py").read_bytes()
    return cache_root() / "numba" / f"ready-{hashlib.sha256(src).hexdigest()[:16]}"
