"""The tuning NLP in CasADi, built once per problem *structure* and re-used.

Structure key = (controller structure, continuous or discrete, plant sizes and delay per plant,
horizon K, points per sample N (optionally only over the first ``head`` samples, ``tail_N`` after them),
which constraints exist, the objective, the solver). Plant data, dt, the spec's numbers, the frequency
grid and the time grid enter as parameters, so re-solving from another start, or for another plant of
the same sizes, does not rebuild anything (``BUILDS`` counts real builds, and solvers made of a stored graph).

Decision variables: the structure's coordinates ``v`` (see :mod:`tuner.optimize.space`; gains
linear in their plant-based unit, frequencies logarithmic), the band slack, and per plant the
gain-crossover frequency ``wc`` (and the phase-crossover frequency ``wp`` where the loop has one
below Nyquist), when the phase and gain margins are constrained.

Constraints, per plant:

* ``|L(j wc)| = 1`` and ``Re L(j wc) >= -cos(PM_min)``  (phase margin at wc);
* ``Im L(j wp) = 0`` and ``Re L(j wp) >= -10^(-GM/20)``  (gain margin at wp), and for sampled-data
  loops the same at the Nyquist frequency, where L is real; the plant's response at these free
  frequencies comes from its zeros, poles and gain (factored, never expanded);
* on a frequency grid (the plant's response there is a parameter): ``|S| <= Ms``, ``|T| <= Mt``,
  ``|C S| <= Mks``, ``2|1 + L| >= alpha |1 - L|`` (disk margin), ``|S| <= 1/sqrt(2)`` at the grid's frequencies up to
  the disturbance rejection bandwidth's limit (one of them at the limit itself), as requested; the grid has spare
  slots that :mod:`~tuner.optimize.nlp.refine` fills with the frequencies where the verifier finds a
  peak the grid missed (an exchange method), so the limits hold on the verifier's dense grid;
* the unit step response between samples (lifted ZOH model, exact at N points per sample, or at N over the
  first ``head`` samples and ``tail_N`` after them, where a slow tail needs no more; a 2-DOF
  controller's reference path drives it, its feedback part the load response and every frequency-domain row):
  ``y <= 1 + overshoot`` and, for the settling-time objective, the envelope ``|y_i - 1| <= b - slack``
  for every ``t_i >= Ts`` (a 0/1 parameter ``mask``, so moving ``Ts`` never rebuilds; with ``interp`` also at
  ``Ts`` itself between grid points, the output interpolated there); optionally
  ``|u_k| <= control_peak_max``.

Objectives, each the verifier's own definition on the same grid (exact, not a proxy):

* ``settling_time``: for a given ``Ts``, maximise the slack; the caller bisects on ``Ts`` (the
  smallest ``Ts`` with slack >= 0 is the minimum settling time on the grid);
* ``iae``: the trapezoid integral of ``|y|`` after a unit load step at the plant input (``|.|`` as
  ``sqrt(y^2 + eps^2)`` with ``eps`` far below the verifier's resolution, so its derivative exists);
* ``itae``: the same of ``t |1 - y|`` for the reference step;
* ``ie``: ``-Ki`` (the integral gain ``lim s C(s)``: IE = 1/Ki after a load step), the MIGO criterion;
* ``mks`` / ``disk_margin``: a level (the decision variable ``slack``) bounds ``|C S|`` from above (or ``2|1 + L|/|1 -
  L|`` from below) on the grid, and the level is minimised (maximised), with the same exchange of missed peaks.

Solvers: ``"sqp"`` (default; CasADi's SQP with a limited-memory Hessian and the DAQP active-set QP
solver: deterministic, no state kept between calls) or ``"ipopt"``.
"""

from __future__ import annotations

import math
import os
import threading
import warnings
from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import casadi as cs
import numpy as np

from ...controllers import Structure
from ..builds import timed_build
from ..space import Space
from . import codecache, graphcache
from .layout import Layout

__all__ = ["ProblemKey", "Problem", "get_problem", "working_set", "estimated_build_s", "is_built", "cached_count",
           "sqp_options", "parameter_layout", "variable_layout", "BUILDS", "MS_GRID",
           "GRID_EXTRA", "SOLVERS"]

BUILDS = {"count": 0}
MS_GRID = 60
GRID_EXTRA = 8  # spare grid slots for the exchange method
SOLVERS = ("sqp", "ipopt")
MAX_SQP_ITER = 150  # per solve: a feasible bisection step takes 3-25; a long move across the settling time's
                    # valleys takes 50-150 (PI on 1/(20s+1)^2 at dt 0.1: from the 5.9 tau basin to the 2.69 tau
                    # valley; at 40 such solves stopped early and the bisection took them for infeasible)
SQP_TOL_DU = 1e-4
# the build cache: every problem the running tune has used (a tune comes back to its problems: the coarse and
# fine grids of each refine, the bisection's; see working_set), and beyond those the most recently used ones up to
# about CACHE_MB of memory. A built problem holds its expression graphs and CasADi's derivative functions, up to
# BYTES_PER_NODE per node of _estimated_nodes (measured 165-212 over the first 40 loops of every fourth quality-suite
# case: 20 MB for a typical loop's problem, three a tune). Unbounded, a study worker held 8.5 GB after 250 loops of
# the suite, and a service solver would reach its 4 GB address-space cap (api/settings.py; api.worker gives the
# cache a quarter of it) after a hundred or so different plants. What later tunes reuse (the suite's loops of one
# class and structure share horizons) needs about 2 GB: replaying the suite's requests in halves of 140 loops
# (bench/build_cache_replay.py), the builds took 88.1 s and 98.1 s with nothing dropped, 93.0 s and 100.4 s at 2 GB,
# 119.2 s and 105.2 s at 1 GB, 178.2 s and 123.1 s keeping nothing between tunes (a two-segment policy, which keeps
# what was used twice apart from what was used once: 99.6 s and 103.3 s at 2 GB)
CACHE_MB = 2048.0


