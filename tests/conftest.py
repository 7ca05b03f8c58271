"""Test configuration of the foundation suite.

The independent reference computations live in ``tests/reference.py`` (numpy/scipy only,
no ``tuner`` import) and the thesis data in ``tests/quadrotor.py``; this makes both
importable whatever pytest's import mode.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(__file__))
