"""Test configuration of the foundation suite.

The independent reference computations live in ``tests/reference.py`` (numpy/scipy only,
no ``tuner`` import) and the thesis data in ``tests/quadrotor.py``; this makes both
importable whatever pytest's import mode.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(__file__))

# FastAPI's TestClient sends ``Host: testserver``: serve it too (the service's default is loopback only,
# api.guard). Servers started as processes (tests/uvicorn_server.py) drop TUNER_* and keep the default.
os.environ.setdefault("TUNER_ALLOWED_HOSTS", "127.0.0.1,localhost,::1,testserver")


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
