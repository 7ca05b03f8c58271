"""Controller structures: named parameters <-> transfer function.

Every structure is written once, with plain arithmetic on its parameters, so the
same coefficient formulas serve numbers (numpy) and symbols (CasADi ``SX``): the
optimiser and the verifier build the controller the same way.

Continuous forms and the discretisation used at sample time ``dt``:

==========  ==========================================  ===============================================
structure   continuous C(s)                             discrete C(z) at dt
==========  ==========================================  ===============================================
p           Kp                                          Kp
pi          Kp + Ki/s                                   Kp + Ki*dt*z/(z-1)            (backward Euler)
pd          Kp + Kd*s/(Tf*s+1)                          Kp + Kd*(z-1)/((Tf+dt)*z-Tf)  (backward Euler)
pid         Kp + Ki/s + Kd*s/(Tf*s+1)                   sum of the two rows above
pid_z       --                                          K*(z^2+a1*z+a2)/(z*(z-1))     (the thesis form)
pid2        u = Kp(b r - y) + Ki/s (r - y)              the pid's discretisation of each term: C_fb = pid's
            + Kd s/(Tf s+1) (c r - y)                   C(z); C_r = Kp b + Ki*dt*z/(z-1)
            (2-DOF: C_fb on -y = pid; C_r on r =        + Kd c (z-1)/((Tf+dt)*z-Tf)  (b in [0, 2], c in [0, 1])
            Kp b + Ki/s + Kd c s/(Tf s+1))
pid_mf2     (Kp + Ki/s + Kd*s)/(Tf^2 s^2 + sqrt2 Tf s + 1)  [Kp + Ki*dt*z/(z-1) + Kd*(z-1)/(dt*z)] * F(z),
                                                        F = the filter by Tustin  (DyadControlSystems'
                                                        form; Tf > 0; a PID with a second-order
                                                        measurement filter; ``pidf2`` is its deprecated
                                                        alias)
lead, lag   K*(s/wz+1)/(s/wp+1)                         K*(1-pd)/(1-zd)*(z-zd)/(z-pd), zd=exp(-wz*dt),
                                                        pd=exp(-wp*dt)                (matched, DC gain K)
leadlag     lead(K, wz1, wp1) * lag(1, wz2, wp2)        product of the matched forms
==========  ==========================================  ===============================================

A lead has ``wp > wz``; a lag has ``wp < wz``; these orderings are part of the
structure (``orderings``) and are enforced by the search and the NLP.

Two-degree-of-freedom structures (``pid2``) act on the reference and the measurement separately:
``u = C_r r - C_fb y``. ``C_fb`` (what acts on ``-y``: the feedback, from which margins, Ms, Mt, Mks and the
load response follow) is ``num/den`` as for every structure; the reference path ``C_r`` has the same
denominator (the shared integrator and filter) and its own numerator ``num_r`` (:attr:`ControllerTF.num_r`).
The loop is realised with both inputs on one set of states (:meth:`ControllerTF.ref_ss`), so the steady state
is exact.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import InvalidControllerError, TunerError
from .firmware import laws
from .firmware.registry import firmwares
from .lti import SS, Zpk, realize, roots_of, trim_leading
from .plant import MAX_ORDER, check_dt, tf_freqresp
from .tolerances import SAME_COEFF_RTOL

GAIN_SPAN = 100.0
MAX_CONTROLLER_ORDER = 2 * MAX_ORDER  # one limit for every form (expression, coefficients): 40
MAX_RAW_GYRO_HZ = 100_000.0  # raw_hz (PX4's raw gyro rate) at most this: 32 kHz is the fastest gyro PX4 drives

__all__ = [
    "GAIN_SPAN",
    "MAX_CONTROLLER_ORDER",
    "ControllerTF",
    "Structure",
    "STRUCTURES",
    "get_structure",
    "DEPRECATED_STRUCTURES",
    "deprecation_note",
    "controller_tf",
    "controller_from_expr",
    "controller_from_coeffs",
]


@dataclass(frozen=True, eq=False)
class ControllerTF:
    """A controller transfer function ``num/den`` (highest power first), continuous or at ``dt``.

    Build it validated with :func:`controller_from_coeffs`, :func:`controller_from_expr` or
    :func:`controller_tf`; a tune's is ``TuneResult.controller``.

    Examples
    --------
    >>> from tuner import controller_from_coeffs
    >>> c = controller_from_coeffs([2.0, 2.0], [1.0, 0.0], dt=None)  # 2 (s + 1) / s
    >>> c.dt, [float(z.real) for z in c.zpk.zeros], c.zpk.gain
    (None, [-1.0], 2.0)
    >>> abs(complex(c.freqresp([1.0])[0]))  # |2 (j + 1) / j| = 2 sqrt(2)  # doctest: +ELLIPSIS
    2.828...
    >>> c.to_dict()
    {'num': [2.0, 2.0], 'den': [1.0, 0.0], 'dt': None}
    """

    num: np.ndarray
    den: np.ndarray
    dt: float | None = None
    #: 2-DOF controllers: the reference path's numerator over the same ``den`` (``u = C_r r - C y``); None: 1-DOF
    num_r: np.ndarray | None = None
    #: 2-DOF: an explicit realisation ``(A, B, C, D, Br, Dr)`` of ``C`` (B, D) and ``C_r`` (Br, Dr) on shared states
    realization: tuple | None = field(default=None, repr=False)
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def two_dof(self) -> bool:
        """Whether the controller has its own reference path ``num_r/den`` (a 2-DOF controller)."""
        return self.num_r is not None

    @property
    def zpk(self) -> Zpk:
        """Zeros, poles and gain (a controller is low order: its roots are well conditioned)."""
        if "zpk" not in self._cache:
            n, d = trim_leading(np.asarray(self.num)), trim_leading(np.asarray(self.den))
            zeros, poles = roots_of(n), roots_of(d)  # None: not computable in double precision
            with np.errstate(all="ignore"):
                gain = float(n[0] / d[0]) if n.size else 0.0
            if zeros is None or poles is None or not np.isfinite(gain):
                raise InvalidControllerError(
                    "the controller's zeros, poles or gain cannot be computed in double precision (its coefficients "
                    f"span too many decades: num {self.num.tolist()}, den {self.den.tolist()}): rescale them",
                    field="controller")
            self._cache["zpk"] = Zpk(zeros, poles, gain)
        return self._cache["zpk"]

    def ss(self) -> SS:
        """A balanced cascade realisation (in s, or in z at ``dt``); a 2-DOF controller: the feedback part of its
        two-input realisation (:meth:`ref_ss`)."""
        if "ss" not in self._cache:
            if self.two_dof:
                A, B, C, D, _, _ = self._two_input()
                self._cache["ss"] = SS(A, B, C, D)
            else:
                self._cache["ss"] = realize(self.zpk, discrete=self.dt is not None)
        return self._cache["ss"]

    def ref_ss(self) -> SS:
        """The reference path on the same states as :meth:`ss` (same ``A``, ``C``; its own ``B``, ``D``): the
        controller's state is driven by ``B e`` (1-DOF, ``e = r - y``) or ``Br r - B y`` (2-DOF)."""
        if not self.two_dof:
            return self.ss()
        if "ref_ss" not in self._cache:
            A, _, C, _, Br, Dr = self._two_input()
            self._cache["ref_ss"] = SS(A, Br, C, Dr)
        return self._cache["ref_ss"]

    def reference(self) -> ControllerTF:
        """``C_r`` as a 1-DOF transfer function (``self`` for a 1-DOF controller)."""
        if not self.two_dof:
            return self
        return ControllerTF(num=np.asarray(self.num_r, float), den=self.den, dt=self.dt)

    def _two_input(self) -> tuple:
        if self.realization is not None:
            return self.realization
        if "two_input" not in self._cache:
            self._cache["two_input"] = _observable_pair(self.num, self.num_r, self.den)
        return self._cache["two_input"]

    def without_dc_cancellation(self) -> ControllerTF:
        """This controller with a pole at DC (``s = 0``, ``z = 1``) that a zero of each of its paths cancels exactly
        divided out: an integrator whose gain is 0 (a PI at ``Ki = 0``, a firmware law at ``I = 0``), whose state would
        be a mode of the loop that nothing drives and nothing sees. ``self`` when there is none.

        Examples
        --------
        >>> from tuner import controller_from_coeffs
        >>> c = controller_from_coeffs([2.0, -2.0], [1.0, -1.0], dt=0.1)  # 2 (z - 1)/(z - 1): a P of 2
        >>> r = c.without_dc_cancellation()
        >>> r.num.tolist(), r.den.tolist()
        ([2.0], [1.0])
        """
        x0 = 1.0 if self.dt is not None else 0.0
        polys = [np.asarray(self.den, float), np.asarray(self.num, float)]
        if self.two_dof:
            polys.append(np.asarray(self.num_r, float))
        if any(p.size < 2 for p in polys):
            return self
        if not all(abs(float(np.polyval(p, x0))) <= 1e-12 * float(np.max(np.abs(p))) for p in polys):
            return self
        red = [np.polydiv(p, [1.0, -x0])[0] for p in polys]
        return ControllerTF(num=red[1], den=red[0], dt=self.dt, num_r=red[2] if self.two_dof else None)

    def freqresp(self, w: np.ndarray) -> np.ndarray:
        """``C(j w)`` (continuous) or ``C(exp(j w dt))`` at the frequencies ``w``, rad/s."""
        return tf_freqresp(self.num, self.den, w, dt=self.dt)

    def to_dict(self) -> dict[str, Any]:
        """``{"num": [...], "den": [...], "dt": ...}`` (JSON-ready; a 2-DOF controller also ``num_r``)."""
        out = {"num": [float(c) for c in self.num], "den": [float(c) for c in self.den], "dt": self.dt}
        if self.two_dof:
            out["num_r"] = [float(c) for c in self.num_r]
        return out


