"""``tuner analyze`` end to end: the table, --json, exit codes, and bad input without tracebacks."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from quadrotor import DT, PITCH, PITCH_C, ROLL, ROLL_C, YAW, YAW_C, scaled

from tuner.cli import main

METRIC_KEYS = {
    "stable", "phase_margin_deg", "crossover_rad_s", "gain_margin_db", "gain_margin_lower_db", "disk_margin",
    "ms", "mt", "mks", "bandwidth_rad_s", "overshoot_pct", "settling_time_s", "rise_time_s", "steady_state_error",
    "control_peak", "disturbance_rejection_bandwidth_rad_s", "disturbance_rejection_peak_db", "load_iae", "load_peak",
    "load_recovery_s", "integral_gain",
}
PITCH_X27 = ["analyze", "--plant", PITCH, "--dt", str(DT), "--controller", scaled(PITCH_C, 2.7)]
ROLL_X1 = ["analyze", "--plant", ROLL, "--dt", str(DT), "--controller", ROLL_C]
YAW_X1079 = ["analyze", "--plant", YAW, "--dt", str(DT), "--controller", scaled(YAW_C, 10.7924)]


def _strict_json(text: str):
    """Parse JSON, refusing the bare NaN/Infinity tokens that are not JSON."""

    def refuse(tok):
        raise AssertionError(f"bare {tok} in JSON output")

    return json.loads(text, parse_constant=refuse)


# -- the table --------------------------------------------------------------------------------

def test_table_reports_pitch_x27_failing_with_values(capsys):
    rc = main(PITCH_X27)
    out, err = capsys.readouterr()
    assert rc == 1  # a failed spec is reported, and exit 1 says so (with or without --check)
    assert err == ""
    assert "51.37" in out and "18.87" in out  # PM 51.4 deg, overshoot 18.9 %
    assert out.count("FAIL") == 2
    verdict = [line for line in out.splitlines() if line.startswith("controller")]
    assert verdict == [
        "controller does NOT meet the spec: phase_margin_deg = 51.37 (required >= 60); "
        "overshoot_pct = 18.87 (required <= 10)"
    ]


def test_table_roll_meets_the_spec_and_check_exit_codes(capsys):
    assert main(ROLL_X1 + ["--check"]) == 0
    out, _ = capsys.readouterr()
    assert "controller meets the spec" in out
    assert "75.39" in out and "18.31" in out  # PM 75.4 deg, GM 18.3 dB
    assert "FAIL" not in out
    assert main(PITCH_X27 + ["--check"]) == 1
    capsys.readouterr()


def test_spec_options_change_the_verdict(capsys):
    # relax the PM to 50 deg and the overshoot to 20 %: pitch x2.7 then passes
    assert main(PITCH_X27 + ["--pm", "50", "--overshoot", "20", "--check"]) == 0
    assert "controller meets the spec" in capsys.readouterr().out


# -- --json -------------------------------------------------------------------------------------

def test_json_pitch_x27(capsys):
    assert main(PITCH_X27 + ["--json"]) == 1  # spec not met: exit 1, the JSON still on stdout
    doc = _strict_json(capsys.readouterr().out)
    assert set(doc) == {"metrics", "checks", "meets_spec", "verdict", "basis"}
    assert doc["basis"] == "model" and doc["verdict"].startswith("does NOT meet the spec: phase_margin_deg")
    m = doc["metrics"]
    assert set(m) == METRIC_KEYS
    assert m["stable"] is True
    assert m["phase_margin_deg"] == pytest.approx(51.4, abs=0.5)
    assert m["overshoot_pct"] == pytest.approx(18.9, abs=0.05)
    assert m["gain_margin_lower_db"] == "-Infinity"
    assert doc["meets_spec"] is False
    for c in doc["checks"]:
        assert {"name", "required", "achieved", "ok"} <= set(c)
    checks = {c["name"]: c for c in doc["checks"]}
    assert {n for n, c in checks.items() if not c["ok"]} == {"phase_margin_deg", "overshoot_pct"}
    assert checks["phase_margin_deg"]["required"] == 60.0
    assert checks["phase_margin_deg"]["achieved"] == pytest.approx(m["phase_margin_deg"])
    assert checks["overshoot_pct"]["required"] == 10.0
    assert checks["settling_time_s"]["required"] == "Infinity"


def test_json_unstable_loop_writes_nan_and_infinity(capsys):
    assert main(YAW_X1079 + ["--json", "--check"]) == 1
    doc = _strict_json(capsys.readouterr().out)
    m = doc["metrics"]
    assert m["stable"] is False
    assert m["overshoot_pct"] == "NaN"
    assert m["rise_time_s"] == "NaN"
    assert m["steady_state_error"] == "NaN"
    assert m["settling_time_s"] == "Infinity"
    assert m["gain_margin_db"] == "Infinity"
    assert isinstance(m["gain_margin_lower_db"], float) and m["gain_margin_lower_db"] < 0
    checks = {c["name"]: c for c in doc["checks"]}
    assert checks["stable"]["ok"] is False
    assert doc["meets_spec"] is False


# -- real processes -----------------------------------------------------------------------------
# Each process pays the imports (control, scipy): they are started together, once per module.

CONSOLE_SCRIPT = Path(sys.executable).with_name("tuner")
MODULE = [sys.executable, "-m", "tuner.cli"]
PROCESSES = {
    "table": (MODULE, PITCH_X27 + ["--check"]),
    "json": ([str(CONSOLE_SCRIPT)], PITCH_X27 + ["--json"]),
    "hostile": (MODULE, ["analyze", "--plant", "__import__('os').system('touch /tmp/x')", "--controller", "1"]),
    "long": ([str(CONSOLE_SCRIPT)], ["analyze", "--plant", "1/(s+1)", "--controller",
                                     "(" * 60_000 + "s" + ")" * 60_000]),
}


def _run_together(procs):
    running = {k: subprocess.Popen(exe + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
               for k, (exe, args) in procs.items()}
    done = {}
    try:
        for k, p in running.items():
            out, err = p.communicate(timeout=120)
            done[k] = subprocess.CompletedProcess(p.args, p.returncode, out, err)
    finally:  # none left running past the test (a timeout above fails it)
        for p in running.values():
            if p.poll() is None:
                p.kill()
                p.wait()
    return done


@pytest.mark.slow
def test_real_processes():
    """One test (so that pytest-xdist does not start the processes twice), four processes at once."""
    assert CONSOLE_SCRIPT.exists(), f"console script not installed next to {sys.executable}"
    done = _run_together(PROCESSES)

    # the table, through python -m tuner.cli, with --check
    p = done["table"]
    assert p.returncode == 1, p.stderr  # the spec is not met
    assert "Traceback" not in p.stderr
    assert "does NOT meet the spec" in p.stdout
    assert "phase_margin_deg = 51.37 (required >= 60)" in p.stdout
    assert "overshoot_pct = 18.87 (required <= 10)" in p.stdout
    assert p.stdout.count("FAIL") == 2

    # --json, through the console script
    p = done["json"]
    assert p.returncode == 1, p.stderr  # the spec is not met
    doc = _strict_json(p.stdout)
    assert set(doc["metrics"]) == METRIC_KEYS
    assert doc["metrics"]["phase_margin_deg"] == pytest.approx(51.4, abs=0.5)
    assert doc["metrics"]["overshoot_pct"] == pytest.approx(18.9, abs=0.05)
    assert doc["metrics"]["gain_margin_lower_db"] == "-Infinity"
    assert {c["name"] for c in doc["checks"] if not c["ok"]} == {"phase_margin_deg", "overshoot_pct"}
    assert doc["meets_spec"] is False

    # bad input: exit 2, one line on stderr, nothing on stdout
    for name, words in (("hostile", "unknown name '__import__'"), ("long", "longer than 2000")):
        p = done[name]
        assert p.returncode == 2, (name, p.stderr)
        assert p.stdout == ""
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("tuner: error:"), p.stderr
        assert words in lines[0]


def test_readme_job_in_process(capsys):
    assert main(ROLL_X1 + ["--json", "--check"]) == 0
    m = _strict_json(capsys.readouterr().out)["metrics"]
    assert m["phase_margin_deg"] == pytest.approx(75.4, abs=0.5)
    assert m["gain_margin_db"] == pytest.approx(18.3, abs=0.2)
    assert m["settling_time_s"] == pytest.approx(0.43, abs=0.01)
    assert m["overshoot_pct"] == pytest.approx(0.0, abs=0.05)


# -- bad input in process: exit 2, one line, no traceback ---------------------------------------

R, RC = ROLL, ROLL_C
BAD = [
    # plants
    (["--plant", "1e999/(s+1)", "--controller", "1"], "--plant: number '1e999' is not finite"),
    (["--plant", "1/0", "--controller", "1"], "--plant: division by zero"),
    (["--plant", "1/(s-s)", "--controller", "1"], "--plant: division by zero"),
    (["--plant", "0/(s+1)", "--controller", "1"], "--plant: num is zero"),
    (["--plant", "s^2/(s+1)", "--controller", "1"], "--plant: improper transfer function"),
    (["--plant", "1/(s+1)^21", "--controller", "1"], "--plant: plant order 21 is above the limit 20"),
    (["--plant", R, "--dt", "0", "--controller", RC], "--dt: dt must be finite and > 0"),
    (["--plant", R, "--dt", "-0.04", "--controller", RC], "--dt: dt must be finite and > 0"),
    (["--plant", R, "--dt", "nan", "--controller", RC], "--dt: dt must be finite and > 0"),
    (["--plant", R, "--dt", "inf", "--controller", RC], "--dt: dt must be finite and > 0"),
    (["--plant", "s/(z+1)", "--dt", "0.04", "--controller", RC], "--plant: mixes 's' and 'z'"),
    (["--plant", "1/(z-0.5)", "--controller", "1"], "--plant: plant is in z: give its sample time dt"),
    (["--plant", R, "--dt", "0.04", "--delay", "-0.04", "--controller", RC], "delay must be finite and >= 0"),
    (["--plant", "1/(z-0.5)", "--dt", "0.04", "--delay", "0.05", "--controller", RC],
     "a plant given in z needs a multiple of dt"),
    # controllers
    (["--plant", R, "--dt", "0.04", "--controller", "1/s"], "--controller: controller is in s but a sample time"),
    (["--plant", R, "--controller", RC], "--controller: controller is in z: give its sample time dt"),
    (["--plant", R, "--dt", "0.04", "--controller", "z^2/(z-1)"], "--controller: controller is improper"),
    (["--plant", "1/(z-0.5)", "--dt", "0.1", "--controller", "1/(s+1)"], "controller is in s but a sample time"),
    # hostile expressions
    (["--plant", "os.system('ls')", "--controller", "1"], "--plant: unknown name 'os'"),
    (["--plant", "1/(s+1)", "--controller", "lambda: 0"], "--controller: unknown name 'lambda'"),
    (["--plant", "1/(s+1)", "--controller", "s.__class__"], "unexpected character '.' (at position 1)"),
    (["--plant", "1/(s^99999+1)", "--controller", "1"], "exponent 99999 is above the limit"),
    (["--plant", "1/(10^400*s+1)", "--controller", "1"], "exponent 400 is above the limit"),
    (["--plant", "1/((10^40)^40*s+1)", "--controller", "1"], "overflows"),
    (["--plant", "(" * 10_000 + "1/(s+1)" + ")" * 10_000, "--controller", "1"], "longer than 2000"),
    (["--plant", "(" * 500 + "1/(s+1)" + ")" * 500, "--controller", "1"], "nesting deeper than"),
    (["--plant", "1/(s+1)", "--controller", "1" + "+1" * 500_000], "longer than 2000"),
    (["--plant", "1/(s+\u017f)", "--controller", "1"], "unexpected character"),
    (["--plant", "1/(s+1)", "--controller", "(s+1"], "missing ')' (at position 4)"),
    (["--plant", "1/(s+1)", "--controller", ""], "empty expression"),
    # spec
    (["--plant", "1/(s+1)", "--controller", "1", "--pm", "100"], "--pm: "),
    (["--plant", "1/(s+1)", "--controller", "1", "--band", "0"], "--band: "),
]


@pytest.mark.parametrize("args, words", BAD, ids=[f"{i}:{w[:30]}" for i, (_, w) in enumerate(BAD)])
def test_bad_input_exit_2_with_one_line_message(args, words, capsys):
    rc = main(["analyze", *args])
    out, err = capsys.readouterr()
    assert rc == 2
    assert out == ""
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("tuner: error: ")
    assert words in lines[0]


def test_argparse_errors_exit_2(capsys):
    assert main(["analyze", "--plant", "1/(s+1)"]) == 2  # no --controller (nor --structure with --params)
    assert "--controller" in capsys.readouterr().err
    with pytest.raises(SystemExit) as ei:
        main(["analyze", "--plant", "1/(s+1)", "--controller", "1", "--dt", "fast"])
    assert ei.value.code == 2


def test_nan_in_json_is_never_a_bare_token(capsys):
    # the unstable yaw loop has nan metrics; math.nan must come out as the string "NaN"
    main(YAW_X1079 + ["--json"])
    text = capsys.readouterr().out
    assert "NaN" in text
    assert ": NaN" not in text and ": Infinity" not in text and ": -Infinity" not in text
    assert math.isnan(float(_strict_json(text)["metrics"]["overshoot_pct"]))


# -- --plot --------------------------------------------------------------------------------

@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_plot_writes_the_kind_asked_for(tmp_path, capsys):
    out_svg, out_png = tmp_path / "roll_bode.svg", tmp_path / "roll.png"
    assert main([*ROLL_X1, "--json", "--plot", str(out_svg), "--plot-kind", "bode"]) == 0
    m = _strict_json(capsys.readouterr().out)["metrics"]  # stdout stays JSON
    svg = out_svg.read_text()
    assert f"PM {m['phase_margin_deg']:.1f}°" in svg and "control u" not in svg  # Bode only
    assert main([*ROLL_X1, "--plot", str(out_png)]) == 0
    assert f"wrote {out_png}" in capsys.readouterr().out
    assert out_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("name", ["roll.pdf", "roll"])
def test_plot_with_an_unknown_suffix_is_bad_input(tmp_path, capsys, name):
    assert main([*ROLL_X1, "--plot", str(tmp_path / name)]) == 2
    err = capsys.readouterr().err
    assert "--plot" in err and ".png or .svg" in err and "Traceback" not in err
    assert not (tmp_path / name).exists()
