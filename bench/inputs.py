"""Issue 31's figures: what reading a file costs the CLI, and how fast it refuses what it cannot read.

    python bench/inputs.py            # a few minutes (writes CSVs of up to 10^7 rows in a temporary folder)

1. ``tuner identify`` on CSVs of 10^5, 10^6 and 10^7 rows (time, input, output at 400 Hz): wall time and peak
   memory (the child's maximum resident set, ``resource.getrusage``), beside the file's size.
2. The time each command that reads a file takes to refuse ``/dev/zero``, a 2 GB sparse file and a FIFO with no
   writer (a fresh process each: Python's start-up is part of it).

Nothing here is asserted (tests/tuner/test_cli_inputs.py checks the exit codes).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
STUDY = str(ROOT / "studies" / "quadrotor.toml")


_PEAK = ("import resource, subprocess, sys; r = subprocess.run(sys.argv[1:], stdin=subprocess.DEVNULL, "
         "capture_output=True); print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); sys.exit(r.returncode)")


def _run(args: list[str]) -> tuple[int, float, float]:
    """(exit code, wall s, peak RSS MB) of ``tuner args`` in a fresh process (measured by a parent of its own, so
    that each figure is that command's alone)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", _PEAK, sys.executable, "-m", "tuner.cli", *args], capture_output=True,
                       text=True, env=env, stdin=subprocess.DEVNULL, timeout=900)
    wall = time.perf_counter() - t0
    return p.returncode, wall, float(p.stdout.strip().splitlines()[-1]) / 1024.0


def _csv(path: Path, n: int) -> Path:
    rng = np.random.default_rng(0)
    u = rng.standard_normal(n)
    y = np.convolve(u, [0.2, 0.3, 0.2, 0.1])[:n] + 0.01 * rng.standard_normal(n)
    with open(path, "w") as f:
        f.write("t,u,y\n")
        for k in range(0, n, 100_000):
            b = slice(k, min(n, k + 100_000))
            np.savetxt(f, np.c_[np.arange(b.start, b.stop) * 0.0025, u[b], y[b]], delimiter=",", fmt="%.6f")
    return path


def memory(tmp: Path) -> None:
    print("1. tuner identify on CSV logs (3 columns, 400 Hz), one fresh process each")
    small = _csv(tmp / "log_small.csv", 5000)  # the libraries identify loads, and its fixed costs: the baseline
    _, _, base = _run(["identify", str(small), "--time", "t", "--input", "u", "--output", "y", "--poles", "2"])
    for n in (10**5, 10**6, 10**7):
        p = _csv(tmp / f"log{n}.csv", n)
        size = p.stat().st_size / 1e6
        code, wall, peak = _run(["identify", str(p), "--time", "t", "--input", "u", "--output", "y", "--poles", "2"])
        print(f"   {n:>9} rows, {size:7.1f} MB: exit {code}, {wall:6.2f} s, peak {peak:7.1f} MB "
              f"({peak / size:.1f} x the file; above the {base:.0f} MB of a 5000-row log's: "
              f"{(peak - base) / size:.1f} x)")
        p.unlink()
    print(f"   (identify on a 5000-row log, the libraries and fixed costs: {base:.1f} MB)")


def refusals(tmp: Path) -> None:
    fifo = tmp / "fifo"
    os.mkfifo(fifo)
    sparse = tmp / "sparse.json"
    with open(sparse, "wb") as f:
        f.truncate(2 << 30)
    cmds = {
        "identify FILE": lambda x: ["identify", x, "--input", "a", "--output", "b", "--poles", "2", "--rate", "10"],
        "tune --identified": lambda x: ["tune", "--identified", x, "--structure", "pi"],
        "tune --params": lambda x: ["tune", "--plant", "1/s", "--structure", "px4_rate", "--params", x],
        "analyze --identified": lambda x: ["analyze", "--identified", x, "--controller", "1"],
        "export --result": lambda x: ["export", "--result", x, "--format", "c"],
        "verify --gains": lambda x: ["verify", STUDY, "--gains", x],
        "study run FILE": lambda x: ["study", "run", x],
    }
    print("2. time to refuse (exit code, wall s, a fresh process each)")
    for name, make in cmds.items():
        row = []
        for label, path in (("/dev/zero", "/dev/zero"), ("2 GB sparse", str(sparse)), ("FIFO", str(fifo))):
            code, wall, _ = _run(make(path))
            row.append(f"{label} exit {code} {wall:.2f} s")
        print(f"   {name:<22} " + "; ".join(row))


if __name__ == "__main__":
    with tempfile.TemporaryDirectory() as d:
        memory(Path(d))
        refusals(Path(d))
