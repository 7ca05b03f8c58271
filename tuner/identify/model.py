"""The parametric model: a gain, factored pole and zero sections, an optional delay.

``T(s) = K * prod_zeros q(s) / prod_poles q(s) * exp(-s*tau)`` with every section normalised to
unit DC gain: a real section ``q(s) = 1 + s/a`` and a quadratic one
``q(s) = 1 + 2*zeta*s/wn + (s/wn)^2``. ``n`` poles are ``n // 2`` quadratic sections and, for odd
``n``, one real section (a quadratic with ``zeta > 1`` is a pair of real poles); zeros likewise.
Poles and zeros are in the left half plane (a stable, minimum-phase rational part; the delay
carries the extra phase lag). The parameters are ``log|K|``, ``log wn``, ``log zeta``, ``log a`` (so
steps are relative, every value stays positive) and ``tau`` in seconds.

The response is evaluated section by section (``log T`` as a sum), never through expanded
polynomials; the phase of each section is continuous in ``w``, so the model's phase is
unwrapped by construction. :meth:`Model.state_space` chains the sections in state space.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Model", "Structure", "section_kinds"]

_DB = 20.0 / np.log(10.0)
_DEG = 180.0 / np.pi


def section_kinds(n: int) -> list[str]:
    """``n`` roots as sections: ``["quad", ..., "real"]``."""
    return ["quad"] * (n // 2) + ["real"] * (n % 2)


@dataclass(frozen=True)
class Structure:
    """How many poles and zeros, and whether the delay is a free parameter."""

    poles: int
    zeros: int
    free_delay: bool

    def names(self) -> list[str]:
        """Parameter names, in the order of the parameter vector."""
        out = ["gain"]
        for role, n in (("pole", self.poles), ("zero", self.zeros)):
            q = 0
            for kind in section_kinds(n):
                if kind == "quad":
                    q += 1
                    out += [f"{role}_wn_{q}_rad_s", f"{role}_zeta_{q}"]
                else:
                    out.append(f"{role}_{q + 1}_rad_s")
        if self.free_delay:
            out.append("delay_s")
        return out

    @property
    def size(self) -> int:
        """The number of fitted parameters (``len(names())``)."""
        return len(self.names())


@dataclass(frozen=True, eq=False)
class Model:
    """A point of the model family: ``theta`` (log-parameters, then ``tau`` if free), the gain's sign
    and the delay (``tau`` when it is not a parameter)."""

    structure: Structure
    theta: np.ndarray
    sign: float = 1.0
    fixed_delay_s: float = 0.0
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    # -- parameters ---------------------------------------------------------------------------
    def _sections(self) -> list[tuple[str, str, slice]]:
        """(role, kind, slice of theta) for every section."""
        out, i = [], 1
        for role, n in (("pole", self.structure.poles), ("zero", self.structure.zeros)):
            for kind in section_kinds(n):
                k = 2 if kind == "quad" else 1
                out.append((role, kind, slice(i, i + k)))
                i += k
        return out

    @property
    def delay_s(self) -> float:
        """The model's input delay, s (fitted, or the fixed one)."""
        return float(self.theta[-1]) if self.structure.free_delay else float(self.fixed_delay_s)

    @property
    def gain(self) -> float:
        """The model's gain factor (the sign times ``exp(theta[0])``)."""
        return float(self.sign * np.exp(self.theta[0]))

    def values(self) -> dict[str, float]:
        """Physical parameter values by name (gain with its sign, frequencies in rad/s, delay in s)."""
        n_log = self.theta.size - (1 if self.structure.free_delay else 0)  # the delay (last) is in s, not a log
        v = np.concatenate([np.exp(self.theta[:n_log]), self.theta[n_log:]])
        v[0] *= self.sign
        out = dict(zip(self.structure.names(), (float(x) for x in v)))
        if not self.structure.free_delay:
            out["delay_s"] = float(self.fixed_delay_s)
        return out

    # -- frequency response -------------------------------------------------------------------
    def _log_terms(self, w: np.ndarray) -> tuple[np.ndarray, list[tuple[slice, list[np.ndarray]]]]:
        """``log T(jw)`` and, per section, ``d log T / d theta`` for its parameters."""
        s = 1j * np.asarray(w, dtype=float)
        logt = np.full(s.shape, self.theta[0] + (0j if self.sign > 0 else 1j * np.pi))
        grads: list[tuple[slice, list[np.ndarray]]] = []
        for role, kind, sl in self._sections():
            sgn = 1.0 if role == "zero" else -1.0
            p = np.exp(self.theta[sl])
            if kind == "real":
                x = s / p[0]
                q = 1.0 + x
                grads.append((sl, [sgn * (-x / q)]))
            else:
                x = s / p[0]
                q = 1.0 + 2.0 * p[1] * x + x * x
                grads.append((sl, [sgn * (-(2.0 * p[1] * x + 2.0 * x * x) / q), sgn * (2.0 * p[1] * x / q)]))
            logt = logt + sgn * np.log(q)
        return logt - s * self.delay_s, grads

    def freqresp(self, w: np.ndarray) -> np.ndarray:
        """Complex response at ``w`` rad/s, delay included."""
        return np.exp(self._log_terms(w)[0])

    def bode(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Magnitude (dB) and continuous phase (deg) at ``w``."""
        logt, _ = self._log_terms(w)
        return _DB * logt.real, _DEG * logt.imag

    def bode_jacobian(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Magnitude, phase, and their derivatives with respect to ``theta`` (``len(w) x size``)."""
        logt, grads = self._log_terms(w)
        d = np.zeros((np.size(w), self.structure.size), dtype=complex)
        d[:, 0] = 1.0
        for sl, g in grads:
            for j, col in enumerate(g):
                d[:, sl.start + j] = col
        if self.structure.free_delay:
            d[:, -1] = -1j * np.asarray(w, dtype=float)
        return _DB * logt.real, _DEG * logt.imag, _DB * d.real, _DEG * d.imag

    # -- transfer function and state space ----------------------------------------------------
    def section_polys(self) -> tuple[list[np.ndarray], list[np.ndarray], float]:
        """Monic pole and zero polynomials of the sections, and the numerator's gain factor."""
        poles, zeros, k = [], [], self.gain
        for role, kind, sl in self._sections():
            p = np.exp(self.theta[sl])
            poly = np.array([1.0, p[0]]) if kind == "real" else np.array([1.0, 2 * p[1] * p[0], p[0] ** 2])
            norm = poly[-1]  # the section is poly / norm
            if role == "pole":
                poles.append(poly)
                k *= norm
            else:
                zeros.append(poly)
                k /= norm
        return poles, zeros, k

    def tf(self) -> tuple[np.ndarray, np.ndarray]:
        """``num``, monic ``den`` (highest power first; the orders here are small)."""
        poles, zeros, k = self.section_polys()
        num, den = np.array([k]), np.array([1.0])
        for z in zeros:
            num = np.polymul(num, z)
        for p in poles:
            den = np.polymul(den, p)
        return num, den

    def state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C, D) of the rational part: sections in series, each in controllable form."""
        if "ss" in self._cache:
            return self._cache["ss"]
        import control as ct

        poles, zeros, k = self.section_polys()
        nums = list(zeros) + [np.array([1.0])] * max(0, len(poles) - len(zeros))
        dens = list(poles) + [np.array([1.0])] * max(0, len(zeros) - len(poles))
        # pair each zero section with a pole section of at least its degree (proper blocks)
        nums.sort(key=len, reverse=True)
        dens.sort(key=len, reverse=True)
        sys = ct.ss([], [], [], [[k]])
        for n, d in zip(nums, dens):
            sys = ct.series(sys, ct.tf2ss(ct.tf(n, d)))
        out = tuple(np.atleast_2d(np.asarray(m, dtype=float)) for m in (sys.A, sys.B, sys.C, sys.D))
        self._cache["ss"] = out
        return out  # type: ignore[return-value]

    def to_dict(self) -> dict[str, Any]:
        """The model as a dict: ``num``, ``den``, ``delay``, the structure and the named parameters."""
        num, den = self.tf()
        return {"num": num.tolist(), "den": den.tolist(), "delay": self.delay_s,
                "poles": self.structure.poles, "zeros": self.structure.zeros, "parameters": self.values()}

    @classmethod
    def from_values(cls, poles: int, zeros: int, values: dict[str, float]) -> Model:
        """Rebuild from :meth:`values` (the delay becomes a fixed one)."""
        st = Structure(poles=poles, zeros=zeros, free_delay=False)
        names = st.names()
        gain = float(values["gain"])
        theta = np.log(np.abs(np.array([gain] + [float(values[n]) for n in names[1:]])))
        return cls(st, theta, sign=1.0 if gain >= 0 else -1.0, fixed_delay_s=float(values.get("delay_s", 0.0)))
