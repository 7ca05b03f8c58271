"""Plants: building and validating transfer functions, delay, ZOH.

A :class:`Plant` is a SISO transfer function ``num/den`` in ``s`` (``dt is None``)
or in ``z`` (sample time ``dt``), with an optional input delay in seconds.
Coefficients are stored highest power first, denominator monic.

Delay: continuous plants accept any delay >= 0 (handled exactly in the
frequency domain, by a fine-step simulation in the time domain). A discrete
plant, or a continuous plant in a sampled-data loop, needs a delay that is a
whole number of samples; anything else is rejected with a clear error rather
than rounded.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import control as ct
import numpy as np
from scipy import linalg

from .errors import InvalidPlantError, TunerError
from .expr import parse_tf_expr

__all__ = ["Plant", "tf_freqresp", "make_plant", "plant_from_expr", "MAX_ORDER", "delay_in_samples", "check_dt"]

MAX_ORDER = 20
_SAMPLE_TOL = 1e-9


def check_dt(dt: float | None, *, what: str = "dt") -> float | None:
    """Validate a sample time: ``None`` (continuous) or a finite number > 0."""
    if dt is None:
        return None
    try:
        v = float(dt)
    except (TypeError, ValueError) as e:
        raise InvalidPlantError(f"{what} must be a number, got {dt!r}", field=what) from e
    if not np.isfinite(v) or v <= 0:
        raise InvalidPlantError(f"{what} must be finite and > 0, got {dt!r}", field=what)
    return v


def delay_in_samples(delay_s: float, dt: float) -> int:
    """Whole number of samples in ``delay_s``; a clear error if it is not whole."""
    d = delay_s / dt
    k = int(round(d))
    if abs(d - k) > 1e-6 * max(1.0, d):
        raise InvalidPlantError(
            f"delay {delay_s} s is not a whole number of samples of dt={dt} s "
            f"({d:.4g} samples); give a multiple of dt", field="delay"
        )
    return k


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
    """A validated SISO plant. Build it with :func:`make_plant` or :func:`plant_from_expr`."""

    num: np.ndarray
    den: np.ndarray
    dt: float | None = None
    delay_s: float = 0.0
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def is_discrete(self) -> bool:
        return self.dt is not None

    @property
    def order(self) -> int:
        return self.den.size - 1

    @property
    def tf(self) -> ct.TransferFunction:
        """The rational part as a python-control transfer function (delay not included)."""
        return ct.tf(self.num, self.den, 0 if self.dt is None else self.dt)

    def dc_gain(self) -> float:
        """Steady-state gain (``inf`` with an integrator)."""
        x = 0.0 if self.dt is None else 1.0
        d = np.polyval(self.den, x)
        n = np.polyval(self.num, x)
        return float(n / d) if d != 0 else float(np.copysign(np.inf, n))

    def freqresp(self, w: np.ndarray) -> np.ndarray:
        """Complex frequency response at ``w`` rad/s, delay included exactly."""
        return tf_freqresp(self.num, self.den, w, dt=self.dt, delay_s=self.delay_s)

    def zoh(self, dt: float) -> Plant:
        """Zero-order-hold equivalent at ``dt`` (delay carried as whole samples)."""
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
        d = delay_in_samples(self.delay_s, dt)
        try:
            with np.errstate(all="ignore"):
                gd = ct.sample_system(self.tf, dt, method="zoh")
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as e:
            raise InvalidPlantError(f"cannot discretise the plant at dt={dt} (ZOH): {e}; rescale the model") from e
        num = np.atleast_1d(np.squeeze(gd.num[0][0]))
        den = np.atleast_1d(np.squeeze(gd.den[0][0]))
        if not (np.all(np.isfinite(num)) and np.all(np.isfinite(den))) or den[0] == 0:
            raise InvalidPlantError(f"the ZOH equivalent at dt={dt} is not finite: rescale the model")
        return Plant(num=num / den[0], den=den / den[0], dt=dt, delay_s=d * dt)

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
        if "ct" not in self._cache:
            self._cache["ct"] = self._continuous_equivalent()
        return self._cache["ct"]

    def _continuous_equivalent(self) -> Plant | None:
        sys = ct.tf2ss(self.tf)
        A, B, C, D = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (sys.A, sys.B, sys.C, sys.D))
        n = A.shape[0]
        if n == 0:
            return Plant(num=self.num, den=self.den, dt=None, delay_s=self.delay_s)
        ev = np.linalg.eigvals(A)
        if np.any((np.abs(ev.imag) < 1e-12) & (ev.real <= 1e-12)):
            return None
        M = np.zeros((n + 1, n + 1))
        M[:n, :n], M[:n, n:] = A, B
        M[n, n] = 1.0
        with np.errstate(all="ignore"):
            logm = linalg.logm(M)
        if np.max(np.abs(np.imag(logm))) > 1e-8 * max(1.0, np.max(np.abs(logm))):
            return None
        Lm = np.real(logm) / self.dt
        Ac, Bc = Lm[:n, :n], Lm[:n, n:]
        g = ct.ss2tf(ct.ss(Ac, Bc, C, D))
        num = np.atleast_1d(np.squeeze(g.num[0][0]))
        den = np.atleast_1d(np.squeeze(g.den[0][0]))
        num[np.abs(num) < 1e-10 * np.max(np.abs(num))] = 0.0
        den[np.abs(den) < 1e-10 * np.max(np.abs(den))] = 0.0
        return Plant(num=np.trim_zeros(num, "f") / den[0], den=den / den[0], dt=None, delay_s=self.delay_s)

    def describe(self) -> str:
        var = "s" if self.dt is None else "z"
        s = f"({_poly_str(self.num, var)}) / ({_poly_str(self.den, var)})"
        if self.dt is not None:
            s += f", dt={self.dt:g}"
        if self.delay_s:
            s += f", delay={self.delay_s:g} s"
        return s


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
    num: Sequence[float],
    den: Sequence[float],
    *,
    dt: float | None = None,
    delay: float = 0.0,
    max_order: int = MAX_ORDER,
) -> Plant:
    """Build and validate a plant from coefficients (highest power first).

    Raises :class:`~tuner.errors.InvalidPlantError` naming the problem: non-finite
    coefficients, zero denominator or numerator, improper, order above
    ``max_order``, ``dt <= 0``, negative or non-finite delay, or a delay that is
    not a whole number of samples of a discrete plant. Open-loop unstable plants
    are accepted.
    """
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
    return Plant(num=n, den=d, dt=dt, delay_s=tau)


def plant_from_expr(
    text: str, *, dt: float | None = None, delay: float = 0.0, max_order: int = MAX_ORDER
) -> Plant:
    """Build a plant from an expression such as ``0.2843*18.611/(s+18.611)``.

    An expression in ``z`` needs ``dt``; an expression in ``s`` is continuous
    (``dt``, if given, is then the loop's sample time and is ignored here).
    """
    try:
        p = parse_tf_expr(text)
    except TunerError as e:
        raise e.at("expr") from None
    if p.var == "z" and dt is None:
        raise InvalidPlantError("plant is in z: give its sample time dt", field="dt")
    try:
        return make_plant(p.num, p.den, dt=dt if p.var == "z" else None, delay=delay, max_order=max_order)
    except TunerError as e:  # a coefficient problem is a problem of the expression
        if e.field in (("num",), ("den",)):
            e.field = ("expr",)
        raise