def _cache_mb_from_env() -> float:
    v = os.environ.get("TUNER_NLP_CACHE_MB", "")
    try:
        mb = float(v) if v.strip() else CACHE_MB
    except ValueError:
        mb = math.nan
    if not mb >= 0:  # nan, negative
        warnings.warn(f"TUNER_NLP_CACHE_MB={v!r} is not a number of megabytes >= 0: using {CACHE_MB:g}", stacklevel=2)
        return CACHE_MB
    return mb


CACHE_MB = _cache_mb_from_env()
BYTES_PER_NODE = 210.0
_CACHE: OrderedDict[ProblemKey, tuple[Problem, float]] = OrderedDict()  # key -> (problem, estimated bytes)
_PINNED: dict[str, Any] = {"depth": 0, "keys": set()}  # the running tune's problems (working_set)
_LOCK = threading.RLock()  # the cache's bookkeeping (tunes in threads: all of them are one scope, see working_set)


@dataclass(frozen=True)
class ProblemKey:
    """What decides the NLP's shape (structure, plant orders, delays, grid sizes, active constraints): the
    build cache's key; the plant data themselves are parameters."""

    structure: str
    continuous: bool
    orders: tuple[int, ...]  # plant state dimension per plant
    zeros: tuple[int, ...]  # number of plant zeros per plant (of the factored form the NLP evaluates)
    poles: tuple[int, ...]  # number of plant poles per plant
    delays: tuple[int, ...]  # delay in samples per plant
    K: int
    N: int  # points per sample (over the first ``head`` samples where ``head`` > 0)
    phase_cross: tuple[bool, ...]  # per plant: a phase crossover below Nyquist
    control_peak: bool
    objective: str
    solver: str = "sqp"
    pm: bool = True  # phase margin constrained
    gm: bool = True  # gain margin constrained
    ms: bool = False
    mt: bool = False
    mks: bool = False
    dm: bool = False
    drb: bool = False  # a disturbance-rejection-bandwidth limit: |S| <= -3 dB at the grid's frequencies up to it
    ki: bool = False  # a minimum integral gain: kisgn Ki / ki_min >= 1 (kisgn: the sign a stable loop's Ki has)
    filter_n: bool = False  # the derivative-filter rule N = Td/Tf <= nmax (Spec.filter_n_max)
    settling_max: bool = False  # a settling-time limit with another objective: the band from the mask on
    head: int = 0  # > 0: only the first ``head`` samples have N points, the later ones ``tail_N`` (N a multiple)
    tail_N: int = 1
    interp: bool = False  # the envelope's first row is the output interpolated at Ts between two grid points (theta)

    @property
    def points(self) -> int:
        """The number of points of the step response's time grid (per plant)."""
        return self.K * self.N if not self.head else self.head * self.N + (self.K - self.head) * self.tail_N

    @property
    def grid(self) -> bool:
        """The problem has a frequency grid (an Ms, Mt, Mks, disk-margin or DRB limit, or objective)."""
        return self.ms or self.mt or self.mks or self.dm or self.drb or self.objective in ("mks", "disk_margin")

    @property
    def n_grid(self) -> int:
        """The number of grid frequencies (0 without a grid)."""
        return MS_GRID + GRID_EXTRA if self.grid else 0


@dataclass
class Problem:
    """A built NLP: the CasADi solver, its constraint bounds and the layouts of its parameters and variables."""

    key: ProblemKey
    solver: Any  # casadi nlpsol Function
    n_v: int
    lbg: np.ndarray
    ubg: np.ndarray
    params: Layout  # the parameter vector p
    variables: Layout  # the decision vector x
    step: Any = None  # casadi Function (x, p) -> the reference-step outputs of every plant, stacked (key.points each)
    compiled: bool = False  # the solver and step are the cache's compiled code (codecache), not the interpreted graph
    nlp: Any = None  # the casadi Function (x, p) -> (f, g) the interpreted solver is made of (graphcache stores it)


# the spec's numbers and the steps, in the parameter vector (see refine for their values)
GLOBALS = ("dt", "h", "band", "os", "cpk", "msinv", "mt", "mks", "alpha", "eps", "kiu", "nmax", "kscale",
           "kimin", "kisgn")


