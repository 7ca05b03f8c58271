"""Search coordinates of a structure: a box in which every point is a valid controller.

Gains of either sign are searched as ``unit * 2e-3 * sinh(v ln 10)``, i.e.
``unit * sign(v) * 10**(|v| - 3)`` away from zero: uniform in ``v`` is
log-uniform in magnitude from 1e-3 to 1e2 units, smooth through zero
(``unit = K0 * w0**k``, ``k`` = +1 for an integral gain, -1 for a derivative
gain, 0 otherwise) (log-like in magnitude,
through zero, no sign assumed); frequencies and time constants on a log scale;
polynomial coefficients linearly. Ordering constraints (a lead's pole above its
zero) are built in: the second frequency is the first times ``10**r``, r >= 0.
The same mapping is written with plain arithmetic so that CasADi can use it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..controllers import GAIN_SPAN, Structure
from ..plant import Plant
from .design import PlantScale, bounds, plant_scale

__all__ = ["Space", "make_space"]

DECADES_BELOW = 3.0  # gains from 1e-3 unit ...
_LN10 = math.log(10.0)
RATIO_DECADES = 4.0  # a lead's pole up to 10^4 times its zero (a lag's zero over its pole)
_V_SPAN = math.log10(GAIN_SPAN) + DECADES_BELOW  # ... to GAIN_SPAN unit
_G = 10 ** -DECADES_BELOW  # g = unit * 2*_G*sinh(v ln10) ~ unit * sign(v) 10^(|v|-3)


@dataclass(frozen=True)
class Space:
    """The search box of a structure on a plant: coordinates (gains scaled by ``K0 w0^unit``, frequencies and
    time constants in log10, ordered pairs as log-ratios) with their bounds ``lo``, ``hi``."""

    structure: Structure
    k0: float
    w0: float
    units: tuple[float, ...]  # per parameter: K0 * w0**unit for gains, 1 otherwise
    lo: np.ndarray
    hi: np.ndarray
    names: tuple[str, ...]  # coordinate names (for Optuna)
    _ratio_of: tuple[int | None, ...]  # coordinate i is a log-ratio over param _ratio_of[i]

    def to_params(self, v: Any, *, exp: Callable[[Any], Any] = np.exp, sinh: Callable[[Any], Any] = np.sinh,
                  units: Any = None, linear_gains: bool = False) -> list[Any]:
        """Coordinates -> structure parameters (numbers or CasADi symbols; ``units`` may be symbols).

        ``linear_gains``: gains are ``unit * w`` instead of the log-like map (the NLP's coordinates:
        the controller's coefficients are linear in the gains, which keeps IPOPT's model smooth).
        """
        units = self.units if units is None else units
        x: list[Any] = []
        ln10 = math.log(10.0)
        for i, kind in enumerate(self.structure.kinds):
            if kind == "gain":
                x.append(units[i] * (v[i] if linear_gains else (2 * _G) * sinh(v[i] * _LN10)))
            elif kind in ("freq", "time"):
                j = self._ratio_of[i]
                if j is None:
                    x.append(exp(v[i] * ln10))
                else:
                    x.append(x[j] * exp(v[i] * ln10))
            else:
                x.append(v[i])
        return x

    def from_params(self, x: np.ndarray, *, linear_gains: bool = False) -> np.ndarray:
        """Coordinates of the structure parameters ``x`` (the inverse of :meth:`params`)."""
        v = np.zeros(len(x))
        for i, kind in enumerate(self.structure.kinds):
            if kind == "gain":
                w = x[i] / self.units[i]
                v[i] = w if linear_gains else math.asinh(w / (2 * _G)) / _LN10
            elif kind in ("freq", "time"):
                j = self._ratio_of[i]
                xi = max(float(x[i]), 1e-300)
                v[i] = math.log10(xi) if j is None else math.log10(xi / max(float(x[j]), 1e-300))
            else:
                v[i] = x[i]
        lo, hi = self.bounds(linear_gains=linear_gains)
        return np.clip(v, lo, hi)

    def bounds(self, *, linear_gains: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The box ``(lo, hi)`` in coordinates (``linear_gains``: gains unscaled, within +-``GAIN_SPAN``)."""
        if not linear_gains:
            return self.lo, self.hi
        g = np.array([k == "gain" for k in self.structure.kinds])
        g_lo = 0.0 if self.structure.nonneg else -GAIN_SPAN  # a firmware law's gains are >= 0
        lo, hi = np.where(g, g_lo, self.lo), np.where(g, GAIN_SPAN, self.hi)
        for i, p in enumerate(self.structure.params):  # a firmware law's documented ranges, in units
            rng = self.structure.param_range(p) if g[i] else None
            if rng is not None:
                lo[i] = self.params(self.lo)[i] / self.units[i]
                hi[i] = self.params(self.hi)[i] / self.units[i]
        return lo, hi

    def params(self, v: np.ndarray, *, linear_gains: bool = False) -> np.ndarray:
        """Numeric :meth:`to_params`; a coordinate far outside the box (an NLP iterate) may overflow to an
        infinite (or NaN) parameter, which the callers drop (the engine scores finite points only)."""
        with np.errstate(over="ignore", invalid="ignore"):
            return np.asarray(self.to_params(np.asarray(v, dtype=float), linear_gains=linear_gains), dtype=float)


