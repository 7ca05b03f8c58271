"""What the benchmarks share: the study loops as a workload, the machine, and the alternatives
(Optuna alone, scipy's differential evolution) run on the same verifier as the tuner.

Used by ``bench/run_all.py`` (quality against a reference) and ``bench/tune_speed.py`` (speed).
Nothing here asserts a timing.
"""

from __future__ import annotations

import json
import math
import os
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tuner import Spec, get_structure  # noqa: E402
from tuner.optimize.engine import designed_starts  # noqa: E402
from tuner.optimize.scoring import Evaluator  # noqa: E402
from tuner.plant import Plant  # noqa: E402
from tuner.studies.evaluate import check_gains_file, evaluate_thesis, loop_plants  # noqa: E402
from tuner.studies.schema import load_study  # noqa: E402

__all__ = ["Loop", "load_loops", "canonical_key", "machine", "load_average", "verified", "Budgeted", "run_optuna",
           "run_de", "fmt", "STUDIES", "ATTITUDE_PID"]

# the benchmark workload: (study file, gains file whose controllers close the cascades' inner loops)
STUDIES = (("quadrotor.toml", "quadrotor.gains.json"), ("process.toml", None))
# the attitude loops are pid_z in the study; issue 12's target names pid too: these loops again with pid
ATTITUDE_PID = ("roll", "pitch", "yaw")


@dataclass
class Loop:
    study: str
    name: str
    plants: list[Plant]
    structure: str
    dt: float | None
    spec: Spec
    key: str
    thesis_settling: float | None = None
    tune_kw: dict[str, Any] = field(default_factory=dict)  # the loop's own n_trials / n_starts
    results: dict[str, Any] = field(default_factory=dict)
    # builds the plants again (new objects, none of their per-object caches): a timed tune gets fresh ones
    fresh: Callable[[], list[Plant]] | None = field(default=None, repr=False)

    def new_plants(self) -> list[Plant]:
        return self.fresh() if self.fresh is not None else self.plants

    @property
    def label(self) -> str:
        return f"{self.study}/{self.name}"

    @property
    def order(self) -> int:
        return max(p.order for p in self.plants)


def machine() -> dict[str, str]:
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import casadi
    import control
    import optuna
    import scipy

    return {"cpu": cpu, "cores": str(os.cpu_count()), "python": platform.python_version(),
            "os": platform.platform(), "numpy": np.__version__, "scipy": scipy.__version__,
            "control": control.__version__, "casadi": casadi.__version__, "optuna": optuna.__version__}


def load_average() -> list[float]:
    """The 1, 5 and 15 minute load averages (the machine may be shared)."""
    return [round(x, 2) for x in os.getloadavg()]


def load_loops(*, attitude_pid: bool = False) -> list[Loop]:
    """The loops of the benchmark studies, with their plants as the tuner sees them (a cascade's outer
    plant around its inner loop closed with the published gains); ``attitude_pid`` adds roll, pitch
    and yaw with structure ``pid`` (named ``roll (pid)`` ...)."""
    loops: list[Loop] = []
    for fname, gains in STUDIES:
        study = load_study(ROOT / "studies" / fname)
        ctrls = {}
        if gains:
            ctrls = check_gains_file(study, json.loads((ROOT / "studies" / gains).read_text()))
        thesis = evaluate_thesis(study, ctrls) if gains else {}
        variants = [(lp, lp.name) for lp in study.order()]
        if attitude_pid:
            variants += [(lp.model_copy(update={"structure": "pid"}), f"{lp.name} (pid)")
                         for lp in study.order() if lp.name in ATTITUDE_PID and lp.structure != "pid"]
        for lp, name in variants:
            plants = loop_plants(study, lp, ctrls)
            th = thesis.get(lp.name) if name == lp.name else None
            ts = None
            if th is not None:
                ts = max(a.metrics.settling_time_s if a.metrics.stable else math.inf for a in th.analyses)
            key = canonical_key(json.dumps([fname, lp.name, lp.structure, lp.dt, [p.describe() for p in plants],
                                            lp.spec.model_dump()], default=str))
            kw = {k: v for k, v in (("n_trials", lp.n_trials), ("n_starts", lp.n_starts)) if v is not None}
            loops.append(Loop(study.name, name, plants, lp.structure, lp.dt, lp.spec, key, ts, kw,
                              fresh=partial(loop_plants, study, lp, ctrls)))
    return loops


