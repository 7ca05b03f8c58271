"""Crafted result files are bad input (issue 42, item 3): a result file (``tune --json``) given to ``export --result``
and an identification (``identify --json``) given to ``--identified`` are checked against their schema before
anything is formatted or built, so a field of the wrong type is exit 2 naming it, never exit 3 ("internal error").
Before: a non-number in vehicle.gyro_cutoff_hz, vehicle.current_gains.P or controller.dt, a list in gains.P, a
model.poles of 1e308 or a delay of 1e308 s ended in exit 3.

The property test mutates saved results field by field: every field (dicts and lists included, the first items of a
list) replaced by each of a set of hostile values, then values drawn by hypothesis."""

from __future__ import annotations

import fcntl
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from tuner.cli import main
from tuner.export.resultfile import check_result

ROOT = Path(__file__).resolve().parents[2]
PARAMS = ("1\t1\tMC_ROLLRATE_P\t0.15\t9\n1\t1\tMC_ROLLRATE_I\t0.2\t9\n1\t1\tMC_ROLLRATE_D\t0.003\t9\n"
          "1\t1\tIMU_GYRO_RATEMAX\t400\t6\n1\t1\tIMU_GYRO_CUTOFF\t40\t9\n")
HOSTILE = ["x", [1, 2], {"a": 1}, None, True, -1, 0, 1e308, "NaN", [], {}]
SETTINGS = dict(deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck),
                phases=[Phase.explicit, Phase.generate])


