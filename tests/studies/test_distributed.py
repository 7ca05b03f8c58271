"""Several workers share one study through the Optuna storage: no loop tuned twice, a killed
worker's loop taken up again, nothing lost.

The PostgreSQL test runs two real ``tuner study run`` processes against the server on
127.0.0.1:5432 and kills one of them with SIGKILL while it holds a loop.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest
from optuna.trial import TrialState
from pg import require_pg_base_url
from quadrotor import ROLL, YAW

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


def _completed(rows) -> list[tuple[int, str, str | None]]:
    return [r for r in rows if r[1] == TrialState.COMPLETE.name]


def _run(f: Path, url: str, out: Path) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "tuner.cli", "study", "run", str(f), "--storage", url, "--out", str(out),
           "--heartbeat", "1", "--grace", "4", "--no-plots"]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


@pytest.mark.postgres
@pytest.mark.slow
def test_two_workers_one_killed_nothing_lost_or_duplicated(tmp_path, pg_url):
    f, name = _study_file(tmp_path)
    study = load_study(f)
    storage = open_storage(pg_url, heartbeat_s=1, grace_s=4)  # creates Optuna's tables before the workers start
    coord = Coordinator(study, storage, observe_only=True)
    procs: list[subprocess.Popen] = []
    try:
        a = _run(f, pg_url, tmp_path / "a")
        b = _run(f, pg_url, tmp_path / "b")
        procs += [a, b]
        wid_a = f"{socket.gethostname()}:{a.pid}"
        wid_b = f"{socket.gethostname()}:{b.pid}"
        killed_loop = None
        deadline = time.monotonic() + 120
        while killed_loop is None and time.monotonic() < deadline:
            sts = coord.statuses()
            a_running = [n for n, s in sts.items() if s.state == "running" and s.worker == wid_a]
            b_started = any(s.worker == wid_b for s in sts.values())
            if a_running and b_started:
                killed_loop = a_running[0]
                killed_epoch = sts[killed_loop].epoch
                os.kill(a.pid, signal.SIGKILL)  # mid-run: its loop's claim is RUNNING, its heartbeat stops
                a.wait(timeout=30)
            else:
                time.sleep(0.1)
        assert killed_loop is not None, "worker A never held a loop while B was working"
        assert a.returncode == -signal.SIGKILL

        out_b, _ = b.communicate(timeout=300)
        assert b.returncode == 0, out_b

        claims = _claims(coord)
        # every loop completed exactly once, across all workers and attempts
        for loop, rows in claims.items():
            assert len(_completed(rows)) == 1, (loop, rows)
        # the killed worker's loop: its claim failed (stale heartbeat), re-done once by B, in the next epoch
        rows = claims[killed_loop]
        assert (killed_epoch, "FAIL", wid_a) in rows, rows
        assert _completed(rows) == [(killed_epoch + 1, "COMPLETE", wid_b)], rows

        # nothing lost: B's results.json has every loop, as stored
        doc = json.loads((tmp_path / "b" / "results.json").read_text())
        sts = coord.statuses()
        assert set(doc["loops"]) == {lp.name for lp in study.loop}
        for loop, r in doc["loops"].items():
            assert "error" not in r and r["gains"] == sts[loop].result["gains"], loop
        assert doc["loops"][killed_loop]["worker"] == wid_b
        assert doc["loops"][killed_loop]["epoch"] == killed_epoch + 1

        # re-running the finished study reuses its results at once: no new claim anywhere
        c = _run(f, pg_url, tmp_path / "c")
        procs.append(c)
        out_c, _ = c.communicate(timeout=120)
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


def test_claims_are_exclusive_and_a_stale_claim_is_taken_over(tmp_path):
    """In-process, on SQLite: one claim per epoch; a claim whose heartbeat stops is failed after the
    grace period and claimed again; the zombie cannot complete it any more."""
    f, _ = _study_file(tmp_path)
    study = load_study(f)
    url = f"sqlite:///{tmp_path / 'study.db'}"
    a = Coordinator(study, open_storage(url, heartbeat_s=1, grace_s=2), worker="A")
    b = Coordinator(study, open_storage(url, heartbeat_s=1, grace_s=2), worker="B")
    yaw = study.get("yaw")
    ca = a.claim(yaw, 0)
    assert ca is not None
    assert b.claim(yaw, 0) is None  # the same epoch cannot be claimed twice
    assert b.statuses()["yaw"].state == "running"
    assert b.statuses()["y"].state == "blocked"  # waits for its inner loop, roll

    ca._stop.set()  # A "dies": its heartbeat stops
    ca._thread.join()
    deadline = time.monotonic() + 20
    while (st := b.statuses()["yaw"]).state != "free" and time.monotonic() < deadline:
        time.sleep(0.3)
    assert (st.state, st.epoch) == ("free", 1)
    cb = b.claim(yaw, 1)
    assert cb is not None and cb.complete({"loop": "yaw", "gains": {"K": 1.0, "a1": 0.0, "a2": 0.0}})
    assert not ca.complete({"loop": "yaw", "gains": {"K": 2.0, "a1": 0.0, "a2": 0.0}})  # the zombie loses
    done = b.statuses()["yaw"]
    assert (done.state, done.worker, done.result["gains"]["K"]) == ("done", "B", 1.0)
    assert _claims(b)["yaw"] == [(0, "FAIL", "A"), (1, "COMPLETE", "B")]


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