def parameter_layout(key: ProblemKey, nv: int) -> Layout:
    """The parameter vector: spec numbers, gain units, per-plant data, the frequency grid, time weights, mask."""
    blocks: list[tuple[str, tuple[int, ...]]] = [(n, ()) for n in GLOBALS] + [("units", (nv,))]
    ng = key.n_grid
    for i, n in enumerate(key.orders):
        blocks += [(f"Phi{i}", (n, n)), (f"Gam{i}", (n,)), (f"C{i}", (n,)), (f"D{i}", ()), (f"Cf{i}", (key.N, n)),
                   (f"Df{i}", (key.N,)), (f"zr{i}", (key.zeros[i],)), (f"zi{i}", (key.zeros[i],)),
                   (f"pr{i}", (key.poles[i],)), (f"pi{i}", (key.poles[i],)), (f"k{i}", ()), (f"tau{i}", ()),
                   (f"Gre{i}", (ng,)), (f"Gim{i}", (ng,)),
                   # the plant's margins (a gain-variation member's its own: TuningProblem.plant_spec)
                   (f"cospm{i}", ()), (f"g{i}", ())]
    blocks += [("wgrid", (ng,)), ("tw", (key.points,)), ("mask", (key.points,))]
    if key.drb:  # 1 at the grid's frequencies up to the DRB limit, 0 above
        blocks += [("drbmask", (ng,))]
    if key.settling_max:  # per plant: the verifier's output minus the NLP's at the grid's points (defect correction)
        blocks += [(f"yoff{i}", (key.points,)) for i in range(len(key.orders))]
    if key.interp:
        blocks += [("theta", (key.points,))]
    return Layout(tuple(blocks))


def variable_layout(key: ProblemKey, nv: int) -> Layout:
    """The decision vector: coordinates ``v``, the band slack, crossover frequencies per plant."""
    n_wc = len(key.orders) if key.pm else 0
    n_wp = sum(key.phase_cross) if key.gm else 0
    return Layout((("v", (nv,)), ("slack", ()), ("wc", (n_wc,)), ("wp", (n_wp,))))


def _cplx_poly(coeffs: list[Any], w: Any, dt: Any, continuous: bool) -> tuple[Any, Any]:
    """Real and imaginary parts of a polynomial (highest power first) at s=jw or z=exp(jw dt)."""
    re, im = 0, 0
    deg = len(coeffs) - 1
    for i, c in enumerate(coeffs):
        k = deg - i
        if continuous:
            wk = w ** k if k else 1  # (j w)^k = w^k j^k
            r = k % 4
            if r == 0:
                re = re + c * wk
            elif r == 1:
                im = im + c * wk
            elif r == 2:
                re = re - c * wk
            else:
                im = im - c * wk
        else:
            re = re + c * cs.cos(k * w * dt)
            im = im + c * cs.sin(k * w * dt)
    return re, im


def _cmul(a: tuple[Any, Any], b: tuple[Any, Any]) -> tuple[Any, Any]:
    return a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0]


def _abs2(a: tuple[Any, Any]) -> Any:
    return a[0] ** 2 + a[1] ** 2


def _tustin(num: list[Any], den: list[Any], h: Any) -> tuple[list[Any], list[Any]]:
    """Substitute s = (2/h)(z-1)/(z+1) symbolically."""
    M = max(len(num), len(den)) - 1

    def sub(p: list[Any]) -> list[Any]:
        deg = len(p) - 1
        out: list[Any] = [0] * (M + 1)
        for i, c in enumerate(p):
            k = deg - i
            poly = np.array([1.0])
            for _ in range(k):
                poly = np.polymul(poly, [1.0, -1.0])
            for _ in range(M - k):
                poly = np.polymul(poly, [1.0, 1.0])
            scale = (2 / h) ** k if k else 1
            poly = np.concatenate([np.zeros(M + 1 - poly.size), poly])
            for j in range(M + 1):
                if poly[j] != 0:
                    out[j] = out[j] + c * scale * float(poly[j])
        return out

    return sub(num), sub(den)


def _canonical(num: list[Any], den: list[Any]) -> tuple[list[Any], list[Any], Any]:
    """Controllable canonical form pieces of num/den (den not necessarily monic).

    Returns (a, beta, d): den = z^m + a1 z^{m-1} + ..., u = beta . xc + d e.
    """
    m = len(den) - 1
    num = [0] * (len(den) - len(num)) + list(num)
    a0 = den[0]
    a = [den[i] / a0 for i in range(1, m + 1)]
    b = [num[i] / a0 for i in range(m + 1)]
    beta = [b[i + 1] - b[0] * a[i] for i in range(m)]
    return a, beta, b[0]


def integral_gain(num: list[Any], den: list[Any], dt: Any, continuous: bool) -> Any:
    """``lim s C(s)`` (continuous) or ``lim (z - 1) C(z) / dt`` (discrete), symbolically: the denominator's
    root at DC divided out by synthetic division (the structure's integrator is exactly there)."""
    x = 0.0 if continuous else 1.0
    q = [den[0]]
    for c in den[1:-1]:
        q.append(c + q[-1] * x)

    def at(p: list[Any]) -> Any:
        v = 0
        for c in p:
            v = v * x + c
        return v

    ki = at(num) / at(q)
    return ki if continuous else ki / dt


class _Constraints:
    """g(x, p) with its bounds, appended in order."""

    def __init__(self) -> None:
        self.g: list[Any] = []
        self.lbg: list[float] = []
        self.ubg: list[float] = []

    def add(self, expr: Any, lo: float, hi: float) -> None:
        self.g.append(expr)
        n = expr.shape[0] if hasattr(expr, "shape") else 1
        self.lbg.extend([lo] * n)
        self.ubg.extend([hi] * n)


