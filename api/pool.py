"""The solver processes: pebble's :class:`~pebble.ProcessPool`, with admission and fairness in front.

pebble runs each job in a worker process with a per-task ``timeout`` (counted from when a worker
takes the job, so no job pays for a wait or a start): past it the process is stopped
(``SIGTERM``, which :func:`api.worker.init_worker` makes fatal at once) and replaced, so a runaway
solve really stops, whatever it is doing. A worker that dies mid-job fails that job only
(``ProcessExpired``) and is replaced; ``max_tasks`` recycles workers; the ``initializer`` caps each
worker's memory, pins it to one thread and ties its life to the service's. Workers are forked from
a forkserver that has imported the tuning stack once (``api._preload``), so a replacement is warm
in milliseconds and no job's budget pays for imports (where there is no forkserver, ``spawn`` is
used and each worker imports the stack in its initializer, before it takes a job).

What this module adds on top:

* **Admission.** At most ``size + queue_size`` jobs at once (running or waiting for a solver);
  beyond that, and when no solver frees up within ``queue_timeout_s``: :class:`PoolBusy` (503 with
  ``Retry-After``). Nothing waits without bound. Jobs are handed to pebble only when a solver is
  free, so pebble's own queue stays empty and the wait is ours to bound.
* **Fairness.** One client (see :func:`api.deps.client_id`) holds at most ``max_running_per_client``
  solvers at once (default: all but one, so one client cannot hold every solver); its further
  jobs wait behind other clients' jobs, at most ``max_waiting_per_client`` of them
  (:class:`ClientBusy`, 429 with ``Retry-After``, beyond that).
* **Recovery from a broken pebble pool.** pebble declares its pool broken when a worker dies while
  no job is running (e.g. the kernel's OOM killer took an idle worker; pebble issue #70). No job
  can have been running then, so the pool is rebuilt and the jobs it aborted are resubmitted. A job that
  no solver starts within ``start_timeout_s`` (it was handed over with a solver free; a solver pebble lost
  track of) is resubmitted the same way, on fresh solvers, once, when no other job runs on the pool (a
  rebuild would kill it); otherwise, or if fresh solvers do not start it either, it is refused as when the
  service is full (:class:`PoolBusy`, 503 with ``Retry-After``): nothing waits for a solver without bound.

Exceptions for the routes (mapped in :mod:`api.errors`): :class:`PoolBusy`, :class:`ClientBusy`,
:class:`PoolClosed`, :class:`JobTimeout`, :class:`WorkerCrashed`, :class:`JobFailed`.
"""

from __future__ import annotations

import asyncio
import collections
import itertools
import logging
import math
import multiprocessing
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import BrokenExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass
from typing import Any

from pebble import ProcessExpired, ProcessPool

from .worker import EXIT_OUT_OF_MEMORY, SERVICE_PID_VAR, SOLVER_MODULES, init_worker, run_job

__all__ = ["WorkerPool", "start_forkserver", "PoolBusy", "ClientBusy", "PoolClosed", "JobTimeout", "WorkerCrashed",
           "JobFailed"]

log = logging.getLogger("api.pool")


class PoolBusy(Exception):
    """Every solver is busy and the queue is full (or the wait for a solver timed out)."""

    def __init__(self, message: str, *, retry_after_s: int) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s


class ClientBusy(PoolBusy):
    """This client already has as many jobs waiting as it may (429)."""


class PoolClosed(Exception):
    """The pool is shutting down."""


class JobTimeout(Exception):
    """The job overran its limit; its worker was stopped."""

    def __init__(self, limit_s: float) -> None:
        super().__init__(f"job exceeded {limit_s:g} s")
        self.limit_s = limit_s


class WorkerCrashed(Exception):
    """The worker process died while running the job."""


class JobFailed(Exception):
    """The job raised inside the worker. ``kind`` is ``"tuner_error"`` (bad input) or ``"error"``."""

    def __init__(self, kind: str, info: dict[str, Any]) -> None:
        super().__init__(info.get("message", kind))
        self.kind = kind
        self.info = info


@dataclass(eq=False)
class _Waiter:
    client: str
    future: asyncio.Future[None]


