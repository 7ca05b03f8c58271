"""Exit codes of every ``tuner`` command (issue 11): 0 ok, 1 spec not met, 2 bad input, 3 internal error.

Bad input is one line on stderr naming the argument, never a traceback; ``--json`` output stays on
stdout whatever the exit code. The classes from the issue: a gain of 1e200 (an honest result now),
``lead`` at dt = 10000 (inverted search bounds before), a gains file with ``"dt": "fast"`` or not in
UTF-8, and dt = 1e-9 (below the minimum the API also applies, :data:`tuner.plant.MIN_DT_S`).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tuner import cli
from tuner.cli import EXIT_BAD_INPUT, EXIT_INTERNAL, EXIT_OK, EXIT_SPEC_NOT_MET, main
from tuner.plant import MIN_DT_S

ROOT = Path(__file__).resolve().parents[2]
QUAD = ROOT / "studies" / "quadrotor.toml"
GAINS = ROOT / "studies" / "quadrotor.gains.json"


def run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(err: str, *words: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tuner: error:"), err
    assert "Traceback" not in err
    for w in words:
        assert w in lines[0], (w, lines[0])


# -- analyze ------------------------------------------------------------------------------------------

def test_analyze_ok_0_and_not_met_1(capsys):
    assert run(capsys, "analyze", "--plant", "1/(s+1)", "--controller", "2+2/s")[0] == EXIT_OK
    code, out, _ = run(capsys, "analyze", "--plant", "1/(s+1)", "--controller", "2", "--json")
    assert code == EXIT_SPEC_NOT_MET  # a P controller leaves a steady-state error of 1/3
    assert json.loads(out)["meets_spec"] is False  # the JSON is still written, on stdout


def test_analyze_huge_gain_is_an_honest_answer(capsys):
    """1e200/(s+1) in unity feedback: one pole at -(1 + 1e200), crossover at 1e200 rad/s, PM 90 deg."""
    code, out, err = run(capsys, "analyze", "--plant", "1/(s+1)", "--controller", "1e200", "--json")
    assert code == EXIT_OK, err
    m = json.loads(out)["metrics"]
    assert m["stable"] is True
    assert m["phase_margin_deg"] == pytest.approx(90.0, abs=1e-6)
    assert m["crossover_rad_s"] == pytest.approx(1e200, rel=1e-6)


@pytest.mark.parametrize(("args", "words"), [
    (["--controller", "1e150+1e150/s"], ["--controller", "decades"]),  # poles at -1 and -1e150: undecidable
    (["--controller", "2", "--dt", "1e-9"], ["--dt", "1e-06"]),
    (["--controller", "2", "--dt", "nan"], ["--dt"]),
    (["--controller", "2", "--delay", "-1"], ["--plant", "delay"]),
    (["--controller", "2", "--delay", "1e-7"], ["--delay", "1e-06"]),
    (["--controller", "__import__('os')"], ["--controller"]),
    (["--controller", "(s+1)^41/(s+2)^41"], ["--controller", "40"]),
    (["--controller", "s^2/(s+1)"], ["--controller", "improper"]),
])
def test_analyze_bad_input_2(capsys, args, words):
    code, out, err = run(capsys, "analyze", "--plant", "1/(s+1)", *args)
    assert code == EXIT_BAD_INPUT
    assert_one_line_error(err, *words)


def test_min_dt_is_the_services():
    from api.schemas import AnalyzeRequest

    assert MIN_DT_S == 1e-6
    assert AnalyzeRequest.model_json_schema()["properties"]["dt"]["anyOf"][0]["minimum"] == MIN_DT_S


# -- tune ---------------------------------------------------------------------------------------------

def test_tune_spec_not_met_is_1_with_json_on_stdout(capsys):
    """The issue's lead at dt = 10000 (a 500 before): a result now; a lead has no integral action, so the
    default spec's zero steady-state error cannot be met: exit 1, the JSON still on stdout."""
    code, out, err = run(capsys, "tune", "--plant", "1/(s+1)", "--structure", "lead", "--dt", "10000",
                         "--budget", "1", "--json")
    assert code == EXIT_SPEC_NOT_MET, err
    d = json.loads(out)
    assert d["meets_spec"] is False and "steady_state_error" in d["failing"]


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_tune_ok_0(capsys):
    code, out, err = run(capsys, "tune", "--plant", "1/(s+1)", "--structure", "pi", "--budget", "3", "--json")
    assert code == EXIT_OK, err
    assert json.loads(out)["meets_spec"] is True


