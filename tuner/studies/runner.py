"""Running a study: workers that share its loops through an Optuna storage.

The storage (SQLite by default, PostgreSQL for several machines) is the only coordination
point. Each loop is one Optuna study, ``<study>:<loop>:<key>@<epoch>``, whose trials are the
attempts at tuning it; a worker holds the loop while it holds a RUNNING trial.

What Optuna provides and this module uses as it is:

* **Heartbeats and stale trials**: ``RDBStorage(heartbeat_interval, grace_period)`` records
  heartbeats; :func:`optuna.storages.fail_stale_trials` fails a RUNNING trial whose heartbeat is
  older than the grace period (a row-locked state change: once, whoever calls it);
* **Re-queuing a dead worker's loop**: the storage's stale-trial callback,
  :class:`optuna.storages.RetryHeartbeatStaleTrialCallback` (``RetryFailedTrialCallback`` before
  Optuna 5), adds a WAITING copy of the failed trial, with its ``retry_history``;
* **Exclusive claims**: a WAITING trial is claimed with ``set_trial_state_values(RUNNING)``, which
  succeeds for exactly one caller (the primitive behind Optuna's own ``ask`` of enqueued trials);
  a trial told COMPLETE cannot be failed, and one failed as stale cannot be completed, so a zombie
  that wakes up late loses and every loop has at most one COMPLETE trial.

What still needs this module, and why:

* **Which loop, once**: Optuna has no "create this study with one trial" in one step, so the
  study's *name* is the exclusive event: whoever creates ``...@0`` adds its first WAITING trial.
  A worker that died between the two leaves an empty study; after the grace period any worker
  claims the name ``...@1`` instead (the epoch). Only this rare path changes the epoch;
* **The heartbeat thread**: Optuna runs its own only inside ``Study.optimize``, which would also
  create a fresh trial when the WAITING one was taken; the claim beats (``record_heartbeat``)
  before it takes its trial, so a claimed trial always has a heartbeat (Optuna never fails a
  RUNNING trial without one);
* **Cascades and results**: an outer loop is claimed only once its inner loop is done; the
  result is the trial's user attribute ``result`` (stored before the trial is told COMPLETE);
  ``key`` hashes everything the loop's result depends on (:func:`tuner.studies.schema.loop_key`),
  so an edited study file is tuned afresh and an unchanged one reuses its results at once;
* **Waking up**: workers on one machine wake each other when a loop is done
  (:class:`Wakeup`), instead of polling the storage; across machines they poll it.
"""

from __future__ import annotations

import logging
import math
import os
import re
import socket
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import datetime
from typing import Any

import optuna
from optuna.exceptions import DuplicatedStudyError, UpdateFinishedTrialError
from optuna.storages import RDBStorage, fail_stale_trials
from optuna.study import StudyDirection
from optuna.trial import TrialState

from ..errors import TunerError
from .schema import LoopDef, StudyDef, base_plants, controller_of, loop_key

__all__ = ["StorageError", "open_storage", "LoopStatus", "Coordinator", "claim_order", "nlp_shape", "Claim", "Wakeup",
           "work", "default_storage_url", "delete_study_records", "redact"]

log = logging.getLogger(__name__)
optuna.logging.set_verbosity(optuna.logging.WARNING)

HEARTBEAT_S = 2
GRACE_S = 30


class StorageError(TunerError, RuntimeError):
    """The Optuna storage cannot be opened or used."""


def default_storage_url(out_dir: str) -> str:
    """The default study storage: a SQLite file in ``out_dir``."""
    return f"sqlite:///{os.path.abspath(os.path.join(out_dir, 'study.db'))}"


def redact(url: str) -> str:
    """The URL without its password."""
    return re.sub(r"(//[^:/@]+):[^@/]*@", r"\1:***@", url)


IDLE_IN_TRANSACTION_S = 60.0  # PostgreSQL: a session idle inside a transaction this long is ended (open_storage)


