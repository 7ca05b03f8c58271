"""Local refinement of one start with the cached CasADi/IPOPT problem.

Numbers enter the symbolic world here (parameter vector, initial point, bounds, all packed by
name through the problem's :class:`~tuner.optimize.nlp.layout.Layout`) and leave it here (the
solution coordinates). What the NLP says about margins or settling is not reported anywhere:
the caller re-verifies the solution.

Steps: :func:`_grid` (horizon and time grid from the start's settling time), :func:`_plant_data`
(lifted plant models and crossover estimates from the start's analysis), :func:`_values` (the
spec's numbers), :func:`_box` (start and bounds), then :class:`_Solves` runs the solves: one for
an objective other than the settling time, a bisection on the settling time otherwise.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...analysis.verify import Analysis
from ...controllers import ControllerTF
from ...loop import build_loop
from ..scoring import SEARCH_BAND_GUARD, Evaluator
from ..space import Space
from .plantdata import LiftedPlant, lift
from .transcribe import MS_GRID, Problem, ProblemKey, get_problem

__all__ = ["RefineResult", "refine", "POINTS_PER_SAMPLE"]

log = logging.getLogger(__name__)

POINTS_PER_SAMPLE = 4
CONTINUOUS_STEPS = 240
_MIN_SAMPLES, _MAX_SAMPLES = 15, 80


@dataclass
class RefineResult:
    candidates: list[np.ndarray] = field(default_factory=list)  # coordinates
    iterations: int = 0
    evaluations: int = 0
    success: bool = False
    status: str = ""


@dataclass(frozen=True)
class _Grid:
    """The NLP's time discretisation: K steps of ``step`` s, N points per step."""

    K: int
    N: int
    step: float  # dt, or the fine step h of a continuous loop
    h: float | None  # continuous loops: the simulation step (divides every delay)

    @property
    def t(self) -> np.ndarray:
        return np.arange(self.K * self.N) / self.N * self.step


def _horizon(settle: float, dt: float | None, w0: float) -> float:
    unit = dt if dt else 1.0 / w0
    base = 3.0 * settle if math.isfinite(settle) and settle > 0 else 60 * unit
    if dt:
        return float(np.clip(base, _MIN_SAMPLES * dt, _MAX_SAMPLES * dt))
    return float(np.clip(base, 5.0 / w0, 500.0 / w0))


def _grid(ev: Evaluator, settle: float, w0: float) -> _Grid:
    T = _horizon(settle, ev.dt, w0)
    if ev.dt is not None:
        return _Grid(K=int(math.ceil(T / ev.dt / 5.0) * 5), N=POINTS_PER_SAMPLE, step=ev.dt, h=None)
    h = T / CONTINUOUS_STEPS
    taus = [p.delay_s for p in ev.plants if p.delay_s]
    if taus:
        h = min(taus) / max(1, math.ceil(min(taus) / h))
    return _Grid(K=int(math.ceil(T / h)), N=1, step=h, h=h)


@dataclass
class _PlantData:
    lifted: list[LiftedPlant] = field(default_factory=list)
    wc: list[float] = field(default_factory=list)  # gain-crossover estimate per plant
    wp: list[float] = field(default_factory=list)  # phase-crossover estimates (plants that have one)
    has_pc: list[bool] = field(default_factory=list)


def _plant_data(ev: Evaluator, start: tuple[Analysis, ...], ctrl: ControllerTF, grid: _Grid, w0: float) -> _PlantData:
    """Lifted model of every plant, and the start's crossovers (from the verifier's analysis)."""
    out = _PlantData()
    wnyq = math.pi / ev.dt if ev.dt else math.inf
    for p, a in zip(ev.plants, start):
        if grid.h is not None:  # continuous loop: ZOH at the fine step, the plant's own zpk for L(jw)
            lf = lift(build_loop(p, ControllerTF(num=np.ones(1), den=np.ones(1), dt=grid.h)), 1)
            lf = lf.with_response_of(p.zpk)
        else:
            lf = lift(build_loop(p, ctrl), grid.N)
        mg = a.margins
        has_pc = math.isfinite(mg.phase_crossover_rad_s) and 0 < mg.phase_crossover_rad_s < 0.98 * wnyq
        out.lifted.append(lf)
        out.wc.append(mg.crossover_rad_s if math.isfinite(mg.crossover_rad_s) else w0)
        out.has_pc.append(has_pc)
        if has_pc:
            out.wp.append(mg.phase_crossover_rad_s)
    return out


def _wmax(ev: Evaluator, w0: float) -> float:
    return math.pi / ev.dt * 0.999 if ev.dt else 1e3 * w0


def _values(ev: Evaluator, space: Space, grid: _Grid, data: _PlantData) -> dict[str, Any]:
    """Every parameter block but the settling mask, by name."""
    spec = ev.spec
    values: dict[str, Any] = {
        "dt": ev.dt or grid.h, "h": grid.step, "band": spec.settling_band_pct / 100.0 * SEARCH_BAND_GUARD,
        "os": min(spec.overshoot_max_pct / 100.0 * 0.99, 10.0),
        "cospm": math.cos(math.radians(spec.phase_margin_min_deg)), "g": 10 ** (-spec.gain_margin_min_db / 20.0),
        "cpk": spec.control_peak_max or 1.0, "msinv": 1.0 / spec.ms_max if spec.ms_max else 0.0,
        "units": np.asarray(space.units, float)}
    for i, (p, lf) in enumerate(zip(ev.plants, data.lifted)):
        values.update(lf.blocks(i, delay_s=p.delay_s if grid.h is not None else 0.0))
    values["wms"] = (np.logspace(math.log10(space.w0 * 1e-2), math.log10(_wmax(ev, space.w0)), MS_GRID)
                     if spec.ms_max else np.zeros(0))
    return values


