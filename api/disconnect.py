"""Stop waiting for a solve whose client has gone away.

A browser's Cancel button (``AbortController``), a closed tab or a ``curl`` stopped with Ctrl-C closes
the connection; without this the route would keep a solver busy until the budget ran out, for an
answer nobody reads. :func:`unless_disconnected` awaits the solve while polling
:meth:`starlette.requests.Request.is_disconnected`; when the client is gone it cancels the awaiting
task (the pool then stops the solver process that ran the job, see :meth:`api.pool.WorkerPool.run`,
or takes the job out of the queue) and raises :class:`ClientDisconnected`, answered with 499
(nginx's "client closed request"; nobody receives it, the access log shows it).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable
from typing import Any, Protocol, TypeVar

__all__ = ["ClientDisconnected", "unless_disconnected", "CLIENT_CLOSED_REQUEST", "POLL_S"]

log = logging.getLogger("api")

T = TypeVar("T")
CLIENT_CLOSED_REQUEST = 499
POLL_S = 0.25  # how often the connection is looked at while a solve runs


class ClientDisconnected(Exception):
    """The client closed the connection before the answer was ready; the work was cancelled."""


class _Request(Protocol):
    async def is_disconnected(self) -> bool: ...

    @property
    def url(self) -> Any: ...


async def unless_disconnected(request: _Request, work: Awaitable[T], *, poll_s: float = POLL_S) -> T:
    """The result of ``work``, unless the client disconnects first: then ``work`` is cancelled (and
    awaited, so its clean-up has run) and :class:`ClientDisconnected` is raised. Errors of ``work``
    propagate as they are."""
    task = asyncio.ensure_future(work)
    try:
        while True:
            done, _ = await asyncio.wait({task}, timeout=poll_s)
            if done:
                return task.result()
            if await request.is_disconnected():
                break
    except BaseException:  # this request's own task was cancelled (server shutdown): take the work with it
        task.cancel()
        raise
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError, Exception):
        await task
    log.info("client went away during %s: its work was cancelled", getattr(request.url, "path", "?"))
    raise ClientDisconnected