def _engine_kwargs(url: str) -> dict[str, Any]:
    """SQLAlchemy's engine settings for the storage at ``url``."""
    if url.startswith("sqlite"):
        return {"connect_args": {"timeout": 60}}
    if url.startswith("postgresql"):
        # a worker that stops inside a transaction (stopped, swapped out, blocked on its own output) would hold its
        # row locks for as long as it is stuck, and every worker that fails or claims that trial would wait on them:
        # the server ends such a session after IDLE_IN_TRANSACTION_S (Optuna's transactions are single statements'
        # worth of work, never idle for long). The stuck worker's own next statement then fails (a storage error
        # that ends that worker; its loop is re-queued like a dead worker's); the others go on
        from sqlalchemy.engine import make_url

        options = f"-c idle_in_transaction_session_timeout={int(IDLE_IN_TRANSACTION_S * 1000)}"
        given = make_url(url).query.get("options")  # the URL's own (e.g. ?options=-csearch_path%3Dstudies) stay
        if given:
            options = f"{given if isinstance(given, str) else ' '.join(given)} {options}"
        return {"pool_pre_ping": True, "connect_args": {"connect_timeout": 10, "options": options}}
    return {}


def open_storage(url: str, *, heartbeat_s: int = HEARTBEAT_S, grace_s: int = GRACE_S) -> RDBStorage:
    """An Optuna RDB storage with heartbeats. ``postgresql://`` uses psycopg 3."""
    if url.startswith(("postgresql://", "postgres://")):
        url = "postgresql+psycopg://" + url.split("://", 1)[1]
    try:
        engine = _engine_kwargs(url)
        with warnings.catch_warnings():  # heartbeat_interval is marked experimental; it is what we build on
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            key, retry = _retry_callback()  # a dead worker's loop is re-queued by Optuna itself
            return RDBStorage(url, engine_kwargs=engine, heartbeat_interval=int(heartbeat_s), grace_period=int(grace_s),
                              **{key: retry})
    except Exception as e:  # SQLAlchemy/driver errors of every kind: one clear message
        raise StorageError(f"--storage {redact(url)}: cannot open: {str(e).splitlines()[0]}") from e


@dataclass(frozen=True)
class LoopStatus:
    """What the storage says about one loop."""

    state: str  # "done", "running", "free" (claimable), "blocked" (its inner loop is not done)
    epoch: int  # the claim study to use: to create ("free" without trial_id), or the current one
    result: dict[str, Any] | None = None
    worker: str | None = None
    since: datetime | None = None
    trial_id: int | None = None  # "free": the WAITING trial to claim (None: create the epoch's study)
    attempt: int = 0  # how many earlier attempts failed (Optuna's retry history)

    def __repr__(self) -> str:
        parts = [self.state, f"epoch {self.epoch}"]
        if self.worker:
            parts.append(f"worker {self.worker}")
        if self.trial_id is not None:
            parts.append(f"trial {self.trial_id}")
        if self.attempt:
            parts.append(f"attempt {self.attempt + 1}")
        if self.result is not None:
            parts.append(f"result with {len(self.result)} fields")
        return f"LoopStatus({', '.join(parts)})"


def _retry_callback() -> Any:
    cls = getattr(optuna.storages, "RetryHeartbeatStaleTrialCallback", None)  # Optuna >= 5
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        if cls is not None:
            return "heartbeat_stale_trial_callback", cls()
        return "failed_trial_callback", optuna.storages.RetryFailedTrialCallback()


def _attempt(t: Any) -> int:
    return len(t.system_attrs.get("retry_history", []))


