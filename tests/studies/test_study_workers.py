"""``tuner study run --workers N`` on one machine: the same gains whatever N, and the workers' idle time spent on the
figures of the loops that are done (each drawn once, by whichever worker is free)."""

from __future__ import annotations

import json
import threading

import pytest
from quadrotor import ROLL, YAW

from tuner.cli import main
from tuner.studies import cli as scli
from tuner.studies import runner
from tuner.studies.runner import Coordinator, LoopStatus, open_storage
from tuner.studies.schema import load_study

# quick loops, and a budget no run here reaches (a wall-clock cap that cut one run's search and not another's would
# change its gains: the same seed gives the same gains only where the cap cuts nothing)
STUDY = f"""
name = "same_{{n}}"
seed = 0
time_budget_s = 300

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
name = "integrating"
plant = "0.5/s"
delay = 1.0
dt = 0.25
structure = "pd"
"""


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_one_and_two_workers_give_bitwise_the_same_gains(tmp_path):
    """The workers are forked from one prepared process whatever their number (the batch's compiled kernels loaded
    and warmed before the fork), so a loop's tune is the same at 1 and 2 workers, to the last bit; the plots are
    all there either way."""
    docs = {}
    for w in (1, 2):
        f = tmp_path / f"s{w}.toml"
        f.write_text(STUDY.format(n=w))
        out = tmp_path / f"o{w}"
        assert main(["study", "run", str(f), "--workers", str(w), "--out", str(out)]) in (0, 1)
        docs[w] = json.loads((out / "results.json").read_text())
        for name in ("yaw", "fopdt", "integrating"):
            for kind in ("step", "bode", "nyquist"):
                assert (out / "plots" / f"{name}_{kind}.png").stat().st_size > 1000
        assert not list((out / "plots").glob("*.lock"))
    for name in ("yaw", "fopdt", "integrating"):
        one, two = docs[1]["loops"][name], docs[2]["loops"][name]
        assert one["solver"]["cut"] is None and two["solver"]["cut"] is None  # (else the test says nothing)
        assert one["gains"] == two["gains"], name  # floats from JSON: equal means bitwise
        assert one["metrics"] == two["metrics"], name
    assert {r["worker"] for r in docs[2]["loops"].values()} != {docs[1]["loops"]["yaw"]["worker"]}


def _done(study, gains: dict[str, dict[str, float]]) -> dict[str, LoopStatus]:
    return {lp.name: LoopStatus("done", 0, result={"loop": lp.name, "gains": gains[lp.name]}) for lp in study.loop}


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_idle_workers_draw_each_figure_once_and_the_report_uses_them(tmp_path, monkeypatch):
    """Two workers' idle plotters over one plots folder: every figure of every done loop is drawn once (the lock
    file decides who draws it), a figure whose lock another process holds is left to it, and the report takes the
    figures for the result they show and draws a loop whose figures are not all there."""
    f = tmp_path / "s.toml"
    f.write_text(f'name = "idle"\nseed = 0\n[[loop]]\nname = "roll"\nplant = "{ROLL}"\ndt = 0.04\nstructure = "pid_z"\n'
                 f'[[loop]]\nname = "yaw"\nplant = "{YAW}"\ndt = 0.04\nstructure = "pid_z"\n'
                 '[[loop]]\nname = "y"\ninner = "roll"\nplant = "9.81/s^2"\ndt = 0.04\nstructure = "lead"\n')
    study = load_study(str(f))
    gains = {"roll": {"K": 3.868, "a1": -1.305, "a2": 0.5668}, "yaw": {"K": 1.0, "a1": -1.2, "a2": 0.4},
             "y": {"K": 0.1, "wz": 0.5, "wp": 5.0}}
    statuses = _done(study, gains)
    plots = tmp_path / "plots"
    drawn: list[tuple[str, str]] = []
    real = scli._draw_figure

    def counted(study_, lp, result, kind, *a):
        drawn.append((lp.name, kind))
        return real(study_, lp, result, kind, *a)

    monkeypatch.setattr(scli, "_draw_figure", counted)
    fp_yaw = scli._fingerprint(study, study.get("yaw"), statuses["yaw"].result)
    plots.mkdir()
    held = plots / f"yaw_nyquist.{fp_yaw}.lock"  # another process is drawing this one
    held.touch()
    a, b = scli._idle_plotter(study, str(plots)), scli._idle_plotter(study, str(plots))
    turns = []
    while True:  # the two workers take turns while either finds something to draw
        ta, tb = a(statuses), b(statuses)
        turns.append((ta, tb))
        if not (ta or tb):
            break
    want = [(n, k) for n in ("roll", "y") for k in ("step", "bode", "nyquist")] + [("yaw", "step"), ("yaw", "bode")]
    assert sorted(drawn) == sorted(want)
    assert len(set(drawn)) == len(drawn)  # each once
    assert turns[0] == (True, True)  # they share the work
    assert not [p for p in plots.glob("*.lock") if p != held]  # every lock taken was released
    # the report: roll's three figures as drawn; yaw's nyquist is missing, so yaw is drawn whole; y, the outer loop
    # around roll, drawn for its gains and roll's (roll re-tuned: y's figures are not the ones drawn)
    assert scli._drawn_early(study, study.get("roll"), statuses["roll"].result, plots) == {
        k: plots / f"roll_{k}.png" for k in ("step", "bode", "nyquist")}
    results = {n: st.result for n, st in statuses.items()}
    assert scli._drawn_early(study, study.get("y"), results["y"], plots, results) == {
        k: plots / f"y_{k}.png" for k in ("step", "bode", "nyquist")}
    retuned = {**results, "roll": {"gains": {**gains["roll"], "K": 3.9}}}
    assert scli._drawn_early(study, study.get("y"), results["y"], plots, retuned) is None
    assert scli._drawn_early(study, study.get("yaw"), statuses["yaw"].result, plots) is None
    assert scli._drawn_early(study, study.get("yaw"), {"gains": {**gains["yaw"], "K": 1.1}}, plots) is None
    assert a(statuses) is False  # nothing left for this process (it does not try a figure twice)