def _controller(key: ProblemKey, st: Structure, space: Space, v: Any, P: dict[str, Any]
                ) -> tuple[list, list, list | None]:
    """The controller's coefficients from the same formulas as the verifier (symbols in, symbols out): the
    feedback ``num, den`` and, for a 2-DOF structure, the reference path's numerator over ``den`` (else None)."""
    nv = len(st.params)
    x_par = space.to_params([v[i] for i in range(nv)], exp=cs.exp, sinh=cs.sinh, units=P["units"],
                            linear_gains=True)
    dt = None if key.continuous else P["dt"]
    num, den = st.coeffs(x_par, dt, cs.exp)
    num_r = st.ref_coeffs(x_par, dt, cs.exp)[0] if st.two_dof else None
    return num, den, num_r


def _open_loop_at(w: Any, key: ProblemKey, i: int, cnum: list, cden: list, P: dict[str, Any]
                  ) -> tuple[Any, Any, Any, Any]:
    """``L(jw)`` of plant ``i`` as Re(N conj D), Im(N conj D), |N|^2, |D|^2 (L = N/D); the plant from its
    zeros, poles and gain (factored: no expanded polynomial)."""
    dly, dt = key.delays[i], P["dt"]
    cn = _cplx_poly(cnum, w, dt, key.continuous)
    cd = _cplx_poly(cden, w, dt, key.continuous)
    x = (0, w) if key.continuous else (cs.cos(w * dt), cs.sin(w * dt))
    gn: tuple[Any, Any] = (P[f"k{i}"], 0)
    for j in range(key.zeros[i]):
        gn = _cmul(gn, (x[0] - P[f"zr{i}"][j], x[1] - P[f"zi{i}"][j]))
    gd: tuple[Any, Any] = (1, 0)
    for j in range(key.poles[i]):
        gd = _cmul(gd, (x[0] - P[f"pr{i}"][j], x[1] - P[f"pi{i}"][j]))
    Nn = _cmul(cn, gn)
    if key.continuous:
        tau = P[f"tau{i}"]
        Nn = _cmul(Nn, (cs.cos(w * tau), -cs.sin(w * tau)))
    elif dly:
        Nn = _cmul(Nn, (cs.cos(dly * w * dt), -cs.sin(dly * w * dt)))
    Dd = _cmul(cd, gd)
    re = Nn[0] * Dd[0] + Nn[1] * Dd[1]
    im = Nn[1] * Dd[0] - Nn[0] * Dd[1]
    return re, im, _abs2(Nn), _abs2(Dd)


def _margin_constraints(c: _Constraints, key: ProblemKey, i: int, cnum: list, cden: list, P: dict[str, Any],
                        wc: Any | None, wp: Any | None) -> None:
    """Phase margin at the gain crossover ``wc``; gain margin at the phase crossover ``wp`` and (sampled-data)
    at the Nyquist frequency."""
    if wc is not None:
        re, im, nn2, dd2 = _open_loop_at(wc, key, i, cnum, cden, P)
        c.add((nn2 - dd2) / (nn2 + dd2), 0.0, 0.0)  # |L(j wc)| = 1
        c.add((re + P[f"cospm{i}"] * dd2) / (nn2 + dd2), 0.0, cs.inf)  # Re L >= -cos(PM)
    if key.gm:
        if wp is not None:
            re, im, nn2, dd2 = _open_loop_at(wp, key, i, cnum, cden, P)
            c.add(im / (nn2 + dd2), 0.0, 0.0)
            c.add((re + P[f"g{i}"] * dd2) / (nn2 + dd2), 0.0, cs.inf)
        if not key.continuous:
            re, im, nn2, dd2 = _open_loop_at(math.pi / P["dt"], key, i, cnum, cden, P)
            c.add((re + P[f"g{i}"] * dd2) / (nn2 + dd2 + 1e-300), 0.0, cs.inf)


def _grid_constraints(c: _Constraints, key: ProblemKey, i: int, cnum: list, cden: list, P: dict[str, Any],
                      level: Any = None) -> None:
    """Ms, Mt, Mks and disk-margin limits on the frequency grid: with L = Cn G / Cd (G a parameter there),
    each is a ratio of squared magnitudes, multiplied through by the (positive) denominators."""
    for j in range(key.n_grid):
        w = P["wgrid"][j]
        cn = _cplx_poly(cnum, w, P["dt"], key.continuous)
        cd = _cplx_poly(cden, w, P["dt"], key.continuous)
        cng = _cmul(cn, (P[f"Gre{i}"][j], P[f"Gim{i}"][j]))  # Cn G
        one_plus = _abs2((cd[0] + cng[0], cd[1] + cng[1]))  # |Cd + Cn G|^2 = |Cd|^2 |1 + L|^2
        scale = _abs2(cd) + _abs2(cng) + 1e-300
        if key.ms:
            c.add((one_plus - P["msinv"] ** 2 * _abs2(cd)) / scale, 0.0, cs.inf)
        if key.mt:
            c.add((P["mt"] ** 2 * one_plus - _abs2(cng)) / scale, 0.0, cs.inf)
        if key.mks:
            c.add((P["mks"] ** 2 * one_plus - _abs2(cn)) / (scale + _abs2(cn)), 0.0, cs.inf)
        if key.dm:
            one_minus = _abs2((cd[0] - cng[0], cd[1] - cng[1]))
            c.add((4 * one_plus - P["alpha"] ** 2 * one_minus) / scale, 0.0, cs.inf)
        if key.drb:  # |S|^2 = |Cd|^2 / |Cd + Cn G|^2 <= 1/2 where the mask is 1; above the limit the row is 1 >= 0
            mk = P["drbmask"][j]
            c.add(mk * (one_plus - 2.0 * _abs2(cd)) / scale + (1 - mk), 0.0, cs.inf)
        # the objectives mks and disk_margin: the level (the decision variable "slack") bounds the peak
        if key.objective == "mks":
            c.add((level ** 2 * one_plus - _abs2(cn)) / (scale + _abs2(cn)), 0.0, cs.inf)
        elif key.objective == "disk_margin":
            one_minus = _abs2((cd[0] - cng[0], cd[1] - cng[1]))
            c.add((4 * one_plus - level ** 2 * one_minus) / scale, 0.0, cs.inf)