def nlp_shape(lp: LoopDef) -> tuple[Any, ...]:
    """What a loop's tune tends to share with another loop's through the NLP build cache, as far as it is known
    before the tune: the structure, a continuous or sampled loop, each plant's order, zeros and delay in samples as
    the NLP models it (a sampled loop: the zero-order-hold plant, a fractional delay's extra state included), which
    of the spec's settings differ from the default (the constraints and objective the NLP carries). The build
    cache's key (:class:`tuner.optimize.nlp.transcribe.ProblemKey`) holds more (the horizon, the grid, whether the
    loop has a phase crossover), which only the search knows. A data loop's plant is known only once it is
    identified (during its tune), and a loop whose plant cannot be modelled here fails in its own tune: each is
    its own shape (the order is a matter of speed only)."""
    if lp.data is not None:
        return ("data", lp.name)
    try:
        plants = base_plants(lp)
        per = []
        for p in plants:
            m = p.zoh(lp.dt) if lp.dt is not None else p
            per.append((m.order, m.zeros.size, round(m.delay_s / lp.dt) if lp.dt is not None else m.delay_s > 0))
    except Exception:  # (grouping is an optimisation: a failing loop fails in its tune, as before)
        return ("unmodelled", lp.name)
    return (lp.structure, lp.dt is None, tuple(per), tuple(sorted(lp.spec.model_dump(exclude_defaults=True))))


def claim_order(study: StudyDef) -> list[LoopDef]:
    """The study's loops in the order workers take them: the study's order (:meth:`StudyDef.order`: file order,
    inner loops first), regrouped so that loops of one :func:`nlp_shape` are consecutive, each group in the study's
    order; the groups of one structure together (the structures in the order their first loop comes), and within a
    structure those of the same plant shapes together (in the order of their first loops); a structure whose tune
    first runs the whole search of a structure it contains (pid2: pid's) with that structure, after its group of the
    same plant shapes; an outer loop of a cascade right after its inner loop.

    Loops of one shape reuse each other's NLP builds, and a worker tunes a stretch of consecutive loops (see
    :meth:`Coordinator.candidates`): in file order a worker that takes half the study builds what the other half
    builds too wherever shapes recur across the file. On the quality suite's 40-loop slice (bench/quality_scale.py;
    structures and plant orders alternate from case to case), two workers taking a half each build 4.5 % more than
    one in file order, 0-0.7 % in this order (bench/claim_order_builds.py, bench/results/claim_order_builds.json)."""
    from ..optimize.engine import CONTAINS, FULL_CONTAINMENT

    units: list[list[LoopDef]] = []
    unit_of: dict[str, list[LoopDef]] = {}
    for lp in study.order():
        if lp.inner is not None and lp.inner in unit_of:
            unit = unit_of[lp.inner]
            unit.append(lp)
        else:
            unit = [lp]
            units.append(unit)
        unit_of[lp.name] = unit
    groups: dict[tuple[Any, ...], list[LoopDef]] = {}
    for unit in units:
        groups.setdefault(nlp_shape(unit[0]), []).extend(unit)
    # a structure's family: itself, or the structure whose whole search its tune runs first (it builds those problems)
    family = {sh: CONTAINS[sh[0]] if sh[0] in FULL_CONTAINMENT else sh[0]
              for sh in groups if len(sh) == 4}
    first: dict[Any, int] = {}
    for sh in groups:
        first.setdefault(family.get(sh, sh), len(first))
        first.setdefault((family.get(sh, sh), sh[1:3]), len(first))

    def rank(sh: tuple[Any, ...]) -> tuple[int, int, bool]:
        f = family.get(sh, sh)
        return first[f], first[(f, sh[1:3])], f != sh[0]  # (pid2 after pid's group of its plants)

    return [lp for sh in sorted(groups, key=rank) for lp in groups[sh]]


