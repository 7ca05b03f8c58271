"""Reading results from Python: ``TuneResult.metrics``/``checks``, ``worst`` = the plant that limits the design,
``analyze(..., dt=)`` as ``tuner analyze --dt``, and reprs of a few lines for every result type.

The plant sets are built so that the slowest plant is NOT the one with the worst margin: with the PI controller
``C = 2 (s + 1)/s`` on ``k e^{-tau s}/(s + 1)`` the loop is ``L = 2k e^{-tau s}/s``, whose figures are known in
closed form: crossover ``2k`` rad/s, phase margin ``90 - 2k tau (180/pi)`` deg; without delay the closed loop is
``2k/(s + 2k)``, which settles into 2 % in ``ln(50)/(2k)`` s. The disk margin and the delayed loops' settling are
computed here independently (a dense frequency grid; a fine fixed-step simulation).
"""

from __future__ import annotations

import math

import control
import numpy as np
import pytest

from tuner import Spec, TuneResult, analyze, controller_from_coeffs, make_plant
from tuner.errors import TunerError

C = controller_from_coeffs([2.0, 2.0], [1.0, 0.0], dt=None)


def pm_closed_form(k: float, tau: float) -> float:
    return 90.0 - math.degrees(2 * k * tau)


def disk_margin_grid(k: float, tau: float) -> float:
    w = np.logspace(-3, 3, 200_001)
    L = 2 * k * np.exp(-1j * w * tau) / (1j * w)
    return float(np.min(2 * np.abs(1 + L) / np.abs(1 - L)))


def settling_sim(k: float, tau: float, t_end: float = 20.0, h: float = 1e-4) -> float:
    """2 % settling time of the unit step of the loop, by a fixed-step simulation (exact hold of each step's
    input for the plant's first-order lag; the integrator by the trapezoid rule; the delay as a buffer)."""
    n = int(round(t_end / h))
    d = int(round(tau / h))
    buf = np.zeros(n + d + 1)
    y, integ, e_prev = 0.0, 0.0, 1.0
    a = math.exp(-h)
    ys = np.empty(n)
    for i in range(n):
        e = 1.0 - y
        integ += 0.5 * h * (e + e_prev) if i else 0.0
        e_prev = e
        buf[i + d] = 2 * e + 2 * integ
        y = a * y + (1 - a) * k * buf[i]
        ys[i] = y
    outside = np.flatnonzero(np.abs(ys - 1.0) > 0.02)
    return (outside[-1] + 1) * h if outside.size else 0.0


def result(members, spec: Spec | None = None) -> TuneResult:
    """A TuneResult of the fixed controller on the plant set (the verifier's analyses, no search)."""
    spec = spec or Spec()
    analyses = tuple(analyze(make_plant([k], [1.0, 1.0], delay=tau), C, spec) for k, tau in members)
    return TuneResult(structure="pi", gains={"Kp": 2.0, "Ki": 2.0}, controller=C, analyses=analyses, solver={},
                      spec=spec)


def test_the_oracles_agree_with_the_closed_forms():
    assert settling_sim(1.0, 0.0) == pytest.approx(math.log(50) / 2, abs=2e-3)
    assert settling_sim(0.5, 0.0) == pytest.approx(math.log(50), abs=2e-3)
    assert disk_margin_grid(1.0, 0.0) == pytest.approx(2.0)


def test_worst_is_the_failing_plant_not_the_slowest():
    members = [(1.0, 0.0), (0.5, 0.0), (1.0, 0.3)]  # nominal; half the gain (slowest); 0.3 s delay (PM 55.6)
    settle = [settling_sim(k, tau) for k, tau in members]
    pm = [pm_closed_form(k, tau) for k, tau in members]
    assert int(np.argmax(settle)) == 1 and pm[2] < 60 <= min(pm[:2])  # the set is as described
    res = result(members)
    assert not res.meets_spec
    assert res.worst is res.analyses[2]
    assert res.worst.metrics.phase_margin_deg == pytest.approx(pm[2], abs=0.05)
    assert max(res.analyses, key=lambda a: a.metrics.settling_time_s) is res.analyses[1]  # not the worst


def test_worst_of_several_failing_is_the_one_failing_most():
    members = [(1.0, 0.0), (1.0, 0.35), (1.0, 0.3)]  # both delayed plants fail; 0.35 s the more (PM 49.9)
    pm = [pm_closed_form(k, tau) for k, tau in members]
    assert pm[1] < pm[2] < 60
    res = result(members)
    assert res.worst is res.analyses[1]


def test_worst_when_all_meet_the_spec_is_the_worst_objective():
    members = [(1.0, 0.0), (0.5, 0.0), (1.0, 0.2)]  # all meet the spec (PM 90, 90, 67)
    dm = [disk_margin_grid(k, tau) for k, tau in members]
    settle = [settling_sim(k, tau) for k, tau in members]
    assert int(np.argmin(dm)) == 2 and int(np.argmax(settle)) == 1
    by_dm = result(members, Spec(objective="disk_margin"))
    assert by_dm.meets_spec
    assert by_dm.worst is by_dm.analyses[2]  # the smallest disk margin, although plant 1 is the slowest
    assert by_dm.worst.metrics.disk_margin == pytest.approx(dm[2], rel=1e-3)
    assert by_dm.objective == pytest.approx(-dm[2], rel=1e-3)
    by_time = result(members)
    assert by_time.worst is by_time.analyses[1]  # settling time: the slowest
    assert by_time.worst.metrics.settling_time_s == pytest.approx(settle[1], abs=5e-3)


