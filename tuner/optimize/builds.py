"""The NLP build clock: seconds a thread has spent building NLPs (:func:`tuner.optimize.nlp.transcribe.get_problem`).

A tune on the default budget (``tune(time_budget_s=None)``) does not count them against its search time: a build is
a one-off cost of the process (the problem is cached), and its size grows with the sample rate and horizon, so a
budget that counted it would stop a 250 Hz loop's search before its first refinement. Kept apart from the NLP
module so that the engine reads it without loading CasADi."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

_CLOCK = threading.local()


def build_seconds() -> float:
    """Seconds this thread has spent in NLP builds (monotone)."""
    return getattr(_CLOCK, "s", 0.0)


@contextmanager
def timed_build() -> Iterator[None]:
    """Count the enclosed build on this thread's clock."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        _CLOCK.s = build_seconds() + (time.perf_counter() - t0)
