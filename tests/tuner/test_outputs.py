"""Outputs and the opened-file check (issue 42, items 5 and the file check): a plot or an export is written only to a
regular file, all of it, or the command says why with exit 2; a FIFO never hangs it (before: a plot or an export to
a FIFO waited for a reader forever, and `identify --plot /dev/full` printed "wrote" with exit 0). An input is checked
on the handle that is read (fstat), not only on its path: a FIFO put in a checked path's place is refused, not
waited on. The FIFO cases run in a subprocess with a timeout (a hang fails the test instead of holding it)."""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tuner.cli import main
from tuner.errors import TunerError
from tuner.fileio import write_output

ROOT = Path(__file__).resolve().parents[2]
PITCH = str(ROOT / "studies" / "data" / "pitch_sweep.csv")
WRITERS = {
    "analyze --plot": (["analyze", "--plant", "1/(s+1)", "--controller", "2", "--plot"], "--plot"),
    "identify --plot": (["identify", PITCH, "--time", "t", "--input", "pitch_cmd", "--output", "pitch", "--poles", "2",
                         "--holdout", "0", "--plot"], "--plot"),
    "export --out": (["export", "--controller", "2*(z-0.5)/(z-1)", "--dt", "0.01", "--format", "c", "--out"], "--out"),
}


def _tuner(args: list[str], timeout_s: float = 120.0, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tuner.cli", *args], capture_output=True, text=True,
                          timeout=timeout_s, cwd=ROOT, **kw)


@pytest.mark.parametrize("target", ["/dev/full", "/dev/null", "dir"])
@pytest.mark.parametrize("cmd", list(WRITERS))
def test_a_device_or_a_directory_is_refused_with_exit_2(cmd, target, tmp_path, capsys):
    """A device through a link with the right suffix (out.png -> /dev/full), or a directory named out.png."""
    args, opt = WRITERS[cmd]
    out = tmp_path / "out.png"
    if target == "dir":
        out.mkdir()
    else:
        out.symlink_to(target)
    assert main([*args, str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"tuner: error: {opt} {out}: ") and "wrote" not in err, err
    assert ("not a regular file (a character device)" in err) if target != "dir" else ("a directory" in err), err


@pytest.mark.parametrize("cmd", list(WRITERS))
def test_a_fifo_is_refused_never_waited_on(cmd, tmp_path):
    args, opt = WRITERS[cmd]
    fifo = tmp_path / "out.png"
    os.mkfifo(fifo)
    p = _tuner([*args, str(fifo)], timeout_s=120)  # before: blocked in open() until a reader came
    assert p.returncode == 2, p.stderr
    assert f"{opt} {fifo}: not a regular file (a FIFO or pipe)" in p.stderr, p.stderr


def _small_files(limit: int):
    def pre() -> None:  # a file may grow to `limit` bytes: a write past it fails with EFBIG, as on a full disk
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return pre


@pytest.mark.parametrize("cmd", ["analyze --plot", "export --out"])
@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_a_write_that_fails_midway_is_exit_2_and_leaves_no_partial_file(cmd, tmp_path):
    args, opt = WRITERS[cmd]
    out = tmp_path / "out.png"
    p = _tuner([*args, str(out)], preexec_fn=_small_files(512))
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert f"{opt} {out}: cannot write: File too large" in p.stderr and "wrote" not in p.stdout, p.stderr
    assert not out.exists()  # before: a truncated file was left behind


def test_write_output_writes_every_byte_to_a_regular_file(tmp_path):
    p = tmp_path / "x.bin"
    data = os.urandom(3 << 20)
    write_output(p, data)
    assert p.read_bytes() == data
    write_output(p, "é\n")  # replaced, text as UTF-8
    assert p.read_bytes() == "é\n".encode()
    (tmp_path / "sock").mkdir()
    with pytest.raises(TunerError, match="a directory"):
        write_output(tmp_path / "sock", b"x", label="--out d")


def test_the_input_check_is_made_on_the_opened_handle(tmp_path):
    """The path check passes (a regular file when it looked), then a FIFO is in its place when it is opened: the open
    does not block and the handle's fstat refuses it. Simulated by skipping the path check."""
    fifo = tmp_path / "log.csv"
    os.mkfifo(fifo)
    code = ("import tuner.fileio as f\n"
            "f.check_input = lambda *a, **k: 0\n"  # the path looked like a regular file
            "try:\n"
            f"    f.open_checked({str(fifo)!r}, limit=1 << 20)\n"
            "except f.TunerError as e:\n"
            "    print(e)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert p.returncode == 0 and "not a regular file (a FIFO or pipe)" in p.stdout, (p.stdout, p.stderr)


@pytest.mark.parametrize("cmd", list(WRITERS))
def test_a_target_that_cannot_take_it_is_refused_before_the_work(cmd, tmp_path, monkeypatch, capsys):
    """The identification, the analysis, the export are not run for an output that would be refused."""
    import importlib

    args, opt = WRITERS[cmd]
    ran = []
    for mod, name in (("tuner.identify.cli", "_run"), ("tuner.analysis.verify", "analyze"),
                      ("tuner.export.cli", "_source")):
        m = importlib.import_module(mod)
        if hasattr(m, name):
            monkeypatch.setattr(m, name, lambda *a, **k: ran.append(1))
    (tmp_path / "out.png").symlink_to("/dev/full")
    assert main([*args, str(tmp_path / "out.png")]) == 2
    assert "not a regular file (a character device)" in capsys.readouterr().err and not ran