def start_forkserver() -> None:
    """Start the forkserver from this thread (the service's main thread), told to die with this process.

    Its death signal is tied to the thread that starts it (the kernel sends it when that *thread*
    ends), so it is asked for only from the main thread, as under uvicorn. From any other thread
    (an embedding application's, a test client's portal) the forkserver would be killed when that
    thread ends, under the pools still using it; there it simply ends with the process (the
    forkserver exits when its parent's end of the alive pipe closes). A forkserver already running
    is left as it is.
    """
    from multiprocessing import forkserver

    if threading.current_thread() is threading.main_thread():
        os.environ[SERVICE_PID_VAR] = str(os.getpid())  # read by api._preload in the forkserver
    else:
        os.environ.pop(SERVICE_PID_VAR, None)
    try:
        forkserver.ensure_running()
    finally:  # a forkserver relaunched later (from pebble's thread, after a crash) must not tie itself to that thread
        os.environ.pop(SERVICE_PID_VAR, None)


class WorkerPool:
    """``size`` solver processes; see the module docstring."""

    def __init__(
        self,
        *,
        size: int,
        queue_size: int,
        queue_timeout_s: float = 30.0,
        start_timeout_s: float = 120.0,
        max_tasks_per_worker: int | None = None,
        start_method: str = "forkserver",
        warm: bool | tuple[str, ...] = True,
        memory_mb: int | None = None,
        nice: int = 0,
        max_running_per_client: int | None = None,
        max_waiting_per_client: int | None = None,
    ) -> None:
        if size < 1:
            raise ValueError(f"size must be >= 1, got {size}")
        self.size = size
        self.queue_size = max(0, queue_size)
        self.queue_timeout_s = queue_timeout_s
        self.start_timeout_s = start_timeout_s
        self.max_running_per_client = max(1, min(size, max_running_per_client or max(1, size - 1)))
        self.max_waiting_per_client = self.queue_size if max_waiting_per_client is None else max_waiting_per_client
        if start_method == "forkserver" and "forkserver" not in multiprocessing.get_all_start_methods():
            start_method = "spawn"  # pragma: no cover - not on this platform
        self._ctx = multiprocessing.get_context(start_method)
        if start_method == "forkserver":
            # the forkserver imports the tuning stack once; every solver is then forked from it, warm
            self._ctx.set_forkserver_preload(["api._preload"])
        modules = SOLVER_MODULES if warm is True else (warm or ())
        self._pebble_kwargs = {"max_workers": size, "max_tasks": max_tasks_per_worker or 0,
                               "initializer": init_worker, "initargs": (os.getpid(), memory_mb, modules, nice),
                               "context": self._ctx}
        self._pebble: ProcessPool | None = None
        self._rebuilding: asyncio.Lock | None = None
        self._monitor: asyncio.Task[None] | None = None
        self._free = size  # solvers not handed a job
        self._running: collections.Counter[str] = collections.Counter()  # solvers held, per client
        self._waiting: collections.Counter[str] = collections.Counter()
        self._waiters: collections.deque[_Waiter] = collections.deque()
        self._deadlines: dict[int, tuple[str, float]] = {}  # running job -> (client, monotonic end)
        self._inflight: dict[Any, ProcessPool] = {}  # pebble futures -> the pool each was handed to
        self._keys = itertools.count()
        self._admitted = 0
        self._closed = False
        self.crashes = 0
        self.timeouts = 0
        self.rebuilds = 0

    # -- life cycle ---------------------------------------------------------------------

    async def start(self) -> None:
        """Start the solver processes (in a thread: the first fork waits for the forkserver's imports)."""
        if self._ctx.get_start_method() == "forkserver":
            start_forkserver()
        self._rebuilding = asyncio.Lock()
        self._pebble = await asyncio.wait_for(asyncio.to_thread(self._new_pebble), self.start_timeout_s)
        self._monitor = asyncio.get_running_loop().create_task(self._watch())

    def _new_pebble(self) -> ProcessPool:
        pool = ProcessPool(**self._pebble_kwargs)
        pool.active  # noqa: B018 - starts pebble's threads and forks the workers now
        return pool

    async def wait_ready(self, timeout: float | None = None) -> bool:
        """Wait until every worker is up (for tests and warm start); True if they are."""
        end = None if timeout is None else time.monotonic() + timeout
        while self._pebble is None or len(self.pids()) < self.size:
            if end is not None and time.monotonic() > end:
                return False
            await asyncio.sleep(0.05)
        return True

    async def close(self) -> None:
        """Stop every solver process (anything still running is killed)."""
        self._closed = True
        for w in self._waiters:
            if not w.future.done():
                w.future.set_exception(PoolClosed("the service is shutting down"))
        self._waiters.clear()
        if self._monitor is not None:
            self._monitor.cancel()
        for f in list(self._inflight):
            f.cancel()
        if self._pebble is not None:
            await asyncio.to_thread(self._stop_pebble, self._pebble)

    @staticmethod
    def _stop_pebble(pool: ProcessPool) -> None:
        pool.stop()
        try:
            pool.join(timeout=10)
        except (RuntimeError, TimeoutError) as e:  # pragma: no cover - pebble could not stop a worker
            log.error("stopping the solver processes: %s", e)

    async def _watch(self) -> None:
        """Rebuild a broken pebble pool before a request finds it broken."""
        while not self._closed:
            await asyncio.sleep(0.25)
            if self._pebble is not None and not self._pebble.active:
                await self._rebuild(self._pebble)

    async def _rebuild(self, broken: ProcessPool, why: str = "a worker died while idle", *,
                       crash: bool = True) -> None:
        assert self._rebuilding is not None
        async with self._rebuilding:
            if self._closed or self._pebble is not broken:
                return  # someone else rebuilt it
            log.error("the solver pool broke (%s); starting fresh solver processes", why)
            self.rebuilds += 1
            self.crashes += crash
            self._pebble = await asyncio.to_thread(self._new_pebble)
        await asyncio.to_thread(self._stop_pebble, broken)

    def _workers(self) -> list[Any]:
        """pebble's live worker processes (its internals: for ``stats`` and ``pids`` only)."""
        manager = getattr(getattr(self._pebble, "_pool_manager", None), "worker_manager", None)
        procs = list(getattr(manager, "workers", {}).values()) if manager is not None else []
        return [p for p in procs if p.is_alive()]

    def pids(self) -> list[int]:
        return [p.pid for p in self._workers() if p.pid is not None]

    def stats(self) -> dict[str, Any]:
        live = len(self._workers())
        busy = self.size - self._free
        return {
            "size": self.size,
            "ready": max(0, live - busy),
            "busy": busy,
            "starting": max(0, self.size - live),
            "waiting": len(self._waiters),
            "queue_size": self.queue_size,
            "max_running_per_client": self.max_running_per_client,
            "crashes": self.crashes,
            "timeouts": self.timeouts,
        }

    # -- admission and fairness ---------------------------------------------------------

    def retry_after_s(self, client: str | None = None) -> int:
        """When a solver (this client's, if given) likely frees up: the earliest running limit (1..60 s)."""
        now = time.monotonic()
        ends = [end - now for c, end in self._deadlines.values() if client is None or c == client]
        est = min(ends) if ends else 1.0
        return int(min(60, max(1, math.ceil(est))))

    def _eligible(self, client: str) -> bool:
        return self._free > 0 and self._running[client] < self.max_running_per_client

    def _grant(self, client: str) -> None:
        self._free -= 1
        self._running[client] += 1

    def _dispatch(self) -> None:
        """Hand free solvers to the first waiters whose client is under its limit."""
        for w in list(self._waiters):
            if self._free == 0:
                return
            if w.future.done():
                self._waiters.remove(w)
            elif self._running[w.client] < self.max_running_per_client:
                self._waiters.remove(w)
                self._grant(w.client)
                w.future.set_result(None)

    def _release(self, client: str) -> None:
        self._free += 1
        self._running[client] -= 1
        if self._running[client] <= 0:
            del self._running[client]
        self._dispatch()

    def would_refuse(self, client: str) -> bool:
        """Whether a job of ``client`` asked for now would get :class:`ClientBusy` (decided before its body is read)."""
        if self._eligible(client) and not any(w.client == client for w in self._waiters):
            return False
        return self._waiting[client] >= self.max_waiting_per_client

    async def _acquire(self, client: str) -> None:
        if self._eligible(client) and not any(w.client == client for w in self._waiters):
            self._grant(client)
            return
        if self._waiting[client] >= self.max_waiting_per_client:
            raise ClientBusy(f"this client already has {self._running[client]} job(s) running and "
                             f"{self._waiting[client]} waiting, the most it may",
                             retry_after_s=self.retry_after_s(client))
        waiter = _Waiter(client, asyncio.get_running_loop().create_future())
        self._waiters.append(waiter)
        self._waiting[client] += 1
        granted = False
        try:
            await asyncio.wait_for(asyncio.shield(waiter.future), self.queue_timeout_s)  # PoolClosed is raised here
            granted = True
        except TimeoutError:
            raise PoolBusy(f"no solver process became free within {self.queue_timeout_s:g} s",
                           retry_after_s=self.retry_after_s()) from None
        finally:
            self._waiting[client] -= 1
            if self._waiting[client] <= 0:
                del self._waiting[client]
            if waiter in self._waiters:
                self._waiters.remove(waiter)
            if not granted:
                f = waiter.future
                if f.done() and not f.cancelled() and f.exception() is None:
                    self._release(client)  # it was handed a solver just as it gave up
                else:
                    f.cancel()

    # -- running jobs -------------------------------------------------------------------

    async def run(self, fn: Callable[[Any], Any], payload: Any, *, timeout_s: float, client: str = "") -> Any:
        """Run ``fn(payload)`` in a solver; the solver is stopped if it takes longer than ``timeout_s``.

        ``fn`` must be a module-level function (it is pickled by reference). ``client`` names who
        asks, for the per-client limits. Raises :class:`PoolBusy`, :class:`ClientBusy`,
        :class:`JobTimeout`, :class:`WorkerCrashed`, :class:`JobFailed` or :class:`PoolClosed`.
        """
        if self._closed or self._pebble is None:
            raise PoolClosed("the service is shutting down")
        if self._admitted >= self.size + self.queue_size:
            raise PoolBusy(f"all {self.size} solver processes are busy and the queue ({self.queue_size}) is full",
                           retry_after_s=self.retry_after_s())
        self._admitted += 1
        try:
            await self._acquire(client)
            try:
                return await self._run_on_solver(fn, payload, timeout_s, client)
            finally:
                self._release(client)
        finally:
            self._admitted -= 1

    async def _run_on_solver(self, fn: Callable[[Any], Any], payload: Any, timeout_s: float, client: str) -> Any:
        for _attempt in range(2):  # a second time only on a pool rebuilt after it broke (the job never ran)
            pool = self._pebble
            if self._closed or pool is None:
                raise PoolClosed("the service is shutting down")
            key = next(self._keys)
            self._deadlines[key] = (client, time.monotonic() + timeout_s)
            try:
                future = pool.schedule(run_job, args=(fn, payload), timeout=timeout_s)
            except RuntimeError:  # pebble's pool is broken or stopped
                self._deadlines.pop(key, None)
                await self._rebuild(pool)
                continue
            self._inflight[future] = pool
            try:
                kind, value = await self._outcome(future)
            except _NotStarted:  # a free solver did not take it: a solver is stuck, not busy
                future.cancel()
                if _attempt or any(p is pool and f.running() for f, p in self._inflight.items()):
                    # other jobs run on this pool (a rebuild would kill them), or fresh solvers did not start it
                    # either: refused, as when the service is full, and nothing else is touched
                    log.error("a job was not started within %.3g s by a free solver; refused", self.start_timeout_s)
                    raise PoolBusy(f"no solver process started the job within {self.start_timeout_s:g} s",
                                   retry_after_s=self.retry_after_s()) from None
                await self._rebuild(pool, f"a job waited {self.start_timeout_s:g} s for a free solver to start "
                                          "it, and no other job ran", crash=False)
                continue
            except FutureTimeout:
                self.timeouts += 1
                log.warning("a solver overran its limit of %.3g s; stopped", timeout_s)
                raise JobTimeout(timeout_s) from None
            except ProcessExpired as e:
                if e.exitcode == EXIT_OUT_OF_MEMORY:
                    raise JobFailed("error", {"error": "MemoryError",
                                              "message": "out of the solver's memory allowance"}) from None
                self.crashes += 1
                log.error("solver process %s died during a job (exit code %s)", e.pid, e.exitcode)
                raise WorkerCrashed("the solver process died while running the job") from e
            except BrokenExecutor:  # the pool broke while no job ran: this one never started
                if self._closed:
                    raise PoolClosed("the service is shutting down") from None
                await self._rebuild(pool)
                continue
            except asyncio.CancelledError:
                future.cancel()  # a running job's worker is stopped by pebble
                raise
            finally:
                self._inflight.pop(future, None)
                self._deadlines.pop(key, None)
            if kind == "ok":
                return value
            raise JobFailed(kind, value)
        raise WorkerCrashed("the solver pool could not be restarted")

    async def _outcome(self, future: Any) -> Any:
        """The job's result (or its exception), once pebble has it. A job is handed to pebble only when a solver is
        free, so it starts at once; one not started within ``start_timeout_s`` (a solver pebble lost track of:
        seen once under load, an idle solver killed and neither replaced nor the pool declared broken) raises
        :class:`_NotStarted` instead of waiting without bound. Once started, pebble's own ``timeout`` bounds it
        (the caller rebuilds a pool only when none of its jobs is running, so no started job loses its pool)."""
        wrapped = asyncio.wrap_future(future)
        done, _ = await asyncio.wait({wrapped}, timeout=self.start_timeout_s)
        if not done and not (future.running() or future.done()):
            raise _NotStarted
        return await wrapped


class _NotStarted(Exception):
    """A job handed to a free solver was not started within the pool's start timeout."""

