"""One place where a route runs a job in the solver pool and maps the pool's outcomes to answers.

:func:`run_job` awaits the job (cancelled if the client goes away, :mod:`api.disconnect`) and maps:

* :class:`~api.pool.JobTimeout` -> 504 with the route's own message (``timeout_detail``);
* the library's "nothing verified within the budget" (a :class:`~tuner.errors.TunerError` marked
  ``timeout``) -> 504 with ``budget_detail``, when the route gives one;
* any other :class:`~tuner.errors.TunerError` -> 422 at the body's place of its ``field``
  (``loc``; ``default_field`` when the library named none), typed by ``type_of``;
* anything else that failed in the job -> 500 (``internal_message``; the traceback is logged).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from fastapi import HTTPException

from .convert import FieldError
from .disconnect import unless_disconnected
from .errors import internal_message
from .pool import JobFailed, JobTimeout, WorkerPool

__all__ = ["run_job"]


async def run_job(request: Any, pool: WorkerPool, job: Callable[[Any], Any], payload: Any, *, timeout_s: float,
                  client: str, what: str, timeout_detail: Callable[[JobTimeout], str],
                  loc: Callable[[Sequence[str | int]], tuple[str | int, ...]],
                  default_field: tuple[str | int, ...] = (),
                  type_of: Callable[[dict[str, Any]], str] = lambda info: "tuner_error",
                  budget_detail: Callable[[dict[str, Any]], str] | None = None) -> Any:
    """The job's result, or the HTTP error its failure means (see the module's docstring)."""
    try:
        return await unless_disconnected(request, pool.run(job, payload, timeout_s=timeout_s, client=client))
    except JobTimeout as e:
        raise HTTPException(504, timeout_detail(e)) from None
    except JobFailed as e:
        if e.kind == "tuner_error" and budget_detail is not None and e.info.get("timeout"):
            raise HTTPException(504, budget_detail(e.info)) from None
        if e.kind == "tuner_error":
            raise FieldError(loc(tuple(e.info.get("field") or default_field)), e.info["message"],
                             type=type_of(e.info)) from None
        raise HTTPException(500, internal_message(e.info, what)) from None