def _observable_pair(num: np.ndarray, num_r: np.ndarray, den: np.ndarray) -> tuple:
    """A balanced observable-canonical realisation of ``num/den`` and ``num_r/den`` on shared states (a 2-DOF
    controller given by its coefficients only; the structures give their own parallel form)."""
    den = np.trim_zeros(np.asarray(den, float), "f")
    m = den.size - 1
    a = den[1:] / den[0]

    def cols(n):
        n = np.asarray(n, float)
        if n.size > den.size:
            raise InvalidControllerError("the reference path is improper: its numerator is longer than den",
                                         field="num_r")
        b = np.concatenate([np.zeros(den.size - n.size), n]) / den[0]
        return b[1:] - b[0] * a, float(b[0])

    B, D = cols(num)
    Br, Dr = cols(num_r)
    A = np.zeros((m, m))
    if m:
        A[:, 0] = -a
        A[:-1, 1:] = np.eye(m - 1)
    C = np.zeros(m)
    if m:
        C[0] = 1.0
        from scipy import linalg

        _, (sc, _) = linalg.matrix_balance(A, permute=False, separate=True)
        A = A / sc[:, None] * sc[None, :]
        B, Br, C = B / sc, Br / sc, C * sc
    return A, B, C, D, Br, Dr


# -- polynomial helpers that work on numbers and on CasADi symbols -------------------------

