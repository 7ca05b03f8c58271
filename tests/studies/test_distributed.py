"""Several workers share one study through the Optuna storage: no loop tuned twice, a killed
worker's loop taken up again, nothing lost.

The PostgreSQL test runs two real ``tuner study run`` processes against the server on
127.0.0.1:5432 and kills one of them with SIGKILL while it holds a loop.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
import uuid
from pathlib import Path

import pytest
from optuna.trial import TrialState
from pg import require_pg_base_url
from quadrotor import ROLL, YAW
from study_workers import finish_worker, start_worker, worker_ids

from tuner.cli import main
from tuner.studies.runner import Coordinator, delete_study_records, open_storage
from tuner.studies.schema import load_study

STUDY = f"""
name = "{{name}}"
seed = 0
time_budget_s = 4

[[loop]]
name = "roll"
plant = "{ROLL}"
dt = 0.04
structure = "pid_z"

[[loop]]
name = "yaw"
plant = "{YAW}"
dt = 0.04
structure = "pid_z"

[[loop]]
name = "fopdt"
plant = "1/(10s+1)"
delay = 2.0
dt = 0.5
structure = "pi"

[[loop]]
name = "lag4"
plant = "1/(s+1)^4"
dt = 0.2
structure = "pid"

[[loop]]
name = "y"
inner = "roll"
plant = "9.81/s^2"
dt = 0.04
structure = "lead"
n_trials = 100
"""


@pytest.fixture
def pg_url():
    return require_pg_base_url()


def _study_file(tmp_path: Path) -> tuple[Path, str]:
    name = f"dist_{uuid.uuid4().hex[:12]}"  # unique per run: the server is shared
    f = tmp_path / "study.toml"
    f.write_text(STUDY.format(name=name))
    return f, name


def _claims(coord: Coordinator) -> dict[str, list[tuple[int, str, str | None]]]:
    """Per loop: (epoch, trial state, worker) of every claim in the storage."""
    out = {}
    for lp in coord.study.loop:
        rows = []
        for epoch, _, sid in coord.claim_studies(lp):
            for t in coord.storage.get_all_trials(sid, deepcopy=False):
                rows.append((epoch, t.state.name, t.user_attrs.get("worker")))
        out[lp.name] = rows
    return out


def _retries(coord: Coordinator, lp) -> list[int]:
    """Per COMPLETE trial of the loop: the number of the trial it retries (Optuna's ``failed_trial``)."""
    out = []
    for _, _, sid in coord.claim_studies(lp):
        for t in coord.storage.get_all_trials(sid, deepcopy=False):
            if t.state == TrialState.COMPLETE:
                out.append(t.system_attrs.get("failed_trial"))
    return out


def _completed(rows) -> list[tuple[int, str, str | None]]:
    return [r for r in rows if r[1] == TrialState.COMPLETE.name]


@pytest.mark.postgres
@pytest.mark.slow
@pytest.mark.timeout(900)  # its own waits are bounded (worker starts, the survivor's run, a re-run)
def test_two_workers_one_killed_nothing_lost_or_duplicated(tmp_path, pg_url):
    f, name = _study_file(tmp_path)
    study = load_study(f)
    storage = open_storage(pg_url, heartbeat_s=1, grace_s=4)  # creates Optuna's tables before the workers start
    coord = Coordinator(study, storage, observe_only=True)
    procs: list[subprocess.Popen] = []
    try:
        a = start_worker(f, pg_url, tmp_path / "a")
        b = start_worker(f, pg_url, tmp_path / "b")
        procs += [a, b]
        ids_b: set[str] = set()  # the command's worker (forked: its id is the child's pid)
        killed_loop = None
        deadline = time.monotonic() + 120
        while killed_loop is None and time.monotonic() < deadline:
            ids_a = worker_ids(a)
            ids_b |= worker_ids(b)
            sts = coord.statuses()
            a_running = [n for n, s in sts.items() if s.state == "running" and s.worker in ids_a]
            b_started = any(s.worker in ids_b for s in sts.values())
            if a_running and b_started:
                killed_loop = a_running[0]
                killed_epoch = sts[killed_loop].epoch
                wid_a = sts[killed_loop].worker
                os.kill(a.pid, signal.SIGKILL)  # mid-run: its loop's claim is RUNNING, its heartbeat stops
                a.wait(timeout=30)
            else:
                time.sleep(0.1)
        assert killed_loop is not None, "worker A never held a loop while B was working"
        assert a.returncode == -signal.SIGKILL

        out_b = finish_worker(b, tmp_path / "b", 300)
        assert b.returncode == 0, out_b
        assert len(ids_b) == 1, ids_b  # (one worker per command here)
        wid_b = next(iter(ids_b))

        claims = _claims(coord)
        # every loop completed exactly once, across all workers and attempts
        for loop, rows in claims.items():
            assert len(_completed(rows)) == 1, (loop, rows)
        # the killed worker's loop: its trial failed (stale heartbeat), Optuna re-queued it, B re-did it once
        rows = claims[killed_loop]
        assert (killed_epoch, "FAIL", wid_a) in rows, rows
        assert _completed(rows) == [(killed_epoch, "COMPLETE", wid_b)], rows
        assert _retries(coord, study.get(killed_loop)) == [0], "the COMPLETE trial is Optuna's retry of trial 0"

        # nothing lost: B's results.json has every loop, as stored
        doc = json.loads((tmp_path / "b" / "results.json").read_text())
        sts = coord.statuses()
        assert set(doc["loops"]) == {lp.name for lp in study.loop}
        for loop, r in doc["loops"].items():
            assert "error" not in r and r["gains"] == sts[loop].result["gains"], loop
        assert doc["loops"][killed_loop]["worker"] == wid_b
        assert (doc["loops"][killed_loop]["epoch"], doc["loops"][killed_loop]["attempt"]) == (killed_epoch, 1)

        # re-running the finished study reuses its results at once: no new claim anywhere
        c = start_worker(f, pg_url, tmp_path / "c")
        procs.append(c)
        out_c = finish_worker(c, tmp_path / "c", 120)
        assert c.returncode == 0, out_c
        assert _claims(coord) == claims
        again = json.loads((tmp_path / "c" / "results.json").read_text())
        assert {n: r["gains"] for n, r in again["loops"].items()} == {n: r["gains"] for n, r in doc["loops"].items()}
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        delete_study_records(storage, name)
    assert coord.claim_studies(study.loop[0]) == []


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_claims_are_exclusive_and_a_stale_claim_is_taken_over(tmp_path):
    """In-process, on SQLite: one claim per loop; a claim whose heartbeat stops is failed after the
    grace period and re-queued by Optuna, taken by exactly one worker; the zombie cannot complete it."""
    f, _ = _study_file(tmp_path)
    study = load_study(f)
    url = f"sqlite:///{tmp_path / 'study.db'}"
    a = Coordinator(study, open_storage(url, heartbeat_s=1, grace_s=2), worker="A")
    b = Coordinator(study, open_storage(url, heartbeat_s=1, grace_s=2), worker="B")
    c = Coordinator(study, open_storage(url, heartbeat_s=1, grace_s=2), worker="C")
    yaw = study.get("yaw")
    free = a.statuses()["yaw"]
    assert (free.state, free.epoch, free.trial_id) == ("free", 0, None)
    ca = a.claim(yaw, free)
    assert ca is not None
    assert b.claim(yaw, free) is None  # the same loop cannot be claimed twice
    assert b.statuses()["yaw"].state == "running"
    assert b.statuses()["y"].state == "blocked"  # waits for its inner loop, roll

    ca._stop.set()  # A "dies": its heartbeat stops
    ca._thread.join()
    deadline = time.monotonic() + 20
    while (st := b.statuses()["yaw"]).state != "free" and time.monotonic() < deadline:
        time.sleep(0.3)
    assert (st.state, st.epoch, st.attempt) == ("free", 0, 1) and st.trial_id is not None  # re-queued
    cb = b.claim(yaw, st)
    assert cb is not None
    assert c.claim(yaw, st) is None  # the re-queued trial is taken once
    assert cb.complete({"loop": "yaw", "gains": {"K": 1.0, "a1": 0.0, "a2": 0.0}})
    assert not ca.complete({"loop": "yaw", "gains": {"K": 2.0, "a1": 0.0, "a2": 0.0}})  # the zombie loses
    done = b.statuses()["yaw"]
    assert (done.state, done.worker, done.result["gains"]["K"], done.attempt) == ("done", "B", 1.0, 1)
    assert _claims(b)["yaw"] == [(0, "FAIL", "A"), (0, "COMPLETE", "B")]
    assert _retries(b, yaw) == [0]


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_a_claim_study_left_empty_is_claimed_again_in_the_next_epoch(tmp_path):
    """A worker that died between creating a loop's claim study and adding its trial: after the
    grace period the loop is claimed under the next epoch's name, once."""
    from optuna.study import StudyDirection

    f, _ = _study_file(tmp_path)
    study = load_study(f)
    url = f"sqlite:///{tmp_path / 'study.db'}"
    a = Coordinator(study, open_storage(url, heartbeat_s=1, grace_s=1), worker="A")
    b = Coordinator(study, open_storage(url, heartbeat_s=1, grace_s=1), worker="B")
    fopdt = study.get("fopdt")
    a.storage.create_new_study([StudyDirection.MINIMIZE], f"{a.prefix(fopdt)}0")  # ... and A dies
    assert b.statuses()["fopdt"].state == "running"
    deadline = time.monotonic() + 20
    while (st := b.statuses()["fopdt"]).state != "free" and time.monotonic() < deadline:
        time.sleep(0.3)
    assert (st.state, st.epoch, st.trial_id) == ("free", 1, None)
    cb = b.claim(fopdt, st)
    assert cb is not None and a.claim(fopdt, st) is None
    assert cb.complete({"loop": "fopdt", "gains": {"Kp": 1.0, "Ki": 0.1}})
    assert _claims(b)["fopdt"] == [(1, "COMPLETE", "B")]


@pytest.mark.slow
def test_local_workers_share_a_sqlite_study(tmp_path, capsys):
    """``--workers 2``: two spawned processes on the default SQLite storage; every loop once."""
    f, _ = _study_file(tmp_path)
    out = tmp_path / "o"
    assert main(["study", "run", str(f), "--workers", "2", "--out", str(out), "--no-plots"]) == 0
    doc = json.loads((out / "results.json").read_text())
    assert set(doc["loops"]) == {"roll", "yaw", "fopdt", "lag4", "y"}
    coord = Coordinator(load_study(f), open_storage(f"sqlite:///{out / 'study.db'}"), observe_only=True)
    claims = _claims(coord)
    assert all(len(_completed(rows)) == 1 and len(rows) == 1 for rows in claims.values()), claims
    assert json.loads((out / "gains.json").read_text()).keys() == doc["loops"].keys()


def test_plots_drawn_early_are_used_only_for_the_result_they_show(tmp_path):
    """A worker's early figures carry a fingerprint (loop definition + gains), one mark per figure: the report uses
    them for that result only, and only when every figure of the loop is there; it draws again otherwise (e.g. a
    re-tuned loop in the same folder, or a worker killed between two figures)."""
    from tuner.studies.cli import _drawn_early, _fingerprint

    f, _ = _study_file(tmp_path)
    study = load_study(f)
    yaw = study.get("yaw")
    plots = tmp_path / "plots"
    plots.mkdir()
    result = {"gains": {"K": 1.0, "a1": -0.5, "a2": 0.1}}
    fp = _fingerprint(study, yaw, result)
    for kind in ("step", "bode", "nyquist"):
        (plots / f"yaw_{kind}.png").write_bytes(b"\x89PNG")
        (plots / f"yaw_{kind}.plotted").write_text(json.dumps({"fingerprint": fp, "figure": f"yaw_{kind}.png"}))
    assert _drawn_early(study, yaw, result, plots) == {k: plots / f"yaw_{k}.png" for k in ("step", "bode", "nyquist")}
    assert _drawn_early(study, yaw, {"gains": {**result["gains"], "K": 2.0}}, plots) is None  # other gains
    (plots / "yaw_bode.png").unlink()
    assert _drawn_early(study, yaw, result, plots) is None  # a figure is missing
    (plots / "yaw_bode.png").write_bytes(b"\x89PNG")
    (plots / "yaw_nyquist.plotted").unlink()
    assert _drawn_early(study, yaw, result, plots) is None  # a figure was not marked (its drawing did not end)


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_a_done_loop_is_not_read_again(tmp_path):
    """statuses() before every claim must not re-read the loops already done (a study of n loops would
    cost O(n^2) reads): once a loop is seen done, later calls read only the loops that are not, and the
    cached status is the one the storage holds."""
    f, _ = _study_file(tmp_path)
    study = load_study(f)
    url = f"sqlite:///{tmp_path / 'study.db'}"
    a = Coordinator(study, open_storage(url), worker="A")
    obs = Coordinator(study, open_storage(url), observe_only=True)
    for name in ("roll", "yaw", "fopdt"):
        claim = a.claim(study.get(name), a.statuses()[name])
        assert claim is not None and claim.complete({"loop": name, "gains": {"K": 1.0}})
    reads: list[int] = []
    real = obs.storage.get_all_trials
    obs.storage.get_all_trials = lambda sid, **kw: reads.append(sid) or real(sid, **kw)  # type: ignore[method-assign]
    first = obs.statuses()
    assert {n for n, s in first.items() if s.state == "done"} == {"roll", "yaw", "fopdt"}
    assert len(reads) == 3  # the three done loops' claim studies (the others have none yet)
    reads.clear()
    again = obs.statuses()
    assert reads == [] and again == first  # nothing re-read; the same statuses
    claim = a.claim(study.get("lag4"), a.statuses()["lag4"])  # a running loop is read every time
    assert claim is not None
    assert obs.statuses()["lag4"].state == "running" and len(reads) == 1
    assert claim.complete({"loop": "lag4", "gains": {"K": 2.0}})
    reads.clear()
    assert obs.statuses()["lag4"].result == {"loop": "lag4", "gains": {"K": 2.0}} and len(reads) == 1
    reads.clear()
    assert obs.statuses()["y"].state == "free" and reads == []  # roll is done: y is free, nothing re-read


def test_each_worker_takes_a_stretch_of_consecutive_loops(tmp_path, monkeypatch):
    """Neighbouring loops share the NLPs a tune builds: a worker continues after its last loop, and one that has to
    move on starts in the middle of the longest stretch of free loops (at its start if no worker runs into it)."""
    from tuner.studies.runner import LoopStatus

    body = "\n".join(f'[[loop]]\nname = "l{i}"\nplant = "1/(s+{i + 1})"\ndt = 0.1\nstructure = "pi"\n'
                     for i in range(10))
    f = tmp_path / "ten.toml"
    f.write_text(f'name = "ten"\nseed = 0\n\n{body}')
    study = load_study(str(f))
    coord = Coordinator(study, storage=None, worker="A")  # type: ignore[arg-type]  (candidates reads no storage)

    def pick(states: str, last: int | None = None) -> str:  # one letter per loop: free, running, done, blocked
        coord._last = None if last is None else f"l{last}"
        names = {"f": "free", "r": "running", "d": "done", "b": "blocked"}
        got = coord.candidates({f"l{i}": LoopStatus(names[c], 0) for i, c in enumerate(states)})
        assert sorted(lp.name for lp in got) == sorted(f"l{i}" for i, c in enumerate(states) if c == "f")
        return got[0].name if got else ""

    assert pick("ffffffffff") == "l0"  # the first worker starts at the beginning
    assert pick("rfffffffff") == "l5"  # the second halves what the first runs into
    assert pick("ddffffrfff", last=1) == "l2"  # a worker continues after its own last loop
    assert pick("ddrfffffff", last=1) == "l6"  # ... unless another took it: the middle of what that one runs into
    assert pick("ddrffffrdd", last=9) == "l5"  # the middle of the longest stretch, l3-l6, entered from l2
    assert pick("ddffdrffdd", last=9) == "l2"  # ties: the first; no worker runs into l2-l3, so its start
    # an outer loop waiting for its inner one belongs to the stretch (a cascade's pairs stay together)
    assert pick("rfbfbfbfbd") == "l5"  # the middle of l1-l8 is l5 (free)
    assert pick("rfbfbbbfbd") == "l7"  # ... l5 blocked: the first free loop after it
    assert pick("dddddddddd") == ""
    # through the storage (work() itself, its tunes stubbed): a worker that loses a claim it read as free goes to
    # the middle of what the winner runs into, and the winner continues after its own loop
    import threading

    from tuner.studies import runner

    url = f"sqlite:///{tmp_path / 'ten.db'}"
    a, b = Coordinator(study, open_storage(url), worker="A"), Coordinator(study, open_storage(url), worker="B")
    stale = b.statuses()  # B reads every loop free ...
    held = a.claim(study.get("l0"), a.statuses()["l0"])  # ... then A takes l0
    assert held is not None
    reads = iter([stale])
    real = b.statuses
    b.statuses = lambda: next(reads, None) or real()  # type: ignore[method-assign]
    done = {"Kp": 1.0, "Ki": 1.0}
    monkeypatch.setattr(runner, "run_claimed", lambda coord, claim, sts: claim.complete({"gains": done}) and {})
    got: list[str] = []
    stop = threading.Event()
    runner.work(b, on_claim=lambda name: got.append(name) or stop.set(), stop=stop, poll_s=0.01)
    assert got == ["l5"]
    assert held.complete({"gains": done})
    assert a.candidates(a.statuses())[0].name == "l1"  # A continues after l0
    held = a.claim(study.get("l8"), a.statuses()["l8"])  # a claim sets where its worker continues
    assert held is not None and held.complete({"gains": done})
    assert a.candidates(a.statuses())[0].name == "l9"


def test_workers_take_loops_whose_nlps_have_one_shape_together(tmp_path):
    """The claim order (runner.claim_order) regroups the study's loops by what their tunes' NLPs share (structure,
    sampled or continuous, each plant's order, zeros and delay in samples as the NLP models it, the spec's settings
    that differ from the default): the groups of one structure together, those of the same plant shapes next to each
    other, each group in file order; pid2 with pid (its tune runs pid's search first); a cascade's loops in a row,
    innermost first, even where the file lists the outer loop first."""
    from tuner.studies.runner import LoopStatus, claim_order, nlp_shape

    loops = [  # name, plant, structure, extra
        ("p2", "1/(s+3)^2", "pid2", ""),  # before any pid loop in the file: still after pid's group of its plants
        ("a", "1/(s+1)", "pi", ""),
        ("b", "1/(s+1)^2", "pid", ""),
        ("c", "2/(3*s+1)", "pi", ""),
        ("top", "1/s", "pi", 'inner = "mid"\n'),  # a chain listed outermost first: low <- mid <- top
        ("d", "1/(s+1)^2", "pi", ""),
        ("mid", "1/s", "pi", 'inner = "low"\n'),
        ("e", "1/(s+2)^2", "pid", ""),
        ("f", "1/(s+1)", "pi", "delay = 0.3\n"),  # 3 whole samples of delay: another shape
        ("f2", "1/(s+1)", "pi", "delay = 0.27\n"),  # 2.7 samples: 2, and a state for the fraction (a zero too)
        ("g", "1/(s+1)", "pi", "spec = { ms_max = 1.6 }\n"),  # an Ms limit: another shape
        ("h", "1/(s+1)", "pi", "spec = { phase_margin_min_deg = 45 }\n"),  # a setting of its own: another shape
        ("low", "5/(s+5)", "pd", ""),
        ("i", "5/(s+5)", "pi", ""),
        ("m", "1/(s+1)^2", "pid", ""),
    ]
    body = "\n".join(f'[[loop]]\nname = "{n}"\nplant = "{p}"\ndt = 0.1\nstructure = "{st}"\n{x}'
                     for n, p, st, x in loops)
    f = tmp_path / "mixed.toml"
    f.write_text(f'name = "mixed"\nseed = 0\n\n{body}')
    study = load_study(str(f))
    shapes = {lp.name: nlp_shape(lp) for lp in study.loop}
    assert shapes["a"] == shapes["c"] == shapes["i"] == ("pi", False, ((1, 0, 0),), ())
    assert shapes["b"] == shapes["e"] == shapes["m"] and shapes["d"] != shapes["a"]
    assert shapes["f"][2] == ((1, 0, 3),) and shapes["f2"][2] == ((2, 1, 2),)
    assert shapes["g"] != shapes["a"] and shapes["g"] != shapes["h"] and shapes["p2"][0] == "pid2"
    got = [lp.name for lp in claim_order(study)]
    # pid first (p2's family comes first in the file): b, e, m, then p2 (the same plant shapes); then pi: a, c, i with
    # g and h (the same plants, other settings), d, f, f2; then pd's low with its chain mid, top (pi loops, kept with
    # their inner loop)
    assert got == ["b", "e", "m", "p2", "a", "c", "i", "g", "h", "d", "f", "f2", "low", "mid", "top"]
    assert sorted(got) == sorted(lp.name for lp in study.loop)
    coord = Coordinator(study, storage=None, worker="A")  # type: ignore[arg-type]  (candidates reads no storage)
    free = {lp.name: LoopStatus("free", 0) for lp in study.loop}
    free.update(mid=LoopStatus("blocked", 0), top=LoopStatus("blocked", 0))
    assert coord.candidates(free)[0].name == "b"  # the file's first loop is p2; the claim order starts at b
    coord._last = "e"
    assert coord.candidates(free)[0].name == "m"  # a worker continues in the claim order, not the file's


@pytest.mark.postgres
@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_a_worker_stuck_inside_a_transaction_does_not_block_the_others(pg_url, monkeypatch):
    """A session of the storage that sits idle in a transaction holding a trial's row lock (a worker stopped or
    blocked mid-transaction) is ended by the server, and the worker failing that trial goes on instead of waiting
    for it for good."""
    import threading

    from optuna.study import StudyDirection
    from sqlalchemy import text

    from tuner.studies import runner

    # 5 s, not less: opening the storage (Optuna's schema checks) idles between its statements, and on a loaded 2-core
    # host a 1 s limit ended that session too (IdleInTransactionSessionTimeout inside open_storage)
    monkeypatch.setattr(runner, "IDLE_IN_TRANSACTION_S", 5.0)
    storage = open_storage(pg_url)
    name = f"stuck_{uuid.uuid4().hex[:12]}"
    sid = storage.create_new_study([StudyDirection.MINIMIZE], f"{name}:loop")
    tid = storage.create_new_trial(sid)
    stuck = storage.engine.connect()
    try:
        assert stuck.execute(text("SHOW idle_in_transaction_session_timeout")).scalar() == "5s"
        stuck.execute(text("SELECT trial_id FROM trials WHERE trial_id = :t FOR UPDATE"), {"t": tid})  # ... and stops
        done = threading.Event()

        def fail_it() -> None:
            storage.set_trial_state_values(tid, TrialState.FAIL)
            done.set()

        other = threading.Thread(target=fail_it, daemon=True)
        other.start()
        other.join(timeout=60)
        assert done.is_set(), "the update waited on the stuck session's lock"
        assert storage.get_trial(tid).state == TrialState.FAIL
    finally:
        stuck.invalidate()  # the server ended it
        stuck.close()
        delete_study_records(storage, name)
        storage.engine.dispose()


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_wakeup_is_seen_across_processes_and_waits_out_its_timeout_without_one():
    """Workers of one machine wake each other through a count in shared memory that waiters only read (no lock a
    killed worker could leave held is ever waited on without a timeout)."""
    import multiprocessing as mp

    from tuner.studies.runner import Wakeup

    ctx = mp.get_context("fork")
    w = Wakeup(ctx)
    seen = w.seen()
    t0 = time.monotonic()
    w.wait(seen, 0.2)  # nothing came: back after its timeout, the count unchanged
    assert time.monotonic() - t0 >= 0.2 and w.seen() == seen
    p = ctx.Process(target=w.notify)
    t0 = time.monotonic()
    p.start()
    w.wait(seen, 200.0)
    assert time.monotonic() - t0 < 200.0 and w.seen() != seen  # woken by the other process, not by the timeout
    p.join(30)
    assert p.exitcode == 0
    # a notifier killed while it held the count's lock: the others still notify (without it) and wait
    holder = ctx.Process(target=_hold_the_lock_and_hang, args=(w,))
    holder.start()
    deadline = time.monotonic() + 60
    while w._gen.get_lock().acquire(timeout=0.01) and time.monotonic() < deadline:  # until the holder has it
        w._gen.get_lock().release()
        time.sleep(0.01)
    os.kill(holder.pid, signal.SIGKILL)
    holder.join(30)
    seen = w.seen()
    w.notify()
    w.wait(seen, 200.0)
    assert w.seen() != seen


def _hold_the_lock_and_hang(w) -> None:
    w._gen.get_lock().acquire()
    time.sleep(600)
