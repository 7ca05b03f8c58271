"""The identification cases of issue 13, measured: data -> model -> controller, judged on the truth.

    .venv/bin/python bench/identify_cases.py            (about two minutes)
    .venv/bin/python bench/identify_cases.py --quick    (no tuning, no Monte Carlo)

For each synthetic flight (tests/flight.py: a 90 s piloted sweep 0.3-25 rad/s with doublets in the
last 18 s, through the thesis's roll, pitch and yaw models and a third-order plant, 40 ms transport
delay, gusts, sensor noise, bias drift, simulated at 1 kHz and logged at 50 Hz; the seeds of
tests/identify/test_flight.py), it prints: the band, J, the largest magnitude and phase error of the
identified model against the true one over the band, each parameter's error with its Cramér–Rao
bound and insensitivity, the held-out check (Theil, NRMSE), and the verifier's figures of a pid_z
controller (dt = 0.04 s) tuned on the identified model, judged on the TRUE plant. Then a Monte Carlo
over 12 flights per axis: the scatter of the identified parameters against their mean Cramér–Rao
bound. Timing: identify's wall time as a ratio to one scipy.signal.csd call on the same record,
measured in the same run (nothing here asserts a time).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.append(str(ROOT / "tests"))  # after the repository: tests/tuner must not shadow the package

from flight import AXES, THIRD_ORDER, fly, true_response  # noqa: E402

from tuner import identify  # noqa: E402
from tuner.analysis import analyze  # noqa: E402
from tuner.plant import make_plant  # noqa: E402

DT = 0.04
CASES = [("roll", AXES["roll"], 2, 1), ("pitch", AXES["pitch"], 2, 2), ("yaw", AXES["yaw"], 1, 3),
         ("third order, 2 poles", THIRD_ORDER, 2, 4), ("third order, 3 poles", THIRD_ORDER, 3, 4)]


def true_parameters(num: list[float], den: list[float]) -> dict[str, float]:
    """The true parameters in the fit's terms, from the true coefficients (roots, not tuner)."""
    out = {"gain": num[-1] / den[-1]}
    roots = np.roots(den)
    pairs = sorted([r for r in roots if r.imag > 1e-9], key=abs)
    reals = sorted([-r.real for r in roots if abs(r.imag) <= 1e-9])
    for i, r in enumerate(pairs, 1):
        out[f"pole_wn_{i}_rad_s"] = abs(r)
        out[f"pole_zeta_{i}"] = -r.real / abs(r)
    for r in reals:
        out[f"pole_{len(pairs) + 1}_rad_s"] = r
    out["delay_s"] = 0.04
    return out


def errors(log, res) -> tuple[float, float]:
    w = np.geomspace(*res.band_rad_s, 400)
    ratio = res.model.freqresp(w) / true_response(log, w)
    return float(np.max(np.abs(20 * np.log10(np.abs(ratio))))), float(np.max(np.abs(np.degrees(np.angle(ratio)))))