_pmul, _padd = laws.poly_mul, laws.poly_add  # one pair of polynomial helpers (numbers and CasADi symbols)


def _sum_fractions(terms: Sequence[tuple[list[Any], list[Any]]]) -> tuple[list[Any], list[Any]]:
    num, den = terms[0]
    for n2, d2 in terms[1:]:
        num, den = _padd(_pmul(num, d2), _pmul(n2, den)), _pmul(den, d2)
    return num, den


# -- the structures ----------------------------------------------------------------------

Coeffs = tuple[list[Any], list[Any]]


def _p(x, dt, exp):
    return [x[0]], [1]


def _pi_terms(kp, ki, dt):
    if dt is None:
        return [([kp], [1]), ([ki], [1, 0])]
    return [([kp], [1]), ([ki * dt, 0], [1, -1])]


def _d_term(kd, tf, dt):
    if dt is None:
        return ([kd, 0], [tf, 1])
    return ([kd, -kd], [tf + dt, -tf])


def _pi(x, dt, exp):
    return _sum_fractions(_pi_terms(x[0], x[1], dt))


def _pd(x, dt, exp):
    return _sum_fractions([([x[0]], [1]), _d_term(x[1], x[2], dt)])


def _pid(x, dt, exp):
    return _sum_fractions(_pi_terms(x[0], x[1], dt) + [_d_term(x[2], x[3], dt)])


def _pid2(x, dt, exp):
    """The feedback part of pid2 (what acts on -y): exactly pid's controller."""
    return _pid(x[:4], dt, exp)


def _pid2_ref(x, dt, exp):
    """pid2's reference path over pid's denominator: Kp b + Ki/s + Kd c s/(Tf s + 1) (at dt: pid's forms)."""
    kp, ki, kd, tf, b, c = x
    num, den = _sum_fractions(_pi_terms(kp * b, ki, dt) + [_d_term(kd * c, tf, dt)])
    return num, den


def _pid2_realization(x, dt):
    """Parallel form of pid2 on two states, the integrator and the derivative filter's low-passed input, both
    paths on them: ``(A, B, C, D, Br, Dr)`` (``B, D``: the feedback C acting on -y; ``Br, Dr``: C_r on r)."""
    kp, ki, kd, tf, b, c = (float(v) for v in x)
    if dt is None:  # xi' = e_i; xf' = (v - xf)/Tf, D = Kd/Tf (v - xf)
        A = np.diag([0.0, -1.0 / tf])
        B, Br = np.array([1.0, 1.0 / tf]), np.array([1.0, c / tf])
        C = np.array([ki, -kd / tf])
        return A, B, C, kp + kd / tf, Br, kp * b + kd * c / tf
    # backward Euler: I = Ki dt (s_i + e), s_i+ = s_i + e; D = g (v - q), q+ = a q + (1 - a) v, a = Tf/(Tf+dt)
    a, g = tf / (tf + dt), kd / (tf + dt)
    A = np.diag([1.0, a])
    B, Br = np.array([1.0, 1.0 - a]), np.array([1.0, c * (1.0 - a)])
    C = np.array([ki * dt, -g])
    return A, B, C, kp + ki * dt + g, Br, kp * b + ki * dt + g * c


_SQRT2 = 2.0 ** 0.5


def _pid_mf2(x, dt, exp):
    """(Kp + Ki/s + Kd s) / (Tf^2 s^2 + sqrt(2) Tf s + 1); at dt: the backward-Euler PID with a one-sample
    derivative times the filter by Tustin (unit DC gain, no trigonometric function of the parameters)."""
    kp, ki, kd, tf = x
    if dt is None:
        return [kd, kp, ki], _pmul([tf * tf, _SQRT2 * tf, 1], [1, 0])
    pn = [kp + ki * dt + kd / dt, -(kp + 2 * kd / dt), kd / dt]  # over z (z - 1)
    a, b = tf * tf * 4 / (dt * dt), _SQRT2 * tf * 2 / dt
    return _pmul(pn, [1, 2, 1]), _pmul([1, -1, 0], [a + b + 1, 2 - 2 * a, a - b + 1])