def _tuner_json(*args: str, cwd: Path) -> subprocess.Popen:
    """``tuner ARGS --json`` started in ``cwd`` (:func:`_json` waits for it and reads its output)."""
    return subprocess.Popen([sys.executable, "-m", "tuner.cli", *args, "--json"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=cwd)


def _json(p: subprocess.Popen) -> dict[str, Any]:
    out, err = p.communicate(timeout=300)
    assert p.returncode in (0, 1), err
    return json.loads(out)


def _saved(d: Path) -> dict[str, dict[str, Any]]:
    """Results as the command line saves them (written in ``d``): a px4_rate tune with its vehicle, a pid_z, a 2-DOF
    pid2, and an identification, and a tune of the identified model (the runs side by side: after the
    identification, the tune it needs)."""
    (d / "quad.params").write_text(PARAMS)
    fast = ["--budget", "3", "--effort", "fast"]
    runs = {
        "identified": _tuner_json("identify", str(ROOT / "studies/data/pitch_sweep.csv"), "--time", "t", "--input",
                                  "pitch_cmd", "--output", "pitch", "--poles", "2", "--holdout", "0", cwd=d),
        "px4": _tuner_json("tune", "--plant", "200/(s*(0.02*s+1))", "--structure", "px4_rate", "--params",
                           "quad.params", *fast, cwd=d),
        "pid_z": _tuner_json("tune", "--plant", "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)", "--dt", "0.04",
                             "--structure", "pid_z", *fast, cwd=d),
        "pid2": _tuner_json("tune", "--plant", "1/(s+1)^3", "--structure", "pid2", *fast, cwd=d),
    }
    try:
        ident = _json(runs["identified"])
        (d / "ident.json").write_text(json.dumps(ident))
        # a tune of an identified model: its checks include the measured response's and the identification's rating
        runs["px4 identified"] = _tuner_json("tune", "--identified", "ident.json", "--structure", "px4_rate",
                                             "--dt", "0.0025", *fast, cwd=d)
        return {"identified": ident, **{k: _json(p) for k, p in runs.items() if k != "identified"}}
    finally:
        for p in runs.values():  # (one failed: the others are not left running)
            if p.poll() is None:
                p.kill()
                p.wait()


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> dict[str, dict[str, Any]]:
    """:func:`_saved`'s results, made once per run (five command-line runs, ~16 s of CPU): under xdist the first
    worker to need them makes them, under a lock in the run's temporary folder that every worker shares, and the
    others read them from there (as JSON: what they were made of)."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return _saved(tmp_path_factory.mktemp("saved"))
    shared = tmp_path_factory.getbasetemp().parent / "test_result_files.saved.json"
    with open(f"{shared}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not shared.exists():
            shared.write_text(json.dumps(_saved(tmp_path_factory.mktemp("saved"))))
        return json.loads(shared.read_text())


@pytest.mark.slow
def test_every_saved_result_passes_the_schema_as_written(saved):
    """The schema is no stricter than what tune and identify write (an identification's rating is a string where
    the other checks have figures): export reads every result the command line saved."""
    assert any(c["name"] == "identification_quality" and isinstance(c["achieved"], str)
               for c in saved["px4 identified"]["checks"])
    for kind, result in saved.items():
        if kind != "identified":
            assert check_result(result) is result, kind


def _paths(d: Any, pre: tuple = (), depth: int = 4) -> list[tuple]:
    """Every field's path (a list's first two items), to ``depth`` levels."""
    out = []
    if depth and isinstance(d, dict):
        for k, v in d.items():
            out += [(*pre, k), *_paths(v, (*pre, k), depth - 1)]
    elif depth and isinstance(d, list):
        for i, v in enumerate(d[:2]):
            out += [(*pre, i), *_paths(v, (*pre, i), depth - 1)]
    return out


def _mutated(base: dict[str, Any], path: tuple, value: Any) -> dict[str, Any]:
    d = json.loads(json.dumps(base))
    node = d
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    return d


COMMANDS = {  # (saved result, the command that reads it, where it names the file)
    "export px4": ("px4", ["export", "--format", "px4", "--result"]),
    "export c (pid_z)": ("pid_z", ["export", "--format", "c", "--result"]),
    "export text (pid2)": ("pid2", ["export", "--format", "text", "--result"]),
    "analyze --identified": ("identified", ["analyze", "--controller", "2*(z-0.5)/(z-1)", "--dt", "0.04",
                                            "--identified"]),
}


def _run(capsys, tmp_path: Path, cmd: str, doc: Any) -> tuple[int, str]:
    f = tmp_path / "mutated.json"
    f.write_text(json.dumps(doc))
    rc = main([*COMMANDS[cmd][1], str(f)])
    return rc, capsys.readouterr().err


@pytest.fixture(scope="module")
def _parser():
    import tuner.cli

    return tuner.cli.build_parser()


@pytest.fixture
def one_parser(_parser, monkeypatch):
    """A sweep's cases share one command-line parser: ``main`` builds the same one (``build_parser``, a function of
    nothing) on every call, which was most of an export's time (~60 % of export px4's). Each case still goes through
    ``main``: its argument parsing, the command, and the mapping of errors to exit codes and messages.
    (``test_the_issues_cases_name_the_field`` and the other command-line tests build it per call.)"""
    import tuner.cli

    monkeypatch.setattr(tuner.cli, "build_parser", lambda: _parser)


def _bad_input_or_done(rc: int, err: str, what: str) -> None:
    assert rc in (0, 1, 2), (what, rc, err)
    assert "internal error" not in err and "Traceback" not in err, (what, err)
    if rc == 2:
        assert err.startswith("tuner: error: ") and err.count("\n") == 1, (what, err)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("cmd", list(COMMANDS))
def test_every_field_of_a_saved_result_replaced_by_a_hostile_value(cmd, saved, one_parser, tmp_path, capsys):
    base = saved[COMMANDS[cmd][0]]
    paths = _paths(base, depth=4 if cmd.startswith("export") else 3)
    assert len(paths) > 40
    for path in paths:
        for value in HOSTILE:
            rc, err = _run(capsys, tmp_path, cmd, _mutated(base, path, value))
            _bad_input_or_done(rc, err, f"{cmd}: {path} = {value!r}")


json_values = st.recursive(st.none() | st.booleans() | st.integers(-10**20, 10**20) | st.floats(allow_nan=False)
                           | st.text(max_size=20) | st.sampled_from(["Infinity", "-Infinity", "NaN"]),
                           lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner,
                                                                                       max_size=4), max_leaves=8)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("cmd", ["export px4", "export c (pid_z)", "analyze --identified"])
@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_values_drawn_into_a_field_are_bad_input_or_read(cmd, saved, one_parser, tmp_path_factory, capsys):
    base = saved[COMMANDS[cmd][0]]
    paths = _paths(base, depth=3)
    tmp = tmp_path_factory.mktemp("drawn")

    @given(path=st.sampled_from(paths), value=json_values)
    @settings(max_examples=60, **SETTINGS)
    def check(path, value):
        rc, err = _run(capsys, tmp, cmd, _mutated(base, path, value))
        _bad_input_or_done(rc, err, f"{cmd}: {path} = {value!r}")

    check()


@pytest.mark.parametrize("cmd, path, value, words", [
    ("export px4", ("vehicle", "gyro_cutoff_hz"), "fast", "vehicle.gyro_cutoff_hz: a number or null, got 'fast'"),
    ("export px4", ("vehicle", "current_gains", "P"), "x", "vehicle.current_gains.P: a number, got 'x'"),
    ("export c (pid_z)", ("controller", "dt"), "x", "controller.dt: a number or null, got 'x'"),
    ("export px4", ("gains", "P"), [1, 2], "gains.P: a number, got [1, 2]"),
    ("analyze --identified", ("model", "poles"), 1e308, "model.poles: a whole number, got 1e+308"),
    ("analyze --identified", ("model", "parameters", "delay_s"), 1e308,
     "model.parameters.delay_s: a delay of 0 to 1e6 s, got 1e+308"),
    ("analyze --identified", ("options", "coherence_min"), "x", "options.coherence_min: a number, got 'x'"),
])
def test_the_issues_cases_name_the_field(cmd, path, value, words, saved, tmp_path, capsys):
    rc, err = _run(capsys, tmp_path, cmd, _mutated(saved[COMMANDS[cmd][0]], path, value))
    assert rc == 2 and f"{tmp_path / 'mutated.json'}: {words}" in err, err
