"""Compatibility: the default design limits on a structure's parameters live in :mod:`tuner.rules` (a bottom
layer, so that :mod:`tuner.problem` uses them without importing :mod:`tuner.optimize`); this name re-exports them."""

from ..rules import *  # noqa: F403
from ..rules import __all__  # noqa: F401
