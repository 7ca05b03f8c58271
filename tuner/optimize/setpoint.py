"""The stages of a 2-DOF design after the search: the setpoint path shaped for the reference step, and the integral
action raised for the load (Astrom & Hagglund, *Advanced PID Control*, 2006, ch. 7: the feedback designed for the load
disturbance and robustness, the setpoint response shaped with setpoint weights or feed-forward).

A 2-DOF structure's setpoint parameters (:attr:`tuner.controllers.Structure.setpoint`: pid2's ``b`` and ``c``, a
firmware law's ``FF``) act on the reference path alone: the loop's margins, sensitivities and load response do not
depend on them. Once the search has designed the feedback for a load objective (``iae``, ``ie``), :func:`shape_setpoint`
chooses them for the fastest reference step: the worst settling time over the plant set, every constraint of the spec
held on every plant. It scores a grid over their box with the batched verifier, zooms twice around the best cell, and
has the full verifier judge the best few; the feedback's parameters are never moved, so the load objective is what the
search found.

:func:`raise_integral` is the load design of ``objective="auto"`` on a firmware rate law (px4_rate, ardupilot_rate).
Its setpoint path is a feed-forward ``FF >= 0`` alone: it cannot take back the slow overshoot tail that a strong
integrator leaves in the reference step (a setpoint weight below 1 could), so the feedback cannot be designed for the
load alone. From the search's fastest reference step the stage raises the integral gain along a ray (in steps of
``LEVEL_STEP`` decades, and at the classical integral times ``Ti = k/wc``), re-choosing the other parameters at each
level for the fastest reference step by a pattern search on the batched verifier (a strong integrator wants no
feed-forward: PX4's law on a small quad settles in 0.14 s at I = 0.21 with FF = 0 and in 0.82 s with the FF of
I = 0.09), every constraint held on every plant of the set. Of the levels, the one with the least :func:`balance`
wins, the verifier's word on it taken: the later of the reference step's settling time and the load step's recovery
time over :data:`LOAD_TIME_RATIO`. The settling time is flat in the integral gain until the integrator's tail leaves
the band, where it jumps (there, 0.14 s to 0.57 s between I = 0.2 and 0.3): on a plant with damping the balance stops
before the jump; on one that integrates (no aerodynamic damping) the reference step slows as the integrator grows, and
the balance gives the load its time.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["SetpointStage", "LoadStage", "shape_setpoint", "raise_integral", "balance", "LOAD_TIME_RATIO", "GRID_1D",
           "GRID_2D", "ZOOMS", "CHECKED",
           "LEVEL_DECADES", "LEVEL_STEP"]

GRID_1D = 65  # points over a single setpoint parameter's box (a firmware law's FF: log-like, 13 a decade)
GRID_2D = 13  # points a side over two (pid2's b and c: linear)
ZOOMS = 2  # finer grids around the best cell
CHECKED = 4  # the best candidates the full verifier judges
LEVEL_DECADES = 4.0  # the integral gain's ray: up to this many decades above the fastest design's
LEVEL_STEP = 0.1  # ... in steps of this many decades, then bisections between the last that holds and the next
BISECTIONS = 3
HORIZON_FACTOR = 10.0  # the ray's reference steps are simulated up to this many times the fastest's settling time
MAX_HORIZON_FACTOR = 100.0  # ... or as far as the fastest's balance, up to this many times
#: the load design gives a load step this many times as long to recover (back within 2 % of its peak) as the reference
#: step to settle (within 2 %): a rate loop should absorb a step load (a CG shift, a weak motor) on the time scale of
#: its reference step; PX4's and ArduPilot's autotunes recover (to 10 % of the peak) in 1 to 10 times their settling
#: time on the five airframes of bench/autotune_h2h.py
LOAD_TIME_RATIO = 5.0
RAY_MISSES = 4  # the ray ends after this many levels in a row hold no design meeting the spec
TI_CROSSOVERS = (2.0, 4.0, 8.0, 16.0)  # the classical integral times tried too: Ti = k/wc
POLL_STEP = 0.04  # the pattern search's first step, in search coordinates (about decades of a gain)
POLL_MIN_STEP = 0.003
POLL_ITERATIONS = 25
PENALTY = 1e3  # the merit of a candidate that fails a constraint: above every settling time
# a pattern search whose best merit is still PENALTY after this many polls is dropped (None: never, as the product
# runs; bench/px4_speed.py's ``giveup`` variant sets it to measure what it would save and cost)
GIVE_UP_POLLS: int | None = None
#: the load stage runs levels ahead of their turn beside others (see :func:`raise_integral`; False: each level at its
#: turn alone, the same answer at more batch calls)
RUN_AHEAD = True


@dataclass(frozen=True)
class SetpointStage:
    """What :func:`shape_setpoint` did: the setpoint parameters before and after, the worst settling time over the
    plants before and after (the verifier's), and how many candidates the batch and the verifier scored."""

    params: tuple[str, ...]
    before: dict[str, float]
    after: dict[str, float]
    settling_before_s: float
    settling_after_s: float
    evaluated: int
    verified: int

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (the solver record's ``setpoint_stage``)."""
        return {"params": list(self.params), "before": dict(self.before), "after": dict(self.after),
                "settling_before_s": self.settling_before_s, "settling_after_s": self.settling_after_s,
                "evaluated": self.evaluated, "verified": self.verified}


def _worst_settling(scored: Any) -> float:
    """The verifier's worst settling time over the plants of a feasible candidate (``inf`` otherwise)."""
    if not scored.feasible or not scored.analyses:
        return math.inf
    return max(float(a.metrics.settling_time_s) for a in scored.analyses)


def _grid(lo: np.ndarray, hi: np.ndarray, n: int) -> np.ndarray:
    axes = [np.linspace(a, b, n) for a, b in zip(lo, hi)]
    return np.array(list(itertools.product(*axes)), float)


def shape_setpoint(engine: Any, x0: np.ndarray) -> tuple[np.ndarray, SetpointStage, Any] | None:
    """The setpoint parameters of ``x0`` (structure parameters) re-chosen for the fastest reference step, its feedback
    parameters kept: ``(x, record, scored)`` (``scored``: the full verifier's :class:`~tuner.optimize.scoring.Scored`
    of ``x``), ``x`` is ``x0`` itself when nothing verified better. None when the structure has no setpoint parameters
    or ``x0`` does not meet the spec (the feedback must first).

    ``engine`` is the search's :class:`~tuner.optimize.engine.Engine` (its space, batched verifier and full verifier).
    """
    st = engine.problem.structure
    idx = [st.params.index(p) for p in st.setpoint]
    if not idx:
        return None
    x0 = np.asarray(x0, float)
    s0 = engine.ev.score(x0)
    if not s0.feasible:
        return None
    space, batch = engine.space, engine.batch
    v0 = space.from_params(x0)
    lo, hi = space.lo[idx].copy(), space.hi[idx].copy()
    n = GRID_1D if len(idx) == 1 else GRID_2D
    evaluated = 0
    cands: dict[bytes, tuple[float, np.ndarray]] = {}
    box_lo, box_hi = lo.copy(), hi.copy()
    for _ in range(1 + ZOOMS):
        G = _grid(lo, hi, n)
        V = np.repeat(v0[None, :], len(G), axis=0)
        V[:, idx] = G
        X = np.array([space.params(v) for v in V])
        ok = np.all(np.isfinite(X), axis=1)
        X, V = X[ok], V[ok]
        r = batch.evaluate(X)
        evaluated += len(X)
        ts = np.max(np.stack([m["settling_time_s"] for m in r.per_plant]), axis=0)
        ts = np.where(r.feasible, ts, np.inf)
        for j in np.flatnonzero(np.isfinite(ts)):
            cands[X[j].tobytes()] = (float(ts[j]), X[j])
        if not np.any(np.isfinite(ts)):
            break
        j = int(np.argmin(ts))
        cell = (hi - lo) / (n - 1)
        lo = np.maximum(box_lo, V[j, idx] - 2 * cell)
        hi = np.minimum(box_hi, V[j, idx] + 2 * cell)
        if np.all(hi - lo <= 1e-9 * np.maximum(1.0, np.abs(hi))):
            break
    t0 = _worst_settling(s0)
    best_x, best_t, best_s = x0, t0, s0
    verified = 0
    for _, x in sorted(cands.values(), key=lambda c: c[0])[:CHECKED]:
        s = engine.ev.score(x)
        verified += 1
        t = _worst_settling(s)
        if t < best_t:
            best_x, best_t, best_s = x, t, s
    rec = SetpointStage(params=tuple(st.setpoint), before={p: float(x0[i]) for p, i in zip(st.setpoint, idx)},
                        after={p: float(best_x[i]) for p, i in zip(st.setpoint, idx)}, settling_before_s=t0,
                        settling_after_s=best_t, evaluated=evaluated, verified=verified)
    return best_x, rec, best_s


@dataclass(frozen=True)
class LoadStage:
    """What :func:`raise_integral` did: the integral gain and the other parameters before and after, the fastest
    design's worst settling time, how many integral levels held a design meeting the spec, the settling time after and
    the load objective (IE) before and after (the verifier's, worst over the plants), the balance reached (settling
    time over integral gain), and how many candidates the batch and the verifier scored."""

    integral: str
    before: dict[str, float]
    after: dict[str, float]
    fastest_settling_s: float
    levels: int
    settling_after_s: float
    objective_before: float
    objective_after: float
    balance: float
    evaluated: int
    verified: int

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (the solver record's ``load_design``)."""
        return {"integral": self.integral, "before": dict(self.before), "after": dict(self.after),
                "fastest_settling_s": self.fastest_settling_s, "levels": self.levels,
                "settling_after_s": self.settling_after_s, "objective_before": self.objective_before,
                "objective_after": self.objective_after, "balance": self.balance, "evaluated": self.evaluated,
                "verified": self.verified}


def _merit(batch: Any, X: np.ndarray, limit: float) -> tuple[np.ndarray, np.ndarray]:
    """``(merit, worst settling)`` of candidates ``X``: the worst settling time over the plants where every constraint
    holds, else a penalty above every settling time graded by the violation (the batch's). The horizon is three times
    ``limit``: a candidate that has not settled by then is no candidate."""
    r = batch.evaluate(X, incumbent_s=limit)
    ts = np.max(np.stack([m["settling_time_s"] for m in r.per_plant]), axis=0)
    merit = np.where(r.feasible & np.isfinite(ts), ts, PENALTY * (1.0 + np.nan_to_num(r.violation, nan=1e3,
                                                                                      posinf=1e3)))
    return np.where(np.isfinite(merit), merit, PENALTY * 1e3), ts


class _Merits:
    """:func:`_merit` of candidates, each distinct row scored once in a call of :func:`raise_integral` (the batch
    scores each row on its own: a row's figures do not depend on the others in its batch, so a row met again, a
    pattern search's poll back to where it came from, a step clipped to the box, is looked up, not simulated again)."""

    def __init__(self, batch: Any, limit: float) -> None:
        self.batch, self.limit = batch, limit
        self.seen: dict[bytes, float] = {}
        # where a row's figures depend on its batch (BatchEvaluator.rows_independent: a continuous loop with a delay),
        # each row is scored alone (review of issue 41; no such loop reaches this stage today: it serves the firmware
        # rate laws)
        self.alone = not getattr(batch, "rows_independent", True)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        X = np.ascontiguousarray(X, dtype=float)
        keys = [x.tobytes() for x in X]
        new: dict[bytes, int] = {}
        for j, k in enumerate(keys):
            if k not in self.seen and k not in new:
                new[k] = j
        if new:
            rows = list(new.values())
            m = np.concatenate([_merit(self.batch, X[[j]], self.limit)[0] for j in rows]) if self.alone else \
                _merit(self.batch, X[rows], self.limit)[0]
            for k, v in zip(new, m):
                self.seen[k] = float(v)
        return np.array([self.seen[k] for k in keys])


def _settle_locally(merits: _Merits, space: Any, jobs: list[tuple[np.ndarray, dict[int, float]]], free: list[int]
                    ) -> list[tuple[np.ndarray, float, int]]:
    """Pattern searches (Hooke-Jeeves polls along each free coordinate, both ways, the step halved when none improves)
    over the coordinates ``free`` for the fastest reference step, one per job ``(start, fixed)`` (``fixed``: index ->
    value, the parameters held); ``(coordinates, merit, candidates scored)`` per job. The searches run side by side,
    each poll of all of them one batch: each is the search it is alone (the batch scores each row on its own)."""
    lo, hi = space.lo, space.hi

    def params(V: np.ndarray, fixed: dict[int, float]) -> np.ndarray:
        X = np.array([space.params(w) for w in V])
        for i, val in fixed.items():
            X[:, i] = val
        return X

    vs = [np.clip(np.asarray(v, float), lo, hi) for v, _ in jobs]
    m = merits(np.concatenate([params(v[None, :], f) for v, (_, f) in zip(vs, jobs)]))
    best = [float(x) for x in m]
    count = [1] * len(jobs)
    step = [POLL_STEP] * len(jobs)
    live = list(range(len(jobs)))
    for it in range(POLL_ITERATIONS):
        if not live:
            break
        polls = []
        for s in live:
            V = []
            for i in free:
                for sgn in (1.0, -1.0):
                    w = vs[s].copy()
                    w[i] = min(max(w[i] + sgn * step[s], lo[i]), hi[i])
                    V.append(w)
            polls.append(np.array(V))
        m = merits(np.concatenate([params(V, jobs[s][1]) for s, V in zip(live, polls)]))
        at = 0
        for s, V in zip(list(live), polls):
            ms = m[at:at + len(V)]
            at += len(V)
            count[s] += len(V)
            j = int(np.argmin(ms))
            if ms[j] < best[s] - 1e-12 * max(1.0, abs(best[s])):
                vs[s], best[s] = V[j], float(ms[j])
            else:
                step[s] /= 2
                if step[s] < POLL_MIN_STEP:
                    live.remove(s)
            if GIVE_UP_POLLS is not None and it + 1 >= GIVE_UP_POLLS and best[s] >= PENALTY and s in live:
                live.remove(s)
    return list(zip(vs, best, count))


def raise_integral(problem: Any, engine: Any, x0: np.ndarray) -> tuple[np.ndarray, LoadStage, Any] | None:
    """The load design from the fastest reference step ``x0`` (structure parameters; see the module docstring):
    ``(x, record, scored)``, ``x`` the balanced design (its integral gain raised, the other parameters re-chosen for
    the reference step), or ``x0`` itself when nothing verified better; None when the structure has no integral gain
    or setpoint parameters, or ``x0`` does not meet the spec. ``engine``'s full verifier judges ``problem``."""
    from .batch import BatchEvaluator

    st = problem.structure
    if st.integral is None or not st.setpoint:
        return None
    ii = st.params.index(st.integral)
    x0 = np.asarray(x0, float)
    s0 = engine.ev.score(x0)
    if not s0.feasible:
        return None
    ts0 = _worst_settling(s0)
    rec0 = _worst_recovery(s0)
    space = engine.space
    batch = BatchEvaluator(problem, space)
    # (the ray's reference steps are simulated as far as a design could still beat the fastest one's balance)
    horizon = max(HORIZON_FACTOR * ts0, min(rec0 / LOAD_TIME_RATIO, MAX_HORIZON_FACTOR * ts0))
    if problem.spec.settling_time_max is not None:
        horizon = min(horizon, float(problem.spec.settling_time_max))
    unit = space.units[ii]
    floor = max(float(space.params(space.lo)[ii]), 1e-3 * unit)
    top = float(space.params(space.hi)[ii])
    free = [i for i in range(len(st.params)) if i != ii]
    counter = [0]
    v0 = space.from_params(x0)
    found: dict[float, tuple[np.ndarray, float]] = {}  # integral gain -> (coordinates, worst settling)

    merits = _Merits(batch, horizon / 3.0)
    # a level's searches, run ahead of their turn beside others (one batch per poll for all of them), under the
    # levels found when they ran: (level, its starts) -> (best, candidates scored); a level's turn takes its result
    # only where its starts are still those (else it searches then), so the stage finds what it finds level by level
    ahead: dict[tuple[float, bytes], tuple[tuple[np.ndarray, float] | None, int]] = {}

    def nearest(level: float) -> list[np.ndarray]:
        """Where a level's local search starts: the fastest design, and the found level nearest below it."""
        below = [lv for lv in found if lv < level]
        return [v0] + ([found[max(below)][0]] if below else [])

    def key(level: float) -> tuple[float, bytes]:
        return level, b"".join(np.asarray(v, float).tobytes() for v in nearest(level))

    def search(levels: list[float]) -> None:
        """The searches of ``levels`` from their starts now, side by side, into ``ahead``."""
        levels = list(dict.fromkeys(levels))  # (a classical level may be a ray level too)
        jobs, owner = [], []
        for lv in levels:
            for start in nearest(lv):
                jobs.append((start, {ii: lv}))
                owner.append(lv)
        out: dict[float, list[Any]] = {lv: [None, 0] for lv in levels}
        for lv, (w, m, c) in zip(owner, _settle_locally(merits, space, jobs, free)):
            o = out[lv]
            o[1] += c
            if m < PENALTY and (o[0] is None or m < o[0][1]):
                o[0] = (w, m)
        for lv in levels:
            ahead[key(lv)] = (out[lv][0], out[lv][1])

    def at(level: float, more: list[float]) -> None:
        """The level's turn: its search's best design (meeting the spec) into ``found``; when it has not run from
        the starts it has now, it runs with the levels ``more`` beside it."""
        k = key(level)
        if k not in ahead:
            search([level] + [lv for lv in more if key(lv) not in ahead])
        best, count = ahead.pop(k)
        counter[0] += count
        if best is not None:
            found[level] = best

    # the classical integral times, Ti = k/wc on the fastest design's worst crossover (Astrom & Hagglund: Ti of a
    # few times 1/wc): starts the ray cannot reach from a design without integral action
    r0 = batch.evaluate(x0[None, :])
    wc = float(np.nanmin([m["wc"][0] for m in r0.per_plant])) if r0.per_plant else math.nan
    p_gain = _proportional(st, x0)
    classical = [p_gain * wc / k for k in TI_CROSSOVERS] if math.isfinite(wc) and wc > 0 and p_gain > 0 else []

    def untried(lv: float) -> bool:
        """Level ``lv`` lies in the box and no level found so far is within half a step of it."""
        return floor <= lv <= top and not any(abs(math.log10(lv / f)) < LEVEL_STEP / 2 for f in found)

    def classical_left() -> list[float]:
        """The classical levels the stage would try with the levels found now."""
        return [lv for lv in classical if untried(lv)]

    # the ray: from the fastest design's integral gain (or the box's floor) up in steps, on past levels that fail
    # (a plant that integrates: its reference step slows as the integrator grows, then speeds up again once the
    # integrator's own mode is fast), until RAY_MISSES fail in a row. Run ahead: after a level that failed, the levels
    # up to the ray's end should they all fail (and then the classical levels too); after one that held, the next
    i0 = float(x0[ii])
    start = max(i0, floor)
    end = start * 10.0 ** LEVEL_DECADES
    lv, misses, held = start, 0, True
    while misses < RAY_MISSES:
        lv *= 10.0 ** LEVEL_STEP
        if lv > top or lv > end:
            break
        more, nxt = [], lv
        for _ in range(0 if held or not RUN_AHEAD else RAY_MISSES - misses - 1):
            nxt *= 10.0 ** LEVEL_STEP
            if nxt > top or nxt > end:
                break
            more.append(nxt)
        if not held and RUN_AHEAD:
            more += classical_left()
        n = len(found)
        at(lv, more)
        held = len(found) > n
        misses = 0 if held else misses + 1
    for lv in classical:
        if untried(lv):
            at(lv, classical_left() if RUN_AHEAD else [])
    if not found:
        return None

    # the load step's recovery of each level's design (the batch at full horizon), then the balance
    lv_list = sorted(found)
    X = np.array([space.params(found[lv][0]) for lv in lv_list])
    X[:, ii] = lv_list
    batch.load_recovery = True
    r = batch.evaluate(X)
    batch.load_recovery = False
    counter[0] += len(X)
    rec = np.max(np.stack([m["load_recovery_s"] for m in r.per_plant]), axis=0)
    cands = sorted(((balance(found[lv][1], float(rc)), lv, x) for lv, x, rc in zip(lv_list, X, rec)),
                   key=lambda c: c[0])
    best_x, best_s, best_f, best_t = x0, s0, balance(ts0, rec0), ts0
    verified = 0
    for f, _, x in cands:
        if f >= best_f or verified >= CHECKED:
            break
        s = engine.ev.score(x)
        verified += 1
        t = _worst_settling(s)
        fv = balance(t, _worst_recovery(s))
        if s.feasible and fv < best_f:
            best_x, best_s, best_f, best_t = x, s, fv, t
            break
    names = [st.integral, *[p for p in st.params if p != st.integral]]
    rec = LoadStage(integral=st.integral, before={p: float(x0[st.params.index(p)]) for p in names},
                    after={p: float(best_x[st.params.index(p)]) for p in names}, fastest_settling_s=ts0,
                    levels=len(found), settling_after_s=best_t, objective_before=float(s0.score),
                    objective_after=float(best_s.score), balance=best_f, evaluated=counter[0], verified=verified)
    return best_x, rec, best_s


def balance(settling_s: float, recovery_s: float) -> float:
    """The load design's measure: the later of the reference step's settling and the load step's recovery given
    :data:`LOAD_TIME_RATIO` times as long (both back within 2 %: the step's band, the load step's peak)."""
    return max(settling_s, recovery_s / LOAD_TIME_RATIO)


def _worst_recovery(scored: Any) -> float:
    """The verifier's worst load recovery time over the plants (inf when one does not recover)."""
    if not scored.analyses:
        return math.inf
    return max(float(a.metrics.load_recovery_s) for a in scored.analyses)


def _proportional(st: Any, x: np.ndarray) -> float:
    """The structure's proportional gain at ``x`` (the gain of unit 0 that is no setpoint parameter), or nan."""
    units = st.gain_units or (0,) * len(st.params)
    for p, k, u, v in zip(st.params, st.kinds, units, x):
        if k == "gain" and u == 0 and p not in st.setpoint:
            return float(v)
    return math.nan
