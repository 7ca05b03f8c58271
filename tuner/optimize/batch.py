"""The search-resolution verifier, batched: hundreds of candidates per numpy call.

The global stage and the local stage's ranking score candidates here; the reported numbers always
come from the full verifier (:mod:`tuner.analysis`). The same numerics as the verifier, vectorised
over a batch of controllers of one structure:

* the plant's realisation (the ZOH of its cascade realisation, or the continuous one), its lifted
  between-sample outputs and its frequency response on a fixed grid are computed once per problem;
* each candidate's controller is realised in controllable canonical form (low order) and the closed
  loops are assembled as a stack ``(B, nz, nz)``: poles are their eigenvalues, responses are one
  state recursion for the whole stack;
* margins, Ms, Mt, Mks and the disk margin come from ``L = C G`` on the grid (crossings by linear
  interpolation between grid points), so they are a little optimistic or pessimistic between grid
  points: the search tightens every limit by a small guard, and the final verification decides.

The horizon follows the plant and each candidate: ten time constants of its own slowest closed-loop pole
(at least ``MIN_HORIZON_W0 / w0``); candidates are simulated in groups of similar length (powers of two
of samples), so none is cut short and none pays for another's, up to the verifier's own limit of
``MAX_SAMPLES`` samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import linalg

from ..analysis.response import MAX_SAMPLES, lifted_with_switch  # the verifier's (one source)
from ..controllers import ControllerTF
from ..limits import CROSSOVER_TOL, LIMITS, SSE_TOL, limit, objective
from ..limits import INFEASIBLE as _INFEASIBLE
from ..loop import build_loop
from ..lti import zoh_delayed
from ..problem import TuningProblem
from ..tolerances import (
    ALGEBRAIC_LOOP_TOL,
    EXACT_ROOT_TOL,
    ROOT_AT_DC_TOL,
    ROOT_MAG_FLOOR,
    STABILITY_MARGIN,
)
from . import rules
from .space import Space

__all__ = ["BatchEvaluator", "BatchResult", "GUARD", "Start"]

# how much the search tightens each limit (the batch's grid is coarser than the verifier's); the frequency-domain
# peaks are not tightened: optima sit on those limits, and the final verification judges them on its dense grid
# how far inside its limits the search keeps (the registry's guards, tuner.limits; the NLP reads these too)
GUARD = {"band": 1.0, "margin_deg": limit("phase_margin_min_deg").guard[1],
         "margin_db": limit("gain_margin_min_db").guard[1], "peak": 1.0,
         "overshoot": limit("overshoot_max_pct").guard[1]}
SETTLING_MAX_GUARD = limit("settling_time_max").guard[1]  # a settling-time limit, kept this much inside in the search
# the limits the batch holds generically (their figure, held inside by their guard and normalised by their value):
# all but the thesis's margins and overshoot (scaled by max(limit, 1) and kept inside only when set above 0) and
# the crossover target (a two-sided tolerance), whose rows in _combine are their own
_SIMPLE = tuple(lim for lim in LIMITS if lim.batch and lim.sense and lim.default is None)
GRID_POINTS = 500
SAMPLES_PER_DT = 6
CONTINUOUS_STEPS = 600
MIN_HORIZON_W0 = 40.0
# MAX_SAMPLES (from tuner.analysis.response): a candidate needing more samples is judged on that many
INFEASIBLE = _INFEASIBLE  # (the registry's: tuner.limits.INFEASIBLE)
UNSTABLE = 1e5


# the compiled kernels (tuner.optimize.kernels): loaded on a batch's first use, never by importing tuner
_KERNELS: dict[str, Any] = {"module": None, "spawned": False, "warm": False}


def kernels(*, compile_now: bool = False) -> Any:
    """The compiled kernels module for a new batch, or None for the numpy path.

    ``TUNER_KERNELS``: ``off`` (numpy always), ``on`` (the kernels, compiled in this process on first use if this
    machine has not compiled them yet) or ``auto`` (the default): the kernels where this process has loaded them
    (:func:`preload_kernels`: the service's solver processes and the study workers do at their start), else numpy,
    so that no search pays numba's import (about half a second) inside its time budget, and a one-shot command
    (``tuner tune``) none at all. ``compile_now``: as ``on``."""
    mod = _KERNELS["module"]
    if mod is not None:
        return mod
    import os

    mode = os.environ.get("TUNER_KERNELS", "auto").strip().lower()
    if not compile_now and mode not in ("on", "1", "yes", "true"):
        return None
    # warmed here, once (as preload_kernels does): a compile or cache load inside the search's first batch would make
    # that batch look dear, and the search, which prices its time left by the last batch's cost per point, cut the tune
    # in round 0 (a fresh machine's first TUNER_KERNELS=on tune: cut after 7.6 s of its 60 s cap)
    return _warmed(_import_kernels())


def _warmed(mod: Any) -> Any:
    """``mod`` (the kernels, or None) with every kernel called once in this process."""
    if mod is not None and not _KERNELS.get("warm"):
        mod.warm()
        _KERNELS["warm"] = True
    return mod


def preload_kernels() -> Any:
    """Load the kernels now, at a long-lived process's start (``TUNER_KERNELS`` ``auto`` or ``on``), where this
    machine has compiled them (the cache's ready mark), and call each once (:func:`tuner.optimize.kernels.warm`) so
    that numba has loaded their machine code before the first tune; where it has not, start their compile in a
    detached background process, once per machine, and stay on numpy. The module, or None.

    The warm call matters for the answer, not only for speed: loaded lazily inside a process's first batch, numba's
    cache load (seconds on a loaded machine) made that batch look dear, and the search, which prices what its time
    left affords by the last batch's cost per point, cut the first tune in round 0 (the service's solver processes
    and the study workers alike; bench/results/study_workers_issue41.md)."""
    return _warmed(_preload())


def _preload() -> Any:
    import os

    mode = os.environ.get("TUNER_KERNELS", "auto").strip().lower()
    if mode in ("off", "0", "no", "false"):
        return None
    if mode in ("on", "1", "yes", "true"):
        return _import_kernels()
    from .cachedir import kernels_ready_mark, trusted_root

    if _KERNELS["module"] is None and trusted_root() is None:
        return None  # (a cache root others can write: no machine code loaded from it, none compiled into it)
    if _KERNELS["module"] is None and not kernels_ready_mark().exists():
        import importlib.util

        if importlib.util.find_spec("numba") is not None:
            _spawn_kernel_build()
        return None
    return _import_kernels()


def _import_kernels() -> Any:
    import importlib.util

    if importlib.util.find_spec("numba") is None:
        return None
    from . import kernels as mod

    _KERNELS["module"] = mod
    return mod


def _spawn_kernel_build() -> None:
    """Compile the kernels into the machine's cache in a detached background process (once per process; a lock
    file keeps concurrent processes from compiling twice; a lock older than ten minutes is taken as stale)."""
    if _KERNELS["spawned"]:
        return
    _KERNELS["spawned"] = True
    import os
    import subprocess
    import sys
    import time

    from .cachedir import cache_root

    lock = cache_root() / "numba" / "build.lock"
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        if lock.exists() and time.time() - lock.stat().st_mtime > 600:
            lock.unlink(missing_ok=True)
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        os.close(fd)
    except OSError:
        return  # another process compiles them (or the cache is not writable: numpy it stays)
    code = ("import pathlib,sys\ntry:\n from tuner.optimize.kernels import warm; warm()\n"
            f"finally:\n pathlib.Path({str(lock)!r}).unlink(missing_ok=True)")
    try:
        subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL, start_new_session=True)
    except OSError:
        lock.unlink(missing_ok=True)


@dataclass(frozen=True)
class StackedLoops:
    """The closed loops of a batch of candidates around one plant, stacked on the first axis (B): the state
    ``x+ = A x + Bm [r, w]`` (or ``x' = ...`` in continuous time), the output ``y = Cy x + Dy [r, w]``, the
    control signal ``u = Cu x + Du [r, w]`` and the plant's input ``Ca x + Da [r, w]``; the plant's states
    are the first ``n_plant``. Passed whole between the closed-loop builder, the time metrics and the
    simulation."""

    A: np.ndarray
    Bm: np.ndarray
    Cy: np.ndarray
    Dy: np.ndarray
    Cu: np.ndarray
    Du: np.ndarray
    Ca: np.ndarray
    Da: np.ndarray
    n_plant: int

    def rows(self, sel: np.ndarray) -> StackedLoops:
        """The loops of the candidates ``sel`` (an index array)."""
        return StackedLoops(self.A[sel], self.Bm[sel], self.Cy[sel], self.Dy[sel], self.Cu[sel], self.Du[sel],
                            self.Ca[sel], self.Da[sel], self.n_plant)


@dataclass
class BatchResult:
    """Per candidate: ``score`` (objective if feasible, else graded penalties above INFEASIBLE), ``feasible``,
    the metrics used, and ``violation`` (sum of normalised violations)."""

    score: np.ndarray
    feasible: np.ndarray
    violation: np.ndarray
    metrics: dict[str, np.ndarray] = field(default_factory=dict)  # worst over the plants
    per_plant: list[dict[str, np.ndarray]] = field(default_factory=list)


@dataclass(frozen=True, eq=False)
class _PlantData:
    Phi: np.ndarray
    Gam: np.ndarray
    C: np.ndarray
    D: float
    d: int  # delay in samples (sampled-data loops)
    tau: float  # continuous delay
    Cf: np.ndarray | None  # lifted outputs between samples (N, n)
    Df: np.ndarray | None
    G: np.ndarray  # frequency response on the grid (delay included)
    G_nyq: complex | None  # at z = -1
    G_dc: complex | None  # at DC, when finite
    G_inf: float  # continuous: G(inf)
    fine: tuple | None = None  # continuous loops with delay: zoh_delayed(...) at the search step
    offsets: np.ndarray | None = None  # the instants of Cf's rows within a sample, s (j dt / N, and a fractional
                                       # delay's input switch phi, where the output has a corner)


def _canonical(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, ...]:
    """Batched controllable canonical form of num/den (B, m+1) (den not necessarily monic)."""
    a0 = den[:, :1]
    a = den[:, 1:] / a0
    b = num / a0
    B, m = a.shape
    A = np.zeros((B, m, m))
    if m:
        A[:, 0, :] = -a
        A[:, 1:, :-1] = np.eye(m - 1)[None]
    Bc = np.zeros((B, m))
    if m:
        Bc[:, 0] = 1.0
    Cc = b[:, 1:] - b[:, :1] * a
    return A, Bc, Cc, b[:, 0]


def _realize(num: np.ndarray, den: np.ndarray, num_r: np.ndarray | None) -> tuple[np.ndarray, ...]:
    """``(A, B, C, D, Br, Dr)`` of stacked controllers: 1-DOF, the controllable canonical form (``Br, Dr`` None);
    2-DOF, the observable canonical form, whose states both paths share (``B, D`` the feedback C on -y, ``Br, Dr``
    the reference path C_r over the same denominator)."""
    Ac, Bc, Cc, Dc = _canonical(num, den)
    if num_r is None:
        return Ac, Bc, Cc, Dc, None, None
    _, _, Ccr, Dcr = _canonical(num_r, den)
    return np.swapaxes(Ac, 1, 2), Cc, Bc, Dc, Ccr, Dcr


@dataclass(frozen=True)
class Start:
    """What the batched verifier says about the start, per plant."""

    settle: np.ndarray
    wc: np.ndarray
    wp: np.ndarray
    horizon: np.ndarray
    overshoot: np.ndarray  # %

    @classmethod
    def row(cls, r: BatchResult, j: int) -> Start:
        """Row ``j`` of a :class:`~tuner.optimize.batch.BatchResult`."""
        return cls(*(np.array([float(m[k][j]) for m in r.per_plant]) for k in ("settling_time_s", "wc", "wp",
                                                                                  "horizon_s", "overshoot_pct")))

    @classmethod
    def of(cls, batch: BatchEvaluator, x0: np.ndarray) -> Start:
        """The batched verifier's figures of the single point ``x0``."""
        return cls.row(batch.evaluate(x0[None]), 0)


class BatchEvaluator:
    """Scores batches of structure parameters (rows of ``X``) on every plant of ``problem``."""

    def __init__(self, problem: TuningProblem, space: Space, *, grid_points: int = GRID_POINTS,
                 samples_per_dt: int = SAMPLES_PER_DT) -> None:
        self.problem, self.space = problem, space
        self.st, self.dt, self.spec = problem.structure, problem.dt, problem.spec
        w0 = space.w0
        wmax = math.pi / self.dt * 0.9999 if self.dt else 1e3 * w0
        wmin = min(1e-3 * w0, *(self._slowest(p) for p in problem.plants))
        self.w = np.geomspace(wmin, wmax, grid_points)
        self.N = samples_per_dt if self.dt else 1
        self.horizon_floor = MIN_HORIZON_W0 / w0
        self.n_evals = 0
        self.plants = [self._plant_data(p) for p in problem.plants]
        #: compute the load step's recovery time too (``load_recovery_s``: as the verifier's, the last time |y| is above
        #: 2 % of its peak; inf where not back within the horizon), the load stage's measure
        self.load_recovery = False
        #: compute the reference step's ITAE (``itae``) whatever the objective (by default only where the objective is
        #: ``itae``: no limit reads it, and it is a quarter of a sampled row's work after its simulation; nan otherwise)
        self.all_figures = False
        #: per plant: the phase and gain margins it must keep (the spec's; a gain-variation member's its own)
        self.margins = [(q.phase_margin_min_deg, q.gain_margin_min_db) for q in problem.specs]
        sp = self.spec
        # the figures the spec checks or optimises (the registry's batch keys of the limits it sets, its objective's)
        self._needs = frozenset({lim.batch for lim in LIMITS if lim.batch and getattr(sp, lim.field) is not None}
                                | {objective(sp.objective).batch})
        #: the compiled kernels (:func:`kernels`), or None: the numpy path (the reference; set None to use it)
        self.kernels = kernels()

    @staticmethod
    def _slowest(p) -> float:
        r = np.concatenate([p.zeros, p.poles])
        if p.dt is not None:
            r = r[(np.abs(r) > EXACT_ROOT_TOL) & (np.abs(r - 1) > ROOT_AT_DC_TOL)]
            r = np.log(r.astype(complex)) / p.dt
        m = np.abs(r)
        m = m[m > ROOT_MAG_FLOOR]
        return float(m.min()) / 10 if m.size else math.inf

    def _plant_data(self, plant) -> _PlantData:
        unit = ControllerTF(num=np.ones(1), den=np.ones(1), dt=self.dt)
        lp = build_loop(plant, unit)
        g = lp.loop_plant.ss()
        Cf = Df = offsets = None
        if self.dt is not None and lp.plant_ct is not None and self.N > 1:
            # the verifier's rows, a fractional delay's input switch included (else the search's best candidates
            # may verify later than it thinks)
            Cf, Df, offsets, _ = lifted_with_switch(lp, self.N)
        G = lp.freqresp(self.w)
        G_nyq = lp.value_at(-1.0) if self.dt else None
        G_dc = None if lp.integrating else lp.value_at(0.0 if self.dt is None else 1.0)
        G = np.ascontiguousarray(G, dtype=complex)
        return _PlantData(g.A, g.B, g.C, float(g.D), lp.delay_samples, lp.delay_s, Cf, Df, G, G_nyq, G_dc,
                          float(g.D) if self.dt is None else 0.0, offsets=offsets)

    # -- the controllers ------------------------------------------------------------------------

    def controllers(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Numerator and denominator coefficients (B, m+1) of each candidate's controller."""
        B = X.shape[0]
        cols = [X[:, j] for j in range(X.shape[1])]
        with np.errstate(all="ignore"):
            num, den = self.st.coeffs(cols, self.dt, np.exp)
        den = np.stack([np.broadcast_to(np.asarray(c, float), (B,)) for c in den], axis=1)
        num = np.stack([np.broadcast_to(np.asarray(c, float), (B,)) for c in num], axis=1)
        if num.shape[1] < den.shape[1]:
            num = np.concatenate([np.zeros((B, den.shape[1] - num.shape[1])), num], axis=1)
        return num, den

    def controllers_r(self, X: np.ndarray, m1: int) -> np.ndarray | None:
        """2-DOF structures: the reference path's numerator (B, m1) over the same denominator; None for 1-DOF."""
        if not self.st.two_dof:
            return None
        B = X.shape[0]
        cols = [X[:, j] for j in range(X.shape[1])]
        with np.errstate(all="ignore"):
            num_r, _ = self.st.ref_coeffs(cols, self.dt, np.exp)
        num_r = np.stack([np.broadcast_to(np.asarray(c, float), (B,)) for c in num_r], axis=1)
        if num_r.shape[1] < m1:
            num_r = np.concatenate([np.zeros((B, m1 - num_r.shape[1])), num_r], axis=1)
        return num_r

    def _c_at(self, num: np.ndarray, den: np.ndarray, x: np.ndarray) -> np.ndarray:
        """C at the points x (s or z values), (B, len(x)), by Horner (controllers are low order)."""
        cn = np.zeros((num.shape[0], x.size), complex)
        cd = np.zeros_like(cn)
        for k in range(num.shape[1]):
            cn = cn * x[None, :] + num[:, k:k + 1]
            cd = cd * x[None, :] + den[:, k:k + 1]
        with np.errstate(all="ignore"):
            return cn / cd

    # -- evaluation -----------------------------------------------------------------------------

    def evaluate(self, X: np.ndarray, *, incumbent_s: float | None = None) -> BatchResult:
        """Score every row of ``X`` (structure parameters).

        ``incumbent_s``: the best feasible settling time (or, for other objectives, the horizon that matters)
        found so far. A candidate is then simulated over at most three times that: if it has not settled by
        then it is worse than the incumbent anyway, and is scored as not settled."""
        self._incumbent = incumbent_s
        X = np.atleast_2d(np.asarray(X, dtype=float))
        self.n_evals += X.shape[0]
        num, den, ok, num_r = self.usable_controllers(X)
        # what every plant's loop shares (the plants share the frequency grid): the controllers' responses on it
        # (numpy path) and their state-space realisations, each made once a batch, not once a plant (bitwise the same)
        x = 1j * self.w if self.dt is None else np.exp(1j * self.w * self.dt)
        C = self._c_at(num, den, x) if self.kernels is None else None
        realized = _realize(num, den, num_r)
        per_plant = [self._evaluate_plant(pd, num, den, ok, num_r, C=C, realized=realized) for pd in self.plants]
        # the controller's own figure (every plant alike): |Ki|, once a batch
        ki = np.abs(self.integral_gain(X)) if "ki" in self._needs or self.spec.objective == "ie" else None
        if "ki" in self._needs:
            for m in per_plant:
                m["ki"] = ki
        return self._combine(per_plant, X, ki)

    def usable_controllers(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """``(num, den, ok, num_r)`` of the rows of ``X``: the controllers' coefficients (:meth:`controllers`,
        :meth:`controllers_r`), ``ok`` where they are finite with a leading denominator coefficient, the other rows
        replaced by the controller 0/1 (scored as not usable by what follows)."""
        num, den = self.controllers(X)
        ok = np.all(np.isfinite(num), axis=1) & np.all(np.isfinite(den), axis=1) & (np.abs(den[:, 0]) > 0)
        num_r = self.controllers_r(X, den.shape[1])
        if num_r is not None:
            ok &= np.all(np.isfinite(num_r), axis=1)
            num_r = np.where(ok[:, None], num_r, 0.0)
        num = np.where(ok[:, None], num, 0.0)
        den = np.where(ok[:, None], den, 1.0)
        return num, den, ok, num_r

    def _evaluate_plant(self, pd: _PlantData, num, den, ok, num_r=None, *, C: np.ndarray | None = None,
                        realized: tuple[np.ndarray, ...] | None = None) -> dict[str, np.ndarray]:
        """One plant's metrics; ``num_r``: the 2-DOF reference path (the frequency metrics are the feedback's).
        ``C``: the controllers' responses on the grid (numpy path), ``realized``: :func:`_realize` of the
        controllers, where the caller has them (the same for every plant); else computed here."""
        m: dict[str, np.ndarray] = {}
        if self.kernels is not None:
            x = 1j * self.w if self.dt is None else np.exp(1j * self.w * self.dt)
            with np.errstate(all="ignore"):
                C, L = self.kernels.c_and_l(num, den, x, pd.G)
            m.update(_frequency_metrics(L, C, self.w, pd, num, den, self.dt, self._needs, kernels=self.kernels))
        else:
            if C is None:
                x = 1j * self.w if self.dt is None else np.exp(1j * self.w * self.dt)
                C = self._c_at(num, den, x)
            L = C * pd.G[None, :]
            m.update(_frequency_metrics(L, C, self.w, pd, num, den, self.dt, self._needs))
        cl = self._closed_loop(pd, num, den, num_r, realized=realized)
        if self.dt is None and pd.tau:
            A_eig = self._fine_delay_dense(pd, num, den, num_r=num_r)[0]
        else:
            A_eig = cl.A
        with np.errstate(all="ignore"):
            good = ok & np.all(np.isfinite(A_eig), axis=(1, 2))
            poles = np.full((A_eig.shape[0], A_eig.shape[1]), np.nan, complex)
            if good.any():
                poles[good] = np.linalg.eigvals(A_eig[good])
        # fmax.reduce: nanmax without its warning on the rows of candidates whose loop is not finite (all NaN: not
        # stable, scored as far outside)
        if self.dt is None and not pd.tau:
            out = np.fmax.reduce(poles.real, axis=1)
            tol = -STABILITY_MARGIN * np.maximum(1.0, np.fmax.reduce(np.abs(poles), axis=1))
            stable = good & (out < tol)
            sig = np.where(poles.real < 0, -poles.real, np.inf)
        else:
            h = self._fine_h(pd) if self.dt is None else self.dt
            r = np.fmax.reduce(np.abs(poles), axis=1)
            stable = good & (r < 1 - STABILITY_MARGIN)
            out = r - 1
            sig = -np.log(np.clip(np.abs(poles), 1e-300, None)) / h
            sig = np.where(np.isfinite(sig) & (sig > 0), sig, np.inf)
        m["stable"] = stable
        m["outside"] = np.where(stable, 0.0, np.where(np.isfinite(out), np.maximum(out, 1e-9), 1e3))
        smin = np.min(sig, axis=1)
        m.update(self._time_metrics(pd, cl, stable, smin, num, den, num_r))
        if num_r is not None and self.spec.zero_steady_state_error and not self.problem.variation:
            # a separate setpoint path: zero error must not rest on a feed-forward matched to the nominal gain (a set
            # with gain-variation members checks each member's own error: :attr:`TuningProblem.variation`). With
            # integral action the error is zero at every gain (the reference and the feedback share the integrator):
            # only the rows without it (no pole at DC, or one its zero cancels) can rest on a matched feed-forward
            dc = 1.0 if self.dt is not None else 0.0
            with np.errstate(all="ignore"):
                none = np.abs(np.polyval(den.T, dc)) > 1e-12 * np.max(np.abs(den), axis=1)
                none |= np.abs(np.polyval(num.T, dc)) <= 1e-12 * np.max(np.abs(num), axis=1)
            if none.any():
                sel = np.flatnonzero(none)
                err = self._gain_varied_error(pd, num[sel], den[sel], num_r[sel])
                m["steady_state_error"][sel] = np.fmax(np.abs(m["steady_state_error"][sel]), err)
        return m

    def _gain_varied_error(self, pd: _PlantData, num, den, num_r) -> np.ndarray:
        """The largest steady-state error of the unit reference step with the plant's gain times each of
        :data:`tuner.analysis.verify.GAIN_VARIATION` (the verifier's ``steady_state_error`` of a 2-DOF loop)."""
        from dataclasses import replace as _replace

        from ..analysis.verify import GAIN_VARIATION

        worst = np.zeros(num.shape[0])
        for k in GAIN_VARIATION:
            cl = self._closed_loop(_replace(pd, C=pd.C * k, D=pd.D * k), num, den, num_r)
            Mdc = (np.eye(cl.A.shape[1])[None] - cl.A) if self.dt is not None else -cl.A
            zf = _solve_dc(Mdc, cl.Bm[:, :, 0])
            with np.errstate(all="ignore"):
                e = np.abs(1.0 - (np.einsum("bz,bz->b", zf, cl.Cy) + cl.Dy[:, 0]))
            worst = np.fmax(worst, np.where(np.isfinite(e), e, np.inf))
        return worst

    # -- closed loops ---------------------------------------------------------------------------

    def _closed_loop(self, pd: _PlantData, num, den, num_r=None, *, realized: tuple[np.ndarray, ...] | None = None
                     ) -> StackedLoops:
        """The stacked closed loops (B, nz, nz) with inputs [r, w] and the maps to y, u and the plant input
        (``num_r``: a 2-DOF controller's reference path, ``u = C_r r - C y`` on shared states; ``realized``:
        :func:`_realize` of the controllers, where the caller has it: read here, never written)."""
        Ac, Bc, Cc, Dc, Br, Dr = _realize(num, den, num_r) if realized is None else realized
        Bn, m = Bc.shape
        n = pd.Phi.shape[0]
        d = pd.d if self.dt is not None else 0
        if self.dt is None and pd.tau:
            d = 0  # the delay is in the fine model (simulation), not in this matrix
        nz = n + d + m
        ix, ic = slice(0, n), slice(n + d, nz)
        A = np.zeros((Bn, nz, nz))
        Bm = np.zeros((Bn, nz, 2))
        g_C, g_D = pd.C, pd.D
        e_r = np.array([1.0, 0.0])
        if d > 0:
            Ca = np.zeros((Bn, nz))
            Ca[:, n + d - 1] = 1.0
            Da = np.zeros((Bn, 2))
            Cy = np.zeros((Bn, nz))
            Cy[:, :n] = g_C
            Cy = Cy + g_D * Ca
            Dy = g_D * Da
            Cu = -Dc[:, None] * Cy
            Cu[:, ic] += Cc
            Du = Dc[:, None] * (e_r[None, :] - Dy) if Br is None else \
                np.stack([Dr, np.zeros(Bn)], axis=1) - Dc[:, None] * Dy
        else:
            dnm = 1.0 + Dc * g_D
            dnm = np.where(np.abs(dnm) < ALGEBRAIC_LOOP_TOL, np.nan, dnm)
            Cu = np.zeros((Bn, nz))
            Cu[:, ix] = -(Dc / dnm)[:, None] * g_C[None, :]
            Cu[:, ic] = Cc / dnm[:, None]
            Du = np.stack([Dc if Br is None else Dr, -Dc * g_D], axis=1) / dnm[:, None]
            Ca, Da = Cu.copy(), Du + np.array([0.0, 1.0])
            Cy = np.zeros((Bn, nz))
            Cy[:, :n] = g_C
            Cy = Cy + g_D * Ca
            Dy = g_D * Da
        Ce, De = -Cy, e_r[None, :] - Dy
        A[:, ix, :] += pd.Gam[None, :, None] * Ca[:, None, :]
        A[:, ix, ix] += pd.Phi[None]
        Bm[:, ix, :] += pd.Gam[None, :, None] * Da[:, None, :]
        if d > 0:
            A[:, n, :] = Cu
            Bm[:, n, :] = Du + np.array([0.0, 1.0])
            for j in range(1, d):
                A[:, n + j, n + j - 1] = 1.0
        A[:, ic, :] += Bc[:, :, None] * Ce[:, None, :]
        A[:, ic, ic] += Ac
        if Br is None:
            Bm[:, ic, :] += Bc[:, :, None] * De[:, None, :]
        else:  # 2-DOF: the controller's states take Br r - B y
            Bm[:, ic, :] += Bc[:, :, None] * (-Dy)[:, None, :]
            Bm[:, ic, 0] += Br
        return StackedLoops(A, Bm, Cy, Dy, Cu, Du, Ca, Da, n)

    def _fine_h(self, pd: _PlantData) -> float:
        return pd.tau / 20.0

    def _fine_delay_dense(self, pd: _PlantData, num, den, h: float | None = None, num_r=None
                          ) -> tuple[np.ndarray, ...]:
        """The fine sampled model of a continuous loop with delay at step ``h`` (default tau/20, for the poles):
        plant ZOH with the delay on a shifted grid, controller Tustin. States [plant, register of the plant's
        past inputs (m+1), controller]; returns (A, Bm, Cy, Cu)."""
        h = self._fine_h(pd) if h is None else h
        Phi, G_old, G_new, mreg, f = zoh_delayed(_SS(pd.Phi, pd.Gam, pd.C, pd.D), h, pd.tau)
        Ac0, Bc0, Cc0, Dc0, Br0, Dr0 = _realize(num, den, num_r)
        Ac, Bc, Cc, Dc = _tustin_batch(Ac0, Bc0, Cc0, Dc0, h)
        Br, Dr = (Bc, Dc) if Br0 is None else _tustin_batch(Ac0, Br0, Cc0, Dr0, h)[1::2]
        Bn, m = Bc.shape
        n, nr = Phi.shape[0], mreg + 1
        nz = n + nr + m
        ic = slice(n + nr, nz)
        a_y = np.zeros(nz)
        a_y[n + mreg - 1 if f == 0.0 else n + mreg] = 1.0
        Cy = np.broadcast_to(np.concatenate([pd.C, np.zeros(nr + m)]) + pd.D * a_y, (Bn, nz)).copy()
        Cu = -Dc[:, None] * Cy
        Cu[:, ic] += Cc
        Du = np.stack([Dr, np.zeros(Bn)], axis=1)  # u = Cu z + Dr r
        v_in = Du + np.array([0.0, 1.0])  # the register takes u + w
        A = np.zeros((Bn, nz, nz))
        Bm = np.zeros((Bn, nz, 2))
        A[:, :n, :n] = Phi
        A[:, :n, n + mreg] += G_old
        if mreg >= 1:
            A[:, :n, n + mreg - 1] += G_new
        else:
            A[:, :n, :] += G_new[None, :, None] * Cu[:, None, :]
            Bm[:, :n, :] += G_new[None, :, None] * v_in[:, None, :]
        A[:, n, :] += Cu
        Bm[:, n, :] += v_in
        for j in range(1, nr):
            A[:, n + j, n + j - 1] = 1.0
        A[:, ic, :] += Bc[:, :, None] * (-Cy)[:, None, :]
        A[:, ic, ic] += Ac
        Bm[:, ic, 0] += Br
        return A, Bm, Cy, Cu, Du

    # -- time responses -------------------------------------------------------------------------

    def _row_horizons(self, smin: np.ndarray, pd: _PlantData) -> np.ndarray:
        """Each candidate's own horizon: ten time constants of its slowest closed-loop pole (at least
        ``MIN_HORIZON_W0 / w0``), plus twice the delay."""
        with np.errstate(all="ignore"):
            T = np.where(np.isfinite(smin) & (smin > 0), 10.0 / smin, self.horizon_floor)
        T = np.maximum(T, self.horizon_floor) + 2 * (pd.tau + pd.d * (self.dt or 0))
        inc = getattr(self, "_incumbent", None)
        if inc is not None and math.isfinite(inc):
            T = np.minimum(T, max(3.0 * inc, self.horizon_floor))
        return T

    def _classes(self, T: np.ndarray, step: float) -> list[tuple[int, np.ndarray]]:
        """Rows grouped by the number of steps they need (powers of two, at least 32, at most MAX_SAMPLES):
        every row is simulated over at least its own horizon; a longer one costs at most twice."""
        K = np.minimum(np.ceil(T / step).astype(np.int64) + 1, MAX_SAMPLES)
        Kc = np.maximum(32, 2 ** np.ceil(np.log2(np.maximum(K, 1))).astype(np.int64))
        Kc = np.minimum(Kc, MAX_SAMPLES)
        return [(int(k), np.flatnonzero(Kc == k)) for k in np.unique(Kc)]

    @property
    def rows_independent(self) -> bool:
        """Whether a row's figures depend only on that row: not for a continuous loop with a delay, simulated at a
        step and over a horizon its whole batch shares (the batch's shortest settling class, its longest horizon:
        :meth:`_time_metrics`)."""
        return self.dt is not None or not any(pd.tau for pd in self.plants)

    def _time_metrics(self, pd: _PlantData, cl: StackedLoops, stable, smin, num, den, num_r=None
                      ) -> dict[str, np.ndarray]:
        spec = self.spec
        Bn = cl.A.shape[0]
        need_load = spec.objective == "iae" or self.load_recovery
        need_itae = spec.objective == "itae" or self.all_figures
        res = {k: np.full(Bn, np.nan) for k in ("overshoot_pct", "steady_state_error", "control_peak", "iae",
                                                   "itae", "load_recovery_s")}
        res["settling_time_s"] = np.full(Bn, np.inf)
        idx = np.flatnonzero(stable)
        if idx.size == 0:
            res["horizon_s"] = np.full(Bn, np.nan)
            return res
        T = self._row_horizons(smin[idx], pd)
        res["horizon_s"] = np.full(Bn, np.nan)
        res["horizon_s"][idx] = T
        band = spec.settling_band_pct / 100.0 * GUARD["band"]
        if self.dt is None and not pd.tau:
            groups = [(CONTINUOUS_STEPS + 1, np.arange(idx.size))]  # a step per row: T/CONTINUOUS_STEPS
        else:
            step = self.dt if self.dt is not None else None
            if step is None:  # continuous with delay: one fine step per class
                groups = [(CONTINUOUS_STEPS + 1, r) for _, r in self._classes(T, T.min() / CONTINUOUS_STEPS)]
            else:
                groups = self._classes(T, step)
        for K, rows in groups:
            sel = idx[rows]
            Tr = T[rows]
            if self.kernels is not None and self.dt is not None:
                self._time_kernel(pd, cl.rows(sel), K, sel, res, band, need_load)
                continue
            if self.dt is None and pd.tau:
                sim, args = self._simulate_fine_delay, (pd, num[sel], den[sel], float(Tr.max()),
                                                        None if num_r is None else num_r[sel])
            else:
                sim, args = self._simulate, (pd, cl.rows(sel), Tr, K)
            y, u, t, yf = sim(*args, 0)
            with np.errstate(all="ignore"):
                yn = y / yf[:, None]
                ts = _settling(t, yn, band)
                res["settling_time_s"][sel] = np.where(np.isfinite(yf) & (yf != 0), ts, np.inf)
                res["overshoot_pct"][sel] = np.maximum(0.0, (np.max(yn, axis=1) - 1.0) * 100.0)
                res["steady_state_error"][sel] = 1.0 - yf
                res["control_peak"][sel] = np.max(np.abs(u), axis=1)  # (u per sample: its rows between are alike)
                if self.dt is None and pd.tau:  # the Tustin controller's first output is C(2/h), not the kick C(inf)
                    lead = (num_r[sel] if num_r is not None else num[sel])[:, 0] / den[sel][:, 0]
                    res["control_peak"][sel] = np.maximum(res["control_peak"][sel], np.abs(lead))
                if need_itae:
                    res["itae"][sel] = np.trapezoid(t * np.abs(1.0 - y), t, axis=1)
                if need_load:
                    yl, _, tl, _ = sim(*args, 1)
                    res["iae"][sel] = np.trapezoid(np.abs(yl), tl, axis=1)
                    if self.load_recovery:
                        res["load_recovery_s"][sel] = _recovery(tl, np.abs(yl))
        return res

    def _time_kernel(self, pd: _PlantData, cl: StackedLoops, K: int, sel: np.ndarray, res: dict[str, np.ndarray],
                     band: float, need_load: bool) -> None:
        """:meth:`_time_metrics` of sampled-data loops by the compiled kernel (the same figures as the numpy path's
        :meth:`_simulate` and :func:`_settling`, :func:`_recovery`), into ``res``'s rows ``sel``."""
        from ..analysis.verify import LOAD_RECOVERY_SHARE

        f = np.ascontiguousarray
        nf = 0 if pd.Cf is None else pd.Cf.shape[0]
        Cf = f(pd.Cf, dtype=float) if nf else np.zeros((0, cl.n_plant))
        Df = f(pd.Df, dtype=float) if nf else np.zeros(0)
        off = f(pd.offsets, dtype=float) if nf else np.zeros(0)

        def args(inp: int) -> tuple:
            return (f(cl.A), f(cl.Bm[:, :, inp]), f(cl.Cy), f(cl.Dy[:, inp]), f(cl.Cu), f(cl.Du[:, inp]), f(cl.Ca),
                    f(cl.Da[:, inp]), Cf, Df, int(cl.n_plant), int(K), float(self.dt), off)

        yf = self._final(cl, 0)
        with np.errstate(all="ignore"):
            ts, ov, cpk, itae, _, _ = self.kernels.step_sampled(*args(0), f(yf), band, True, False, False, 0.0)
            res["settling_time_s"][sel] = ts
            res["overshoot_pct"][sel] = ov
            res["steady_state_error"][sel] = 1.0 - yf
            res["control_peak"][sel] = cpk
            if self.spec.objective == "itae" or self.all_figures:
                res["itae"][sel] = itae
            if need_load:
                _, _, _, _, iae, rec = self.kernels.step_sampled(*args(1), np.ones(len(sel)), band, False, True,
                                                                 bool(self.load_recovery), LOAD_RECOVERY_SHARE)
                res["iae"][sel] = iae
                if self.load_recovery:
                    res["load_recovery_s"][sel] = rec

    def _final(self, cl: StackedLoops, inp: int) -> np.ndarray:
        """The final value of each loop's output after a unit step at input ``inp`` (nan where not defined)."""
        nz = cl.A.shape[1]
        Mdc = (np.eye(nz)[None] - cl.A) if self.dt is not None else -cl.A
        zf = _solve_dc(Mdc, cl.Bm[:, :, inp])
        return np.einsum("bz,bz->b", zf, cl.Cy) + cl.Dy[:, inp]

    def _simulate(self, pd: _PlantData, cl: StackedLoops, T, K, inp):
        """Unit step responses of stacked closed loops: (y, u, t, y_final), t per row (B, points); ``u`` at the
        points, or (the rows between samples) once a sample."""
        A, Bm, Cy, Dy, Cu, Du, Ca, Da, n = cl.A, cl.Bm, cl.Cy, cl.Dy, cl.Cu, cl.Du, cl.Ca, cl.Da, cl.n_plant
        Bn, nz, _ = A.shape
        if self.dt is None:  # continuous, no delay: exact discretisation at each row's own fine step
            h = T / CONTINUOUS_STEPS
            M = np.zeros((Bn, nz + 1, nz + 1))
            M[:, :nz, :nz] = A * h[:, None, None]
            M[:, :nz, nz] = Bm[:, :, inp] * h[:, None]
            with np.errstate(all="ignore"):
                E = linalg.expm(M)
            Z = _run(E[:, :nz, :nz], E[:, :nz, nz], K)
            y = np.einsum("bkz,bz->bk", Z, Cy) + Dy[:, inp, None]
            u = np.einsum("bkz,bz->bk", Z, Cu) + Du[:, inp, None]
            t = np.arange(K)[None, :] * h[:, None]
        else:
            Z = _run(A, Bm[:, :, inp], K)
            u = np.einsum("bkz,bz->bk", Z, Cu) + Du[:, inp, None]
            if pd.Cf is not None:  # (the output between the samples: its rows at the samples are the output there)
                ua = np.einsum("bkz,bz->bk", Z, Ca) + Da[:, inp, None]
                y = (np.einsum("bkn,jn->bkj", Z[:, :, :n], pd.Cf) + ua[:, :, None] * pd.Df[None, None, :])
                nf = pd.Cf.shape[0]
                y = y.reshape(Bn, K * nf)
                t = np.broadcast_to((np.arange(K)[:, None] * self.dt + pd.offsets[None, :]).ravel(), y.shape)
            else:
                y = np.einsum("bkz,bz->bk", Z, Cy) + Dy[:, inp, None]
                t = np.broadcast_to(np.arange(K) * self.dt, y.shape)
        return y, u, t, self._final(cl, inp)

    def _simulate_fine_delay(self, pd, num, den, T, num_r, inp):
        """Continuous loop with delay at the fine step T/CONTINUOUS_STEPS (plant exact, controller Tustin)."""
        h = T / CONTINUOUS_STEPS
        K = CONTINUOUS_STEPS + 1
        A, Bm, Cy, Cu, Du = self._fine_delay_dense(pd, num, den, h, num_r=num_r)
        Z = _run(A, Bm[:, :, inp], K)
        y = np.einsum("bkz,bz->bk", Z, Cy)
        u = np.einsum("bkz,bz->bk", Z, Cu) + Du[:, inp, None]
        # steady state of the delay-free continuous loop (e^{-s tau} = 1 at s = 0)
        cl0 = self._closed_loop(pd, num, den, num_r)
        zf = _solve_dc(-cl0.A, cl0.Bm[:, :, inp])
        yf = np.einsum("bz,bz->b", zf, cl0.Cy) + cl0.Dy[:, inp]
        return y, u, np.broadcast_to(np.arange(K) * h, y.shape), yf

    # -- scoring --------------------------------------------------------------------------------

    def _combine(self, per_plant: list[dict[str, np.ndarray]], X: np.ndarray, ki: np.ndarray | None = None
                 ) -> BatchResult:
        spec = self.spec
        Bn = X.shape[0]
        viol = np.zeros(Bn)
        unstable = np.zeros(Bn, bool)
        outside = np.zeros(Bn)
        obj = np.full(Bn, -np.inf)
        g = GUARD
        for i, m in enumerate(per_plant):
            unstable |= ~m["stable"]
            outside = np.maximum(outside, m["outside"])
            v = np.zeros(Bn)
            pm_min, gm_min = self.margins[i]  # (a gain-variation member's: TuningProblem.plant_spec)
            v += _viol_ge(m["pm"], pm_min + g["margin_deg"] * (pm_min > 0), max(pm_min, 1.0))
            v += _viol_ge(m["gm"], gm_min + g["margin_db"] * (gm_min > 0), max(gm_min, 1.0))
            v += _viol_le(m["gml"], -gm_min - g["margin_db"] * (gm_min > 0), max(gm_min, 1.0))
            v += _viol_le(m["overshoot_pct"], spec.overshoot_max_pct * g["overshoot"], max(spec.overshoot_max_pct, 1.0))
            if spec.zero_steady_state_error:
                v += _viol_le(np.abs(m["steady_state_error"]), SSE_TOL * 0.5, 1.0)
            for lim in _SIMPLE:  # every other limit of the registry the batch computes, held a little inside
                value = getattr(spec, lim.field)
                if value is not None:
                    inside = lim.search_limit(value)
                    v += (_viol_le(m[lim.batch], inside, value) if lim.sense < 0 else
                          _viol_ge(m[lim.batch], inside, value))
            if spec.crossover_rad_s is not None:  # within +-1 % (a little inside in the search)
                err = np.abs(m["wc"] - spec.crossover_rad_s) / spec.crossover_rad_s
                v += np.where(np.isfinite(err), np.maximum(err - 0.9 * CROSSOVER_TOL, 0.0), 10.0)
            v += np.where(np.isfinite(m["settling_time_s"]), 0.0, 10.0)
            viol += v
            obj = np.maximum(obj, self._objective(m, X, ki))
        if rules.applies(self.st, spec):  # the derivative-filter rule, on the parameters
            viol += _viol_le(rules.filter_n_batch(self.st, X), spec.filter_n_max, spec.filter_n_max)
        score = np.where(viol > 0, INFEASIBLE * (1.0 + viol), obj)
        score = np.where(np.isfinite(score), score, INFEASIBLE * 20)
        score = np.where(unstable, UNSTABLE * (1.0 + np.minimum(outside, 1e3)), score)
        feasible = (~unstable) & (viol == 0) & np.isfinite(obj)
        metrics = {k: np.max(np.stack([m[k] for m in per_plant]), axis=0) for k in
                   ("settling_time_s", "overshoot_pct", "control_peak")}
        return BatchResult(score=score, feasible=feasible, violation=viol, metrics=metrics, per_plant=per_plant)

    def _objective(self, m: dict[str, np.ndarray], X: np.ndarray, ki: np.ndarray | None = None) -> np.ndarray:
        o = self.spec.objective
        if o == "settling_time":
            return m["settling_time_s"]
        if o == "iae":
            return m["iae"]
        if o == "itae":
            return m["itae"]
        if o == "ie":  # |1/Ki|: a stabilising Ki has the sign of the plant's static gain (negative for G(0) < 0)
            ki = np.abs(self.integral_gain(X)) if ki is None else ki
            return np.where(ki > 0, 1.0 / np.where(ki > 0, ki, 1.0), np.inf)
        if o == "mks":
            return m["mks"]
        if o == "disk_margin":
            return -m["dm"]
        return -m["bw"]  # bandwidth

    def integral_gain(self, X: np.ndarray) -> np.ndarray:
        """``lim s C(s)`` (continuous) or ``lim (z - 1) C(z) / dt`` (discrete): the controller's integral gain,
        ``1/IE`` after a unit load step; 0 without integral action."""
        num, den = self.controllers(np.atleast_2d(X))
        x = 0.0 if self.dt is None else 1.0
        # den has a root at x: divide it out (synthetic division), then evaluate at x
        q = den.copy()
        for k in range(1, q.shape[1]):
            q[:, k] = q[:, k] + q[:, k - 1] * x
        rem = q[:, -1]
        quot = q[:, :-1]
        with np.errstate(all="ignore"):
            val = np.polyval(num.T, x) / np.polyval(quot.T, x) if quot.shape[1] else np.zeros(num.shape[0])
        ki = np.where(np.abs(rem) < 1e-12 * np.max(np.abs(den), axis=1), val, 0.0)
        return ki / (self.dt or 1.0)


@dataclass(frozen=True)
class _SS:  # the plant's (A, B, C, D) for zoh_delayed
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: float

    @property
    def n(self) -> int:
        return self.A.shape[0]


def _tustin_batch(A, B, C, D, h):
    """Tustin of stacked continuous controllers (B, m, m)."""
    Bn, m = B.shape
    if m == 0:
        return A, B, C, D
    eye = np.eye(m)[None]
    ima = eye - A * (h / 2)
    inv = np.linalg.inv(ima)
    Ad = inv @ (eye + A * (h / 2))
    Bd = np.einsum("bij,bj->bi", inv, B * h)
    Cd = np.einsum("bj,bji->bi", C, inv)
    Dd = D + 0.5 * np.einsum("bi,bi->b", C, Bd)
    return Ad, Bd, Cd, Dd


def _solve_dc(M: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The steady states ``M z = b`` of a stack (B, n, n), (B, n); a loop whose matrix is singular in double
    precision (stable, but with gains near 1e300) gets NaN, its final value unknown, instead of failing the
    whole batch (numpy solves a stack all or nothing)."""
    with np.errstate(all="ignore"):
        try:
            return np.linalg.solve(M, b[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            z = np.full(b.shape, np.nan)
            for i in range(M.shape[0]):
                try:
                    z[i] = np.linalg.solve(M[i], b[i])
                except np.linalg.LinAlgError:
                    pass
            return z


def _run(A: np.ndarray, b: np.ndarray, K: int) -> np.ndarray:
    """States (B, K, nz) of z_{k+1} = A z_k + b from z_0 = 0, by doubling: z_{k+m} = A^m z_k + z_m, so K
    states cost log2(K) batched matrix products instead of K small ones."""
    Bn, nz, _ = A.shape
    Z = np.zeros((Bn, K, nz))
    if K <= 1:
        return Z
    with np.errstate(all="ignore"):
        Z[:, 1] = b
        m, Am = 1, A.copy()  # Z[:, :m+1] known, Am = A^m
        while m + 1 < K:
            k = min(m, K - 1 - m)  # states m+1 .. m+k from states 1 .. k
            Z[:, m + 1:m + 1 + k] = np.matmul(Z[:, 1:1 + k], np.swapaxes(Am, 1, 2)) + Z[:, m:m + 1]
            Am = Am @ Am
            m *= 2
    return Z


def _recovery(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per row: the last time ``|y|`` (rows of a load step's response, ``y >= 0``) is above
    :data:`tuner.analysis.verify.LOAD_RECOVERY_SHARE` of its peak, interpolated as the verifier does; inf where the
    last point is above it (not back within the horizon)."""
    from ..analysis.verify import LOAD_RECOVERY_SHARE

    peak = np.max(y, axis=1)
    thr = LOAD_RECOVERY_SHARE * peak
    above = y > thr[:, None]
    K = y.shape[1]
    last = K - 1 - np.argmax(above[:, ::-1], axis=1)  # the last index above (0 if none)
    out = np.full(y.shape[0], np.inf)
    back = ~above[:, -1]
    j = np.clip(last, 0, K - 2)
    rows = np.arange(y.shape[0])
    t0, t1 = t[rows, j] if t.ndim == 2 else t[j], t[rows, j + 1] if t.ndim == 2 else t[j + 1]
    e0, e1 = y[rows, j], y[rows, j + 1]
    with np.errstate(all="ignore"):
        rec = np.where(e0 > e1, t0 + (e0 - thr) / (e0 - e1) * (t1 - t0), t1)
    out[back] = rec[back]
    out[back & ~np.any(above, axis=1)] = 0.0
    return out


def _settling(t: np.ndarray, yn: np.ndarray, band: float) -> np.ndarray:
    """Last time |yn - 1| > band (linear interpolation), inf if still outside at the end; per row (t per row)."""
    out = np.abs(yn - 1.0) > band
    B, K = yn.shape
    last = np.where(out.any(axis=1), K - 1 - np.argmax(out[:, ::-1], axis=1), -1)
    ts = np.zeros(B)
    still = last == K - 1
    mid = (last >= 0) & ~still
    j = last[mid]
    rows = np.flatnonzero(mid)
    y0, y1 = yn[rows, j], yn[rows, j + 1]
    level = np.where(y0 > 1.0, 1.0 + band, 1.0 - band)
    with np.errstate(all="ignore"):
        frac = np.where(y1 != y0, (level - y0) / (y1 - y0), 1.0)
    ts[rows] = t[rows, j] + frac * (t[rows, j + 1] - t[rows, j])
    ts[still] = np.inf
    ts[~np.all(np.isfinite(yn), axis=1)] = np.inf
    return ts


def _viol_ge(v: np.ndarray, req: float, scale: float) -> np.ndarray:
    with np.errstate(all="ignore"):
        d = np.where(np.isnan(v), 10.0, np.where(v >= req, 0.0, np.minimum((req - v) / scale, 10.0)))
    return np.where(np.isfinite(d), d, 10.0)


def _viol_le(v: np.ndarray, req: float, scale: float) -> np.ndarray:
    with np.errstate(all="ignore"):
        d = np.where(np.isnan(v), 10.0, np.where(v <= req, 0.0, np.minimum((v - req) / scale, 10.0)))
    return np.where(np.isfinite(d), d, 10.0)


def _first_crossing(w: np.ndarray, f: np.ndarray, *, falling: bool) -> np.ndarray:
    """Per row, the lowest frequency where ``f`` changes sign (to negative if ``falling``, else to >= 0), linear in
    log frequency between the grid's points; ``inf`` where it never does, ``w[0]`` where it has at the first point."""
    hit = (f < 0) if falling else (f >= 0)
    hit &= np.isfinite(f)
    any_ = hit.any(axis=1)
    i = np.argmax(hit, axis=1)
    rows = np.arange(f.shape[0])
    j = np.maximum(i - 1, 0)
    f0, f1 = f[rows, j], f[rows, i]
    lw = np.log(w)
    with np.errstate(all="ignore"):
        t = np.where((i > 0) & (f0 != f1) & np.isfinite(f0), f0 / (f0 - f1), 1.0)
    t = np.clip(t, 0.0, 1.0)
    x = np.exp(lw[j] + t * (lw[i] - lw[j]))
    return np.where(any_, np.where(i > 0, x, w[0]), np.inf)


def _ends(pd: _PlantData, num, den, dt) -> list[np.ndarray]:
    """Re L at DC (a plant that does not integrate) and at Nyquist (sampled loops), where the plant is finite there:
    gain factors for the gain margins, with no phase-crossover frequency."""
    ends = []
    x_dc = 0.0 if dt is None else 1.0
    if pd.G_dc is not None and np.isfinite(pd.G_dc):
        c_dc = np.polyval(num.T, x_dc) / np.polyval(den.T, x_dc)
        ends.append((c_dc * pd.G_dc).real)
    if dt is not None and pd.G_nyq is not None and np.isfinite(pd.G_nyq):
        c_ny = np.polyval(num.T, -1.0) / np.polyval(den.T, -1.0)
        ends.append((c_ny * pd.G_nyq).real)
    return ends


def _frequency_metrics(L: np.ndarray, C: np.ndarray, w: np.ndarray, pd: _PlantData, num, den, dt,
                       needs: frozenset[str] = frozenset({"ms", "mt", "mks", "dm", "bw", "drb"}), *,
                       kernels: Any = None) -> dict[str, Any]:
    """Phase margin, upper/lower gain margins and the crossover frequencies on the grid; Ms, Mt, Mks, disk
    margin and bandwidth where ``needs`` asks for them (nan otherwise). Crossings are found on the whole
    grid at once and interpolated only where they are (a few per candidate); ``kernels``: the margins by the
    compiled kernel (:func:`tuner.optimize.kernels.margins`, the same rules row by row)."""
    Bn = L.shape[0]
    nan = np.full(Bn, np.nan)
    lw = np.log(w)
    with np.errstate(all="ignore"):
        if kernels is not None:
            ends = _ends(pd, num, den, dt)
            E = np.stack(ends, axis=1) if ends else np.zeros((Bn, 0))
            pm, wc, gm, gml, wp = kernels.margins(L, lw, np.ascontiguousarray(E, dtype=float))
        else:
            pm, wc, gm, gml, wp = _margins(L, lw, pd, num, den, dt)
        out = {"pm": pm, "gm": gm, "gml": gml, "wc": wc, "wp": wp, "ms": nan, "mt": nan, "mks": nan, "dm": nan,
               "bw": nan, "drb": nan.copy()}
        _peak_metrics(out, L, C, w, pd, num, den, dt, needs)
    return out


def _margins(L: np.ndarray, lw: np.ndarray, pd: _PlantData, num, den, dt) -> tuple[np.ndarray, ...]:
    """The numpy path of :func:`_frequency_metrics`'s margins: ``(pm, wc, gm, gml, wp)`` per row."""
    Bn = L.shape[0]
    rows = np.arange(Bn)
    nan = np.full(Bn, np.nan)
    with np.errstate(all="ignore"):
        absL = np.abs(L)
        lm = np.log(absL)
        # gain crossings |L| = 1: linear interpolation of L between the grid points
        r, c = np.nonzero((lm[:, :-1] * lm[:, 1:] < 0) & np.isfinite(lm[:, :-1]) & np.isfinite(lm[:, 1:]))
        f = lm[r, c] / (lm[r, c] - lm[r, c + 1])
        Lc = L[r, c] + f * (L[r, c + 1] - L[r, c])
        pmv = 180.0 - np.abs(np.degrees(np.angle(Lc)))
        # the sign as the verifier's (tuner.analysis.margins._phase_margin): 180 + the phase unwrapped along the grid
        # from its lowest frequency (the principal angle there, less 360 above +90: a loop's phase at low frequency
        # is 0, -90 or -180 deg, not its alias just below +180), where it is within +-180 (else the distance)
        if r.size:
            # (unwrapped only as far as the last crossing: unwrap's correction is a running sum along the grid,
            # np.cumsum adding in order, so the points up to there are bitwise those of the whole grid's)
            ur = np.unique(r)
            ph = np.unwrap(np.angle(L[ur, :int(c.max()) + 2]), axis=1)
            row = np.searchsorted(ur, r)
            a0 = ph[:, :1]
            ph = ph - np.where(a0 > np.pi / 2 + 1e-9, 2 * np.pi, 0.0)
            pc = ph[row, c] + f * (ph[row, c + 1] - ph[row, c])
            signed = 180.0 + np.degrees(pc)
            pmv = np.where(np.isfinite(signed) & (np.abs(signed) <= 180.0) & (np.abs(np.abs(((signed + 180.0) % 360.0)
                                                                                     - 180.0) - pmv) < 1e-3),
                           signed, pmv)
        pm = np.full(Bn, np.inf)
        np.minimum.at(pm, r, pmv)
        wc = nan.copy()
        hit = pmv == pm[r]  # the crossing that sets each row's margin
        wc[r[hit]] = np.exp(lw[c[hit]] + f[hit] * (lw[c[hit] + 1] - lw[c[hit]]))
        # real-axis crossings: Im L sign changes (finite), the -1/Re as gain factors
        im = L.imag
        fin = np.isfinite(L) & (absL < 1e9)
        r2, c2 = np.nonzero((im[:, :-1] * im[:, 1:] < 0) & fin[:, :-1] & fin[:, 1:])
        g = im[r2, c2] / (im[r2, c2] - im[r2, c2 + 1])
        re = L.real[r2, c2] + g * (L.real[r2, c2 + 1] - L.real[r2, c2])
        wpv = np.exp(lw[c2] + g * (lw[c2 + 1] - lw[c2]))
        ends = _ends(pd, num, den, dt)
        rr = np.concatenate([r2] + [rows for _ in ends])
        res = np.concatenate([re] + ends)
        wps = np.concatenate([wpv] + [nan for _ in ends])  # (ends: _ends)  # the ends have no phase-crossover frequency
        k = np.where(res < 0, -1.0 / res, np.nan)
        kup = np.where(k > 1.0, k, np.inf)
        up = np.full(Bn, np.inf)
        np.minimum.at(up, rr, kup)
        wp = nan.copy()
        hit = np.isfinite(kup) & (kup == up[rr])
        wp[rr[hit]] = wps[hit]
        lo = np.zeros(Bn)
        np.maximum.at(lo, rr, np.where(k <= 1.0, k, 0.0))
        gm = 20 * np.log10(up)
        gml = np.where(lo > 0, 20 * np.log10(lo), -np.inf)
    return pm, wc, gm, gml, wp


def _peak_metrics(out: dict[str, Any], L, C, w, pd: _PlantData, num, den, dt, needs: frozenset[str]) -> None:
    """Ms, Mt, Mks, the disk margin, the bandwidth and the DRB into ``out``, where ``needs`` asks for them."""
    with np.errstate(all="ignore"):
        if needs & {"ms", "mt", "mks", "dm", "bw", "drb"}:
            finL = np.isfinite(L)
            S = 1.0 / (1.0 + L)
            if "ms" in needs:
                out["ms"] = np.max(np.where(finL, np.abs(S), 0.0), axis=1)
            if "mt" in needs or "bw" in needs:
                absT = np.abs(L * S)
                # |T(0)| exactly, as the verifier (1 where the loop integrates; the grid's lowest point is not w = 0)
                t0 = np.ones(L.shape[0])  # a plant that integrates
                if pd.G_dc is not None:
                    x_dc = 0.0 if dt is None else 1.0
                    L0 = np.polyval(num.T, x_dc) / np.polyval(den.T, x_dc) * pd.G_dc
                    t0 = np.where(np.isfinite(L0), np.abs(L0 / (1 + L0)), 1.0)
                    t0 = np.where(np.isnan(t0), np.abs(absT[:, 0]), t0)
                out["mt"] = np.maximum(np.max(np.where(finL, absT, 0.0), axis=1), np.where(np.isfinite(t0), t0, 0.0))
                if "bw" in needs:  # |T| first below |T(0)|/sqrt(2), interpolated in log frequency (as the verifier)
                    out["bw"] = _first_crossing(w, absT - t0[:, None] / math.sqrt(2), falling=True)
            if "drb" in needs:  # |S| first up to -3 dB, interpolated in log frequency (as the verifier)
                absS = np.where(finL, np.abs(S), np.nan)
                drb = _first_crossing(w, absS - 1.0 / math.sqrt(2), falling=False)
                out["drb"] = np.where(absS[:, 0] >= 1.0 / math.sqrt(2), 0.0, drb)
            if "mks" in needs:
                CS = np.abs(C * S)
                mks = np.max(np.where(np.isfinite(CS), CS, 0.0), axis=1)
                if dt is None:  # w -> inf: C(inf)/(1 + C(inf) G(inf))
                    c_inf = num[:, 0] / den[:, 0]
                    mks = np.maximum(mks, np.abs(c_inf / (1 + c_inf * pd.G_inf)))
                out["mks"] = mks
            if "dm" in needs:
                out["dm"] = np.min(np.where(finL, 2 * np.abs(1 + L) / np.abs(1 - L), np.inf), axis=1)