def test_metrics_checks_and_to_dict_are_the_nominal_plants():
    res = result([(1.0, 0.0), (0.5, 0.0)])
    assert res.metrics is res.analyses[0].metrics
    assert res.metrics.phase_margin_deg == pytest.approx(90.0, abs=1e-6)
    assert res.metrics.crossover_rad_s == pytest.approx(2.0, rel=1e-6)
    assert res.checks == res.analyses[0].checks and res.failing == []
    d = res.to_dict()
    assert d["metrics"]["phase_margin_deg"] == res.metrics.phase_margin_deg
    assert d["gains"] == {"Kp": 2.0, "Ki": 2.0} and len(d["plants"]) == 2


# -- analyze(..., dt=) ------------------------------------------------------------------------------------------

G = control.tf([1], [1, 1])


def test_analyze_dt_agrees_with_the_controllers():
    cd = control.c2d(control.tf([2, 2], [1, 0]), 0.05, "tustin")
    a = analyze(G, cd, dt=0.05)
    b = analyze(G, cd)
    assert a.loop.dt == 0.05 and a.metrics == b.metrics
    c = analyze(G, controller_from_coeffs([2.0, -1.9], [1.0, -1.0], dt=0.05), dt=0.05)
    assert c.loop.dt == 0.05


@pytest.mark.parametrize("controller, dt, needle", [
    (control.tf([2, 2], [1, 0]), 0.05, "continuous"),
    (control.c2d(control.tf([2, 2], [1, 0]), 0.05, "tustin"), 0.1, "sample time is 0.05"),
    (C, 0.01, "continuous"),
    (control.c2d(control.tf([2, 2], [1, 0]), 0.05, "tustin"), -1.0, "dt"),
    (control.c2d(control.tf([2, 2], [1, 0]), 0.05, "tustin"), "fast", "dt"),
])
def test_analyze_dt_that_disagrees_names_dt(controller, dt, needle):
    with pytest.raises(TunerError) as ei:
        analyze(G, controller, dt=dt)
    assert ei.value.field == ("dt",)
    assert needle in str(ei.value)


def test_analyze_dt_like_the_cli(capsys):
    """``tuner analyze --dt 0.05 --controller <z expression>`` and ``analyze(..., dt=0.05)`` agree."""
    import json

    from tuner.cli import main

    code = main(["analyze", "--plant", "1/(s+1)", "--controller", "2.05*(z - 0.951219512195122)/(z - 1)",
                 "--dt", "0.05", "--json"])
    cli = json.loads(capsys.readouterr().out)
    from tuner import controller_from_expr

    py = analyze(G, controller_from_expr("2.05*(z - 0.951219512195122)/(z - 1)", dt=0.05), dt=0.05)
    assert code in (0, 1)
    assert cli["metrics"]["phase_margin_deg"] == pytest.approx(py.metrics.phase_margin_deg, rel=1e-12)
    assert cli["meets_spec"] == py.meets_spec


# -- reprs -------------------------------------------------------------------------------------------------------

def test_result_reprs_are_a_few_lines():
    res = result([(1.0, 0.0), (0.5, 0.0), (1.0, 0.3)])
    a = res.analyses[0]
    for obj, head in [(res, "TuneResult("), (a, "Analysis("), (a.metrics, "Metrics("), (a.margins, "Margins("),
                      (a.checks[1], "Check("), (a.response, "StepResponse(")]:
        text = repr(obj)
        assert text.startswith(head), text
        assert len(text.splitlines()) <= 8 and len(text) < 1000, text
    assert repr(a.checks[1]) == "Check(phase_margin_deg 90 >= 60: ok)"
    bad = res.analyses[2].failing[0]
    assert "FAILS by" in repr(bad) and bad.name in repr(bad)
    assert "UNSTABLE" in repr(analyze(G, control.tf([-3], [1])).metrics)


def test_study_result_repr_is_a_few_lines():
    from tuner.studies.evaluate import LoopEval

    lp = type("LoopDefStub", (), {"name": "roll", "spec": Spec(), "inner": None})()
    ev = LoopEval(loop=lp, controller=C, analyses=result([(1.0, 0.0), (1.0, 0.3)]).analyses)
    text = repr(ev)
    assert text.startswith("LoopEval(roll") and len(text.splitlines()) <= 8, text
    assert "does NOT meet" in text


# -- the README's "Reading a result" ---------------------------------------------------------------------------

def test_readme_reading_a_result_block_runs():
    import doctest
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    section = text.split("## From Python", 1)[1].split("\n## ", 1)[0]
    blocks = [b.split("```", 1)[0] for b in section.split("```pycon\n")[1:]]
    block = next(b for b in blocks if "res.worst" in b)
    test = doctest.DocTestParser().get_doctest(block, {}, "README Reading a result", "README.md", 0)
    runner = doctest.DocTestRunner(optionflags=doctest.NORMALIZE_WHITESPACE | doctest.ELLIPSIS)
    runner.run(test)
    assert runner.tries >= 10 and runner.failures == 0


def test_study_loop_status_repr_is_one_line():
    from tuner.studies.runner import LoopStatus

    st = LoopStatus("done", 2, result={"gains": {"Kp": 1.0}, "metrics": {f"m{i}": i for i in range(200)}},
                    worker="w1")
    assert repr(st) == "LoopStatus(done, epoch 2, worker w1, result with 2 fields)"
