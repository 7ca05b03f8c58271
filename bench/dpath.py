"""PX4's D path at the raw gyro rate (issue 40): the margins of PX4's default gains on the head-to-head airframes,
as the tuner's law predicts them (the loop-rate D path it had, and the raw-rate one, ``tuner.firmware.laws.
dgyro_filter``) and as the firmware flies them (the airframe, its gyro low-pass, the difference and the D filter on
every raw sample, lifted exactly to the loop rate: ``h2h.sim.lift``), for the current (first-order ``AlphaFilter``
at 20 Hz) and the 2021-era (second-order ``LowPassFilter2p`` at 30 Hz) generation.

Every figure uses the same exact loop-rate plant (the lifted airframe's rate as the law reads it): the rows differ
only in the D path. Run: ``python bench/dpath.py`` (writes ``bench/results/dpath_issue40.md`` with ``--write``).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from h2h.airframes import AIRFRAMES
from h2h.sim import lift

from tuner.controllers import get_structure

GENERATIONS = {"first order (AlphaFilter, 20 Hz)": (1, 20.0), "second order (LowPassFilter2p, 30 Hz)": (2, 30.0)}
DEFAULTS = {"P": 0.15, "I": 0.2, "D": 0.003, "FF": 0.0}  # MC_ROLLRATE_P/I/D/FF (mc_rate_control_params)


def margins(L: np.ndarray, w: np.ndarray) -> tuple[float, float]:
    """Phase margin (deg, the smallest over the gain crossings) and gain margin (dB, the smallest over the phase
    crossings of -180 deg) of the frequency response ``L`` on the grid ``w`` (crossings interpolated linearly)."""
    mag = np.abs(L)
    ph = np.unwrap(np.angle(L))
    pm = math.inf
    for i in np.nonzero(np.diff(np.sign(mag - 1.0)))[0]:
        t = (1.0 - mag[i]) / (mag[i + 1] - mag[i])
        p = ph[i] + t * (ph[i + 1] - ph[i])
        pm = min(pm, (math.degrees(p) + 180.0) % 360.0)
    gm = math.inf
    phd = np.degrees(ph)
    for k in range(-3, 3):
        c = -180.0 + 360.0 * k
        for i in np.nonzero(np.diff(np.sign(phd - c)))[0]:
            t = (c - phd[i]) / (phd[i + 1] - phd[i])
            g = mag[i] + t * (mag[i + 1] - mag[i])
            gm = min(gm, -20.0 * math.log10(g))
    return pm, gm


def _resp(num: list, den: list, z: np.ndarray) -> np.ndarray:
    return np.polyval(np.asarray(num, float), z) / np.polyval(np.asarray(den, float), z)


def compare(af, order: int, dgyro_hz: float, gains: dict, n: int = 20000) -> dict:
    """The PM/GM of ``gains`` on ``af``: the old model (loop-rate first-order D path), the new one (raw-rate,
    ``order``) and the exact raw-rate loop."""
    dt = 1.0 / af.loop_hz
    lf = lift(af, "px4", dgyro_hz=dgyro_hz, dgyro_order=order)
    w = np.logspace(-1, math.log10(math.pi / dt * 0.9999), n)
    z = np.exp(1j * w * dt)
    F, G, Cy = lf.F, lf.G[:, 0], lf.Cy
    eye = np.eye(F.shape[0])
    Gy = np.array([Cy @ np.linalg.solve(zi * eye - F, G) for zi in z])  # (n, 2): w_f and the D value per u
    k, p, i, d = gains["K"], gains["P"], gains["I"], gains["D"]
    truth = k * (p + i * dt / (z - 1)) * Gy[:, 0] + k * d * Gy[:, 1]
    st = get_structure("px4_rate")
    out = {"truth": margins(truth, w)}
    for name, fx in (("old", {"dgyro_hz": dgyro_hz, "dgyro_order": 1.0, "raw_hz": 0.0}),
                     ("new", {"dgyro_hz": dgyro_hz, "dgyro_order": float(order), "raw_hz": af.raw_hz})):
        num, den = st.with_fixed(fx).coeffs([p, i, d, 0.0], dt, np.exp)
        num = [c * k for c in num]
        out[name] = margins(_resp(num, den, z) * Gy[:, 0], w)
    return out


def flags(af, step: float = 8.0, u_max: float = 0.4) -> dict:
    """The saturated step of ``step`` rad/s with ``|u| <= u_max`` (the README's firmware bench figures) and PX4's
    default gains on ``af``'s plant as the tuner models it: the flags as the allocator publishes them (the
    saturation module) against this sample's own (what it simulated before: ``Simulator.flags_late = False``, of
    ``tuner.firmware.px4``)."""
    from tuner import analyze, controller_tf
    from tuner.analysis.saturation import Actuator
    from tuner.firmware.px4 import Simulator  # PX4's law in saturation (the firmware seam's module)

    g = {**DEFAULTS, "K": af.start_scale, "dgyro_hz": 20.0, "int_lim": 0.3, "dgyro_order": 1.0, "raw_hz": af.raw_hz}
    c = controller_tf("px4_rate", g, dt=af.dt)
    act = Actuator.of(u_max=u_max, step_size=step)

    out = {}
    for name, late in (("late", True), ("same", False)):
        Simulator.flags_late, orig = late, Simulator.flags_late
        try:
            a = analyze(af.plant_tf("px4"), c, dt=af.dt, delay=af.delay_s, actuator=act, structure="px4_rate",
                        gains=g)
        finally:
            Simulator.flags_late = orig
        s = a.saturated
        out[name] = (s.metrics.overshoot_pct, s.metrics.settling_time_s, s.saturated_fraction)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--write", action="store_true", help="write bench/results/dpath_issue40.md")
    args = ap.parse_args()
    lines = ["| airframe | loop / raw Hz | D path | PM old | PM new | PM truth | GM old | GM new | GM truth |",
             "|---|---|---|---|---|---|---|---|---|"]
    worst = {g: {"new_pm": 0.0, "new_gm": 0.0, "old_pm": 0.0, "old_gm": 0.0} for g in GENERATIONS}
    for af in AIRFRAMES.values():
        gains = {**DEFAULTS, "K": af.start_scale}  # the racer's defaults are scaled (h2h.airframes)
        for gen, (order, fd) in GENERATIONS.items():
            r = compare(af, order, fd, gains)
            (po, go), (pn, gn), (pt, gt) = r["old"], r["new"], r["truth"]
            lines.append(f"| {af.name} (K {gains['K']:g}) | {af.loop_hz:g} / {af.raw_hz:g} | {gen} | {po:.2f} | "
                         f"{pn:.2f} | {pt:.2f} | {go:.2f} | {gn:.2f} | {gt:.2f} |")
            ww = worst[gen]
            ww["new_pm"] = max(ww["new_pm"], abs(pn - pt))
            ww["new_gm"] = max(ww["new_gm"], abs(gn - gt))
            ww["old_pm"] = max(ww["old_pm"], abs(po - pt))
            ww["old_gm"] = max(ww["old_gm"], abs(go - gt))
    lines.append("")
    for gen, ww in worst.items():
        lines.append(f"- {gen}: largest |model - truth|: old PM {ww['old_pm']:.2f} deg, GM {ww['old_gm']:.2f} dB; "
                     f"new PM {ww['new_pm']:.2f} deg, GM {ww['new_gm']:.2f} dB")
    lines += ["", "Saturation flags (a step of 8 rad/s with |u| <= 0.4, PX4's defaults, the first-order D path at the "
              "raw rate; the saturated step of `tuner.analysis.saturation`): the flags as `ControlAllocator` publishes "
              "them (every ceil(5 ms/dt) samples, read the sample after) against this sample's own (before).", "",
              "| airframe | flag period (samples) | overshoot late / same, % | settling late / same, s | saturated "
              "share late / same |", "|---|---|---|---|---|"]
    from tuner.analysis.saturation import px4_flag_period

    for af in AIRFRAMES.values():
        r = flags(af)
        (ol, sl, fl), (os_, ss, fs) = r["late"], r["same"]
        lines.append(f"| {af.name} | {px4_flag_period(af.dt)} | {ol:.2f} / {os_:.2f} | {sl:.3f} / {ss:.3f} | "
                     f"{fl:.3f} / {fs:.3f} |")
    text = "\n".join(lines)
    print(text)
    if args.write:
        head = ("# PX4's D path at the raw gyro rate: margins of PX4's default gains (issue 40)\n\n"
                "Command: `.venv/bin/python bench/dpath.py --write`. PX4's default roll gains (P 0.15, I 0.2, D "
                "0.003, K 1; the racer K 0.3 as in the head-to-head) on `bench/h2h/airframes.py`. *old*: the D "
                "path differenced and first-order filtered at the loop rate (the tuner before this change, whatever "
                "the generation); *new*: `tuner.firmware.laws.dgyro_filter` (the raw-rate filter decimated, the "
                "rate taken linear between loop samples); *truth*: the airframe, its gyro low-pass, the "
                "difference and the D filter run on every raw gyro sample, lifted exactly to the loop rate "
                "(`h2h.sim.lift`). All three use the same exact loop-rate plant. PM in deg, GM in dB.\n\n")
        Path(__file__).resolve().parent.joinpath("results", "dpath_issue40.md").write_text(head + text + "\n")


if __name__ == "__main__":
    main()