def _pid_z(x, dt, exp):
    k, a1, a2 = x
    return [k, k * a1, k * a2], [1, -1, 0]


def _first_order(k, wz, wp, dt, exp):
    if dt is None:
        # K (s/wz + 1)/(s/wp + 1) = K*wp/wz * (s + wz)/(s + wp)
        return [k * wp, k * wp * wz], [wz, wz * wp]
    zd, pd = exp(-wz * dt), exp(-wp * dt)
    g = k * (1 - pd) / (1 - zd)
    return [g, -g * zd], [1, -pd]


def _leadlag1(x, dt, exp):
    return _first_order(x[0], x[1], x[2], dt, exp)


def _leadlag(x, dt, exp):
    n1, d1 = _first_order(x[0], x[1], x[2], dt, exp)
    n2, d2 = _first_order(1, x[3], x[4], dt, exp)
    return _pmul(n1, n2), _pmul(d1, d2)


@dataclass(frozen=True)
class Structure:
    """A controller structure.

    ``kinds`` gives each parameter's role: ``"gain"`` (any sign, scaled by the
    plant's gain), ``"freq"`` (rad/s, > 0), ``"time"`` (s, >= 0), ``"coef"``
    (dimensionless polynomial coefficient) or ``"weight"`` (a 2-DOF setpoint weight, searched
    linearly on ``weight_ranges``).
    """

    name: str
    params: tuple[str, ...]
    kinds: tuple[str, ...]
    coeffs: Callable[[Sequence[Any], float | None, Callable[[Any], Any]], Coeffs] = field(repr=False)
    discrete_only: bool = False
    orderings: tuple[tuple[str, str], ...] = ()  # (a, b): a < b
    integrating: bool = False
    gain_units: tuple[int, ...] = ()  # per parameter: the gain scales as K0 * w0**unit (Ki: +1, Kd: -1)
    positive_time: bool = False  # time constants must be > 0 in discrete time too (pid_mf2's filter)
    #: 2-DOF: the reference path's coefficients (numerator over the same denominator as ``coeffs``)
    ref_coeffs: Callable[[Sequence[Any], float | None, Callable[[Any], Any]], Coeffs] | None = field(
        default=None, repr=False)
    #: 2-DOF: an explicit two-input realisation from the parameters (numbers), see ControllerTF.realization
    realize2: Callable[[Sequence[float], float | None], tuple] | None = field(default=None, repr=False)
    #: per parameter of kind "weight": its range (lo, hi)
    weight_ranges: tuple[tuple[str, float, float], ...] = ()
    #: a firmware law (``px4_rate``, ``ardupilot_rate``): what the vehicle fixes, ``(name, value)``; never searched,
    #: carried in every result's gains (so ``get_structure(name).tf(gains, dt)`` rebuilds the exact law)
    fixed: tuple[tuple[str, float], ...] = ()
    #: a firmware law's coefficient functions ``(coeffs, ref_coeffs)``, each ``f(x, dt, fixed_dict)``
    law: tuple[Callable, Callable] | None = field(default=None, repr=False)
    #: every parameter is >= 0 (the firmware's own parameter ranges)
    nonneg: bool = False
    #: the integral gain's name (None: no integral action, or a form without one named gain)
    integral: str | None = None
    #: the firmware this structure's parameters belong to (a registered firmware's name: "px4", "ardupilot", ...),
    #: None for the generic forms
    firmware: str | None = None
    #: a firmware law's documented parameter ranges on one axis, ``(name, lo, hi)`` (the ground station's metadata,
    #: :func:`tuner.firmware.names.law_ranges`): the search stays inside them, so that a design can be written to
    #: the vehicle's parameter file; empty: no ranges (the generic structures)
    ranges: tuple[tuple[str, float, float], ...] = ()
    #: the axis whose ranges :attr:`ranges` holds (a firmware law), None otherwise
    axis: str | None = None
    #: a 2-DOF structure's parameters that act on the setpoint path alone (pid2's ``b``, ``c``; a firmware law's
    #: ``FF``): the feedback, and so the margins and the load response, do not depend on them
    setpoint: tuple[str, ...] = ()

    @property
    def two_dof(self) -> bool:
        """Whether the structure acts on the reference and the measurement separately (pid2)."""
        return self.ref_coeffs is not None

    @property
    def fixed_values(self) -> dict[str, float]:
        """What the vehicle fixes (a firmware law), by name; empty for the generic structures."""
        return dict(self.fixed)

    @property
    def key(self) -> str:
        """The structure's identity for caches: its name, with the fixed values of a firmware law."""
        if not self.fixed:
            return self.name
        return self.name + "(" + ",".join(f"{k}={v!r}" for k, v in self.fixed) + ")"

    def with_fixed(self, values: Mapping[str, float]) -> Structure:
        """This firmware law with some of its fixed values replaced (validated), e.g. a vehicle's ``K``."""
        if not self.fixed:
            if values:
                raise InvalidControllerError(f"{self.name} has no fixed parameters; got {sorted(values)}",
                                             field="gains")
            return self
        names = dict(self.fixed)
        unknown = set(values) - set(names)
        if unknown:
            raise InvalidControllerError(f"{self.name} fixes {sorted(names)}; unknown {sorted(unknown)}",
                                         field="gains")
        new = dict(names)
        for k, v in values.items():
            try:
                f = float(v)
            except (TypeError, ValueError) as e:
                raise InvalidControllerError(f"{self.name}: {k} must be a number, got {v!r}",
                                             field=("gains", k)) from e
            low = 0.0 if k != "K" else None
            if not math.isfinite(f) or (low is not None and f < low) or (k == "K" and f <= 0):
                raise InvalidControllerError(f"{self.name}: {k} must be finite and "
                                             + ("> 0" if k == "K" else ">= 0") + f", got {v!r}",
                                             field=("gains", k))
            if k == "raw_hz" and f > MAX_RAW_GYRO_HZ:  # (a rate beyond any gyro's: the D filter's poles underflow)
                raise InvalidControllerError(f"{self.name}: raw_hz must be at most {MAX_RAW_GYRO_HZ:g} Hz (the raw "
                                             f"gyro rate; PX4's fastest gyros sample at 32 kHz), got {v!r}",
                                             field=("gains", k))
            if k == "dgyro_order" and f not in (1.0, 2.0):  # PX4's D filter: AlphaFilter or LowPassFilter2p
                raise InvalidControllerError(f"{self.name}: dgyro_order must be 1 (first order, PX4 v1.13 on) or 2 "
                                             f"(second order, the releases before), got {v!r}", field=("gains", k))
            new[k] = f
        if new == names:
            return self
        return _firmware_structure(self, tuple((k, new[k]) for k, _ in self.fixed))

    def with_ranges(self, axis: str) -> Structure:
        """This firmware law with the documented ranges of its parameters on ``axis`` (``roll``, ``pitch``,
        ``yaw``): the search keeps every tuned parameter inside them (:func:`tuner.firmware.names.law_ranges`)."""
        if self.firmware is None:
            return self
        import dataclasses

        from .firmware.names import law_ranges

        r = law_ranges(self.firmware, axis)
        rng = tuple((p, float(r[p][0]), float(r[p][1])) for p in self.params if p in r)
        if rng == self.ranges and axis == self.axis:
            return self
        return dataclasses.replace(self, ranges=rng, axis=axis)

    def param_range(self, p: str) -> tuple[float, float] | None:
        """The documented range ``(lo, hi)`` of parameter ``p`` (a firmware law's, on its axis), or None."""
        return next(((lo, hi) for q, lo, hi in self.ranges if q == p), None)

    def weight_range(self, p: str) -> tuple[float, float]:
        """The (lower, upper) range of the setpoint weight ``p`` (pid2's ``b``, ``c``)."""
        return next((lo, hi) for q, lo, hi in self.weight_ranges if q == p)

    def gain_scale(self, k0: float, w0: float) -> np.ndarray:
        """Each parameter's natural scale for a plant of gain scale ``k0`` at frequency ``w0``: ``k0 * w0**unit``."""
        units = self.gain_units or (0,) * len(self.params)
        return np.array([k0 * w0 ** u for u in units])

    def tf(self, values: Mapping[str, float] | Sequence[float], dt: float | None) -> ControllerTF:
        """The controller's transfer function for parameter ``values`` (by name or in order), continuous or at
        ``dt``; validated (kinds, signs, a proper result)."""
        if self.fixed and isinstance(values, Mapping):
            fx = {k: values[k] for k, _ in self.fixed if k in values}
            if fx:
                st = self.with_fixed(fx)
                if st is not self:
                    return st.tf({k: v for k, v in values.items() if k not in fx}, dt)
        x = self.vector(values)
        dt = check_dt(dt)
        if self.discrete_only and dt is None:
            raise InvalidControllerError(f"structure {self.name!r} is discrete: give dt", field="dt")
        if dt is None or self.positive_time:
            zero_t = [p for k, p, v in zip(self.kinds, self.params, x) if k == "time" and v == 0]
            if zero_t:
                why = "in continuous time (a pure derivative is improper)" if dt is None else \
                    "(the measurement filter's time constant)"
                raise InvalidControllerError(
                    f"{self.name}: {zero_t[0]} must be > 0 {why}",
                    field=("gains", zero_t[0]),
                )
        with np.errstate(over="ignore", invalid="ignore"):  # overflowing parameters: refused just below
            num, den = self.coeffs(x, dt, np.exp)
            num = np.asarray(num, dtype=float)
            den = np.asarray(den, dtype=float)
        if not (np.all(np.isfinite(num)) and np.all(np.isfinite(den))) or den[0] == 0:
            raise InvalidControllerError(f"{self.name} parameters {self.named(x)} give an invalid transfer function",
                                         field="gains")
        with np.errstate(all="ignore"):
            nn, dn = num / den[0], den / den[0]
        if not (np.all(np.isfinite(nn)) and np.all(np.isfinite(dn))):  # finite, but not once made monic
            raise InvalidControllerError(f"{self.name} parameters {self.named(x)} give coefficients beyond double "
                                         "precision once the denominator is made monic: rescale them",
                                         field="gains")
        no_integral = self.integral is not None and x[self.params.index(self.integral)] == 0
        if self.ref_coeffs is None:  # checked like every other controller: finite roots and realisation
            c = ControllerTF(num=nn, den=dn, dt=dt)
            # an integrator of gain 0 is no state of the loop (else: a mode at DC nothing drives, "not stable")
            return _checked(c.without_dc_cancellation() if no_integral else c, "gains")
        num_r, den_r = self.ref_coeffs(x, dt, np.exp)
        num_r, den_r = np.asarray(num_r, dtype=float), np.asarray(den_r, dtype=float)
        if not np.all(np.isfinite(num_r)) or not np.allclose(den_r, den, rtol=SAME_COEFF_RTOL, atol=0):
            raise InvalidControllerError(f"{self.name} parameters {self.named(x)} give an invalid reference path",
                                         field="gains")
        c = ControllerTF(num=num / den[0], den=den / den[0], dt=dt, num_r=num_r / den[0])
        if no_integral:  # (as above: the reduced controller, realised from its coefficients)
            reduced = c.without_dc_cancellation()
            if reduced is not c:
                return reduced
        real = None
        if self.realize2 is not None:
            A, B, C, D, Br, Dr = self.realize2(x, dt)
            real = (A, B, C, float(D), Br, float(Dr))
        return ControllerTF(num=num / den[0], den=den / den[0], dt=dt, num_r=num_r / den[0], realization=real)

    def vector(self, values: Mapping[str, float] | Sequence[float]) -> np.ndarray:
        """``values`` (a mapping by name, or a sequence in :attr:`params` order) as a validated array."""
        if isinstance(values, Mapping):
            values = {k: v for k, v in values.items() if k not in dict(self.fixed)}
            unknown = set(values) - set(self.params)
            missing = [p for p in self.params if p not in values]
            if unknown or missing:
                raise InvalidControllerError(
                    f"{self.name} takes parameters {list(self.params)}; "
                    + (f"missing {missing}" if missing else f"unknown {sorted(unknown)}"), field="gains"
                )
            vals = [values[p] for p in self.params]
        else:
            vals = list(values)
            if len(vals) != len(self.params):
                raise InvalidControllerError(f"{self.name} takes {len(self.params)} parameters {list(self.params)}",
                                             field="gains")
        try:
            x = np.asarray(vals, dtype=float)
        except (TypeError, ValueError) as e:
            raise InvalidControllerError(f"{self.name} parameters must be numbers", field="gains") from e
        if not np.all(np.isfinite(x)):
            raise InvalidControllerError(f"{self.name} parameters must be finite, got {self.named(x)}", field="gains")
        for kind, p, v in zip(self.kinds, self.params, x):
            if kind == "freq" and v <= 0:
                raise InvalidControllerError(f"{self.name}: {p} is a frequency and must be > 0, got {v}",
                                             field=("gains", p))
            if kind == "time" and v < 0:
                raise InvalidControllerError(f"{self.name}: {p} is a time constant and must be >= 0, got {v}",
                                             field=("gains", p))
            if self.nonneg and v < 0:
                raise InvalidControllerError(f"{self.name}: {p} must be >= 0 (the firmware's range), got {v}",
                                             field=("gains", p))
            if kind == "weight" and v < 0:
                raise InvalidControllerError(f"{self.name}: {p} is a setpoint weight and must be >= 0, got {v}",
                                             field=("gains", p))
        return x

    def named(self, x: Sequence[float]) -> dict[str, float]:
        """The parameter vector ``x`` as ``{name: value}`` (a firmware law: its fixed values after them)."""
        return {**{p: float(v) for p, v in zip(self.params, x)}, **dict(self.fixed)}


