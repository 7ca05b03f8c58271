"""Frequency-domain robustness figures of a loop, computed from a dense grid and refined.

Unlike ``control.margin`` these report the *worst* phase margin over all gain
crossings, and the upper and lower gain margins separately:

* the upper gain margin is the smallest factor ``k > 1`` at which ``k*L``
  passes through -1 (first crossing of the negative real axis to the right of
  -1, in dB, ``+inf`` if none);
* the lower gain margin is the largest factor ``k < 1`` at which ``k*L``
  passes through -1 (in dB, negative; ``-inf`` if none). Conditionally stable
  loops and loops with unstable open-loop poles have one.

The phase margin is the smallest distance in phase from -1 over all gain crossings:
at each crossing ``|L| = 1`` it is ``180 deg - |angle(L)|`` (in [0, 180]), the phase change that
would put that point on -1; a loop whose crossings are all far from -1 has a large phase margin
whatever the sign of its phases (python-control reports the signed value of the crossing it
picks). Stability is judged separately, from the closed-loop poles.

Crossings are bracketed on a logarithmic grid (endpoints ``w -> 0``, the
Nyquist frequency ``pi/dt`` and, continuous, ``w -> inf`` included) and refined
by vectorised bracketing (two rounds of 72 log-spaced samples inside the bracket,
then linear interpolation in log frequency: :func:`_root`); peaks are refined
around the grid maximum and finished with a parabola (:func:`_peak`). ``L`` is
evaluated from the factored/state-space forms (:meth:`tuner.loop.Loop.freqresp`),
never from expanded polynomials.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import TunerError
from ..loop import Loop
from ..tolerances import EXACT_ROOT_TOL, ROOT_AT_DC_TOL, ROOT_MAG_FLOOR

__all__ = ["Margins", "disk_margin", "disturbance_rejection_bandwidth", "frequency_grid", "margins",
           "sensitivity_peaks", "DRB_LEVEL"]

_GRID_POINTS = 3000


@dataclass(frozen=True)
class Margins:
    """The frequency-domain figures of a loop (what :func:`margins` returns; the module says how).

    Attributes
    ----------
    phase_margin_deg, crossover_rad_s : float
        The worst phase margin over all gain crossings, degrees in [0, 180], and where it is taken
        (``inf``/``nan`` when ``|L|`` never crosses 1; both ``nan`` when it crosses 1 beyond 1e-300..1e300 rad/s,
        out of double precision's reach: unknown, and failing a phase-margin limit).
    gain_margin_db, gain_margin_lower_db : float
        Upper (> 0 dB, ``inf`` if none) and lower (< 0 dB, ``-inf`` if none) gain margins.
    phase_crossover_rad_s : float
        Where the upper gain margin is taken (``nan`` if none).
    disk_margin : float
        Balanced disk margin alpha (0..2).
    ms, mt, mks : float
        Peaks of ``|S|``, ``|T|`` and ``|C S|``.
    bandwidth_rad_s : float
        Where ``|T|`` first falls 3 dB below ``|T(0)|``.

    Examples
    --------
    >>> import control
    >>> from tuner import analyze
    >>> mg = analyze(control.tf([1], [1, 1]), control.tf([2, 2], [1, 0])).margins  # L = 2/s
    >>> round(mg.phase_margin_deg, 6), round(mg.crossover_rad_s, 6), mg.gain_margin_db
    (90.0, 2.0, inf)
    >>> mg
    Margins(PM 90 deg at 2 rad/s, GM inf dB
      Ms 1 | Mt 1 | Mks 2 | bandwidth 2 rad/s | disk margin 2)
    """

    phase_margin_deg: float
    crossover_rad_s: float
    gain_margin_db: float
    gain_margin_lower_db: float
    phase_crossover_rad_s: float
    disk_margin: float
    ms: float
    bandwidth_rad_s: float
    mt: float = math.nan  # peak of |T| = |L / (1 + L)|
    mks: float = math.nan  # peak of |C S| = |C / (1 + L)|: how much measurement noise reaches the actuator
    #: the disturbance rejection bandwidth: the lowest frequency where |S| rises to -3 dB (1/sqrt(2)); 0 when |S| is
    #: there already at w -> 0, inf when it never gets there
    drb_rad_s: float = math.nan

    def __repr__(self) -> str:
        from ..text import margins_repr

        return margins_repr(self)


def frequency_grid(loop: Loop, n: int = _GRID_POINTS) -> np.ndarray:
    """Log grid covering every pole/zero frequency of the loop by two decades each side."""
    zk = loop.zpk
    roots = np.concatenate([zk.zeros, zk.poles])
    if loop.dt is not None:
        # roots at z = 0 (delays) have no frequency; at z = 1 (integrators) they are at DC
        roots = roots[(np.abs(roots) > EXACT_ROOT_TOL) & (np.abs(roots - 1.0) > ROOT_AT_DC_TOL)]
        roots = np.log(roots.astype(complex)) / loop.dt
    mags = np.abs(roots)
    mags = mags[(mags > ROOT_MAG_FLOOR) & np.isfinite(mags)]  # roots at 0 up to rounding are not frequencies
    asym = _asymptote_crossings(loop)  # deliberate: a gain of 1e-100 on 1/s crosses at 1e-100 rad/s
    mags = np.concatenate([mags, asym[(asym > 0) & np.isfinite(asym)]])
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


def _asymptote_crossings(loop: Loop) -> np.ndarray:
    """Where the low- and high-frequency asymptotes of ``|L|`` cross 1 (rad/s), from the factored form in logs.

    A loop with a very large or very small gain crosses over far from every pole and zero (a gain of
    1e150 on 1/(s+1) crosses at 1e150 rad/s): the grid must reach it, or "no crossing" would be reported.
    Low: ``|L| ~ |K_q| / w^q`` with ``q`` integrators (z = 1 in discrete time: ``w dt`` for ``w``);
    high (continuous): ``|L| ~ |k| w^-r`` with relative degree ``r``.
    """
    zk = loop.zpk
    if zk.gain == 0 or not np.isfinite(zk.gain):
        return np.zeros(0)
    out = []
    q, lk = _dc_asymptote(loop, ROOT_AT_DC_TOL)
    if q > 0:
        w = 10.0 ** np.clip(lk / q, -300, 300)
        out.append(w / loop.dt if loop.dt is not None else w)
    r = zk.poles.size - zk.zeros.size
    if loop.dt is None and r > 0:
        out.append(10.0 ** np.clip(math.log10(abs(zk.gain)) / r, -300, 300))
    return np.asarray(out, dtype=float)


def _dc_asymptote(loop: Loop, tol: float) -> tuple[int, float]:
    """``(q, log10 |K_q|)`` of the low-frequency asymptote ``|L| ~ |K_q| / w^q`` (``w dt`` for ``w`` in discrete
    time), from the factored form in logs: ``q`` poles less zeros at DC (s = 0; z = 1) within ``tol``, exactly at
    it for ``tol`` 0, and ``K_q`` from the gain and the other roots' distances to DC."""
    zk = loop.zpk
    x0 = 0.0 if loop.dt is None else 1.0
    zeros, poles = zk.zeros, zk.poles
    if loop.dt is not None:  # delay poles at z = 0 have |1 - 0| = 1: they do not change |K_q|
        poles = poles[np.abs(poles) > EXACT_ROOT_TOL]
    zi, pi_ = (np.abs(zeros - x0) < tol, np.abs(poles - x0) < tol) if tol else (zeros == x0, poles == x0)
    with np.errstate(divide="ignore"):
        lk = math.log10(abs(zk.gain)) + float(np.sum(np.log10(np.abs(x0 - zeros[~zi])))) \
            - float(np.sum(np.log10(np.abs(x0 - poles[~pi_]))))
    return int(pi_.sum() - zi.sum()), lk


def _root(fv, a: float, b: float, *, rounds: int = 2, n: int = 72) -> float:
    """Root of a real function in ``[a, b]`` (bracketed by a sign change): each round samples ``fv`` (an
    array function) at ``n`` log-spaced points and keeps the sub-bracket, ``n^rounds``-fold narrower in
    all; then linear interpolation. Vectorised: ``rounds`` calls of ``fv`` in all (no scalar iteration)."""
    if not (a > 0 and b > a):
        return 0.5 * (a + b)
    fa = fb = math.nan
    for _ in range(rounds):
        x = np.geomspace(a, b, n)
        with np.errstate(all="ignore"):
            f = np.asarray(fv(x), dtype=float)
        s = np.sign(f)
        idx = np.flatnonzero((s[:-1] * s[1:] <= 0) & np.isfinite(f[:-1]) & np.isfinite(f[1:]))
        if idx.size == 0:
            break
        i = int(idx[0])
        a, b, fa, fb = float(x[i]), float(x[i + 1]), float(f[i]), float(f[i + 1])
    if not (math.isfinite(fa) and math.isfinite(fb)) or fa == fb:
        return math.sqrt(a * b)
    t = fa / (fa - fb)
    return float(math.exp(math.log(a) + t * (math.log(b) - math.log(a))))


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
        def im_rel(x: np.ndarray) -> np.ndarray:
            Lx = loop.freqresp(x)
            return Lx.imag / np.maximum(np.abs(Lx), 1e-300)

        wc = _root(im_rel, w[i], w[i + 1])
        Lc = complex(loop.freqresp(np.array([wc]))[0])
        mag = _cabs(Lc)
        if abs(Lc.imag) <= 1e-6 * mag and mag < 1e12:
            pts.append((wc, Lc))
    # exact zeros of Im L on the grid
    for i in np.flatnonzero(im == 0):
        pts.append((float(w[i]), complex(L[i])))
    # endpoints where L is real: DC of a type-0 loop, and infinity (continuous) with feedthrough
    if not loop.integrating:
        pts.append((0.0, complex(loop.value_at(0.0 if loop.dt is None else 1.0).real)))
    v_inf = _at_infinity(loop)
    if v_inf is not None:
        pts.append((math.inf, complex(v_inf)))
    if loop.dt is not None:
        # the Nyquist frequency pi/dt, z = -1 exactly: L is real there, but on the grid
        # exp(j*pi) has a rounding-size imaginary part, so no sign change is seen
        v = loop.value_at(-1.0)
        if np.isfinite(v):
            pts.append((math.pi / loop.dt, complex(v.real)))
    return pts


def _cabs(z: complex) -> float:
    """``|z|``, inf where it overflows (Python's ``abs`` of a complex raises OverflowError there: near a pole on
    the imaginary axis, ``L`` of a loop gain of 1e300)."""
    with np.errstate(over="ignore"):
        return float(np.abs(np.complex128(z)))


def _at_infinity(loop: Loop) -> float | None:
    """``L(j inf)`` of a continuous loop without delay (``C(inf) G(inf)``), else None."""
    if loop.dt is not None or loop.delay_s:
        return None
    return float(loop.controller.ss().D * loop.plant.ss().D)


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


def _pm_at(L: complex) -> float:
    """Distance in phase from -1 of a point on the unit circle, degrees in [0, 180]."""
    return 180.0 - abs(math.degrees(np.angle(L)))


class _Phase:
    """The loop's phase unwrapped along the frequency axis from its lowest frequency, in degrees: the sum of its
    factors' phases (the gain's, each zero's ``angle(x - z)``, minus each pole's, a continuous delay's ``-w tau``), each
    factor unwrapped on its own along the verifier's grid (a factor's phase moves by at most 180 degrees, and fast only
    next to its own root: unwrapping the sum would take a lightly damped mode's swing for a jump). ``at(wc, i)`` is the
    phase at ``wc`` between grid points ``i`` and ``i + 1``, each factor on the branch nearest its value at ``w[i]``.
    The low-frequency branch: each factor's principal angle, a negative loop gain a lag of 180 degrees."""

    def __init__(self, loop: Loop, w: np.ndarray) -> None:
        self.loop = loop
        zk = loop.zpk
        self.roots = np.concatenate([np.asarray(zk.zeros, complex), np.asarray(zk.poles, complex)])
        self.sign = np.concatenate([np.ones(len(zk.zeros)), -np.ones(len(zk.poles))])
        self.k = 0.0 if zk.gain >= 0 else -math.pi
        self.w = w
        self.grid = np.unwrap(np.angle(self._x(w)[None, :] - self.roots[:, None]), axis=1) if self.roots.size else \
            np.zeros((0, w.size))

    def _x(self, w: np.ndarray) -> np.ndarray:
        return 1j * w if self.loop.dt is None else np.exp(1j * w * self.loop.dt)

    def at(self, wc: float, i: int) -> float:
        """The unwrapped phase at ``wc`` (degrees), ``w[i] <= wc``."""
        a = np.angle(self._x(np.array([wc]))[0] - self.roots) if self.roots.size else np.zeros(0)
        ref = self.grid[:, min(max(i, 0), self.w.size - 1)]
        a = a + 2 * np.pi * np.round((ref - a) / (2 * np.pi))
        ph = self.k + float(np.sum(self.sign * a)) - (wc * self.loop.delay_s if self.loop.dt is None else 0.0)
        return math.degrees(ph)


def _phase_margin(loop: Loop, w: np.ndarray, L: np.ndarray) -> tuple[float, float]:
    """The worst phase margin over every gain crossing: ``180 + phase(L)`` at the crossing, the phase unwrapped from
    low frequency (:class:`_Phase`): negative where the phase lag at a crossing exceeds 180 degrees (a loop stable only
    through its other crossings, the PX4 autotune's design on a flexible frame: -52 deg, where the distance of ``L``
    from -1 alone, 52 deg, reads as a margin); at most 180 (a phase lead at the crossing: the distance from -1, the
    nearer way round) and at least -180 (a lag of more than a turn, a delay's before a resonance's peak crosses 1:
    an identified pitch loop's 180 - 814.9 deg is the distance, 85.1 deg). A loop whose factors cannot be had gives
    that distance, unsigned."""
    with np.errstate(divide="ignore"):
        mag = np.log(np.abs(L))
    s = np.sign(mag)
    idx = np.flatnonzero((s[:-1] * s[1:] < 0) & np.isfinite(mag[:-1]) & np.isfinite(mag[1:]))
    brackets: list[tuple[float, float] | None] = [(w[i], w[i + 1]) for i in idx]
    brackets += _beyond_grid(loop, w, L)
    try:
        phase: _Phase | None = _Phase(loop, w)
    except (TunerError, ValueError, FloatingPointError):
        phase = None
    best, wbest = math.inf, math.nan
    for br in brackets:
        if br is None:  # a crossing beyond double precision's reach: the margin is unknown
            return math.nan, math.nan
        wc = _root(lambda x: np.log(np.abs(loop.freqresp(x))), *br)
        pm = _pm_at(complex(loop.freqresp(np.array([wc]))[0]))
        if phase is not None and w[0] <= wc <= w[-1]:
            signed = 180.0 + phase.at(wc, int(np.searchsorted(w, wc)) - 1)
            # the unwrapped phase decides the side; where it and the factored value disagree by more than rounding
            # (a crossing the realisation and the factors see differently) the distance stands, and so it does for a
            # phase lead at the crossing (signed above 180: the distance from -1 is then the nearer way round)
            # beyond one turn of lag (signed below -180: a delay's lag accumulated while |L| < 1, before a lightly
            # damped mode's peak crosses 1) the sign says nothing about the side and the distance stands too
            if math.isfinite(signed) and -180.0 <= signed <= 180.0 and \
                    abs(abs(((signed + 180.0) % 360.0) - 180.0) - pm) < 1e-6 * max(1.0, pm):
                pm = signed
        if pm < best:
            best, wbest = pm, wc
    return best, wbest


def _dc_magnitude(loop: Loop) -> float:
    """``|L|`` in the limit w -> 0, from the factored form in logs (no overflow): inf with more poles than zeros
    exactly at DC (s = 0; z = 1), 0 with fewer, else ``|k| prod|x0 - z| / prod|x0 - p|`` over the others (a pole
    near DC, 1e-11/(s + 1e-10), has its finite value, 0.1; a zero cancelling an integrator, a washout on 1/s,
    leaves the rest's)."""
    if loop.zpk.gain == 0:  # a zero controller: L = 0 at every frequency, integrator or not
        return 0.0
    q, lk = _dc_asymptote(loop, 0.0)
    if q:
        return math.inf if q > 0 else 0.0
    return 10.0 ** lk if lk < 308.0 else math.inf


_W_REACH = 300  # decades: the frequencies searched beyond the grid, 1e-300 .. 1e300 rad/s


def _beyond_grid(loop: Loop, w: np.ndarray, L: np.ndarray) -> list[tuple[float, float] | None]:
    """Brackets of the gain crossings beyond the grid's ends. Where ``|L|`` is on one side of 1 at an end of the
    grid and on the other in the limit beyond it (w -> 0; continuous, w -> inf) it crosses 1 out there (the grid
    spans two decades beyond every pole and zero and the asymptote crossings, so this is a rounding-level
    near-miss, ``|L(0)|`` = 1.00001, or a crossing far out, 1e-300/(s (s - 1e6)) at 1e-306 rad/s): searched by
    decades out to 1e-300 / 1e300 rad/s, and None (unknown) when it is not found there. Differences of ``|L|``
    from 1 at rounding level (1e-9) are no side."""
    def side(m: float) -> float:
        if math.isnan(m):
            return 0.0
        lg = math.log(m) if m > 0 else -math.inf
        return 0.0 if abs(lg) <= 1e-9 else math.copysign(1.0, lg)

    ends = [(w[0], L[0], _dc_magnitude(loop), -1.0)]
    if loop.dt is None:  # |L(jw)| -> |C(inf) G(inf)|, delay or not
        ends.append((w[-1], L[-1], abs(float(loop.controller.ss().D * loop.plant.ss().D)), 1.0))
    out: list[tuple[float, float] | None] = []
    for w_end, L_end, limit, way in ends:
        far = side(limit)
        if not (np.isfinite(L_end) and far * side(_cabs(L_end)) < 0):
            continue
        n = int(math.floor(_W_REACH - way * math.log10(w_end)))
        xs = w_end * 10.0 ** (way * np.arange(1, n + 1)) if n >= 1 else np.zeros(0)
        with np.errstate(all="ignore"):
            mags = np.abs(loop.freqresp(xs)) if xs.size else np.zeros(0)
        hit = next((i for i, m in enumerate(mags) if side(float(m)) == far), None)
        if hit is None:
            out.append(None)
            continue
        prev = w_end if hit == 0 else float(xs[hit - 1])
        out.append((float(xs[hit]), prev) if way < 0 else (prev, float(xs[hit])))
    return out


def _limit_values(loop: Loop) -> np.ndarray:
    """``L`` at the ends the grid only approaches: w = 0 (when finite) and, continuous, w -> inf."""
    vals = []
    if not loop.integrating:
        vals.append(loop.value_at(0.0 if loop.dt is None else 1.0))
    if loop.dt is None:
        # strictly proper: L -> 0 (|S| -> 1, with or without delay); biproper without delay: C(inf) G(inf)
        c_inf, g_inf = loop.controller.ss().D, loop.plant.ss().D
        if c_inf * g_inf == 0:
            vals.append(0.0)
        elif not loop.delay_s:
            vals.append(c_inf * g_inf)
    v = np.asarray(vals, dtype=complex)
    return v[np.isfinite(v) & (v != 1.0) & (v != -1.0)]


def _peak(fv, w: np.ndarray, vals: np.ndarray, *, rounds: int = 2, n: int = 65) -> float:
    """Maximum over the grid, refined around the grid maximum: each round samples ``fv`` (an array
    function) at ``n`` points between the neighbours of the best point so far; then a parabola."""
    i = int(np.nanargmax(vals))
    best = float(vals[i])
    a, b = w[max(i - 1, 0)], w[min(i + 1, w.size - 1)]
    for _ in range(rounds):
        if not (a > 0 and b > a):
            break
        x = np.geomspace(a, b, n)
        with np.errstate(all="ignore"):
            f = np.where(np.isfinite(v := np.asarray(fv(x), dtype=float)), v, -np.inf)
        j = int(np.argmax(f))
        best = max(best, float(f[j]))
        if 0 < j < n - 1:  # parabola through the three points around the maximum (log frequency)
            f0, f1, f2 = f[j - 1], f[j], f[j + 1]
            if np.isfinite(f0) and np.isfinite(f2):
                with np.errstate(over="ignore"):
                    den, d = f0 - 2 * f1 + f2, f2 - f0
                    if den < 0:  # vertex f1 - d^2 / (8 den), formed without squaring d (no overflow near 1e300)
                        top = f1 - 0.125 * d * (d / den)
                        if np.isfinite(top):
                            best = max(best, float(top))
        a, b = x[max(j - 1, 0)], x[min(j + 1, n - 1)]
    return best


def _bandwidth(loop: Loop, w: np.ndarray, T: np.ndarray) -> float:
    if loop.integrating:
        t0 = 1.0
    else:
        L0 = loop.value_at(0.0 if loop.dt is None else 1.0)
        t0 = abs(L0 / (1 + L0)) if np.isfinite(L0) and L0 != -1 else math.nan
    if not np.isfinite(t0) or t0 == 0:
        return math.nan
    thr = t0 / math.sqrt(2.0)
    below = np.flatnonzero(np.abs(T) < thr)
    if below.size == 0:
        return math.inf
    i = int(below[0])
    if i == 0:
        return float(w[0])

    def f(x: np.ndarray) -> np.ndarray:
        Lx = loop.freqresp(x)
        return np.abs(Lx / (1 + Lx)) - thr

    return _root(f, w[i - 1], w[i])


def disk_margin(loop: Loop, w: np.ndarray | None = None, L: np.ndarray | None = None) -> float:
    """Balanced (skew 0) disk margin: min over w of ``2|1+L|/|1-L|`` on the frequency response (what
    ``control.disk_margins(L, w, skew=0)`` computes), the limits w -> 0 and w -> inf included."""
    if w is None:
        w = frequency_grid(loop)
    if L is None:
        with np.errstate(divide="ignore", invalid="ignore"):
            L = loop.freqresp(w)
    finite = np.isfinite(L)
    dm = float(np.min(_disk_ratio(L[finite]))) if finite.any() else math.inf
    L_ends = _limit_values(loop)  # the grid stops short of w = 0 and w = inf: include the limits
    if L_ends.size:
        dm = min(dm, float(np.min(_disk_ratio(L_ends))))
    return dm


def _disk_ratio(L: np.ndarray) -> np.ndarray:
    """``2|1+L|/|1-L|`` at finite ``L``, evaluated at ``1/L`` where ``|L| > 1`` (the ratio is the same at ``L`` and
    ``1/L``): ``|1 +- L|`` of an ``L`` near 1e308 overflows, and inf/inf was a NaN margin."""
    with np.errstate(all="ignore"):  # 1/L of |L| ~ 1e308 underflows to 0, as it should
        big = np.abs(L) > 1.0
        u = np.where(big, 1.0 / np.where(big, L, 1.0), L)
        return 2 * np.abs(1 + u) / np.abs(1 - u)


def margins(loop: Loop, *, grid_points: int = _GRID_POINTS) -> Margins:
    """All frequency-domain figures of ``loop``."""
    w = frequency_grid(loop, grid_points)
    with np.errstate(divide="ignore", invalid="ignore"):
        L = loop.freqresp(w)
        S = 1.0 / (1.0 + L)
    pm, wc = _phase_margin(loop, w, L)
    gm, gml, wpc = _gain_margins(_real_axis_points(loop, w, L))
    ms, mt, mks = sensitivity_peaks(loop, w, L)
    bw = _bandwidth(loop, w, L * S)
    dm = disk_margin(loop, w, L)
    return Margins(
        phase_margin_deg=pm, crossover_rad_s=wc, gain_margin_db=gm, gain_margin_lower_db=gml,
        phase_crossover_rad_s=wpc, disk_margin=dm, ms=ms, bandwidth_rad_s=bw, mt=mt, mks=mks,
        drb_rad_s=disturbance_rejection_bandwidth(loop, w, S),
    )


DRB_LEVEL = 1.0 / math.sqrt(2.0)  # -3 dB


def disturbance_rejection_bandwidth(loop: Loop, w: np.ndarray, S: np.ndarray) -> float:
    """The lowest frequency where ``|S| = |1/(1 + L)|`` rises to -3 dB (rotorcraft practice, e.g. ADS-33E-PRF's
    disturbance rejection bandwidth): on the loop's exact frequency response (a sampled-data loop's at its dt, the hold
    and a fractional delay included), the grid's first point at or above the level refined by root finding. 0 when
    ``|S|`` is at the level already as w -> 0 (no low-frequency rejection), inf when it never reaches it on the grid
    (up to Nyquist at dt)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        mag = np.abs(S)
    above = np.flatnonzero(np.isfinite(mag) & (mag >= DRB_LEVEL))
    if above.size == 0:
        return math.inf
    i = int(above[0])

    def f(x: np.ndarray) -> np.ndarray:
        return np.abs(1.0 / (1.0 + loop.freqresp(x))) - DRB_LEVEL

    if i == 0:  # at the grid's lowest frequency already: with integral action |S(0)| = 0, so it rises below that
        if not loop.integrating:
            return 0.0
        lo = float(w[0])
        for _ in range(6):  # down by decades to where |S| is below the level, then the root between
            hi, lo = lo, lo / 10.0
            with np.errstate(all="ignore"):
                if float(f(np.array([lo]))[0]) < 0:
                    return _root(f, lo, hi)
        return 0.0  # not below -3 dB even 1e6 times lower: no rejection worth the name
    return _root(f, w[i - 1], w[i])


def sensitivity_peaks(loop: Loop, w: np.ndarray, L: np.ndarray) -> tuple[float, float, float]:
    """Peaks of ``|S|``, ``|T|`` and ``|C S|`` over the grid (refined locally), limits at w -> 0, inf included."""
    with np.errstate(divide="ignore", invalid="ignore"):
        C = loop.controller.freqresp(w)
        S = 1.0 / (1.0 + L)
        T = L * S
        CS = C * S

    def f_s(x: np.ndarray) -> np.ndarray:
        return np.abs(1.0 / (1.0 + loop.freqresp(x)))

    def f_t(x: np.ndarray) -> np.ndarray:
        Lx = loop.freqresp(x)
        return np.abs(Lx / (1.0 + Lx))

    def f_cs(x: np.ndarray) -> np.ndarray:
        return np.abs(loop.controller.freqresp(x) / (1.0 + loop.freqresp(x)))

    def finite(v: np.ndarray) -> np.ndarray:
        return np.where(np.isfinite(v), np.abs(v), 0.0)

    ms, mt, mks = (_peak(f, w, finite(v)) for f, v in ((f_s, S), (f_t, T), (f_cs, CS)))
    L_ends = _limit_values(loop)  # the grid stops short of w = 0 and w = inf: include the limits
    if L_ends.size:
        ms = max(ms, float(np.max(1.0 / np.abs(1.0 + L_ends))))
        mt = max(mt, float(np.max(np.abs(L_ends / (1.0 + L_ends)))))
    if loop.dt is None:  # w -> inf: C(inf) / (1 + L(inf))
        c_inf, g_inf = loop.controller.ss().D, loop.plant.ss().D
        l_inf = 0.0 if loop.delay_s and g_inf == 0 else c_inf * g_inf
        if not loop.delay_s or g_inf == 0:
            mks = max(mks, abs(c_inf / (1.0 + l_inf)) if l_inf != -1 else math.inf)
    w_low = float(w[0]) * 1e-6 if w.size and w[0] > 0 else 0.0  # the grid stops short of w = 0: |C S| there
    if w_low > 0:
        with np.errstate(all="ignore"):
            low = f_cs(np.array([w_low]))[0]  # -> 1/|G(0)| with integral action (and no plant integrator)
        if np.isfinite(low):
            mks = max(mks, float(low))
    if loop.integrating:
        mt = max(mt, 1.0)  # T(0) = 1
    return ms, mt, mks
