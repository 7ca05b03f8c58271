"""What is exported: a controller, a tune result, or a stored result (the JSON of ``tuner tune --json`` or of
``GET /tunes/{id}``), with the sample time and method for a continuous one."""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from typing import Any

from ..controllers import ControllerTF, controller_from_coeffs
from ..errors import InvalidControllerError
from .codegen import check_name, render
from .discrete import DifferenceEquation, difference_equation

__all__ = ["export_controller", "from_result", "equation_of", "clamp_note", "ExportWarning"]


def from_result(result: Mapping[str, Any]) -> tuple[ControllerTF, str | None, dict[str, float] | None]:
    """The controller of a result dict (``controller: {num, den, dt}``, and ``structure``, ``gains`` if there)."""
    if not isinstance(result, Mapping):
        raise InvalidControllerError("a result must be a JSON object with a 'controller' {num, den, dt}",
                                     field="result")
    c = result.get("controller")
    if not isinstance(c, Mapping) or "num" not in c or "den" not in c:
        raise InvalidControllerError("the result has no 'controller' with 'num' and 'den' (give the JSON of "
                                     "'tuner tune --json' or of GET /tunes/{id})", field=("result", "controller"))
    try:
        ctrl = controller_from_coeffs(c["num"], c["den"], dt=c.get("dt"))
    except InvalidControllerError as e:
        raise e.at("result", "controller") from None
    gains = result.get("gains")
    structure = result.get("structure")
    if not (isinstance(structure, str) and isinstance(gains, Mapping)):
        return ctrl, None, None
    return ctrl, structure, {str(k): v for k, v in gains.items()}


def _parts(controller: Any) -> tuple[ControllerTF, str | None, dict[str, float] | None]:
    from ..tuning import TuneResult

    if isinstance(controller, ControllerTF):
        return controller, None, None
    if isinstance(controller, TuneResult):
        return controller.controller, controller.structure, dict(controller.gains)
    if isinstance(controller, Mapping):
        return from_result(controller)
    from ..interop import controller_from_control, is_control_lti

    if is_control_lti(controller):
        return controller_from_control(controller), None, None
    raise InvalidControllerError("export takes a ControllerTF, a TuneResult, a result dict or a python-control "
                                 f"TransferFunction/StateSpace, got {type(controller).__name__}", field="controller")


def equation_of(controller: Any, *, dt: float | None = None, method: str = "tustin", u_min: float | None = None,
                u_max: float | None = None) -> DifferenceEquation:
    """The :class:`DifferenceEquation` of anything :func:`export_controller` takes."""
    ctrl, structure, gains = _parts(controller)
    return difference_equation(ctrl, dt=dt, method=method, structure=structure, gains=gains, u_min=u_min,
                               u_max=u_max)


def export_controller(controller: Any, *, format: str = "c", name: str = "controller", dt: float | None = None,
                      method: str = "tustin", u_min: float | None = None, u_max: float | None = None) -> str:
    """The controller as code for the target.

    Parameters
    ----------
    controller : ControllerTF, TuneResult, dict or control.TransferFunction/StateSpace
        A discrete controller is exported as it is; a continuous one is discretised at ``dt`` by ``method``.
        A dict is a result as JSON (``tuner tune --json``, ``GET /tunes/{id}``).
    format : {"c", "python", "text"}
        C99 (``name_state``, ``name_init``, ``name_update``), a Python class ``name`` with ``update(e)``, or the
        difference equation as text.
    name : str
        A C identifier (also the Python class name).
    dt : float, optional
        Sample time, seconds: required for a continuous controller; for a discrete one it must be its own.
    method : {"tustin", "zoh", "structure"}
        How a continuous controller is discretised (:data:`tuner.export.METHODS`); ``"structure"`` uses the
        structure's own discretisation (:mod:`tuner.controllers`) and needs a tune result.
    u_min, u_max : float, optional
        Output limits; a controller with integral action gets anti-windup by conditional integration.

    Returns
    -------
    str
        The source (or text); its header says where the equation came from and how it is realised.

    Examples
    --------
    >>> from tuner import controller_from_expr, export_controller
    >>> pi = controller_from_expr("2*(s + 1)/s", dt=None)
    >>> src = export_controller(pi, format="python", name="Roll", dt=0.01, u_min=-1, u_max=1)
    >>> ns = {}
    >>> exec(src, ns)  # our own generated code, not user text
    >>> ctrl = ns["Roll"]()
    >>> round(ctrl.update(0.25), 6)  # first sample of 2 (s + 1)/s by Tustin at 10 ms: (2 + 0.01) e[0]
    0.5025
    >>> print(export_controller(pi, format="text", dt=0.01))  # doctest: +ELLIPSIS
    controller: ...
    """
    check_name(name)
    de = equation_of(controller, dt=dt, method=method, u_min=u_min, u_max=u_max)
    out = render(de, format, name)
    note = clamp_note(controller, u_min, u_max)
    if note:
        warnings.warn(note, ExportWarning, stacklevel=2)
        mark = {"c": "// ", "python": "# "}.get(format, "")
        out = f"{mark}WARNING: {note}\n{out}"
    return out


class ExportWarning(UserWarning):
    """The exported controller's limits change what was verified (the design's linear control peak exceeds them)."""


def clamp_note(controller: Any, u_min: float | None, u_max: float | None) -> str | None:
    """A warning when the verified linear control peak of a unit reference step exceeds the output limits the
    export clamps to (the clamp then shapes the response, which the verifier did not see); None otherwise or when
    the peak is unknown (a bare controller)."""
    from ..tuning import TuneResult

    if u_min is None and u_max is None:
        return None
    peak = None
    if isinstance(controller, TuneResult):
        peak = max(a.metrics.control_peak for a in controller.analyses)
    elif isinstance(controller, Mapping) and isinstance(controller.get("metrics"), Mapping):
        v = controller["metrics"].get("control_peak")
        peak = float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None
    if peak is None or not math.isfinite(peak):
        return None
    room = min(abs(v) for v in (u_min, u_max) if v is not None)
    if peak <= room:
        return None
    return (f"the design's linear control peak for a unit reference step is {peak:.4g}, beyond the output limit "
            f"{room:g} this export clamps to: steps larger than {room / peak:.3g} saturate the actuator and the "
            "verified margins and step metrics no longer describe the response; tune with a control-peak limit "
            f"(--control-peak {room:g}) or scale the reference")