def test_an_outer_loops_early_evaluation_is_the_reports(tmp_path):
    """An idle worker evaluates an outer loop (for its figures) as the report does (:func:`_evaluate_all`: around
    its inner loop's controller, with that loop's bandwidth), and only once the loop it wraps is done."""
    f = tmp_path / "s.toml"
    f.write_text(f'name = "o"\nseed = 0\n[[loop]]\nname = "roll"\nplant = "{ROLL}"\ndt = 0.04\nstructure = "pid_z"\n'
                 '[[loop]]\nname = "y"\ninner = "roll"\nplant = "9.81/s^2"\ndt = 0.04\nstructure = "lead"\n')
    study = load_study(str(f))
    gains = {"roll": {"K": 3.868, "a1": -1.305, "a2": 0.5668}, "y": {"K": 0.1, "wz": 0.5, "wp": 5.0}}
    statuses = _done(study, gains)
    results = {n: st.result for n, st in statuses.items()}
    from tuner.studies.schema import controller_of

    ctrls = {lp.name: controller_of(lp, gains[lp.name]) for lp in study.loop}
    report, _ = scli._evaluate_all(study, ctrls, None, 1)
    early = scli._evaluate_chain(study, study.get("y"), results)
    assert early.to_dict() == report["y"].to_dict()
    assert early.cascade is not None and early.inner_bandwidth_rad_s > 0  # (the simulation ran; roll's bandwidth)
    assert scli._chain_results(study, study.get("y"), {"y": statuses["y"]}) is None  # roll not done: not yet
    assert scli._chain_results(study, study.get("y"), statuses) == results


def test_the_figures_the_workers_mark_are_the_loop_plots():
    """The studies name a loop's figures without importing the plots' module (matplotlib): the same names."""
    from tuner.analysis.plots import LOOP_PLOTS

    assert scli._FIGURES == LOOP_PLOTS
    assert sorted(scli._DRAW_ORDER) == sorted(LOOP_PLOTS)  # (every figure, each once, the dearest first)


