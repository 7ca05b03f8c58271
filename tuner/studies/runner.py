"""Running a study: workers that share its loops through an Optuna storage.

The storage (SQLite by default, PostgreSQL for several machines) is the only coordination
point. For each loop, *claims* are Optuna studies named ``<study>:<loop>:<key>@<epoch>``:

* ``key`` hashes everything the loop's result depends on (:func:`tuner.studies.schema.loop_key`), so
  an edited study file is tuned afresh and an unchanged one reuses its results at once;
* a worker claims epoch ``e`` by *creating* that study (names are unique in the storage, so
  exactly one worker succeeds) and asks one trial in it: a RUNNING trial whose heartbeat the
  worker records every ``heartbeat_s`` (Optuna's RDB heartbeat);
* the result is stored as the trial's user attribute ``result`` and the trial is told
  COMPLETE. A worker that dies stops its heartbeat; after ``grace_s`` any worker fails the
  stale trial (:func:`optuna.storages.fail_stale_trials`, a row-locked state change, so once)
  and the loop is claimed again as epoch ``e + 1``. A zombie that wakes up after that cannot
  complete its trial any more, so every loop has at most one COMPLETE claim;
* an outer loop is claimed only once its inner loop is done (workers poll the storage).
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
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import optuna
from optuna.exceptions import DuplicatedStudyError, UpdateFinishedTrialError
from optuna.storages import RDBStorage, fail_stale_trials
from optuna.study import StudyDirection
from optuna.trial import TrialState

from ..errors import TunerError
from .schema import LoopDef, StudyDef, controller_of, loop_key

__all__ = ["StorageError", "open_storage", "LoopStatus", "Coordinator", "work", "default_storage_url",
           "delete_study_records", "redact"]

log = logging.getLogger(__name__)
optuna.logging.set_verbosity(optuna.logging.WARNING)

HEARTBEAT_S = 2
GRACE_S = 30


class StorageError(TunerError, RuntimeError):
    """The Optuna storage cannot be opened or used."""


def default_storage_url(out_dir: str) -> str:
    return f"sqlite:///{os.path.abspath(os.path.join(out_dir, 'study.db'))}"


def redact(url: str) -> str:
    """The URL without its password."""
    return re.sub(r"(//[^:/@]+):[^@/]*@", r"\1:***@", url)


def open_storage(url: str, *, heartbeat_s: int = HEARTBEAT_S, grace_s: int = GRACE_S) -> RDBStorage:
    """An Optuna RDB storage with heartbeats. ``postgresql://`` uses psycopg 3."""
    if url.startswith(("postgresql://", "postgres://")):
        url = "postgresql+psycopg://" + url.split("://", 1)[1]
    engine: dict[str, Any] = {}
    if url.startswith("sqlite"):
        engine = {"connect_args": {"timeout": 60}}
    elif url.startswith("postgresql"):
        engine = {"pool_pre_ping": True, "connect_args": {"connect_timeout": 10}}
    try:
        with warnings.catch_warnings():  # heartbeat_interval is marked experimental; it is what we build on
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            return RDBStorage(url, engine_kwargs=engine, heartbeat_interval=int(heartbeat_s), grace_period=int(grace_s))
    except Exception as e:  # SQLAlchemy/driver errors of every kind: one clear message
        raise StorageError(f"--storage {redact(url)}: cannot open: {str(e).splitlines()[0]}") from e


@dataclass(frozen=True)
class LoopStatus:
    """What the storage says about one loop."""

    state: str  # "done", "running", "free" (claimable), "blocked" (its inner loop is not done)
    epoch: int  # the epoch to claim next ("free"), or the current one
    result: dict[str, Any] | None = None
    worker: str | None = None
    since: datetime | None = None


