"""Test configuration of the foundation suite.

The independent reference computations live in ``tests/reference.py`` (numpy/scipy only,
no ``tuner`` import) and the thesis data in ``tests/quadrotor.py``; this makes both
importable whatever pytest's import mode.
"""

from __future__ import annotations

import os
import sys

import pytest

sys.path.insert(0, os.path.dirname(__file__))

# FastAPI's TestClient sends ``Host: testserver``: serve it too (the service's default is loopback only,
# api.guard). Servers started as processes (tests/uvicorn_server.py) drop TUNER_* and keep the default, but for
# TUNER_NLP_COMPILE (no background gcc from a test's server).
os.environ.setdefault("TUNER_ALLOWED_HOSTS", "127.0.0.1,localhost,::1,testserver")
# One OpenBLAS thread per process, as tune() already runs its solve (tuner.tuning._one_thread): the suite's matrices
# are small, and with -n 2 each worker's pool of 2 threads spins on the 2 cores the other worker needs (the fast lane
# at -n 2: 111 -> 84 s of wall, 182 -> 132 s of CPU; the analyze --identified sweep alone 1.6-1.9x). Subprocesses
# inherit it; a value set beforehand is kept
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# The NLPs' compiled-code cache (tuner.optimize.nlp.codecache) would start a background gcc for every problem shape
# the suite builds: off here (tests/tuner/test_codecache.py turns it on in its own cache folder)
os.environ.setdefault("TUNER_NLP_COMPILE", "off")
# The NLPs' stored graphs (tuner.optimize.nlp.graphcache): off, so that every test builds what it uses, as in a fresh
# machine (tests/tuner/test_graphcache.py turns them on in its own cache folder)
os.environ.setdefault("TUNER_NLP_GRAPHS", "off")


def pytest_runtest_makereport(item, call):
    """In CI (``CI`` set, as ``.ci/run`` does) a skipped test is a failure: CI has every dependency (gcc,
    PostgreSQL, Chromium), so a skip there means a check silently did not run."""
    if call.when != "setup" and call.when != "call":
        return None
    if os.environ.get("CI", "").lower() not in ("1", "true", "yes") or call.excinfo is None:
        return None
    import pytest

    if call.excinfo.errisinstance(pytest.skip.Exception) and not hasattr(call.excinfo.value, "wasxfail"):
        from _pytest.reports import TestReport

        rep = TestReport.from_item_and_call(item, call)
        rep.outcome = "failed"
        rep.longrepr = f"skipped in CI, which is a failure (CI has every dependency): {rep.longrepr}"
        return rep
    return None


# A test that does not finish within its timeout (pytest-timeout: ``timeout`` in pyproject.toml, or its
# ``@pytest.mark.timeout``) is stuck. pytest-timeout's own "thread" method ends the xdist worker with ``os._exit``,
# but xdist notices a dead worker only when the worker's end of their pipe closes, and a process the test forked
# (not exec'd: a study worker, a pool's child) holds a copy of that pipe: the run would stall for as long as that
# child lives, which for a child blocked on its queue is for good. So, on expiry: every thread's stack to the
# stream that reaches the run's output (pytest's faulthandler keeps it open past the capture), every process
# descended from this one killed, then the worker ended; xdist reports the test as failed and starts a new worker.
_STUCK_TIMER = pytest.StashKey()


def pytest_timeout_set_timer(item, settings):
    if settings.timeout <= 0:
        return None
    import threading

    timer = threading.Timer(settings.timeout, _stuck, args=(item, settings.timeout))
    timer.name = f"stuck-test-timer {item.nodeid}"
    timer.daemon = True
    item.stash[_STUCK_TIMER] = timer
    timer.start()
    return True


def pytest_timeout_cancel_timer(item):
    timer = item.stash.get(_STUCK_TIMER, None)
    if timer is not None:
        timer.cancel()
        timer.join()
    return True


def _descendants(pid: int) -> list[int]:
    """Every live process below ``pid`` (children first found, then theirs), from /proc."""
    parent: dict[int, int] = {}
    for name in os.listdir("/proc"):
        if name.isdigit():
            try:
                with open(f"/proc/{name}/stat") as f:
                    parent[int(name)] = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue  # gone meanwhile
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        kids = [c for c, pp in parent.items() if pp == p]
        out += kids
        todo += kids
    return out


def _stuck(item, timeout: float) -> None:
    import faulthandler
    import signal

    try:
        from _pytest.faulthandler import fault_handler_stderr_fd_key

        fd = item.config.stash[fault_handler_stderr_fd_key]
    except (ImportError, KeyError):
        fd = 2
    kids = _descendants(os.getpid())
    try:
        head = (f"{item.nodeid} did not finish in {timeout:g} s: it is stuck; every thread's stack, then the "
                f"{len(kids)} process(es) it started and its worker are killed")
        os.write(fd, f"\n{'+' * 30} {head} {'+' * 30}\n".encode())
        faulthandler.dump_traceback(file=fd, all_threads=True)
    except OSError:
        pass
    for k in kids:
        try:
            os.kill(k, signal.SIGKILL)
        except OSError:
            pass
    os._exit(1)
