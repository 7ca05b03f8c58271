"""What runs inside a solver process: its set-up (pebble's ``initializer``) and the job wrapper.

:func:`init_worker` runs once in every new solver process, before it takes a job:

* one solve = one core (BLAS/OpenMP thread pools limited to one thread);
* the address space is capped (``RLIMIT_AS``), so a solve that would exhaust the machine fails
  with ``MemoryError`` in its own process;
* ``SIGTERM`` is made fatal at once (pebble's own handler runs Python code, which a solve stuck in
  C code would never reach): a stop at the time limit really stops the process;
* the process dies with the service: ``prctl(PR_SET_PDEATHSIG, SIGKILL)``, so a busy solver is
  killed at once instead of running its job to the end. Its parent is the forkserver, which itself
  has the same death signal towards the service (set by ``api._preload``; the pool starts the
  forkserver from the service's main thread), so a ``kill -9`` of the service takes down the
  forkserver and with it every solver, in the kernel, whatever the solver is doing. (The forkserver
  does not exit by itself: every child it forks holds its "alive" pipe.) Under ``spawn``, where the
  parent is a *thread* of the service that may end, a watchdog thread checks the service's pid
  instead;
* the tuning stack is imported (already done by the forkserver's preload: then this is instant).

:func:`run_job` wraps every job: ``(kind, value)`` with ``kind`` ``"ok"`` (``value`` = what the job
returned), ``"tuner_error"`` (the library rejected the input: ``{"error", "message", "field"}``, and
``"timeout"``: the error is a ``TimeoutError``, nothing verified within the budget) or
``"error"`` (anything else; the traceback goes to this process's log, never to a client). A job that
runs out of memory ends its process with :data:`EXIT_OUT_OF_MEMORY` instead of answering: the process
may be unhealthy after that, and pebble replaces it (the parent reports the cause).
"""

from __future__ import annotations

import logging
import os
import signal
import threading
import time
from collections.abc import Callable
from typing import Any

__all__ = ["init_worker", "run_job", "warm_up", "die_with_parent", "set_parent_death_signal", "EXIT_OUT_OF_MEMORY",
           "SERVICE_PID_VAR", "THREAD_VARS", "SOLVER_MODULES", "PLOT_MODULES"]

log = logging.getLogger("api.worker")

THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")
SERVICE_PID_VAR = "TUNER_SERVICE_PID"  # tells the forkserver (api._preload) whose life to share
EXIT_OUT_OF_MEMORY = 86  # exit status of a solver process whose job ran out of its memory allowance


SOLVER_MODULES = ("tuner.tuning", "tuner.optimize.search", "tuner.optimize.nlp.refine", "scipy.signal",
                  "scipy.optimize", "api.jobs")  # scipy.signal/optimize: what identification imports
PLOT_MODULES = ("tuner.analysis.verify", "api.plots", "matplotlib.figure", "matplotlib.backends.backend_agg",
                "matplotlib.backends.backend_svg")


def warm_up(modules: tuple[str, ...] = SOLVER_MODULES) -> None:
    """Import ``modules`` now, so that no job's time budget pays for it."""
    import importlib

    for mod in modules:
        try:
            importlib.import_module(mod)
        except ImportError as e:  # optional parts: a job that needs them reports the error itself
            log.debug("warm-up: %s not imported: %s", mod, e)


def _cap_memory(memory_mb: int) -> None:
    try:
        import resource

        limit = memory_mb * 1024 * 1024
        _soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        if hard != resource.RLIM_INFINITY:
            limit = min(limit, hard)
        resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    except (ImportError, ValueError, OSError) as e:  # pragma: no cover - platform without it
        log.warning("could not cap the solver's memory: %s", e)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # pragma: no cover - someone else's process now has the pid
        return True
    return True


def set_parent_death_signal() -> bool:
    """:func:`tuner._process.set_parent_death_signal`, imported only when called (importing ``tuner``
    imports numpy, which must come after the thread settings)."""
    from tuner._process import set_parent_death_signal as set_pdeathsig

    return set_pdeathsig()


def die_with_parent(service_pid: int) -> None:
    """Make this solver end when the service does (see the module docstring)."""
    if os.getppid() != service_pid and set_parent_death_signal():  # forked by the forkserver
        if not _alive(service_pid):  # the service died before prctl took effect
            os._exit(1)
        return

    def watchdog() -> None:  # spawn (or no prctl): the parent is a thread of the service, which may end
        while _alive(service_pid):
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watchdog, daemon=True, name="solver-watchdog").start()


def init_worker(service_pid: int, memory_mb: int | None, warm: tuple[str, ...] = SOLVER_MODULES,
                nice: int = 0) -> None:
    """pebble's ``initializer`` of a solver process (see the module docstring).

    ``warm``: modules to import before the first job; ``nice``: a lower CPU priority (plot processes).
    """
    for var in THREAD_VARS:  # one solve = one core; parallelism comes from the pool
        os.environ.setdefault(var, "1")
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the service decides when we stop
    die_with_parent(service_pid)
    if memory_mb:
        _cap_memory(memory_mb)
    if nice:
        os.nice(nice)
    if warm:
        warm_up(warm)
    if not nice:  # a solver (not a plot process): the batch's compiled kernels, where this machine has them
        from tuner.optimize.batch import preload_kernels

        preload_kernels()
    # the NLP build cache within a quarter of the cap: a solver lives for max_tasks_per_worker jobs, each plant
    # bringing problems of its own (the module is already loaded where the forkserver or the warm-up imported the
    # tuning stack)
    if memory_mb:
        from tuner.optimize.nlp import transcribe

        transcribe.CACHE_MB = min(transcribe.CACHE_MB, memory_mb / 4)


def _out_of_memory(e: BaseException) -> bool:
    return isinstance(e, MemoryError) or "bad_alloc" in str(e)


def run_job(fn: Callable[[Any], Any], payload: Any) -> tuple[str, Any]:
    """Run one job in the solver process; see the module docstring for the answer."""
    from tuner.errors import TunerError

    try:
        return "ok", fn(payload)
    except TunerError as e:
        # a library error that is a TimeoutError: the budget ran out before anything could be verified
        return "tuner_error", {"error": type(e).__name__, "message": str(e), "field": list(e.field),
                               "timeout": isinstance(e, TimeoutError)}
    except Exception as e:
        if _out_of_memory(e):
            log.error("job %s ran out of memory (%s); this solver process ends", getattr(fn, "__name__", fn), e)
            os._exit(EXIT_OUT_OF_MEMORY)
        log.exception("job %s failed", getattr(fn, "__name__", fn))
        return "error", {"error": type(e).__name__, "message": str(e)}