def _step_function(key: ProblemKey, i: int, m: int, r: float, w: float, two_dof: bool, N: int) -> Any:
    """One sample of the closed loop of plant ``i`` as a CasADi Function ``(s, Phi, Gam, C, D, Cf, Df, c) -> (s+,
    [y_1..y_N, u])``: ``s`` the plant state, the controller state (``m``) and the delay line, ``c`` the controller's
    canonical coefficients (``a, beta, d0`` and, 2-DOF, ``beta_r, d_r``); ``N`` points a sample. :func:`_responses`
    repeats it K times with ``mapaccum`` and calls the result on the problem's symbols, which inlines the K samples in
    C++: the same expression graph as a Python loop over the samples, built about 50 times faster."""
    n, dly = key.orders[i], key.delays[i]
    s = cs.SX.sym("s", n + m + dly)
    Phi, Gam, Cx = cs.SX.sym("Phi", n, n), cs.SX.sym("Gam", n), cs.SX.sym("C", n)
    Dp, Cf, Df = cs.SX.sym("D"), cs.SX.sym("Cf", N, n), cs.SX.sym("Df", N)
    nc = 2 * m + 1 + (m + 1 if two_dof else 0)
    c = cs.SX.sym("c", nc)
    a, beta, d0 = [c[j] for j in range(m)], [c[m + j] for j in range(m)], c[2 * m]
    x, xc, buf = s[:n], [s[n + j] for j in range(m)], [s[n + m + j] for j in range(dly)]
    cx = cs.dot(Cx, x) if n else cs.SX(0)
    if not two_dof:
        bxc = sum((beta[j] * xc[j] for j in range(m)), cs.SX(0))
        if dly == 0:
            # u = (beta xc + d0 (r - C x - D w)) / (1 + d0 D); plant input u + w
            u = (bxc + d0 * (r - cx - Dp * w)) / (1 + d0 * Dp)
            ua = u + w
            e = r - (cx + Dp * ua)
        else:
            ua = buf[0]
            e = r - (cx + Dp * ua)
            u = bxc + d0 * e
            buf = buf[1:] + [u + w]
        xc_new = ([-sum((a[j] * xc[j] for j in range(m)), cs.SX(0)) + e] + xc[:m - 1]) if m else []
    else:
        # u = C_r r - C y on the observable canonical form of the common denominator:
        # xc+ = A xc - beta y + beta_r r, u = xc[0] - d0 y + d_r r
        beta_r, d_r = [c[2 * m + 1 + j] for j in range(m)], c[3 * m + 1]
        x0 = xc[0] if m else cs.SX(0)
        if dly == 0:
            u = (x0 + d_r * r - d0 * (cx + Dp * w)) / (1 + d0 * Dp)
            ua = u + w
            y = cx + Dp * ua
        else:
            ua = buf[0]
            y = cx + Dp * ua
            u = x0 + d_r * r - d0 * y
            buf = buf[1:] + [u + w]
        xc_new = [-a[j] * xc[0] + (xc[j + 1] if j + 1 < m else 0) - beta[j] * y + beta_r[j] * r for j in range(m)]
    out = cs.mtimes(Cf, x) + Df * ua if n else Df * ua
    x_new = cs.mtimes(Phi, x) + Gam * ua if n else cs.SX(0, 1)
    s_new = cs.vertcat(x_new, *xc_new, *buf)
    return cs.Function(f"sample{i}_{N}", [s, Phi, Gam, Cx, Dp, Cf, Df, c], [s_new, cs.vertcat(out, u)])


def _responses(key: ProblemKey, i: int, ctrl: tuple, P: dict[str, Any], r: float, w: float) -> tuple[Any, list]:
    """The closed loop's output at N points per sample (lifted model; a head grid: ``tail_N`` of them, every
    ``N / tail_N``-th row of the lifted model, after the first ``head`` samples) and the control sequence, for a unit
    step of the reference ``r`` and of the load ``w`` at the plant input (before its delay). ``ctrl``: the
    controller's canonical form ``(a, beta, d0)``, or for a 2-DOF controller ``u = C_r r - C y`` also the reference
    path's ``(beta_r, d_r)`` over the same denominator."""
    two_dof = len(ctrl) > 3
    a = ctrl[0]
    m = len(a)
    coeffs = cs.vertcat(*a, *ctrl[1], ctrl[2], *((*ctrl[3], ctrl[4]) if two_dof else ()))
    n = key.orders[i]
    s0 = cs.SX.zeros(n + m + key.delays[i])
    plant = [P[f"{b}{i}"] for b in ("Phi", "Gam", "C", "D", "Cf", "Df")]
    parts = [(key.N, key.head or key.K, plant)]
    if key.head:
        every = key.N // key.tail_N
        parts.append((key.tail_N, key.K - key.head, plant[:4] + [plant[4][::every, :], plant[5][::every]]))
    ys, us = [], []
    for N, K, data in parts:
        F = _step_function(key, i, m, r, w, two_dof, N).mapaccum(f"samples{i}_{N}", K, [0], [0])
        states, out = F(s0, *data, coeffs)
        s0 = states[:, -1]
        ys.append(cs.vec(out[:N, :]))
        us.append(out[N, :].T)
    return cs.vertcat(*ys), [cs.vertcat(*us)]


