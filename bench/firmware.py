"""Issue 28's figures: identification under feedback, the firmware laws flown, and the log-to-parameter-file wall time.

    python bench/firmware.py            # all of it (about a minute on 2 cores)

1. A hover in turbulence and a rate-setpoint sweep (turbulence and gyro noise on top), flown with PX4's rate law
   in the loop (tests/closed_loop.py: the law and the plant written there, scipy for the plant). The hover is
   identified at 2p/0z and 3p/2z (its verdict); the sweep with --reference: the model held at dt against the true
   plant as logged over the band, and the direct estimate's error beside it.
2. px4_rate and ardupilot_rate tuned on the true plant, then flown with the laws written in
   tests/tuner/test_firmware_flight.py (independent of tuner): PM, settling and overshoot claimed vs simulated; the
   saturated step (8 rad/s, |u| <= 0.4) claimed vs simulated.
3. identify -> tune -> export on a 100 s, 400 Hz ULog (the CLI in-process, wall time of each step).

Nothing here is asserted (tests/identify/test_closed_loop.py and tests/tuner/test_firmware_flight.py do).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "tuner"), str(ROOT)]

SIGNALS = ["--input", "vehicle_torque_setpoint.xyz[0]", "--output", "vehicle_angular_velocity.xyz[0]"]


def _cli_json(args: list[str]) -> dict:
    import contextlib
    import io

    from tuner.cli import main

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
        code = main(args)
    if code not in (0, 1):
        raise SystemExit(f"tuner {' '.join(args)}: exit {code}")
    return json.loads(buf.getvalue())


def identification(tmp: Path) -> None:
    from closed_loop import DT, fly, true_zoh_response, write

    from tuner.identify.result import IdentifyResult

    hover = write(fly("hover", seconds=60, seed=1), tmp / "hover.ulg")
    sweep = write(fly("sweep", seconds=60, seed=2, sweep_amplitude=3.0, turbulence=0.03), tmp / "sweep.ulg")
    print("1. identification of logs flown with PX4's rate law in the loop (400 Hz, 60 s)")
    for p, z in ((2, 0), (3, 2)):
        d = _cli_json(["identify", str(hover), *SIGNALS, "--poles", str(p), "--zeros", str(z), "--json"])
        print(f"   hover {p}p/{z}z: quality {d['quality']!r}, J = {d['cost']:.3g}, closed loop detected "
              f"{d['closed_loop']['detected']} ({len(d['closed_loop']['signs'])} signs; -1/C median difference "
              f"{100 * d['closed_loop']['inverse_match']['median_relative_difference']:.1f} %)")
    for p, z in ((2, 0), (3, 2)):
        d = _cli_json(["identify", str(sweep), *SIGNALS, "--reference", "vehicle_rates_setpoint.roll", "--poles",
                       str(p), "--zeros", str(z), "--json"])
        lo, hi = d["band_rad_s"]
        w = np.geomspace(lo, hi, 300)
        e = IdentifyResult.from_dict(d).plant().zoh(DT).freqresp(w) / true_zoh_response(w)
        dd = _cli_json(["identify", str(sweep), *SIGNALS, "--poles", str(p), "--zeros", str(z), "--band", str(lo),
                        str(hi), "--json"])
        ed = IdentifyResult.from_dict(dd).plant().zoh(DT).freqresp(w) / true_zoh_response(w)
        print(f"   sweep {p}p/{z}z with --reference: band {lo:.3g}-{hi:.3g} rad/s, quality {d['quality']!r}, "
              f"J = {d['cost']:.3g}; model held at dt vs the true plant: max "
              f"{np.max(np.abs(20 * np.log10(np.abs(e)))):.2f} dB, {np.max(np.abs(np.degrees(np.angle(e)))):.1f} deg"
              f" | direct estimate's model: max {np.max(np.abs(20 * np.log10(np.abs(ed)))):.1f} dB, "
              f"{np.max(np.abs(np.degrees(np.angle(ed)))):.0f} deg (quality {dd['quality']!r})")


def flown() -> None:
    import control as ct
    from test_firmware_flight import DEN, DT, NUM, fly, phase_margin, settling_time

    from tuner import tune
    from tuner.analysis.saturation import Actuator

    print("2. the tuned laws flown with the firmware laws written in the test (true plant, between samples)")
    for name in ("px4_rate", "ardupilot_rate"):
        act = Actuator.of(u_max=0.4, step_size=8.0)
        res = tune(ct.tf(NUM, DEN), structure=name, dt=DT, delay=DT, time_budget_s=10, actuator=act)
        g = res.gains
        pm = phase_margin(name, g)
        t, y, _ = fly(name, g, t_end=max(1.0, 4 * res.metrics.settling_time_s))
        ts = settling_time(t, y, 1.0)
        s = res.analyses[0].saturated
        t2, y2, _ = fly(name, g, amplitude=8.0, u_min=-0.4, u_max=0.4, t_end=float(s.response.t[-1]))
        ts2 = settling_time(t2, y2, 8.0)
        print(f"   {name}: P {g['P']:.4g} I {g['I']:.3g} D {g['D']:.3g} FF {g['FF']:.3g}; PM claimed "
              f"{res.metrics.phase_margin_deg:.2f} vs flown {pm:.2f} deg; settling {res.metrics.settling_time_s:.4f} "
              f"vs {ts:.4f} s; overshoot {res.metrics.overshoot_pct:.2f} vs {100 * (y.max() - 1):.2f} %")
        print(f"      8 rad/s with |u| <= 0.4 ({100 * s.saturated_fraction:.0f} % of the step saturated): settling "
              f"{s.metrics.settling_time_s:.4f} vs {ts2:.4f} s ({100 * (s.metrics.settling_time_s / ts2 - 1):+.1f} %); "
              f"overshoot {s.metrics.overshoot_pct:.2f} vs {100 * (y2.max() - 8) / 8:.2f} %")


def wall(tmp: Path) -> None:
    from closed_loop import fly, write

    from tuner.cli import main

    print("3. identify -> tune -> export on a 100 s, 400 Hz ULog (in-process CLI, wall time)")
    log = write(fly("sweep", seconds=100, seed=5, sweep_amplitude=3.0, turbulence=0.03), tmp / "long.ulg")
    t0 = time.perf_counter()
    d = _cli_json(["identify", str(log), *SIGNALS, "--reference", "vehicle_rates_setpoint.roll", "--poles", "3",
                   "--zeros", "2", "--json"])
    (tmp / "id.json").write_text(json.dumps(d))
    t1 = time.perf_counter()
    r = _cli_json(["tune", "--identified", str(tmp / "id.json"), "--structure", "px4_rate", "--params", str(log),
                   "--json"])
    (tmp / "r.json").write_text(json.dumps(r))
    t2 = time.perf_counter()
    code = main(["export", "--result", str(tmp / "r.json"), "--format", "px4", "--out", str(tmp / "roll.params")])
    t3 = time.perf_counter()
    print(f"   log {log.stat().st_size / 1e6:.1f} MB; identify {t1 - t0:.2f} s (quality {d['quality']!r}), tune "
          f"{t2 - t1:.2f} s (meets spec {r['meets_spec']}), export {t3 - t2:.3f} s (exit {code}); total "
          f"{t3 - t0:.2f} s")


if __name__ == "__main__":
    with tempfile.TemporaryDirectory() as d:
        identification(Path(d))
        flown()
        wall(Path(d))