@pytest.mark.parametrize(("args", "words"), [
    (["--structure", "pi", "--dt", "1e-9"], ["--dt", "1e-06"]),
    (["--structure", "pidd"], ["--structure", "unknown structure"]),
    (["--structure", "pi", "--budget", "0"], ["--budget"]),
    (["--structure", "pi", "--budget", "nan"], ["--budget"]),
    (["--structure", "pi", "--seed", "-1"], ["--seed"]),
    (["--structure", "pid_z"], ["--dt", "discrete"]),
    (["--structure", "pi", "--pm", "120"], ["--pm"]),
])
def test_tune_bad_input_2(capsys, args, words):
    code, out, err = run(capsys, "tune", "--plant", "1/(s+1)", *args)
    assert code == EXIT_BAD_INPUT
    assert_one_line_error(err, *words)
    assert out == ""


def test_argparse_errors_are_2():
    with pytest.raises(SystemExit) as ei:
        main(["tune", "--plant", "1/(s+1)"])  # --structure missing
    assert ei.value.code == EXIT_BAD_INPUT
    with pytest.raises(SystemExit) as ei:
        main(["analyze", "--plant", "1/(s+1)", "--controller", "1", "--dt", "fast"])
    assert ei.value.code == EXIT_BAD_INPUT


# -- verify -------------------------------------------------------------------------------------------

@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_verify_0_and_1(tmp_path, capsys):
    assert run(capsys, "verify", str(QUAD), "--gains", str(GAINS))[0] == EXIT_OK
    g = json.loads(GAINS.read_text())
    g["pitch"]["gains"]["K"] *= 3
    (tmp_path / "g.json").write_text(json.dumps(g))
    code, out, err = run(capsys, "verify", str(QUAD), "--gains", str(tmp_path / "g.json"), "--json")
    assert code == EXIT_SPEC_NOT_MET
    assert json.loads(out)["pitch"]["meets_spec"] is False


@pytest.mark.parametrize(("content", "words"), [
    (lambda g: g["roll"].update(dt="fast") or json.dumps(g).encode(), ["roll", "dt", "fast"]),
    (lambda g: g["roll"].update(dt=True) or json.dumps(g).encode(), ["roll", "dt"]),
    (lambda g: g["roll"]["gains"].update(K="big") or json.dumps(g).encode(), ["roll", "gains"]),
    (lambda g: b'{"roll": \xff\xfe}', ["UTF-8"]),
    (lambda g: b"{not json", ["not valid JSON"]),
    (lambda g: b"[]", ["expected an object"]),
])
def test_verify_bad_gains_file_2(tmp_path, capsys, content, words):
    f = tmp_path / "g.json"
    f.write_bytes(content(json.loads(GAINS.read_text())))
    code, _, err = run(capsys, "verify", str(QUAD), "--gains", str(f))
    assert code == EXIT_BAD_INPUT
    assert_one_line_error(err, *words)


def test_verify_bad_study_file_2(tmp_path, capsys):
    f = tmp_path / "s.toml"
    f.write_bytes(b'name = "\xff"\n')
    code, _, err = run(capsys, "verify", str(f), "--gains", str(GAINS))
    assert code == EXIT_BAD_INPUT
    assert_one_line_error(err, "UTF-8")
    code, _, err = run(capsys, "verify", str(tmp_path / "missing.toml"), "--gains", str(GAINS))
    assert code == EXIT_BAD_INPUT
    assert_one_line_error(err, "cannot read")


# -- study run ----------------------------------------------------------------------------------------

STUDY = 'name = "t"\ntime_budget_s = 1\n[[loop]]\nname = "a"\nplant = "1/(s+1)"\nstructure = "{s}"\n{extra}'


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_study_run_0_and_1(tmp_path, capsys):
    ok = tmp_path / "ok.toml"
    ok.write_text(STUDY.format(s="pi", extra=""))
    assert run(capsys, "study", "run", str(ok), "--out", str(tmp_path / "o1"), "--no-plots")[0] == EXIT_OK
    bad = tmp_path / "bad.toml"  # a P controller cannot give zero steady-state error on 1/(s+1)
    bad.write_text(STUDY.format(s="p", extra=""))
    code, _, err = run(capsys, "study", "run", str(bad), "--out", str(tmp_path / "o2"), "--no-plots")
    assert code == EXIT_SPEC_NOT_MET, err


@pytest.mark.parametrize(("extra", "words"), [
    ("dt = 1e-9\n", ["dt"]),
    ("delay = -1\n", ["delay"]),
    ("[loop.spec]\novershoot_max_pct = -1\n", ["overshoot_max_pct"]),
])
def test_study_run_bad_input_2(tmp_path, capsys, extra, words):
    f = tmp_path / "s.toml"
    f.write_text(STUDY.format(s="pi", extra=extra))
    code, _, err = run(capsys, "study", "run", str(f), "--out", str(tmp_path / "o"), "--no-plots")
    assert code == EXIT_BAD_INPUT
    assert_one_line_error(err, *words)


