"""Write the synthetic flight logs of ``studies/fractional.toml`` (run from the repository root).

    .venv/bin/python studies/data/make_fractional_logs.py

The same flights as ``make_flight_logs.py`` (``tests/flight.py``: a pilot-like sweep with doublets through
the thesis's model of each axis, gusts at the plant input, sensor noise and a bias drift; 1 kHz simulation,
logged at 50 Hz), but with transport delays that are NOT a whole number of samples of the loop's dt = 0.04 s:
23 ms (0.575 samples), 17 ms and 31 ms. The delays are on the 1 kHz simulation grid, so they are exact. Seeds
are fixed (the files are reproducible); values are written with 6 significant digits. The truth of each log
is written into the study file as ``true_plant``.
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1] / "tests"))

from flight import AXES, fly  # noqa: E402
from make_flight_logs import write_log  # noqa: E402

DELAYS_S = {"roll": 0.023, "pitch": 0.017, "yaw": 0.031}
SEEDS = {"roll": 21, "pitch": 22, "yaw": 23}
DURATION_S = 60.0
LOG_HZ = 50.0


def main() -> None:
    for axis, seed in SEEDS.items():
        delay = DELAYS_S[axis]
        log = fly(*AXES[axis], delay_s=delay, seed=seed, duration_s=DURATION_S, log_hz=LOG_HZ)
        write_log(HERE / f"{axis}_sweep_frac.csv", axis, log, delay, seed)


if __name__ == "__main__":
    main()