class Coordinator:
    """One worker's (or observer's) view of a study in the storage."""

    def __init__(self, study: StudyDef, storage: RDBStorage, *, worker: str | None = None, observe_only: bool = False):
        self.study = study
        self.storage = storage
        self.worker = worker or f"{socket.gethostname()}:{os.getpid()}"
        self.observe_only = observe_only
        self.keys = {lp.name: loop_key(study, lp.name) for lp in study.loop}
        self._first_seen: dict[tuple[str, int], float] = {}

    def prefix(self, lp: LoopDef) -> str:
        return f"{self.study.name}:{lp.name}:{self.keys[lp.name]}@"

    def claim_studies(self, lp: LoopDef, names: list[str] | None = None) -> list[tuple[int, str, int]]:
        """(epoch, study name, study id) of the loop's claims, oldest first."""
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
        """The loop's state; a worker (not an observer) also fails the claims of dead workers here."""
        claims = self.claim_studies(lp, names)
        trials: list[Any] = []
        for e, _, sid in claims:
            # one read per claim, decided from that read alone: a COMPLETE trial is done (its result is
            # stored before it is told COMPLETE), whatever a later read would say
            trials = self.storage.get_all_trials(sid, deepcopy=False)
            for t in trials:
                if t.state == TrialState.COMPLETE:
                    return LoopStatus("done", e, t.user_attrs.get("result"), t.user_attrs.get("worker"),
                                      t.datetime_start)
        if lp.inner is not None and statuses is not None and statuses[lp.inner].state != "done":
            return LoopStatus("blocked", claims[-1][0] + 1 if claims else 0)
        if not claims:
            return LoopStatus("free", 0)
        e, name, sid = claims[-1]
        if not trials:  # the owner is between creating the claim and asking its trial, or died there
            if not self.observe_only and self._waited(("empty", sid)) > self.storage.grace_period:
                return LoopStatus("free", e + 1)
            return LoopStatus("running", e)
        t = trials[0]
        if t.state == TrialState.RUNNING and not self.observe_only:
            with warnings.catch_warnings():  # marked experimental since Optuna 2.9; it is what we build on
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                fail_stale_trials(optuna.Study(name, self.storage))
            tid = self.storage.get_trial_id_from_study_id_trial_number(sid, t.number)
            if "alive" not in t.user_attrs and self._waited(("mute", tid)) > self.storage.grace_period:
                self._fail(tid)  # died before its first heartbeat
            t = self.storage.get_trial(tid)
        if t.state == TrialState.COMPLETE:  # completed between the two reads above
            return LoopStatus("done", e, t.user_attrs.get("result"), t.user_attrs.get("worker"), t.datetime_start)
        if t.state == TrialState.RUNNING:
            return LoopStatus("running", e, worker=t.user_attrs.get("worker"), since=t.datetime_start)
        return LoopStatus("free", e + 1)  # FAIL: a dead worker's claim

    def _fail(self, trial_id: int) -> None:
        try:
            self.storage.set_trial_state_values(trial_id, state=TrialState.FAIL)
        except UpdateFinishedTrialError:
            pass

    def statuses(self) -> dict[str, LoopStatus]:
        out: dict[str, LoopStatus] = {}
        names = [s.study_name for s in self.storage.get_all_studies()]
        for lp in self.study.order():
            out[lp.name] = self.status(lp, out, names)
        return out

    def claim(self, lp: LoopDef, epoch: int) -> Claim | None:
        name = f"{self.prefix(lp)}{epoch}"
        try:
            sid = self.storage.create_new_study([StudyDirection.MINIMIZE], name)
        except DuplicatedStudyError:
            return None  # another worker claimed this epoch first
        study = optuna.Study(name, self.storage)
        with warnings.catch_warnings():  # "heartbeat is supposed to be used with optimize": we beat ourselves
            warnings.simplefilter("ignore", UserWarning)
            trial = study.ask()
        trial_id = self.storage.get_trial_id_from_study_id_trial_number(sid, trial.number)
        self.storage.record_heartbeat(trial_id)
        trial.set_user_attr("worker", self.worker)
        trial.set_user_attr("alive", True)
        return Claim(self, lp, epoch, study, trial, trial_id)


class Claim:
    """A loop held by this worker: a RUNNING trial with a heartbeat thread."""

    def __init__(self, coord: Coordinator, lp: LoopDef, epoch: int, study: optuna.Study, trial: Any, trial_id: int):
        self.coord, self.loop, self.epoch = coord, lp, epoch
        self.study, self.trial, self.trial_id = study, trial, trial_id
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
            self.trial.set_user_attr("result", result)
            ts = result.get("metrics", {}).get("settling_time_s")
            value = ts if isinstance(ts, (int, float)) and math.isfinite(ts) else 1e9
            self.study.tell(self.trial, value)
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


def run_claimed(coord: Coordinator, claim: Claim, statuses: dict[str, LoopStatus]) -> bool:
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
    result.update({"worker": coord.worker, "epoch": claim.epoch, "wall_time_s": time.perf_counter() - t0})
    return claim.complete(result)


def work(coord: Coordinator, *, poll_s: float = 0.5, stop: threading.Event | None = None,
         on_claim: Callable[[str], None] | None = None) -> dict[str, LoopStatus]:
    """Claim and tune loops until every loop of the study is done; returns the final statuses."""
    while True:
        statuses = coord.statuses()
        if all(s.state == "done" for s in statuses.values()):
            return statuses
        if stop is not None and stop.is_set():
            return statuses
        claimed = False
        for lp in coord.study.order():
            st = statuses[lp.name]
            if st.state != "free":
                continue
            claim = coord.claim(lp, st.epoch)
            if claim is None:
                continue
            if on_claim is not None:
                on_claim(lp.name)
            run_claimed(coord, claim, statuses)
            claimed = True
            break
        if not claimed:
            time.sleep(poll_s)


def delete_study_records(storage: RDBStorage, study_name: str) -> int:
    """Delete every claim of ``study_name`` from the storage; returns how many were deleted."""
    n = 0
    for s in storage.get_all_studies():
        if s.study_name.startswith(f"{study_name}:"):
            optuna.delete_study(study_name=s.study_name, storage=storage)
            n += 1
    return n
