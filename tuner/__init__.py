"""tuner: optimisation-based controller tuning with an independent verifier.

The public surface is ``__all__``: build a plant (:func:`make_plant`, :func:`plant_from_expr`),
state what "good" means (:class:`Spec`), then :func:`tune` a structure or :func:`analyze` a given
controller; from flight data, :func:`identify` the plant first. Everything returned has been checked
by the verifier (:mod:`tuner.analysis`). python-control models go in and come out (:mod:`tuner.interop`:
``tune(control.tf(...))``, ``result.to_control()``, ``result.loop_tfs()``); :func:`export_controller` writes
the controller as C99, Python or its difference equation (:mod:`tuner.export`). ``STRUCTURES`` maps each
controller structure's name to its definition (:func:`get_structure`); ``__version__`` is the installed version.

Examples
--------
>>> import control
>>> import tuner
>>> a = tuner.analyze(control.tf([1], [1, 1]), control.tf([2, 2], [1, 0]))
>>> a.meets_spec
True
>>> "pid" in tuner.STRUCTURES
True
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

# Lazy: ``import tuner`` (and ``tuner --help``) costs nothing until a name is used; each name comes from
# its module on first access (PEP 562), so ``tuner analyze`` never imports CasADi, Optuna or pydantic-heavy
# service code, and ``tuner.tune`` imports the search only when called for.
_EXPORTS = {
    "analysis": ("Analysis", "Metrics", "analyze"),
    "controllers": ("STRUCTURES", "ControllerTF", "controller_from_coeffs", "controller_from_expr", "controller_tf",
                    "get_structure"),
    "export": ("export_controller",),  # the package tuner.export (lazy); the name is the function
    "errors": ("IdentificationError", "InvalidControllerError", "InvalidDataError", "InvalidExpressionError",
               "InvalidPlantError", "InvalidSpecError", "TunerError"),
    "identify": ("IdentifyResult", "identify"),  # the package tuner.identify; the name is the function
    "interop": ("LoopTFs", "controller_from_control", "plant_from_control"),
    "jsonio": ("jsonable",),
    "plant": ("Plant", "make_plant", "plant_from_expr"),
    "problem": ("TuningProblem",),
    "spec": ("Check", "Spec"),
    "tuning": ("TuneResult", "tune"),
}
_WHERE = {name: mod for mod, names in _EXPORTS.items() for name in names}

if TYPE_CHECKING:  # for type checkers and IDEs: the eager form
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
    from .export import export_controller
    from .identify import IdentifyResult, identify
    from .interop import LoopTFs, controller_from_control, plant_from_control
    from .jsonio import jsonable
    from .plant import Plant, make_plant, plant_from_expr
    from .problem import TuningProblem
    from .spec import Check, Spec
    from .tuning import TuneResult, tune

__all__ = [
    "tune", "TuneResult", "TuningProblem", "analyze", "Analysis", "Metrics", "Spec", "Check",
    "Plant", "make_plant", "plant_from_expr", "ControllerTF", "controller_tf", "controller_from_expr",
    "controller_from_coeffs", "get_structure", "STRUCTURES", "jsonable",
    "identify", "IdentifyResult", "export_controller", "plant_from_control", "controller_from_control", "LoopTFs",
    "TunerError", "InvalidControllerError", "InvalidDataError", "InvalidExpressionError", "InvalidPlantError",
    "InvalidSpecError", "IdentificationError", "__version__",
]



def __getattr__(name: str) -> Any:
    mod = _WHERE.get(name)
    if mod is None:
        if name == "__version__":
            from ._lazy import installed_version

            value: Any = installed_version("0+unknown")
            globals()[name] = value
            return value
        raise AttributeError(f"module 'tuner' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{mod}", __name__), name)
    if name != "identify":  # see _Package: the function must win over the subpackage of the same name
        globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    """``tuner.identify`` is the function (the subpackage of that name stays in ``sys.modules``): the import
    system's ``setattr(tuner, "identify", <module>)`` after loading the subpackage is not kept."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name == "identify" and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)

    def __getattribute__(self, name: str) -> Any:
        if name == "identify":
            return importlib.import_module("tuner.identify").identify
        return super().__getattribute__(name)


sys.modules[__name__].__class__ = _Package
