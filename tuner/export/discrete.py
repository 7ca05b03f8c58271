"""The controller as it runs on the target: a difference equation at ``dt``.

A discrete controller ``C(z) = N(z)/D(z)`` (degree ``n``, ``D`` monic) is written in powers of ``z^-1``::

    C(z) = (b0 + b1 z^-1 + ... + bn z^-n) / (1 + a1 z^-1 + ... + an z^-n)
    u[k] = b0 e[k] + ... + bn e[k-n] - a1 u[k-1] - ... - an u[k-n]

(``e = r - y``, ``u`` the controller's output), and realised in direct form II transposed, as
:func:`scipy.signal.lfilter` does. A continuous controller is first discretised at ``dt`` by a
stated method (:data:`METHODS`).

Output limits and anti-windup (:class:`Integrator`): a controller with one pole at ``z = 1`` (PI,
PID and the digital PID forms) is split by partial fractions into an integrator of the error and
the rest, ``C(z) = r/(z - 1) + Q(z)/A'(z)``; with limits, the integrator's state ``x`` is updated
only when that does not drive a saturated output further into saturation (conditional
integration, "clamping")::

    v[k] = w[k] + x[k]              (w: the output of Q/A', direct form II transposed)
    u[k] = min(max(v[k], u_min), u_max)
    x[k+1] = x[k] + r e[k]  unless  (v[k] > u_max and r e[k] > 0) or (v[k] < u_min and r e[k] < 0)

Inside the limits this is ``C(z)`` exactly. A controller without integrator is clamped only (its
stable state cannot wind up); limits on a controller with another pole on or outside the unit
circle, or with two integrators, are refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..controllers import ControllerTF, controller_from_coeffs, get_structure
from ..errors import InvalidControllerError, TunerError
from ..plant import check_dt
from ..tolerances import ROOT_AT_DC_TOL, SAME_DT_RTOL

__all__ = ["METHODS", "DifferenceEquation", "Integrator", "difference_equation", "discretize"]

METHODS = {
    "tustin": "Tustin (bilinear): s = 2/dt (z - 1)/(z + 1)",
    "zoh": "zero-order hold (step invariant)",
    "structure": "the structure's own discretisation (tuner.controllers: backward Euler for the integrator and "
                 "the filtered derivative, matched pole-zero for lead/lag)",
}
_ONE_TOL = ROOT_AT_DC_TOL  # a root at z = 1: |D(1)| below this share of sum |d_i|
_STABLE = 1.0 - 1e-12


@dataclass(frozen=True)
class Integrator:
    """``C(z) = r/(z - 1) + Q(z)/A'(z)``: ``r`` the integrator's gain on ``e`` per sample; ``q``, ``a`` the
    rest in powers of ``z^-1`` (``a[0] = 1``)."""

    r: float
    q: np.ndarray
    a: np.ndarray


@dataclass(frozen=True, eq=False)
class DifferenceEquation:
    """``u[k] = sum b[i] e[k-i] - sum_{i>=1} a[i] u[k-i]`` at ``dt`` seconds (``a[0] = 1``).

    ``source`` says where it came from (the controller as given, or discretised by ``method``).
    ``u_min``/``u_max`` are output limits (``None``: none); ``integrator`` the split used for
    anti-windup, when there are limits and the controller has integral action.
    """

    b: np.ndarray
    a: np.ndarray
    dt: float
    source: str
    method: str | None = None
    u_min: float | None = None
    u_max: float | None = None
    integrator: Integrator | None = None

    @property
    def order(self) -> int:
        """The order of the difference equation (the denominator's degree)."""
        return self.a.size - 1

    @property
    def limited(self) -> bool:
        """An output limit is set (``u_min`` or ``u_max``)."""
        return self.u_min is not None or self.u_max is not None

    @property
    def anti_windup(self) -> bool:
        """The output is limited and the controller integrates: conditional integration applies."""
        return self.limited and self.integrator is not None

    def controller(self) -> ControllerTF:
        """The same controller as a :class:`~tuner.controllers.ControllerTF` in ``z`` (powers of ``z``)."""
        return ControllerTF(num=self.b.copy(), den=self.a.copy(), dt=self.dt)


def discretize(c: ControllerTF, dt: float, *, method: str = "tustin", structure: str | None = None,
               gains: dict[str, float] | None = None) -> ControllerTF:
    """``c`` (continuous) at ``dt`` by ``method`` (:data:`METHODS`); ``structure``/``gains`` for ``"structure"``."""
    dt = check_dt(dt)
    if method not in METHODS:
        raise TunerError(f"method must be one of {sorted(METHODS)}, got {method!r}", field="method")
    if method == "structure":
        if structure is None or gains is None:
            raise TunerError("method 'structure' needs the controller's structure and gains (a tune result); "
                             "for an expression choose 'tustin' or 'zoh'", field="method")
        return get_structure(structure).tf(gains, dt)
    from scipy import signal

    if method == "tustin":
        num, den = signal.bilinear(c.num, c.den, fs=1.0 / dt)
    else:
        num, den, _ = signal.cont2discrete((c.num, c.den), dt, method="zoh")
    num = np.atleast_1d(np.squeeze(num))
    try:
        return controller_from_coeffs(num, den, dt=dt)
    except TunerError as e:
        raise InvalidControllerError(f"the controller discretised at dt={dt:g} s by {method} is not usable: {e}",
                                     field="controller") from None


def _z_inverse(c: ControllerTF) -> tuple[np.ndarray, np.ndarray]:
    """``b``, ``a`` in powers of ``z^-1``, same length, ``a[0] = 1`` (common trailing zeros dropped)."""
    den = np.asarray(c.den, float) / c.den[0]
    num = np.asarray(c.num, float) / c.den[0]
    b = np.concatenate([np.zeros(den.size - num.size), num])
    a = den.copy()
    while a.size > 1 and a[-1] == 0 and b[-1] == 0:  # a common factor z^-1
        a, b = a[:-1], b[:-1]
    return b, a


def _at_one(p: np.ndarray) -> bool:
    return abs(np.polyval(p, 1.0)) <= _ONE_TOL * float(np.sum(np.abs(p)))


def _deflate(p: np.ndarray) -> np.ndarray:
    """``p(z) / (z - 1)`` for ``p(1) = 0`` (synthetic division; the remainder is dropped)."""
    q = np.zeros(p.size - 1)
    acc = 0.0
    for i in range(p.size - 1):
        acc = acc + p[i]
        q[i] = acc
    return q


def _split(b: np.ndarray, a: np.ndarray) -> Integrator | None:
    """Partial fractions ``C = r/(z - 1) + Q/A'`` when ``a`` (powers of z^-1, read as powers of z: the same
    coefficients) has one root at 1; ``None`` without integrator."""
    if a.size < 2 or not _at_one(a):
        return None
    ap = _deflate(a)  # A'(z), degree n-1, monic
    if ap.size > 1 and _at_one(ap):
        raise InvalidControllerError("output limits with anti-windup take one integrator; this controller has two "
                                     "or more poles at z = 1: leave out the limits", field="controller")
    r = float(np.polyval(b, 1.0) / np.polyval(ap, 1.0))
    rest = b - r * np.concatenate([[0.0], ap])  # B(z) - r A'(z): a root at 1 by construction
    q = _deflate(rest)  # degree n-1 in z over A' of degree n-1: proper
    return Integrator(r=r, q=q, a=ap)


def check_limits(u_min: Any, u_max: Any) -> tuple[float | None, float | None]:
    """The output limits as floats (None: no limit), checked: finite, ``u_min < u_max``; errors name the field."""
    out = []
    for name, v in (("u_min", u_min), ("u_max", u_max)):
        if v is None:
            out.append(None)
            continue
        try:
            f = float(v)
        except (TypeError, ValueError) as e:
            raise TunerError(f"{name} must be a number, got {v!r}", field=name) from e
        if not math.isfinite(f):
            raise TunerError(f"{name} must be finite, got {v!r} (leave it out for no limit)", field=name)
        out.append(f)
    lo, hi = out
    if lo is not None and hi is not None and not lo < hi:
        raise TunerError(f"u_min ({lo:g}) must be below u_max ({hi:g})", field="u_min")
    return lo, hi


def difference_equation(c: ControllerTF, *, dt: float | None = None, method: str = "tustin",
                        structure: str | None = None, gains: dict[str, float] | None = None,
                        u_min: float | None = None, u_max: float | None = None) -> DifferenceEquation:
    """The difference equation of ``c``: as given when discrete (``dt``, if given, must be its own), else
    discretised at ``dt`` by ``method``; optional output limits with anti-windup (see the module)."""
    lo, hi = check_limits(u_min, u_max)
    if c.dt is None:
        if dt is None:
            raise TunerError("the controller is continuous: give the sample time dt to discretise it at "
                             f"(method {method!r})", field="dt")
        cd = discretize(c, dt, method=method, structure=structure, gains=gains)
        source, used = f"discretised at dt = {cd.dt:g} s by {METHODS[method]}", method
    else:
        dt = check_dt(dt)
        if dt is not None and abs(dt - c.dt) > SAME_DT_RTOL * c.dt:
            raise TunerError(f"the controller is discrete at dt={c.dt:g} s but dt={dt:g} s was given: resampling "
                             "a discrete controller is not supported; leave dt out or give its own", field="dt")
        cd, source, used = c, "the discrete controller as given", None
    b, a = _z_inverse(cd)
    integ = None
    if lo is not None or hi is not None:
        integ = _split(b, a)
        _check_limitable(a, integ)
    return DifferenceEquation(b=b, a=a, dt=float(cd.dt), source=source, method=used, u_min=lo, u_max=hi,
                              integrator=integ)


def _check_limitable(a: np.ndarray, integ: Integrator | None) -> None:
    rest = integ.a if integ is not None else a
    poles = np.roots(rest) if rest.size > 1 else np.zeros(0)
    if poles.size and np.max(np.abs(poles)) >= _STABLE:
        raise InvalidControllerError(
            "output limits need a stable controller (plus at most one integrator): this one has a pole at |z| = "
            f"{np.max(np.abs(poles)):.6g}, whose state would wind up; leave out the limits", field="controller")
