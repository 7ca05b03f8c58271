"""What a cold ``tuner tune`` pays beyond its search (issue 41): the SQP solver is made without CasADi's
``nlp_grad`` Function (the Lagrangian's gradient, evaluated after a solve only to recompute f, g and the
multipliers), and answers bitwise as the solver with it: every solve's x, f and g, and every tune's gains."""

from __future__ import annotations

import os
import subprocess
import sys
from collections import OrderedDict

import casadi as cs
import numpy as np
import pytest

from tuner import tune
from tuner.optimize import batch
from tuner.optimize.nlp import transcribe
from tuner.plant import make_plant
from tuner.spec import Spec

_NO_GRAD = ("no_nlp_grad", "calc_f", "calc_g", "calc_lam_x", "calc_lam_p")
_SQP_OPTIONS = transcribe.sqp_options


def _with_nlp_grad() -> dict:
    """The solver's options as CasADi's defaults have them for nlp_grad: made, and f, g, lam_x, lam_p recomputed
    with it after each solve."""
    return {k: v for k, v in _SQP_OPTIONS().items() if k not in _NO_GRAD}


class _Recording:
    """A built problem's solver that records every call's arguments (what a refinement really asks: its starts, its
    parameters and its bounds) and how the call ended."""

    def __init__(self, solver) -> None:
        self.solver, self.calls = solver, []

    def __call__(self, **kw):
        sol = self.solver(**kw)
        self.calls.append(({k: np.array(v, dtype=float, copy=True) for k, v in kw.items()},
                           self.solver.stats()["return_status"]))
        return sol

    def stats(self):
        return self.solver.stats()


@pytest.fixture
def fresh(monkeypatch):
    monkeypatch.setenv("TUNER_NLP_GRAPHS", "off")
    monkeypatch.setenv("TUNER_NLP_COMPILE", "off")
    monkeypatch.setenv("TUNER_KERNELS", "off")
    monkeypatch.setitem(batch._KERNELS, "module", None)
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    built = []
    real = transcribe._build

    def build(key, st, space):
        prob = real(key, st, space)
        prob.solver = _Recording(prob.solver)
        built.append(prob)
        return prob

    monkeypatch.setattr(transcribe, "_build", build)
    return built


def test_the_sqp_solver_makes_no_nlp_grad():
    x = cs.SX.sym("x", 2)
    p = cs.SX.sym("p")
    nlp = cs.Function("nlp", [x, p], [(x[0] - p) ** 2 + x[1] ** 2, x[0] + x[1]], ["x", "p"], ["f", "g"])
    solver = cs.nlpsol("s", "sqpmethod", nlp, transcribe.sqp_options())
    assert "nlp_grad" not in solver.get_function()
    assert "nlp_grad" in cs.nlpsol("r", "sqpmethod", nlp, _with_nlp_grad()).get_function()
    sol = solver(x0=[3.0, -1.0], p=2.0, lbg=-np.inf, ubg=1.0)
    # min (x0 - 2)^2 + x1^2 with x0 + x1 <= 1: on the line, x0 - 2 = x1 (the gradient normal to it)
    assert np.allclose(np.asarray(sol["x"]).ravel(), [1.5, -0.5], atol=1e-6)
    assert float(sol["f"]) == pytest.approx(0.5, abs=1e-6)


@pytest.mark.parametrize("objective", ["settling_time", "itae"])
def test_every_solve_answers_bitwise_as_with_nlp_grad(fresh, objective):
    """Every solve a tune's refinements made (their own starts, parameters and bounds, converged ones among them),
    replayed on the solver made with nlp_grad: the same x, f, g, iterations and status, bitwise."""
    tune(make_plant([1.0], [1.0, 2.0, 1.0]), structure="pid", dt=0.1, seed=1, diagnose=False, effort="fast",
         spec=Spec(objective=objective))
    calls = [(prob, kw, status) for prob in fresh for kw, status in prob.solver.calls]
    assert calls
    assert any(status == "Solve_Succeeded" for _, _, status in calls), {s for _, _, s in calls}
    refs: dict[int, object] = {}
    for prob, kw, status in calls:
        ref = refs.setdefault(id(prob), cs.nlpsol("ref", "sqpmethod", prob.nlp, _with_nlp_grad()))
        a, b = prob.solver.solver(**kw), ref(**kw)
        for k in ("x", "f", "g"):
            assert np.array_equal(np.asarray(a[k]), np.asarray(b[k]), equal_nan=True), k
        assert prob.solver.solver.stats()["iter_count"] == ref.stats()["iter_count"]
        assert prob.solver.solver.stats()["return_status"] == ref.stats()["return_status"] == status


@pytest.mark.slow  # (two tunes of each objective: the whole suite runs it)
@pytest.mark.parametrize("objective", ["settling_time", "itae"])
def test_a_tune_finds_bitwise_the_gains_it_found_with_nlp_grad(fresh, monkeypatch, objective):
    def run():
        transcribe._CACHE.clear()
        r = tune(make_plant([1.0], [1.0, 3.0, 3.0, 1.0]), structure="pid", dt=0.1, seed=0, diagnose=False,
                 spec=Spec(objective=objective), effort="fast", time_budget_s=600)
        return {k: float(v).hex() for k, v in r.gains.items()}, r.meets_spec

    now = run()
    monkeypatch.setattr(transcribe, "sqp_options", _with_nlp_grad)
    assert run() == now


def test_a_cold_command_line_tune_imports_only_what_it_uses(tmp_path):
    """A cold ``tuner tune`` of a model (no identification, no plot, one process) imports none of: the robust
    plant sets (tuner.robust), the batch's compiled kernels and numba, scipy.stats, Optuna, matplotlib."""
    heavy = ("tuner.robust", "tuner.optimize.kernels", "numba", "scipy.stats", "optuna", "matplotlib")
    code = ("import sys\nfrom tuner.cli import main\n"
            "rc = main(['tune', '--plant', '1/(s+1)^2', '--dt', '0.1', '--structure', 'pi', '--effort', 'fast'])\n"
            f"print(rc, [m for m in {heavy!r} if m in sys.modules])")
    # (the library's defaults for the rest: a TUNER_KERNELS=on the caller set would load the kernels on purpose)
    env = {**os.environ, "TUNER_CACHE_DIR": str(tmp_path), "TUNER_NLP_COMPILE": "off", "TUNER_KERNELS": "auto"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "0 []"
