"""Local refinement of one start with the cached CasADi problem.

Numbers enter the symbolic world here (parameter vector, initial point, bounds, all packed by
name through the problem's :class:`~tuner.optimize.nlp.layout.Layout`) and leave it here (the
solution coordinates). What the NLP says about margins or settling is not reported anywhere:
the caller re-verifies the solution.

Steps: :func:`_grid` (horizon and time grid from the start; a polish at the overshoot limit whose uniform grid
misses the peak: :func:`_head_grid`, dense over the first samples only), :func:`_plant_data` (lifted plant
models, factored forms and crossover estimates from the start's analysis), :func:`_values` (the
spec's numbers, the frequency grid with the plant's response on it, the time weights), :func:`_box`
(start and bounds), then :class:`_Solves` runs the solves: for the settling time a bisection on the
settling time (the polish at ``detail`` >= 2 between the grid's points too: ``ProblemKey.interp``); for the
other objectives one solve. After each accepted solve the frequency-domain limits are checked on the verifier's
dense grid and any peak the NLP's grid missed is added to it (exchange), then the solve is repeated from the
solution.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...analysis.margins import frequency_grid
from ...analysis.response import step_response
from ...controllers import ControllerTF
from ...design import plant_sign
from ...limits import LIMITS
from ...loop import build_loop
from ...tolerances import ROOT_AT_DC_TOL
from .. import rules
from ..batch import GUARD, SETTLING_MAX_GUARD, BatchEvaluator, Start
from ..builds import build_seconds
from ..scoring import Evaluator
from ..space import Space
from .plantdata import LiftedPlant, lift
from .transcribe import GRID_EXTRA, MS_GRID, Problem, ProblemKey, estimated_build_s, get_problem, is_built

__all__ = ["RefineResult", "refine", "POINTS_PER_SAMPLE", "MAX_NLP_STEPS"]

log = logging.getLogger(__name__)

POINTS_PER_SAMPLE = 4
POINTS_PER_SETTLE = 100  # at least this many NLP grid points up to the settling time (its resolution: 1 %)
MAX_POINTS_PER_SAMPLE = 32
MAX_GRID_POINTS = 2048  # the more points per sample are taken only while K * N stays within this
RIPPLE_RAD = 0.08  # at most this much of the start's crossover phase between two NLP grid points ...
RIPPLE_POINTS = 8  # ... with up to this many points a sample
# a polish from an incumbent at the overshoot limit whose uniform grid is too coarse for the peak (its points a sample
# capped by MAX_GRID_POINTS over a long horizon, or by RIPPLE_POINTS) runs on a head grid: RIPPLE_RAD between its
# points (up to MAX_POINTS_PER_SAMPLE a sample) over the first samples, as many as cover this much of the start's
# crossover phase (about five of its periods: the overshoot's peak and the ripple between samples are there, the
# crossover's modes have decayed by then), the uniform grid's own points after them (:func:`_head_grid`)
HEAD_RAD = 32.0
SETTLE_HEAD = 1.5  # a polish's fine grid is dense up to this many target settling times (then a slow loop's own points
                   # a sample: POINTS_PER_SAMPLE, 2 or 1 by the settling time in samples; see _settle_head)
SLOW_TAIL = 40.0
CONTINUOUS_STEPS = 400
MAX_CONTINUOUS_STEPS = 1024  # continuous loops: the fine steps of the NLP (horizon = that many steps of h)
H_POLE = 0.5  # continuous loops: the fine step is at most 0.5 / (the start controller's fastest pole)
H_WC = 0.1  # continuous loops: the NLP's fine step is at most 0.1 / (the start's fastest gain crossover)
MIN_SAMPLES = 16
MAX_NLP_STEPS = 4096  # the NLP's horizon in samples (cost limit of one local solve); documented in the README
_ABS_EPS = 1e-9
_TIGHT = 1 - 2e-4  # the NLP keeps its peak limits this much inside the spec: optima sit on the limits, and the
                   # verifier's dense grid must still find them inside (margins: twice the search's guard)
_TIGHT_OS = 0.995
INTEGRAL_FLOOR = 1e-3  # a start's integral gain keeps at least this fraction of itself (see _integral_sign)
NEAR = 0.85  # the bisection's first lower end, as a fraction of an incumbent's settling time
POLISH_STEPS = 2.0  # a polish's first lower end: this many coarse-grid steps below the incumbent's settling time
FIRST = 0.95  # the first solve from a start (no better incumbent) asks for this fraction of its settling time
# a restart's own refinement (``refine(reach=)``: the evidence rule's draw, not bounded by the incumbent) runs on the
# grid of a start settling by ``reach`` (the engine's OWN_REACH times the incumbent's settling time) at the latest:
# REACH_HORIZON times its settling time or ``reach``, whichever is less, its points a sample by the same rule. A start
# that settles later (the common case: the best of a restart's space-filling set settles 7-13 times later than the
# roll loop's incumbent) gets one shape per problem, so that the restarts of every seed share the builds a warm
# process holds; a start that settles later than the horizon is asked first to settle within 0.9 of it (the
# bisection's own rule); one that settles earlier, or not at all (sixty samples), gets the grid it always had
REACH_HORIZON = 3.0
# the fine polish, where its grid resolves the overshoot's peak (:func:`_resolves_peak`; a head grid where a uniform
# one cannot, :func:`_head_grid`; the sharp polish: where the batch's points see no higher peak than the grid's,
# :func:`_measured_os`) and the overshoot limit is active at its answer, bisects on with the limit only this much
# inside the batch's: the settling time can fall steeply with the overshoot allowed (PID on an unstable plant, poles
# +0.26 and -0.53 rad/s at dt 0.33: 22.54 s at the 0.995 tightening, 22.27 s at 0.9995, the optimum with the batch's
# own limit 22.22 s); a candidate whose peak the grid still misses fails the batch and is dropped
_TIGHT_OS_FINE = 0.9995
# the sharp polish (``refine(detail >= 2)``, effort thorough) interpolates Ts between the grid's points and resolves it
# to this part of a grid step: the optimum of a loop that enters the band a few samples after the step (the overshoot
# at the band's edge) lies between the grid's points, where a bisection on the grid stopped up to a step above it
# (PID on a lightly damped plant settling in 3.3 samples, 16 points a sample: 0.5 % above the reference optimum;
# interpolated, 0.03 % below it; a split of 8 left it 0.03 % above and a lead on an integrating plant 0.1 %)
INTERP_SPLIT = 32
# the bisection on the grid (not interpolated): Ts asked only at the grid's points (the envelope starts at the first
# point at or after Ts, so every Ts between two points asks the same problem: a bisection on the time axis asked it
# again), at the secant of the NLP's slack between the bracket's ends where both are known (the slack is nearly
# linear in Ts near the edge: PID on the thesis roll model, -0.0106 at 0.304 s and +0.0075 at 0.416 s, the edge at
# 0.362 s), kept within SECANT_CLAMP of the bracket from either end (a secant that keeps one end twice halves)
SECANT_CLAMP = 0.1
SETTLE_STEPS = 100  # continuous loops, another objective under a settling-time limit: steps up to the limit
SETTLING_MAX_TRIES = 4  # solves of another objective under a settling-time limit (see _other_objective)


@dataclass
class RefineResult:
    """What the local refinements found (candidate coordinates) and what they cost (iterations, evaluations,
    solves; the last solve's success and status)."""

    candidates: list[np.ndarray] = field(default_factory=list)  # coordinates
    iterations: int = 0
    evaluations: int = 0
    solves: int = 0
    success: bool = False
    status: str = ""
    unbuilt_s: float = 0.0  # the estimated build time of an NLP the time left could not afford (status says so)
    cut: bool = False  # the bisection stopped above ``refine(above=)``: its own optimum's value left unresolved


@dataclass(frozen=True)
class _Grid:
    """The NLP's time discretisation: K steps of ``step`` s, N points per step (``head`` > 0: over the first
    ``head`` steps only, ``tail_N`` points per step after them)."""

    K: int
    N: int
    step: float  # dt, or the fine step h of a continuous loop
    h: float | None  # continuous loops: the simulation step (divides every delay)
    head: int = 0
    tail_N: int = 1

    @property
    def t(self) -> np.ndarray:
        if not self.head:
            return np.arange(self.K * self.N) / self.N * self.step
        return np.concatenate([np.arange(self.head * self.N) / self.N * self.step,
                               np.arange(self.head * self.tail_N, self.K * self.tail_N) / self.tail_N * self.step])

    def spacing(self, t: float) -> float:
        """The distance between the grid's points at time ``t``."""
        return self.step / (self.N if not self.head or t < self.head * self.step else self.tail_N)


def _bucket(k: int) -> int:
    """Horizons in a few sizes (powers of two and 1.5 times them), so a warm process reuses its builds."""
    k = max(k, MIN_SAMPLES)
    p = 2 ** math.floor(math.log2(k))
    for size in (p, int(1.5 * p), 2 * p):
        if size >= k:
            return min(size, MAX_NLP_STEPS)
    return min(2 * p, MAX_NLP_STEPS)


def _target(start: Start, incumbent: float | None) -> float:
    """The settling time the refinement must reach to matter: the start's, or the incumbent's if smaller
    (a solution that settles later than the best known one is of no use to the search)."""
    settle = float(np.max(start.settle))
    if incumbent is not None and math.isfinite(incumbent) and incumbent > 0:
        settle = min(settle, incumbent) if math.isfinite(settle) else incumbent
    return settle


def _horizon(ev: BatchEvaluator, start: Start, w0: float, incumbent: float | None = None, fine: bool = False,
             reach: float | None = None) -> float:
    """What the objective needs: three target settling times (:func:`_target`) for the settling time (a restart's
    own refinement, ``reach``: the start's settling time capped at it), the start's own horizon (ten time constants
    of its slowest pole, where the verifier integrates) for the integral objectives."""
    settle = _target(start, incumbent)
    unit = ev.dt if ev.dt else 1.0 / w0
    if ev.spec.objective == "settling_time":
        if reach is not None and not fine and math.isfinite(settle) and settle > 0:
            return REACH_HORIZON * min(settle, reach)
        if not (math.isfinite(settle) and settle > 0):
            return 60 * unit
        if not fine:
            return 3.0 * settle
        # three settling times, or as far as the start's slowest pole reaches (up to SLOW_TAIL settling times): a
        # slow closed-loop pole of small residue (a PID's zero near an integrator or a slow plant pole) can take
        # the response out of the band again long after it settled; a horizon that ends first lets the
        # bisection chase settling times the verifier then finds at six times that (underdamped at dt = tau/5)
        tail = np.nanmax(start.horizon) if np.any(np.isfinite(start.horizon)) else 0.0
        return float(min(max(3.0 * settle, tail), SLOW_TAIL * settle))
    T = np.nanmax(start.horizon) if np.any(np.isfinite(start.horizon)) else 60 * unit
    if ev.spec.settling_time_max is not None:  # the band is constrained from the limit on: see past it
        T = max(float(T), 8.0 * ev.spec.settling_time_max)
    return float(T)


def _points_per_sample(ev: BatchEvaluator, start: Start, incumbent: float | None = None, K: int = 0,
                       fine: bool = False, detail: int = 1, reach: float | None = None) -> int:
    """Between-sample points the NLP constrains: a loop that settles in a few samples can ripple between
    them (the thesis's attitude loops: 3 samples), a slow one cannot by much (the verifier checks anyway).
    ``reach`` (a restart's own refinement): the samples counted up to the start's settling time capped at it."""
    settle = _target(start, incumbent)
    if reach is not None and not fine:
        settle = min(settle, reach)
    samples = settle / ev.dt if math.isfinite(settle) else math.inf
    base = POINTS_PER_SAMPLE if samples <= 15 else (2 if samples <= 40 else 1)
    # a loop can settle slowly and still cross over fast (an unstable plant's slow tail after a fast rise): its
    # overshoot peak then lies between the samples (pid_z on an unstable plant, wc dt = 0.5: the samples show
    # 9.8 %, the response 10.2 %; at 4 points a sample still 9.93 % against the batch's 9.9), and solutions the
    # NLP keeps at the limit fail it; enough points that one step of the grid is at most RIPPLE_RAD of the
    # crossover's phase (the peak then within 0.1 % of the oscillation's amplitude)
    wc = max((w for w in np.atleast_1d(start.wc) if np.isfinite(w) and w > 0), default=0.0)
    cap = MAX_GRID_POINTS * detail
    while base < RIPPLE_POINTS and wc * ev.dt / base > RIPPLE_RAD and (not K or K * base * 2 <= cap):
        base *= 2
    if not fine:
        return base
    # the bisection resolves the settling time to one grid step: a loop settling in a few samples needs more
    # points per sample than the ripple does (underdamped at dt = tau/5, settling in 3.6 samples: 4 points per
    # sample left the answer 9 % above the optimum); powers of two, so a warm process reuses its builds
    want = POINTS_PER_SETTLE * detail ** 2 / samples if math.isfinite(samples) and samples > 0 else 0
    n = base
    while n < want and n < MAX_POINTS_PER_SAMPLE and K * n * 2 <= cap:
        n *= 2
    return n


def _resolves_peak(start: Start, grid: _Grid) -> bool:
    """Whether the grid's points are at most RIPPLE_RAD of the start's crossover phase apart (the overshoot's peak
    then within 0.1 % of the oscillation's amplitude above the grid's highest point); a head grid's: over its head."""
    wc = max((w for w in np.atleast_1d(start.wc) if np.isfinite(w) and w > 0), default=math.inf)
    return wc * grid.step / grid.N <= RIPPLE_RAD


def _head_grid(start: Start, grid: _Grid) -> _Grid | None:
    """A sampled loop's grid that resolves the overshoot's peak (:func:`_resolves_peak`) where the uniform ``grid``
    does not: enough points a sample over a head of HEAD_RAD of the crossover's phase (about HEAD_RAD / RIPPLE_RAD
    points, 400 to 1600 whatever the horizon), ``grid``'s own after it; None if ``grid`` resolves the peak or more
    than MAX_POINTS_PER_SAMPLE would be needed.

    A loop that crosses over fast for its sample time yet settles slowly (PID on an unstable plant at wc dt = 1.0,
    its slow tail in the band after 240 samples) peaks within its first ten samples; the polish's horizon (the tail's
    slow pole: 1536 samples) leaves it one point a sample under MAX_GRID_POINTS, so the polish could not loosen the
    overshoot limit (its candidates at 9.895 % peaked at 9.901 % between the points, above the batch's 9.9) and
    stopped at 2.039 s where the optimum, at the limit, is 1.861 s; the head grid reaches 1.880 s. The tail needs no
    more points: it is the slow modes', the ripple has decayed, and the settling time's resolution is the uniform
    grid's."""
    wc = max((w for w in np.atleast_1d(start.wc) if np.isfinite(w) and w > 0), default=0.0)
    if grid.h is not None or grid.head or not 0 < wc < math.inf or _resolves_peak(start, grid):
        return None
    n = grid.N
    while wc * grid.step / n > RIPPLE_RAD:
        n *= 2
        if n > MAX_POINTS_PER_SAMPLE:
            return None
    head = 2 ** math.ceil(math.log2(max(HEAD_RAD / (wc * grid.step), MIN_SAMPLES)))
    if head >= grid.K:
        return _Grid(K=grid.K, N=n, step=grid.step, h=None)
    return _Grid(K=grid.K, N=n, step=grid.step, h=None, head=head, tail_N=grid.N)


def _settle_head(ev: BatchEvaluator, start: Start, incumbent: float | None, grid: _Grid, detail: int) -> _Grid:
    """A polish's fine grid for a sampled loop, dense only where the detail is needed: over the first SETTLE_HEAD
    target settling times (a power of two of samples; the bisection resolves the settling time there, and the
    overshoot peaks there), at the fine rule's points a sample (POINTS_PER_SETTLE detail^2 up to the settling time,
    the ripple's), as many as the cap (MAX_GRID_POINTS detail) allows for the whole grid; after the head, over the
    rest of a long horizon that catches a slow tail's return to the band's edge, the points a sample of a loop that
    settles as slowly (POINTS_PER_SAMPLE, 2 or 1, without the ripple's doubling: the fast modes have decayed there,
    and the tail changes over many samples). An integrating plant's PID settling in 3.5 samples, its slow zero's tail
    reaching 192 samples, had 8 points a sample over all 192 (1536 points) and has 32 over the first 16 and 4 after
    them (1216). Used only where it has fewer points than ``grid`` (so a polish never costs more than it did): where
    the tail keeps ``grid``'s own points a sample, a denser head would add points and ``grid`` itself is returned."""
    settle = _target(start, incumbent)
    if ev.dt is None or grid.head or not (math.isfinite(settle) and settle > 0):
        return grid
    samples = settle / ev.dt
    head = 2 ** math.ceil(math.log2(max(SETTLE_HEAD * samples, MIN_SAMPLES)))
    if head >= grid.K:
        return grid
    tail_n = min(POINTS_PER_SAMPLE if samples <= 15 else (2 if samples <= 40 else 1), grid.N)
    cap = MAX_GRID_POINTS * detail
    want = POINTS_PER_SETTLE * detail ** 2 / samples
    n = grid.N
    while n < want and n < MAX_POINTS_PER_SAMPLE and head * n * 2 + (grid.K - head) * tail_n <= cap:
        n *= 2
    if n == tail_n or head * n + (grid.K - head) * tail_n >= grid.K * grid.N:
        return grid
    return _Grid(K=grid.K, N=n, step=grid.step, h=None, head=head, tail_N=tail_n)


def _at_overshoot_limit(ev: BatchEvaluator, start: Start) -> bool:
    """Whether the start's overshoot (the batch's) is within 1 % of the NLP's limit: the limit is likely to be
    active at the polish's answer too."""
    limit = ev.spec.overshoot_max_pct * GUARD["overshoot"] * _TIGHT_OS
    return bool(np.any(np.asarray(start.overshoot) >= 0.99 * limit))


def _grid(ev: BatchEvaluator, start: Start, w0: float, incumbent: float | None = None, fine: bool = False,
          detail: int = 1, c_fast: float = 0.0, reach: float | None = None) -> _Grid:
    T = _horizon(ev, start, w0, incumbent, fine, reach)
    if ev.dt is not None:
        K = _bucket(int(math.ceil(T / ev.dt)))
        return _Grid(K=K, N=_points_per_sample(ev, start, incumbent, K, fine, detail, reach), step=ev.dt, h=None)
    # the fine step resolves the loop (H_WC rad of the fastest crossover per step) as well as the horizon: a
    # slow closed-loop pole of small residue (a PI zero next to a plant pole) must not stretch the step over
    # the loop's own dynamics (1/(4s+1) with pidf2: T = 204 s would give h = 0.5 s against wc = 2.7 rad/s);
    # the horizon is then what MAX_NLP_STEPS such steps cover
    h = T / CONTINUOUS_STEPS
    wc = [w for w in np.atleast_1d(start.wc) if np.isfinite(w) and w > 0]
    if wc:
        h = min(h, H_WC / max(wc))
    if 0 < c_fast < math.inf:
        # and the start controller's fastest pole (a derivative filter's 1/Tf): Tustin at h |p| >> 1 maps it next to
        # z = -1 and the simulated output rings (a PID with 1/Tf = 20.7 rad/s at h = 0.144 s: 26 % of the step off the
        # verifier's, found by tests/tuner/test_registry_contract.py)
        h = min(h, H_POLE / c_fast)
    if ev.spec.settling_time_max is not None and ev.spec.objective != "settling_time":
        # another objective under a settling-time limit: the envelope's edge resolved (the Tustin model's error is
        # O(h), and the limit is where the answer sits); the horizon then ends after MAX_CONTINUOUS_STEPS steps (ten
        # times the limit, or less where the controller's fastest pole makes the step finer still)
        h = min(h, ev.spec.settling_time_max / SETTLE_STEPS)
    taus = [p.delay_s for p in ev.problem.plants if p.delay_s]
    if taus:
        h = min(taus) / max(1, math.ceil(min(taus) / h))
    return _Grid(K=min(_bucket(int(math.ceil(T / h))), MAX_CONTINUOUS_STEPS), N=1, step=h, h=h)


@dataclass
class _PlantData:
    lifted: list[LiftedPlant] = field(default_factory=list)
    wc: list[float] = field(default_factory=list)  # gain-crossover estimate per plant
    wp: list[float] = field(default_factory=list)  # phase-crossover estimates (plants that have one)
    has_pc: list[bool] = field(default_factory=list)


def _plant_data(ev: BatchEvaluator, start: Start, ctrl: ControllerTF, grid: _Grid, w0: float) -> _PlantData:
    """Lifted model of every plant, and the start's crossovers (from the batched verifier)."""
    out = _PlantData()
    wnyq = math.pi / ev.dt if ev.dt else math.inf
    for p, wc, wp in zip(ev.problem.plants, start.wc, start.wp):
        if grid.h is not None:  # continuous loop: ZOH at the fine step, the plant's own zpk for L(jw)
            lf = lift(build_loop(p, ControllerTF(num=np.ones(1), den=np.ones(1), dt=grid.h)), 1)
            lf = lf.with_response_of(p.zpk)
        else:
            lf = lift(build_loop(p, ctrl), grid.N)
        has_pc = bool(math.isfinite(wp) and 0 < wp < 0.98 * wnyq)
        out.lifted.append(lf)
        out.wc.append(float(wc) if math.isfinite(wc) else w0)
        out.has_pc.append(has_pc)
        if has_pc:
            out.wp.append(float(wp))
    return out


def _wmax(ev: BatchEvaluator, w0: float) -> float:
    return math.pi / ev.dt * 0.999 if ev.dt else 1e3 * w0


def _time_weights(grid: _Grid, objective: str) -> np.ndarray:
    """Trapezoid weights of the verifier's integrals on the NLP's time grid (times t for the ITAE)."""
    t = grid.t
    if grid.head:
        d = np.diff(t)
        w = np.concatenate([d, [0.0]]) / 2 + np.concatenate([[0.0], d]) / 2
    else:
        w = np.full(t.size, grid.step / grid.N)
        w[0] = w[-1] = 0.5 * grid.step / grid.N
    return w * t if objective == "itae" else w


def _values(ev: BatchEvaluator, space: Space, grid: _Grid, data: _PlantData, key: ProblemKey) -> dict[str, Any]:
    """Every parameter block but the settling mask, by name."""
    spec = ev.spec
    kiu = next((u for p, u in zip(space.structure.params, space.units) if p == space.structure.integral),
               space.k0 * space.w0)
    values: dict[str, Any] = {
        "dt": ev.dt or grid.h, "h": grid.step, "band": spec.settling_band_pct / 100.0 * GUARD["band"],
        "os": min(spec.overshoot_max_pct / 100.0 * GUARD["overshoot"] * _TIGHT_OS, 10.0),
        "cpk": (spec.control_peak_max or 1.0) * _TIGHT, "msinv": 1.0 / (spec.ms_max * _TIGHT) if spec.ms_max else 0.0,
        "mt": (spec.mt_max or 1.0) * _TIGHT, "mks": (spec.mks_max or 1.0) * _TIGHT,
        "alpha": (spec.disk_margin_min or 0.0) / _TIGHT,
        "eps": _ABS_EPS, "kiu": abs(float(kiu)) or 1.0, "units": np.asarray(space.units, float),
        "nmax": (spec.filter_n_max or 1.0) * _TIGHT, "kscale": space.k0,
        "kimin": (spec.ki_min or 1.0) / _TIGHT, "kisgn": _ki_sign(ev),
        "tw": _time_weights(grid, spec.objective)}
    for i, (pm_min, gm_min) in enumerate(ev.margins):  # each plant's margins (a gain-variation member's its own)
        values[f"cospm{i}"] = math.cos(math.radians(min(pm_min + 2 * GUARD["margin_deg"], 180.0)))
        values[f"g{i}"] = 10 ** (-(gm_min + 2 * GUARD["margin_db"]) / 20.0)
    if key.settling_max:
        values.update({f"yoff{i}": np.zeros(grid.t.size) for i in range(len(ev.problem.plants))})
    for i, (p, lf) in enumerate(zip(ev.problem.plants, data.lifted)):
        values.update(lf.blocks(i, delay_s=p.delay_s if grid.h is not None else 0.0))
    wgrid = np.zeros(key.n_grid)
    if key.grid:
        base = np.geomspace(space.w0 * 1e-2, _wmax(ev, space.w0), MS_GRID)
        wgrid = np.concatenate([base, np.repeat(base[MS_GRID // 2], GRID_EXTRA)])  # spare slots: a duplicate
    if key.drb:  # the limit itself is a grid frequency (the nearest base point moved there): the row that binds
        drb = float(spec.drb_min_rad_s)
        j = int(np.argmin(np.abs(np.log(wgrid[:MS_GRID] / drb))))
        wgrid[j] = drb
        values["drbmask"] = (wgrid <= drb * (1 + 1e-9)).astype(float)
    values["wgrid"] = wgrid
    _grid_response(ev, values) if key.grid else values.update(
        {f"{k}{i}": np.zeros(0) for i in range(len(ev.problem.plants)) for k in ("Gre", "Gim")})
    return values


def _grid_response(ev: BatchEvaluator, values: dict[str, Any]) -> None:
    """The plants' frequency responses (delay included) at the NLP's grid frequencies."""
    unit = ControllerTF(num=np.ones(1), den=np.ones(1), dt=ev.dt)
    for i, p in enumerate(ev.problem.plants):
        G = build_loop(p, unit).freqresp(values["wgrid"])
        values[f"Gre{i}"], values[f"Gim{i}"] = G.real, G.imag
    if ev.spec.drb_min_rad_s is not None and "drbmask" in values:  # (the exchange's frequencies too)
        values["drbmask"] = (values["wgrid"] <= ev.spec.drb_min_rad_s * (1 + 1e-9)).astype(float)


def _box(prob: Problem, space: Space, x0: np.ndarray, data: _PlantData, band: float, wmax: float,
         wc_target: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start, lower and upper bounds of the decision vector (``wc_target``: the crossovers pinned there)."""
    vlo, vhi = space.bounds(linear_gains=True)
    key = prob.key
    wc = data.wc if key.pm else []
    if wc_target is not None and wc:
        wc = [wc_target] * len(wc)
    wp = data.wp if key.gm else []
    lay = prob.variables
    xs = lay.pack({"v": space.from_params(x0, linear_gains=True), "slack": 0.0, "wc": wc, "wp": wp})
    lbx = lay.pack({"v": vlo, "slack": -1.0, "wc": [1e-6 * space.w0] * len(wc), "wp": [w / 3 for w in wp]})
    ubx = lay.pack({"v": vhi, "slack": band, "wc": [wmax] * len(wc), "wp": [min(3 * w, wmax) for w in wp]})
    if wc_target is not None and len(wc):
        sl = lay.slice("wc")
        lbx[sl], ubx[sl] = wc_target * (1 - 0.005), wc_target * (1 + 0.005)
    return np.clip(xs, lbx, ubx), lbx, ubx


def _dc_sign(ev: BatchEvaluator) -> float | None:
    """The sign of the integral gain every stable loop has (see :func:`_integral_sign`): that of the plants'
    numerator at DC, ``n_p(0)`` (``n_p(1)`` in z; a continuous plant at dt: its ZOH's ``n(1)`` has the sign of
    ``n(0)``), the denominator monic; None where the plants disagree or it is not defined (a biproper plant, whose
    leading coefficient depends on Kp, or a zero at DC)."""
    signs = set()
    for p in ev.problem.plants:
        zk = p.zpk
        at = 1.0 if p.is_discrete else 0.0
        if zk.zeros.size >= zk.poles.size or np.any(np.abs(zk.zeros - at) <= ROOT_AT_DC_TOL * max(1.0, at)):
            return None
        with np.errstate(all="ignore"):
            n_at = float(np.real(zk.gain * np.prod(at - zk.zeros)))  # n_p at DC, d_p monic
        if not (math.isfinite(n_at) and n_at != 0.0):
            return None
        signs.add(1.0 if n_at > 0 else -1.0)
    return signs.pop() if len(signs) == 1 else None


def _ki_sign(ev: BatchEvaluator) -> float:
    """The sign the ``ki_min`` row gives the integral gain: :func:`_dc_sign`, else the nominal plant's static
    sign."""
    sign = _dc_sign(ev)
    return sign if sign is not None else plant_sign(ev.problem.nominal)


def _integral_sign(ev: BatchEvaluator, space: Space, prob: Problem, x0: np.ndarray, lbx: np.ndarray,
                   ubx: np.ndarray) -> None:
    """Bound the integral gain to the sign every stable loop has: the characteristic polynomial of ``C = n_c/(s d_c)``
    on a strictly proper plant ``n_p/d_p`` is ``s d_c d_p + n_c n_p``; its value at s = 0 is ``Ki n_p(0)`` (times
    ``d_c(0) > 0``) and its leading coefficient that of ``s d_c d_p``, so an integral gain of the other sign than
    ``n_p(0)``'s (``d_p`` monic) puts a real root in
    the right half plane (at z = 1 the same for the sampled loop, a delay's ``e^{-s tau}`` is 1 at s = 0 and vanishes
    for large real s). The NLP cannot see that root when it is slow: a vanishing integral (a P on an integrating
    plant) crossing zero leaves a pole that leaves the band only after the NLP's horizon, and every candidate of
    the bisection would be unstable."""
    st = space.structure
    ki = st.integral  # the integral gain's name ("Ki"; a firmware law's "I", scaled by its K > 0)
    if ki is None or ki not in st.params or not st.integrating or st.kinds[st.params.index(ki)] != "gain":
        return
    dc = _dc_sign(ev)
    if dc is None:
        return
    k = st.params.index(ki)
    i = prob.variables.slice("v").start + k
    unit = float(space.units[k])
    sign = dc * np.sign(unit)
    floor = INTEGRAL_FLOOR * float(x0[k]) / unit if unit else 0.0  # the start's integral, in the NLP's coordinate
    if sign > 0:
        lbx[i] = max(lbx[i], floor, 0.0)
    elif sign < 0:
        ubx[i] = min(ubx[i], floor, 0.0)


class _Solves:
    """Solves of one problem from one start, accumulating the solver's statistics in ``res``."""

    def __init__(self, prob: Problem, values: dict[str, Any], grid: _Grid, lbx: np.ndarray, ubx: np.ndarray,
                 res: RefineResult, solver: str) -> None:
        self.prob, self.values, self.tgrid, self.lbx, self.ubx = prob, values, grid.t, lbx, ubx
        self.res, self.solver = res, solver
        self.lam: dict[str, np.ndarray] = {}
        self.slack = prob.variables.slice("slack").start
        self.interp = prob.key.interp
        # the settling time the bisection resolves, in grid steps: one, or (Ts interpolated between the grid's points)
        # a fraction of one
        self.split = INTERP_SPLIT if self.interp else 1
        # the sharp polish (set by refine): ``accept(x, ts)``, whether the verifier confirms that solution ``x`` settles
        # by ``ts``; a solution it does not confirm counts as infeasible
        self.accept: Any = None
        self.last_ok = False  # the last solve succeeded (its slack, feasible or not, is the NLP's optimum at its Ts)

    def _params(self, ts: float) -> np.ndarray:
        """The parameter vector with the envelope from ``ts`` on (``inf``: none)."""
        t = self.tgrid
        mask = (t >= ts - 1e-12).astype(float) if math.isfinite(ts) else np.zeros(t.size)
        extra = {}
        if self.interp:
            theta = np.zeros(t.size)
            j = int(np.searchsorted(t, ts - 1e-12)) if math.isfinite(ts) else t.size
            if 0 < j < t.size and t[j] - ts > 1e-12:  # Ts inside (t[j-1], t[j]): row j-1 is the output at Ts
                theta[j - 1], mask[j - 1] = (ts - t[j - 1]) / (t[j] - t[j - 1]), 1.0
            extra["theta"] = theta
        return self.prob.params.pack({**self.values, "mask": mask, **extra})

    def settles_at(self, x: np.ndarray) -> float:
        """The settling time of solution ``x`` on the NLP's own time grid (every plant; the envelope's band):
        the first grid time from which every output stays in the band (``interp``: where the output, linearly
        interpolated, last crosses into the band, as the verifier finds it); ``inf`` if the last point is out."""
        Y = self._step(x)
        err = np.abs(Y - 1.0) - self.values["band"]
        out = np.any(err > 0, axis=0)
        if not out.any():
            return 0.0
        j = int(np.flatnonzero(out)[-1])
        if j + 1 >= self.tgrid.size:
            return math.inf
        t0, t1 = float(self.tgrid[j]), float(self.tgrid[j + 1])
        if not self.interp:
            return t1
        e0, e1 = float(np.max(err[:, j])), float(np.max(err[:, j + 1]))  # e0 > 0 >= e1
        return t0 + e0 / (e0 - e1) * (t1 - t0) if e0 > e1 else t1

    def overshoot(self, x: np.ndarray) -> float:
        """The overshoot of solution ``x`` on the NLP's grid (every plant's worst), as a fraction."""
        return float(np.max(self._step(x))) - 1.0

    def peak_time(self, x: np.ndarray) -> float:
        """When solution ``x`` peaks on the NLP's grid (every plant's worst)."""
        return float(self.tgrid[int(np.argmax(np.max(self._step(x), axis=0)))])

    def _step(self, x: np.ndarray) -> np.ndarray:
        """The reference-step outputs of solution ``x`` on the NLP's grid, one row per plant."""
        return np.asarray(self.prob.step(x, self._params(math.inf))).reshape(-1, self.tgrid.size)

    def __call__(self, ts: float, x_init: np.ndarray) -> tuple[float, np.ndarray] | None:
        """Solve with the settling envelope from ``ts`` on (``inf``: none): (slack or objective, x); the first
        is < 0 if the settling problem is infeasible."""
        res, prob = self.res, self.prob
        p = self._params(ts)
        try:
            sol = prob.solver(x0=x_init, p=p, lbx=self.lbx, ubx=self.ubx, lbg=prob.lbg, ubg=prob.ubg, **self.lam)
        except RuntimeError as e:  # solver failures surface as RuntimeError in CasADi
            res.status = f"solver error: {e}"
            return None
        stats = prob.solver.stats()
        res.solves += 1
        res.iterations += int(stats.get("iter_count", 0))
        res.evaluations += sum(int(stats.get(k, 0)) for k in ("n_call_nlp_f", "n_call_nlp_g", "n_call_nlp_fg"))
        res.success = res.success or bool(stats.get("success", False))
        res.status = str(stats.get("return_status", ""))
        x = np.asarray(sol["x"]).ravel()
        if not np.all(np.isfinite(x)):
            return None
        if self.solver == "ipopt":  # warm start the next bisection solve from this one's multipliers
            self.lam.update(lam_x0=np.asarray(sol["lam_x"]).ravel(), lam_g0=np.asarray(sol["lam_g"]).ravel())
        ok = stats.get("success", False) or res.status == "Solved_To_Acceptable_Level"
        self.last_ok = bool(ok)
        if prob.key.objective == "settling_time":
            if ok and x[self.slack] >= 0 and self.accept is not None and not self.accept(x, ts):
                ok = False  # the bisection does not go on from a solution the verifier does not confirm
            return (float(x[self.slack]) if ok else -1.0), x
        return (float(sol["f"]) if ok else math.inf), x


def _other_objective(ev: BatchEvaluator, space: Space, solve: _Solves, xs: np.ndarray, res: RefineResult,
                     to_search: Any, exchange: Any, out_of_time: Any, settling_max: bool) -> None:
    """An objective other than the settling time: one solve, its answer a candidate. Under a settling-time limit
    the NLP's envelope starts a little before the limit (1 % inside the search's guard), and where the batched
    verifier finds the answer settling later, the envelope is corrected by the difference between the verifier's
    output and the NLP's at that answer (a defect correction) and solved again from it (up to SETTLING_MAX_TRIES
    solves); then once more with the envelope from the guard itself, from the last answer the batch found
    feasible. A continuous loop's NLP simulates a Tustin controller on the plant held at its fine step, whose output
    differs from the continuous one by up to several percent of the step (tests/tuner/test_registry_contract.py): on
    1/(s + 1)^3 with a PID, objective Mks, settling <= 3 s, the NLP's answer settled at 2.94 s on its grid and at
    5.4 s in the verifier, every answer of the search failed the limit, and the tune fell back to the fastest
    design (Mks 57 where 3.4 meets it)."""
    if not settling_max:
        r = solve(math.inf, xs)
        if r is not None:
            res.candidates.append(to_search(exchange(r[1], math.inf)))
        return
    edge = ev.spec.settling_time_max * SETTLING_MAX_GUARD  # what the batch holds
    x = xs
    for ts in (edge * 0.99, edge):
        ok = _corrected(ev, space, solve, x, ts, edge, res, to_search, exchange, out_of_time)
        if ok is None or out_of_time():
            return
        x = ok


def _judged(ev: BatchEvaluator, X: np.ndarray) -> Any:
    """One candidate judged on the batch's numpy path (the reference), whichever path the batch scores with: the
    compiled kernels give its figures to about 1e-10, not bitwise, and a refinement's accept-or-not against an edge
    it rides (the settling envelope's) must not depend on which path ran (issue 41: the same answer on the service,
    which loads the kernels, and the command line, which does not)."""
    k, ev.kernels = ev.kernels, None
    try:
        return ev.evaluate(X)
    finally:
        ev.kernels = k


def _corrected(ev: BatchEvaluator, space: Space, solve: _Solves, x: np.ndarray, ts: float, edge: float,
               res: RefineResult, to_search: Any, exchange: Any, out_of_time: Any) -> np.ndarray | None:
    """Solves with the envelope from ``ts`` on, each answer a candidate, corrected by the verifier's output until the
    batch finds the answer settling by ``edge`` (see :func:`_other_objective`); that answer, or None."""
    for _ in range(SETTLING_MAX_TRIES):
        r = solve(ts, x)
        if r is None:
            return None
        x = exchange(r[1], ts)
        v = to_search(x)
        res.candidates.append(v)
        if not math.isfinite(r[0]) or out_of_time():
            return None
        if float(np.max(_judged(ev, space.params(v)[None]).metrics["settling_time_s"])) <= edge:
            return x
        # the envelope constrains the NLP's output plus what the verifier's differs from it at this answer
        ctrl = ev.st.tf(space.params(v), ev.dt)
        t = solve.tgrid
        Y = solve._step(x)
        for i, p in enumerate(ev.problem.plants):
            resp = step_response(build_loop(p, ctrl), horizon_s=float(t[-1]))
            yv = np.interp(t, resp.t, resp.y)
            if not np.all(np.isfinite(yv)):
                return None
            solve.values[f"yoff{i}"] = yv - Y[i]  # (Y is the NLP's own output, without the offset: the whole defect)
    return None


def _peaks(ev: BatchEvaluator, ctrl: ControllerTF) -> tuple[float, float]:
    """Mks and the disk margin of ``ctrl`` on the verifier's dense grids, worst over the plants."""
    mks, dm = 0.0, math.inf
    for p in ev.problem.plants:
        lp = build_loop(p, ctrl)
        w = frequency_grid(lp)
        with np.errstate(all="ignore"):
            L = lp.freqresp(w)
            S = 1 / (1 + L)
            cs_ = np.abs(ctrl.freqresp(w) * S)
            d = 2 * np.abs(1 + L) / np.abs(1 - L)
        mks = max(mks, float(np.max(np.where(np.isfinite(cs_), cs_, 0.0))))
        dm = min(dm, float(np.min(np.where(np.isfinite(d), d, np.inf))))
    return mks, dm


def _missed_peak(ev: BatchEvaluator, space: Space, v: np.ndarray, level: float | None = None) -> float | None:
    """The frequency where the verifier's dense grid finds a frequency-domain limit violated, or None
    (``level``: the mks / disk_margin objective's level at the solution, a limit too)."""
    spec = ev.spec
    if level is not None:
        field_ = "mks_max" if spec.objective == "mks" else "disk_margin_min"
        cur = getattr(spec, field_)
        # the NLP holds the peak at the level itself (not _TIGHT inside it): a peak counts as missed beyond it
        level = level / _TIGHT if spec.objective == "mks" else level * _TIGHT
        tighter = level if cur is None else (min(cur, level) if spec.objective == "mks" else max(cur, level))
        spec = spec.model_copy(update={field_: tighter})
    if not (spec.ms_max or spec.mt_max or spec.mks_max or spec.disk_margin_min or spec.drb_min_rad_s):
        return None  # no frequency-domain limit the dense grid could find violated (the default spec's case)
    ctrl = ev.st.tf(space.params(v), ev.dt)
    worst, w_worst = _TIGHT + 1e-6, None  # the NLP keeps the peaks at most _TIGHT times the limits
    for p in ev.problem.plants:
        lp = build_loop(p, ctrl)
        w = frequency_grid(lp)
        with np.errstate(all="ignore"):
            L = lp.freqresp(w)
            C = ctrl.freqresp(w)
            S = 1 / (1 + L)
        checks = []
        if spec.ms_max:
            checks.append(np.abs(S) / spec.ms_max)
        if spec.mt_max:
            checks.append(np.abs(L * S) / spec.mt_max)
        if spec.mks_max:
            checks.append(np.abs(C * S) / spec.mks_max)
        if spec.disk_margin_min:
            checks.append(spec.disk_margin_min / np.maximum(2 * np.abs(1 + L) / np.abs(1 - L), 1e-300))
        if spec.drb_min_rad_s:  # |S| above -3 dB below the limit
            checks.append(np.where(w <= spec.drb_min_rad_s, np.abs(S) * math.sqrt(2.0), 0.0))
        for r in checks:
            r = np.where(np.isfinite(r), r, 0.0)
            i = int(np.argmax(r))
            if r[i] > worst:
                worst, w_worst = float(r[i]), float(w[i])
    return w_worst


def refine(ev: BatchEvaluator, space: Space, v0: np.ndarray, *, deadline: float | None = None,
           solver: str = "sqp", incumbent: float | None = None, start: Start | None = None, fine: bool = False,
           detail: int = 1, build_cap: float | None = None, reach: float | None = None,
           above: float | None = None) -> RefineResult:
    """Refine coordinates ``v0`` on the exact local problem; returns candidate coordinates.

    ``ev`` is the batched verifier of the tune (it holds the problem); it judges the start and the
    bisection's intermediate solutions. ``incumbent``: the best settling time known to the caller; the
    refinement then looks only for solutions that settle no later (its horizon follows that target,
    not the start's possibly much longer settling). ``start``: what the batch already said about ``v0``.
    ``fine`` (the polish of an incumbent, settling time only): a sampled loop's NLP grid resolves the settling
    time to about 1 % (more points per sample) and reaches as far as the start's slowest pole (up to
    ``SLOW_TAIL`` settling times); dearer per solve, so the search runs it once per incumbent; where the overshoot
    limit holds the incumbent and the grid misses its peak, on a head grid (:func:`_head_grid`). ``detail`` (the
    effort's ``Effort.detail``): the grid's cap (``MAX_GRID_POINTS``) times it, the polish's points up to the
    settling time (``POINTS_PER_SETTLE``) times its square (2: resolved to about 0.25 %); from 2 on the polish is
    *sharp*: its settling time is not quantised to the grid (the envelope's first row is the output interpolated at
    Ts, bisected to ``1/INTERP_SPLIT`` of a step; also where the fine grid is the coarse one), a solution counts as
    feasible only if the full verifier confirms it (at that edge nothing is left for what the grid does not see),
    and where the overshoot limit is active its looser margin is measured at the answer (:func:`_measured_os`) and
    starts from the incumbent when the tight one cannot hold even the incumbent's own settling time. ``build_cap``
    (a tune on the default budget): the NLP's build does not count against ``deadline`` (it is moved on by the
    build's time), only against this wall-clock cap. ``reach`` (settling time, without an ``incumbent``: a restart's
    own refinement to its start's local optimum): the NLP's grid is that of a start settling by this at the latest, so
    that refinements from starts settling later share one problem shape (the caller passes a multiple of its
    incumbent's settling time: a basin that settles later than that is no rival). ``above`` (with ``reach``: the
    incumbent's settling time plus the search's tolerance): the bisection stops at its first infeasible solve above
    this (``RefineResult.cut``): from there the bisection goes below that value only if a later solution settles
    earlier than asked (it then re-opens its bracket), so it mostly only resolves its own, worse optimum's value, which
    the caller does not need (the evidence rule counts such a draw as an optimum of its own, distinct from every other:
    more cautious, never a claim easier)."""
    res = RefineResult()
    r = _setup(ev, space, v0, res, deadline=deadline, solver=solver, incumbent=incumbent, start=start, fine=fine,
               detail=detail, build_cap=build_cap, reach=reach)
    if r is None:  # (res.status says why)
        return res
    if r.out_of_time():
        res.status = "no time left"
        return res
    if ev.spec.objective != "settling_time":
        _other_objective(ev, space, r.solve, r.xs, res, r.to_search, r.exchange, r.out_of_time, r.key.settling_max)
        return res
    _settling_time(r, above)
    return res


@dataclass
class _Refinement:
    """One refinement's NLP and what its steps share (see :func:`refine`)."""

    ev: BatchEvaluator
    space: Space
    res: RefineResult
    deadline: float | None
    start: Start
    incumbent: float | None
    fine: bool
    grid: _Grid
    coarse: _Grid
    headed: _Grid | None
    sharp: bool
    same: bool
    key: ProblemKey
    prob: Problem
    values: dict[str, Any]
    xs: np.ndarray
    solve: _Solves

    def out_of_time(self) -> bool:
        return self.deadline is not None and time.perf_counter() > self.deadline

    def to_search(self, x: np.ndarray) -> np.ndarray:
        """NLP coordinates -> the search's coordinates."""
        return self.space.from_params(self.space.params(x[self.prob.variables.slice("v")], linear_gains=True))

    def exchange(self, x: np.ndarray, ts: float) -> np.ndarray:
        """Add the frequencies where the limits are violated between the grid's points, and solve again."""
        ev, spec, solve, values = self.ev, self.ev.spec, self.solve, self.values
        for slot in range(GRID_EXTRA if self.key.grid else 0):
            level = float(x[solve.slack]) if spec.objective in ("mks", "disk_margin") else None
            w_miss = _missed_peak(ev, self.space, self.to_search(x), level)
            if w_miss is None or self.out_of_time():
                break
            values["wgrid"][MS_GRID + slot] = w_miss
            _grid_response(ev, values)
            r = solve(ts, x)
            if r is None:
                break
            x = r[1]
        return x

    def bisect(self, target: float, x: np.ndarray, **kw: Any) -> tuple[float, np.ndarray] | None:
        return _bisect(self.solve, self.ev, self.space, target, self.grid, x, self.res, self.to_search,
                       self.out_of_time, self.exchange, **kw)


def _grids(ev: BatchEvaluator, space: Space, start: Start, incumbent: float | None, fine: bool, detail: int,
           c_fast: float = 0.0, reach: float | None = None) -> tuple[_Grid, _Grid, _Grid | None, bool, bool]:
    """The NLP's time grid, the coarse one (a polish's own start), the head grid (where the polish's looser overshoot
    limit needs the peak resolved), whether the polish is sharp, and whether the fine grid is the coarse one."""
    spec = ev.spec
    grid = _grid(ev, start, space.w0, incumbent, fine, detail, c_fast, reach)
    # the polish's looser overshoot limit (below) needs the peak resolved
    headed = _head_grid(start, grid) if fine and spec.objective == "settling_time" and \
        _at_overshoot_limit(ev, start) else None
    grid = headed or grid
    coarse = _grid(ev, start, space.w0, incumbent, False, detail, c_fast, reach) if fine else grid
    if fine and headed is None:
        grid = _settle_head(ev, start, incumbent, grid, detail)
    # the sharp polish (``detail`` >= 2): Ts interpolated between the grid's points and the overshoot margin measured
    sharp = fine and detail >= 2 and spec.objective == "settling_time"
    # a polish on the coarse grid itself would repeat the refinement it follows: only its looser overshoot margin
    # (below) or, sharp, its settling time between the grid's points can add to it
    same = fine and (coarse.K, coarse.N, coarse.head) == (grid.K, grid.N, grid.head) and not sharp
    return grid, coarse, headed, sharp, same


def _key(ev: BatchEvaluator, space: Space, data: _PlantData, grid: _Grid, solver: str, sharp: bool) -> ProblemKey:
    """The NLP's shape: which rows the spec asks for (the registry's limits the NLP states), the plants' sizes, the
    grid's."""
    spec = ev.spec
    return ProblemKey(structure=space.structure.key, continuous=ev.dt is None,
                      orders=tuple(lf.n for lf in data.lifted), zeros=tuple(lf.zeros.size for lf in data.lifted),
                      poles=tuple(lf.poles.size for lf in data.lifted),
                      delays=tuple(lf.delay_samples for lf in data.lifted), K=grid.K, N=grid.N,
                      phase_cross=tuple(data.has_pc), control_peak=spec.control_peak_max is not None,
                      objective=spec.objective, solver=solver,
                      pm=spec.phase_margin_min_deg > 0 or spec.crossover_rad_s is not None,
                      gm=spec.gain_margin_min_db > 0,
                      # the frequency-grid rows: the registry's limits the NLP states on its grid (each ProblemKey
                      # flag named as the limit's batch figure: ms, mt, mks, dm, drb)
                      **{lim.batch: getattr(spec, lim.field) is not None for lim in LIMITS if lim.nlp == "grid"},
                      ki=spec.ki_min is not None,
                      filter_n=rules.applies(space.structure, spec),
                      settling_max=spec.settling_time_max is not None and spec.objective != "settling_time",
                      head=grid.head, tail_N=grid.tail_N, interp=sharp)


def _setup(ev: BatchEvaluator, space: Space, v0: np.ndarray, res: RefineResult, *, deadline: float | None,
           solver: str, incumbent: float | None, start: Start | None, fine: bool, detail: int,
           build_cap: float | None = None, reach: float | None = None) -> _Refinement | None:
    """The start, the grids, the NLP (built, or None when its build does not fit the time left), its parameters and
    bounds, the sharp polish's verifier, the objective's level: what the solves need."""
    spec = ev.spec
    x0 = space.params(v0)
    try:
        ctrl0 = ev.st.tf(x0, ev.dt)
    except (ValueError, ArithmeticError) as e:
        res.status = f"start not usable: {e}"
        return None
    start = start or Start.of(ev, x0)
    incumbent = incumbent if spec.objective == "settling_time" else None
    # (the settling time's bisection judges every step by the batch, and a finer step would cut its horizon: PID on
    # the thesis pitch model 0.204 s against 0.195 s; the other objectives take the NLP's answer as it is)
    c_fast = float(np.max(np.abs(ctrl0.zpk.poles), initial=0.0)) \
        if ev.dt is None and spec.objective != "settling_time" else 0.0
    reach = reach if spec.objective == "settling_time" and incumbent is None and reach is not None and \
        math.isfinite(reach) and reach > 0 else None
    grid, coarse, headed, sharp, same = _grids(ev, space, start, incumbent, fine, detail, c_fast, reach)
    if same and not _resolves_peak(start, grid):
        res.status = "the fine grid is the coarse one"
        return None
    if ev.dt is not None and any(build_loop(p, ctrl0).plant_ct is None for p in ev.problem.plants):
        # a plant known only at the samples (e.g. a cascade's composite plant): constrain the samples
        grid, headed = _Grid(K=grid.K, N=1, step=grid.step, h=None), None
    data = _plant_data(ev, start, ctrl0, grid, space.w0)
    key = _key(ev, space, data, grid, solver, sharp)
    est = 0.0 if is_built(key) else estimated_build_s(key, len(space.structure.params))
    if deadline is not None and est and time.perf_counter() + est > (deadline if build_cap is None else build_cap):
        res.status = "no time left to build this NLP"  # its cost is known before it starts
        res.unbuilt_s = est
        return None
    b0 = build_seconds()
    prob = get_problem(key, space.structure, space)
    if deadline is not None and build_cap is not None:  # (the build is not the search's time)
        deadline = min(deadline + build_seconds() - b0, build_cap)
    values = _values(ev, space, grid, data, key)
    xs, lbx, ubx = _box(prob, space, x0, data, values["band"], _wmax(ev, space.w0), spec.crossover_rad_s)
    _integral_sign(ev, space, prob, x0, lbx, ubx)
    xs = np.clip(xs, lbx, ubx)
    solve = _Solves(prob, values, grid, lbx, ubx, res, solver)
    r = _Refinement(ev=ev, space=space, res=res, deadline=deadline, start=start, incumbent=incumbent, fine=fine,
                    grid=grid, coarse=coarse, headed=headed, sharp=sharp, same=same, key=key, prob=prob,
                    values=values, xs=xs, solve=solve)
    if sharp:
        # its settling times between the grid's points take the bisection to the very edge of what the NLP holds,
        # with no slack left for what it does not see: a peak between the grid's points or at a fractional delay's
        # input switch (a PI at 2.0000 % on the grid, 2.0007 % there: the band left again, 0.404 s for the 0.327 s
        # asked), a second gain crossover (a pid_z on a lightly damped plant: 29.6 degrees there, which the batch's
        # grid missed too), a slow unstable pole past the horizon; the full verifier decides, and a solution it does
        # not confirm is not bisected on
        full = Evaluator(list(ev.problem.plants), ev.st, ev.dt, spec, w0=space.w0,
                         specs=[q.model_copy(update={"objective": spec.objective}) for q in ev.problem.specs])

        def accept(x: np.ndarray, ts: float) -> bool:
            s = full.score(space.params(r.to_search(x)))
            return s.feasible and s.score <= ts + grid.spacing(ts)

        solve.accept = accept
    if spec.objective in ("mks", "disk_margin"):  # the slack is the level of the peak (the objective)
        mks0, dm0 = _peaks(ev, ctrl0)
        lvl0 = mks0 * 1.01 if spec.objective == "mks" else max(min(dm0, 1.99) * 0.99, 1e-3)
        solve.lbx[solve.slack], solve.ubx[solve.slack] = (0.0, max(1e3 * lvl0, 1e-300)) \
            if spec.objective == "mks" else (0.0, 2.0)
        xs[solve.slack] = lvl0 if math.isfinite(lvl0) else 1.0
    elif spec.objective != "settling_time":
        solve.lbx[solve.slack] = solve.ubx[solve.slack] = 0.0  # the slack is the settling objective's alone
    return r


def _settling_time(r: _Refinement, above: float | None = None) -> None:
    """The settling-time objective: bisection on the settling time from the target (the incumbent's, or the start's),
    then, on a polish, on at the looser overshoot limit where that limit is active (``above``: see :func:`refine`)."""
    solve, values, grid, xs = r.solve, r.values, r.grid, r.xs
    target = _target(r.start, r.incumbent)
    near = r.incumbent is not None and target == r.incumbent and float(np.max(r.start.settle)) > r.incumbent
    # a polish starts from a refinement's end: the fine grid's optimum is within a step or two of the coarse grid's
    lo_step = POLISH_STEPS * r.coarse.step / r.coarse.N if r.fine else None
    out = (target, xs) if r.same else r.bisect(target, xs, near=near, lo_step=lo_step, above=above)
    if r.sharp:
        if out is None and not r.out_of_time() and (r.headed is not None or
                                                    solve.overshoot(xs) >= 0.999 * values["os"]):
            # the incumbent overshoots more than the tight limit allows (a coarser grid missed its peak): not even its
            # own settling time is feasible at that limit; the looser one below starts from it
            out = (target, xs)
        if out is not None and not r.out_of_time() and solve.overshoot(out[1]) >= 0.999 * values["os"]:
            loose = _measured_os(r.ev, r.space, r.to_search(out[1]), solve.overshoot(out[1]))
            if loose is not None and loose > values["os"]:  # the overshoot limit is active: bisect on at the looser one
                values["os"] = loose
                r.bisect(out[0], out[1], near=True)
    elif r.fine and out is not None and _resolves_peak(r.start, grid) and not r.out_of_time():
        hi, best = out
        # the overshoot limit is active (and, on a head grid, the peak within the head): bisect on at the looser one
        if solve.overshoot(best) >= 0.999 * values["os"] and \
                (not grid.head or solve.peak_time(best) < grid.head * grid.step):
            values["os"] *= _TIGHT_OS_FINE / _TIGHT_OS
            r.bisect(hi, best, near=True)
    elif out is None and r.headed is not None and not r.out_of_time() and \
            (not grid.head or solve.peak_time(xs) < grid.head * grid.step):
        # the coarse grid missed the peak this one resolves: the incumbent can be above the tight limit here (pid_z at
        # wc dt = 0.5: 9.869 % against 9.851 %), and only the looser one leaves it room
        values["os"] *= _TIGHT_OS_FINE / _TIGHT_OS
        r.bisect(target, xs, near=True)


def _measured_os(ev: BatchEvaluator, space: Space, v: np.ndarray, on_grid: float) -> float | None:
    """The sharp polish's overshoot limit near a solution ``v`` whose overshoot ``on_grid`` (on the NLP's grid) is at
    the tight limit: the batch's own limit (what a candidate must pass) ``_TIGHT_OS_FINE`` inside, less twice what
    the batch's points see above the NLP's at ``v`` (its peak between the NLP's points). Measured, not inferred
    from the crossover's phase per grid step (:func:`_resolves_peak`): a PI on an unstable plant at wc dt = 0.87 and
    8 points a sample peaks at a sample instant, which every grid holds (9.85 % at the tight limit, 18.82 s; 9.895 %,
    18.68 s). None if the batch cannot tell."""
    r = _judged(ev, space.params(v)[None])
    seen = float(r.metrics["overshoot_pct"][0]) / 100.0
    if not math.isfinite(seen):
        return None
    limit = ev.spec.overshoot_max_pct / 100.0 * GUARD["overshoot"]
    return min(limit * _TIGHT_OS_FINE - 2.0 * max(0.0, seen - on_grid), 10.0)


def _bisect(solve: _Solves, ev: BatchEvaluator, space: Space, settle: float, grid: _Grid, xs: np.ndarray,
            res: RefineResult, to_search: Any, out_of_time: Any, exchange: Any, near: bool = False,
            lo_step: float | None = None, above: float | None = None) -> tuple[float, np.ndarray] | None:
    """Bisection on Ts from ``settle`` (feasible at hi, infeasible at lo); every feasible solution is a
    candidate. ``near``: ``settle`` is an incumbent's, the optimum is probably close below it; ``lo_step``: it is
    probably within this much below (a polish: the coarse grid's resolution). Either lower end is a guess, widened
    to 0.3 hi if the bisection reaches it untested. ``above``: stop at the first infeasible solve above this (see
    :func:`refine`). Returns the last feasible settling time and solution (None if the first solve was not
    feasible)."""
    tgrid = grid.t
    hi = settle if math.isfinite(settle) and settle < tgrid[-1] else 0.9 * tgrid[-1]
    r = None
    if not near and lo_step is None and math.isfinite(settle) and settle < tgrid[-1]:
        # the first solve a little below the start's own settling time: at that time itself it maximises the band's
        # slack, and the most robust point can lie in another basin (PI on a lightly damped plant: from Kp 0.50,
        # Ki 1.13, settling 6.69 s, to Kp -0.23 and 5.80 s; asked for 6.36 s it stays, and ends at 5.69 s)
        r = solve(FIRST * hi, xs)
        if r is not None and r[0] >= 0:
            hi = FIRST * hi
        else:
            if r is not None:
                res.candidates.append(to_search(r[1]))
            r = None
    if r is None:
        r = solve(hi, xs)
    if r is None:
        return None
    res.candidates.append(to_search(r[1]))
    if r[0] < 0:
        return None
    best = exchange(r[1], hi)
    res.candidates.append(to_search(best))
    s_hi = float(best[solve.slack]) if solve.last_ok else None  # (the slack at hi, where known; at lo, below)
    ts_nlp = solve.settles_at(best)
    if 0 < ts_nlp < hi:
        hi, s_hi = ts_nlp, None
    # the lower end: a guess near hi when the target is an incumbent (another refinement's local optimum:
    # this one is likely to end near it), widened to 0.3 hi if the bisection reaches the guess untested
    lo, proven = (NEAR * hi, False) if near else (0.3 * hi, True)
    if lo_step is not None and hi - lo_step > lo:
        lo, proven = hi - lo_step, False
    s_lo: float | None = None
    kept = 0  # the secant's steps in a row that moved the same end
    while not out_of_time():
        # the NLP's resolution of Ts: its grid's (the verifier then judges between its points), or a part of it
        on_grid = solve.split == 1
        if hi - lo <= grid.spacing(hi) / solve.split or (on_grid and _grid_gap(tgrid, lo, hi) <= 1):
            if proven:
                break
            lo, proven, s_lo = 0.3 * hi, True, None
            continue
        mid = _grid_step(tgrid, lo, hi, s_lo, s_hi, kept) if on_grid else 0.5 * (lo + hi)
        r = solve(mid, best)
        if r is not None and r[0] >= 0:
            kept = kept + 1 if kept >= 0 else 1
            s_hi = float(r[0])
            hi, best = mid, exchange(r[1], mid)
            res.candidates.append(to_search(best))
            # the solution may settle earlier than asked (on the NLP's grid): jump there; the verifier judges
            # every candidate afterwards
            ts_nlp = solve.settles_at(best)
            if 0 < ts_nlp < hi:
                hi, s_hi = ts_nlp, None
                if hi <= lo:  # lo was a failed solve, not an infeasible problem (or a guess): reopen the bracket
                    if proven and solve.accept is not None:
                        break  # (the sharp polish: lo a solve the verifier refused; the bracket is closed)
                    lo, proven, s_lo = 0.3 * hi, True, None
        else:
            kept = kept - 1 if kept <= 0 else -1
            s_lo = float(r[0]) if r is not None and solve.last_ok and r[0] < 0 else None
            lo, proven = mid, True
            if above is not None and mid > above:
                res.cut = True  # (it can no longer reach the incumbent's value: see refine)
                break
    return hi, best


def _grid_gap(tgrid: np.ndarray, lo: float, hi: float) -> int:
    """How many grid points apart the envelopes asked at ``lo`` and ``hi`` start (each at the first point at or
    after its Ts): at most 1, no Ts between them asks anything new."""
    i_lo, i_hi = np.searchsorted(tgrid, [lo - 1e-12, hi - 1e-12])
    return int(i_hi - i_lo)


def _grid_step(tgrid: np.ndarray, lo: float, hi: float, s_lo: float | None, s_hi: float | None, kept: int
               ) -> float:
    """The bisection's next Ts on the grid: a grid point strictly between the envelopes asked at ``lo`` and ``hi``,
    at the secant of the slacks ``s_lo`` < 0 <= ``s_hi`` where both are known (clamped to SECANT_CLAMP of the
    bracket; the midpoint after two steps in a row that kept one end, ``kept``), else at the middle."""
    i_lo, i_hi = (int(i) for i in np.searchsorted(tgrid, [lo - 1e-12, hi - 1e-12]))
    frac = 0.5
    if s_lo is not None and s_hi is not None and s_hi > s_lo and abs(kept) < 2:
        frac = min(max(-s_lo / (s_hi - s_lo), SECANT_CLAMP), 1.0 - SECANT_CLAMP)
    m = i_lo + int(round(frac * (i_hi - i_lo)))
    return float(tgrid[min(max(m, i_lo + 1), i_hi - 1)])
