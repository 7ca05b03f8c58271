"""Helpers for worker processes (study workers, and the service's solvers in :mod:`api.worker`)."""

from __future__ import annotations

import logging
import os
import signal
import sys

__all__ = ["set_parent_death_signal"]

log = logging.getLogger(__name__)

_PR_SET_PDEATHSIG = 1


def set_parent_death_signal() -> bool:
    """``prctl(PR_SET_PDEATHSIG, SIGKILL)``: the kernel kills this process when the thread that
    forked it ends (Linux only; False where it is not available)."""
    if not sys.platform.startswith("linux"):
        return False  # pragma: no cover
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
    except (OSError, AttributeError) as e:  # pragma: no cover - no prctl
        log.warning("process %d: %s", os.getpid(), e)
        return False
    return True