def _envelope(c: _Constraints, key: ProblemKey, y: Any, slack: Any, P: dict[str, Any]) -> None:
    """Upper: y_i - 1 <= overshoot before Ts, <= band - slack from Ts on (the band is the tighter one);
    lower: 1 - y_i <= band - slack from Ts on. ``mask`` is 1 from Ts on. Other objectives: the overshoot
    only (their mask is 0). ``key.interp``: Ts between two grid points, the first of the envelope's rows is the
    output linearly interpolated at Ts (as the verifier interpolates its settling time), so that Ts is not
    quantised to the grid (``theta``: the fraction of the step from the grid point before Ts, 0 elsewhere)."""
    mask = P["mask"]
    if key.interp:  # row i holds y_i + theta_i (y_i+1 - y_i): the grid point before Ts moved to Ts (theta 0 elsewhere)
        y = y + P["theta"] * (cs.vertcat(y[1:], y[-1]) - y)
    c.add(y - 1 - (1 - mask) * P["os"] - mask * (P["band"] - slack), -cs.inf, 0.0)
    if key.objective == "settling_time" or key.settling_max:
        # before Ts (mask 0) the row is -1 <= 0, never active: a row 0 <= 0 there would be an active constraint
        # with a zero gradient, which makes the QP's active set degenerate (SQP: Non_Regular_Sensitivities)
        c.add(mask * (1 - y + slack - P["band"]) - (1 - mask), -cs.inf, 0.0)


def sqp_options() -> dict[str, Any]:
    """The SQP solver's options (``nlpsol(..., "sqpmethod", nlp, sqp_options())``)."""
    # min_step_size: CasADi's default (1e-10 in the inf-norm) stops well-progressing solves whose steps in
    # a coordinate are small (a pid at dt near its optimum: "Search_Direction_Becomes_Too_Small")
    # tol_du: the stationarity a solve stops at (CasADi's default 1e-6); the bisection asks only the slack's
    # sign and the batch judges every candidate, and the limited-memory Hessian's last digits cost a fifth of the
    # iterations (on every fourth suite case: 21 % fewer, 3-7 % less CPU a tune). Where a filter time constant is
    # nearly free the solve ends elsewhere and the search follows: with 1e-6, PI on 1/(20s+1)^2 at dt 0.1 ends at
    # 64.9 s against 53.6 s (tests/tuner/test_effort_limits.py), with 1e-4 bench/quality.py's nmp-19 (default)
    # 5.5 % and delay-22 (fast) 14 % worse; neither is the better tolerance everywhere
    # no_nlp_grad (with the calc_* it needs off): nlpsol makes no "nlp_grad" Function, the Lagrangian's gradient in
    # x and p evaluated once after each solve to recompute f, g and the multipliers lam_x, lam_p at the answer. Its
    # reverse sweep is the largest of the solver's derivative graphs (measured before f39d2ed made default's polish
    # sharp: the roll loop's K = 48, N = 32 shape: 59 200 instructions, against 45 700 for the Jacobian the iterations
    # use; its sharp polish shape now 66 869 against 53 730), and deriving it was half of each nlpsol (a cold process
    # making its solvers of stored graphs, tuner/optimize/nlp/graphcache.py: the roll loop's four shapes 0.10 s ->
    # 0.05 s; nor is its C generated for a compiled entry). The SQP answers only x and f: x is the
    # iterate either way, and f the one the last iteration evaluated at it, the same expression nodes evaluated in
    # the same order (bitwise the same, every solve's x, f, g and every tune's gains: tests/tuner/test_cold_cli.py);
    # the multipliers are used only by the ipopt solver's warm starts
    return {"qpsol": "daqp", "hessian_approximation": "limited-memory", "max_iter": MAX_SQP_ITER,
            "tol_du": SQP_TOL_DU, "min_step_size": 1e-16, "print_time": False, "print_header": False,
            "print_iteration": False, "print_status": False, "error_on_fail": False, "show_eval_warnings": False,
            "no_nlp_grad": True, "calc_f": False, "calc_g": False, "calc_lam_x": False, "calc_lam_p": False,
            "qpsol_options": {"error_on_fail": False}}


def _solver(key: ProblemKey, nlp: Any) -> Any:
    """The NLP's solver: ``nlp`` the Function ``(x, p) -> (f, g)`` (built, or deserialized by graphcache), or the
    shared library of its compiled code (codecache)."""
    if key.solver == "sqp":
        return cs.nlpsol(f"tune_{key.structure.partition('(')[0]}", "sqpmethod", nlp, sqp_options())
    opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.max_iter": 150,
            "ipopt.tol": 1e-6, "ipopt.acceptable_tol": 1e-4, "ipopt.acceptable_iter": 5,
            "ipopt.mu_strategy": "adaptive", "ipopt.warm_start_init_point": "yes",
            "ipopt.warm_start_bound_push": 1e-6, "ipopt.warm_start_mult_bound_push": 1e-6,
            "ipopt.max_wall_time": 30.0, "show_eval_warnings": False}  # a safety net only: budgets between solves
    return cs.nlpsol(f"tune_{key.structure.partition('(')[0]}", "ipopt", nlp, opts)


