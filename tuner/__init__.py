"""tuner: optimisation-based controller tuning with an independent verifier.

The public surface is ``__all__``: build a plant (:func:`make_plant`, :func:`plant_from_expr`),
state what "good" means (:class:`Spec`), then :func:`tune` a structure or :func:`analyze` a given
controller; from flight data, :func:`identify` the plant first. Everything returned has been checked
by the verifier (:mod:`tuner.analysis`).
"""

from __future__ import annotations

from .analysis import Analysis, Metrics, analyze
from .controllers import (
    STRUCTURES,
    ControllerTF,
    controller_from_coeffs,
    controller_from_expr,
    controller_tf,
    get_structure,
)
from .errors import (
    IdentificationError,
    InvalidControllerError,
    InvalidDataError,
    InvalidExpressionError,
    InvalidPlantError,
    InvalidSpecError,
    TunerError,
)
from .identify import IdentifyResult, identify  # the package tuner.identify; the name is the function
from .jsonio import jsonable
from .plant import Plant, make_plant, plant_from_expr
from .problem import TuningProblem
from .spec import Check, Spec
from .tuning import TuneResult, tune

__all__ = [
    "tune", "TuneResult", "TuningProblem", "analyze", "Analysis", "Metrics", "Spec", "Check",
    "Plant", "make_plant", "plant_from_expr", "ControllerTF", "controller_tf", "controller_from_expr",
    "controller_from_coeffs", "get_structure", "STRUCTURES", "jsonable",
    "identify", "IdentifyResult",
    "TunerError", "InvalidControllerError", "InvalidDataError", "InvalidExpressionError", "InvalidPlantError",
    "InvalidSpecError", "IdentificationError", "__version__",
]



def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("tuner")
    except metadata.PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "0+unknown"


__version__ = _version()
