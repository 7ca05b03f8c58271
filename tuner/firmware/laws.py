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

    C_fb(z) = K [P + I dt/(z - 1) + D a_d (z - 1)/(dt (z - (1 - a_d)))] H_q      acting on -w
    C_r(z)  = (K [P + I dt/(z - 1)] + FF) H_q                                    acting on w_sp

where the D path ``a_d z/(z - (1 - a_d))`` is, in general, :func:`dgyro_filter`: the firmware differences and
filters the rate on every raw gyro sample (``raw_hz``), first order (``AlphaFilter``) or, before v1.13, second order
(``LowPassFilter2p``, ``dgyro_order`` 2), and the loop reads the last value; with ``raw_hz`` 0 (the loop rate) and
first order it is the formula above.

``H_q`` is the output low-pass ``MulticopterRateControl::Run`` applies to the yaw torque after the law and before it
publishes ``vehicle_torque_setpoint``: ``torque_setpoint(2) = _output_lpf_yaw.update(torque_setpoint(2), dt)``, an
``AlphaFilter`` (``y += a (x - y)``, ``a = dt/(dt + 1/(2 pi f))``) at ``_output_lpf_yaw.setCutoffFreq(
_param_mc_yaw_tq_cutoff.get())`` (``src/modules/mc_rate_control/MulticopterRateControl.cpp``, PX4/PX4-Autopilot main,
the v1.14/v1.15 generation; the revision of that file in this project's source index, 8ab295e, predates the filter
and has none, so the lines are quoted as in the current file): ``tq_hz``, ``MC_YAW_TQ_CUTOFF`` (default 2 Hz) on yaw,
0 (none) on roll and pitch. A plant identified from ``vehicle_torque_setpoint`` starts after it, so the loop the
tuner designs and verifies holds it.

**ArduPilot** (``libraries/AC_PID/AC_PID.cpp``, ``AC_PID::update_all``): the target filtered (FLTT), the error
of the filtered target filtered (FLTE), the D term on the derivative of the filtered error (FLTD), the
integrator updated *before* the output (backward Euler ``I dt z/(z - 1)``), FF on the filtered target::

    PID(z)  = P + I dt z/(z - 1) + D a_D (z - 1)/(dt (z - (1 - a_D)))
    C_fb(z) = PID H_E                                                        acting on -w
    C_r(z)  = PID H_E H_T + FF H_T + D_FF (1 - 1/z) H_T / dt                 acting on the target

``D_FF`` (``ATC_RAT_*_D_FF``): ``get_ff() = _target * _kff + _target_derivative * _kdff`` with ``_target_derivative
= (_target - target_last)/dt`` of the filtered target (``AC_PID.cpp``, ``update_all``, ArduPilot/ardupilot master
as of 2024-2025, the ``Defaults``-block generation; sent to the mixer with the FF). With FLTT on, ``(1 - 1/z) H_T =
a_T (z - 1)/(z - (1 - a_T))``: no new pole.

Per-axis defaults (:func:`law_defaults`): ArduPilot builds ``_pid_rate_yaw`` with ``filt_E_hz =
AC_ATC_MULTI_RATE_YAW_FILT_HZ`` = 2.5 Hz and roll/pitch with 0 (the ``AC_PID::Defaults`` blocks of
``libraries/AC_AttitudeControl/AC_AttitudeControl_Multi.h``, ArduPilot master 2024-2025; the 2.5 Hz ``#define``
itself at commit 05ae9d2 of the same file); FLTT = FLTD = ``AC_ATC_MULTI_RATE_RPY_FILT_HZ`` 20 Hz, IMAX 0.5, FF 0,
D_FF 0 on every axis. PX4's yaw has the 2 Hz torque low-pass; roll and pitch none.

