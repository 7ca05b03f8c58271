"""The anytime search: rounds of global sampling and local refinement until converged or out of budget.

Round 0 is deterministic (the same for every seed): the structure's plant-based starts, a fixed
space-filling set of points and, for a structure that contains a smaller one (``leadlag`` contains
``lead``; ``pid2`` contains ``pid`` at b = c = 1), the smaller structure's designed starts; all
scored in one batch (:class:`~tuner.optimize.batch.BatchEvaluator`), the best few distinct ones
refined by the CasADi NLP (:mod:`~tuner.optimize.nlp`), a scan around the incumbent, and the incumbent
polished once on the NLP's fine grid (:meth:`Engine._polish`). Later rounds are restarts
(:meth:`Engine._restart`; with ``Effort.optuna`` also Optuna's seeded sampler, told every point scored
so far). The search stops when

* **converged**: the evidence rule holds (:meth:`Engine.evidence`, issue 41: on a principle, not a suite). The
  principle is multistart's Bayesian stopping rule (Boender and Rinnooy Kan, "Bayesian stopping rules for multistart
  global optimization methods", Math. Programming 37 (1987) 59-80): after ``n`` local searches from independent
  random starts have reached ``w`` distinct local optima, the posterior expectation of the total relative volume of
  the regions of attraction not yet reached is ``w (w + 1) / (n (n - 1))``; the search may claim its answer when that
  is at most :data:`UNSEEN_LEVEL`. Its sample is each restart's own draw (:meth:`Engine._restart`): a fresh
  scrambled-Sobol set over the whole box (seeded by the user's seed and the restart: independent draws), the best
  quarter by batch score of its points that meet the spec kept (the reduced sample of multi-level multistart: the
  estimate then speaks of the basins of that level set; where none meets the spec, the best point), one point of it
  picked at random (seeded) and refined to its own local optimum, wherever it lies (``Effort.draw_cutoff``, fast and
  default: only until it can no longer reach the incumbent's value; such a draw is an optimum of its own, never merged
  with another and never a re-find: a claim can only become more cautious). The distinct optima are counted by
  value: two draws reached one optimum when their scores agree within the search's tolerance (half a sample of
  settling time, or 0.1 %), never when their scores differ, however close in the box (infeasible ends: within
  ``Effort.basin`` of each other). The search stops when at least
  ``max(Effort.confirm, Effort.refind)`` restarts ran, the last one found nothing better than that tolerance, and
  the estimate is at most :data:`UNSEEN_LEVEL`; the result claims "converged" only if ``Effort.refind`` of those
  draws also reached the incumbent's value (the draw that first found it does not count). One draw can never make
  the claim; with every draw in one optimum the estimate is 1/3 after 3 draws and 1/6 after 4, so a claim needs at
  least 4 draws (default effort affords 4 restarts, thorough 8); any second optimum reached (better or worse) needs
  more (w = 2: 6 draws, 2·3/(6·5) = 0.2, the level inclusive). It is an estimate of what the draws' distribution
  leaves unexplored, not a bound on whether
  a better design exists: a better basin that random starts of the best quarter seldom reach is missed whatever
  the estimate. Round 0 agreeing with itself (two refinements from distinct starts reaching the same value) ends
  ``effort="fast"``, which claims nothing without a restart. A restart also refines, at
  ``Effort.restart_refines`` > 0, the best candidates outside every basin refined so far (``Effort.restart_spread``:
  those farthest from every point refined; not the rule's sample), scans around an incumbent it has not scanned and
  casts the loop-gain ray from one it has not; or
* **work**: the restarts the effort affords (``Effort.max_restarts``) ran without that evidence: the default
  stopping rule counts work, never seconds, so a seed gives the same steps, and the same gains, on an idle and on a
  loaded machine, for every run the time cap did not cut; or
* **budget**: the time cap (the default budget's wall-clock cap, or an explicit budget, minus what the final
  verification needs) cut the search; ``info.cut`` says which step. Given the seed, the search's steps are one
  fixed sequence whatever the budget and the machine's load: the first step the time left cannot afford (a batch,
  an NLP build, a scan, estimated from its size and the batches before it) ends the search, and nothing is skipped
  for time while a later step runs. The cap is checked between steps: a started step is not interrupted, so a run
  can overrun it by a step; a cut run's gains depend on where it was cut.
  A larger budget therefore runs a longer prefix of the same search, and its
  incumbent is never worse (``tests/tuner/test_budget_prefix.py``); a restart the budget cut short is no evidence
  of convergence.

``info["stop"]`` says which; ``info.optimality`` (:meth:`Engine.optimality`) says what the search knows
about how close its answer is: the basins its refinements ended in, the best distinct alternative and
its gap, the restarts and whether one improved. The final choice is made by the full verifier, never by
the search: the best verified of ``Effort.verify`` finalists.

``effort`` (:data:`EFFORTS`) trades time for confidence: ``fast`` is round 0 alone (its own agreement
ends it), ``default`` adds 4 restarts (the rule cannot hold before the fourth draw) and polishes sharp (at twice
the grid detail), ``thorough`` 4-8 with more starts, points and refinements.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..controllers import get_structure
from ..errors import TunerError
from ..limits import EFFORT_NAMES, INFEASIBLE, OBJECTIVES
from ..problem import TuningProblem
from ..tolerances import REAL_ROOT_TOL, ROOT_AT_DC_TOL
from .batch import BatchEvaluator, Start
from .builds import build_seconds
from .design import initial_guess, slow_poles, zero_variants
from .scoring import Evaluator, Scored
from .search import SeededSearch
from .space import Space, make_space

__all__ = ["Engine", "designed_starts", "NLP_OBJECTIVES", "Effort", "EFFORTS"]

#: the objectives the local NLP states exactly (``nlp.transcribe._objective``); the others (bandwidth) are
#: optimised by the global search alone
NLP_OBJECTIVES = tuple(o.name for o in OBJECTIVES if o.nlp)

log = logging.getLogger(__name__)

DESIGN_SEED = 20261201  # fixed: round 0 does not depend on the user's seed
SCAN_SEED = 20261202
GAIN_DECADES = (0.0, -0.25, 0.25, -0.5, 0.5, -1.0, -1.5)  # the designed starts' gains, in decades of the guess
PROJECTION_SHRINK = (1e-2, 1e-4)  # the projections' shrunk gains (see Engine._projections)
# the ray's loop gains (Engine._ray), in decades: geometric towards the incumbent (an optimum on the edge where the
# overshoot reaches the band is often a fraction of a percent of gain away: a PD on 0.46/(s (5.3 s + 1)) at 1.902 %
# overshoot, 1.384 s, and 1.372 s at 2.0 %, 0.0016 decades further) and coarse further out
RAY_DECADES = tuple(sorted({sgn * 0.04 * 2.0 ** -k for k in range(7) for sgn in (-1.0, 1.0)}
                           | {-0.32, -0.24, -0.16, 0.16, 0.24}))
# a distinct basin within this of the incumbent (relative) leaves its convergence not confirmed (Engine.optimality)
CLAIM_RIVAL = 0.01
CLAIM_MOVED = 1e-3  # ... and an incumbent that improved by more than this (relative) after round 0
# the finalists' parameters are rounded to this many significant digits before the verifier judges them (issue 41,
# the same answer on either batch path): the compiled kernels and the numpy path score a candidate alike to 1e-10
# (the settling time's interpolation) and their refinements end alike to about 1e-14, so the verified answer is
# bitwise the same on both unless a parameter falls within ~1e-14 of a rounding boundary (about 1e-4 a parameter)
ANSWER_DIGITS = 10
# ... and what a refinement starts from (the start's batch figures, the incumbent's settling time) to this many: the
# refinement's grid (its horizon, points per sample) follows them, and a figure a rounding's width apart on the two
# paths must not give two grids
INPUT_DIGITS = 7


def _sig(a: float, digits: int) -> float:
    """``a`` rounded to ``digits`` significant digits (non-finite: as is)."""
    return float(f"{a:.{digits}g}") if math.isfinite(a) else a


def _decimal(x: np.ndarray) -> np.ndarray:
    """``x`` rounded to :data:`ANSWER_DIGITS` significant digits (decimal: what the answer prints is what was
    verified)."""
    return np.array([float(f"{a:.{ANSWER_DIGITS}g}") for a in np.asarray(x, float)])
# a restart's own refinement (the evidence rule's draw) runs on the NLP grid of a loop settling in this many times the
# incumbent's settling time (refine's ``reach``: its horizon three times that), whatever its start's settling time: one
# problem shape for every restart of every seed (round 0 is the same for all seeds, so is its incumbent), which a warm
# process builds once. A basin that settles later than that is no rival; a start settling later is asked first to
# settle within 0.9 of the horizon, and its refinement's end is scored by the batch as every draw's is
OWN_REACH = 4.0
REPRICE_POINTS = 4  # points a step's price is measured again on before the step is refused for time (Engine._repriced)


@dataclass(frozen=True)
class Effort:
    """How hard a tune searches (``tune(..., effort=)``, CLI ``--effort``): see the module docstring."""

    name: str
    n_starts: int  # round 0's refinements from distinct candidates
    design_points: int  # round 0's fixed space-filling set
    confirm: int  # restarts at least before the evidence rule may stop the search (0: round 0's agreement ends it)
    restart_points: int  # scrambled-Sobol points over the whole box per restart
    restart_refines: int  # refinements per restart (the best candidates outside every refined basin; restart_spread)
    verify: int  # finalists verified at full resolution; the best verified wins
    optuna: bool  # restarts also ask Optuna's seeded sampler (told every point so far) for a batch
    # the NLP grid's detail (refine's ``detail``): thorough resolves the polish to ~0.25 %, not 1 %, and from 2 on the
    # polish is sharp (its settling time between the grid's points, its overshoot margin measured)
    detail: int = 1
    # the fine polish's own detail (0: ``detail``). default polishes at 2 (sharp, at twice the grid detail) while its
    # other refinements stay at 1: at 1 the polish resolves the settling time to about 1 %, the very tolerance
    # "within 1 % of the optimum" is judged by, so an answer in the optimum's basin fell 1.0-1.8 % short by
    # resolution alone (bench/convergence.py's intdelay4-02, -10, -16 at default, design part). Measured on the
    # convergence suite's design part (332 cases with a reference, the same run, bench/polish_detail_ab.py,
    # bench/results/polish_detail_ab_design_stop46.txt): within 1 % 328 -> 331, better by more than 0.1 % on 235
    # cases, worse on 2 (underdamped-30 +0.15 %, nmp-28 +0.5 %); warm CPU on the README's loops -1 to +23 %
    # (bench/results/warm_speed_issue41_stop46.md). thorough is sharp throughout (``detail`` 2)
    polish_detail: int = 0
    # -- the search's other constants, the same at every effort today (one place: here) --------------------------
    patience: int = 1  # rounds in a row without improvement that end an Optuna-only search (no local stage)
    extra_verify: int = 12  # finalists verified beyond ``verify`` when none of those is feasible
    stale_refines: int = 2  # refinements in a row that did not improve on the best: round 0 has converged
    round_trials: int = 24  # Optuna points per restart (where Optuna is asked; ``tune(n_trials=)`` overrides)
    # the local scan around the incumbent after round 0's refinements (see Engine._scan): a fixed cloud
    scan_points: int = 96
    scan_decades: float = 0.3  # half-width per coordinate, in the search's coordinates (decades for gains and times)
    ray_zooms: int = 2  # the ray's zooms around its best factor (Engine._ray)
    ray_checks: int = 3  # ray points verified at full resolution per level, at most (Engine._ray)
    basin: float = 0.05  # refinements ending closer than this (norm over the box's span) are one basin
    infeasible_extra: int = 2  # an infeasible incumbent must survive this many more restarts before "converged"
    # a restart refines the restart_refines of its best restart_refines + this many distinct unrefined candidates (round
    # 0's included; only the feasible ones where the best is) that lie farthest from every refined point (0: simply the
    # best): a lone refinement spent on the best-scoring candidate beside a start already refined tends to end in that
    # start's basin again (a PID on a non-minimum-phase plant, bench/convergence.py's nmp-19: round 0's starts with
    # the derivative filter at Td / 10 and Td / 3 end in one basin, 5.9 % above the one its Tf = Td start reaches,
    # which scores a little worse before its refinement). fast and default: 3; thorough's three refinements a
    # restart take the best (0): on the convergence suite the spread there lost a 2-DOF basin (twodof-14, 9 %) and
    # found nothing its round 0's five starts had not
    restart_spread: int = 0
    # -- the evidence rule (see the module docstring and Engine.evidence) -------------------------------------------
    refind: int = 2  # restarts whose own draw must re-find the incumbent's value before "converged"
    # the work budget: restarts after round 0 at most (the default stopping rule counts work); the rule's estimate
    # w (w + 1) / (n (n - 1)) needs n >= 4 draws to reach UNSEEN_LEVEL at all, so an effort that may claim affords 4
    max_restarts: int = 6
    # the reduced sample a restart's draw starts from: a random one of the best this share of its Sobol points
    draw_share: float = 0.25
    # a draw's refinement stops at its first failed solve above the incumbent's value (plus the tolerance): from there
    # it seldom reaches that value (only where a later solution settles earlier than asked and the bisection re-opens
    # its bracket), and mostly only resolves its own, worse optimum's value. Such a draw is counted as an optimum of its
    # own (never merged with another draw's, never a re-find), so the rule's estimate can only grow and a claim only
    # become more cautious, never easier: PI on 1/(s+1)^3 at dt 0.1, seed 1, whose cut draw would have re-opened and
    # ended at the incumbent's value, says "not confirmed" where the full draw lets it say "converged" (the same
    # gains). thorough (8 draws, where two draws in one slower optimum still allow a claim) resolves every draw
    draw_cutoff: bool = False


#: the stated level of the evidence rule: "converged" only where the posterior expected relative volume of the regions
#: of attraction no restart's draw has reached (Boender and Rinnooy Kan 1987: w (w + 1) / (n (n - 1)) after n draws
#: reached w distinct optima; an estimate of what the draws' distribution leaves unexplored, not a bound on whether a
#: better basin exists) is at most this
UNSEEN_LEVEL = 0.2

EFFORTS = {
    "fast": Effort("fast", n_starts=2, design_points=32, confirm=0, restart_points=32, restart_refines=1, verify=1,
                   optuna=True, restart_spread=3, max_restarts=4, draw_cutoff=True),
    # default: two round-0 refinements and one per restart cost 30 % less than three and two, and on every fourth
    # suite case changed no ratio by more than 0.3 % (bench/QUALITY.md)
    "default": Effort("default", n_starts=2, design_points=48, confirm=1, restart_points=64,
                      restart_refines=1, verify=2, optuna=False, restart_spread=3, max_restarts=4, draw_cutoff=True,
                      polish_detail=2),
    "thorough": Effort("thorough", n_starts=5, design_points=128, confirm=3, restart_points=128, restart_refines=3,
                       verify=5, optuna=True, detail=2, refind=3, max_restarts=8),
}
assert tuple(EFFORTS) == EFFORT_NAMES  # (the registry lists them for the interfaces)


def designed_starts(space: Space, plant, dt: float | None, *, variants: bool = False, spec: Any = None
                    ) -> list[np.ndarray]:
    """Plant-based starts: the structure's initial guess with all gains scaled by 10^-1.5 ... 10^0.5
    (most loops are stable somewhere on that ray); ``variants``: the same for each placement of the
    controller's zeros of :func:`~tuner.optimize.design.zero_variants` (the first is the classic one)."""
    st = space.structure
    scale = (space.k0, space.w0)
    zs = zero_variants(plant, dt, space.w0) if variants else [None]
    if variants:
        zs = zs + _unstable_variants(plant, dt, space.w0)
        if st.integrating:
            zs = zs + _integrator_variants(plant, dt, space.w0)
    guesses = []
    for zeros in zs:
        with np.errstate(all="ignore"):
            g = initial_guess(st, plant, dt, scale=scale, zeros=zeros, spec=spec)
        x0 = np.array([g[p] for p in st.params])
        if np.all(np.isfinite(x0)) and not any(np.allclose(x0, g0, rtol=1e-9, atol=0) for g0 in guesses):
            guesses.append(x0)  # placements a structure cannot tell apart (one zero) only once
    starts = []
    for decades in GAIN_DECADES:  # every placement at the nominal gain first
        for x0 in guesses:
            x = x0.copy()
            for i, kind in enumerate(st.kinds):
                if kind == "gain":
                    x[i] *= 10.0 ** decades
            starts.append(space.from_params(x))
    if variants:
        starts += _filter_variants(space, guesses)
        starts += _filter_variants(space, guesses, negative_p=True)
        starts += _negative_p_variants(space, guesses)
    return starts


