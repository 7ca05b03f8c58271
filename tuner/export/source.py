"""What is exported: a controller, a tune result, or a stored result (the JSON of ``tuner tune --json`` or of
``GET /tunes/{id}``), with the sample time and method for a continuous one."""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from .._lazy import is_instance_of
from ..controllers import ControllerTF, controller_from_coeffs
from ..errors import InvalidControllerError, TunerError
from .codegen import check_name, render
from .discrete import DifferenceEquation, difference_equation
from .twodof import TwoDofLaw, two_dof_law

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
        if c.get("num_r") is not None:  # a 2-DOF controller: its reference path (exported from its gains)
            num_r = controller_from_coeffs(c["num_r"], c["den"], dt=c.get("dt")).num
            ctrl = ControllerTF(num=ctrl.num, den=ctrl.den, dt=ctrl.dt, num_r=num_r)
    except InvalidControllerError as e:
        raise e.at("result", "controller") from None
    gains = result.get("gains")
    structure = result.get("structure")
    if not (isinstance(structure, str) and isinstance(gains, Mapping)):
        return ctrl, None, None
    return ctrl, structure, {str(k): v for k, v in gains.items()}


def _is_tune_result(obj: Any) -> bool:
    """``obj`` is a :class:`tuner.TuneResult` (export sits below the tuning layer: it does not import it)."""
    return is_instance_of(obj, "tuner.tuning", "TuneResult")


def _parts(controller: Any) -> tuple[ControllerTF, str | None, dict[str, float] | None]:
    if isinstance(controller, ControllerTF):
        return controller, None, None
    if _is_tune_result(controller):
        return controller.controller, controller.structure, dict(controller.gains)
    if isinstance(controller, Mapping):
        return from_result(controller)
    from ..interop import controller_from_control, is_control_lti

    if is_control_lti(controller):
        return controller_from_control(controller), None, None
    raise InvalidControllerError("export takes a ControllerTF, a TuneResult, a result dict or a python-control "
                                 f"TransferFunction/StateSpace, got {type(controller).__name__}", field="controller")


def equation_of(controller: Any, *, dt: float | None = None, method: str = "tustin", u_min: float | None = None,
                u_max: float | None = None, anti_windup: str = "conditional", tt: float | None = None
                ) -> DifferenceEquation | TwoDofLaw:
    """The :class:`DifferenceEquation` of anything :func:`export_controller` takes; a 2-DOF ``pid2`` result gives
    its :class:`~tuner.export.twodof.TwoDofLaw` (inputs r and y)."""
    ctrl, structure, gains = _parts(controller)
    if structure == "pid2" and gains is not None:
        return two_dof_law(gains, ctrl.dt, dt=dt, method=method, u_min=u_min, u_max=u_max,
                           anti_windup=anti_windup, tt=tt)
    from ..firmware.registry import by_structure

    law = by_structure(structure)
    if law is not None:  # the autopilot runs the law itself: its parameters are the export
        fmt = law.export_format
        raise InvalidControllerError(f"a {structure} result runs as the firmware's own law: export its parameter file "
                                     f"(format {fmt}), which the ground station loads", field="format")
    if ctrl.two_dof:
        raise InvalidControllerError("a 2-DOF controller is exported from its structure and gains: give the tune "
                                     "result (TuneResult or its JSON)", field="controller")
    if anti_windup != "conditional" or tt is not None:
        raise TunerError("the 1-DOF export (u = C(z) e) has anti-windup by conditional integration only; "
                         "back-calculation (anti_windup, tt) is for pid2", field="anti_windup")
    return difference_equation(ctrl, dt=dt, method=method, structure=structure, gains=gains, u_min=u_min,
                               u_max=u_max)


def export_controller(controller: Any, *, format: str = "c", name: str = "controller", dt: float | None = None,
                      method: str = "tustin", u_min: float | None = None, u_max: float | None = None,
                      anti_windup: str = "conditional", tt: float | None = None) -> str:
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
    anti_windup : {"conditional", "back_calculation"}
        pid2 only (``N_update(s, r, y)``, :mod:`tuner.export.twodof`): conditional integration, or
        back-calculation with the tracking time ``tt`` (default ``sqrt(Ti Td)``, ``Ti`` for a PI; Astrom &
        Hagglund). The 1-DOF export (``N_update(s, e)``) has conditional integration.
    tt : float, optional
        Back-calculation's tracking time, seconds (at least ``dt``).

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
    de = equation_of(controller, dt=dt, method=method, u_min=u_min, u_max=u_max, anti_windup=anti_windup, tt=tt)
    out = render(de, format, name)
    note = clamp_note(controller, u_min, u_max)
    if note:
        warnings.warn(note, ExportWarning, stacklevel=2)
        mark = {"c": "// ", "python": "# "}.get(format, "")
        out = f"{mark}WARNING: {note}\n{out}"
    return out


class ExportWarning(UserWarning):
    """The exported controller's limits change what was verified (the design's linear control peak exceeds them)."""


def clamp_note(controller: Any, u_min: float | None, u_max: float | None, *, flag: bool = False) -> str | None:
    """A warning when the verified control signal of a unit reference step leaves the output limits the export
    clamps to (the clamp then shapes the response, which the verifier did not see); None otherwise, or when the
    response is unknown (a bare controller). ``flag``: name the command-line flag, else the spec field."""
    if u_min is None and u_max is None:
        return None
    hi = lo = None  # the largest and smallest u of the verified unit-step responses
    if _is_tune_result(controller):
        us = [a.response.u for a in controller.analyses if a.response is not None and a.response.u.size]
        if us:
            hi, lo = max(float(np.max(u)) for u in us), min(float(np.min(u)) for u in us)
    elif isinstance(controller, Mapping) and isinstance(controller.get("metrics"), Mapping):
        v = controller["metrics"].get("control_peak")  # a stored result: max |u| only (its sign is not kept)
        if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
            hi, lo = float(v), (-float(v) if u_min is not None and u_min < 0 else None)
    if hi is None or not (math.isfinite(hi) and (lo is None or math.isfinite(lo))):
        return None
    over = []
    if u_max is not None and hi > u_max:
        over.append((hi, u_max, "above"))
    if u_min is not None and lo is not None and lo < u_min:
        over.append((lo, u_min, "below"))
    if not over:
        return None
    peak, lim, side = max(over, key=lambda t: abs(t[0] - t[1]))
    share = lim / peak if peak != 0 and lim / peak > 0 else None
    steps = f"reference steps larger than {share:.3g} saturate the actuator" if share is not None else \
        "every reference step saturates the actuator"
    name = "--control-peak" if flag else "control_peak_max"
    room = min(abs(v) for v in (u_min, u_max) if v is not None)
    hint = f"tune with a control-peak limit ({name} {room:g}) or scale the reference" if room > 0 else \
        "scale the reference or the limits"
    return (f"the design's control signal for a unit reference step reaches {peak:.4g}, {side} the output limit "
            f"{lim:g} this export clamps to: {steps}, and the verified margins and step metrics no longer describe "
            f"the response; {hint}")
