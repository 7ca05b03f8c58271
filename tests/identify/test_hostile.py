"""Hostile and odd input to identification and export (issue 21): each answered with exit 2 and a message that
names the input, never exit 3 or a traceback; and the data-scale checks (overflow, tiny amplitude)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from flight import AXES, fly

from tuner.cli import main
from tuner.errors import InvalidDataError
from tuner.fileio import MAX_CSV_BYTES
from tuner.identify import identify


@pytest.fixture(scope="module")
def log():
    return fly(*AXES["pitch"], seed=8, duration_s=60.0)


@pytest.fixture
def csv_file(tmp_path, log):
    path = tmp_path / "pitch.csv"
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(("t", "cmd", "angle"))
        w.writerows((f"{t:.6g}", f"{u:.6g}", f"{y:.6g}") for t, u, y in zip(log.t, log.u, log.y))
    return str(path)


ARGS = ["--time", "t", "--input", "cmd", "--output", "angle", "--poles", "2"]


def _err(capsys) -> str:
    err = capsys.readouterr().err
    assert err.startswith("tuner: error: ") and "Traceback" not in err and "internal error" not in err, err
    return err


def test_a_fixed_delay_longer_than_the_record_is_exit_2_naming_delay(csv_file, capsys):
    assert main(["identify", csv_file, *ARGS, "--delay", "31"]) == 2
    assert "--delay" in _err(capsys)


def test_a_csv_cell_over_the_field_limit_is_exit_2(tmp_path, capsys):
    p = tmp_path / "long.csv"
    p.write_text("t,cmd,angle\n0,1," + "9" * 131_073 + "\n")
    assert main(["identify", str(p), *ARGS]) == 2
    assert "not a readable CSV log" in _err(capsys)


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
def test_devices_are_refused_at_once(device, capsys):
    assert main(["identify", device, *ARGS]) == 2
    assert device in _err(capsys)
    assert main(["export", "--result", device, "--format", "c"]) == 2
    assert f"--result {device}" in _err(capsys)


def test_a_text_file_beyond_the_limit_is_refused_without_reading_it_whole(tmp_path, capsys):
    """A sparse file of MAX_CSV_BYTES + 1 (no disk used): refused against the documented limit."""
    p = tmp_path / "huge.csv"
    with open(p, "wb") as f:
        f.write(b"t,cmd,angle\n")
        f.truncate(MAX_CSV_BYTES + 1)  # the rest reads as NUL bytes: refused at the first chunk anyway
    assert main(["identify", str(p), *ARGS]) == 2
    _err(capsys)
    from tuner.errors import TunerError
    from tuner.fileio import read_text

    q = tmp_path / "big.txt"
    q.write_text("x" * 5000)
    with pytest.raises(TunerError, match="larger than") as e:
        read_text(q, limit=4096, field="file")
    assert e.value.field == ("file",)


def test_deeply_nested_json_to_export_is_exit_2(tmp_path, capsys):
    p = tmp_path / "deep.json"
    p.write_text("[" * 100_000)
    assert main(["export", "--result", str(p), "--format", "c"]) == 2
    assert "nested too deeply" in _err(capsys)


def test_export_result_errors_name_the_file_not_options_never_given(tmp_path, capsys):
    result = {"structure": "nonesuch", "gains": {"Kp": 1.0},
              "controller": {"num": [1.0], "den": [1.0], "dt": None}}
    p = tmp_path / "r.json"
    p.write_text(json.dumps(result))
    assert main(["export", "--result", str(p), "--format", "c", "--dt", "0.01", "--method", "structure"]) == 2
    err = _err(capsys)
    assert f"--result {p}: its structure" in err and "--structure" not in err and "--controller" not in err
    p.write_text(json.dumps({**result, "structure": "pid"}))
    assert main(["export", "--result", str(p), "--format", "c", "--dt", "0.01", "--method", "structure"]) == 2
    err = _err(capsys)
    assert f"--result {p}: its gains" in err and "--controller" not in err


@pytest.mark.parametrize("name", ["_x", "_", "_Foo", "__y"])
def test_reserved_c_names_are_refused(name, capsys):
    assert main(["export", "--controller", "1 + 1/s", "--dt", "0.01", "--format", "c", "--name", name]) == 2
    assert "--name" in _err(capsys)


def test_values_near_1e300_get_a_message_about_overflow(log):
    with pytest.raises(InvalidDataError, match="overflow") as e:
        identify(log.u * 1e300, log.y, time=log.t, poles=2)
    assert e.value.field == ("input",)
    with pytest.raises(InvalidDataError, match="overflow") as e:
        identify(log.u, log.y * 1e300, time=log.t, poles=2)
    assert e.value.field == ("output",)


def test_values_below_1e_60_get_a_message_about_underflow(log):
    with pytest.raises(InvalidDataError, match="underflow") as e:
        identify(log.u * 1e-100, log.y * 1e-100, time=log.t, poles=2)
    assert e.value.field == ("input",)


def test_a_tiny_well_excited_signal_is_identified_as_the_same_model(log):
    """Scale invariance: the input and output in other units (x 1e-13) give the same model and cost."""
    ref = identify(log.u, log.y, time=log.t, poles=2, delay_step=0.04)
    tiny = identify(log.u * 1e-13, log.y * 1e-13, time=log.t, poles=2, delay_step=0.04)
    assert tiny.quality == ref.quality == "good"
    np.testing.assert_allclose(tiny.model.theta, ref.model.theta, rtol=1e-6)
    assert tiny.cost == pytest.approx(ref.cost, rel=1e-6)


def test_the_same_column_as_input_and_output_is_refused(csv_file, log, capsys):
    with pytest.raises(InvalidDataError, match="same signal") as e:
        identify(log.u, log.u, time=log.t, poles=1)
    assert e.value.field == ("output",)
    assert main(["identify", csv_file, "--time", "t", "--input", "cmd", "--output", "cmd", "--poles", "1"]) == 2
    assert "--output cmd" in _err(capsys)


def test_every_cli_file_input_goes_through_the_bounded_reader(tmp_path, capsys):
    """The study file and the gains file too: a device is refused at once (exit 2, naming the input)."""
    assert main(["study", "run", "/dev/zero"]) == 2
    assert "/dev/zero" in _err(capsys)
    study = tmp_path / "s.toml"
    study.write_text('name = "t"\n[[loop]]\nname = "a"\nplant = "1/(s+1)"\nstructure = "pi"\n')
    assert main(["verify", str(study), "--gains", "/dev/urandom"]) == 2
    assert "--gains /dev/urandom" in _err(capsys)
    from tuner.analysis import response
    from tuner.optimize import batch

    assert batch.MAX_SAMPLES is response.MAX_SAMPLES  # one source for the verifier's and the search's limit


def test_the_delimiter_is_sniffed_on_a_capped_sample(tmp_path, monkeypatch, capsys):
    """Issue 42: csv.Sniffer takes time quadratic in a line's length (a 64 kB line of '",' held identify 19 s, 200 kB
    92 s); it sees at most SNIFF_CHARS characters (the header and the rows that fit)."""
    import csv as csv_module

    from tuner.identify.csvlog import SNIFF_CHARS, read_columns

    seen: list[int] = []
    real = csv_module.Sniffer.sniff

    def spy(self, sample, delimiters=None):
        seen.append(len(sample))
        return real(self, sample, delimiters)

    monkeypatch.setattr(csv_module.Sniffer, "sniff", spy)
    p = tmp_path / "long.csv"
    p.write_text("t,cmd,angle\n" + '",' * 32_768 + "\n")
    assert main(["identify", str(p), *ARGS]) == 2
    assert "line 2" in _err(capsys)
    assert seen and max(seen) <= SNIFF_CHARS, seen
    # a header wider than the sample (600 columns, ';'): still told from its first SNIFF_CHARS characters
    names = [f"signal_{i:04d}" for i in range(600)]
    wide = tmp_path / "wide.csv"
    rows = ["\n" + ";".join(str(i + k) for i in range(600)) for k in range(3)]
    wide.write_text(";".join(names) + "".join(rows) + "\n")
    got = read_columns(wide, {"input": "signal_0003", "output": "signal_0599"})
    assert got["input"].tolist() == [3.0, 4.0, 5.0] and got["output"].tolist() == [599.0, 600.0, 601.0]
    assert max(seen) <= SNIFF_CHARS


@pytest.mark.parametrize("cell", ["1_5", "١٢"])
def test_a_csv_cell_python_reads_but_no_log_writes_is_not_a_number(tmp_path, cell, capsys):
    """float() reads '1_5' as 15 (issue 42) and other scripts' digits as numbers."""
    p = tmp_path / "u.csv"
    p.write_text("t,cmd,angle\n0,1,2\n0.02," + cell + ",3\n")
    assert main(["identify", str(p), *ARGS]) == 2
    assert f"line 3, column 'cmd': not a number: '{cell}'" in _err(capsys)