# derivative filters of the filtered starts: Tf = Td / N (Td = Kd / Kp), on a half-decade grid from the textbook's
# N = 10 to N = 0.3 (a start's Tf is clipped to the space's bound, where N = 0.3 often lands). N <= 1 is the lag form
# (Tf >= Td: above 1/Tf the controller's gain is Kp + Kd / Tf, a lead-lag rather than a derivative). A PID on a
# non-minimum-phase plant, zero at +13.9 rad/s, poles at -6.3 and -27 rad/s, dt 0.02 (bench/convergence.py's nmp-19),
# settles in 0.268 s with Tf = 0.107 s = 2.7 Td, against 0.284 s in the basin every textbook filter (N = 3 ... 10)
# refines into. Another, its zero at +0.057 rad/s just below its poles at -0.061 and -0.068 rad/s (nmpfast-19, dt
# 0.6466), settles in 66.33 s with Tf = 2.1 Td, which no start down to N = 1 refined into (69.04 s, Tf at its floor);
# N = 0.3 (stop 49) reaches it. Measured with bench/filter_n_ab.py (bench/results/filter_n_ab_*_stop49.txt): on the
# convergence suite's design part 331 -> 332 of 332 within 1 %, none worse by more than 0.1 %; on issue 41's held-out
# part (no longer held out: nmpfast-19 is in it) nmpfast-19 1.041 -> 1.000 but nmpneg-07 1.000 -> 1.011 (another
# start took the refinement that found its optimum: at two refinements in round 0 more starts are not monotone); on a
# fresh part drawn before the change (fresh2) no result changed
FILTER_N = (10.0, 3.0, 1.0, 0.3)
FILTER_DECADES = (0.0, -0.5)
NEGATIVE_P = 0.3  # the PI's negative-proportional starts: Kp = -NEGATIVE_P times the designed start's (see below)