def _law_coeffs(x, dt, exp, *, law, fixed):
    return law(x, dt, fixed)


def _firmware_structure(base: Structure, fixed: tuple[tuple[str, float], ...]) -> Structure:
    """``base`` (a firmware law) with its coefficient functions bound to ``fixed``."""
    import dataclasses
    from functools import partial

    fx = dict(fixed)
    return dataclasses.replace(base, fixed=fixed, coeffs=partial(_law_coeffs, law=base.law[0], fixed=fx),
                               ref_coeffs=partial(_law_coeffs, law=base.law[1], fixed=fx))


def _firmware(name: str, law: tuple[Callable, Callable], fixed: tuple[tuple[str, float], ...], firmware: str
              ) -> Structure:
    st = Structure(name, ("P", "I", "D", "FF"), ("gain", "gain", "gain", "gain"), _p, discrete_only=True,
                   integrating=True, gain_units=(0, 1, -1, 0), ref_coeffs=_p, law=law, nonneg=True, integral="I",
                   firmware=firmware, setpoint=("FF",))
    # the documented ranges of the default axis (roll; a vehicle's axis rebinds them: tuner.firmware.bind)
    return _firmware_structure(st, fixed).with_ranges("roll")


STRUCTURES: dict[str, Structure] = {
    s.name: s
    for s in (
        Structure("p", ("Kp",), ("gain",), _p),
        Structure("pi", ("Kp", "Ki"), ("gain", "gain"), _pi, integrating=True, gain_units=(0, 1), integral="Ki"),
        Structure("pd", ("Kp", "Kd", "Tf"), ("gain", "gain", "time"), _pd, gain_units=(0, -1, 0)),
        Structure("pid", ("Kp", "Ki", "Kd", "Tf"), ("gain", "gain", "gain", "time"), _pid, integrating=True,
                  gain_units=(0, 1, -1, 0), integral="Ki"),
        Structure("pid_z", ("K", "a1", "a2"), ("gain", "coef", "coef"), _pid_z, discrete_only=True, integrating=True),
        Structure("pid2", ("Kp", "Ki", "Kd", "Tf", "b", "c"), ("gain", "gain", "gain", "time", "weight", "weight"),
                  _pid2, integrating=True, gain_units=(0, 1, -1, 0, 0, 0), ref_coeffs=_pid2_ref, integral="Ki",
                  realize2=_pid2_realization, weight_ranges=(("b", 0.0, 2.0), ("c", 0.0, 1.0)), setpoint=("b", "c")),
        Structure("pid_mf2", ("Kp", "Ki", "Kd", "Tf"), ("gain", "gain", "gain", "time"), _pid_mf2, integrating=True,
                  gain_units=(0, 1, -1, 0), positive_time=True, integral="Ki"),
        Structure("lead", ("K", "wz", "wp"), ("gain", "freq", "freq"), _leadlag1, orderings=(("wz", "wp"),)),
        Structure("lag", ("K", "wz", "wp"), ("gain", "freq", "freq"), _leadlag1, orderings=(("wp", "wz"),)),
        Structure(
            "leadlag",
            ("K", "wz1", "wp1", "wz2", "wp2"),
            ("gain", "freq", "freq", "freq", "freq"),
            _leadlag,
            orderings=(("wz1", "wp1"), ("wp2", "wz2")),
        ),
        # every registered firmware's rate law (tuner.firmware.registry: px4_rate, ardupilot_rate, ...)
        *(_firmware(fw.structure, (fw.coeffs, fw.ref_coeffs), fw.fixed, fw.name) for fw in firmwares()),
    )
}