def _objective(key: ProblemKey, terms: list[Any], cnum: list, cden: list, P: dict[str, Any], X: dict[str, Any]) -> Any:
    if key.objective == "settling_time":
        return -X["slack"]
    if key.objective == "ie":
        return -integral_gain(cnum, cden, P["dt"], key.continuous) / P["kiu"]
    if key.objective == "mks":  # the level bounding |C S| on the grid (see _grid_constraints), relative to the unit
        return X["slack"] / P["kscale"]
    if key.objective == "disk_margin":
        return -X["slack"]
    return cs.mmax(cs.vertcat(*terms)) if len(terms) > 1 else terms[0]


def _build(key: ProblemKey, st: Structure, space: Space) -> Problem:
    BUILDS["count"] += 1
    nv = len(st.params)
    play, xlay = parameter_layout(key, nv), variable_layout(key, nv)
    p = cs.SX.sym("p", play.size)
    xvar = cs.SX.sym("x", xlay.size)
    P, X = play.unpack(p), xlay.unpack(xvar)
    cnum, cden, cnum_r = _controller(key, st, space, X["v"], P)
    # the controller in the simulation: at dt, or (continuous loops) Tustin at the fine step h
    snum, sden = _tustin(cnum, cden, P["h"]) if key.continuous else (cnum, cden)
    ctrl = _canonical(snum, sden)
    if cnum_r is not None:  # 2-DOF: the reference path over the same (Tustin) denominator
        snum_r = _tustin(cnum_r, cden, P["h"])[0] if key.continuous else cnum_r
        _, beta_r, d_r = _canonical(snum_r, sden)
        ctrl = ctrl + (beta_r, d_r)
    c = _Constraints()
    if key.ki:  # sign(plant) Ki / ki_min >= 1: integral action demanded, of the sign a stable loop has (linear: a
        # start with Ki near 0 has a gradient to follow)
        c.add(P["kisgn"] * integral_gain(cnum, cden, P["dt"], key.continuous) / P["kimin"] - 1.0, 0.0, cs.inf)
    if key.filter_n:  # (N Kp Tf)^2 >= Kd^2, scaled to O(1)
        xp = space.to_params([X["v"][i] for i in range(nv)], exp=cs.exp, sinh=cs.sinh, units=P["units"],
                             linear_gains=True)
        kp, kd, tf = (xp[st.params.index(n)] for n in ("Kp", "Kd", "Tf"))
        lhs, rhs = (P["nmax"] * kp * tf) ** 2, kd ** 2
        c.add((lhs - rhs) / (lhs + rhs + 1e-300), 0.0, cs.inf)
    terms = []
    outputs = []
    ipc = 0
    for i in range(len(key.orders)):
        wp = None
        if key.gm and key.phase_cross[i]:
            wp, ipc = X["wp"][ipc], ipc + 1
        _margin_constraints(c, key, i, cnum, cden, P, X["wc"][i] if key.pm else None, wp)
        if key.grid:
            _grid_constraints(c, key, i, cnum, cden, P, X["slack"])
        y, us = _responses(key, i, ctrl, P, 1.0, 0.0)
        outputs.append(y)
        # a settling limit with another objective: the band kept 3 % inside (optima ride its edge)
        _envelope(c, key, y + P[f"yoff{i}"] if key.settling_max else y,
                  X["slack"] if key.objective == "settling_time" else 0.03 * P["band"], P)
        if key.control_peak:
            c.add(cs.vertcat(*us) / P["cpk"], -1.0, 1.0)
        if key.objective == "itae":
            terms.append(cs.dot(P["tw"], cs.sqrt((1 - y) ** 2 + P["eps"] ** 2)))
        elif key.objective == "iae":
            yl, _ = _responses(key, i, ctrl, P, 0.0, 1.0)
            terms.append(cs.dot(P["tw"], cs.sqrt(yl ** 2 + P["eps"] ** 2)))
    f = _objective(key, terms, cnum, cden, P, X)
    # (the Function nlpsol would make of the expressions {x, p, f, g}, made here: graphcache stores it)
    nlp = cs.Function("nlp", [xvar, p], [f, cs.vertcat(*c.g)], ["x", "p"], ["f", "g"])
    return Problem(key=key, solver=_solver(key, nlp), n_v=nv, lbg=np.array(c.lbg, dtype=float),
                   ubg=np.array(c.ubg, dtype=float), params=play, variables=xlay,
                   step=cs.Function("step", [xvar, p], [cs.vertcat(*outputs)]), nlp=nlp)


def _load_graph(key: ProblemKey, space: Space) -> Problem | None:
    """The problem of ``key`` made of its stored graph (:mod:`~tuner.optimize.nlp.graphcache`), or None."""
    parts = graphcache.load(key, space)
    if parts is None:
        return None
    nlp, step, lbg, ubg, nv = parts
    try:
        solver = _solver(key, nlp)
    except Exception:  # (a stored graph CasADi will not make a solver of: built instead, as if it were not there)
        return None
    BUILDS["count"] += 1  # (a solver made: its plugins loaded, as a build's)
    return Problem(key=key, solver=solver, n_v=nv, lbg=lbg, ubg=ubg, params=parameter_layout(key, nv),
                   variables=variable_layout(key, nv), step=step, nlp=nlp)