def test_a_worker_draws_only_when_no_loop_is_free_and_drains_the_figures_at_the_end(tmp_path, monkeypatch):
    """Loops first: ``work`` calls ``idle`` only when it finds nothing to claim, and once every loop is done it calls
    it until it says there is nothing left, then returns; a stopped worker does not."""
    f = tmp_path / "s.toml"
    f.write_text('name = "order"\nseed = 0\n' + "".join(
        f'[[loop]]\nname = "l{i}"\nplant = "1/(s+{i + 1})"\ndt = 0.1\nstructure = "pi"\n' for i in range(3)))
    study = load_study(str(f))
    url = f"sqlite:///{tmp_path / 's.db'}"
    events: list[str] = []

    def tuned(coord, claim, sts):
        events.append(f"tune {claim.loop.name}")
        return claim.complete({"loop": claim.loop.name, "gains": {"Kp": 1.0, "Ki": 1.0}}) and {}

    monkeypatch.setattr(runner, "run_claimed", tuned)
    left = [3]

    def idle(statuses):
        events.append(f"idle {sum(s.state == 'done' for s in statuses.values())} done")
        left[0] -= 1
        return left[0] > 0

    final = runner.work(Coordinator(study, open_storage(url), worker="A"), idle=idle, poll_s=0.01)
    assert all(s.state == "done" for s in final.values())
    assert events == ["tune l0", "tune l1", "tune l2", "idle 3 done", "idle 3 done", "idle 3 done"]
    # another worker holds l1: A tunes l0 and l2, then draws while it waits, then drains
    url2 = f"sqlite:///{tmp_path / 's2.db'}"
    b = Coordinator(study, open_storage(url2), worker="B")
    held = b.claim(study.get("l1"), b.statuses()["l1"])
    assert held is not None
    events.clear()
    left[0] = 10**6
    stop = threading.Event()

    def idle2(statuses):
        events.append("idle")
        if events.count("idle") == 3:  # B finishes its loop while A draws
            assert held.complete({"loop": "l1", "gains": {"Kp": 1.0, "Ki": 2.0}})
        return events.count("idle") < 5

    runner.work(Coordinator(study, open_storage(url2), worker="A"), idle=idle2, poll_s=0.01, stop=stop)
    assert events[:2] == ["tune l0", "tune l2"] and set(events[2:]) == {"idle"} and len(events) == 7
    stop.set()
    events.clear()
    runner.work(Coordinator(study, open_storage(url2), worker="A"), idle=idle2, poll_s=0.01, stop=stop)
    assert events == []  # stopped: it neither tunes nor draws


def test_a_figure_lock_a_killed_worker_left_is_cleared_when_stale(tmp_path):
    # (review: a worker killed mid-draw left its lock for good, so no later run's idle worker drew that figure)
    import os
    import time

    from tuner.studies.cli import STALE_LOCK_S, _clear_stale_locks

    old, new = tmp_path / "roll_step.abc.lock", tmp_path / "pitch_step.abc.lock"
    old.touch()
    new.touch()
    past = time.time() - STALE_LOCK_S - 5
    os.utime(old, (past, past))
    _clear_stale_locks(tmp_path)
    assert not old.exists() and new.exists()


@pytest.mark.skipif(scli._context().get_start_method() != "fork", reason="only forked workers inherit the start")
def test_forked_workers_inherit_the_start_and_the_parent_keeps_its_own(tmp_path, monkeypatch):
    """The workers' one-time start (the kernels loaded and warmed) is paid once, in the parent before the fork: a
    worker starts with it loaded and with the parent's objects frozen out of the collector; the parent then has its
    own batch path and collector back."""
    import gc
    import sys

    from tuner.optimize import batch

    f = tmp_path / "s.toml"
    f.write_text(STUDY.format(n="start"))
    study = load_study(str(f))
    loads: list[int] = []
    monkeypatch.setitem(batch._KERNELS, "module", None)
    monkeypatch.setitem(batch._KERNELS, "warm", False)
    sentinel = object()

    def load() -> None:  # (counted in this process; a forked worker inherits the count)
        loads.append(1)
        batch._KERNELS.update(module=sentinel, warm=True)

    seen = tmp_path / "seen.json"

    def entry(*a, **k) -> None:  # a worker that reports what it started with, and stops
        seen.write_text(json.dumps({"loads": len(loads), "warm": batch._KERNELS["module"] is sentinel,
                                    "frozen": gc.get_freeze_count(), "engine": "tuner.optimize.engine" in sys.modules}))

    monkeypatch.setattr(scli, "_load_kernels", load)
    monkeypatch.setattr(scli, "_worker_entry", entry)
    assert gc.get_freeze_count() == 0
    statuses = scli.run_study(study, str(f), f"sqlite:///{tmp_path / 'study.db'}", workers=1, progress=False,
                              plots_dir=tmp_path / "plots")
    assert all(s.state == "free" for s in statuses.values())  # (the stub tuned nothing)
    got = json.loads(seen.read_text())
    assert got["loads"] == 1 and got["warm"] and got["frozen"] > 1000
    assert got["engine"]
    assert loads == [1]  # once for the study, in this process
    assert batch._KERNELS["module"] is None and batch._KERNELS["warm"] is False  # this process's own path again
    assert gc.get_freeze_count() == 0
