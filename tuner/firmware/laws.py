"""The autopilots' rate laws as the firmware computes them every sample, in transfer-function form.

Each law is linear between its clamps (the integrator limit, the output limits, PX4's integrator fade, which is
1 for errors well below 400 deg/s); that linear part is what the tuner designs and the verifier checks, and
:mod:`tuner.analysis.saturation` simulates the clamps. The formulas are plain arithmetic on the parameters and
``dt``, so the same code serves numbers (numpy) and symbols (CasADi): see :mod:`tuner.controllers`.

With ``a_f = dt/(dt + 1/(2 pi f))`` a first-order low-pass ``y += a_f (x - y)`` (PX4's ``AlphaFilter``,
ArduPilot's ``calc_lowpass_alpha_dt``) is ``H_f(z) = a_f z/(z - (1 - a_f))``; a cutoff ``f <= 0`` is no filter.

**PX4** (``src/lib/rate_control/rate_control.cpp``, ``RateControl::update``): the error ``e = w_sp - w``, the
D term on the derivative of the measured rate through the D-gyro low-pass, gains ``K P``, ``K I``, ``K D``
(``MC_xRATE_K`` scales them, not FF), the output built from the integrator *before* this sample's update
(a forward-Euler integrator ``I dt/(z - 1)``)::

    C_fb(z) = K [P + I dt/(z - 1) + D a_d (z - 1)/(dt (z - (1 - a_d)))]     acting on -w
    C_r(z)  = K [P + I dt/(z - 1)] + FF                                     acting on w_sp

**ArduPilot** (``libraries/AC_PID/AC_PID.cpp``, ``AC_PID::update_all``): the target filtered (FLTT), the error
of the filtered target filtered (FLTE), the D term on the derivative of the filtered error (FLTD), the
integrator updated *before* the output (backward Euler ``I dt z/(z - 1)``), FF on the filtered target::

    PID(z)  = P + I dt z/(z - 1) + D a_D (z - 1)/(dt (z - (1 - a_D)))
    C_fb(z) = PID H_E                                                        acting on -w
    C_r(z)  = PID H_E H_T + FF H_T                                           acting on the target

Both paths are written over one denominator (the structures' 2-DOF convention: ``u = C_r r - C_fb w``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

__all__ = ["PX4_FIXED", "ARDUPILOT_FIXED", "alpha", "poly_add", "poly_mul", "px4_coeffs", "px4_ref_coeffs",
           "ardupilot_coeffs", "ardupilot_ref_coeffs"]

#: what the vehicle fixes for PX4's law (defaults: firmware.md, PX4's parameter defaults): the gain K
#: (``MC_ROLLRATE_K``), the D-gyro low-pass cutoff (``IMU_DGYRO_CUTOFF``, Hz) and the integrator limit
#: (``MC_RR_INT_LIM``; acts only when the output saturates or the integrator grows large)
PX4_FIXED: tuple[tuple[str, float], ...] = (("K", 1.0), ("dgyro_hz", 20.0), ("int_lim", 0.3))
#: ArduPilot's: the target, error and derivative filters (``ATC_RAT_RLL_FLTT/FLTE/FLTD``, Hz; 0 = off) and the
#: integrator limit ``IMAX``
ARDUPILOT_FIXED: tuple[tuple[str, float], ...] = (("fltt_hz", 20.0), ("flte_hz", 0.0), ("fltd_hz", 20.0),
                                                  ("imax", 0.5))


def alpha(f_hz: float, dt: Any) -> Any:
    """The first-order low-pass coefficient ``a = dt/(dt + 1/(2 pi f))``; 1 (no filter) for ``f <= 0``.

    Examples
    --------
    >>> from tuner.firmware.laws import alpha
    >>> round(alpha(20.0, 0.0025), 6)  # PX4's D-gyro low-pass at 400 Hz
    0.239057
    >>> alpha(0.0, 0.0025)
    1.0
    """
    if f_hz <= 0:
        return 1.0
    return dt / (dt + 1.0 / (2.0 * math.pi * f_hz))


def poly_mul(a: Sequence[Any], b: Sequence[Any]) -> list[Any]:
    """The product of two polynomials (highest power first), on numbers or symbols."""
    out: list[Any] = [0] * (len(a) + len(b) - 1)
    for i, x in enumerate(a):
        for j, y in enumerate(b):
            out[i + j] = out[i + j] + x * y
    return out


def poly_add(a: Sequence[Any], b: Sequence[Any]) -> list[Any]:
    """The sum of two polynomials (highest power first, aligned at the constant term), on numbers or symbols."""
    n = max(len(a), len(b))
    a = [0] * (n - len(a)) + list(a)
    b = [0] * (n - len(b)) + list(b)
    return [x + y for x, y in zip(a, b)]


def _scale(a: Sequence[Any], k: Any) -> list[Any]:
    return [k * c for c in a]


def _px4_parts(x: Sequence[Any], dt: Any, fixed: dict[str, float]) -> tuple[list, list, list]:
    """PX4 over the denominator (z - 1)(z - (1 - a_d)): the P+I numerator, the D numerator, the denominator."""
    p, i, d = x[0], x[1], x[2]
    a = alpha(fixed["dgyro_hz"], dt)
    q = [1, -(1 - a)]
    den = poly_mul([1, -1], q)
    pi_num = poly_add(poly_mul([p, -p], q), _scale(q, i * dt))  # (P (z - 1) + I dt)(z - (1 - a))
    d_num = poly_mul(_scale([1, -1], d * a / dt), [1, -1])  # D a/dt (z - 1)^2
    return pi_num, d_num, den


def px4_coeffs(x: Sequence[Any], dt: Any, fixed: dict[str, float]) -> tuple[list, list]:
    """PX4's feedback path ``C_fb`` (numerator, denominator; highest power first) for ``x = (P, I, D, FF)``."""
    pi_num, d_num, den = _px4_parts(x, dt, fixed)
    return _scale(poly_add(pi_num, d_num), fixed["K"]), den


