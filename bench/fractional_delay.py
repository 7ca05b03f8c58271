"""Issue 19's targets, measured: fractional-sample delays from a flight log to the loop, judged on the truth.

    .venv/bin/python bench/fractional_delay.py          (about two minutes)

For each held-out synthetic flight (tests/flight.py: a 90 s piloted sweep with doublets, gusts, sensor noise
and a bias drift; delays that are a fraction of dt = 0.04 s): identify (delay as fitted), then

* the old ways of tuning with a whole-sample delay, rounded down and up, and the delay as fitted;
* ``robust = 2``: one controller for the identified 2-sigma plant set, then 200 draws from the covariance;

each controller judged by the verifier on the TRUE plant (whose fractional delay is exact: the ZOH of the
delayed plant, checked against a fine-step simulation in tests/tuner/test_fractional_delay.py). Nothing is
asserted here; the tests (tests/tuner/test_identified_tune.py) assert the targets.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.append(str(ROOT / "tests"))

from flight import fly  # noqa: E402

from tuner import analyze, identify, make_plant, tune  # noqa: E402

DT = 0.04
CASES = [  # name, (gain, wn, zeta, delay), log rate, seed
    ("issue log 1: 0.31/12.2/0.42, 20 ms", (0.31, 12.2, 0.42, 0.020), 50.0, 31),
    ("issue log 2: 2/8/0.5, 33 ms, 100 Hz", (2.0, 8.0, 0.5, 0.033), 100.0, 32),
    ("roll 23 ms", (0.2655, 14.8528, 14.195 / (2 * 14.8528), 0.023), 50.0, 33),
]


def _tf(K, wn, z):
    return [K * wn**2], [1.0, 2 * z * wn, wn**2]


def _line(tag, m, ok=None):
    s = (f"    {tag:<26} PM {m.phase_margin_deg:6.2f} deg  GM {m.gain_margin_db:6.2f} dB  overshoot "
         f"{m.overshoot_pct:6.2f} %  settling {m.settling_time_s:6.3f} s")
    return s + ("" if ok is None else f"  {'meets' if ok else 'FAILS'} the spec")


def main() -> None:
    for name, (K, wn, z, tau), hz, seed in CASES:
        log = fly(*_tf(K, wn, z), delay_s=tau, seed=seed, duration_s=90.0, log_hz=hz)
        ident = identify(log.u, log.y, rate_hz=log.rate_hz, poles=2, zeros=0, delay="auto")
        v = ident.model.values()
        print(f"{name}: identified gain {v['gain']:.4g}, wn {v['pole_wn_1_rad_s']:.4g}, zeta "
              f"{v['pole_zeta_1']:.4g}, delay {v['delay_s'] * 1e3:.2f} ms (true {tau * 1e3:.0f} ms), J "
              f"{ident.cost:.3g}")
        true = make_plant(*_tf(K, wn, z), delay=tau)
        num, den = ident.model.tf()
        for tag, d in (("whole samples, rounded down", math.floor(ident.delay_s / DT) * DT),
                       ("whole samples, rounded up", math.ceil(ident.delay_s / DT) * DT)):
            r = tune(make_plant(num, den, delay=d), structure="pid_z", dt=DT)
            print(_line(f"{tag}: reported", r.analyses[0].metrics))
            a = analyze(true, r.controller)
            print(_line(f"{tag}: TRUE", a.metrics, a.meets_spec))
        r = tune(ident, structure="pid_z", dt=DT)
        print(_line("delay as fitted: reported", r.analyses[0].metrics))
        a = analyze(true, r.controller)
        print(_line("delay as fitted: TRUE", a.metrics, a.meets_spec))
        rr = tune(ident, structure="pid_z", dt=DT, robust=2)
        print(_line(f"robust=2 ({rr.robust.n_plants} plants): nominal", rr.analyses[0].metrics))
        a = analyze(true, rr.controller)
        print(_line("robust=2: TRUE", a.metrics, a.meets_spec))
        print(f"    robust=2: {rr.robust.monte_carlo.summary()}")


if __name__ == "__main__":
    main()
