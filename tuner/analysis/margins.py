"""Frequency-domain robustness figures of a loop, computed from a dense grid and refined.

Unlike ``control.margin`` these report the *worst* phase margin over all gain
crossings, and the upper and lower gain margins separately:

* the upper gain margin is the smallest factor ``k > 1`` at which ``k*L``
  passes through -1 (first crossing of the negative real axis to the right of
  -1, in dB, ``+inf`` if none);
* the lower gain margin is the largest factor ``k < 1`` at which ``k*L``
  passes through -1 (in dB, negative; ``-inf`` if none). Conditionally stable
  loops and loops with unstable open-loop poles have one.

Crossings are bracketed on a logarithmic grid (endpoints ``w -> 0``, the
Nyquist frequency ``pi/dt`` and, continuous, ``w -> inf`` included) and refined
with Brent's method.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import control as ct
import numpy as np
from scipy import optimize

from ..loop import Loop

__all__ = ["Margins", "disk_margin", "frequency_grid", "margins"]

_GRID_POINTS = 3000


@dataclass(frozen=True)
class Margins:
    phase_margin_deg: float
    crossover_rad_s: float
    gain_margin_db: float
    gain_margin_lower_db: float
    phase_crossover_rad_s: float
    disk_margin: float
    ms: float
    bandwidth_rad_s: float


def frequency_grid(loop: Loop, n: int = _GRID_POINTS) -> np.ndarray:
    """Log grid covering every pole/zero frequency of the loop by two decades each side."""
    roots = np.concatenate([np.roots(loop.ln), np.roots(loop.ld)]) if loop.ld.size > 1 else np.zeros(0)
    if loop.dt is not None:
        # roots at z = 1 (integrators) are at DC; a multiple root there comes back from
        # np.roots split by ~sqrt(eps), which would otherwise pull the grid down to ~1e-7 rad/s
        # where L (evaluated from expanded polynomials) is rounding noise and shows spurious
        # real-axis crossings (e.g. a -235 dB "lower gain margin" of a type-2 loop)
        roots = roots[(np.abs(roots) > 1e-12) & (np.abs(roots - 1.0) > 1e-5)]
        roots = np.log(roots.astype(complex)) / loop.dt
    mags = np.abs(roots)
    mags = mags[(mags > 1e-9) & np.isfinite(mags)]
    wnyq = loop.nyquist_w()
    lo = (mags.min() if mags.size else 1.0) / 100.0
    if wnyq:
        lo = min(lo, wnyq * 1e-4)
        return np.concatenate([np.logspace(np.log10(lo), np.log10(wnyq), n)[:-1], [wnyq]])
    hi = (mags.max() if mags.size else 1.0) * 100.0
    if loop.delay_s:
        hi = max(hi, 20.0 / loop.delay_s)
        lo = min(lo, 0.01 / loop.delay_s)
    return np.logspace(np.log10(lo), np.log10(hi), n)


def _brent(f, a: float, b: float) -> float:
    try:
        return float(optimize.brentq(f, a, b, xtol=1e-12 * max(a, 1e-300), rtol=1e-12, maxiter=100))
    except (ValueError, RuntimeError):
        return 0.5 * (a + b)


def _wrap_pm(L: complex) -> float:
    """Phase margin of one gain crossing: angle from -1, in (-180, 180]."""
    deg = math.degrees(np.angle(L)) + 180.0
    return (deg + 180.0) % 360.0 - 180.0 if deg != 180.0 else 180.0


def _real_axis_points(loop: Loop, w: np.ndarray, L: np.ndarray) -> list[tuple[float, complex]]:
    """Frequencies where ``L`` is real (sign change of Im L with a finite value), plus the endpoints."""
    pts: list[tuple[float, complex]] = []
    im = L.imag / np.maximum(np.abs(L), 1e-300)
    s = np.sign(im)
    idx = np.flatnonzero(s[:-1] * s[1:] < 0)
    for i in idx:
        # a sign change through infinity (imaginary-axis pole) is not a crossing
        if not (np.isfinite(L[i]) and np.isfinite(L[i + 1])):
            continue
        wc = _brent(lambda x: float(np.imag(loop.freqresp(np.array([x]))[0]) /
                                    max(abs(loop.freqresp(np.array([x]))[0]), 1e-300)), w[i], w[i + 1])
        Lc = complex(loop.freqresp(np.array([wc]))[0])
        if abs(Lc.imag) <= 1e-6 * abs(Lc) and abs(Lc) < 1e12:
            pts.append((wc, Lc))
    # exact zeros of Im L on the grid
    for i in np.flatnonzero(im == 0):
        pts.append((float(w[i]), complex(L[i])))
    # endpoints where L is real: DC of a type-0 loop, and infinity (continuous) with feedthrough
    dc_x = 0.0 if loop.dt is None else 1.0
    dden = np.polyval(loop.ld, dc_x)
    if abs(dden) > 1e-9 * np.sum(np.abs(loop.ld)):  # not an integrating loop
        pts.append((0.0, complex(np.polyval(loop.ln, dc_x) / dden)))
    if loop.dt is None and loop.ln.size == loop.ld.size and not loop.delay_s:
        pts.append((math.inf, complex(loop.ln[0] / loop.ld[0])))
    if loop.dt is not None:
        # the Nyquist frequency pi/dt, z = -1 exactly: L is real there, but on the grid
        # exp(j*pi) has a rounding-size imaginary part, so no sign change is seen
        dnyq = np.polyval(loop.ld, -1.0)
        if abs(dnyq) > 1e-12 * np.sum(np.abs(loop.ld)):
            pts.append((math.pi / loop.dt, complex(np.polyval(loop.ln, -1.0) / dnyq)))
    return pts


def _gain_margins(pts: list[tuple[float, complex]]) -> tuple[float, float, float]:
    upper, lower, w_up = math.inf, 0.0, math.nan
    for wc, Lc in pts:
        if Lc.real >= 0 or Lc == 0:
            continue
        k = 1.0 / abs(Lc.real)
        if k > 1.0 and k < upper:
            upper, w_up = k, wc
        elif k <= 1.0 and k > lower:
            lower = k
    gm = 20 * math.log10(upper) if math.isfinite(upper) else math.inf
    gml = 20 * math.log10(lower) if lower > 0 else -math.inf
    return gm, gml, w_up


def _phase_margin(loop: Loop, w: np.ndarray, L: np.ndarray) -> tuple[float, float]:
    with np.errstate(divide="ignore"):
        mag = np.log(np.abs(L))
    s = np.sign(mag)
    idx = np.flatnonzero((s[:-1] * s[1:] < 0) & np.isfinite(mag[:-1]) & np.isfinite(mag[1:]))
    best, wbest = math.inf, math.nan
    for i in idx:
        wc = _brent(lambda x: float(np.log(abs(loop.freqresp(np.array([x]))[0]))), w[i], w[i + 1])
        pm = _wrap_pm(complex(loop.freqresp(np.array([wc]))[0]))
        if pm < best:
            best, wbest = pm, wc
    return best, wbest


def _limit_values(loop: Loop) -> np.ndarray:
    """``L`` at the ends the grid only approaches: w = 0 (when finite) and, continuous, w -> inf."""
    vals = []
    dc_x = 0.0 if loop.dt is None else 1.0
    dden = np.polyval(loop.ld, dc_x)
    if abs(dden) > 1e-9 * np.sum(np.abs(loop.ld)):
        vals.append(np.polyval(loop.ln, dc_x) / dden)
    if loop.dt is None:
        # strictly proper: L -> 0 (|S| -> 1, with or without delay); biproper without delay: ln[0]/ld[0]
        if loop.ln.size < loop.ld.size:
            vals.append(0.0)
        elif not loop.delay_s:
            vals.append(loop.ln[0] / loop.ld[0])
    v = np.asarray(vals, dtype=complex)
    return v[np.isfinite(v) & (v != 1.0) & (v != -1.0)]


def _peak(f, w: np.ndarray, vals: np.ndarray) -> float:
    """Maximum of ``f`` over the grid, refined locally around the grid maximum."""
    i = int(np.nanargmax(vals))
    a, b = w[max(i - 1, 0)], w[min(i + 1, w.size - 1)]
    if b <= a:
        return float(vals[i])
    r = optimize.minimize_scalar(lambda x: -f(x), bounds=(a, b), method="bounded",
                                 options={"xatol": 1e-10 * b})
    return float(max(vals[i], -r.fun))


def _bandwidth(loop: Loop, w: np.ndarray, T: np.ndarray) -> float:
    dc_x = 0.0 if loop.dt is None else 1.0
    cp = np.polyval(loop.charpoly, dc_x)
    t0 = abs(np.polyval(loop.ln, dc_x) / cp) if cp != 0 else math.nan
    if not np.isfinite(t0) or t0 == 0:
        return math.nan
    thr = t0 / math.sqrt(2.0)
    below = np.flatnonzero(np.abs(T) < thr)
    if below.size == 0:
        return math.inf
    i = int(below[0])
    if i == 0:
        return float(w[0])

    def f(x: float) -> float:
        Lx = loop.freqresp(np.array([x]))[0]
        return abs(Lx / (1 + Lx)) - thr

    return _brent(f, w[i - 1], w[i])


def disk_margin(loop: Loop, w: np.ndarray | None = None, L: np.ndarray | None = None) -> float:
    """Balanced (skew 0) disk margin: ``control.disk_margins`` for rational loops; with a delay, the
    same quantity, min over w of 2|1+L|/|1-L|, on the exact frequency response."""
    if w is None:
        w = frequency_grid(loop)
    if L is None:
        with np.errstate(divide="ignore", invalid="ignore"):
            L = loop.freqresp(w)
    finite = np.isfinite(L)
    if loop.delay_s:
        dm = float(np.min(2 * np.abs(1 + L[finite]) / np.abs(1 - L[finite])))
    else:
        tf = ct.tf(loop.ln, loop.ld, 0 if loop.dt is None else loop.dt)
        dm = float(ct.disk_margins(tf, w[finite], skew=0.0)[0])
    L_ends = _limit_values(loop)  # the grid stops short of w = 0 and w = inf: include the limits
    if L_ends.size:
        dm = min(dm, float(np.min(2 * np.abs(1 + L_ends) / np.abs(1 - L_ends))))
    return dm


def margins(loop: Loop, *, with_disk: bool = True, grid_points: int = _GRID_POINTS) -> Margins:
    """All frequency-domain figures of ``loop``; ``with_disk=False`` skips the disk margin."""
    w = frequency_grid(loop, grid_points)
    with np.errstate(divide="ignore", invalid="ignore"):
        L = loop.freqresp(w)
        S = 1.0 / (1.0 + L)
    pm, wc = _phase_margin(loop, w, L)
    gm, gml, wpc = _gain_margins(_real_axis_points(loop, w, L))
    absS = np.where(np.isfinite(S), np.abs(S), 0.0)
    ms = _peak(lambda x: abs(1.0 / (1.0 + loop.freqresp(np.array([x]))[0])), w, absS)
    L_ends = _limit_values(loop)  # the grid stops short of w = 0 and w = inf: include the limits
    if L_ends.size:
        ms = max(ms, float(np.max(1.0 / np.abs(1.0 + L_ends))))
    bw = _bandwidth(loop, w, L * S)
    dm = disk_margin(loop, w, L) if with_disk else math.nan
    return Margins(
        phase_margin_deg=pm, crossover_rad_s=wc, gain_margin_db=gm, gain_margin_lower_db=gml,
        phase_crossover_rad_s=wpc, disk_margin=dm, ms=ms, bandwidth_rad_s=bw,
    )
