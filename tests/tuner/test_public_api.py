"""The public surface: ``from tuner import tune, analyze, ...`` gives the functions, in any import order."""

from __future__ import annotations

import inspect
import pickle
import subprocess
import sys

import pytest

import tuner
from tuner.errors import InvalidExpressionError, InvalidPlantError, TunerError

ORDERS = {
    "package first": "import tuner\nfrom tuner import tune, analyze, Spec, make_plant",
    "submodules first": "import tuner.tuning, tuner.analysis.verify, tuner.optimize.search\n"
                        "from tuner import tune, analyze, Spec, make_plant",
    "from-import first": "from tuner import tune, analyze, Spec, make_plant\nimport tuner.tuning",
}
CHECK = """
import inspect, tuner
assert inspect.isfunction(tune) and tune.__module__ == "tuner.tuning", tune
assert inspect.isfunction(analyze) and analyze.__module__ == "tuner.analysis.verify", analyze
assert inspect.isfunction(make_plant), make_plant
assert isinstance(Spec, type), Spec
assert tuner.tune is tune and tuner.analyze is analyze
print("ok")
"""


@pytest.mark.parametrize("order", list(ORDERS))
def test_public_functions_in_any_import_order(order):
    code = ORDERS[order] + CHECK
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_all_is_the_public_surface():
    for name in tuner.__all__:
        assert hasattr(tuner, name), name
    assert "tune" in tuner.__all__ and inspect.isfunction(tuner.tune)
    assert isinstance(tuner.__version__, str) and tuner.__version__


def test_errors_carry_their_field_and_survive_pickling():
    with pytest.raises(InvalidPlantError) as ei:
        tuner.make_plant([1.0], [1.0, 1.0], delay=-1)
    assert ei.value.field == ("delay",)
    with pytest.raises(InvalidExpressionError) as ei:
        tuner.plant_from_expr("1/(s+")
    assert ei.value.field == ("expr",) and ei.value.position is not None
    e = pickle.loads(pickle.dumps(ei.value))
    assert type(e) is InvalidExpressionError and e.field == ("expr",) and e.position == ei.value.position
    assert str(e) == str(ei.value)
    assert TunerError("x", field=("plants", 2, "delay")).at("body").field == ("body", "plants", 2, "delay")


def test_python_control_and_export_names():
    assert {"export_controller", "plant_from_control", "controller_from_control", "LoopTFs"} <= set(tuner.__all__)
    assert inspect.isfunction(tuner.export_controller) and tuner.export_controller.__module__ == "tuner.export.source"
    assert tuner.plant_from_control.__module__ == "tuner.plant"  # (with the plant since issue 29; interop re-exports)
    assert tuner.LoopTFs._fields == ("L", "S", "T")


def test_help_stays_light():
    """``tuner --help`` builds every sub-command's parser (export included) without numpy, control or the rest."""
    code = ("import sys, tuner.cli\ntuner.cli.build_parser()\n"
            "heavy = [m for m in ('numpy', 'scipy', 'control', 'matplotlib', 'casadi', 'optuna', 'pydantic') "
            "if m in sys.modules]\nprint(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "[]", (out.stdout, out.stderr)