class Coordinator:
    """One worker's (or observer's) view of a study in the storage."""

    def __init__(self, study: StudyDef, storage: RDBStorage, *, worker: str | None = None, observe_only: bool = False):
        self.study = study
        self.storage = storage
        self.worker = worker or f"{socket.gethostname()}:{os.getpid()}"
        self.observe_only = observe_only
        self.keys = {lp.name: loop_key(study, lp.name) for lp in study.loop}
        self._first_seen: dict[tuple[str, int], float] = {}
        self._done: dict[str, LoopStatus] = {}  # loops seen done (final: see statuses)
        self._last: str | None = None  # the loop this worker claimed last
        self._claim_order: list[LoopDef] | None = None

    def prefix(self, lp: LoopDef) -> str:
        """The name prefix of the loop ``lp``'s claim studies in the storage (study, loop, the loop's key)."""
        return f"{self.study.name}:{lp.name}:{self.keys[lp.name]}@"

    def claim_studies(self, lp: LoopDef, names: list[str] | None = None) -> list[tuple[int, str, int]]:
        """(epoch, study name, study id) of the loop's claim studies, oldest first."""
        pre = self.prefix(lp)
        if names is None:
            names = [s.study_name for s in self.storage.get_all_studies()]
        out = []
        for n in names:
            if n.startswith(pre) and n[len(pre):].isdigit():
                out.append((int(n[len(pre):]), n, self.storage.get_study_id_from_name(n)))
        return sorted(out)

    def _waited(self, key: tuple[str, int]) -> float:
        return time.monotonic() - self._first_seen.setdefault(key, time.monotonic())

    def status(self, lp: LoopDef, statuses: dict[str, LoopStatus] | None = None,
               names: list[str] | None = None) -> LoopStatus:
        """The loop's state; a worker (not an observer) also fails the trials of dead workers here
        (Optuna re-queues each as a WAITING trial)."""
        claims = self.claim_studies(lp, names)
        trials: list[Any] = []
        for e, _, sid in claims:
            # one read per claim study, decided from that read alone: a COMPLETE trial is done (its result
            # is stored before it is told COMPLETE), whatever a later read would say
            trials = self.storage.get_all_trials(sid, deepcopy=False)
            for t in trials:
                if t.state == TrialState.COMPLETE:
                    return LoopStatus("done", e, t.user_attrs.get("result"), t.user_attrs.get("worker"),
                                      t.datetime_start, attempt=_attempt(t))
        if lp.inner is not None and statuses is not None and statuses[lp.inner].state != "done":
            return LoopStatus("blocked", claims[-1][0] + 1 if claims else 0)
        if not claims:
            return LoopStatus("free", 0)
        e, name, sid = claims[-1]
        if not trials:  # its creator is between creating it and adding its trial, or died there
            if not self.observe_only and self._waited(("empty", sid)) > self.storage.grace_period:
                return LoopStatus("free", e + 1)
            return LoopStatus("running", e)
        if not self.observe_only and any(t.state == TrialState.RUNNING for t in trials):
            with warnings.catch_warnings():  # marked experimental since Optuna 2.9; it is what we build on
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                fail_stale_trials(optuna.Study(name, self.storage))
            trials = self.storage.get_all_trials(sid, deepcopy=False)
        for t in trials:
            if t.state == TrialState.COMPLETE:  # completed between the two reads above
                return LoopStatus("done", e, t.user_attrs.get("result"), t.user_attrs.get("worker"),
                                  t.datetime_start, attempt=_attempt(t))
        for t in trials:
            if t.state == TrialState.RUNNING:
                return LoopStatus("running", e, worker=t.user_attrs.get("worker"), since=t.datetime_start,
                                  attempt=_attempt(t))
        waiting = [t for t in trials if t.state == TrialState.WAITING]
        if waiting:
            t = waiting[0]
            return LoopStatus("free", e, trial_id=self.storage.get_trial_id_from_study_id_trial_number(sid, t.number),
                              attempt=_attempt(t))
        # every trial failed and none re-queued (the worker that failed one died before re-queuing it):
        # after the grace period, a fresh claim study
        if not self.observe_only and self._waited(("dead", sid)) > self.storage.grace_period:
            return LoopStatus("free", e + 1)
        return LoopStatus("running", e)

    def statuses(self) -> dict[str, LoopStatus]:
        """What the storage says about every loop (:class:`LoopStatus` by loop name).

        A loop once seen done is not read again: its COMPLETE trial can neither be failed nor replaced
        (the loop's key is fixed for this coordinator), so its status is final. A worker reads the storage
        before every claim; without this, a study of n loops cost O(n) reads per claim, O(n^2) in all."""
        out: dict[str, LoopStatus] = {}
        names: list[str] | None = None
        for lp in self.study.order():
            st = self._done.get(lp.name)
            if st is None:
                if names is None:  # one listing of the storage's studies per call, only if a loop needs it
                    names = [s.study_name for s in self.storage.get_all_studies()]
                st = self.status(lp, out, names)
                if st.state == "done":
                    self._done[lp.name] = st
            out[lp.name] = st
        return out

    def loops_in_claim_order(self) -> list[LoopDef]:
        """The order in which workers take the loops (:func:`claim_order`; computed once)."""
        if self._claim_order is None:
            self._claim_order = claim_order(self.study)
        return self._claim_order

    def candidates(self, statuses: dict[str, LoopStatus]) -> list[LoopDef]:
        """The free loops, the one this worker should take first at the front (then the claim order).

        Each worker tunes a stretch of consecutive loops in the claim order (:func:`claim_order`: loops whose NLPs
        have one shape together, inner loops before the loops that wrap them): the loop after the one it tuned
        last while that is free, else the middle of the longest stretch of loops still to tune (its start if no
        worker is tuning into it from the loop before); a stretch counts the outer loops still waiting for their
        inner ones, so that a cascade's pairs stay together. A worker keeps the NLPs it built (up to its build
        cache's bound), and loops of one shape reuse them. Replaying the requests the quality suite's tunes made of
        the build cache (bench/build_cache_replay.py: each half of the suite, a 2 GB cache per worker), two workers
        taking loops at random spent 6-33 % more time building than one, taking every other loop 6-7 %, a half
        each 0-4 %. The split needs no count of the workers: a worker that joins halves the longest stretch
        left."""
        loops = self.loops_in_claim_order()
        free = [i for i, lp in enumerate(loops) if statuses[lp.name].state == "free"]
        if not free:
            return []
        after = next((i + 1 for i, lp in enumerate(loops) if lp.name == self._last), None)
        if after in free:
            pick = after
        else:
            runs: list[list[int]] = []  # stretches of loops still to tune (free, or waiting for an inner loop)
            for i, lp in enumerate(loops):
                if statuses[lp.name].state not in ("free", "blocked"):
                    continue
                if runs and runs[-1][-1] == i - 1:
                    runs[-1].append(i)
                else:
                    runs.append([i])
            runs = [r for r in runs if any(statuses[loops[i].name].state == "free" for i in r)]
            run = max(runs, key=len)  # the first of the longest
            entered = run[0] > 0 and statuses[loops[run[0] - 1].name].state == "running"
            at = run[len(run) // 2] if entered else run[0]
            pick = next((i for i in run if i >= at and statuses[loops[i].name].state == "free"),
                        next(i for i in run if statuses[loops[i].name].state == "free"))
        return [loops[pick]] + [loops[i] for i in free if i != pick]

    def claim(self, lp: LoopDef, st: LoopStatus) -> Claim | None:
        """Take the loop as ``st`` (a "free" status) says: its WAITING trial, or a new claim study."""
        name = f"{self.prefix(lp)}{st.epoch}"
        trial_id = st.trial_id
        if trial_id is None:
            try:
                sid = self.storage.create_new_study([StudyDirection.MINIMIZE], name)
            except DuplicatedStudyError:
                return None  # another worker created this epoch's study first
            trial_id = self.storage.create_new_trial(sid, template_trial=optuna.trial.create_trial(
                state=TrialState.WAITING))
        self.storage.record_heartbeat(trial_id)  # before it is RUNNING: a claimed trial always has a heartbeat
        try:
            if not self.storage.set_trial_state_values(trial_id, state=TrialState.RUNNING):
                return None  # another worker took this trial first
        except UpdateFinishedTrialError:
            return None
        self.storage.set_trial_user_attr(trial_id, "worker", self.worker)
        self._last = lp.name
        return Claim(self, lp, st.epoch, optuna.Study(name, self.storage), trial_id, attempt=st.attempt)


class Claim:
    """A loop held by this worker: a RUNNING trial with a heartbeat thread."""

    def __init__(self, coord: Coordinator, lp: LoopDef, epoch: int, study: optuna.Study, trial_id: int, *,
                 attempt: int = 0):
        self.coord, self.loop, self.epoch, self.attempt = coord, lp, epoch, attempt
        self.study, self.trial_id = study, trial_id
        self.number = coord.storage.get_trial(trial_id).number
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, daemon=True, name=f"heartbeat-{lp.name}")
        self._thread.start()

    def _beat(self) -> None:
        interval = self.coord.storage.heartbeat_interval
        while not self._stop.wait(interval):
            try:
                self.coord.storage.record_heartbeat(self.trial_id)
            except Exception as e:  # a transient storage error must not kill the worker; the next beat retries
                log.warning("heartbeat of %s failed: %s", self.loop.name, e)

    def complete(self, result: dict[str, Any]) -> bool:
        """Store the result and complete the trial; False if the claim was lost (failed as stale)."""
        try:
            self.coord.storage.set_trial_user_attr(self.trial_id, "result", result)
            ts = result.get("metrics", {}).get("settling_time_s")
            value = ts if isinstance(ts, (int, float)) and math.isfinite(ts) else 1e9
            self.study.tell(self.number, value)
            return True
        except (UpdateFinishedTrialError, ValueError, RuntimeError) as e:
            log.warning("claim of loop %s (epoch %d) was lost: %s", self.loop.name, self.epoch, e)
            return False
        finally:
            self._stop.set()
            self._thread.join(timeout=5)