#: deprecated structure names (accepted for one release, with a DeprecationWarning): old -> new
DEPRECATED_STRUCTURES: dict[str, str] = {"pidf2": "pid_mf2"}


def deprecation_note(name: str) -> str | None:
    """The note for a deprecated structure name, or None."""
    new = DEPRECATED_STRUCTURES.get(name)
    if new is None:
        return None
    return (f"structure {name!r} is deprecated (MATLAB's pidf2 is its 2-DOF PIDF): it is {new!r}, a PID with a "
            f"second-order measurement filter; {name!r} is accepted for one release")


def get_structure(name: str) -> Structure:
    """The structure called ``name`` (a key of :data:`STRUCTURES`): its parameters, kinds and transfer function.

    Raises :class:`~tuner.errors.InvalidControllerError` (``field == ("structure",)``) for an unknown name; a
    deprecated name (``pidf2``) gives its new structure with a ``DeprecationWarning``.

    Examples
    --------
    >>> from tuner import STRUCTURES, get_structure
    >>> get_structure("pid").params
    ('Kp', 'Ki', 'Kd', 'Tf')
    >>> sorted(s for s in STRUCTURES if not get_structure(s).firmware)  # and every registered firmware's rate law
    ['lag', 'lead', 'leadlag', 'p', 'pd', 'pi', 'pid', 'pid2', 'pid_mf2', 'pid_z']
    >>> {"px4_rate", "ardupilot_rate"} <= set(STRUCTURES)
    True
    >>> get_structure("pdi")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    tuner.errors.InvalidControllerError: unknown structure 'pdi'; choose one of [...]
    """
    if name in DEPRECATED_STRUCTURES:
        import warnings

        warnings.warn(deprecation_note(name), DeprecationWarning, stacklevel=2)
        return STRUCTURES[DEPRECATED_STRUCTURES[name]]
    try:
        return STRUCTURES[name]
    except KeyError:
        raise InvalidControllerError(
            f"unknown structure {name!r}; choose one of {sorted(STRUCTURES)}", field="structure"
        ) from None


