"""Local refinement of one start with the cached CasADi/IPOPT problem.

Numbers enter the symbolic world here (parameter vector, initial point, bounds)
and leave it here (the solution coordinates). What the NLP says about margins
or settling is not reported anywhere: the caller re-verifies the solution.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ...controllers import ControllerTF
from ...loop import build_loop
from ..scoring import SEARCH_BAND_GUARD, Evaluator
from ..space import Space
from .plantdata import lift
from .transcribe import MS_GRID, ProblemKey, get_problem

__all__ = ["RefineResult", "refine", "POINTS_PER_SAMPLE"]

log = logging.getLogger(__name__)

POINTS_PER_SAMPLE = 4
WARM_START = True
CONTINUOUS_STEPS = 240
_MIN_SAMPLES, _MAX_SAMPLES = 15, 80


@dataclass
class RefineResult:
    candidates: list[np.ndarray] = field(default_factory=list)  # coordinates
    iterations: int = 0
    evaluations: int = 0
    success: bool = False
    status: str = ""


def _horizon(settle: float, dt: float | None, w0: float) -> float:
    unit = dt if dt else 1.0 / w0
    base = 3.0 * settle if math.isfinite(settle) and settle > 0 else 60 * unit
    if dt:
        return float(np.clip(base, _MIN_SAMPLES * dt, _MAX_SAMPLES * dt))
    return float(np.clip(base, 5.0 / w0, 500.0 / w0))


def refine(ev: Evaluator, space: Space, v0: np.ndarray, *, deadline: float | None = None,
           solver: str = "ipopt") -> RefineResult:
    """Refine coordinates ``v0`` on the exact local problem; returns candidate coordinates."""
    res = RefineResult()
    spec = ev.spec
    x0 = space.params(v0)
    try:
        start = ev.analyse(x0)
    except (ValueError, ArithmeticError) as e:
        res.status = f"start not analysable: {e}"
        return res
    settle = max((a.metrics.settling_time_s for a in start), default=math.inf)
    dt = ev.dt
    T = _horizon(settle, dt, space.w0)
    continuous = dt is None
    if continuous:
        h = T / CONTINUOUS_STEPS
        taus = [p.delay_s for p in ev.plants if p.delay_s]
        if taus:
            h = min(taus) / max(1, math.ceil(min(taus) / h))
        K, N = int(math.ceil(T / h)), 1
        step = h
    else:
        K, N = int(math.ceil(T / dt / 5.0) * 5), POINTS_PER_SAMPLE
        step = dt
    lifted, orders, delays, pcs, wcs, wps = [], [], [], [], [], []
    ctrl = ev.controller(x0)
    for p, a in zip(ev.plants, start):
        if continuous:
            lp_h = build_loop(p, ControllerTF(num=np.ones(1), den=np.ones(1), dt=h))
            lf = lift(lp_h, 1)
            n = lf.n
            num_c = np.concatenate([np.zeros(n + 1 - p.num.size), p.num])
            lf = type(lf)(lf.Phi, lf.Gam, lf.C, lf.D, lf.Cf, lf.Df, num_c, np.asarray(p.den, float), lf.delay_samples)
        else:
            lf = lift(build_loop(p, ctrl), N)
        mg = a.margins
        wnyq = math.pi / dt if dt else math.inf
        wc = mg.crossover_rad_s if math.isfinite(mg.crossover_rad_s) else space.w0
        has_pc = math.isfinite(mg.phase_crossover_rad_s) and 0 < mg.phase_crossover_rad_s < 0.98 * wnyq
        lifted.append(lf)
        orders.append(lf.n)
        delays.append(lf.delay_samples)
        pcs.append(has_pc)
        wcs.append(wc)
        if has_pc:
            wps.append(mg.phase_crossover_rad_s)
    key = ProblemKey(structure=space.structure.name, continuous=continuous, orders=tuple(orders),
                     delays=tuple(delays), K=K, N=N, phase_cross=tuple(pcs),
                     control_peak=spec.control_peak_max is not None, ms=spec.ms_max is not None,
                     objective=spec.objective, solver=solver)
    prob = get_problem(key, space.structure, space)
    # -- parameters -----------------------------------------------------------------------
    band = spec.settling_band_pct / 100.0 * SEARCH_BAND_GUARD
    os = min(spec.overshoot_max_pct / 100.0 * 0.99, 10.0)
    glob = [dt or h, step, band, os, math.cos(math.radians(spec.phase_margin_min_deg)),
            10 ** (-spec.gain_margin_min_db / 20.0), spec.control_peak_max or 1.0,
            1.0 / spec.ms_max if spec.ms_max else 0.0, *space.units]
    blocks = []
    for p, lf in zip(ev.plants, lifted):
        blocks.append(lf.vector())
        blocks.append([p.delay_s if continuous else 0.0])
    wmax = math.pi / dt * 0.999 if dt else 1e3 * space.w0
    wms = np.logspace(math.log10(space.w0 * 1e-2), math.log10(wmax), MS_GRID) if spec.ms_max else np.zeros(0)
    pbase = np.concatenate([np.asarray(glob, float)] + [np.asarray(b, float).ravel() for b in blocks] + [wms])
    tgrid = np.arange(K * N) / N * step
    # -- start and bounds ---------------------------------------------------------------------
    vlo, vhi = space.bounds(linear_gains=True)
    xs = np.concatenate([space.from_params(x0, linear_gains=True), [0.0], wcs, wps])
    lbx = np.concatenate([vlo, [-1.0], [1e-6 * space.w0] * len(wcs), [w / 3 for w in wps]])
    ubx = np.concatenate([vhi, [band], [wmax] * len(wcs), [min(3 * w, wmax) for w in wps]])
    xs = np.clip(xs, lbx, ubx)
    sl = prob.x_layout["slack"].start

    lam: dict[str, np.ndarray] = {}

    def solve(ts: float, x_init: np.ndarray) -> tuple[float, np.ndarray] | None:
        mask = (tgrid >= ts - 1e-12).astype(float)
        try:
            sol = prob.solver(x0=x_init, p=np.concatenate([pbase, mask]), lbx=lbx, ubx=ubx,
                              lbg=prob.lbg, ubg=prob.ubg, **lam)
        except RuntimeError as e:  # IPOPT failures surface as RuntimeError in CasADi
            res.status = f"ipopt error: {e}"
            return None
        stats = prob.solver.stats()
        res.iterations += int(stats.get("iter_count", 0))
        res.evaluations += int(stats.get("n_call_nlp_f", 0)) + int(stats.get("n_call_nlp_g", 0))
        res.success = res.success or bool(stats.get("success", False))
        res.status = str(stats.get("return_status", ""))
        x = np.asarray(sol["x"]).ravel()
        if not np.all(np.isfinite(x)):
            return None
        if WARM_START and solver == "ipopt":
            lam.update(lam_x0=np.asarray(sol["lam_x"]).ravel(), lam_g0=np.asarray(sol["lam_g"]).ravel())
        ok = stats.get("success", False) or res.status == "Solved_To_Acceptable_Level"
        return (float(x[sl]) if ok else -1.0), x

    def out_of_time() -> bool:
        return deadline is not None and time.perf_counter() > deadline

    def to_search(x: np.ndarray) -> np.ndarray:  # NLP coordinates -> the search's coordinates
        return space.from_params(space.params(x[prob.x_layout["v"]], linear_gains=True))

    def keep(x: np.ndarray) -> None:
        res.candidates.append(to_search(x))

    if out_of_time():
        res.status = "no time left"
        return res
    if spec.objective != "settling_time":
        r = solve(math.inf, xs)
        if r is not None:
            keep(r[1])
        return res
    # bisection on Ts: feasible (slack >= 0) at hi, infeasible at lo
    hi = settle if math.isfinite(settle) and settle < tgrid[-1] else 0.9 * tgrid[-1]
    r = solve(hi, xs)
    if r is None:
        return res
    keep(r[1])
    if r[0] < 0:
        return res
    best, lo = r[1], 0.3 * hi
    tol = step / 2  # half a sample (the verifier then judges between samples)
    while hi - lo > tol and not out_of_time():
        mid = 0.5 * (lo + hi)
        r = solve(mid, best)
        if r is not None and r[0] >= 0:
            hi, best = mid, r[1]
            keep(best)
            # the solution may settle earlier than asked: jump there (judged by the verifier)
            sc = ev.score(space.params(to_search(best)))
            if sc.feasible and spec.objective == "settling_time" and lo < sc.score < hi:
                hi = sc.score
        else:
            lo = mid
    return res
