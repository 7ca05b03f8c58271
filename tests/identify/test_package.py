"""The package's surface: ``from tuner import identify`` is the function, and importing
``tuner.identify`` stays light (scipy.signal, scipy.optimize and matplotlib only inside functions)."""

from __future__ import annotations

import ast
import importlib
import inspect
from pathlib import Path

import tuner

# ``import tuner.identify as pkg`` would give the function: ``tuner.identify`` is the function's name
pkg = importlib.import_module("tuner.identify")

HEAVY = ("scipy", "matplotlib", "control", "casadi", "optuna", "pandas")


def test_the_name_is_the_function_with_every_parameter_documented():
    from tuner import identify

    assert callable(identify) and identify.__module__ == "tuner.identify.core"
    assert "identify" in tuner.__all__ and "IdentifyResult" in tuner.__all__
    doc = identify.__doc__ or ""
    for name, p in inspect.signature(identify).parameters.items():
        assert name in doc, name
        if name not in ("input", "output"):
            assert p.kind is inspect.Parameter.KEYWORD_ONLY, name


def test_no_heavy_import_at_module_level():
    root = Path(pkg.__file__).parent
    for path in sorted(root.glob("*.py")):
        tree = ast.parse(path.read_text())
        for node in tree.body:  # module level only; imports inside functions are the point
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or ""]
            for n in names:
                assert n.split(".")[0] not in HEAVY, f"{path.name} imports {n} at module level"
