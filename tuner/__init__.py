"""tuner: optimisation-based controller tuning with an independent verifier."""

from __future__ import annotations

from .analysis.verify import Analysis, Metrics, analyze, jsonable
from .controllers import STRUCTURES, ControllerTF, controller_from_expr, controller_tf, get_structure
from .errors import (
    InvalidControllerError,
    InvalidExpressionError,
    InvalidPlantError,
    InvalidSpecError,
    TunerError,
)
from .plant import Plant, make_plant, plant_from_expr
from .spec import Spec

__all__ = [
    "Analysis", "Metrics", "analyze", "jsonable", "STRUCTURES", "ControllerTF", "controller_from_expr",
    "controller_tf", "get_structure", "TunerError", "InvalidControllerError", "InvalidExpressionError",
    "InvalidPlantError", "InvalidSpecError", "Plant", "make_plant", "plant_from_expr", "Spec", "tune",
]

__version__ = "0.1.0"


def __getattr__(name: str):  # lazy: the tuning stack (CasADi, Optuna) is heavy to import
    if name == "tune":
        from .tuning import tune

        return tune
    raise AttributeError(name)