def _filter_variants(space: Space, guesses: list[np.ndarray], *, negative_p: bool = False) -> list[np.ndarray]:
    """The designed starts again with the derivative filter Tf = Td / N (FILTER_N: textbook practice, and the lag
    form N <= 1) instead of at its floor: under a noise limit (Mks) the optimum's filter is slow (the pitch model with
    Mks <= 20, IAE: Tf = 0.034 s at dt = 0.04, IAE 0.072, where every floor-filter start ends near 0.25), a long move
    in the search's logarithmic Tf for a refinement. ``negative_p``: the same with the proportional gain's sign flipped
    (the ID-like controllers of lightly damped plants: under the filter rule N = Kd / (|Kp| Tf) <= 20 the optimum
    can have Kp < 0, a region the positive-Kp starts reach only through a long detour in Tf; underdamped pid with
    the default limits: 1.10 s there, 4.01 s the best with Kp > 0)."""
    st = space.structure
    if "Tf" not in st.params or "Kd" not in st.params or "Kp" not in st.params:
        return []
    if negative_p:
        out = []
        for v in _filter_variants(space, guesses):
            x = space.params(v)
            x[st.params.index("Kp")] *= -1.0
            out.append(np.clip(space.from_params(x), space.lo, space.hi))
        return out
    i_tf, i_kd, i_kp = st.params.index("Tf"), st.params.index("Kd"), st.params.index("Kp")
    out = []
    for decades in FILTER_DECADES:
        for x0 in guesses:
            if not (x0[i_kp] != 0 and x0[i_kd] / x0[i_kp] > 0):
                continue
            for n in FILTER_N:
                x = x0.copy()
                for i, kind in enumerate(st.kinds):
                    if kind == "gain":
                        x[i] *= 10.0 ** decades
                x[i_tf] = max(x0[i_tf], x0[i_kd] / x0[i_kp] / n)
                v = space.from_params(x)
                out.append(np.clip(v, space.lo, space.hi))
    return out


def _negative_p_variants(space: Space, guesses: list[np.ndarray]) -> list[np.ndarray]:
    """A controller with a proportional and an integral gain but no derivative (a PI): the nominal-gain designed starts
    (one per placement of the zero) with the proportional gain's sign flipped, at NEGATIVE_P of its magnitude. On a
    lightly damped plant the optimum can be an integral controller whose Kp has the other sign than the designed
    starts' (the PID's are in :func:`_filter_variants`), a basin those starts do not refine into: a PI on a
    third-order plant with lightly damped poles at dt 0.035 (bench/convergence.py's underdamped-31) settles in 21.9 s at
    Kp -0.53, Ki 0.20, against 23.2 s the best with Kp > 0; each of its five starts flipped at 0.3 refines there (at
    full magnitude too, but four of them score 1000-4800 before their refinement, too badly for round 0 to refine)."""
    st = space.structure
    if "Kp" not in st.params or st.integral not in st.params or "Kd" in st.params:
        return []
    i_kp = st.params.index("Kp")
    out = []
    for x0 in guesses:
        x = x0.copy()
        x[i_kp] *= -NEGATIVE_P
        out.append(np.clip(space.from_params(x), space.lo, space.hi))
    return out


VANISHING_ZERO = 1e-4  # the vanishing integral's zero, as a fraction of the plant's slowest pole (or w0)


def _integrator_variants(plant, dt: float | None, w0: float) -> list[np.ndarray]:
    """Zero placements for a controller with an integral on a plant that already has one (K/(s(tau s + 1))): one
    zero at VANISHING_ZERO of the loop's scale, the other on the slowest pole or far. The loop has zero steady-state
    error without the controller's integral, and under a phase-margin limit the optimum is a P (PD) with a vanishing
    integral: a PI zero anywhere near the crossover costs phase (the loop is type 2) and leaves a slow closed-loop
    pole whose tail (residue about Ki / (K Kp^2)) keeps the response out of the band for many settling times; the
    optimum is the plateau where that residue is inside the band (PI on 0.45/(s (6.1 s + 1)): Kp 0.146, Ki ~ 0,
    34.6 s; every other placement's start, the zero at the plant's pole or near w0, settles in hundreds of
    seconds or not at all, and the logarithmic gain coordinate makes Ki -> 0 a long move)."""
    poles = np.asarray(plant.poles, dtype=complex)
    at = 1.0 if plant.dt is not None else 0.0
    if not poles.size or not np.any(np.abs(poles - at) <= ROOT_AT_DC_TOL * max(1.0, float(np.max(np.abs(poles))))):
        return []
    p1 = slow_poles(plant, w0)[0]
    p1 = p1 if abs(p1.imag) <= REAL_ROOT_TOL * max(1.0, abs(p1)) else complex(-abs(p1))
    eps = VANISHING_ZERO * min(abs(p1), w0)
    far = -np.inf if dt is not None else -10.0 * w0
    return [np.array([-eps, p1], dtype=complex), np.array([-eps, far], dtype=complex)]


def _unstable_variants(plant, dt: float | None, w0: float) -> list[np.ndarray]:
    """Zero placements for an open-loop unstable plant: on the mirror image of its slowest unstable pole (a PI
    on 1/(s - 1) meets the spec with its zero near s = -1; the stable-pole placements put it at 0.3 w0, 12 times
    further, where every start overshoots 26 %), alone (the other zero far) and doubled; and the mirror with the
    other zero inside the slowest stable pole, at 0.7 and 0.5 of it (a two-zero controller on a plant with poles
    +1.8 and -35 rad/s: every other placement overshoots 12-60 % along the whole gain ray, these meet the spec;
    the optimum has its zeros at -3.5 and -20)."""
    poles = np.asarray(plant.poles, dtype=complex)
    if plant.dt is not None:
        poles = np.log(poles[np.abs(poles) > 1e-12]) / plant.dt
    rhp = sorted((p for p in poles if p.real > 1e-9 * max(1.0, abs(p))), key=abs)
    if not rhp:
        return []
    r = abs(rhp[0])
    far = -np.inf if dt is not None else -10.0 * r
    p1 = complex(-abs(slow_poles(plant, w0)[0]))
    return [np.array([-r, far], dtype=complex), np.array([-r, -r], dtype=complex),
            np.array([-0.5 * r, far], dtype=complex), np.array([-r, 0.7 * p1], dtype=complex),
            np.array([-r, 0.5 * p1], dtype=complex)]


#: the smaller structure a structure contains (:func:`_contained`: its answer seeds the larger one's search)
CONTAINS = {"leadlag": "lead", "pid2": "pid"}


def _contained(problem: TuningProblem) -> tuple[str, Any] | None:
    """The smaller structure this one contains, and the map of its gains into this one's parameters.

    (A ``pid`` at ``dt`` contains ``pid_z``, but needs no seeding: its own designed starts, zeros on the
    zero-order-hold plant's poles and Tf at the floor, are exactly ``pid_z``'s.)"""
    if problem.structure.name == "leadlag":
        def from_lead(g: dict[str, float]) -> dict[str, float]:
            return {"K": g["K"], "wz1": g["wz"], "wp1": g["wp"], "wz2": 1.001 * g["wz"], "wp2": g["wz"]}
        return CONTAINS["leadlag"], from_lead
    if problem.structure.name == "pid2":
        # pid2 contains pid at b = c = 1: pid's own starts exactly, and the same with setpoint weights
        def from_pid(g: dict[str, float]) -> list[dict[str, float]]:
            return [{**g, "b": b, "c": c} for b, c in PID2_WEIGHT_SEEDS]
        return CONTAINS["pid2"], from_pid
    return None


#: structures whose search first runs the contained structure's whole search (:meth:`Engine._contained_answer`)
FULL_CONTAINMENT = ("pid2",)
CONTAINED_SHARE = 0.9  # of the time left: the contained search (the guarantee) runs as a tune of it would; a
                       # budget-bound one leaves pid2 little more than its answer
