"""python-control in and out: ``control.TransferFunction`` and ``control.StateSpace`` as plants and
controllers, and results as python-control objects.

In: a SISO model, continuous (``dt = 0``; ``dt = None``, python-control's unspecified time base, is taken as
continuous) or discrete (``dt`` a number of seconds, e.g. from ``control.c2d``). ``dt = True`` (discrete with
no sample time) is refused: give the number. python-control has no input delay, so the delay is an argument
of its own (seconds; whole samples for a discrete model). A state-space model's poles are its eigenvalues
and its zeros the invariant zeros (:func:`tuner.lti.zpk_from_ss`): no characteristic polynomial is expanded.

Out (:func:`loop_tfs`): ``L = C G``, ``S = 1/(1 + L)``, ``T = L/(1 + L)`` as transfer functions, uncancelled
(for a 2-DOF ``pid2`` these are the feedback loop's, ``C`` acting on ``-y``; its ``r -> y`` is ``C_r G S``,
from :func:`reference_tfs` with ``r -> u``):

* sampled-data loop (a controller at ``dt``): in ``z`` at ``dt``, the plant's zero-order-hold equivalent
  with its delay as ``z^-d`` (exact at the sample instants; what the controller sees);
* discrete plant: the plant itself, with its delay as ``z^-d``;
* continuous loop: in ``s``; a delay ``tau`` enters as a Padé approximation of order ``pade_order``
  (:func:`control.pade`; ``None`` leaves the delay out), which is exact only at low frequencies.

python-control is imported only when one of its objects is met or made.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from ._lazy import is_instance_of
from .controllers import ControllerTF, controller_from_coeffs
from .errors import InvalidControllerError, InvalidPlantError, TunerError
from .lti import poly_from_roots
from .plant import (  # the python-control plant conversion lives with the plant (no import circle); re-exported
    Plant,
    _dt_of,
    _siso,
    _tf_coeffs,
    _zpk,
    is_control_lti,
    plant_from_control,
)

__all__ = ["LoopTFs", "ReferenceTFs", "reference_tfs",
           "is_control_lti", "plant_from_control", "controller_from_control", "as_plant", "as_plants",
           "as_controller", "controller_to_control", "loop_tfs", "DEFAULT_PADE_ORDER"]

DEFAULT_PADE_ORDER = 6


class LoopTFs(NamedTuple):
    """The loop's transfer functions as python-control objects (``L, S, T = ...``).

    ``L`` the loop gain, ``S = 1/(1 + L)``, ``T = L/(1 + L)``; from ``TuneResult.loop_tfs()`` or
    ``Analysis.loop_tfs()``.

    Examples
    --------
    >>> import control
    >>> from tuner import analyze
    >>> L, S, T = analyze(control.tf([1], [1, 1]), control.tf([2, 2], [1, 0])).loop_tfs()
    >>> round(abs(complex(T(2j))), 6)  # T = 2/(s + 2): |T(2j)| = 1/sqrt(2)
    0.707107
    """

    L: Any
    S: Any
    T: Any


class ReferenceTFs(NamedTuple):
    """The reference's transfer functions: ``r -> y`` and ``r -> u`` (``Tr, Ur = ...``).

    For a 1-DOF controller ``Tr = T`` and ``Ur = C S``; for a 2-DOF one (``pid2``, ``u = C_r r - C y``)
    ``Tr = C_r G S`` and ``Ur = C_r S``, while ``L = C G``, ``S`` and ``T`` of :func:`loop_tfs` are the feedback
    loop's (margins, sensitivities, the load and noise responses)."""

    Tr: Any
    Ur: Any


def controller_from_control(sys: Any) -> ControllerTF:
    """A :class:`~tuner.controllers.ControllerTF` from a python-control model (its ``dt``).

    Examples
    --------
    >>> import control
    >>> from tuner import controller_from_control
    >>> c = controller_from_control(control.tf([2, 2], [1, 0], 0.01))
    >>> c.dt, [float(v) for v in c.den]
    (0.01, [1.0, 0.0])
    """
    import control

    _siso(sys, InvalidControllerError, "controller")
    dt = _dt_of(sys, InvalidControllerError, "controller")
    if isinstance(sys, control.StateSpace):
        zk = _zpk(sys, dt is not None)
        num, den = zk.gain * poly_from_roots(zk.zeros), poly_from_roots(zk.poles)
    else:
        num, den = _tf_coeffs(sys)
    return controller_from_coeffs(num, den, dt=dt)


