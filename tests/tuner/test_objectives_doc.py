"""``tuner --version``, and every objective documented with its exact definition (issue 14), the definitions
checked against the numbers: a PI on 1/(s + 1) in a continuous loop, whose closed loops are known in closed
form (T = (2s + 3)/(s^2 + 3s + 3), from the load to y: s/(s^2 + 3s + 3)), simulated here by scipy.
"""

from __future__ import annotations

import typing
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest
from scipy import integrate, optimize, signal

from tuner import analyze, controller_from_expr, plant_from_expr
from tuner.cli import main
from tuner.objectives import OBJECTIVE_DEFINITIONS, ROBUST_NOTE
from tuner.spec import OBJECTIVES, Spec

ROOT = Path(__file__).resolve().parents[2]
KP, KI = 2.0, 3.0
T_REF = signal.TransferFunction([KP, KI], [1.0, 3.0, 3.0])  # C G / (1 + C G), C = 2 + 3/s, G = 1/(s + 1)
T_LOAD = signal.TransferFunction([1.0, 0.0], [1.0, 3.0, 3.0])  # G / (1 + C G)


def test_version_from_package_metadata(capsys):
    with pytest.raises(SystemExit) as ei:
        main(["--version"])
    assert ei.value.code == 0
    assert capsys.readouterr().out.strip() == f"tuner {metadata.version('tuner')}"


def test_every_objective_of_the_spec_is_defined_in_help_and_readme(capsys):
    literal = typing.get_args(Spec.model_fields["objective"].annotation)
    # "auto" (the default) is no objective of its own: the structure picks one (tuner.spec.resolved_objective)
    assert set(literal) == set(OBJECTIVES) | {"auto"} and set(OBJECTIVES) == set(OBJECTIVE_DEFINITIONS)
    with pytest.raises(SystemExit):
        main(["tune", "--help"])
    help_text = capsys.readouterr().out
    readme = (ROOT / "README.md").read_text()
    for k, v in OBJECTIVE_DEFINITIONS.items():
        assert f"  {k}: {v}" in help_text, k
        assert f"| `{k}` | " + v.replace("|", "\\|") + " |" in readme, k
    assert ROBUST_NOTE in help_text and ROBUST_NOTE in readme
    assert "{" + ",".join(OBJECTIVES) + ",auto}" in help_text.replace("\n", "").replace(" ", "")  # --objective choices


@pytest.fixture(scope="module")
def pi():
    return analyze(plant_from_expr("1/(s+1)"), controller_from_expr(f"{KP}+{KI}/s", dt=None))


def _fine(T: float) -> np.ndarray:
    return np.linspace(0.0, T, 400_001)


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_settling_time_is_the_last_exit_from_the_band(pi):
    t = _fine(pi.response.t[-1])
    _, y = signal.step(T_REF, T=t)
    out = np.flatnonzero(np.abs(y - 1.0) > 0.02)
    assert abs(pi.metrics.settling_time_s - t[out[-1]]) < 1e-3


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_itae_is_t_abs_error_of_the_reference_step_on_the_horizon(pi):
    from tuner.optimize.scoring import objective_value

    T = float(pi.response.t[-1])
    t = _fine(T)
    _, y = signal.step(T_REF, T=t)
    ref = integrate.trapezoid(t * np.abs(1.0 - y), t)
    assert objective_value(pi, Spec(objective="itae")) == pytest.approx(ref, rel=1e-4)


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_iae_is_abs_output_after_a_unit_load_step_at_the_plant_input(pi):
    from tuner.optimize.scoring import objective_value

    t = _fine(float(pi.response.t[-1]))
    _, y = signal.step(T_LOAD, T=t)
    assert objective_value(pi, Spec(objective="iae")) == pytest.approx(integrate.trapezoid(np.abs(y), t), rel=1e-4)


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_ie_is_one_over_ki(pi):
    from tuner.optimize.scoring import objective_value

    # the integrated error after the unit load step, to steady state: the identity the ie objective rests on
    t = _fine(40.0)
    _, y = signal.step(T_LOAD, T=t)
    assert integrate.trapezoid(y, t) == pytest.approx(1.0 / KI, rel=1e-6)
    # and the library's ie objective is that number (on its own horizon, where the loop has settled)
    t = _fine(float(pi.response.t[-1]))
    _, y = signal.step(T_LOAD, T=t)
    assert objective_value(pi, Spec(objective="ie")) == pytest.approx(abs(integrate.trapezoid(y, t)), rel=1e-4)
    assert objective_value(pi, Spec(objective="ie")) == pytest.approx(1.0 / KI, rel=1e-3)
    # without integral action the load step is never rejected: no finite ie
    p_only = analyze(plant_from_expr("1/(s+1)"), controller_from_expr(f"{KP}", dt=None))
    assert objective_value(p_only, Spec(objective="ie")) == float("inf")


def test_bandwidth_is_where_t_falls_below_its_dc_value_over_sqrt2(pi):
    def mag(w):
        return abs(T_REF.num[0] * 1j * w + T_REF.num[1]) / abs((1j * w) ** 2 + 3 * 1j * w + 3) - 1 / np.sqrt(2)

    assert pi.metrics.bandwidth_rad_s == pytest.approx(optimize.brentq(mag, 0.1, 100.0), rel=1e-8)


def test_every_limit_of_the_registry_is_in_the_readme_table_and_help(capsys):
    """The README's limits table lists every optional limit of the registry with its flag; --help has each flag."""
    from tuner.limits import LIMITS

    readme = (ROOT / "README.md").read_text()
    with pytest.raises(SystemExit):
        main(["tune", "--help"])
    help_text = capsys.readouterr().out
    for lim in LIMITS:
        assert f"| `{lim.field}` | `{lim.flag}` |" in readme, lim.field
        assert lim.flag in help_text, lim.flag
