"""A bounded pool of solver processes with hard time limits.

Why not :class:`concurrent.futures.ProcessPoolExecutor`: it cannot stop one running
task, and one dead worker breaks the whole executor. Here every worker is a
process of its own with a pipe:

* **Admission.** At most ``size + queue_size`` jobs are admitted at once (running
  or waiting for a worker). Beyond that, and when no worker frees up within
  ``queue_timeout_s``, :class:`PoolBusy` is raised at once (the route answers
  503 with ``Retry-After``). Nothing waits without bound.
* **Hard limit.** A job runs with a timeout; past it the worker process is
  killed (``SIGKILL``: a runaway solve really stops, whatever it is doing) and a
  fresh one is started. :class:`JobTimeout` is raised.
* **Memory.** Each worker's address space is capped (``memory_mb``): a solve that
  would exhaust the machine fails with ``MemoryError`` in its own process instead.
  A worker whose job raised anything but a library error is replaced.
* **Crashes.** A worker that dies mid-job (segfault, ``os._exit``, OOM kill)
  raises :class:`WorkerCrashed` for that job only; a replacement is started and
  the next job is served.
* **Warm start.** Workers are forked from a forkserver that has imported the tuning
  stack once (``api._preload``), so a replacement is ready in milliseconds; a worker
  reports ready only when warm, so no job's clock pays for imports. (Where there is no
  forkserver, ``spawn`` is used and each worker imports the stack itself.)

The event loop never blocks: waiting on a pipe happens in a small thread pool,
with ``poll(timeout)`` so no thread waits longer than its job's limit.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import math
import multiprocessing
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Any

from .worker import worker_main

__all__ = ["WorkerPool", "PoolBusy", "PoolClosed", "JobTimeout", "WorkerCrashed", "JobFailed"]

log = logging.getLogger("api.pool")


class PoolBusy(Exception):
    """Every worker is busy and the queue is full (or the wait for a worker timed out)."""

    def __init__(self, message: str, *, retry_after_s: int) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s


class PoolClosed(Exception):
    """The pool is shutting down."""


class JobTimeout(Exception):
    """The job overran its limit; its worker was killed."""

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
class _Worker:
    process: Any
    conn: Connection
    started: float = field(default_factory=time.monotonic)
    tasks: int = 0
    deadline: float | None = None  # monotonic time the running job will be stopped at

    @property
    def pid(self) -> int | None:
        return self.process.pid


def _recv(conn: Connection, timeout: float) -> Any:
    """Next message, or TimeoutError; EOFError/OSError when the process died."""
    if conn.poll(max(0.0, timeout)):
        return conn.recv()
    raise TimeoutError


class WorkerPool:
    """``size`` worker processes; see the module docstring."""

    def __init__(
        self,
        *,
        size: int,
        queue_size: int,
        queue_timeout_s: float = 30.0,
        start_timeout_s: float = 120.0,
        max_tasks_per_worker: int | None = None,
        start_method: str = "forkserver",
        warm: bool = True,
        memory_mb: int | None = None,
    ) -> None:
        if size < 1:
            raise ValueError(f"size must be >= 1, got {size}")
        self.size = size
        self.queue_size = max(0, queue_size)
        self.queue_timeout_s = queue_timeout_s
        self.start_timeout_s = start_timeout_s
        self.max_tasks_per_worker = max_tasks_per_worker
        if start_method == "forkserver" and "forkserver" not in multiprocessing.get_all_start_methods():
            start_method = "spawn"  # pragma: no cover - not on this platform
        self._ctx = multiprocessing.get_context(start_method)
        if start_method == "forkserver":
            # the forkserver imports the tuning stack once; every solver is then forked from it, warm
            self._ctx.set_forkserver_preload(["api._preload"])
        self._warm = warm
        self._memory_mb = memory_mb
        self._idle: collections.deque[_Worker] = collections.deque()
        self._busy: set[_Worker] = set()
        self._n_starting = 0  # processes being started or warming up
        self._procs: set[Any] = set()  # every process started and not yet reaped
        self._lock = threading.Lock()  # guards _procs and _closed against the starting threads
        self._waiters: collections.deque[asyncio.Future[_Worker]] = collections.deque()
        self._admitted = 0
        self._closed = False
        self._tasks: set[asyncio.Task[Any]] = set()
        self._threads = ThreadPoolExecutor(max_workers=2 * size + 2, thread_name_prefix="pool-io")
        self.crashes = 0
        self.timeouts = 0

    # -- life cycle ---------------------------------------------------------------------

    async def start(self) -> None:
        for _ in range(self.size):
            self._spawn()

    async def wait_ready(self, timeout: float | None = None) -> bool:
        """Wait until every worker is up (for tests and warm start); True if they are."""
        end = None if timeout is None else time.monotonic() + timeout
        while len(self._idle) + len(self._busy) < self.size:
            if end is not None and time.monotonic() > end:
                return False
            await asyncio.sleep(0.05)
        return True

    async def close(self) -> None:
        """Stop every solver process (idle ones exit cleanly; anything still running is killed)."""
        with self._lock:
            self._closed = True
            procs = list(self._procs)
        for fut in self._waiters:
            if not fut.done():
                fut.set_exception(PoolClosed("the service is shutting down"))
        self._waiters.clear()
        for t in list(self._tasks):
            t.cancel()
        for w in [*self._idle, *self._busy]:
            try:
                w.conn.send(None)
            except (OSError, ValueError):
                pass
        self._idle.clear()
        loop = asyncio.get_running_loop()
        await loop.run_in_executor(self._threads, self._join_all, procs)
        self._threads.shutdown(wait=False, cancel_futures=True)

    @staticmethod
    def _join_all(procs: list[Any]) -> None:
        end = time.monotonic() + 2.0
        for p in procs:
            p.join(max(0.0, end - time.monotonic()))
        for p in procs:
            if p.is_alive():
                p.kill()
                p.join(5)

    def stats(self) -> dict[str, Any]:
        return {
            "size": self.size,
            "ready": len(self._idle),
            "busy": len(self._busy),
            "starting": self._n_starting,
            "waiting": len(self._waiters),
            "queue_size": self.queue_size,
            "crashes": self.crashes,
            "timeouts": self.timeouts,
        }

    def pids(self) -> list[int]:
        return [w.pid for w in [*self._idle, *self._busy] if w.pid is not None]

    # -- running jobs -------------------------------------------------------------------

    async def run(self, fn: Callable[[Any], Any], payload: Any, *, timeout_s: float) -> Any:
        """Run ``fn(payload)`` in a worker; the worker is killed if it takes longer than ``timeout_s``.

        ``fn`` must be a module-level function (it is pickled by reference).
        Raises :class:`PoolBusy`, :class:`JobTimeout`, :class:`WorkerCrashed`,
        :class:`JobFailed` or :class:`PoolClosed`.
        """
        if self._closed:
            raise PoolClosed("the service is shutting down")
        if self._admitted >= self.size + self.queue_size:
            raise PoolBusy(
                f"all {self.size} solver processes are busy and the queue ({self.queue_size}) is full",
                retry_after_s=self.retry_after_s(),
            )
        self._admitted += 1
        try:
            worker = await self._acquire()
            return await self._run_on(worker, fn, payload, timeout_s)
        finally:
            self._admitted -= 1

    def retry_after_s(self) -> int:
        """An estimate of when a worker frees up: the earliest running job's limit (1..60 s)."""
        now = time.monotonic()
        ends = [w.deadline - now for w in self._busy if w.deadline is not None]
        est = min(ends) if ends else 1.0
        return int(min(60, max(1, math.ceil(est))))

    async def _acquire(self) -> _Worker:
        while True:
            worker = await self._next_worker()
            if worker.process.is_alive():
                return worker
            log.error("solver process %s died while idle (exit code %s); replacing it", worker.pid,
                      worker.process.exitcode)
            self.crashes += 1
            self._kill(worker)
            self._spawn()

    async def _next_worker(self) -> _Worker:
        if self._idle:
            return self._idle.popleft()
        loop = asyncio.get_running_loop()
        fut: asyncio.Future[_Worker] = loop.create_future()
        self._waiters.append(fut)
        try:
            await asyncio.wait({fut}, timeout=self.queue_timeout_s)
        except asyncio.CancelledError:
            self._drop_waiter(fut)
            raise
        if fut.done():
            return fut.result()  # PoolClosed is raised here
        self._drop_waiter(fut)
        raise PoolBusy(
            f"no solver process became free within {self.queue_timeout_s:g} s",
            retry_after_s=self.retry_after_s(),
        )

    def _drop_waiter(self, fut: asyncio.Future[_Worker]) -> None:
        if fut.done() and not fut.cancelled() and fut.exception() is None:
            self._release(fut.result())  # it was handed a worker just as it gave up
        else:
            fut.cancel()
        try:
            self._waiters.remove(fut)
        except ValueError:
            pass

    def _release(self, worker: _Worker) -> None:
        """Hand a ready worker to the first waiter, else park it."""
        if self._closed:
            self._retire(worker)
            return
        while self._waiters:
            fut = self._waiters.popleft()
            if not fut.done():
                fut.set_result(worker)
                return
        self._idle.append(worker)

    async def _run_on(self, worker: _Worker, fn: Callable[[Any], Any], payload: Any, timeout_s: float) -> Any:
        loop = asyncio.get_running_loop()
        self._busy.add(worker)
        worker.deadline = time.monotonic() + timeout_s
        ok = False
        try:
            try:
                worker.conn.send((fn, payload))
            except (OSError, ValueError) as e:  # died while idle
                raise WorkerCrashed("the solver process was gone") from e
            try:
                kind, value = await loop.run_in_executor(self._threads, _recv, worker.conn, timeout_s)
            except TimeoutError:
                self.timeouts += 1
                log.warning("solver process %s overran its limit of %.3g s; killed", worker.pid, timeout_s)
                raise JobTimeout(timeout_s) from None
            except (EOFError, OSError) as e:
                self.crashes += 1
                log.error("solver process %s died during a job (exit code %s)", worker.pid, worker.process.exitcode)
                raise WorkerCrashed("the solver process died while running the job") from e
            ok = True
        finally:
            self._busy.discard(worker)
            worker.deadline = None
            if ok:
                worker.tasks += 1
                # after an unexpected error (e.g. MemoryError) the process may be unhealthy: replace it
                if kind == "error" or (self.max_tasks_per_worker and worker.tasks >= self.max_tasks_per_worker):
                    self._retire(worker)
                    self._spawn()
                else:
                    self._release(worker)
            else:  # timed out, crashed or cancelled: the process may still be running the job
                self._kill(worker)
                if not self._closed:
                    self._spawn()
        if kind == "ok":
            return value
        raise JobFailed(kind, value)

    # -- processes ----------------------------------------------------------------------

    def _spawn(self) -> None:
        """Start a replacement in the background; it joins the idle set once warm."""
        self._n_starting += 1
        self._background(self._start_worker())

    def _start_process(self) -> _Worker:
        """Blocking (the first start waits for the forkserver's imports): runs in a thread."""
        t0 = time.monotonic()
        parent, child = self._ctx.Pipe(duplex=True)
        proc = self._ctx.Process(target=worker_main, args=(child, self._warm, self._memory_mb), daemon=True,
                                 name="tuner-solver")
        try:
            proc.start()
        finally:
            child.close()
        with self._lock:
            self._procs.add(proc)
            closed = self._closed
        if closed:  # the pool closed while this one was starting
            proc.kill()
        return _Worker(process=proc, conn=parent, started=t0)

    async def _start_worker(self, attempt: int = 0) -> None:
        loop = asyncio.get_running_loop()
        worker: _Worker | None = None
        ready = False
        try:
            worker = await loop.run_in_executor(self._threads, self._start_process)
            msg = await loop.run_in_executor(self._threads, _recv, worker.conn, self.start_timeout_s)
            ready = isinstance(msg, tuple) and msg[0] == "ready"
        except (TimeoutError, EOFError, OSError) as e:
            log.error("a solver process failed to start: %r", e)
        finally:
            self._n_starting -= 1
        if worker is not None and (self._closed or not ready):
            self._kill(worker)
        if self._closed:
            return
        if ready:
            log.info("solver process %s ready in %.2f s", worker.pid, time.monotonic() - worker.started)
            self._release(worker)
            return
        await asyncio.sleep(min(30.0, 0.5 * 2 ** attempt))  # back off, then try again
        if not self._closed:
            self._n_starting += 1
            self._background(self._start_worker(attempt + 1))

    def _kill(self, worker: _Worker) -> None:
        try:
            worker.process.kill()
        except (OSError, ValueError, AttributeError):
            pass
        self._background(self._reap(worker))

    def _retire(self, worker: _Worker) -> None:
        try:
            worker.conn.send(None)
        except (OSError, ValueError):
            pass
        self._background(self._reap(worker, grace_s=5.0))

    async def _reap(self, worker: _Worker, grace_s: float = 0.0) -> None:
        loop = asyncio.get_running_loop()

        def join() -> None:
            worker.process.join(grace_s or 5.0)
            if worker.process.is_alive():
                worker.process.kill()
                worker.process.join(5.0)
            worker.conn.close()
            with self._lock:
                self._procs.discard(worker.process)

        try:
            await loop.run_in_executor(self._threads, join)
        except RuntimeError:  # executor shut down
            join()

    def _background(self, coro: Any) -> None:
        task = asyncio.get_running_loop().create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
