"""The solver process: receives ``(fn, payload)``, answers ``(kind, value)``.

``kind`` is ``"ok"`` (``value`` = what ``fn`` returned), ``"tuner_error"`` (the
library rejected the input: ``value`` = ``{"error", "message"}``) or ``"error"``
(anything else: ``value`` = ``{"error", "message"}``, the traceback goes to this
process's log, never to a client). Importing this module is cheap: the parent
imports it to name the process target.
"""

from __future__ import annotations

import logging
import os
import signal
from multiprocessing.connection import Connection
from typing import Any

__all__ = ["worker_main", "warm_up"]

log = logging.getLogger("api.worker")

_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")


def warm_up() -> None:
    """Import the tuning stack now, so that no job's time budget pays for it."""
    import importlib

    for mod in ("tuner.tuning", "tuner.optimize.search", "tuner.optimize.nlp.refine", "scipy.signal",
                "scipy.optimize", "api.jobs"):  # scipy.signal/optimize: what identification imports
        try:
            importlib.import_module(mod)
        except ImportError as e:  # optional parts: a job that needs them reports the error itself
            log.debug("warm-up: %s not imported: %s", mod, e)


def _cap_memory(memory_mb: int) -> None:
    try:
        import resource

        limit = memory_mb * 1024 * 1024
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        if hard != resource.RLIM_INFINITY:
            limit = min(limit, hard)
        resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    except (ImportError, ValueError, OSError) as e:  # pragma: no cover - platform without it
        log.warning("could not cap the solver's memory: %s", e)


def worker_main(conn: Connection, warm: bool = True, memory_mb: int | None = None) -> None:
    for var in _THREAD_VARS:  # one solve = one core; parallelism comes from the pool
        os.environ.setdefault(var, "1")
    if memory_mb:
        _cap_memory(memory_mb)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when we stop
    if warm:
        warm_up()  # already done by the forkserver's preload: then this is instant
    from tuner.errors import TunerError

    conn.send(("ready", os.getpid()))
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        except Exception as e:
            log.exception("could not read a job")
            conn.send(("error", {"error": type(e).__name__, "message": str(e)}))
            continue
        if msg is None:
            return
        fn, payload = msg
        try:
            out: tuple[str, Any] = ("ok", fn(payload))
        except TunerError as e:
            out = ("tuner_error", {"error": type(e).__name__, "message": str(e), "field": list(e.field)})
        except Exception as e:
            log.exception("job %s failed", getattr(fn, "__name__", fn))
            out = ("error", {"error": type(e).__name__, "message": str(e)})
        try:
            conn.send(out)
        except (EOFError, OSError):
            return
