"""``tuner tune`` on the command line (tuner.cli.main with capsys).

The JSON output must carry the analyze fields (metrics, checks, meets_spec) plus gains, the
controller (num, den, dt) and the solver information, and its numbers must be the verifier's:
the same controller fed back through ``tuner analyze --json`` gives the same metrics. Several
``--plant`` make a robust tune (a ``plants`` list). Bad input exits 2 with a one-line message and
no traceback.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from quadrotor import DT, ROLL

from tuner.analysis.verify import analyze
from tuner.cli import main
from tuner.controllers import get_structure
from tuner.jsonio import jsonable
from tuner.plant import plant_from_expr
from tuner.spec import Spec

BUDGET = "120"  # never what stops the search
ROLL_FAST_GAIN = "1.2*" + ROLL  # roll with +20 % gain


def run(capsys, *args):
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def tune_json(capsys, *args, expect=0):
    """``tuner tune ... --json``; exit 0 when the spec is met, 1 when it is not (the JSON is printed either way)."""
    code, out, err = run(capsys, "tune", *args, "--budget", BUDGET, "--json")
    assert code == expect, err
    return json.loads(out)


@pytest.fixture(scope="module")
def single(request):
    # module scope, so no capsys here: capture by hand
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["tune", "--plant", ROLL, "--dt", str(DT), "--structure", "pid_z", "--budget", BUDGET, "--json"])
    assert code == 0
    return json.loads(buf.getvalue())


def _poly(coeffs):
    n = len(coeffs) - 1
    return "+".join(f"({c!r})*z^{n - i}" for i, c in enumerate(coeffs))


def _close(a, b, rel=1e-9):
    if isinstance(a, str) or isinstance(b, str):  # "Infinity", "NaN"
        return a == b
    if isinstance(a, bool) or isinstance(b, bool):
        return a == b
    return math.isclose(a, b, rel_tol=rel, abs_tol=1e-12)


def test_tune_json_fields(single):
    d = single
    for key in ("metrics", "checks", "meets_spec", "gains", "controller", "solver", "failing", "structure"):
        assert key in d, key
    assert d["structure"] == "pid_z"
    assert set(d["gains"]) == {"K", "a1", "a2"}
    assert set(d["controller"]) == {"num", "den", "dt"} and d["controller"]["dt"] == DT
    s = d["solver"]
    for key in ("method", "wall_time_s", "nlp_iterations", "nlp_evaluations", "starts_tried", "seed",
                "global_evaluations"):
        assert key in s, key
    assert s["seed"] == 0 and s["method"] == "optuna+casadi-sqp" and s["starts_tried"] >= 1
    assert s["nlp_iterations"] > 0 and s["wall_time_s"] > 0
    assert "plants" not in d  # one plant
    # the thesis roll loop tunes to the spec, 3x faster than the thesis's 0.5 s
    assert d["meets_spec"] is True and d["failing"] == []
    assert all(c["ok"] for c in d["checks"])
    assert d["metrics"]["settling_time_s"] <= 0.5 / 3


def test_tune_json_numbers_are_the_verifiers(single):
    d = single
    c = get_structure("pid_z").tf(d["gains"], DT)
    np.testing.assert_allclose(d["controller"]["num"], c.num, rtol=1e-12)
    np.testing.assert_allclose(d["controller"]["den"], c.den, rtol=1e-12)
    # the spec the tune checked (its default noise budget resolved to mks_max), re-checked by analyze
    want = jsonable(analyze(plant_from_expr(ROLL), c, Spec(**d["spec"])).to_dict())
    assert want["meets_spec"] == d["meets_spec"]
    for k, v in want["metrics"].items():
        assert _close(d["metrics"][k], v), (k, d["metrics"][k], v)
    assert [(x["name"], x["ok"]) for x in d["checks"]] == [(x["name"], x["ok"]) for x in want["checks"]]


def test_tune_output_round_trips_through_analyze(single, capsys):
    """The tuned controller written as an expression and fed to `tuner analyze --json` gives the same figures."""
    d = single
    expr = f"({_poly(d['controller']['num'])})/({_poly(d['controller']['den'])})"
    code, out, err = run(capsys, "analyze", "--plant", ROLL, "--dt", str(DT), "--controller", expr, "--json")
    assert code == 0, err
    a = json.loads(out)
    assert a["meets_spec"] is True
    for k, v in a["metrics"].items():
        assert _close(d["metrics"][k], v, rel=1e-6), (k, d["metrics"][k], v)


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_tune_robust_json(capsys):
    d = tune_json(capsys, "--plant", ROLL, "--plant", ROLL_FAST_GAIN, "--dt", str(DT), "--structure", "pid_z")
    assert len(d["plants"]) == 2
    for p in d["plants"]:
        assert set(p) >= {"metrics", "checks", "meets_spec"}
    assert d["meets_spec"] == all(p["meets_spec"] for p in d["plants"])
    assert d["meets_spec"] is True
    # the nominal figures are the first plant's, and each plant's figures are the verifier's
    assert d["metrics"] == d["plants"][0]["metrics"]
    c = get_structure("pid_z").tf(d["gains"], DT)
    for text, p in zip((ROLL, ROLL_FAST_GAIN), d["plants"]):
        want = jsonable(analyze(plant_from_expr(text), c).to_dict())
        for k, v in want["metrics"].items():
            assert _close(p["metrics"][k], v), (k, p["metrics"][k], v)


def test_tune_table_output(single, capsys):
    code, out, err = run(capsys, "tune", "--plant", ROLL, "--dt", str(DT), "--structure", "pid_z", "--budget", BUDGET)
    assert code == 0, err
    assert "meets the spec" in out and "does NOT" not in out
    d = single  # the same tune with --json: same seed, same gains
    line = "pid_z: " + ", ".join(f"{k} = {v:.6g}" for k, v in d["gains"].items())
    assert line in out
    assert "solver: optuna+casadi-sqp" in out and "seed 0" in out


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_tune_infeasible_json_exits_1_and_names_the_failing_constraint(capsys):
    # --control-peak 1 with zero steady-state error on roll is infeasible: u(inf) = 1/G(0) = 3.77 > 1
    d = tune_json(capsys, "--plant", ROLL, "--dt", str(DT), "--structure", "pid_z", "--control-peak", "1", expect=1)
    assert d["meets_spec"] is False
    assert "control_peak" in d["failing"]
    bad = [c for c in d["checks"] if not c["ok"]]
    assert sorted(c["name"] for c in bad) == d["failing"]
    assert all(c["violation"] > 0 for c in bad)


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--plant", ROLL, "--dt", "0.04", "--structure", "nope"], "structure"),
        (["--plant", ROLL, "--structure", "pid_z"], "dt"),  # discrete structure without --dt
        (["--plant", "1/(s+", "--dt", "0.04", "--structure", "pid"], "--plant"),
        (["--plant", "1/(s+1)*x", "--structure", "pi"], "--plant"),
        (["--plant", ROLL, "--plant", "2/(s", "--dt", "0.04", "--structure", "pid"], "--plant #2"),
        (["--plant", ROLL, "--dt", "0.04", "--structure", "pid", "--budget", "-5"], "--budget"),
        (["--plant", ROLL, "--dt", "0.04", "--structure", "pid", "--budget", "0"], "--budget"),
        (["--plant", ROLL, "--dt", "0.04", "--structure", "pid", "--budget", "nan"], "--budget"),
        (["--plant", ROLL, "--dt", "-0.04", "--structure", "pid"], "dt"),
        (["--plant", ROLL, "--dt", "0.04", "--structure", "pid", "--pm", "120"], "--pm"),
        (["--plant", ROLL, "--dt", "0.04", "--structure", "pid", "--seed", "-1"], "--seed"),
        (["--plant", "0.04/(z-1)", "--structure", "pi"], "dt"),  # z plant without --dt
    ],
)
def test_tune_bad_input_exits_2_with_one_line(capsys, args, needle):
    code, out, err = run(capsys, "tune", *args)
    assert code == 2
    assert out == ""
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("tuner: error: ") and needle in lines[0], lines[0]


def test_tune_missing_structure_is_an_argparse_error(capsys):
    with pytest.raises(SystemExit) as e:
        main(["tune", "--plant", ROLL])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "--structure" in err


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_the_printed_controller_round_trips(capsys):
    """Issue 30: the C(z) the table prints, pasted back, is the controller that was verified (at 6 digits a PID's
    (z - 1) was lost: steady-state error FAIL); its factored line writes the integrator exactly."""
    import re

    from tuner.controllers import controller_from_coeffs

    assert main(["tune", "--plant", "1/(s+1)^3", "--structure", "pid", "--dt", "0.1"]) == 0
    out = capsys.readouterr().out.splitlines()
    line = next(x for x in out if x.startswith("C(z) = ["))
    num, den = (np.array([float(v) for v in grp.split(",")]) for grp in re.findall(r"\[([^\]]*)\]", line))
    assert re.search(r"dt = 0\.1\b", line)
    assert np.sum(den) == 0.0 or abs(np.sum(den)) < 1e-15  # the integrator, as tuned
    a = analyze(plant_from_expr("1/(s+1)^3"), controller_from_coeffs(num, den, dt=0.1))
    assert a.meets_spec and abs(a.metrics.steady_state_error) < 1e-9
    factored = out[out.index(line) + 1]
    assert "(z - 1)" in factored
    # every printed coefficient is the tuned double itself (the JSON's, the same tune again: seeded)
    assert main(["tune", "--plant", "1/(s+1)^3", "--structure", "pid", "--dt", "0.1", "--json"]) == 0
    tuned = json.loads(capsys.readouterr().out)["controller"]
    assert list(num) == tuned["num"] and list(den) == tuned["den"]


@pytest.mark.parametrize("dt, meant", [(4.0, "4 ms"), (250.0, "a rate of 250 Hz")])
@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_a_unit_slip_in_dt_is_named(capsys, dt, meant):
    """Issue 30: a sample time far above a fifth of the plant's fastest time constant (the roll model's 0.067 s) says
    which slip it likely is and what it would give; a plausible one says nothing."""
    main(["tune", "--plant", ROLL, "--structure", "pid_z", "--dt", str(dt), "--budget", "2"])
    err = capsys.readouterr().err
    assert f"if {meant} was meant, give dt = 0.004 s" in err
    assert main(["tune", "--plant", ROLL, "--structure", "pid_z", "--dt", str(DT)]) == 0
    assert "fastest time constant" not in capsys.readouterr().err
