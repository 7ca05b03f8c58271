"""Step response and Bode plot of a tuned loop (matplotlib, Agg backend, no pyplot state).

Top: the plant output after a unit reference step, continuous (between samples)
as a line and, in a sampled-data loop, the values at the sample instants as
markers; the settling band around the final value. Below: magnitude and phase of
the open loop ``L = C*G``, with the gain crossover and phase margin, and the
phase crossover and gain margin, marked. With several plants (robust tuning) the
nominal plant is drawn solid, the others thin.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["draw", "bode_grid", "figure_bytes"]


def bode_grid(loop: Any, metrics: Any, n: int = 800) -> np.ndarray:
    """Log grid around the crossover, up to the Nyquist frequency of a sampled loop."""
    wc = metrics.crossover_rad_s if math.isfinite(metrics.crossover_rad_s) and metrics.crossover_rad_s > 0 else 1.0
    hi = 0.999 * math.pi / loop.dt if loop.dt else 1e3 * wc
    lo = min(wc, hi) * 1e-3
    return np.logspace(math.log10(lo), math.log10(hi), n)


def _phase_crossovers(w: np.ndarray, phase_deg: np.ndarray) -> list[float]:
    """Frequencies where the phase crosses -180 deg (mod 360), linear interpolation."""
    k = np.floor((phase_deg + 180.0) / 360.0)
    out = []
    for i in np.flatnonzero(np.diff(k) != 0):
        level = -180.0 + 360.0 * max(k[i], k[i + 1])
        p0, p1 = phase_deg[i], phase_deg[i + 1]
        f = (level - p0) / (p1 - p0) if p1 != p0 else 0.0
        out.append(float(np.exp(np.log(w[i]) + f * (np.log(w[i + 1]) - np.log(w[i])))))
    return out


def draw(analyses: Sequence[Any], *, fmt: str = "png", title: str = "", band_pct: float = 2.0) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, 9.0), layout="constrained")
    ax_y, ax_m, ax_p = fig.subplots(3, 1, height_ratios=[1.2, 1, 1])
    ax_m.sharex(ax_p)
    for i, a in enumerate(analyses):
        nominal = i == 0
        lw, alpha = (1.6, 1.0) if nominal else (0.8, 0.5)
        label = "nominal" if nominal and len(analyses) > 1 else (None if not nominal else "output y(t)")
        r = a.response
        if r is not None:
            ax_y.plot(r.t, r.y, lw=lw, alpha=alpha, color="C0" if nominal else "C7", label=label)
            if r.t_samples is not None and r.y_samples is not None:
                ax_y.plot(r.t_samples, r.y_samples, "o", ms=3.0 if nominal else 2.0, alpha=alpha,
                          color="C1" if nominal else "C7", label="at samples" if nominal else None)
            if nominal and math.isfinite(r.y_final):
                band = band_pct / 100.0 * abs(r.y_final)
                for lvl in (r.y_final - band, r.y_final + band):
                    ax_y.axhline(lvl, color="0.6", lw=0.7, ls=":")
        elif nominal:
            ax_y.text(0.5, 0.5, "closed loop unstable: no step response", ha="center", va="center",
                      transform=ax_y.transAxes, color="C3")
        w = bode_grid(a.loop, a.metrics)
        L = a.loop.freqresp(w)
        mag = 20 * np.log10(np.maximum(np.abs(L), 1e-300))
        ph = np.degrees(np.unwrap(np.angle(L)))
        ax_m.semilogx(w, mag, lw=lw, alpha=alpha, color="C0" if nominal else "C7")
        ax_p.semilogx(w, ph, lw=lw, alpha=alpha, color="C0" if nominal else "C7")
        if nominal:
            _mark_margins(ax_m, ax_p, w, mag, ph, a.metrics)
    ax_y.axhline(1.0, color="k", lw=0.7, ls="--")
    ax_y.set_xlabel("time (s)")
    ax_y.set_ylabel("output")
    ax_y.set_title(title or "closed-loop step response", fontsize=10)
    if ax_y.get_legend_handles_labels()[0]:
        ax_y.legend(loc="lower right", fontsize=8)
    ax_m.axhline(0.0, color="k", lw=0.7)
    ax_m.set_ylabel("|L| (dB)")
    ax_p.set_ylabel("phase of L (deg)")
    ax_p.set_xlabel("frequency (rad/s)")
    for ax in (ax_y, ax_m, ax_p):
        ax.grid(True, which="both", lw=0.3)
    return figure_bytes(fig, fmt=fmt)


def figure_bytes(fig: Any, *, fmt: str) -> bytes:
    """A matplotlib figure as PNG or SVG bytes (SVG text kept as text, reproducible ids)."""
    import matplotlib

    buf = io.BytesIO()
    with matplotlib.rc_context({"svg.fonttype": "none", "svg.hashsalt": "tuner"}):
        fig.savefig(buf, format=fmt, dpi=100)
    return buf.getvalue()


def _label(ax: Any, w: np.ndarray, x: float, y: float, text: str, color: str) -> None:
    """A label beside the marker at ``x``, on the side with room."""
    right = math.log(x / w[0]) > 0.6 * math.log(w[-1] / w[0])
    ax.text(x, y, f"{text}  " if right else f"  {text}", color=color, fontsize=8, va="center",
            ha="right" if right else "left")


def _mark_margins(ax_m: Any, ax_p: Any, w: np.ndarray, mag: np.ndarray, ph: np.ndarray, m: Any) -> None:
    wc, pm = m.crossover_rad_s, m.phase_margin_deg
    if math.isfinite(wc) and w[0] <= wc <= w[-1]:
        ax_m.axvline(wc, color="C2", lw=0.8, ls="--")
        p_wc = float(np.interp(math.log(wc), np.log(w), ph))
        base = p_wc - pm if math.isfinite(pm) else -180.0
        ax_p.axhline(base, color="0.5", lw=0.7, ls=":")
        ax_p.annotate("", xy=(wc, p_wc), xytext=(wc, base), arrowprops={"arrowstyle": "<->", "color": "C2"})
        _label(ax_p, w, wc, (p_wc + base) / 2, f"PM {pm:.1f}° at {wc:.3g} rad/s", "C2")
    gm = m.gain_margin_db
    crossings = _phase_crossovers(w, ph)
    if crossings and math.isfinite(gm):
        mags = np.interp(np.log(crossings), np.log(w), mag)
        j = int(np.argmin(np.abs(-mags - gm)))  # the crossing whose distance to 0 dB is the margin
        w180, m180 = crossings[j], float(mags[j])
        ax_m.annotate("", xy=(w180, m180), xytext=(w180, 0.0), arrowprops={"arrowstyle": "<->", "color": "C3"})
        _label(ax_m, w, w180, m180 / 2, f"GM {gm:.1f} dB at {w180:.3g} rad/s", "C3")
        ax_p.axvline(w180, color="C3", lw=0.8, ls="--")
    elif not math.isfinite(gm):
        ax_m.text(0.02, 0.05, "GM: infinite (no phase crossover)", transform=ax_m.transAxes, fontsize=8, color="C3")
