"""Plots of a verified loop (matplotlib, Agg backend): step response, Bode, Nyquist.

Every figure is drawn from the verifier's :class:`~tuner.analysis.Analysis`: the step
response shows the continuous output and the sample instants, the Bode plot the margins
the verifier found, the Nyquist plot the unit circle and the critical point.
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from .cascade import CascadeResponse
from .margins import frequency_grid, margins
from .verify import Analysis

__all__ = ["step_plot", "bode_plot", "nyquist_plot", "loop_plots"]


def _window(a: Analysis, resp_t: np.ndarray) -> float:
    """Time axis: a few settling times (a long horizon would squash the transient)."""
    m = a.metrics
    ts = m.settling_time_s if math.isfinite(m.settling_time_s) else float(resp_t[-1])
    t_end = max(3.0 * ts, 10.0 * (m.rise_time_s if math.isfinite(m.rise_time_s) else 0.0))
    if a.loop.dt:
        t_end = max(t_end, 15 * a.loop.dt)
    return float(min(t_end, resp_t[-1]))


def step_plot(a: Analysis, path: str | Path, *, title: str, band_pct: float, overshoot_max_pct: float,
              cascade: CascadeResponse | None = None) -> Path:
    fig, ax = plt.subplots(figsize=(7, 4))
    r = a.response
    if r is None:
        ax.text(0.5, 0.5, "closed loop unstable: no step response", ha="center", va="center", transform=ax.transAxes)
    else:
        t_end = _window(a, r.t)
        cont = cascade.response if cascade is not None else (r if r.between_samples else None)
        if r.t_samples is not None:
            k = r.t_samples <= t_end
            ax.plot(r.t_samples[k], r.y_samples[k], "o", ms=3 if k.sum() <= 60 else 1.5, color="tab:orange",
                    label="output at the samples")
        if cont is not None:
            k = cont.t <= t_end
            ax.plot(cont.t[k], cont.y[k], lw=1.2, color="tab:blue", label="output (continuous, between samples)")
        yf = r.y_final
        for s in (1 + band_pct / 100, 1 - band_pct / 100):
            ax.axhline(s * yf, color="grey", lw=0.8, ls="--")
        ax.axhline((1 + overshoot_max_pct / 100) * yf, color="tab:red", lw=0.8, ls=":",
                   label=f"overshoot limit {overshoot_max_pct:g} %")
        ts = a.metrics.settling_time_s
        if math.isfinite(ts):
            ax.axvline(ts, color="tab:green", lw=0.8, label=f"settled ({band_pct:g} %) at {ts:.3g} s")
        ax.set_xlim(0, t_end)
        ax.legend(loc="lower right", fontsize=8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("output")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    return _save(fig, path)


def _w_grid(a: Analysis) -> np.ndarray:
    w = frequency_grid(a.loop, 1500)
    nyq = a.loop.nyquist_w()
    return w[w < nyq * 0.9999] if nyq else w


def bode_plot(a: Analysis, path: str | Path, *, title: str) -> Path:
    lp = a.loop
    w = _w_grid(a)
    L = lp.freqresp(w)
    mag = 20 * np.log10(np.maximum(np.abs(L), 1e-300))
    ph = np.degrees(np.unwrap(np.angle(L)))
    mg = margins(lp)
    wc = mg.crossover_rad_s
    ref = float(np.interp(np.log(wc), np.log(w), ph)) if math.isfinite(wc) and wc > 0 else float(ph[0])
    ph -= 360.0 * math.ceil(ref / 360.0)  # the reference phase in (-360, 0]: PM = 180 + phase at crossover
    fig, (am, ap) = plt.subplots(2, 1, sharex=True, figsize=(7, 5.5))
    am.semilogx(w, mag, lw=1.4)
    am.axhline(0, color="grey", lw=0.8)
    ap.semilogx(w, ph, lw=1.4)
    ap.axhline(-180, color="grey", lw=0.8)
    if math.isfinite(wc) and wc > 0:
        pc = float(np.interp(np.log(wc), np.log(w), ph))
        am.axvline(wc, color="tab:green", lw=0.8)
        ap.axvline(wc, color="tab:green", lw=0.8)
        ap.annotate("", xy=(wc, pc), xytext=(wc, pc - mg.phase_margin_deg),
                    arrowprops={"arrowstyle": "<->", "color": "tab:green"})
        ap.text(wc, pc, f"  PM {mg.phase_margin_deg:.1f}° at {wc:.3g} rad/s", color="tab:green", fontsize=8)
    wp = mg.phase_crossover_rad_s
    if math.isfinite(wp) and wp > 0 and math.isfinite(mg.gain_margin_db):
        am.axvline(wp, color="tab:red", lw=0.8)
        ap.axvline(wp, color="tab:red", lw=0.8)
        am.annotate("", xy=(wp, 0), xytext=(wp, -mg.gain_margin_db),
                    arrowprops={"arrowstyle": "<->", "color": "tab:red"})
        am.text(wp, -mg.gain_margin_db, f"  GM {mg.gain_margin_db:.1f} dB at {wp:.3g} rad/s", color="tab:red",
                fontsize=8)
    low = mg.gain_margin_lower_db
    am.set_title(title + (f"   (lower GM {low:.1f} dB)" if math.isfinite(low) else ""))
    am.set_ylabel("|L| [dB]")
    ap.set_ylabel("phase of L [deg]")
    ap.set_xlabel("frequency [rad/s]" + ("  (up to the Nyquist frequency)" if lp.dt else ""))
    for ax in (am, ap):
        ax.grid(True, which="both", alpha=0.3)
    return _save(fig, path)


def nyquist_plot(a: Analysis, path: str | Path, *, title: str) -> Path:
    w = _w_grid(a)
    L = a.loop.freqresp(w)
    fig, ax = plt.subplots(figsize=(5.5, 5.5))
    ax.plot(L.real, L.imag, lw=1.4, label="L(jω), ω > 0")
    ax.plot(L.real, -L.imag, lw=0.8, ls="--", color="tab:blue", alpha=0.6, label="ω < 0")
    th = np.linspace(0, 2 * np.pi, 361)
    ax.plot(np.cos(th), np.sin(th), color="grey", lw=0.8, label="unit circle")
    ms = a.metrics.ms
    if math.isfinite(ms) and ms > 1:
        ax.plot(-1 + np.cos(th) / ms, np.sin(th) / ms, color="tab:orange", lw=0.8, ls=":", label=f"1/Ms = {1/ms:.2f}")
    ax.plot([-1], [0], "x", color="tab:red", ms=9, mew=2, label="−1")
    ax.set_xlim(-3, 2)
    ax.set_ylim(-2.5, 2.5)
    ax.set_aspect("equal")
    ax.axhline(0, color="grey", lw=0.5)
    ax.axvline(0, color="grey", lw=0.5)
    ax.set_xlabel("Re L")
    ax.set_ylabel("Im L")
    ax.set_title(title)
    ax.legend(loc="lower left", fontsize=8)
    ax.grid(True, alpha=0.3)
    return _save(fig, path)


def loop_plots(a: Analysis, out_dir: str | Path, name: str, *, band_pct: float, overshoot_max_pct: float,
               cascade: CascadeResponse | None = None) -> dict[str, Path]:
    """The three plots of one loop, as ``<name>_step.png``, ``<name>_bode.png``, ``<name>_nyquist.png``."""
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    return {
        "step": step_plot(a, d / f"{name}_step.png", title=f"{name}: unit step response", band_pct=band_pct,
                          overshoot_max_pct=overshoot_max_pct, cascade=cascade),
        "bode": bode_plot(a, d / f"{name}_bode.png", title=f"{name}: open loop L"),
        "nyquist": nyquist_plot(a, d / f"{name}_nyquist.png", title=f"{name}: Nyquist"),
    }


def _save(fig, path: str | Path) -> Path:
    p = Path(path)
    fig.tight_layout()
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p