#: the (b, c) given to pid's designed starts as pid2's seeds: pid itself first, then D on the measurement with
#: full and half proportional setpoint weight
PID2_WEIGHT_SEEDS = ((1.0, 1.0), (1.0, 0.0), (0.5, 0.0))


@dataclass
class _Best:
    score: float = math.inf
    v: np.ndarray | None = None


@dataclass
class RunInfo:
    """The search's record (rounds, why it stopped, evaluation and NLP counts): ``TuneResult.solver``."""

    rounds: int = 0
    stop: str = "budget"
    batch_evaluations: int = 0
    starts_refined: int = 0
    nlp_solves: int = 0
    nlp_iterations: int = 0
    nlp_evaluations: int = 0
    nlp_solves_ok: int = 0
    seeded_from: str | None = None
    history: list[float] = field(default_factory=list)
    unbuilt_s: float = 0.0  # the estimated build time of an NLP the budget could not afford (0: none refused)
    contained_nlp_solves: int = 0  # the contained structure's search's NLP solves (pid2's pid), not counted above
    notes: list[str] = field(default_factory=list)  # what the user should know of this search (shown with the result)
    #: the step the time cap (or an explicit time budget) cut, when one did (stop = "budget"); None otherwise
    cut: str | None = None


class Engine:
    """One tune's search (see the module docstring); :meth:`run` returns the candidates to verify."""

    def __init__(self, problem: TuningProblem, *, seed: int, deadline: float, solver: str = "sqp", local: bool = True,
                 n_starts: int | None = None, n_trials: int | None = None, sampler: Any = None,
                 storage: Any = None, reserve_s: float = 0.0, effort: str | Effort = "default",
                 seeds: list[np.ndarray] | None = None, build_cap: float | None = None,
                 built0: float | None = None, max_restarts: int | None = None) -> None:
        self.problem = problem
        self.space = make_space(problem.structure, problem.nominal, problem.dt, scale=problem.scale,
                                nyquist=problem.spec.filter_nyquist)
        self.ev = Evaluator(list(problem.plants), problem.structure, problem.dt, problem.spec, w0=self.space.w0,
                            specs=problem.specs)
        self.batch = BatchEvaluator(problem, self.space)
        # the local stage states the objectives it optimises exactly (the others: the global search alone)
        self.seed, self._deadline, self.solver = seed, deadline, solver
        # the default budget (``tune(time_budget_s=None)``): the NLP builds do not count against ``deadline`` (it moves
        # on by their time), only against this wall-clock cap; None: ``deadline`` is the wall-clock limit
        self.build_cap = build_cap
        self._built0 = build_seconds() if built0 is None else built0  # (the tune's start: nested tunes' builds)
        self.local = local and problem.spec.objective in NLP_OBJECTIVES
        self.effort = effort if isinstance(effort, Effort) else EFFORTS[effort]
        self.n_starts = self.effort.n_starts if n_starts is None else n_starts
        self.n_trials = n_trials
        self.refined: list[tuple[float, np.ndarray]] = []  # where each refinement ended (its best candidate)
        self.restarts = 0
        self.restart_improved = 0  # restarts that improved the incumbent by more than the tolerance
        self.round0_best = math.inf
        self._polished: set[bytes] = set()
        self.sampler, self.storage = sampler, storage
        # Optuna's seeded sampler acts in the restarts where the effort asks for it, where there is no local stage
        # (its only way to home in), and wherever the caller asked for it (a number of points, a sampler); a storage
        # only records what was scored
        self._asks_optuna = self.effort.optuna or not self.local or n_trials is not None or sampler is not None
        self.reserve_s = reserve_s
        self.info = RunInfo()
        self.pool: list[tuple[float, np.ndarray, bool]] = []  # (batch score, coordinates, refined?)
        # parameter vectors the caller already knows meet the spec (a robustness objective's fastest design): they lead
        # round 0, so its refinements start from a feasible point
        self._given = [self.space.from_params(np.asarray(x, float)) for x in (seeds or [])]
        self.best = _Best()
        self._search: SeededSearch | None = None
        self._per_point = 0.0  # seconds per point of the last batch
        # set by the first step the time left cannot afford: every later step is refused too, so that a budget only
        # ever cuts the search's fixed sequence of steps short (a larger budget runs a longer prefix of the same
        # search, never a different one; see :meth:`_time_left`)
        self._exhausted = False
        # what the batch said about each pooled point (refine's start): its batch result and row, read when refined
        self._starts: dict[bytes, tuple[Any, int]] = {}
        # the evidence rule's sample: where each restart's refinements ended (restart number, score, coordinates)
        # (restart number, score, coordinates, resolved: False where Effort.draw_cutoff stopped it above the incumbent)
        self.restart_ends: list[tuple[int, float, np.ndarray, bool]] = []
        self._step = "round 0"  # the step running (what a cut says it cut)
        self._rayed: bytes | None = None  # the incumbent the loop-gain ray last started from
        self._scanned: bytes | None = None  # the incumbent a restart's scan last searched around
        self._in_restart = False  # a restart's own refinements run (they are the evidence rule's sample)
        self._round0_refined = 0  # refinements before the first restart (self.refined[:this])
        self._max_restarts = self.effort.max_restarts if max_restarts is None else max_restarts

    # -- bookkeeping ------------------------------------------------------------------------------

    @property
    def deadline(self) -> float:
        """The search's deadline: the given one, moved on by the NLP builds' time where a build cap is set."""
        if self.build_cap is None:
            return self._deadline
        return min(self._deadline + build_seconds() - self._built0, self.build_cap)

    @property
    def build_s(self) -> float:
        """Seconds this search has spent building NLPs."""
        return build_seconds() - self._built0

    def _time_left(self) -> float:
        """The search's time left (the final verification's reserve excluded); <= 0 from the first step that did
        not fit on: a step is never skipped for time while a later one runs, so what a budget decides is only
        where the search's sequence of steps (the same for every budget, given the seed) ends."""
        if self._exhausted:
            return -1.0
        left = self.deadline - self.reserve_s - time.perf_counter()
        if left <= 0:
            self._exhaust()
        return left

    def _exhaust(self) -> None:
        """A step did not fit in the time left: the search ends here (see :meth:`_time_left`), and says what it cut."""
        if not self._exhausted:
            self.info.cut = self._step
        self._exhausted = True

    def _score(self, V: np.ndarray, *, source: str, refined: bool = False) -> np.ndarray:
        """Batch-score coordinates, add them to the pool, track the best (non-finite points are dropped)."""
        V = np.atleast_2d(np.asarray(V, dtype=float)) if len(V) else np.zeros((0, self.space.lo.size))
        V = V[np.all(np.isfinite(V), axis=1)]
        if len(V) == 0:
            return np.zeros(0)
        X = np.array([self.space.params(v) for v in V])
        t0 = time.perf_counter()
        inc = self.best.score if self._settling else None
        r = self.batch.evaluate(X, incumbent_s=inc)
        if inc is not None:
            # the incumbent bounds the simulated horizon (3 times its settling time): a candidate that settles
            # earlier and leaves the band again after that horizon would look better than it is; whatever
            # would beat the incumbent is scored again over its own horizon
            j = np.flatnonzero(r.score < inc)
            if j.size:
                r2 = self.batch.evaluate(X[j])
                r.score[j] = r2.score
                for a, b in zip(r.per_plant, r2.per_plant):
                    for key in ("settling_time_s", "wc", "wp", "horizon_s"):
                        if key in a and key in b:
                            a[key][j] = b[key]
        self._per_point = (time.perf_counter() - t0) / len(V)
        self.info.batch_evaluations += len(V)
        for j, (v, s) in enumerate(zip(V, r.score)):
            v = np.asarray(v, float)
            self.pool.append((float(s), v, refined))
            self._starts[v.tobytes()] = (r, j)
            if s < self.best.score:
                self.best = _Best(float(s), v)
        return r.score

    def _start(self, v: np.ndarray, digits: int | None = None) -> Start | None:
        """What the batch said about the pooled point ``v`` (None if it was not scored here); ``digits``: each figure
        rounded to that many significant digits."""
        row = self._starts.get(v.tobytes())
        if row is None:
            return None
        st = Start.row(*row)
        return st if digits is None else Start(*(np.array([_sig(float(a), digits) for a in f]) for f in
                                                 (st.settle, st.wc, st.wp, st.horizon, st.overshoot)))

    @property
    def _settling(self) -> bool:
        return self.problem.spec.objective == "settling_time" and math.isfinite(self.best.score) and \
            self.best.score < INFEASIBLE

    def _tol(self) -> float:
        b = self.best.score
        if self.problem.spec.objective == "settling_time":
            return max(1e-3 * abs(b), 0.5 * (self.problem.dt or 0.0))
        return 1e-3 * max(abs(b), 1e-12)

    def _span(self, *, weights: bool = True) -> np.ndarray:
        """The box's span per coordinate (the scale of every distance between candidates); ``weights=False``: a
        2-DOF structure's setpoint weights left out (infinite span): designs that differ only there count as one."""
        span = np.maximum(self.space.hi - self.space.lo, 1e-12)
        return span if weights else np.where([k == "weight" for k in self.space.structure.kinds], np.inf, span)

    def _distinct(self, k: int, *, unrefined: bool = True, spread: int = 0) -> list[np.ndarray]:
        """The best ``k`` pooled candidates (batch score) that are distinct from each other and from every refined
        point; ``spread``: the ``k`` of the best ``k + spread`` such candidates that lie farthest from every refined
        point (greedily, each then counting as refined), of the feasible ones only where the best is feasible (a far
        candidate that fails the spec is no better a start than the best one beside a refined point)."""
        # a 2-DOF structure's setpoint weights do not make a start distinct: the refinement moves them freely, and
        # starts that differ only there (pid's starts seeded with several b, c) are one start for the feedback
        span = self._span(weights=False)
        chosen: list[tuple[float, np.ndarray]] = []
        refined = [v for _, v, r in self.pool if r]
        for sc, v, r in sorted(self.pool, key=lambda t: t[0]):
            if unrefined and r:
                continue
            if all(np.linalg.norm((v - w) / span) > self.effort.basin for w in [c for _, c in chosen] + refined):
                chosen.append((sc, v))
            if len(chosen) >= k + spread:
                break
        feasible = bool(chosen) and chosen[0][0] < INFEASIBLE
        cands = [v for sc, v in chosen if sc < INFEASIBLE or not feasible]
        if not spread or len(cands) <= k or not refined:
            return [v for _, v in chosen[:k]]
        picked: list[np.ndarray] = []
        for _ in range(k):
            far = [min(np.linalg.norm((v - w) / span) for w in refined + picked) for v in cands]
            picked.append(cands.pop(int(np.argmax(far))))
        return picked

    def _polish(self) -> None:
        """The incumbent refined once more on the fine NLP grid (``refine(fine=True)``: the settling time
        resolved to about 1 %, or about 0.25 % and sharp at detail 2: default's ``Effort.polish_detail``, thorough's
        ``Effort.detail``; the horizon as far as the slowest pole reaches), if it has not been already:
        the coarse grid's bisection stops up to a grid step (a quarter sample) above the optimum, and a
        horizon of three settling times misses a slow tail that leaves the band later (PID on an integrating
        plant at dt = tau/30: 6.6 % above the optimum)."""
        if not (self.local and self._settling and self.best.v is not None) or self._time_left() <= 0:
            return
        key = self.best.v.tobytes()
        if key in self._polished:
            return
        self._polished.add(key)
        self._refine([self.best.v], fine=True)
        if self.best.v is not None:
            self._polished.add(self.best.v.tobytes())  # what the polish found is polished

    def _refine(self, starts: list[np.ndarray], *, fine: bool = False, own: bool = False) -> list[float]:
        """Refine each start; returns the best batch score each refinement reached. ``own``: to the start's own local
        optimum (not bounded by the incumbent's settling time: the evidence rule's draws)."""
        from .nlp.refine import refine

        out = []
        for v in starts:
            if self._time_left() <= 0:
                break
            self.pool = [(s, w, True) if w is v else (s, w, r) for s, w, r in self.pool]
            try:
                res = refine(self.batch, self.space, v, deadline=self.deadline - self.reserve_s, solver=self.solver,
                             build_cap=None if self.build_cap is None else self.build_cap - self.reserve_s,
                             incumbent=_sig(self.best.score, INPUT_DIGITS) if self._settling and not own else None,
                             reach=_sig(OWN_REACH * self.best.score, INPUT_DIGITS) if self._settling and own else None,
                             above=_sig(self.best.score + self._tol(), INPUT_DIGITS)
                             if self._settling and own and self.effort.draw_cutoff else None,
                             start=self._start(v, digits=INPUT_DIGITS),
                             fine=fine, detail=(self.effort.polish_detail or self.effort.detail) if fine
                             else self.effort.detail)
            except TunerError as e:  # the NLP's own model of this loop cannot be built (its internal simulation
                # step of a stiff plant below the smallest sample time, a loop gain beyond double precision for
                # the NLP's scaled candidate): the search goes on without the local stage, and says so; the user's
                # input is valid (TuningProblem accepted it), so this is never their error
                log.info("local NLP unavailable for this problem: %s", e)
                self.local = False
                note = (f"the local NLP could not model this loop (internally: {e}); the answer is the global "
                        "search's, verified as always, without the local refinement")
                if note not in self.info.notes:
                    self.info.notes.append(note)
                out.append(math.nan)
                break
            self.info.unbuilt_s = max(self.info.unbuilt_s, res.unbuilt_s)
            if res.status.startswith("no time left") or time.perf_counter() > self.deadline - self.reserve_s:
                self._exhaust()  # (a build the time left cannot afford, or a bisection the deadline cut: the end)
            i = self.info
            i.starts_refined += 1
            i.nlp_solves += res.solves
            i.nlp_iterations += res.iterations
            i.nlp_evaluations += res.evaluations
            i.nlp_solves_ok += int(res.success)
            scores = self._score(np.array(res.candidates), source="nlp", refined=True) if res.candidates else []
            if len(scores):
                j = int(np.argmin(scores))
                self.refined.append((float(scores[j]), np.asarray(res.candidates[j], float)))
                if self._in_restart and not fine:  # (the evidence rule's sample: a restart's refinements)
                    self.restart_ends.append((self.restarts, float(scores[j]), np.asarray(res.candidates[j], float),
                                              not res.cut))
            # nan: no solve ran (e.g. no time to build its NLP): no evidence either way for the convergence test
            out.append(float(np.min(scores)) if len(scores) else (math.inf if res.solves else math.nan))
        return out

    # -- rounds -----------------------------------------------------------------------------------

    def _round0(self) -> bool:
        """Deterministic: designed starts, a fixed space-filling set, the contained structure's answer."""
        p = self.problem
        # the plant-based starts first: their best is the incumbent that bounds the simulated horizon of the
        # space-filling points (a point that has not settled by three times the incumbent's settling time
        # is worse anyway)
        starts = designed_starts(self.space, p.nominal, p.dt, variants=True, spec=p.spec)
        span = self._span()
        S = np.array(starts).reshape(len(starts), -1)
        seeded = [v for v in self._seeded_starts()  # those the structure's own starts do not already hold
                  if not len(S) or np.min(np.max(np.abs(S - v) / span, axis=1)) >= 1e-3]
        seeded = self._contained_answer() + self._given + seeded
        n0 = max(1, len(starts) // len(GAIN_DECADES))  # the nominal-gain starts: an incumbent, cheaply
        self._score(np.array(starts[:n0]), source="design")
        # the later batches are cut to what the time left affords (their cost per point is known by now: a slow
        # plant at a fine dt simulates tens of thousands of samples per candidate)
        self._score(np.array(self._affordable(starts[n0:] + seeded)), source="design")
        rng = np.random.default_rng(DESIGN_SEED)
        lo, hi = self.space.lo, self.space.hi
        fixed = [lo + rng.random(lo.size) * (hi - lo) for _ in range(self.effort.design_points)]
        self._score(np.array(self._affordable(fixed)), source="design")
        if not self.local:
            return False
        reached: list[float] = []
        converged, stale = False, 0
        for v in self._distinct(self.n_starts):  # one at a time: stop as soon as the evidence is in
            before = self.best.score
            new = self._refine([v])
            reached += new
            if not new or math.isnan(new[-1]):
                continue  # not refined (no time, or no NLP solve): says nothing about convergence
            good = sorted(r for r in reached if math.isfinite(r) and r < INFEASIBLE)
            # converged: two refinements from distinct starts agree on the best value, or every refinement
            # after the best one (at least Effort.stale_refines of them) failed to improve on it
            agree = len(good) >= 2 and good[1] - good[0] <= self._tol() and good[0] <= self.best.score + self._tol()
            tried = [r for r in reached if not math.isnan(r)]
            stale = stale + 1 if len(tried) > 1 and self.best.score >= before - self._tol() else 0
            converged = agree or stale >= self.effort.stale_refines
            if converged:
                break
        if self._scan():
            converged = False  # a better basin next to the refined one: the search goes on
        self.info.history.append(self.best.score)
        return converged

    def _scan(self, seed: int = SCAN_SEED) -> bool:
        """A fixed cloud of points around the incumbent, scored in one batch; the best, if it beats the
        incumbent, is refined. The settling time is discontinuous in the gains: a loop whose slow tail
        just enters the band earlier lies in a thin valley beside the basin a refinement ends in (PI on
        1/(20 s + 1)^2 at dt 0.1: a valley at 3 tau along a diagonal of (Kp, Ki), next to a basin at
        6 tau), too thin for the space-filling points and out of the NLP's reach from the basin."""
        if not self._settling or self.best.v is None:
            return False
        # (its cost is known from the batches before it)
        if self._time_left() < 2 * self.effort.scan_points * self._per_point and \
                self._time_left() < 2 * self.effort.scan_points * self._repriced([self.best.v]):
            self._exhaust()
            return False
        rng = np.random.default_rng(seed)
        half = np.minimum(self.effort.scan_decades, 0.1 * (self.space.hi - self.space.lo))
        V = self.best.v + (2 * rng.random((self.effort.scan_points, self.best.v.size)) - 1) * half
        V = np.clip(V, self.space.lo, self.space.hi)
        before, v_before = self.best.score, self.best.v
        self._score(V, source="scan")
        if self.best.score >= before - self._tol() or self.best.v is v_before:
            return False
        if self.local:
            self._refine([self.best.v])
        return True

    def _affordable(self, V: list[np.ndarray]) -> list[np.ndarray]:
        """The first of ``V`` that the time left can score, at the last batch's cost per point."""
        if self._per_point <= 0:
            return V
        n = max(0, int(self._time_left() / self._per_point))
        if n < len(V) and V:
            n = max(0, int(self._time_left() / self._repriced(V)))
        if n < len(V):
            self._exhaust()  # the rest of the batch, and everything after it, is beyond the budget
        return V[:n]

    def _repriced(self, V: list[np.ndarray]) -> float:
        """The cost per point measured again, on a few of ``V`` (scored aside: nothing pooled, nothing counted), before
        a step is refused for time: the last batch's price may hold a one-off cost (a kernel's first call, a moment the
        process was not scheduled) that would cut the search for a step it can afford. The lower price is kept."""
        probe = np.array([self.space.params(v) for v in V[:REPRICE_POINTS]])
        n, t0 = self.batch.n_evals, time.perf_counter()
        self.batch.evaluate(probe, incumbent_s=self.best.score if self._settling else None)
        self.batch.n_evals = n
        self._per_point = min(self._per_point, (time.perf_counter() - t0) / len(probe))
        return self._per_point

    def _seeded_starts(self) -> list[np.ndarray]:
        """The contained structure's own designed starts, mapped into this structure's coordinates (a ``pid``
        at ``dt`` starts where a ``pid_z`` would: its Tf at the floor is the backward-Euler PID)."""
        sub = _contained(self.problem)
        if sub is None:
            return []
        name, convert = sub
        p = self.problem
        small = get_structure(name)
        space = make_space(small, p.nominal, p.dt, scale=p.scale, nyquist=p.spec.filter_nyquist)
        out = []
        for v in designed_starts(space, p.nominal, p.dt, variants=True, spec=p.spec):
            g = dict(zip(small.params, space.params(v)))
            with np.errstate(all="ignore"):
                mapped = convert(g)
                for gm in (mapped if isinstance(mapped, list) else [mapped]):
                    x = np.array([gm[q] for q in p.structure.params])
                    if np.all(np.isfinite(x)):
                        out.append(self.space.from_params(x))
        self.info.seeded_from = name if out else None
        return out

    def _contained_answer(self) -> list[np.ndarray]:
        """A structure that must never be worse than the one it contains (``pid2`` and ``pid``): that structure's
        own search, run first on the same problem and seed with at most CONTAINED_SHARE of the time left; its best
        candidates, mapped in (b = c = 1 is that very controller, the other weights are starts), lead this round.
        The refinement then starts from the contained optimum with the weights free."""
        if self.problem.structure.name not in FULL_CONTAINMENT:
            return []
        import dataclasses

        name, convert = _contained(self.problem)
        sub_problem = dataclasses.replace(self.problem, structure=get_structure(name))
        left = self._time_left()
        if left <= 0:
            return []
        sub = Engine(sub_problem, seed=self.seed, deadline=time.perf_counter() + CONTAINED_SHARE * left,
                     solver=self.solver, local=self.local, n_starts=self.n_starts, n_trials=self.n_trials,
                     effort=self.effort,
                     build_cap=None if self.build_cap is None else self.build_cap - self.reserve_s)
        sub.run()
        self.info.unbuilt_s = max(self.info.unbuilt_s, sub.info.unbuilt_s)
        self.info.contained_nlp_solves += sub.info.nlp_solves + sub.info.contained_nlp_solves
        if sub.info.stop == "budget":
            self._exhaust()  # the contained search was cut: so is this one (a budget only ever shortens the search)
        small = sub_problem.structure
        out = []
        for j, (score, x) in enumerate(sub.finalists_scored(3)):
            g = small.named(x)
            for i, gm in enumerate(convert(g)):
                xx = np.array([gm[q] for q in self.problem.structure.params])
                if not np.all(np.isfinite(xx)):
                    continue
                v = self.space.from_params(xx)
                if i == 0:  # b = c = 1: the contained controller itself, pooled with the score its search gave it
                    self.pool.append((float(score), v, False))
                    if score < self.best.score:
                        self.best = _Best(float(score), v)
                    if j == 0:
                        self._contained_x = _decimal(self.space.params(v))
                else:
                    out.append(v)
        self.info.seeded_from = name
        return out

    def _restart(self) -> None:
        """A second basin search, independent of round 0's trajectory: a fresh scrambled-Sobol set over the
        whole box (seeded by the user's seed and the restart's number) and Optuna's batch (told everything
        so far), scored in one batch; the best candidates outside every basin refined so far (round 0's
        included; ``Effort.restart_spread``: those of them farthest from every refined point) are refined; then a
        scan around the incumbent and the loop-gain ray."""
        from .sobol import scrambled  # (scipy.stats.qmc.Sobol's points, without scipy.stats' import)

        self.restarts += 1
        self._step = f"restart {self.restarts}"
        lo, hi = self.space.lo, self.space.hi
        sob = scrambled(lo.size, seed=np.random.default_rng([self.seed, self.restarts, 20]))
        m = max(1, int(round(math.log2(max(1, self.effort.restart_points)))))
        fresh = lo + sob.random_base2(m) * (hi - lo)
        # (TPE's ask costs tens of ms a point with hundreds of trials told; a search without the local stage,
        # e.g. the bandwidth objective, has only the sampler to home in on its optimum)
        if self._asks_optuna:
            self._tell_new()
            trials, V = self._search.ask(self.n_trials or self.effort.round_trials)
            self._search.told(trials, self._score(V, source="optuna") if len(V) else [])
            self._told = len(self.pool)  # (the rest is told by the next _tell_new)
        proj = self._projections()
        sc = self._score(np.array(self._affordable(proj + list(fresh))), source="restart")
        if self.local and self._time_left() > 0:
            # the evidence rule's sample (Engine.evidence): a random point of the best Effort.draw_share of this
            # restart's own space-filling set (the reduced sample), refined wherever it lies: an independent draw of
            # where a refinement from a random start of that level set ends
            fs = np.asarray(sc[len(proj):], float)
            if len(fs) == len(fresh) and len(fs):
                self._in_restart = True
                try:
                    self._refine([self.pool[len(self.pool) - len(fs) + self._draw(fs)][1]], own=True)
                finally:
                    self._in_restart = False
        if self.local and self._time_left() > 0 and self.effort.restart_refines:
            # exploration: of the best candidates outside every refined basin, those farthest from every refined point
            # (Effort.restart_spread); a biased draw (it avoids the basins known), so not the rule's sample
            self._refine(self._distinct(self.effort.restart_refines, spread=self.effort.restart_spread))
        if self._time_left() > 0 and (self.restarts == 1 or self.best.v is None
                                      or self.best.v.tobytes() != self._scanned):
            # (around an incumbent a restart's scan searched already: not again, the evidence is the draws')
            self._scanned = None if self.best.v is None else self.best.v.tobytes()
            self._scan(seed=SCAN_SEED + self.restarts)
        if self._time_left() > 0 and (self.best.v is None or self.best.v.tobytes() != self._rayed):
            # (the ray from an incumbent it started from before repeats itself point for point: not again)
            self._ray()
        self._polish()

    def _draw(self, scores: np.ndarray) -> int:
        """The evidence rule's start in a restart's fresh points (their batch ``scores``): one of the best
        ``Effort.draw_share`` of those that meet the spec (the reduced sample: a random start in the level set of
        the feasible designs' better part; at least one; ties in the fresh set's order; where none meets it, the
        best), picked at random by a generator seeded by the user's seed and the restart, so that the draws are
        independent of each other and of how the search went so far."""
        order = np.argsort(scores, kind="stable")
        feasible = int(np.sum(scores < INFEASIBLE))
        keep = max(1, int(math.ceil(self.effort.draw_share * feasible)))
        rng = np.random.default_rng([self.seed, self.restarts, 21])
        return int(order[int(rng.integers(keep))])

    def _projections(self) -> list[np.ndarray]:
        """The incumbent with one gain at a time set to zero or shrunk by 10^-2 and 10^-4 (a PID's optimum may
        be an ID; a PI's on an integrating plant a P with an integral time thousands of times the settling
        time, where Ki = 0 exactly cancels the integrator: the search's coordinates are logarithmic in a gain
        far from zero, so that move is long for a refinement or a scan, and a restart's refinement from the
        projection reaches the other basin)."""
        if self.best.v is None:
            return []
        out = []
        x = self.space.params(self.best.v)
        for i, kind in enumerate(self.space.structure.kinds):
            if kind == "gain" and abs(self.best.v[i]) > 1e-9:
                v = self.best.v.copy()
                v[i] = min(max(0.0, self.space.lo[i]), self.space.hi[i])  # (a documented range may exclude 0)
                if v[i] != self.best.v[i]:
                    out.append(v)
                for shrink in PROJECTION_SHRINK:
                    y = np.array(x, dtype=float)
                    y[i] *= shrink
                    w = self.space.from_params(y)
                    if np.all(np.isfinite(w)):
                        out.append(np.clip(w, self.space.lo, self.space.hi))
        return out

    def _ray(self) -> None:
        """The incumbent with all its gains scaled together (the loop gain) by RAY_DECADES, then, while that finds
        something the verifier confirms, around the best factor at a quarter of its nearest gap (Effort.ray_zooms
        times); a step within the tolerance is not polished again. The settling time jumps where the overshoot reaches
        the band: a P on 0.45/(s (6.1 s + 1)) settles in 34.6 s at Kp 0.146 and in 52.6 s at 0.152, falling again to
        46 s at the phase-margin limit (Kp 0.23), where a refinement ends; the step back across the jump is a long
        move for the NLP's bisection and too thin a target for the scan."""
        if self.best.v is None or not self._settling:
            return
        gains = [i for i, kind in enumerate(self.space.structure.kinds) if kind == "gain"]
        if not gains:
            return
        x = self.space.params(self.best.v)
        start, tol, v_before = self.best.score, self._tol(), self.best.v
        self._rayed = v_before.tobytes()
        self._ray_levels(x, gains)
        if self.best.v is not None and self.best.v is not v_before and self.best.score >= start - tol and \
                v_before.tobytes() in self._polished:
            # a step from a polished incumbent within the search's tolerance (a fraction of a sample, finer than the
            # NLP's grid resolves): the fine polish would find nothing the ray did not (it costs a dozen NLP solves)
            self._polished.add(self.best.v.tobytes())

    def _ray_levels(self, x: np.ndarray, gains: list[int]) -> None:
        """:meth:`_ray`'s levels from the incumbent's parameters ``x``."""
        center, D = 0.0, np.array(RAY_DECADES)
        for _ in range(1 + self.effort.ray_zooms):
            V, ds = [], []
            for d in center + D:
                y = np.array(x, dtype=float)
                y[gains] *= 10.0 ** d
                w = self.space.from_params(y)
                if np.all(np.isfinite(w)):
                    V.append(np.clip(w, self.space.lo, self.space.hi))
                    ds.append(d)
            V = self._affordable(V)
            if not V:
                return
            saved, n0 = self.best, len(self.pool)
            sc = self._score(np.array(V), source="ray")
            if len(sc) != len(V) or float(np.min(sc)) >= saved.score:
                return
            # the ray homes in on the edge of the band at the batch's resolution, where the verifier's finer one may
            # see the peak outside (and the settling much later): the best points are verified in the batch's order
            # (Effort.ray_checks at most), those it does not confirm taken back (no finalists), the first confirmed kept
            better = [k for k in np.argsort(sc) if sc[k] < saved.score]
            bad, j = set(), None
            for k in better[:self.effort.ray_checks]:
                full = self.ev.score(self.space.params(V[k]))
                if full.feasible and full.score < saved.score:
                    j = int(k)
                    break
                bad.add(V[k].tobytes())
            if j is None:  # (the unchecked ones that beat the incumbent too: they would outrank it as finalists)
                bad |= {V[k].tobytes() for k in better}
            self.pool = self.pool[:n0] + [e for e in self.pool[n0:] if e[1].tobytes() not in bad]
            if j is None:
                self.best = saved
                return
            self.best = _Best(float(sc[j]), np.asarray(V[j], float))
            # around the best factor, at a quarter of its distance to the nearest factor tried (the incumbent's too)
            gap = min(abs(ds[j] - d) for d in [center] + ds[:j] + ds[j + 1:])
            center = ds[j]
            D = gap / 4.0 * np.array([-3.0, -2.0, -1.0, 1.0, 2.0, 3.0])

    def run(self) -> RunInfo:
        """Round 0, then restarts until the evidence rule holds (``stop = "converged"``, see :meth:`evidence`), the
        work budget of restarts is spent (``"work"``: not confirmed) or the time cap cuts the search (``"budget"``,
        ``info.cut`` says which step); returns the record."""
        converged = self._round0()
        self._polish()
        self._round0_refined = len(self.refined)
        self.round0_best = self.best.score
        self.info.rounds = 1
        eff = self.effort
        feasible = lambda: self.best.score < INFEASIBLE
        if eff.confirm == 0:
            # fast: round 0's own agreement ends it (claimed "not confirmed": no restart); without it (or without a
            # feasible point), restarts until the evidence rule holds or Effort.patience of them find nothing better
            converged = converged and feasible() and not self._exhausted
            stale = 0
            while not converged and self._time_left() > 0 and self.restarts < self._max_restarts:
                improved = self._restart_round()
                stale = 0 if improved else stale + 1
                if self._exhausted:
                    break  # a restart the cap cut short is no evidence
                ev = self.evidence()
                converged = ev["holds"] or (stale >= eff.patience + (0 if feasible() else eff.infeasible_extra)
                                            and (not self.local or self.info.nlp_solves > 0))
        else:
            stale, converged = 0, False
            while self._time_left() > 0 and self.restarts < self._max_restarts:
                improved = self._restart_round()
                stale = 0 if improved else stale + 1
                if self._exhausted:
                    break  # a restart the cap cut short is no evidence: stop = "budget"
                if not self.local:
                    # no refinement, no basins: the global search alone stops when eff.confirm restarts in a row found
                    # nothing better (its claim stays "not confirmed": see optimality)
                    if stale >= eff.confirm + (0 if feasible() else eff.infeasible_extra):
                        converged = True
                        break
                    continue
                # the evidence rule (Engine.evidence): enough restarts, the last one found nothing better, and the
                # posterior expected volume of the regions of attraction their draws have not reached
                # (w (w + 1) / (n (n - 1))) is at most UNSEEN_LEVEL; whether they re-found the incumbent's value
                # decides the claim (optimality), not the stop: more draws of the same few optima would add little
                ev = self.evidence()
                if stale >= 1 and self.restarts >= max(eff.confirm, eff.refind) and ev["unseen"] is not None \
                        and ev["unseen"] <= UNSEEN_LEVEL:
                    converged = True
                    break
        if converged:
            self.info.stop = "converged"
        elif self._exhausted or self._time_left() <= 0:
            self.info.stop = "budget"
            self.info.cut = self.info.cut or self._step
        else:
            self.info.stop = "work"  # the restarts the effort affords ran without the evidence: not confirmed
        if self.storage is not None:
            self._tell_new()  # with a storage, every point this tune scored lands in the study
        return self.info

    def _restart_round(self) -> bool:
        """One restart and its bookkeeping; whether it improved the incumbent by more than the tolerance."""
        before = self.best.score
        self._restart()
        self.info.rounds += 1
        self.info.history.append(self.best.score)
        improved = self.best.score < before - self._tol()
        self.restart_improved += int(improved)
        return improved

    def evidence(self) -> dict[str, Any]:
        """The evidence rule's figures, from where the restarts' own draws ended (each draw's refinement's best point;
        round 0's designed starts and a restart's explored refinements are not random draws and do not count):
        ``refinements`` (n), how many draws; ``basins`` (w), the distinct optima they reached, counted by value (two
        draws reached one optimum when their scores agree within the search's tolerance, never when their scores
        differ, however close in the box; infeasible ends when within ``Effort.basin`` of each other over the box's
        span); ``refound``, how many restarts' draws reached the incumbent's value (within that tolerance), not
        counting the one that first found it (where round 0 did not); ``singletons`` and ``good_turing`` (optima
        reached by exactly one draw, and that over n: the Good-Turing estimate, for information); ``unseen``, the
        posterior expected relative volume of the regions of attraction no draw has reached, w (w + 1) / (n (n - 1))
        (Boender and Rinnooy Kan 1987; 1 below two draws; None without a draw): what the draws' distribution
        leaves unexplored, not a bound on whether a better basin exists; ``holds``: refound >= ``Effort.refind`` and
        unseen <= :data:`UNSEEN_LEVEL`."""
        span = self._span(weights=self.problem.spec.objective in ("settling_time", "itae"))
        tol = self._tol()

        def same(sc: float, v: np.ndarray, rs: float, w: np.ndarray) -> bool:
            if sc < INFEASIBLE and rs < INFEASIBLE:
                return abs(sc - rs) <= tol  # one optimum by value: different values are never merged
            return sc >= INFEASIBLE and rs >= INFEASIBLE and np.linalg.norm((v - w) / span) <= self.effort.basin

        inc = [] if self.best.v is None else [(self.best.score, self.best.v)]
        reps: list[tuple[float, np.ndarray, bool]] = []  # the optima the draws reached (each its first draw's end)
        counts: list[int] = []
        refound: set[int] = set()
        for k, sc, v, resolved in self.restart_ends:
            # a draw cut above the incumbent's value (Effort.draw_cutoff): an optimum of its own, and no re-find
            i = next((j for j, (rs, w, ok) in enumerate(reps) if ok and same(sc, v, rs, w)), None) \
                if resolved else None
            if i is None:
                reps.append((sc, v, resolved))
                counts.append(0)
                i = len(reps) - 1
            counts[i] += 1
            if inc and resolved and same(sc, v, *inc[0]):
                refound.add(k)
        if inc and refound and not any(same(sc, v, *inc[0]) for sc, v in self.refined[:self._round0_refined]):
            refound.discard(min(refound))  # the restart that first found the incumbent's optimum did not re-find it
        n, w = len(self.restart_ends), len(reps)
        singles = sum(c == 1 for c in counts)
        unseen = None if not n else (1.0 if n < 2 else min(1.0, w * (w + 1) / (n * (n - 1))))
        holds = unseen is not None and len(refound) >= self.effort.refind and unseen <= UNSEEN_LEVEL
        return {"refinements": n, "basins": w, "refound": len(refound), "singletons": singles,
                "good_turing": singles / n if n else None, "unseen": unseen, "level": UNSEEN_LEVEL,
                "refind": self.effort.refind, "holds": bool(holds)}

    def optimality(self, best_score: float | None = None) -> dict[str, Any]:
        """What the search knows about how close its answer is to the optimum (in the search's scores):
        ``basins``, the distinct basins its refinements ended in (feasible ones); ``alternative``, the best
        value found outside the incumbent's basin and ``gap`` its relative distance (None if every
        refinement ended in the incumbent's basin); ``restarts`` and ``restart_improved`` (how many
        independent restarts ran and how many found something better); ``round0_gap``: how much the
        restarts improved on round 0 (0: round 0 had it); ``claim``: what the result may say of its convergence,
        "converged", "not confirmed" or "budget" (see below); ``evidence`` (:meth:`evidence`), the figures behind it;
        ``stop`` and ``cut`` (what the time cap cut, if it did); ``moved`` and ``rival``, information. Where the
        objective does not see the reference path (a load or frequency-domain objective), distances leave out a
        2-DOF structure's setpoint weights: designs that differ only there have one objective value, one basin."""
        # (settling_time and itae are the reference step's objectives: there the weights make designs distinct)
        span = self._span(weights=self.problem.spec.objective in ("settling_time", "itae"))
        basins: list[tuple[float, np.ndarray]] = []
        for sc, v in sorted(self.refined, key=lambda t: t[0]):
            if sc >= INFEASIBLE:
                continue
            if all(np.linalg.norm((v - w) / span) > self.effort.basin for _, w in basins):
                basins.append((sc, v))
        best = self.best.score if best_score is None else best_score
        alt = None
        if self.best.v is not None and math.isfinite(self.best.score):
            far = [sc for sc, v, _ in self.pool
                   if sc < INFEASIBLE and np.linalg.norm((v - self.best.v) / span) > self.effort.basin]
            alt = min(far) if far else None
        # relative to |best| (a "max" objective's scores are negative: -bandwidth, -disk margin)
        ok = lambda b: math.isfinite(b) and b != 0 and b < INFEASIBLE
        gap = None if alt is None or not ok(best) else (alt - best) / abs(best)
        r0 = None if not (math.isfinite(self.round0_best) and ok(self.best.score)) else \
            (self.round0_best - self.best.score) / abs(self.best.score)
        # the claim (issue 41: on a principle, not a suite). "converged": the search stopped by the evidence rule
        # (Engine.evidence: at least Effort.refind restarts' draws re-found the incumbent's value, and the posterior
        # expected volume of the regions of attraction no draw reached is at most UNSEEN_LEVEL); "not confirmed": it
        # stopped otherwise (the
        # restarts the effort affords ran without that evidence, fast's round 0 agreeing with itself, a search without
        # the local stage); "budget": the time cap (or an explicit time budget) cut it. ``moved`` and ``rival`` are
        # kept as information (the incumbent improved after round 0; a distinct basin within CLAIM_RIVAL): issue 30's
        # rule made them disqualify, a rule fitted to its suite that issue 41's held-out plants broke
        moved = r0 is not None and r0 > CLAIM_MOVED
        rival = gap is not None and gap <= CLAIM_RIVAL
        ev = self.evidence()
        if self.info.stop == "budget":
            claim = "budget"
        elif self.info.stop == "converged" and ev["holds"] and self.restarts and self.local:
            claim = "converged"
        else:
            claim = "not confirmed"
        # what the last completed round still gained (a search the budget ended: an estimate of what more would give)
        h = [x for x in self.info.history if ok(x)]
        last_gain = (h[-2] - h[-1]) / abs(h[-1]) if len(h) >= 2 else None
        return {"effort": self.effort.name, "basins": len(basins), "alternative": alt, "gap": gap,
                "restarts": self.restarts, "restart_improved": self.restart_improved, "round0_gap": r0,
                "evaluations": self.info.batch_evaluations, "refinements": self.info.starts_refined,
                "last_gain": last_gain, "unbuilt_s": self.info.unbuilt_s, "local": self.local,
                "nlp_solves": self.info.nlp_solves, "contained_nlp_solves": self.info.contained_nlp_solves,
                "claim": claim, "moved": bool(moved), "rival": bool(rival), "evidence": ev,
                "max_restarts": self._max_restarts, "stop": self.info.stop, "cut": self.info.cut}

    def _tell_new(self) -> None:
        """Tell the seeded search every point scored since it was last told (one bulk call)."""
        if self._search is None:
            self._search = SeededSearch(self.space, seed=self.seed, sampler=self.sampler, storage=self.storage)
            self._told = 0
        new = self.pool[self._told:]
        self._search.tell([v for _, v, _ in new], [s for s, _, _ in new])
        self._told = len(self.pool)

    # -- the answer ---------------------------------------------------------------------------------

    def finalists(self, k: int = 3) -> list[np.ndarray]:
        """The best ``k`` distinct candidates (structure parameters) for the full verification."""
        return [x for _, x in self.finalists_scored(k)]

    def finalists_scored(self, k: int = 3) -> list[tuple[float, np.ndarray]]:
        """:meth:`finalists` with their batch scores."""
        span = self._span()
        out: list[tuple[float, np.ndarray]] = []
        for s, v, _ in sorted(self.pool, key=lambda t: t[0]):
            if all(np.linalg.norm((v - w) / span) > 1e-6 for _, w in out):
                out.append((s, v))
            if len(out) >= k:
                break
        return [(s, _decimal(self.space.params(v))) for s, v in out]

    def verify_best(self, k: int | None = None) -> tuple[np.ndarray, Scored]:
        """Full-resolution verification of the ``k`` (``Effort.verify``) finalists in the search's order: the
        best verified wins (the settling time is discontinuous: the search's second may verify better than
        its first); ``fast`` stops at the first feasible one. ``self.verified`` counts the verifications."""
        k = self.effort.verify if k is None else k
        best_x, best = None, None
        self.verified = 0
        for x in self.finalists(max(k, 1)):
            if best is not None and best.feasible and self.effort.verify <= 1:
                break
            if self.verified and self.deadline - time.perf_counter() <= 0 and best is not None:
                break  # out of budget: what is verified already
            s = self.ev.score(x)
            self.verified += 1
            if s.analyses and (best is None or s.score < best.score):
                best_x, best = x, s
        if best is not None and not best.feasible:
            # none of the finalists verified feasible (the search's resolution can be fooled, e.g. by a loop whose
            # slow tail outlasts its horizon): verify further candidates, in the search's order, until one is
            for x in self.finalists(max(k, 1) + self.effort.extra_verify)[max(k, 1):]:
                if self.deadline - time.perf_counter() <= 0:
                    break
                s = self.ev.score(x)
                self.verified += 1
                if s.analyses and s.score < best.score:
                    best_x, best = x, s
                if best.feasible:
                    break
        x_c = getattr(self, "_contained_x", None)
        if x_c is not None and not any(np.array_equal(x_c, x) for x in self.finalists(k)):
            # the contained structure's answer (pid2 at b = c = 1 is pid's): verified too, so that the result is
            # never worse than that structure's own tune (the batch's scores of the two may rank them otherwise)
            s = self.ev.score(x_c)
            self.verified += 1
            if s.analyses and (best is None or (s.feasible, -s.score) > (best.feasible, -best.score)):
                best_x, best = x_c, s
        if best is None:
            from ..errors import TunerError

            raise TunerError("no candidate could be evaluated")
        return best_x, best