def _controllers(study: StudyDef, lp: LoopDef, statuses: dict[str, LoopStatus]) -> dict[str, Any]:
    """Controllers of the loops ``lp`` wraps, from their stored results."""
    out = {}
    for inner in study.chain(lp.name)[:-1]:
        r = statuses[inner.name].result or {}
        if "gains" not in r:
            raise TunerError(f"inner loop {inner.name!r} has no result: {r.get('error', 'not tuned')}")
        out[inner.name] = controller_of(inner, r["gains"])
    return out


def run_claimed(coord: Coordinator, claim: Claim, statuses: dict[str, LoopStatus]) -> dict[str, Any] | None:
    """Tune the claimed loop and complete the claim: the stored result, or None if the claim was lost."""
    from .evaluate import tune_loop

    lp = claim.loop
    t0 = time.perf_counter()
    try:
        result = tune_loop(coord.study, lp, _controllers(coord.study, lp, statuses))
    except TunerError as e:
        result = {"loop": lp.name, "key": coord.keys[lp.name], "error": str(e), "meets_spec": False}
    except Exception as e:
        log.exception("tuning loop %s failed", lp.name)
        result = {"loop": lp.name, "key": coord.keys[lp.name], "error": f"{type(e).__name__}: {e}",
                  "meets_spec": False}
    result.update({"worker": coord.worker, "epoch": claim.epoch, "attempt": claim.attempt,
                   "wall_time_s": time.perf_counter() - t0})
    return result if claim.complete(result) else None