def canonical_key(key: str) -> str:
    """A loop's key (study file, name, structure, dt, plants, spec) with the spec's unset (None) fields
    left out, so that a field added to Spec later does not change the key of a loop that leaves it unset."""
    *head, spec = json.loads(key)
    return json.dumps([*head, {k: v for k, v in spec.items() if v is not None}], sort_keys=True, default=str)


def verified(ev: Evaluator, x: np.ndarray) -> float:
    """The verifier's settling time at full resolution (worst over the plants); inf if infeasible."""
    s = ev.score(x, full=True)
    return s.score if s.feasible else math.inf


class Budgeted:
    """An objective that records the best search-resolution candidate and can stop at a target."""

    def __init__(self, ev: Evaluator, space, *, target: float | None, cap_s: float, max_evals: int | None):
        self.ev, self.space, self.target, self.cap_s, self.max_evals = ev, space, target, cap_s, max_evals
        self.t0 = time.perf_counter()
        self.n = 0
        self.best = (math.inf, None)
        self.reached_s = math.inf
        self.best_verified = math.inf

    class Stop(Exception):
        pass

    def __call__(self, v: np.ndarray) -> float:
        if time.perf_counter() - self.t0 > self.cap_s or (self.max_evals and self.n >= self.max_evals):
            raise Budgeted.Stop
        self.n += 1
        s = self.ev.score(self.space.params(v)).score
        if s < self.best[0]:
            self.best = (s, np.array(v, dtype=float))
            if self.target is not None and s < 1e3 and s <= self.target * 1.05:
                ts = verified(self.ev, self.space.params(v))
                self.best_verified = min(self.best_verified, ts)
                if ts <= self.target:
                    self.reached_s = time.perf_counter() - self.t0
                    raise Budgeted.Stop
        return s

    def finish(self) -> float:
        if self.best[1] is not None:
            self.best_verified = min(self.best_verified, verified(self.ev, self.space.params(self.best[1])))
        return self.best_verified


def _budgeted(lp: Loop, *, target: float | None, cap_s: float, max_evals: int | None):
    from tuner.optimize.space import make_space

    st = get_structure(lp.structure)
    space = make_space(st, lp.plants[0], lp.dt)
    return space, Budgeted(Evaluator(lp.plants, st, lp.dt, lp.spec), space, target=target, cap_s=cap_s,
                           max_evals=max_evals)


def run_optuna(lp: Loop, *, seed: int, target: float | None, cap_s: float, max_evals: int | None) -> Budgeted:
    """Optuna's seeded TPE alone (the tuner's plant-based starts enqueued first), on the verifier."""
    import optuna

    from tuner.optimize.search import default_sampler

    space, b = _budgeted(lp, target=target, cap_s=cap_s, max_evals=max_evals)
    study = optuna.create_study(direction="minimize", sampler=default_sampler(seed, len(space.names)))
    dists = {n: optuna.distributions.FloatDistribution(float(a), float(z))
             for n, a, z in zip(space.names, space.lo, space.hi)}
    for v in designed_starts(space, lp.plants[0], lp.dt):
        study.enqueue_trial(dict(zip(space.names, map(float, v))))
    try:
        while True:
            tr = study.ask(dists)
            study.tell(tr, b(np.array([tr.params[n] for n in space.names])))
    except Budgeted.Stop:
        pass
    b.finish()
    return b


def run_de(lp: Loop, *, seed: int, target: float | None, cap_s: float, max_evals: int | None,
           popsize: int = 15) -> Budgeted:
    """scipy's differential evolution (Sobol initialisation, no polish) on the verifier."""
    from scipy.optimize import differential_evolution

    space, b = _budgeted(lp, target=target, cap_s=cap_s, max_evals=max_evals)
    try:
        differential_evolution(b, list(zip(space.lo, space.hi)), seed=seed, popsize=popsize, maxiter=100000,
                               tol=0, atol=0, polish=False, init="sobol")
    except Budgeted.Stop:
        pass
    b.finish()
    return b


def fmt(x: float | str | None, d: int = 3) -> str:
    if x is None:
        return "—"
    if isinstance(x, str):
        return x
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "∞"
    return f"{x:.{d}f}"