def _box(prob: Problem, space: Space, x0: np.ndarray, data: _PlantData, band: float, wmax: float
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start, lower and upper bounds of the decision vector."""
    vlo, vhi = space.bounds(linear_gains=True)
    lay = prob.variables
    xs = lay.pack({"v": space.from_params(x0, linear_gains=True), "slack": 0.0, "wc": data.wc, "wp": data.wp})
    lbx = lay.pack({"v": vlo, "slack": -1.0, "wc": [1e-6 * space.w0] * len(data.wc), "wp": [w / 3 for w in data.wp]})
    ubx = lay.pack({"v": vhi, "slack": band, "wc": [wmax] * len(data.wc),
                    "wp": [min(3 * w, wmax) for w in data.wp]})
    return np.clip(xs, lbx, ubx), lbx, ubx


class _Solves:
    """Solves of one problem from one start, accumulating the solver's statistics in ``res``."""

    def __init__(self, prob: Problem, values: dict[str, Any], grid: _Grid, lbx: np.ndarray, ubx: np.ndarray,
                 res: RefineResult, solver: str) -> None:
        self.prob, self.values, self.tgrid, self.lbx, self.ubx = prob, values, grid.t, lbx, ubx
        self.res, self.solver = res, solver
        self.lam: dict[str, np.ndarray] = {}
        self.slack = prob.variables.slice("slack").start

    def __call__(self, ts: float, x_init: np.ndarray) -> tuple[float, np.ndarray] | None:
        """Maximise the band slack with the settling envelope from ``ts`` on: (slack, x), slack < 0 if infeasible."""
        res, prob = self.res, self.prob
        p = prob.params.pack({**self.values, "mask": (self.tgrid >= ts - 1e-12).astype(float)})
        try:
            sol = prob.solver(x0=x_init, p=p, lbx=self.lbx, ubx=self.ubx, lbg=prob.lbg, ubg=prob.ubg, **self.lam)
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
        if self.solver == "ipopt":  # warm start the next bisection solve from this one's multipliers
            self.lam.update(lam_x0=np.asarray(sol["lam_x"]).ravel(), lam_g0=np.asarray(sol["lam_g"]).ravel())
        ok = stats.get("success", False) or res.status == "Solved_To_Acceptable_Level"
        return (float(x[self.slack]) if ok else -1.0), x


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
    grid = _grid(ev, settle, space.w0)
    if ev.dt is not None and any(build_loop(p, ev.controller(x0)).plant_ct is None for p in ev.plants):
        # a plant known only at the samples (e.g. a cascade's composite plant): constrain the samples
        grid = _Grid(K=grid.K, N=1, step=grid.step, h=None)
    data = _plant_data(ev, start, ev.controller(x0), grid, space.w0)
    key = ProblemKey(structure=space.structure.name, continuous=ev.dt is None,
                     orders=tuple(lf.n for lf in data.lifted), zeros=tuple(lf.zeros.size for lf in data.lifted),
                     poles=tuple(lf.poles.size for lf in data.lifted),
                     delays=tuple(lf.delay_samples for lf in data.lifted),
                     K=grid.K, N=grid.N, phase_cross=tuple(data.has_pc),
                     control_peak=spec.control_peak_max is not None, ms=spec.ms_max is not None,
                     objective=spec.objective, solver=solver)
    prob = get_problem(key, space.structure, space)
    values = _values(ev, space, grid, data)
    xs, lbx, ubx = _box(prob, space, x0, data, values["band"], _wmax(ev, space.w0))
    solve = _Solves(prob, values, grid, lbx, ubx, res, solver)

    def out_of_time() -> bool:
        return deadline is not None and time.perf_counter() > deadline

    def to_search(x: np.ndarray) -> np.ndarray:  # NLP coordinates -> the search's coordinates
        return space.from_params(space.params(x[prob.variables.slice("v")], linear_gains=True))

    if out_of_time():
        res.status = "no time left"
        return res
    if spec.objective != "settling_time":
        r = solve(math.inf, xs)
        if r is not None:
            res.candidates.append(to_search(r[1]))
        return res
    _bisect(solve, ev, space, settle, grid, xs, res, to_search, out_of_time)
    return res


def _bisect(solve: _Solves, ev: Evaluator, space: Space, settle: float, grid: _Grid, xs: np.ndarray,
            res: RefineResult, to_search: Any, out_of_time: Any) -> None:
    """Bisection on Ts: feasible (slack >= 0) at hi, infeasible at lo; every feasible solution is a candidate."""
    tgrid = grid.t
    hi = settle if math.isfinite(settle) and settle < tgrid[-1] else 0.9 * tgrid[-1]
    r = solve(hi, xs)
    if r is None:
        return
    res.candidates.append(to_search(r[1]))
    if r[0] < 0:
        return
    best, lo = r[1], 0.3 * hi
    tol = grid.step / 2  # half a sample (the verifier then judges between samples)
    while hi - lo > tol and not out_of_time():
        mid = 0.5 * (lo + hi)
        r = solve(mid, best)
        if r is not None and r[0] >= 0:
            hi, best = mid, r[1]
            res.candidates.append(to_search(best))
            # the solution may settle earlier than asked: jump there (judged by the verifier)
            sc = ev.score(space.params(to_search(best)))
            if sc.feasible and lo < sc.score < hi:
                hi = sc.score
        else:
            lo = mid