# what a build costs, estimated before it starts, from its size alone (the same estimate on every machine and in
# every process, so that what a tune decides does not depend on what ran before it): CasADi takes about 4.4 us
# per expression node on this project's 2-core machines; the node count is about K N (80 + 1.6 (n + n_c + 2)^2)
# per plant (n plant states, n_c controller parameters; the constant: a step's own bookkeeping, which dominates at
# low order). The samples are built by mapaccum in C++ (:func:`_responses`): what remains is mostly CasADi's
# derivatives, measured at 0.4-1 times this model for the large builds where the estimate decides anything (K N >=
# 1024: a K = 4096 build of an order-2 loop in 1.4 s against 3.3 s estimated) and up to 3 times it for small ones
# (a fixed cost, a few hundredths of a second). The estimate is asked for as it is.
BUILD_S_PER_NODE = 4.4e-6


def _estimated_nodes(key: ProblemKey, n_params: int) -> float:
    # the points between samples are linear maps of the sample's state: they cost an eighth of a sample each
    # (measured: K = 48, N = 32 built in 0.16 s where K * N full samples estimated 2.1 s)
    head = key.head or key.K
    samples = head * (1.0 + (key.N - 1) / 8.0) + (key.K - head) * (1.0 + (key.tail_N - 1) / 8.0)
    return sum(samples * (80.0 + 1.6 * (n + n_params + 2) ** 2) for n in key.orders)


def estimated_build_s(key: ProblemKey, n_params: int) -> float:
    """What building the problem for ``key`` is expected to cost, s (from its size alone: the same on every machine
    and in every process)."""
    return BUILD_S_PER_NODE * _estimated_nodes(key, n_params)


def cached_count() -> int:
    """How many built problems the build cache holds."""
    return len(_CACHE)


def is_built(key: ProblemKey) -> bool:
    """The problem for ``key`` is in the build cache."""
    return key in _CACHE


def get_problem(key: ProblemKey, st: Structure, space: Space) -> Problem:
    """The cached problem for ``key`` (built on first use only; plant data are parameters)."""
    with _LOCK:
        if _PINNED["depth"]:
            _PINNED["keys"].add(key)
        hit = _CACHE.get(key)
        if hit is not None:
            _CACHE.move_to_end(key)
    if hit is not None:
        if not codecache.enabled() or hit[0].compiled:
            return hit[0]
        # built interpreted here: its compiled code may have landed in the cache since (bitwise the same answers)
        prob = codecache.load(key, st, space, _assembler(key))
        if prob is None:
            return hit[0]
        with _LOCK:
            _CACHE[key] = (prob, hit[1])
        return prob
    with timed_build():
        prob = codecache.load(key, st, space, _assembler(key)) if codecache.enabled() else None
        if prob is None:
            graphs = graphcache.enabled()
            # built by an earlier process: its graph, bitwise the same problem
            prob = _load_graph(key, space) if graphs else None
            if prob is None:
                prob = _build(key, st, space)
                if graphs:
                    graphcache.save(key, space, prob.nlp, prob.step, prob.lbg, prob.ubg, prob.n_v)
            codecache.schedule(key, st, space)  # compiled in the background, for the next use (any process)
    with _LOCK:
        _CACHE[key] = (prob, BYTES_PER_NODE * _estimated_nodes(key, len(st.params)))
        _trim()
    return prob


def _assembler(key: ProblemKey) -> Any:
    """The problem of a compiled cache entry's parts (:func:`tuner.optimize.nlp.codecache.load`)."""
    def assemble(nlp_so: str, step: Any, lbg: np.ndarray, ubg: np.ndarray, nv: int) -> Problem:
        return Problem(key=key, solver=_solver(key, nlp_so), n_v=nv, lbg=lbg, ubg=ubg,
                       params=parameter_layout(key, nv), variables=variable_layout(key, nv), step=step, compiled=True)
    return assemble


def _trim() -> None:
    """Drop the least recently used problems beyond ``CACHE_MB``; the running tune's and the newest stay."""
    total = sum(b for _, b in _CACHE.values())
    for k in list(_CACHE)[:-1]:
        if total <= CACHE_MB * 2**20:
            break
        if k not in _PINNED["keys"]:
            total -= _CACHE.pop(k, (None, 0.0))[1]


@contextmanager
def working_set() -> Iterator[None]:
    """A tune's scope (re-entrant: a tune's diagnosis tunes again inside it): the problems used in it are not
    dropped from the build cache before it ends. Tunes running in threads of one process share the scope: what
    they used stays until none of them runs."""
    with _LOCK:
        _PINNED["depth"] += 1
    try:
        yield
    finally:
        with _LOCK:
            _PINNED["depth"] -= 1
            if not _PINNED["depth"]:
                _PINNED["keys"] = set()
                _trim()


if __name__ == "__main__":  # the compiled-code cache's background build (codecache.schedule)
    import sys
    from pathlib import Path

    if len(sys.argv) == 3 and sys.argv[1] == "--build":
        codecache.run_job(Path(sys.argv[2]), _build)