class Wakeup:
    """Workers of one machine wake each other when a loop is done: a generation count in shared memory,
    handed to the processes at their start, that a waiting worker watches.

    A waiter only reads the count (every ``TICK_S``), under no lock: with a ``multiprocessing.Condition``,
    a worker killed while it waited (SIGKILL, the OOM killer) left the next ``notify_all`` blocked for
    good, holding the lock every other worker of the machine then blocked on. A notify increments the
    count under its lock, taken with a timeout: were that lock left held by a worker killed inside
    those few instructions, the increment is made without it, and two such increments racing may leave
    the count where a waiter last saw it. That costs the waiter nothing but the wait: it is bounded by
    the poll interval, after which the worker reads the storage anyway."""

    TICK_S = 0.02

    def __init__(self, ctx: Any) -> None:
        self._gen = ctx.Value("q", 0)  # with its own (process-shared) lock; read through get_obj(), without it

    def seen(self) -> int:
        """The current wake-up count (a later, different one means a wake-up came since)."""
        return int(self._gen.get_obj().value)

    def notify(self) -> None:
        """Wake the waiting workers (a loop was finished or released)."""
        lock = self._gen.get_lock()
        if lock.acquire(timeout=1.0):
            try:
                self._gen.get_obj().value += 1
            finally:
                lock.release()
        else:  # its holder died holding it
            self._gen.get_obj().value += 1

    def wait(self, seen: int, timeout_s: float) -> None:
        """Until something changed since ``seen`` (or ``timeout_s``: other machines' workers do not notify)."""
        end = time.monotonic() + timeout_s
        while self._gen.get_obj().value == seen and (left := end - time.monotonic()) > 0:
            time.sleep(min(self.TICK_S, left))