def controller_tf(structure: str, gains: Mapping[str, float], *, dt: float | None) -> ControllerTF:
    """Transfer function of ``structure`` with named ``gains`` (continuous, or at ``dt``).

    Examples
    --------
    >>> from tuner import controller_tf
    >>> c = controller_tf("pi", {"Kp": 2.0, "Ki": 2.0}, dt=None)  # Kp + Ki/s = 2 (s + 1) / s
    >>> [float(v) for v in c.num], [float(v) for v in c.den]
    ([2.0, 2.0], [1.0, 0.0])
    """
    return get_structure(structure).tf(gains, dt)


def controller_from_expr(text: str, *, dt: float | None) -> ControllerTF:
    """A controller from an expression in ``s`` (continuous) or ``z`` (needs ``dt``).

    The text is parsed, never evaluated; an improper controller, an ``s`` expression with ``dt`` or a ``z``
    expression without it raise :class:`~tuner.errors.InvalidControllerError` naming the field.

    Examples
    --------
    >>> from tuner import controller_from_expr
    >>> c = controller_from_expr("2*(s + 1)/s", dt=None)
    >>> [float(v) for v in c.num], [float(v) for v in c.den]
    ([2.0, 2.0], [1.0, 0.0])
    >>> controller_from_expr("2*(z - 0.9)/(z - 1)", dt=0.01).dt
    0.01
    >>> controller_from_expr("z/(z - 1)", dt=None)
    Traceback (most recent call last):
    ...
    tuner.errors.InvalidControllerError: controller is in z: give its sample time dt
    """
    from .expr import parse_tf_expr

    dt = check_dt(dt)
    try:
        p = parse_tf_expr(text)
    except TunerError as e:
        raise e.at("expr") from None
    if p.var == "z" and dt is None:
        raise InvalidControllerError("controller is in z: give its sample time dt", field="dt")
    if p.var == "s" and dt is not None:
        raise InvalidControllerError(
            "controller is in s but a sample time dt was given: write the digital controller in z", field="expr"
        )
    if p.num.size > p.den.size:
        raise InvalidControllerError("controller is improper (more zeros than poles): add a filter pole",
                                     field="expr")
    _check_order(p.den.size - 1, "expr")
    return _checked(ControllerTF(num=p.num, den=p.den, dt=dt), "expr")


