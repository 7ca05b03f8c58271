"""The fit plot: Bode of the data and the fitted model with a coherence panel (like the thesis's
Figure 4), and the time-domain check below. A :class:`matplotlib.figure.Figure`, no
pyplot state, no backend chosen here (``savefig`` picks one for the file format).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["fit_figure"]


def _align(model_deg: np.ndarray, data_deg: np.ndarray) -> float:
    """Multiple of 360 deg to add to the model's phase so it lies on the data's branch."""
    d = np.asarray(data_deg) - np.asarray(model_deg)
    d = d[np.isfinite(d)]
    return 360.0 * float(np.round(np.median(d) / 360.0)) if d.size else 0.0


def fit_figure(res: Any, *, title: str | None = None, time_domain: bool = True):
    """The identification's figure (matplotlib, no pyplot): the measured frequency response
    with its coherence and the model's, and the held-out time-domain check."""
    from matplotlib.figure import Figure

    fr, fp = res.frequency_response, res.fit_points
    cmin = float(res.options.get("coherence_min", 0.6))
    with_time = time_domain and res.validation is not None and res.validation.t.size > 0
    fig = Figure(figsize=(8.0, 10.0 if with_time else 8.0), layout="constrained")
    ratios = [1.2, 1.0, 0.6] + ([0.9] if with_time else [])
    axes = fig.subplots(len(ratios), 1, height_ratios=ratios)
    ax_m, ax_p, ax_c = axes[:3]
    for ax in (ax_p, ax_c):
        ax.sharex(ax_m)
    lo, hi = res.band_rad_s
    w_model = np.geomspace(min(fr.w[0], lo), max(fr.w[-1], hi), 600)
    mag_m, ph_m = res.model.bode(w_model)
    data_ph = fr.phase_deg
    ph_m = ph_m + _align(np.interp(fp.w, w_model, ph_m), np.interp(fp.w, fr.w, data_ph))
    good = fr.coherence >= cmin
    for ax, data, model in ((ax_m, fr.mag_db, mag_m), (ax_p, data_ph, ph_m)):
        ax.axvspan(lo, hi, color="C2", alpha=0.07, lw=0)
        ax.semilogx(fr.w, np.where(good, data, np.nan), ".", ms=3.0, color="C0", label=f"data (coherence >= {cmin:g})")
        ax.semilogx(fr.w, np.where(good, np.nan, data), ".", ms=2.5, color="0.65", label="data (low coherence)")
        ax.semilogx(w_model, model, "-", lw=1.5, color="C3", label="fitted model")
        ax.grid(True, which="both", lw=0.3)
    fit_ph = np.interp(fp.w, w_model, ph_m)
    fit_ph = fit_ph + (((fp.phase_deg - fit_ph) + 180.0) % 360.0 - 180.0)  # the points on the model's branch
    ax_m.plot(fp.w, fp.mag_db, "o", mfc="none", mec="k", ms=5, label=f"fit points ({fp.w.size})")
    ax_p.plot(fp.w, fit_ph, "o", mfc="none", mec="k", ms=5)
    finite = np.isfinite(fr.mag_db) & good
    if finite.any():
        span = fr.mag_db[finite]
        ax_m.set_ylim(min(span.min(), mag_m.min()) - 5.0, max(span.max(), mag_m.max()) + 5.0)
        ph_span = np.concatenate([data_ph[finite], np.interp(fr.w[finite], w_model, ph_m)])
        ax_p.set_ylim(ph_span.min() - 20.0, ph_span.max() + 20.0)
    ax_m.set_ylabel("magnitude (dB)")
    ax_p.set_ylabel("phase (deg)")
    ax_m.legend(loc="lower left", fontsize=8)
    ax_c.axvspan(lo, hi, color="C2", alpha=0.07, lw=0, label=f"band {lo:.3g}-{hi:.3g} rad/s")
    ax_c.semilogx(fr.w, fr.coherence, "-", color="C0", lw=1.2)
    ax_c.axhline(cmin, color="C3", lw=0.8, ls="--", label=f"coherence {cmin:g}")
    ax_c.set_ylim(0.0, 1.05)
    ax_c.set_ylabel("coherence")
    ax_c.set_xlabel("frequency (rad/s)")
    ax_c.grid(True, which="both", lw=0.3)
    ax_c.legend(loc="lower left", fontsize=8)
    lo, hi = res.band_rad_s
    ax_m.set_title(title or f"{res.describe()}\nJ = {res.cost:.3g} over {lo:.3g}-{hi:.3g} rad/s: {res.quality}; "
                   f"time-domain check: {res.check}", fontsize=9)
    if with_time:
        v = res.validation
        ax_t = axes[3]
        ax_t.plot(v.t, v.measured, lw=1.0, color="C0", label="measured (bias and drift removed)")
        ax_t.plot(v.t, v.model, lw=1.0, color="C3", ls="--", label="model, from the measured input")
        ax_t.set_xlabel("time (s)")
        ax_t.set_ylabel("output")
        from .validate import SOURCES

        ax_t.set_title(f"time-domain check on {SOURCES.get(v.source, v.source)}: Theil {v.theil_u:.3g}, rms error "
                       f"{v.noise_ratio:.2f} x the noise floor: {v.verdict}", fontsize=9)
        ax_t.grid(True, lw=0.3)
        ax_t.legend(loc="upper right", fontsize=8)
    return fig
