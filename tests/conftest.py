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