def _check_order(order: int, field: str) -> None:
    if order > MAX_CONTROLLER_ORDER:
        raise InvalidControllerError(f"controller order {order} is above the limit {MAX_CONTROLLER_ORDER} "
                                     "(the same for an expression and for coefficients): reduce the order",
                                     field=field)


def _checked(c: ControllerTF, field: str) -> ControllerTF:
    """``c`` if its zeros, poles and gain are finite (the factored form every computation uses)."""
    try:
        c.zpk  # noqa: B018 - computed and checked finite here, cached for every later use
    except InvalidControllerError as e:
        raise InvalidControllerError(str(e), field=field) from None
    with np.errstate(all="ignore"):
        ss = c.ss()
    if not _finite_ss(ss):
        raise InvalidControllerError("the controller's state-space realisation overflows (its gain and poles span "
                                     "beyond double precision): rescale its coefficients", field=field)
    return c


def _finite_ss(ss: SS) -> bool:
    return bool(np.all(np.isfinite(ss.A)) and np.all(np.isfinite(ss.B)) and np.all(np.isfinite(ss.C))
                and np.isfinite(ss.D))


def controller_from_coeffs(num: Sequence[float], den: Sequence[float], *, dt: float | None) -> ControllerTF:
    """A controller from coefficients (highest power first), continuous or at ``dt``, validated:
    finite, non-zero numerator and denominator, proper.

    Examples
    --------
    >>> from tuner import controller_from_coeffs
    >>> c = controller_from_coeffs([4.0, 4.0], [2.0, 0.0], dt=None)  # made monic: 2 (s + 1) / s
    >>> [float(v) for v in c.num], [float(v) for v in c.den]
    ([2.0, 2.0], [1.0, 0.0])
    >>> controller_from_coeffs([1.0, 0.0, 0.0], [1.0, 1.0], dt=None)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    tuner.errors.InvalidControllerError: improper controller: ...
    """
    dt = check_dt(dt)
    parts = []
    for name, values in (("num", num), ("den", den)):
        try:
            a = np.atleast_1d(np.asarray(values, dtype=float))
        except (TypeError, ValueError) as e:
            raise InvalidControllerError(f"{name} must be a list of numbers", field=name) from e
        if a.ndim != 1 or not np.all(np.isfinite(a)):
            raise InvalidControllerError(f"{name} must be a list of finite numbers", field=name)
        a = np.trim_zeros(a, "f")
        if a.size == 0:
            what = "the denominator needs" if name == "den" else "the controller has no gain: it needs"
            raise InvalidControllerError(f"{name} is zero: {what} a non-zero coefficient", field=name)
        parts.append(a)
    n, d = parts
    if n.size > d.size:
        raise InvalidControllerError(f"improper controller: numerator degree {n.size - 1} > denominator degree "
                                     f"{d.size - 1}; add a filter pole", field="num")
    with np.errstate(over="ignore", invalid="ignore"):
        n, d = n / d[0], d / d[0]
    if not (np.all(np.isfinite(n)) and np.all(np.isfinite(d))):
        raise InvalidControllerError("coefficients overflow when the denominator is made monic: rescale them",
                                     field="den")
    _check_order(d.size - 1, "den")
    return _checked(ControllerTF(num=n, den=d, dt=dt), "den")
