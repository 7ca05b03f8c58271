"""Every file the CLI reads, given what a hostile or careless user gives: a device, a FIFO with no writer, a 2 GB
sparse file, a directory, a missing file, binary bytes, another encoding, nesting too deep; and every place it
writes, unmakeable. Each is exit 2 with one line naming the argument, never exit 3 (a bug), never a hang (each
case runs with a timeout of its own)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
STUDY = str(ROOT / "studies" / "quadrotor.toml")
CSV = str(ROOT / "studies" / "data" / "pitch_sweep.csv")
IDENT = ["--input", "a", "--output", "b", "--poles", "2", "--rate", "10"]


@pytest.fixture(scope="module")
def bad(tmp_path_factory) -> dict[str, str]:
    d = tmp_path_factory.mktemp("inputs")
    fifo = d / "fifo"
    os.mkfifo(fifo)
    sparse = d / "sparse.json"
    with open(sparse, "wb") as f:
        f.truncate(2 << 30)
    (d / "binary.json").write_bytes(b"\x00\x01\x02\xff" * 64)
    (d / "latin1.csv").write_bytes("t,u,y\n0,1,\xe9\n".encode("latin-1"))
    (d / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    (d / "deep.toml").write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")
    (d / "afile").write_text("x")
    return {"fifo": str(fifo), "sparse": str(sparse), "binary": str(d / "binary.json"),
            "latin1": str(d / "latin1.csv"), "deep_json": str(d / "deep.json"), "deep_toml": str(d / "deep.toml"),
            "dir": str(d), "missing": str(d / "missing.json"), "zero": "/dev/zero", "afile": str(d / "afile")}


def _ref(k: str) -> str:
    """The placeholder of file ``k`` (filled in from the ``bad`` fixture)."""
    return "{" + k + "}"


READS = ["zero", "fifo", "sparse", "dir", "missing", "binary", "deep_json"]
CASES = (
    [(["tune", "--identified", _ref(k), "--structure", "pi"], "--identified") for k in READS]
    + [(["analyze", "--identified", _ref(k), "--controller", "1"], "--identified") for k in READS]
    + [(["tune", "--plant", "1/s", "--structure", "px4_rate", "--params", _ref(k)], "--params") for k in READS]
    + [(["export", "--result", _ref(k), "--format", "c"], "--result") for k in READS]
    + [(["export", "--result", _ref(k), "--format", "px4"], "--result") for k in READS]
    + [(["verify", STUDY, "--gains", _ref(k)], "--gains") for k in READS]
    + [(["identify", _ref(k), *IDENT], "") for k in ("zero", "fifo", "sparse", "dir", "missing", "binary",
                                                        "latin1")]
    + [(["identify", CSV, "--time", "t", "--input", "pitch_cmd", "--output", "pitch", "--poles", "2", "--verify",
         _ref(k)], "") for k in ("zero", "fifo", "dir", "missing")]
    + [(["study", "run", _ref(k)], "") for k in ("zero", "fifo", "sparse", "dir", "missing", "binary",
                                                   "deep_toml")]
    + [(["verify", _ref(k), "--gains", "{missing}"], "") for k in ("zero", "fifo", "dir", "deep_toml")]
    + [(["study", "run", STUDY, "--out", out], "--out") for out in ("/dev/null/x", "{afile}", "/proc/tuner-x")]
    + [(["export", "--controller", "1/s", "--dt", "0.1", "--format", "c", "--out", out], "--out")
       for out in ("/dev/null/x", "/proc/tuner-x/c.c", "{dir}")]
    + [(["tune", "--plant", "1/(s+1)", "--structure", "pi", "--budget", "1", "--plot", out], "--plot")
       for out in ("/dev/null/x.png", "/proc/tuner-x.png")]
)


@pytest.mark.parametrize("args, arg", CASES, ids=[" ".join(a[:3]) + f" [{i}]" for i, (a, _) in enumerate(CASES)])
@pytest.mark.slow  # 73 processes: about a minute on 2 cores
def test_user_input_is_exit_2_never_3(bad, args, arg):
    argv = [a.format(**bad) for a in args]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.run([sys.executable, "-m", "tuner.cli", *argv], capture_output=True, text=True, timeout=60,
                       stdin=subprocess.DEVNULL, env=env, cwd=str(ROOT))
    assert p.returncode == 2, (argv, p.returncode, p.stderr[-500:])
    err = p.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tuner: error: "), p.stderr
    assert "Traceback" not in p.stderr and (not arg or arg in err[0]), err[0]


def test_the_count():
    """The number of cases above, for the closing note (one per command, input and kind of file)."""
    assert len(CASES) >= 60