def _coord(x: float, unit: float) -> float:
    """The search coordinate of gain ``x`` with plant-based ``unit`` (the inverse of the log-like map)."""
    return math.asinh(x / (unit * 2 * _G)) / _LN10


def _range_box(rng: tuple[float, float], unit: float, g_lo: float, g_hi: float) -> tuple[float, float]:
    """A gain's coordinate box within its documented range ``rng``: the plant-based box intersected with the range;
    the range alone where the two do not meet (the range is what the firmware's file can hold: a design outside it
    cannot be written, and the verifier then says what the plant needs)."""
    lo_c = _coord(rng[0], unit) if math.isfinite(rng[0]) else g_lo
    hi_c = _coord(rng[1], unit) if math.isfinite(rng[1]) else g_hi
    a, b = max(g_lo, lo_c), min(g_hi, hi_c)
    if a < b:
        return a, b
    return lo_c, (hi_c if math.isfinite(rng[1]) else max(lo_c + 1.0, g_hi))


def make_space(structure: Structure, plant: Plant, dt: float | None, *, scale: PlantScale | None = None,
               nyquist: bool = False) -> Space:
    """The search box of ``structure`` on ``plant`` at ``dt`` (``scale``: the plant's (K0, w0) if known;
    ``nyquist``: filter time constants from ``dt/pi``, the spec's ``filter_nyquist``)."""
    k0, w0 = scale or plant_scale(plant, dt)
    lo_p, hi_p = bounds(structure, plant, dt, scale=(k0, w0), nyquist=nyquist)
    idx = {p: i for i, p in enumerate(structure.params)}
    ratio_of: list[int | None] = [None] * len(structure.params)
    for a, b in structure.orderings:  # param b (or a) expressed as a ratio over the other
        ia, ib = idx[a], idx[b]
        if ia < ib:
            ratio_of[ib] = ia  # b = a * 10^r, r > 0
        else:
            ratio_of[ia] = ib
    units = tuple(float(u) for u in structure.gain_scale(k0, w0))
    lo, hi, names = [], [], []
    for i, (p, kind) in enumerate(zip(structure.params, structure.kinds)):
        if kind == "gain":
            g_lo, g_hi = (0.0 if structure.nonneg else -_V_SPAN), _V_SPAN
            rng = structure.param_range(p)
            if rng is not None:  # a firmware law's documented range (what its parameter file can hold)
                g_lo, g_hi = _range_box(rng, units[i], g_lo, g_hi)
            lo.append(g_lo), hi.append(g_hi)
            names.append(f"asinh_{p}")
        elif kind in ("freq", "time"):
            if ratio_of[i] is not None:
                j = ratio_of[i]
                # ordering a < b: if b is the ratio coordinate, r in (0, 3]; if a is, r in [-3, 0)
                a, b = next(o for o in structure.orderings if p in o)
                sign = 1.0 if b == p else -1.0
                lo.append(min(0.0, RATIO_DECADES * sign) + (1e-3 if sign > 0 else 0.0))
                hi.append(max(0.0, RATIO_DECADES * sign) - (1e-3 if sign < 0 else 0.0))
                names.append(f"log10_{p}_over_{structure.params[j]}")
            else:
                # a time constant's box starts at 0 (no log): floor it at 1e-4/w0; a frequency's box
                # is already > 0 and its floor must not pass its ceiling (pi/dt at a large dt)
                lo_v = lo_p[i] if kind == "freq" else max(lo_p[i], 1e-4 / w0)
                lo.append(math.log10(lo_v)), hi.append(math.log10(hi_p[i]))
                names.append(f"log10_{p}")
        else:
            lo.append(lo_p[i]), hi.append(hi_p[i])
            names.append(p)
    return Space(structure=structure, k0=k0, w0=w0, units=units, lo=np.array(lo), hi=np.array(hi),
                 names=tuple(names), _ratio_of=tuple(ratio_of))
