"""The quality suite as a study (bench/quality.py study) scales out over workers that share only a storage URL.

Two ``tuner study run`` processes, started separately with nothing in common but the PostgreSQL URL and the
study file (as on two machines), tune a slice of the suite; one is killed with SIGKILL while it holds a loop.
Every loop is completed exactly once over all workers and attempts, and the survivor's results.json has them
all, as stored.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest
from optuna.trial import TrialState
from pg import require_pg_base_url
from study_workers import finish_worker, start_worker, worker_ids

from tuner.studies.runner import Coordinator, delete_study_records, open_storage
from tuner.studies.schema import load_study

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "bench"))

# a slice of the suite over its classes and structures (quick loops: the test is about the workers)
IDS = ["lag-00", "lag-01", "lag-05", "nmp-00", "nmp-01", "delay-00", "integrating-00", "integrating-01",
       "unstable-00", "underdamped-01"]


def _claims(coord: Coordinator) -> dict[str, list[tuple[int, str, str | None]]]:
    out = {}
    for lp in coord.study.loop:
        out[lp.name] = [(epoch, t.state.name, t.user_attrs.get("worker"))
                        for epoch, _, sid in coord.claim_studies(lp)
                        for t in coord.storage.get_all_trials(sid, deepcopy=False)]
    return out


@pytest.mark.postgres
@pytest.mark.slow
@pytest.mark.timeout(900)  # its own waits are bounded (worker starts, the survivor's run, a re-run)
def test_suite_study_two_separate_workers_one_killed(tmp_path):
    import quality

    url = require_pg_base_url()
    name = f"quality_{uuid.uuid4().hex[:10]}"
    cases = {c["id"]: c for c in quality.load_suite()}
    f = tmp_path / "quality.toml"
    f.write_text(quality.study_toml([cases[i] for i in IDS], name=name, budget=4, effort="fast"))
    study = load_study(f)
    storage = open_storage(url, heartbeat_s=1, grace_s=4)
    coord = Coordinator(study, storage, observe_only=True)
    procs: list[subprocess.Popen] = []
    try:
        a, b = start_worker(f, url, tmp_path / "a"), start_worker(f, url, tmp_path / "b")
        procs += [a, b]
        ids_b: set[str] = set()  # each command's worker is its forked child (its id: the child's pid)
        killed = None
        deadline = time.monotonic() + 180
        while killed is None and time.monotonic() < deadline:
            ids_a = worker_ids(a)
            ids_b |= worker_ids(b)
            sts = coord.statuses()
            held = [n for n, s in sts.items() if s.state == "running" and s.worker in ids_a]
            if held and any(s.worker in ids_b for s in sts.values()):
                killed = held[0]
                wid_a = sts[killed].worker
                os.kill(a.pid, signal.SIGKILL)
                a.wait(timeout=30)
            else:
                time.sleep(0.05)
        assert killed is not None, "worker A never held a loop while B was working"
        out_b = finish_worker(b, tmp_path / "b", 400)
        assert b.returncode in (0, 1), out_b  # 1: a loop of the suite may not meet its spec
        assert len(ids_b) == 1, ids_b
        wid_b = next(iter(ids_b))
        claims = _claims(coord)
        for loop, rows in claims.items():  # none lost, none repeated
            assert len([r for r in rows if r[1] == TrialState.COMPLETE.name]) == 1, (loop, rows)
        assert any(r[1] == "FAIL" and r[2] == wid_a for r in claims[killed]), claims[killed]
        assert [r[2] for r in claims[killed] if r[1] == "COMPLETE"] == [wid_b]
        doc = json.loads((tmp_path / "b" / "results.json").read_text())
        assert set(doc["loops"]) == set(IDS)
        sts = coord.statuses()
        for loop, r in doc["loops"].items():
            assert "error" not in r and r["gains"] == sts[loop].result["gains"], loop
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        delete_study_records(storage, name)


def test_study_effort_is_read_and_keys_only_change_when_it_is_not_the_default(tmp_path):
    from tuner.studies.schema import loop_key

    base = 'name = "e"\n[[loop]]\nname = "a"\nplant = "1/(s+1)"\ndt = 0.1\nstructure = "pi"\n'
    f0, f1, f2 = tmp_path / "0.toml", tmp_path / "1.toml", tmp_path / "2.toml"
    f0.write_text(base)
    f1.write_text('effort = "default"\n' + base)
    f2.write_text(base + 'effort = "thorough"\n')
    s0, s1, s2 = load_study(f0), load_study(f1), load_study(f2)
    assert s0.effort == s1.effort == "default" and s2.loop[0].effort == "thorough"
    assert loop_key(s0, "a") == loop_key(s1, "a") != loop_key(s2, "a")
    bad = tmp_path / "3.toml"
    bad.write_text('effort = "max"\n' + base)
    with pytest.raises(Exception, match="effort"):
        load_study(bad)
