"""Plants: building and validating transfer functions, delay, ZOH.

A :class:`Plant` is a SISO transfer function ``num/den`` in ``s`` (``dt is None``)
or in ``z`` (sample time ``dt``), with an optional input delay in seconds.
Coefficients are stored highest power first, denominator monic.

Delay: continuous plants accept any delay >= 0, exactly: in a continuous loop (the frequency
domain, a fine-step simulation in the time domain) and in a sampled-data loop at ``dt``, where
``tau = m dt + phi`` (``0 <= phi < dt``) becomes the ZOH equivalent of ``G(s) e^{-s tau}`` (the
modified z-transform; MATLAB's ``c2d`` of a delayed model): ``m`` whole samples of register and,
for ``phi > 0``, one extra state (the previous input, :func:`tuner.lti.zoh_fractional`). A plant
given in z needs a delay of whole samples of its ``dt``; anything else is rejected with a clear
error rather than rounded.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import linalg

from .errors import InvalidPlantError, TunerError
from .expr import parse_tf_expr
from .lti import SS, Zpk, realize, roots_of, zoh, zoh_fractional, zpk_from_ss
from .lti import freqresp as lti_freqresp
from .tolerances import EXACT_ROOT_TOL, SAME_DT_RTOL

__all__ = ["Plant", "tf_freqresp", "make_plant", "make_plant_zpk", "plant_from_expr", "MAX_ORDER", "delay_in_samples",
           "check_dt", "MIN_DT_S", "MAX_DT_S", "split_delay"]

MAX_ORDER = 20
MIN_DT_S = 1e-6  # 1 us: faster than any digital controller this tunes; keeps pi/dt and the grids finite
MAX_DT_S = 1e4  # the library's, the CLI's and the service's limits (one constant)
_SAMPLE_TOL = SAME_DT_RTOL


def check_dt(dt: float | None, *, what: str = "dt") -> float | None:
    """Validate a sample time: ``None`` (continuous) or a number in [``MIN_DT_S``, ``MAX_DT_S``] seconds."""
    if dt is None:
        return None
    if isinstance(dt, bool):
        raise InvalidPlantError(f"{what} must be a number of seconds, got {dt!r}", field=what)
    try:
        v = float(dt)
    except (TypeError, ValueError) as e:
        raise InvalidPlantError(f"{what} must be a number of seconds, got {dt!r}", field=what) from e
    if not np.isfinite(v) or v <= 0:
        raise InvalidPlantError(f"{what} must be finite and > 0, got {dt!r}", field=what)
    if not MIN_DT_S <= v <= MAX_DT_S:
        raise InvalidPlantError(f"{what} = {v:g} s is outside [{MIN_DT_S:g}, {MAX_DT_S:g}] s: give a sample time "
                                "in that range", field=what)
    return v


def delay_in_samples(delay_s: float, dt: float) -> int:
    """Whole number of samples in ``delay_s`` (the delay of a plant given in z); a clear error if it is not
    whole."""
    d = delay_s / dt
    k = int(round(d))
    if abs(d - k) > 1e-6 * max(1.0, d):
        raise InvalidPlantError(
            f"delay {delay_s} s is not a whole number of samples of dt={dt} s "
            f"({d:.4g} samples): a plant given in z needs a multiple of dt (a continuous plant in s takes any "
            "delay, also in a sampled-data loop)", field="delay"
        )
    return k


def split_delay(delay_s: float, dt: float) -> tuple[int, float]:
    """``(m, phi)`` with ``delay_s = m dt + phi``, ``0 <= phi < dt``; a delay within ``1e-6`` (relative) of
    whole samples is whole (``phi = 0``)."""
    d = delay_s / dt
    k = int(round(d))
    if abs(d - k) <= 1e-6 * max(1.0, d):
        return k, 0.0
    m = int(math.floor(d))
    return m, float(delay_s - m * dt)


def _coeffs(values: Sequence[float], name: str) -> np.ndarray:
    try:
        a = np.atleast_1d(np.asarray(values, dtype=float))
    except (TypeError, ValueError) as e:
        raise InvalidPlantError(f"{name} must be a list of numbers", field=name) from e
    if a.ndim != 1 or a.size == 0:
        raise InvalidPlantError(f"{name} must be a non-empty list of numbers", field=name)
    if not np.all(np.isfinite(a)):
        raise InvalidPlantError(f"{name} has non-finite coefficients: {a.tolist()}", field=name)
    nz = np.flatnonzero(a)
    return a[nz[0]:] if nz.size else np.zeros(1)


@dataclass(frozen=True, eq=False)
class Plant:
    """A validated SISO plant. Build it with :func:`make_plant`, :func:`make_plant_zpk` or
    :func:`plant_from_expr`.

    ``num``/``den`` are the coefficients (for display and storage); every computation uses the
    factored form ``zpk`` and its cascade state-space realisation (:meth:`ss`), never the expanded
    polynomials (see :mod:`tuner.lti`).

    Examples
    --------
    >>> from tuner import make_plant
    >>> p = make_plant([2.0], [1.0, 3.0, 2.0], delay=0.01)  # 2 / ((s + 1)(s + 2)), 10 ms delay
    >>> p.order, p.is_discrete, sorted(float(r) for r in p.poles.real)
    (2, False, [-2.0, -1.0])
    >>> p.describe()  # doctest: +ELLIPSIS
    '(2...) / (...), delay=0.01 s'
    """

    num: np.ndarray
    den: np.ndarray
    dt: float | None = None
    delay_s: float = 0.0
    zpk: Zpk | None = None  # filled by the constructors; None only for hand-made instances
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.zpk is None:  # a Plant built directly from coefficients
            object.__setattr__(self, "zpk", _zpk_of(self.num, self.den))

    @property
    def is_discrete(self) -> bool:
        """A plant in ``z`` at ``dt`` (else continuous, in ``s``)."""
        return self.dt is not None

    @property
    def order(self) -> int:
        """The number of poles (the denominator's degree)."""
        return self.den.size - 1

    @property
    def poles(self) -> np.ndarray:
        """The poles (in ``s``, or in ``z`` at ``dt``), from the factored form."""
        return self.zpk.poles

    @property
    def zeros(self) -> np.ndarray:
        """The zeros (in ``s``, or in ``z`` at ``dt``), from the factored form."""
        return self.zpk.zeros

    @property
    def tf(self):
        """The rational part as a python-control transfer function (delay not included)."""
        import control as ct

        return ct.tf(self.num, self.den, 0 if self.dt is None else self.dt)

    def ss(self) -> SS:
        """The balanced cascade realisation (in s, or in z at ``dt``); delay not included."""
        if "ss" not in self._cache:
            self._cache["ss"] = realize(self.zpk, discrete=self.is_discrete)
        return self._cache["ss"]

    def scaled(self, k: float) -> Plant:
        """The plant with its gain times ``k`` (``k > 0``): the same poles, zeros, delay and realisation, its output
        scaled (a rate loop's control effectiveness moving with battery voltage and payload). A zero-order-hold
        equivalent stays one, of its continuous plant scaled alike.

        Examples
        --------
        >>> from tuner import make_plant
        >>> make_plant([2.0], [1.0, 1.0]).scaled(1.25).dc_gain()
        2.5
        """
        k = float(k)
        if not (math.isfinite(k) and k > 0):
            raise InvalidPlantError(f"a plant's gain scales by a finite factor > 0, got {k!r}", field="gain")
        from dataclasses import replace as _replace

        zk = Zpk(zeros=self.zpk.zeros, poles=self.zpk.poles, gain=self.zpk.gain * k)
        out = Plant(num=self.num * k, den=self.den, dt=self.dt, delay_s=self.delay_s, zpk=zk)
        g = self.ss()
        out._cache["ss"] = _replace(g, C=g.C * k, D=g.D * k, _cache={})
        parent = self._cache.get("ct_parent")
        if parent is not None:
            out._cache["ct_parent"] = parent.scaled(k)
        if "zoh_fraction" in self._cache:
            out._cache["zoh_fraction"] = self._cache["zoh_fraction"]
        return out

    def dc_gain(self) -> float:
        """Steady-state gain (``inf`` with an integrator)."""
        x = 0.0 if self.dt is None else 1.0
        if np.any(np.abs(self.zpk.poles - x) < EXACT_ROOT_TOL):
            return float(np.copysign(np.inf, self.zpk.gain))
        return float(np.real(self.zpk(np.array([x]))[0]))

    def freqresp(self, w: np.ndarray) -> np.ndarray:
        """Complex frequency response at ``w`` rad/s, delay included exactly."""
        w = np.asarray(w, dtype=float)
        x = 1j * w if self.dt is None else np.exp(1j * w * self.dt)
        g = lti_freqresp(self.ss(), x)
        return g * np.exp(-1j * w * self.delay_s) if self.delay_s else g

    @property
    def zoh_fraction(self) -> float:
        """For the ZOH equivalent of a continuous plant whose delay is not whole samples: the fractional part
        ``phi`` (s) of the delay, held in the realisation's extra state (:func:`tuner.lti.zoh_fractional`);
        its ``delay_s`` is then the whole samples. 0 otherwise."""
        return float(self._cache.get("zoh_fraction", 0.0))

    def zoh(self, dt: float) -> Plant:
        """Zero-order-hold equivalent at ``dt`` of the plant with its delay, exact for any delay: ``delay_s``
        of the result is the whole samples ``m dt`` of ``tau = m dt + phi``; a fraction ``phi > 0`` is in the
        realisation (one extra state, the previous input; see :attr:`zoh_fraction`)."""
        dt = check_dt(dt)
        key = ("zoh", dt)
        if key not in self._cache:
            self._cache[key] = self._zoh(dt)
        return self._cache[key]

    def _zoh(self, dt: float) -> Plant:
        if self.is_discrete:
            if abs(self.dt - dt) > _SAMPLE_TOL * dt:
                raise InvalidPlantError(
                    f"plant is discrete at dt={self.dt} but the loop runs at dt={dt}; "
                    "resampling a discrete plant is not supported", field="dt"
                )
            return self
        d, phi = split_delay(self.delay_s, dt)
        with np.errstate(all="ignore"):
            try:
                sysd = zoh(self.ss(), dt) if phi == 0.0 else zoh_fractional(self.ss(), dt, phi)
                zk = zpk_from_ss(sysd, discrete=True)
            except (np.linalg.LinAlgError, ValueError, FloatingPointError) as e:
                raise InvalidPlantError(f"cannot discretise the plant at dt={dt} (ZOH): {e}; rescale the model") \
                    from e
        if not (np.all(np.isfinite(sysd.A)) and np.all(np.isfinite(sysd.B)) and np.isfinite(zk.gain)):
            raise InvalidPlantError(f"the ZOH equivalent at dt={dt} is not finite: rescale the model")
        num, den = _coeffs_of(zk)
        out = Plant(num=num, den=den, dt=dt, delay_s=d * dt, zpk=zk)
        out._cache["ss"] = sysd  # the ZOH of the cascade itself, not a realisation of its zpk
        out._cache["ct_parent"] = self
        if phi:
            out._cache["zoh_fraction"] = phi
        return out

    def rational_discrete(self) -> tuple[np.ndarray, np.ndarray]:
        """Discrete num/den with the delay folded in as ``z^-d`` (requires ``dt``)."""
        if self.dt is None:
            raise InvalidPlantError("plant is continuous; call zoh(dt) first")
        d = delay_in_samples(self.delay_s, self.dt)
        return self.num, np.concatenate([self.den, np.zeros(d)])

    def continuous_equivalent(self) -> Plant | None:
        """For a discrete plant, the continuous plant whose ZOH it is, when one exists.

        Used to evaluate the output between samples of a plant given in z. Returns
        ``None`` when the discrete model has poles on the negative real axis or at
        zero (no real continuous equivalent).
        """
        if not self.is_discrete:
            return self
        if "ct_parent" in self._cache:
            return self._cache["ct_parent"]
        if "ct" not in self._cache:
            self._cache["ct"] = self._continuous_equivalent()
        return self._cache["ct"]

    def _continuous_equivalent(self) -> Plant | None:
        sysd = self.ss()
        n = sysd.n
        if n == 0:
            return Plant(num=self.num, den=self.den, dt=None, delay_s=self.delay_s,
                         zpk=Zpk(np.zeros(0), np.zeros(0), float(sysd.D)))
        ev = self.zpk.poles
        if np.any((np.abs(ev.imag) < EXACT_ROOT_TOL) & (ev.real <= EXACT_ROOT_TOL)):  # no real logarithm
            return None
        M = np.zeros((n + 1, n + 1))
        M[:n, :n], M[:n, n] = sysd.A, sysd.B
        M[n, n] = 1.0
        with np.errstate(all="ignore"):
            logm = linalg.logm(M)
        if not np.all(np.isfinite(logm)) or np.max(np.abs(np.imag(logm))) > 1e-8 * max(1.0, np.max(np.abs(logm))):
            return None
        Lm = np.real(logm) / self.dt
        sysc = SS(Lm[:n, :n], Lm[:n, n], sysd.C.copy(), sysd.D)
        zk = zpk_from_ss(sysc, discrete=False)
        num, den = _coeffs_of(zk)
        out = Plant(num=num, den=den, dt=None, delay_s=self.delay_s, zpk=zk)
        out._cache["ss"] = sysc
        return out

    def describe(self) -> str:
        """The plant as text: ``(num) / (den)``, with its ``dt`` and delay when it has them."""
        var = "s" if self.dt is None else "z"
        s = f"({_poly_str(self.num, var)}) / ({_poly_str(self.den, var)})"
        if self.dt is not None:
            s += f", dt={self.dt:g}"
        if self.delay_s:
            s += f", delay={self.delay_s:g} s"
        return s


def _zpk_of(num: np.ndarray, den: np.ndarray) -> Zpk:
    """Zeros, poles and gain of coefficient lists (the best the expanded data allow). Roots that cannot be
    computed in double precision (:func:`~tuner.lti.roots_of`) raise :class:`~tuner.errors.InvalidPlantError`
    naming ``num`` or ``den``."""
    n, d = np.trim_zeros(np.asarray(num, float), "f"), np.trim_zeros(np.asarray(den, float), "f")
    zeros, poles = roots_of(n), roots_of(d)
    for roots, name, what in ((zeros, "num", "zeros"), (poles, "den", "poles")):
        if roots is None:
            raise InvalidPlantError(f"the plant's {what} cannot be computed in double precision from these "
                                    "coefficients (they span too many decades): rescale the model, or give it as "
                                    "a product of factors, e.g. an expression 1/((s + a)*(s + b))", field=name)
    return Zpk(zeros, poles, float(n[0] / d[0]) if n.size and d.size else 0.0)


def _coeffs_of(zk: Zpk) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients of a zpk (for display and storage; nothing is computed from them). Beyond double precision (a
    gain near 1e300 times the zeros' coefficients) they are inf; the callers that need them finite check."""
    with np.errstate(over="ignore", invalid="ignore"):
        num = np.real(np.poly(zk.zeros)) * zk.gain if zk.zeros.size else np.array([zk.gain])
    den = np.real(np.poly(zk.poles)) if zk.poles.size else np.ones(1)
    return np.atleast_1d(num), np.atleast_1d(den)


def tf_freqresp(num: np.ndarray, den: np.ndarray, w: np.ndarray, *, dt: float | None,
                delay_s: float = 0.0) -> np.ndarray:
    """``num/den`` at ``s = jw`` (``dt`` None) or ``z = exp(jw dt)``, times ``exp(-jw delay_s)``."""
    w = np.asarray(w, dtype=float)
    x = 1j * w if dt is None else np.exp(1j * w * dt)
    g = np.polyval(num, x) / np.polyval(den, x)
    return g * np.exp(-1j * w * delay_s) if delay_s else g


def _poly_str(p: np.ndarray, var: str) -> str:
    n = p.size - 1
    terms = []
    for i, c in enumerate(p):
        k = n - i
        if c == 0:
            continue
        mono = "" if k == 0 else (var if k == 1 else f"{var}^{k}")
        coef = f"{c:.6g}"
        terms.append(mono if mono and coef == "1" else (f"{coef}*{mono}" if mono else coef))
    return " + ".join(terms).replace("+ -", "- ") or "0"


def make_plant(
    num: Any,
    den: Sequence[float] | None = None,
    *,
    dt: float | None = None,
    delay: float = 0.0,
    max_order: int = MAX_ORDER,
    zpk: Zpk | None = None,
) -> Plant:
    """Build and validate a plant from coefficients (highest power first), or from a python-control model.

    ``make_plant(num, den, dt=..., delay=...)``; or ``make_plant(sys, delay=...)`` with ``sys`` a
    ``control.TransferFunction`` or ``control.StateSpace`` (its own ``dt``, see :mod:`tuner.interop`).

    ``zpk``: the same transfer function in factored form when it is known more accurately than the
    roots of the coefficients would give it (e.g. from an expression's factors, or a state-space
    model); every computation uses it.

    Raises :class:`~tuner.errors.InvalidPlantError` naming the problem: non-finite
    coefficients, zero denominator or numerator, improper, order above
    ``max_order``, ``dt <= 0``, negative or non-finite delay, or a delay that is
    not a whole number of samples of a discrete plant (a continuous plant takes any delay). Open-loop unstable plants
    are accepted.

    Examples
    --------
    >>> from tuner import make_plant
    >>> make_plant([1.0], [1.0, 1.0]).order
    1
    >>> make_plant([0.1], [1.0, -0.9], dt=0.01).is_discrete  # in z, at 10 ms
    True
    >>> import control
    >>> make_plant(control.tf([1], [1, 2, 1]), delay=0.02).delay_s
    0.02
    >>> make_plant([1.0, 0.0, 0.0], [1.0, 1.0])
    Traceback (most recent call last):
    ...
    tuner.errors.InvalidPlantError: ...
    """
    if den is None:
        if not is_control_lti(num):
            raise InvalidPlantError("give the denominator den (or a python-control TransferFunction/StateSpace)",
                                    field="den")
        p = plant_from_control(num, delay=delay, max_order=max_order)
        if dt is not None and (p.dt is None or abs(check_dt(dt) - p.dt) > _SAMPLE_TOL * p.dt):
            raise InvalidPlantError(f"the python-control model has its own time base (dt={num.dt}); dt={dt} was "
                                    "given: leave dt out", field="dt")
        return p
    n = _coeffs(num, "num")
    d = _coeffs(den, "den")
    dt = check_dt(dt)
    if not np.any(d):
        raise InvalidPlantError("den is zero: the denominator needs a non-zero coefficient", field="den")
    if not np.any(n):
        raise InvalidPlantError("num is zero: the plant has no gain", field="num")
    if n.size > d.size:
        raise InvalidPlantError(
            f"improper transfer function: numerator degree {n.size - 1} > denominator degree {d.size - 1}",
            field="num",
        )
    if d.size - 1 > max_order:
        raise InvalidPlantError(f"plant order {d.size - 1} is above the limit {max_order}", field="den")
    try:
        tau = float(delay or 0.0)
    except (TypeError, ValueError) as e:
        raise InvalidPlantError(f"delay must be a number of seconds, got {delay!r}", field="delay") from e
    if not np.isfinite(tau) or tau < 0:
        raise InvalidPlantError(f"delay must be finite and >= 0 seconds, got {delay!r}", field="delay")
    if dt is not None and tau:
        tau = delay_in_samples(tau, dt) * dt
    lead = d[0]
    with np.errstate(over="ignore", invalid="ignore"):
        n, d = n / lead, d / lead
    if not (np.all(np.isfinite(n)) and np.all(np.isfinite(d))):
        raise InvalidPlantError("coefficients overflow when the denominator is made monic: rescale the model",
                                field="den")
    if zpk is None:
        zpk = _zpk_of(n, d)
    if not (np.all(np.isfinite(zpk.zeros)) and np.all(np.isfinite(zpk.poles)) and np.isfinite(zpk.gain)) \
            or zpk.gain == 0:
        raise InvalidPlantError("the plant's poles, zeros or gain are not finite: rescale the model", field="den")
    plant = Plant(num=n, den=d, dt=dt, delay_s=tau, zpk=zpk)
    try:
        with np.errstate(all="ignore"):
            ss = plant.ss()
    except (ValueError, np.linalg.LinAlgError) as e:
        raise InvalidPlantError(f"the plant cannot be realised in state space ({e}): rescale the model",
                                field="den") from None
    if not (np.all(np.isfinite(ss.A)) and np.all(np.isfinite(ss.B)) and np.all(np.isfinite(ss.C))
            and np.isfinite(ss.D)):
        raise InvalidPlantError("the plant's state-space realisation overflows (its gain and poles span beyond "
                                "double precision): rescale the model", field="den")
    return plant


def make_plant_zpk(
    zeros: Sequence[complex], poles: Sequence[complex], gain: float, *, dt: float | None = None,
    delay: float = 0.0, max_order: int = MAX_ORDER,
) -> Plant:
    """Build and validate a plant from zeros, poles and gain (complex roots in conjugate pairs)."""
    try:
        z = np.atleast_1d(np.asarray(zeros, dtype=complex))
        p = np.atleast_1d(np.asarray(poles, dtype=complex))
        k = float(gain)
    except (TypeError, ValueError) as e:
        raise InvalidPlantError("zeros, poles and gain must be numbers", field="zpk") from e
    zk = Zpk(z.ravel(), p.ravel(), k)
    num, den = _coeffs_of(zk)
    return make_plant(num, den, dt=dt, delay=delay, max_order=max_order, zpk=zk)


def plant_from_expr(
    text: str, *, dt: float | None = None, delay: float = 0.0, max_order: int = MAX_ORDER
) -> Plant:
    """Build a plant from an expression such as ``0.2843*18.611/(s+18.611)``.

    An expression in ``z`` needs ``dt``; an expression in ``s`` is continuous
    (``dt``, if given, is then the loop's sample time and is ignored here).
    The text is parsed by a small parser (never evaluated): numbers, ``s`` or ``z``, ``+ - * / ^``
    and parentheses; a bad expression raises :class:`~tuner.errors.InvalidExpressionError` with the
    position.

    Examples
    --------
    >>> from tuner import plant_from_expr
    >>> p = plant_from_expr("0.2843*18.611/(s+18.611)")
    >>> p.order, round(float(p.poles[0].real), 3)
    (1, -18.611)
    >>> plant_from_expr("0.1/(z - 0.9)", dt=0.01).dt
    0.01
    >>> plant_from_expr("1/(s+")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    tuner.errors.InvalidExpressionError: ... (at position ...)
    """
    try:
        p = parse_tf_expr(text)
    except TunerError as e:
        raise e.at("expr") from None
    if p.var == "z" and dt is None:
        raise InvalidPlantError("plant is in z: give its sample time dt", field="dt")
    try:
        return make_plant(p.num, p.den, dt=dt if p.var == "z" else None, delay=delay, max_order=max_order,
                          zpk=Zpk(p.zeros, p.poles, p.gain))
    except TunerError as e:  # a coefficient problem is a problem of the expression
        if e.field in (("num",), ("den",)):
            e.field = ("expr",)
        raise


# -- python-control models in (tuner.interop re-exports these; here so that make_plant needs no import of it) --

def is_control_lti(obj: Any) -> bool:
    """``obj`` is a python-control ``TransferFunction`` or ``StateSpace`` (without importing control otherwise)."""
    if not type(obj).__module__.startswith("control"):
        return False
    import control

    return isinstance(obj, (control.TransferFunction, control.StateSpace))


def _dt_of(sys: Any, error: type[TunerError], what: str) -> float | None:
    dt = sys.dt
    if dt is True:
        raise error(f"the {what} is discrete with an unspecified sample time (dt=True): give its sample time in "
                    "seconds, e.g. control.tf(num, den, 0.04) or control.c2d(sys, 0.04)", field="dt")
    if dt is None or dt == 0:
        return None
    return float(dt)


def _siso(sys: Any, error: type[TunerError], what: str) -> None:
    if sys.ninputs != 1 or sys.noutputs != 1:
        raise error(f"the {what} must be SISO (one input, one output), got {sys.noutputs} outputs x "
                    f"{sys.ninputs} inputs: select the channel, e.g. sys[0, 0]")


def _tf_coeffs(sys: Any) -> tuple[np.ndarray, np.ndarray]:
    return (np.asarray(sys.num[0][0], dtype=float).ravel(), np.asarray(sys.den[0][0], dtype=float).ravel())


def _ss_of(sys: Any) -> SS:
    A = np.asarray(sys.A, dtype=float)
    return SS(A.reshape(A.shape[0], A.shape[0]), np.asarray(sys.B, dtype=float).ravel(),
              np.asarray(sys.C, dtype=float).ravel(), float(np.asarray(sys.D, dtype=float).ravel()[0]))


def _zpk(sys: Any, discrete: bool) -> Zpk:
    with np.errstate(all="ignore"):
        return zpk_from_ss(_ss_of(sys), discrete=discrete)


def plant_from_control(sys: Any, *, delay: float = 0.0, max_order: int = MAX_ORDER) -> Plant:
    """A :class:`~tuner.plant.Plant` from a python-control model; ``delay`` in seconds (whole samples if discrete).

    A ``TransferFunction`` or ``StateSpace``, SISO, continuous (``dt=0``) or discrete (its ``dt``; ``dt=True``
    is refused: give the number).

    Examples
    --------
    >>> import control
    >>> from tuner import plant_from_control
    >>> p = plant_from_control(control.tf([1], [1, 1]), delay=0.05)
    >>> p.order, p.delay_s, p.dt
    (1, 0.05, None)
    >>> plant_from_control(control.ss([[-1.0]], [[1.0]], [[2.0]], [[0.0]])).describe()  # doctest: +ELLIPSIS
    '(2...) / (s + 1...)'
    """
    import control

    _siso(sys, InvalidPlantError, "plant")
    dt = _dt_of(sys, InvalidPlantError, "plant")
    if isinstance(sys, control.StateSpace):
        if np.asarray(sys.A).shape[0] > max_order:
            raise InvalidPlantError(f"plant order {np.asarray(sys.A).shape[0]} is above the limit {max_order}",
                                    field="den")
        zk = _zpk(sys, dt is not None)
        if zk.gain == 0 or not np.isfinite(zk.gain):
            raise InvalidPlantError("the state-space plant has no gain (C (sI - A)^-1 B + D is zero) or it is not "
                                    "finite", field="num")
        return make_plant_zpk(zk.zeros, zk.poles, zk.gain, dt=dt, delay=delay, max_order=max_order)
    num, den = _tf_coeffs(sys)
    return make_plant(num, den, dt=dt, delay=delay, max_order=max_order)
