"""Write the synthetic flight logs of ``studies/identified.toml`` (run from the repository root).

    .venv/bin/python studies/data/make_flight_logs.py

One log per attitude axis, as a flight-test engineer would record it: 60 s at 50 Hz of a
pilot-like frequency sweep (0.3 -> 25 rad/s, amplitude modulated, doublets in the last 12 s)
through the thesis's identified model of that axis (shared/reference/quadrotor.md) with a
40 ms transport delay, gusts at the plant input, sensor noise and a bias drift. The simulation
is ``tests/flight.py`` (1 kHz, exact for an input linear between steps, logged by sampling);
the seeds are fixed, so the files are reproducible. Values are written with 6 significant digits.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1] / "tests"))

from flight import AXES, fly  # noqa: E402

SEEDS = {"roll": 11, "pitch": 12, "yaw": 13}
DELAY_S = 0.04
DURATION_S = 60.0
LOG_HZ = 50.0


def write_log(path: Path, axis: str, log, delay_s: float, seed: int) -> None:
    """One axis's log as CSV (t, AXIS_cmd, AXIS), with a comment line naming the model, delay and seed."""
    with path.open("w", newline="", encoding="utf-8") as f:
        f.write(f"# synthetic {axis} sweep: thesis model {AXES[axis]}, delay {delay_s} s, seed {seed}\n")
        w = csv.writer(f)
        w.writerow(["t", f"{axis}_cmd", axis])
        for row in zip(log.t, log.u, log.y):
            w.writerow([f"{x:.6g}" for x in row])
    print(f"wrote {path} ({path.stat().st_size} bytes)")


def main() -> None:
    for axis, seed in SEEDS.items():
        log = fly(*AXES[axis], delay_s=DELAY_S, seed=seed, duration_s=DURATION_S, log_hz=LOG_HZ)
        write_log(HERE / f"{axis}_sweep.csv", axis, log, DELAY_S, seed)


if __name__ == "__main__":
    main()