def px4_ref_coeffs(x: Sequence[Any], dt: Any, fixed: dict[str, float]) -> tuple[list, list]:
    """PX4's setpoint path ``C_r = K (P + I dt/(z - 1)) + FF`` over the feedback path's denominator."""
    pi_num, _, den = _px4_parts(x, dt, fixed)
    return poly_add(_scale(pi_num, fixed["K"]), _scale(den, x[3])), den


def _lp(f_hz: float, dt: Any) -> tuple[list, list]:
    """``H_f = a z/(z - (1 - a))`` as (num, den); ``([1], [1])`` when the filter is off."""
    if f_hz <= 0:
        return [1], [1]
    a = alpha(f_hz, dt)
    return [a, 0], [1, -(1 - a)]


def _ardupilot_parts(x: Sequence[Any], dt: Any, fixed: dict[str, float]) -> tuple[list, list, list, list]:
    """ArduPilot's PID numerator and denominator and the target filter's numerator and denominator."""
    p, i, d = x[0], x[1], x[2]
    ad = alpha(fixed["fltd_hz"], dt)
    q = [1, -(1 - ad)]
    den = poly_mul([1, -1], q)  # (z - 1)(z - (1 - a_D))
    pi = poly_add(poly_mul([p, -p], q), poly_mul([i * dt, 0], q))  # P (z - 1) q + I dt z q
    num = poly_add(pi, poly_mul(_scale([1, -1], d * ad / dt), [1, -1]))  # + D a_D/dt (z - 1)^2
    ne, de = _lp(fixed["flte_hz"], dt)
    nt, dtt = _lp(fixed["fltt_hz"], dt)
    return poly_mul(num, ne), poly_mul(den, de), nt, dtt


def ardupilot_coeffs(x: Sequence[Any], dt: Any, fixed: dict[str, float]) -> tuple[list, list]:
    """ArduPilot's feedback path ``C_fb = PID H_E`` over the common denominator (the target filter's pole
    included, cancelled: the realisation of both paths shares it)."""
    num, den, _, dtt = _ardupilot_parts(x, dt, fixed)
    return poly_mul(num, dtt), poly_mul(den, dtt)


def ardupilot_ref_coeffs(x: Sequence[Any], dt: Any, fixed: dict[str, float]) -> tuple[list, list]:
    """ArduPilot's target path ``C_r = (PID H_E + FF) H_T`` over the feedback path's denominator."""
    num, den, nt, dtt = _ardupilot_parts(x, dt, fixed)
    return poly_mul(poly_add(num, _scale(den, x[3])), nt), poly_mul(den, dtt)