def as_plant(plant: Any, *, delay: float | None = None) -> Plant:
    """``plant`` (a :class:`Plant` or a python-control model) as a :class:`Plant`; ``delay`` for the latter."""
    if isinstance(plant, Plant):
        if delay:
            raise InvalidPlantError("a Plant carries its own delay: build it with make_plant(..., delay=...) or pass "
                                    "a python-control model with delay=", field="delay")
        return plant
    if is_control_lti(plant):
        return plant_from_control(plant, delay=delay or 0.0)
    if is_instance_of(plant, "tuner.identify.result", "IdentifyResult"):  # its fitted model, the delay as fitted
        if delay:
            raise InvalidPlantError("an identification carries its fitted delay: leave delay out", field="delay")
        return plant.plant()
    raise InvalidPlantError("expected a tuner Plant or a python-control TransferFunction/StateSpace, got "
                            f"{type(plant).__name__}")


def as_plants(plant_or_plants: Any, *, delay: float | Sequence[float] | None = None) -> list[Plant]:
    """One plant or a sequence (robust tuning, nominal first), each a Plant or a python-control model.

    ``delay``: one number for every python-control model, or one per plant.
    """
    single = isinstance(plant_or_plants, Plant) or is_control_lti(plant_or_plants)
    if isinstance(plant_or_plants, (str, bytes)):
        raise InvalidPlantError("a plant is a Plant or a python-control model, not text: build it with "
                                "plant_from_expr(text)", field="plants")
    try:
        items = [plant_or_plants] if single else list(plant_or_plants)
    except TypeError:
        raise InvalidPlantError("expected a Plant, a python-control TransferFunction/StateSpace or a list of them, "
                                f"got {type(plant_or_plants).__name__}", field="plants") from None
    if delay is None or np.ndim(delay) == 0:
        delays = [delay] * len(items)
    else:
        delays = list(delay)
        if len(delays) != len(items):
            raise InvalidPlantError(f"{len(delays)} delays for {len(items)} plants: give one delay, or one per plant",
                                    field="delay")
    out = []
    for i, (p, d) in enumerate(zip(items, delays)):
        try:
            out.append(as_plant(p, delay=d))
        except TunerError as e:
            raise e.at("plants", i) from None
    return out


def as_controller(controller: Any) -> ControllerTF:
    """``controller`` (a :class:`ControllerTF` or a python-control model) as a :class:`ControllerTF`."""
    if isinstance(controller, ControllerTF):
        return controller
    if is_control_lti(controller):
        return controller_from_control(controller)
    raise InvalidControllerError("expected a tuner ControllerTF or a python-control TransferFunction/StateSpace, "
                                 f"got {type(controller).__name__}", field="controller")


def controller_to_control(c: ControllerTF) -> Any:
    """The controller as a ``control.TransferFunction`` (``dt`` its own; 0 = continuous)."""
    import control

    return control.tf(np.asarray(c.num, float), np.asarray(c.den, float), 0 if c.dt is None else c.dt)


def loop_tfs(loop: Any, *, pade_order: int | None = DEFAULT_PADE_ORDER) -> LoopTFs:
    """``L``, ``S``, ``T`` of a :class:`~tuner.loop.Loop` as ``control.TransferFunction`` (see the module)."""
    import control

    zk = loop.zpk  # uncancelled; a sampled-data loop's delay z^-d is there as poles at 0
    L = control.zpk(zk.zeros, zk.poles, zk.gain, 0 if loop.dt is None else loop.dt)
    if loop.dt is None and loop.delay_s and pade_order is not None:
        if not (isinstance(pade_order, int) and 1 <= pade_order <= 10):
            raise TunerError(f"pade_order must be an integer from 1 to 10 (or None), got {pade_order!r}",
                             field="pade_order")
        L = L * control.tf(*control.pade(loop.delay_s, pade_order))
    one = control.tf([1.0], [1.0], L.dt)
    return LoopTFs(L=L, S=control.feedback(one, L), T=control.feedback(L, one))


def reference_tfs(loop: Any, *, pade_order: int | None = DEFAULT_PADE_ORDER) -> ReferenceTFs:
    """``r -> y`` and ``r -> u`` of a :class:`~tuner.loop.Loop` (see :class:`ReferenceTFs`); the plant as in
    :func:`loop_tfs` (the zero-order-hold plant with ``z^-d`` at ``dt``; a continuous delay by Padé)."""
    import control

    lt = loop_tfs(loop, pade_order=pade_order)
    dt = 0 if loop.dt is None else loop.dt
    g = loop.loop_plant.zpk
    G = control.zpk(g.zeros, np.concatenate([g.poles, np.zeros(loop.delay_samples)]), g.gain, dt)
    if loop.dt is None and loop.delay_s and pade_order is not None:
        G = G * control.tf(*control.pade(loop.delay_s, pade_order))
    cr = loop.controller.reference()
    Cr = control.tf(np.asarray(cr.num, float), np.asarray(cr.den, float), dt)
    return ReferenceTFs(Tr=Cr * G * lt.S, Ur=Cr * lt.S)