Both paths are written over one denominator (the structures' 2-DOF convention: ``u = C_r r - C_fb w``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

__all__ = ["PX4_FIXED", "ARDUPILOT_FIXED", "LATER_FIXED", "law_defaults", "axis_fixed", "alpha", "poly_add", "poly_mul",
           "dgyro_filter", "px4_coeffs", "px4_ref_coeffs", "ardupilot_coeffs", "ardupilot_ref_coeffs"]

#: what the vehicle fixes for PX4's law (defaults: firmware.md, PX4's parameter defaults): the gain K
#: (``MC_ROLLRATE_K``), the D-gyro low-pass cutoff (``IMU_DGYRO_CUTOFF``, Hz) and the integrator limit
#: (``MC_RR_INT_LIM``; acts only when the output saturates or the integrator grows large)
#: (``MC_RR_INT_LIM``; acts only when the output saturates or the integrator grows large), and the output low-pass
#: ``tq_hz`` (``MC_YAW_TQ_CUTOFF`` on yaw, Hz; 0 = none: roll and pitch). These are the roll axis's; see
#: :func:`law_defaults` for each axis's.
#: The D path's generation and rate (:func:`dgyro_filter`): ``dgyro_order`` 1 (``AlphaFilter``, current firmware) or 2
#: (``LowPassFilter2p``, the 2021-era releases before v1.13), ``raw_hz`` the raw gyro rate the difference and its
#: filter run at (0: the loop rate, what the law was before the D path was modelled at the raw rate).
PX4_FIXED: tuple[tuple[str, float], ...] = (("K", 1.0), ("dgyro_hz", 20.0), ("int_lim", 0.3), ("tq_hz", 0.0),
                                            ("dgyro_order", 1.0), ("raw_hz", 0.0))
#: ArduPilot's: the target, error and derivative filters (``ATC_RAT_RLL_FLTT/FLTE/FLTD``, Hz; 0 = off), the
#: integrator limit ``IMAX`` and the target-derivative feed-forward ``D_FF`` (roll's defaults; yaw's FLTE is 2.5 Hz:
#: :func:`law_defaults`)
ARDUPILOT_FIXED: tuple[tuple[str, float], ...] = (("fltt_hz", 20.0), ("flte_hz", 0.0), ("fltd_hz", 20.0),
                                                  ("imax", 0.5), ("dff", 0.0))
#: the fixed values a result file written before they were modelled may lack: each one's "off" value, which is
#: what the law was then
LATER_FIXED: dict[str, float] = {"tq_hz": 0.0, "dff": 0.0, "dgyro_order": 1.0, "raw_hz": 0.0}
_AXIS_DEFAULTS = {("px4", "yaw"): {"tq_hz": 2.0}, ("ardupilot", "yaw"): {"flte_hz": 2.5}}


def law_defaults(firmware: str, axis: str) -> dict[str, float]:
    """The firmware's defaults of what its law fixes on ``axis`` (see the module's docstring for the sources; the
    registered firmware's :meth:`~tuner.firmware.base.Firmware.law_defaults`: an unknown firmware is an error).

    Examples
    --------
    >>> from tuner.firmware.laws import law_defaults
    >>> law_defaults("ardupilot", "yaw")["flte_hz"], law_defaults("ardupilot", "roll")["flte_hz"]
    (2.5, 0.0)
    >>> law_defaults("px4", "yaw")["tq_hz"], law_defaults("px4", "pitch")["tq_hz"]
    (2.0, 0.0)
    """
    from .registry import get_firmware

    return get_firmware(firmware).law_defaults(axis)


def axis_fixed(firmware: str, axis: str, fixed: dict[str, float]) -> dict[str, float]:
    """The fixed values that become ``axis``'s defaults: those of ``fixed`` still at the structure's (roll's)
    default whose default differs on ``axis`` (a law tuned for yaw without the vehicle's parameters).

    Examples
    --------
    >>> from tuner.firmware.laws import axis_fixed
    >>> axis_fixed("ardupilot", "yaw", {"flte_hz": 0.0}), axis_fixed("ardupilot", "yaw", {"flte_hz": 5.0})
    ({'flte_hz': 2.5}, {})
    """
    from .registry import get_firmware

    return get_firmware(firmware).axis_fixed(axis, fixed)


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
    """PX4 over the denominator (z - 1) Q(z) (times z for a D filter whose numerator has a constant term): the P+I
    numerator, the D numerator, the denominator; ``N_q/Q`` is :func:`dgyro_filter`."""
    p, i, d = x[0], x[1], x[2]
    nq, q = dgyro_filter(fixed, dt)
    if len(nq) == 2:  # first order, a z/(z - (1 - a)): (1 - 1/z) H = a (z - 1)/(z - (1 - a))
        den = poly_mul([1, -1], q)
        d_num = poly_mul(_scale([1, -1], d * nq[0] / dt), [1, -1])  # D a/dt (z - 1)^2
    else:  # second order: (1 - 1/z) N_q/Q = (z - 1) N_q/(z Q)
        q = poly_mul(q, [1, 0])
        den = poly_mul([1, -1], q)
        d_num = poly_mul(poly_mul(_scale([1, -1], d / dt), [1, -1]), nq)  # D/dt (z - 1)^2 N_q
    pi_num = poly_add(poly_mul([p, -p], q), _scale(q, i * dt))  # (P (z - 1) + I dt) Q
    return pi_num, d_num, den


def _fn(name: str, x: Any) -> Any:
    """``cos``, ``sin`` or ``tan`` of a number or a CasADi symbol (the NLP's ``dt`` is a parameter)."""
    if type(x).__module__.startswith("casadi"):
        import casadi

        return getattr(casadi, name)(x)
    return getattr(math, name)(x)


def dgyro_filter(fixed: dict[str, float], dt: Any) -> tuple[list, list]:
    """The D path's filter at the loop rate as PX4 computes it at the raw gyro rate, ``(N_q, Q)`` (highest power
    first): the rate law's D input is ``N_q/Q`` applied to ``(w[k] - w[k-1])/dt``.

    ``VehicleAngularVelocity`` differences the gyro-low-passed rate over the raw gyro ``dt_r`` and low-passes the
    difference on every raw sample; the rate loop reads the last value (``src/modules/sensors/
    vehicle_angular_velocity/VehicleAngularVelocity.cpp``, ``Run``'s FIFO loop ``delta_velocity = data[n] -
    _angular_velocity_prev``, ``_lp_filter_acceleration[axis].apply``, ``/ dt_s``). The filter is an
    ``AlphaFilter`` (first order, ``a = dt_r/(dt_r + 1/(2 pi f))``) in current firmware
    (``VehicleAngularVelocity.hpp`` @ 85e60904e810939752623b4c9c2fa305504a73e4: ``AlphaFilter<float>
    _lp_filter_acceleration[3]``) and a ``math::LowPassFilter2p`` (second-order Butterworth by the prewarped bilinear
    transform, ``IMU_DGYRO_CUTOFF`` 30 Hz by default, ``imu_gyro_parameters.c`` @
    050fa47acac5264c13eb2898851bdbd94417624a: "the 2nd order butterworth filter used on the time derivative")
    in the 2021-era revision of the same files (``math::LowPassFilter2p _lp_filter_acceleration[3]``).

    With ``m = raw_hz dt`` raw samples per loop sample, the difference over each raw sample is taken as the loop
    sample's ``(w[k] - w[k-1])/m`` (the rate linear between the loop's samples), so the raw filter's input is held
    over the ``m`` samples and the loop reads its output after the last: the filter decimated with its input held,
    exact for that input. For a first-order filter ``y_k = (1 - a_r)^m y_{k-1} + (1 - (1 - a_r)^m) v_k``: the loop-rate
    ``a = 1 - (1 - a_r)^m``. For the biquad, from its step response ``s[j] = 1 + 2 Re(alpha p^j)`` (``p`` a pole,
    ``alpha = N(p)/((p - 1)(p - conj p))``): ``H = 1 + (z - 1) 2 Re(beta/(z - P))`` with ``P = p^m``, ``beta = alpha
    p^(m-1)``. ``raw_hz <= 0`` is the loop rate (``m = 1``); ``m`` need not be a whole number in the formulas (the
    NLP's ``dt`` is a symbol), PX4's is (a gyro rate over ``roundf(gyro/IMU_GYRO_RATEMAX)``).

    The approximation is the rate's shape between the loop's samples: on a continuous plant the rate bends within a
    sample. Measured against the exact loop (the plant, the gyro low-pass, the difference and the filter lifted over
    the raw samples; ``bench/dpath.py``, ``bench/results/dpath_issue40.md``) on the head-to-head airframes with PX4's
    default gains: PM within 0.03 deg and GM within 0.07 dB of the exact loop (first and second order), where the
    loop-rate D path was off by up to 0.9 deg and 0.7 dB (first order) and 7.3 deg and 4.3 dB (second order).

    Examples
    --------
    >>> from tuner.firmware.laws import dgyro_filter
    >>> n, q = dgyro_filter({"dgyro_hz": 20.0, "dgyro_order": 1, "raw_hz": 0.0}, 0.0025)  # the loop rate
    >>> round(n[0], 6), round(-q[1], 6)
    (0.239057, 0.760943)
    >>> n, q = dgyro_filter({"dgyro_hz": 20.0, "dgyro_order": 1, "raw_hz": 8000.0}, 0.0025)  # 20 raw samples
    >>> round(n[0], 6)  # 1 - (1 - a_r)^20, near 1 - exp(-2 pi 20 dt) = 0.2695
    0.267812
    """
    f = fixed["dgyro_hz"]
    order = int(round(fixed.get("dgyro_order", 1.0)))
    raw = fixed.get("raw_hz", 0.0)
    if f <= 0:
        return [1, 0], [1, 0]  # no filter (the first-order form with a = 1)
    if order not in (1, 2):
        raise ValueError(f"dgyro_order must be 1 or 2, got {fixed.get('dgyro_order')!r}")
    if raw > 0:
        if f >= raw / 2:  # AlphaFilter::setCutoffFreq and LowPassFilter2p refuse it: no filtering
            return [1, 0], [1, 0]
        m, dt_r = dt * raw, 1.0 / raw
    else:
        m, dt_r = 1, dt
    if order == 1:
        if raw <= 0:
            a = alpha(f, dt)
        else:
            a = 1 - (1 - alpha(f, dt_r)) ** m
        return [a, 0], [1, -(1 - a)]
    # LowPassFilter2p: omega_n = 2 tan(pi f/fs), zeta = 1/sqrt(2), bilinear (LowPassFilter2p::set_cutoff_frequency)
    wn = 2 * _fn("tan", math.pi * f * dt_r)
    w2, t4 = wn * wn, 4 * math.sqrt(0.5) * wn
    c = w2 + t4 + 4
    b0, a1, a2 = w2 / c, (2 * w2 - 8) / c, (w2 - t4 + 4) / c
    if raw <= 0:
        return [b0, 2 * b0, b0], [1, a1, a2]
    import cmath

    p = (-a1 + cmath.sqrt(a1 * a1 - 4 * a2)) / 2  # numbers here: raw_hz and f are fixed values
    if abs(p.imag) < 1e-12 or abs(p - 1) < 1e-12:
        raise ValueError(f"IMU_DGYRO_CUTOFF {f:g} Hz at the raw rate {raw:g} Hz: the biquad's poles are not complex")
    alpha2 = b0 * (p + 1) ** 2 / ((p - 1) * (p - p.conjugate()))
    gam = alpha2 / p
    r, th = abs(p), cmath.phase(p)
    rm = r ** m
    co, si = _fn("cos", m * th), _fn("sin", m * th)
    re_p, mag2 = rm * co, rm * rm
    re_b = rm * (gam.real * co - gam.imag * si)
    re_bp = gam.real * mag2
    return ([1 + 2 * re_b, -2 * re_p - 2 * re_b - 2 * re_bp, mag2 + 2 * re_bp], [1, -2 * re_p, mag2])


def px4_coeffs(x: Sequence[Any], dt: Any, fixed: dict[str, float]) -> tuple[list, list]:
    """PX4's feedback path ``C_fb`` (numerator, denominator; highest power first) for ``x = (P, I, D, FF)``."""
    pi_num, d_num, den = _px4_parts(x, dt, fixed)
    nq, dq = _lp(fixed.get("tq_hz", 0.0), dt)
    return poly_mul(_scale(poly_add(pi_num, d_num), fixed["K"]), nq), poly_mul(den, dq)


def px4_ref_coeffs(x: Sequence[Any], dt: Any, fixed: dict[str, float]) -> tuple[list, list]:
    """PX4's setpoint path ``C_r = (K (P + I dt/(z - 1)) + FF) H_q`` over the feedback path's denominator."""
    pi_num, _, den = _px4_parts(x, dt, fixed)
    nq, dq = _lp(fixed.get("tq_hz", 0.0), dt)
    return poly_mul(poly_add(_scale(pi_num, fixed["K"]), _scale(den, x[3])), nq), poly_mul(den, dq)


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
    if fixed.get("dff", 0.0) != 0 and fixed["fltt_hz"] <= 0:
        nt, dtt = [1, 0], [1, 0]  # no target filter: z/z, so that D_FF's 1 - 1/z has its pole at 0 in the realisation
    return poly_mul(num, ne), poly_mul(den, de), nt, dtt


def ardupilot_coeffs(x: Sequence[Any], dt: Any, fixed: dict[str, float]) -> tuple[list, list]:
    """ArduPilot's feedback path ``C_fb = PID H_E`` over the common denominator (the target filter's pole
    included, cancelled: the realisation of both paths shares it)."""
    num, den, _, dtt = _ardupilot_parts(x, dt, fixed)
    return poly_mul(num, dtt), poly_mul(den, dtt)


def ardupilot_ref_coeffs(x: Sequence[Any], dt: Any, fixed: dict[str, float]) -> tuple[list, list]:
    """ArduPilot's target path ``C_r = (PID H_E + FF) H_T + D_FF (1 - 1/z) H_T/dt`` over the feedback path's
    denominator."""
    num, den, nt, dtt = _ardupilot_parts(x, dt, fixed)
    out = poly_mul(poly_add(num, _scale(den, x[3])), nt)
    dff = fixed.get("dff", 0.0)
    if dff != 0:  # (1 - 1/z) H_T = a_T (z - 1)/(z - (1 - a_T)): over dtt, the numerator a_T (z - 1)
        a_t = alpha(fixed["fltt_hz"], dt) if fixed["fltt_hz"] > 0 else 1.0
        out = poly_add(out, poly_mul(_scale([1, -1], dff * a_t / dt), den))
    return out, poly_mul(den, dtt)