# -- every command: internal errors are 3 (not 1, which means "spec not met"), and --help says so ------

@pytest.mark.parametrize("argv", [
    ["analyze", "--plant", "1/(s+1)", "--controller", "1"],
    ["tune", "--plant", "1/(s+1)", "--structure", "pi"],
    ["verify", str(QUAD), "--gains", str(GAINS)],
    ["study", "run", str(QUAD)],
])
def test_internal_error_is_3_without_traceback(monkeypatch, capsys, argv):
    def boom(*a, **k):
        raise ZeroDivisionError("a bug")

    parser = cli.build_parser()
    handler = cli._COMMANDS.get(argv[0]) or parser.parse_args(argv).handler
    if argv[0] in cli._COMMANDS:
        monkeypatch.setitem(cli._COMMANDS, argv[0], boom)
    else:
        import tuner.studies.cli as scli

        monkeypatch.setattr(scli, handler.__name__, boom)
    code, _, err = run(capsys, *argv)
    assert code == EXIT_INTERNAL
    assert "internal error" in err and "bug" in err and "Traceback" not in err


@pytest.mark.parametrize("argv", [[], ["analyze"], ["tune"], ["verify"], ["study"], ["study", "run"]])
def test_help_documents_exit_codes(capsys, argv):
    with pytest.raises(SystemExit) as ei:
        main([*argv, "--help"])
    assert ei.value.code == 0
    out = capsys.readouterr().out
    assert "exit codes" in out and "1  done, but a spec is not met" in out and "2  bad input" in out


@pytest.mark.parametrize("argv, code, skipped", [
    (["tune", "--plant", "1/(s+1)^2", "--dt", "0.1", "--structure", "pi", "--json"], EXIT_OK, True),
    (["tune", "--plant", "1/(s+1)^2", "--dt", "0.1", "--structure", "pd", "--json"], EXIT_SPEC_NOT_MET, True),
    (["analyze", "--plant", "1/(s+1)^2", "--controller", "2 + 1/s", "--json"], EXIT_OK, False),
])
@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_a_command_that_built_nlps_ends_without_freeing_them_and_loses_no_output(argv, code, skipped):
    """``tuner`` (cli.entry) ends a process that built NLPs with os._exit, skipping the interpreter's teardown (an
    object of the script's is never freed); the exit code is main's, the exit handlers still run after the
    command's output, and --json reaches a pipe whole (stdout block-buffered, as without PYTHONUNBUFFERED). A
    command that built none exits as usual."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    p = subprocess.run([sys.executable, "-c", _witnessed(argv)], capture_output=True, text=True, timeout=120,
                       cwd=str(ROOT), env=env)
    assert p.returncode == code, p.stderr[-800:]
    out, _, last = p.stdout.rstrip("\n").rpartition("\n")
    assert last == "handler ran"  # the exit handler's line, after the whole document
    doc = json.loads(out)
    assert isinstance(doc, dict) and "metrics" in doc
    assert ("torn down" not in p.stderr) is skipped, p.stderr[-800:]


def _witnessed(argv: list[str]) -> str:
    """A script running ``tuner argv`` through cli.entry, with an object that says when it is freed and an exit
    handler that prints a line to stdout."""
    return ("import atexit, sys\n"
            "class Witness:\n"
            "    def __del__(self):\n"
            "        print('torn down', file=sys.stderr)\n"
            "witness = Witness()\n"
            "atexit.register(lambda: print('handler ran'))\n"
            "from tuner import cli\n"
            f"sys.argv = ['tuner', *{argv!r}]\n"
            "cli.entry()\n")


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_output_that_cannot_be_written_is_said_with_status_120():
    """The early exit of cli.entry flushes what the command printed; where that fails (a full disk), it says so on
    stderr and exits with 120, as the interpreter's own exit would, never 0 with the output lost."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    with open("/dev/full", "w") as full:
        p = subprocess.run([sys.executable, "-c", _witnessed(["tune", "--plant", "1/(s+1)^2", "--dt", "0.1",
                                                               "--structure", "pi", "--json"])],
                           stdout=full, stderr=subprocess.PIPE, text=True, timeout=120, cwd=str(ROOT), env=env)
    assert p.returncode == 120, p.stderr[-800:]
    assert "tuner: error: output not written" in p.stderr and "No space left" in p.stderr