def work(coord: Coordinator, *, poll_s: float = 0.5, stop: threading.Event | None = None,
         on_claim: Callable[[str], None] | None = None, wakeup: Wakeup | None = None,
         on_done: Callable[[LoopDef, dict[str, Any]], None] | None = None,
         idle: Callable[[dict[str, LoopStatus]], bool] | None = None) -> dict[str, LoopStatus]:
    """Claim and tune loops until every loop of the study is done; returns the final statuses.

    With nothing to claim (every free loop taken, or waiting for its inner loop) the worker first runs ``idle``
    (the statuses it read; True when it did a piece of work, e.g. drew one figure of a loop that is done, and
    should be asked again) and otherwise waits for ``wakeup`` (a loop done on this machine) or ``poll_s``,
    whichever comes first; once every loop is done it runs ``idle`` until it has nothing left, then returns.
    Loops come first: a worker that finds a loop to claim tunes it before any of that work, so the work fills the
    time a worker would otherwise wait while others tune the last loops. ``on_done`` runs after each loop this
    worker completed."""
    while True:
        seen = wakeup.seen() if wakeup is not None else 0
        statuses = coord.statuses()
        if all(s.state == "done" for s in statuses.values()):
            while idle is not None and not (stop is not None and stop.is_set()) and idle(statuses):
                pass
            return statuses
        if stop is not None and stop.is_set():
            return statuses
        claimed = False
        cands = coord.candidates(statuses)
        while cands:
            lp = cands[0]
            claim = coord.claim(lp, statuses[lp.name])
            if claim is None:  # another worker took it first: where it went decides where this one goes
                statuses = {**statuses, lp.name: replace(statuses[lp.name], state="running")}
                cands = coord.candidates(statuses)
                continue
            if on_claim is not None:
                on_claim(lp.name)
            result = run_claimed(coord, claim, statuses)
            if wakeup is not None:
                wakeup.notify()
            if result is not None and on_done is not None:
                on_done(lp, result)
            claimed = True
            break
        if not claimed:
            if idle is not None and idle(statuses):
                continue  # (it did something: read the storage again at once)
            if wakeup is not None:
                wakeup.wait(seen, poll_s)
            else:
                time.sleep(poll_s)


def delete_study_records(storage: RDBStorage, study_name: str) -> int:
    """Delete every claim of ``study_name`` from the storage; returns how many were deleted."""
    n = 0
    for s in storage.get_all_studies():
        if s.study_name.startswith(f"{study_name}:"):
            optuna.delete_study(study_name=s.study_name, storage=storage)
            n += 1
    return n