def case_rows(quick: bool) -> list[str]:
    from scipy.signal import csd

    L = [("| case | band [rad/s] | J | quality | max |dB| err | max phase err [°] | parameter: identified (true), "
         "error %, CR %, insensitivity % | held out: Theil, NRMSE | tuned pid_z on the identified model, judged on "
         "the TRUE plant | identify time / one csd |"), "|" + "---|" * 10]
    logs = {}
    for name, (num, den), poles, seed in CASES:
        log = logs.setdefault(seed, fly(num, den, delay_s=0.04, seed=seed))
        t0 = time.perf_counter()
        res = identify(log.u, log.y, time=log.t, poles=poles, delay_step=DT)
        t_id = time.perf_counter() - t0
        t0 = time.perf_counter()
        csd(log.u, log.y, fs=1 / log.dt, nperseg=log.u.size // 2)
        t_csd = time.perf_counter() - t0
        mag, ph = errors(log, res)
        truth = true_parameters(num, den)
        params = []
        for k, u in res.uncertainty.items():
            tv = truth.get(k)
            err = f"{100 * (u.value - tv) / tv:+.2f}" if tv else "—"
            params.append(f"{k} {u.value:.4g} ({tv:.4g}), {err}, {u.cr_bound_pct:.2g}, {u.insensitivity_pct:.2g}"
                          if tv else f"{k} {u.value:.4g}, CR {u.cr_bound_pct:.2g}")
        v = res.validation
        tuned = "—"
        if not quick:
            from tuner.tuning import tune

            tr = tune(res.plant(), structure="pid_z", dt=DT, seed=0, time_budget_s=10)
            a = analyze(make_plant(num, den, delay=log.delay_s), tr.controller, tr.spec)
            m, mi = a.metrics, tr.analyses[0].metrics
            tuned = (f"{', '.join(f'{g} = {x:.4g}' for g, x in tr.gains.items())}: identified model PM "
                     f"{mi.phase_margin_deg:.1f}°, OS {mi.overshoot_pct:.2f} %, ts {mi.settling_time_s:.3f} s; TRUE "
                     f"plant PM {m.phase_margin_deg:.1f}°, GM {m.gain_margin_db:.1f} dB, OS {m.overshoot_pct:.2f} %, "
                     f"ts {m.settling_time_s:.3f} s: **{'meets' if a.meets_spec else 'FAILS'} the spec**"
                     + ("" if a.meets_spec else f" ({', '.join(c.name for c in a.failing)})"))
        L.append(f"| {name} | {res.band_rad_s[0]:.3g}–{res.band_rad_s[1]:.3g} | {res.cost:.3g} | {res.quality} | "
                 f"{mag:.2f} | {ph:.2f} | {'; '.join(params)} | {v.theil_u:.3f}, {v.nrmse:.3f} | {tuned} | "
                 f"{t_id / t_csd:.0f} ({t_id:.2f} s) |")
        for w in res.warnings:
            L.append(f"| | | | | | | warning: {w} | | | |")
    return L


def monte_carlo_rows(n: int = 12) -> list[str]:
    L = ["", (f"Monte Carlo over {n} flights per axis (seeds 100-{99 + n}, free delay): scatter (sample standard "
         "deviation) of each identified parameter, its rms error, and the mean Cramér–Rao bound, % of the true "
         "value; the ratio scatter / bound (1 = calibrated bounds)."), "",
         "| axis | parameter | rms error % | scatter % | mean CR bound % | scatter / CR |", "|---|---|---|---|---|---|"]
    for name, poles in (("roll", 2), ("pitch", 2), ("yaw", 1)):
        num, den = AXES[name]
        truth = true_parameters(num, den)
        vals, crs = [], []
        for seed in range(100, 100 + n):
            log = fly(num, den, delay_s=0.04, seed=seed)
            res = identify(log.u, log.y, time=log.t, poles=poles)
            vals.append([res.uncertainty[k].value for k in truth])
            crs.append([res.uncertainty[k].cr_bound for k in truth])
        vals, crs = np.array(vals), np.array(crs)
        tv = np.array(list(truth.values()))
        rmse = np.sqrt(np.mean((vals - tv) ** 2, axis=0))
        sd = vals.std(axis=0, ddof=1)
        for i, k in enumerate(truth):
            L.append(f"| {name} | {k} | {100 * rmse[i] / tv[i]:.2f} | {100 * sd[i] / tv[i]:.2f} | "
                     f"{100 * crs[:, i].mean() / tv[i]:.2f} | {sd[i] / crs[:, i].mean():.2f} |")
    return L


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="no tuning and no Monte Carlo")
    ap.add_argument("--out", default=None, help="also write the tables to this Markdown file")
    a = ap.parse_args()
    lines = case_rows(a.quick)
    if not a.quick:
        lines += monte_carlo_rows()
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        head = ("# Identification cases (issue 13)\n\nWritten by `.venv/bin/python bench/identify_cases.py --out "
                f"{a.out}`; see the script's docstring for what each column is. Errors are identified minus true.\n\n")
        Path(a.out).write_text(head + text)


if __name__ == "__main__":
    main()
