"""Compatibility: the plant-based design helpers live in :mod:`tuner.design` (a bottom layer, so that
:mod:`tuner.problem` uses them without importing :mod:`tuner.optimize`); this name re-exports them."""

from ..design import *  # noqa: F403
from ..design import PID2_START_B, PID2_START_C, START_GM_DB, START_PM_DEG, __all__  # noqa: F401
