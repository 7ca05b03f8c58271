"""The tuning NLP in CasADi, built once per problem *structure* and re-used.

Structure key = (controller structure, continuous or discrete, plant order and
delay per plant, horizon K, points per sample N, which crossovers exist, the
optional constraints). Plant data, dt, the spec's numbers and the time grid
enter as parameters, so re-solving from another start, or for another plant of
the same order, does not rebuild anything (``BUILDS`` counts real builds).

Decision variables: the structure's coordinates ``v`` (see :mod:`tuner.optimize.space`;
gains linear in their plant-based unit, frequencies logarithmic), the band slack, and per plant the gain-crossover
frequency ``wc`` (and the phase-crossover frequency ``wp`` where the loop has
one below Nyquist).

Constraints, per plant:

* ``|L(j wc)| = 1`` and ``Re L(j wc) >= -cos(PM_min)``  (phase margin at wc);
* ``Im L(j wp) = 0`` and ``Re L(j wp) >= -10^(-GM/20)``  (gain margin at wp), and
  for sampled-data loops the same at the Nyquist frequency, where L is real;
* step response between samples (lifted ZOH model, exact at N points per
  sample): ``y <= 1 + overshoot``, and the settling envelope
  ``|y_i - 1| <= b - slack`` for every ``t_i >= Ts``, the set of such points
  given as a 0/1 parameter ``mask`` (so moving ``Ts`` never rebuilds);
* optional ``|u_k| <= control_peak_max`` and ``|1 + L(j w)| >= 1/Ms_max`` on a grid.

Objective: for a given ``Ts``, maximise the slack (the caller bisects on
``Ts``: the smallest ``Ts`` with slack >= 0 is the minimum settling time, exact
on the grid); for other objectives a smooth ITAE surrogate. The verifier
re-judges every solution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import casadi as cs
import numpy as np

from ...controllers import Structure
from ..space import Space

__all__ = ["ProblemKey", "Problem", "get_problem", "BUILDS", "MS_GRID"]

BUILDS = {"count": 0}
MS_GRID = 60
_CACHE: dict["ProblemKey", "Problem"] = {}


@dataclass(frozen=True)
class ProblemKey:
    structure: str
    continuous: bool
    orders: tuple[int, ...]  # plant state dimension per plant
    delays: tuple[int, ...]  # delay in samples per plant
    K: int
    N: int
    phase_cross: tuple[bool, ...]  # per plant: a phase crossover below Nyquist
    control_peak: bool
    ms: bool
    objective: str
    solver: str = "ipopt"  # "ipopt" (interior point) or "sqp" (CasADi sqpmethod with qpOASES)


@dataclass
class Problem:
    key: ProblemKey
    solver: Any  # casadi nlpsol Function
    n_v: int
    lbg: np.ndarray
    ubg: np.ndarray
    x_layout: dict[str, slice]


def _cplx_poly(coeffs: list[Any], w: Any, dt: Any, continuous: bool) -> tuple[Any, Any]:
    """Real and imaginary parts of a polynomial (highest power first) at s=jw or z=exp(jw dt)."""
    re, im = 0, 0
    deg = len(coeffs) - 1
    for i, c in enumerate(coeffs):
        k = deg - i
        if continuous:
            # (j w)^k = w^k * j^k
            wk = w ** k if k else 1
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


def _unpack(p: Any, off: int, n: int, N: int) -> tuple[dict[str, Any], int]:
    def take(k: int) -> Any:
        nonlocal off
        s = p[off:off + k]
        off += k
        return s

    d: dict[str, Any] = {}
    d["Phi"] = cs.reshape(take(n * n), n, n).T  # row-major in the vector
    d["Gam"] = take(n)
    d["C"] = take(n)
    d["D"] = take(1)
    d["Cf"] = cs.reshape(take(N * n), n, N).T
    d["Df"] = take(N)
    d["num"] = take(n + 1)
    d["den"] = take(n + 1)
    return d, off


def _build(key: ProblemKey, st: Structure, space: Space) -> Problem:
    BUILDS["count"] += 1
    nv = len(st.params)
    npl = len(key.orders)
    n_pc = sum(key.phase_cross)
    v = cs.SX.sym("v", nv)
    slack = cs.SX.sym("slack")
    wc = cs.SX.sym("wc", npl)
    wp = cs.SX.sym("wp", n_pc)
    # parameters: global scalars then per-plant blocks
    glob_names = ["dt", "h", "band", "os", "cospm", "g", "cpk", "msinv"]
    G = cs.SX.sym("glob", len(glob_names))
    gp = {n: G[i] for i, n in enumerate(glob_names)}
    plant_sizes = [n * n + n + n + 1 + key.N * n + key.N + 2 * (n + 1) + 1 for n in key.orders]  # +1: delay s
    P = cs.SX.sym("plants", sum(plant_sizes))
    Wms = cs.SX.sym("wms", MS_GRID if key.ms else 0)
    units = cs.SX.sym("units", nv)  # the space's gain units: plant data, hence parameters
    mask = cs.SX.sym("mask", key.K * key.N)  # 1 where the settling band applies (t >= Ts)
    pvec = cs.vertcat(G, units, P, Wms, mask)

    # the controller, from the same coefficient formulas as the verifier
    x_par = space.to_params([v[i] for i in range(nv)], exp=cs.exp, sinh=cs.sinh, units=units, linear_gains=True)
    dt_ctrl = None if key.continuous else gp["dt"]
    cnum, cden = st.coeffs(x_par, dt_ctrl, cs.exp)
    if key.continuous:
        snum, sden = _tustin(cnum, cden, gp["h"])
    else:
        snum, sden = cnum, cden
    a, beta, d0 = _canonical(snum, sden)
    m = len(a)

    g_list: list[Any] = []
    lbg: list[float] = []
    ubg: list[float] = []

    def add(expr: Any, lo: float, hi: float) -> None:
        g_list.append(expr)
        n_ = expr.shape[0] if hasattr(expr, "shape") else 1
        lbg.extend([lo] * n_)
        ubg.extend([hi] * n_)

    obj_terms = []
    off = 0
    ipc = 0
    K, N = key.K, key.N
    for ip, (n, dly) in enumerate(zip(key.orders, key.delays)):
        pl, off2 = _unpack(P, off, n, N)
        tau = P[off2]
        off = off2 + 1
        # -- frequency domain ---------------------------------------------------------
        wnyq = math.pi  # scaled below by dt

        def L_at(w: Any) -> tuple[Any, Any, Any, Any]:
            cn = _cplx_poly(cnum, w, gp["dt"], key.continuous)
            cd = _cplx_poly(cden, w, gp["dt"], key.continuous)
            gn = _cplx_poly([pl["num"][i] for i in range(n + 1)], w, gp["dt"], key.continuous)
            gd = _cplx_poly([pl["den"][i] for i in range(n + 1)], w, gp["dt"], key.continuous)
            Nn = _cmul(cn, gn)
            if key.continuous:
                Nn = _cmul(Nn, (cs.cos(w * tau), -cs.sin(w * tau)))
            elif dly:
                Nn = _cmul(Nn, (cs.cos(dly * w * gp["dt"]), -cs.sin(dly * w * gp["dt"])))
            Dd = _cmul(cd, gd)
            # L = Nn / Dd ;  Nn * conj(Dd)
            re = Nn[0] * Dd[0] + Nn[1] * Dd[1]
            im = Nn[1] * Dd[0] - Nn[0] * Dd[1]
            nn2 = Nn[0] ** 2 + Nn[1] ** 2
            dd2 = Dd[0] ** 2 + Dd[1] ** 2
            return re, im, nn2, dd2

        re, im, nn2, dd2 = L_at(wc[ip])
        add((nn2 - dd2) / (nn2 + dd2), 0.0, 0.0)  # |L(j wc)| = 1
        add((re + gp["cospm"] * dd2) / (nn2 + dd2), 0.0, cs.inf)  # Re L >= -cos(PM)
        if key.phase_cross[ip]:
            re, im, nn2, dd2 = L_at(wp[ipc])
            ipc += 1
            add(im / (nn2 + dd2), 0.0, 0.0)
            add((re + gp["g"] * dd2) / (nn2 + dd2), 0.0, cs.inf)
        if not key.continuous:
            re, im, nn2, dd2 = L_at(wnyq / gp["dt"])
            add((re + gp["g"] * dd2) / (nn2 + dd2 + 1e-300), 0.0, cs.inf)
        if key.ms:
            for i in range(MS_GRID):
                re, im, nn2, dd2 = L_at(Wms[i])
                # |1 + L|^2 >= msinv^2  <=>  dd2 + 2 re + nn2 >= msinv^2 dd2
                add((dd2 + 2 * re + nn2 - gp["msinv"] ** 2 * dd2) / (nn2 + dd2), 0.0, cs.inf)
        # -- time domain: lifted closed loop --------------------------------------------
        x = cs.SX.zeros(n)
        xc = cs.SX.zeros(m)
        buf = [cs.SX(0)] * dly
        ys = []
        us = []
        Cx = pl["C"]
        Dp = pl["D"]
        for k in range(K):
            if dly == 0:
                u = (cs.dot(cs.vertcat(*beta), xc) + d0 * (1 - cs.dot(Cx, x))) / (1 + d0 * Dp) if m else \
                    d0 * (1 - cs.dot(Cx, x)) / (1 + d0 * Dp)
                ua = u
                e = 1 - (cs.dot(Cx, x) + Dp * ua)
            else:
                ua = buf[0]
                e = 1 - (cs.dot(Cx, x) + Dp * ua)
                u = (cs.dot(cs.vertcat(*beta), xc) if m else 0) + d0 * e
                buf = buf[1:] + [u]
            ys.append(cs.mtimes(pl["Cf"], x) + pl["Df"] * ua)
            us.append(u)
            x = cs.mtimes(pl["Phi"], x) + pl["Gam"] * ua
            if m:
                xc_new = [-sum(a[i] * xc[i] for i in range(m)) + e] + [xc[i] for i in range(m - 1)]
                xc = cs.vertcat(*xc_new)
        y = cs.vertcat(*ys)
        t = cs.DM(np.arange(K * N) / N) * gp["h"]
        # upper: y_i - 1 <= overshoot before Ts, <= band - slack from Ts on (the band is the tighter one);
        # lower: 1 - y_i <= band - slack from Ts on (vacuous before)
        add(y - 1 - (1 - mask) * gp["os"] - mask * (gp["band"] - slack), -cs.inf, 0.0)
        add(mask * (1 - y + slack - gp["band"]), -cs.inf, 0.0)
        if key.control_peak:
            uu = cs.vertcat(*us)
            add(uu / gp["cpk"], -1.0, 1.0)
        if key.objective != "settling_time":
            obj_terms.append(cs.sum1(t * cs.sqrt((y - 1) ** 2 + 1e-8)) * (gp["h"] / N))
    if key.objective == "settling_time":
        f = -slack
    else:
        f = cs.mmax(cs.vertcat(*obj_terms)) if len(obj_terms) > 1 else obj_terms[0]
    xvar = cs.vertcat(v, slack, wc, wp)
    g = cs.vertcat(*g_list)
    nlp = {"x": xvar, "p": pvec, "f": f, "g": g}
    opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.max_iter": 150,
            "ipopt.tol": 1e-6, "ipopt.acceptable_tol": 1e-4, "ipopt.acceptable_iter": 5,
            "ipopt.mu_strategy": "adaptive", "ipopt.warm_start_init_point": "yes",
            "ipopt.warm_start_bound_push": 1e-6, "ipopt.warm_start_mult_bound_push": 1e-6,
            "ipopt.max_wall_time": 30.0}  # a safety net only: budgets are enforced between solves
    if key.solver == "sqp":
        opts = {"qpsol": "qpoases", "print_time": False, "print_header": False, "print_iteration": False,
                "print_status": False, "max_iter": 60, "error_on_fail": False,
                "qpsol_options": {"printLevel": "none", "error_on_fail": False}}
        solver = cs.nlpsol(f"tune_{key.structure}", "sqpmethod", nlp, opts)
    else:
        solver = cs.nlpsol(f"tune_{key.structure}", "ipopt", nlp, opts)
    layout = {"v": slice(0, nv), "slack": slice(nv, nv + 1), "wc": slice(nv + 1, nv + 1 + npl),
              "wp": slice(nv + 1 + npl, nv + 1 + npl + n_pc)}
    return Problem(key=key, solver=solver, n_v=nv,
                   lbg=np.array(lbg, dtype=float), ubg=np.array(ubg, dtype=float), x_layout=layout)


def get_problem(key: ProblemKey, st: Structure, space: Space) -> Problem:
    """The cached problem for ``key`` (built on first use only; plant data are parameters)."""
    prob = _CACHE.get(key)
    if prob is None:
        prob = _build(key, st, space)
        _CACHE[key] = prob
    return prob
