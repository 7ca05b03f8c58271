"""Plots of a verified loop: the one plotting module of the command line, the studies and the service.

Every figure is drawn from the verifier's :class:`~tuner.analysis.Analysis`, one per plant: a robust
tune's members are all drawn and labelled (the nominal plant first and bold, the others thin).

* ``step``: the plant output after a unit reference step, continuous between the samples (a line)
  and at the sample instants (markers); the settling band around the final value, the overshoot
  limit and the settling time. Below, on its own axis, the control signal u(t) with its peak (and
  the spec's ``control_peak_max``). The time axis is sized to the response (a few settling times),
  not to the simulation horizon.
* ``bode``: |L| and the phase of ``L = C G``, the gain crossover with the phase margin and the phase
  crossover with the gain margin marked. A delay's phase ``-w tau`` is added in closed form to the
  unwrapped phase of the rational part, the phase at the crossover is put in (-360, 0], and the
  axis stops one and a half turns down, so a delay cannot run it to -10000 degrees.
* ``nyquist``: ``L(jw)`` for w > 0 (and its mirror), the unit circle, the critical point -1 and the
  circle of radius 1/Ms around it (and 1/ms_max of the spec when it has one).
* ``all``: the three side by side.

pyplot is never imported and no backend is chosen: the figures are :class:`matplotlib.figure.Figure`
objects written through the Agg or SVG canvas explicitly (:func:`figure_bytes`). Entry point:
:func:`render` (bytes); :func:`figure` and the ``*_figure`` functions return the figure.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import rc_context
from matplotlib.figure import Figure, SubFigure
from matplotlib.ticker import MultipleLocator

from .._lazy import is_instance_of
from ..errors import TunerError
from ..spec import Spec
from .cascade import CascadeResponse
from .margins import Margins, frequency_grid, margins

__all__ = ["KINDS", "FORMATS", "InvalidPlotError", "render", "figure", "step_figure", "bode_figure",
           "nyquist_figure", "figure_bytes", "loop_plots", "LOOP_PLOTS"]

KINDS = ("all", "step", "bode", "nyquist")
FORMATS = ("png", "svg")
_SIZES = {"step": (7.5, 5.4), "bode": (7.5, 5.6), "nyquist": (6.2, 5.8), "all": (19.0, 6.2)}


class InvalidPlotError(TunerError, ValueError):
    """An unknown plot kind or format."""


def _is_analysis(obj: Any) -> bool:
    """An :class:`~tuner.analysis.Analysis` (recognised without importing the verifier: it shows itself with these
    plots, so importing it here would make a circle)."""
    return is_instance_of(obj, "tuner.analysis.verify", "Analysis")


@dataclass(frozen=True, eq=False)
class _Members:
    analyses: tuple[Any, ...]  # tuner.analysis.Analysis
    labels: tuple[str, ...]
    spec: Spec
    cascade: CascadeResponse | None

    @property
    def robust(self) -> bool:
        return len(self.analyses) > 1


_SPEC_OF_CHECK = {"overshoot_pct": "overshoot_max_pct", "control_peak": "control_peak_max", "ms": "ms_max"}


def _members(obj: Any, spec: Spec | None, labels: Sequence[str] | None,
             cascade: CascadeResponse | None) -> _Members:
    """The analyses to draw from a TuneResult, a study's LoopEval, an Analysis or a sequence of them."""
    if _is_analysis(obj):
        analyses: tuple[Any, ...] = (obj,)
    elif hasattr(obj, "analyses"):
        analyses = tuple(obj.analyses)
        spec = spec or getattr(obj, "spec", None) or getattr(getattr(obj, "loop", None), "spec", None)
        cascade = cascade or getattr(obj, "cascade", None)
    else:
        analyses = tuple(obj)
    if not analyses or not all(_is_analysis(a) for a in analyses):
        raise TypeError("plots draw a TuneResult, an Analysis or a sequence of Analysis objects, got "
                        f"{type(obj).__name__}")
    if spec is None:  # the limits the checks were made against (the settling band is not in them: 2 %)
        spec = Spec(**{_SPEC_OF_CHECK[c.name]: c.required for c in analyses[0].checks if c.name in _SPEC_OF_CHECK})
    if labels is None:
        labels = ["nominal", *(f"plant {i + 1}" for i in range(1, len(analyses)))] if len(analyses) > 1 else [""]
    if len(labels) != len(analyses):
        raise InvalidPlotError(f"{len(labels)} labels for {len(analyses)} plants", field="labels")
    return _Members(analyses, tuple(labels), spec, cascade)


def _style(i: int, n: int) -> dict[str, Any]:
    """Nominal bold in C0; with several plants, each member a colour of its own, thin."""
    if i == 0:
        return {"color": "C0", "lw": 1.7, "alpha": 1.0, "zorder": 3}
    return {"color": f"C{1 + (i - 1) % 9}" if n <= 10 else "0.55", "lw": 0.9, "alpha": 0.75, "zorder": 2}


# -- step response and control signal -------------------------------------------------------------


def _window(a: Any) -> float:
    """End of the time axis: a few settling times (a long horizon would squash the transient)."""
    r, m = a.response, a.metrics
    if r is None:
        return 0.0
    ts = m.settling_time_s if math.isfinite(m.settling_time_s) else float(r.t[-1])
    t_end = max(3.0 * ts, 4.0 * (m.rise_time_s if math.isfinite(m.rise_time_s) else 0.0))
    if a.loop.dt:
        t_end = max(t_end, 15 * a.loop.dt)
    return float(min(t_end, r.t[-1]))


def _draw_step(fig: Figure | SubFigure, m: _Members, title: str) -> None:
    ax_y, ax_u = fig.subplots(2, 1, sharex=True, height_ratios=[2.2, 1])
    t_end = max(_window(a) for a in m.analyses) or 1.0
    spec, n = m.spec, len(m.analyses)
    for i, (a, label) in enumerate(zip(m.analyses, m.labels)):
        r, st = a.response, _style(i, n)
        if r is None:
            ax_y.text(0.5, 0.5 - 0.07 * i, f"{label or 'closed loop'}: unstable, no step response", ha="center",
                      va="center", transform=ax_y.transAxes, color="C3")
            continue
        cont = m.cascade.response if (i == 0 and m.cascade is not None) else (r if r.between_samples else None)
        name = f"{label}: " if m.robust else ""
        if cont is not None:
            k = cont.t <= t_end
            ax_y.plot(cont.t[k], cont.y[k], **st, label=f"{name}output y(t) between samples" if r.t_samples is not None
                      else f"{name}output y(t)")
        if r.t_samples is not None and r.y_samples is not None and (i == 0 or cont is None):
            k = r.t_samples <= t_end
            ax_y.plot(r.t_samples[k], r.y_samples[k], "o", ms=3.0 if k.sum() <= 80 else 1.5, color=st["color"],
                      alpha=st["alpha"], zorder=st["zorder"], label=f"{name}at the samples")
        ur = cont if cont is not None else r
        k = ur.t <= t_end
        peak = float(np.max(np.abs(ur.u))) if ur.u.size else math.nan
        ax_u.plot(ur.t[k], ur.u[k], drawstyle="steps-post" if a.loop.dt else "default", **st,
                  label=f"{name}u(t), peak |u| {peak:.3g}")
    nominal = m.analyses[0]
    if nominal.response is not None and math.isfinite(nominal.response.y_final):
        yf, band = nominal.response.y_final, spec.settling_band_pct
        for s in (1 + band / 100, 1 - band / 100):
            ax_y.axhline(s * yf, color="0.5", lw=0.8, ls="--", label=f"settling band ±{band:g} %" if s > 1 else None)
        ax_y.axhline((1 + spec.overshoot_max_pct / 100) * yf, color="C3", lw=0.9, ls=":",
                     label=f"overshoot limit {spec.overshoot_max_pct:g} %")
        ts = nominal.metrics.settling_time_s
        if math.isfinite(ts):
            ax_y.axvline(ts, color="C2", lw=0.8, label=f"settled at {ts:.3g} s")
    if spec.control_peak_max is not None:
        for s in (1, -1):
            ax_u.axhline(s * spec.control_peak_max, color="C3", lw=0.9, ls=":",
                         label=f"control peak limit {spec.control_peak_max:g}" if s > 0 else None)
    ax_y.set_xlim(0, t_end)
    ax_y.set_ylabel("output y")
    ax_y.set_title(title or "unit step response", fontsize=10)
    ax_u.set_ylabel("control u")
    ax_u.set_xlabel("time [s]")
    for ax in (ax_y, ax_u):
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="lower right" if ax is ax_y else "upper right", fontsize=7, ncol=2 if n > 3 else 1)


# -- Bode ----------------------------------------------------------------------------------------


def _margins(a: Any) -> Margins:
    return a.margins if a.margins is not None else margins(a.loop)


def _finite_pos(*xs: float) -> list[float]:
    return [float(x) for x in xs if math.isfinite(x) and x > 0]


def _grid(m: _Members, n: int = 1200) -> np.ndarray:
    """Log grid two and a half decades around the crossovers (within the loop's own grid: its poles and
    zeros, up to just below the Nyquist frequency), the crossover frequencies included exactly."""
    loop = m.analyses[0].loop
    full = frequency_grid(loop, 400)
    lo, hi = float(full[0]), float(full[-1])
    nyq = loop.nyquist_w()
    if nyq:
        hi = min(hi, 0.9999 * nyq)
    keys = [f for a in m.analyses for f in _finite_pos(_margins(a).crossover_rad_s, _margins(a).phase_crossover_rad_s,
                                                       a.metrics.bandwidth_rad_s)]
    if keys:
        lo, hi = max(lo, min(keys) / 300.0), min(hi, max(keys) * 300.0)
    if not lo < hi:
        lo, hi = hi / 1e4, hi
    w = np.logspace(math.log10(lo), math.log10(hi), n)
    return np.unique(np.concatenate([w, [k for k in keys if lo <= k <= hi]]))


def _phase_deg(a: Any, w: np.ndarray, L: np.ndarray) -> np.ndarray:
    """Unwrapped phase: the rational part unwrapped on the grid, the delay's ``-w tau`` added exactly;
    shifted by whole turns so that the phase at the gain crossover is in (-360, 0] (then the phase
    margin is measured from -180), or, without a crossover, the low-frequency phase in (-180, 180]."""
    lp = a.loop
    tau = lp.delay_s or (lp.delay_samples * lp.dt if lp.dt else 0.0)
    rational = L * np.exp(1j * w * tau) if tau else L
    ph = np.degrees(np.unwrap(np.angle(rational)) - w * tau)
    wc = _margins(a).crossover_rad_s
    if math.isfinite(wc) and w[0] <= wc <= w[-1]:
        return ph - 360.0 * math.ceil(float(np.interp(math.log(wc), np.log(w), ph)) / 360.0)
    return ph - 360.0 * math.floor((ph[0] + 180.0) / 360.0)


def _at(w: np.ndarray, v: np.ndarray, x: float) -> float:
    return float(np.interp(math.log(x), np.log(w), v))


def _draw_bode(fig: Figure | SubFigure, m: _Members, title: str) -> None:
    ax_m, ax_p = fig.subplots(2, 1, sharex=True)
    w = _grid(m)
    n, lowest = len(m.analyses), -math.inf
    phases = []
    for i, (a, label) in enumerate(zip(m.analyses, m.labels)):
        with np.errstate(divide="ignore", invalid="ignore"):
            L = a.loop.freqresp(w)
        mag = 20 * np.log10(np.maximum(np.abs(L), 1e-300))
        ph = _phase_deg(a, w, L)
        phases.append(ph)
        st = _style(i, n)
        ax_m.semilogx(w, mag, **st, label=label or None)
        ax_p.semilogx(w, ph, **st)
        if i == 0:
            lowest = _mark_margins(ax_m, ax_p, w, mag, ph, a)
    allph = np.concatenate(phases)
    top = float(np.max(allph)) + 15.0
    bottom = max(float(np.min(allph)) - 15.0, min(-540.0, lowest - 90.0))  # 1.5 turns below (delays go on)
    ax_p.set_ylim(bottom, top)
    ax_p.yaxis.set_major_locator(MultipleLocator(90.0 * max(1, round((top - bottom) / 720.0))))
    for k in range(math.ceil((bottom + 180.0) / 360.0), math.floor((top + 180.0) / 360.0) + 1):
        ax_p.axhline(-180.0 + 360.0 * k, color="0.5", lw=0.8)
    ax_m.axhline(0.0, color="0.5", lw=0.8)
    mg = _margins(m.analyses[0])
    low = f"   lower GM {mg.gain_margin_lower_db:.1f} dB" if math.isfinite(mg.gain_margin_lower_db) else ""
    ax_m.set_title((title or "open loop L = C G") + low, fontsize=10)
    ax_m.set_ylabel("|L| [dB]")
    ax_p.set_ylabel("phase of L [deg]")
    ax_p.set_xlabel("frequency [rad/s]" + ("  (up to the Nyquist frequency)" if m.analyses[0].loop.dt else ""))
    ax_p.set_xlim(w[0], w[-1])
    if m.robust:
        ax_m.legend(loc="lower left", fontsize=7, ncol=2 if n > 3 else 1)
    for ax in (ax_m, ax_p):
        ax.grid(True, which="both", alpha=0.3)


def _label(ax: Any, w: np.ndarray, x: float, y: float, text: str, color: str) -> None:
    """A label beside the marker at ``x``, on the side with room."""
    right = math.log(x / w[0]) > 0.6 * math.log(w[-1] / w[0])
    ax.text(x, y, f"{text}  " if right else f"  {text}", color=color, fontsize=8, va="center",
            ha="right" if right else "left")


def _mark_margins(ax_m: Any, ax_p: Any, w: np.ndarray, mag: np.ndarray, ph: np.ndarray, a: Any) -> float:
    """The phase margin (arrow from -180 to the phase at the crossover) and the gain margin (arrow from
    |L| at the phase crossover to 0 dB); returns the lowest phase worth showing."""
    mg, lowest = _margins(a), -270.0
    wc, pm = mg.crossover_rad_s, mg.phase_margin_deg
    if math.isfinite(wc) and w[0] <= wc <= w[-1]:
        p_wc = _at(w, ph, wc)
        lowest = min(lowest, p_wc)
        for ax in (ax_m, ax_p):
            ax.axvline(wc, color="C2", lw=0.8, ls="--")
        ax_p.annotate("", xy=(wc, p_wc), xytext=(wc, -180.0), arrowprops={"arrowstyle": "<->", "color": "C2"})
        _label(ax_p, w, wc, (p_wc - 180.0) / 2, f"PM {pm:.1f}° at {wc:.3g} rad/s", "C2")
    w180, gm = mg.phase_crossover_rad_s, mg.gain_margin_db
    if math.isfinite(w180) and math.isfinite(gm) and w[0] <= w180 <= w[-1]:
        m180 = _at(w, mag, w180)
        lowest = min(lowest, _at(w, ph, w180))
        for ax in (ax_m, ax_p):
            ax.axvline(w180, color="C3", lw=0.8, ls="--")
        ax_m.annotate("", xy=(w180, m180), xytext=(w180, 0.0), arrowprops={"arrowstyle": "<->", "color": "C3"})
        _label(ax_m, w, w180, m180 / 2, f"GM {gm:.1f} dB at {w180:.3g} rad/s", "C3")
    elif not math.isfinite(gm):
        ax_m.text(0.02, 0.05, "GM: infinite (no phase crossover)", transform=ax_m.transAxes, fontsize=8, color="C3")
    return lowest


# -- Nyquist -------------------------------------------------------------------------------------


def _draw_nyquist(fig: Figure | SubFigure, m: _Members, title: str) -> None:
    ax = fig.subplots()
    n = len(m.analyses)
    th = np.linspace(0, 2 * np.pi, 361)
    pts = [np.array([-1.0 + 0j, 1.0, 1j, -1j])]
    for i, (a, label) in enumerate(zip(m.analyses, m.labels)):
        w = frequency_grid(a.loop, 3000)
        nyq = a.loop.nyquist_w()
        with np.errstate(divide="ignore", invalid="ignore"):
            L = a.loop.freqresp(w[w <= nyq] if nyq else w)
        L = L[np.isfinite(L)]
        st = _style(i, n)
        ax.plot(L.real, L.imag, **st, label=f"{label + ': ' if m.robust else ''}L(jω), ω > 0")
        ax.plot(L.real, -L.imag, **{**st, "lw": st["lw"] * 0.6, "alpha": 0.5}, ls="--",
                label="ω < 0" if i == 0 else None)
        pts.append(L[np.abs(L + 1.0) < 2.5])  # within 2.5 of -1
    ax.plot(np.cos(th), np.sin(th), color="0.5", lw=0.8, label="unit circle")
    ms = m.analyses[0].metrics.ms
    if math.isfinite(ms) and ms >= 1:
        ax.plot(-1 + np.cos(th) / ms, np.sin(th) / ms, color="C1", lw=1.0, label=f"1/Ms = {1 / ms:.3g} (Ms {ms:.3g})")
    if m.spec.ms_max is not None:
        r = 1.0 / m.spec.ms_max
        ax.plot(-1 + r * np.cos(th), r * np.sin(th), color="C3", lw=0.9, ls=":", label=f"1/ms_max = {r:.3g}")
    ax.plot([-1], [0], "x", color="C3", ms=9, mew=2, label="−1")
    p = np.concatenate(pts)  # a square window around what is near the critical point
    x0, x1 = float(np.min(p.real)), float(np.max(p.real))
    span = 1.1 * max(x1 - x0, 2.0 * float(np.max(np.abs(p.imag))), 2.5)
    xc = 0.5 * (x0 + x1)
    ax.set_xlim(xc - span / 2, xc + span / 2)
    ax.set_ylim(-span / 2, span / 2)
    ax.set_aspect("equal", adjustable="box")
    ax.axhline(0, color="0.5", lw=0.5)
    ax.axvline(0, color="0.5", lw=0.5)
    ax.set_xlabel("Re L")
    ax.set_ylabel("Im L")
    ax.set_title(title or "Nyquist plot of L", fontsize=10)
    ax.legend(loc="lower left", fontsize=7, ncol=2 if n > 3 else 1)
    ax.grid(True, alpha=0.3)


# -- entry points --------------------------------------------------------------------------------

_DRAW = {"step": _draw_step, "bode": _draw_bode, "nyquist": _draw_nyquist}


def figure(obj: Any, kind: str = "all", *, spec: Spec | None = None, title: str = "",
           labels: Sequence[str] | None = None, cascade: CascadeResponse | None = None) -> Figure:
    """The figure of ``kind`` (``all``, ``step``, ``bode``, ``nyquist``) for ``obj``: a
    :class:`~tuner.tuning.TuneResult`, a study's loop evaluation, an :class:`Analysis` or a sequence of
    them (nominal first). ``spec`` gives the settling band and the limits drawn (default: the result's,
    else the limits of the analysis's checks and a 2 % band); ``labels`` name the plants."""
    if kind not in KINDS:
        raise InvalidPlotError(f"unknown plot kind {kind!r}: use one of {', '.join(KINDS)}", field="kind")
    mem = _members(obj, spec, labels, cascade)
    fig = Figure(figsize=_SIZES[kind], layout="constrained")
    if kind != "all":
        _DRAW[kind](fig, mem, title)
        return fig
    subs = fig.subfigures(1, 3, width_ratios=[1.15, 1.15, 0.9])
    for sub, k in zip(subs, ("step", "bode", "nyquist")):
        _DRAW[k](sub, mem, "")
    if title:
        fig.suptitle(title, fontsize=11)
    return fig


def step_figure(obj: Any, **kw: Any) -> Figure:
    """Step response (between samples and at the samples) with the settling band, the overshoot limit and u(t)."""
    return figure(obj, "step", **kw)


def bode_figure(obj: Any, **kw: Any) -> Figure:
    """Bode plot of the open loop with the phase and gain margins marked."""
    return figure(obj, "bode", **kw)


def nyquist_figure(obj: Any, **kw: Any) -> Figure:
    """Nyquist plot of the open loop with the unit circle and the 1/Ms circle around -1."""
    return figure(obj, "nyquist", **kw)


def figure_bytes(fig: Figure, *, fmt: str = "png", dpi: float = 100) -> bytes:
    """A figure as PNG or SVG bytes, through the Agg or SVG canvas (no pyplot, no backend switch); SVG
    text is kept as text and its ids are reproducible (no date, fixed hash salt)."""
    if fmt not in FORMATS:
        raise InvalidPlotError(f"unknown plot format {fmt!r}: use png or svg", field="fmt")
    buf = io.BytesIO()
    if fmt == "png":
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        FigureCanvasAgg(fig).print_figure(buf, format="png", dpi=dpi)
    else:
        from matplotlib.backends.backend_svg import FigureCanvasSVG

        with rc_context({"svg.fonttype": "none", "svg.hashsalt": "tuner"}):
            FigureCanvasSVG(fig).print_figure(buf, format="svg", dpi=dpi, metadata={"Date": None})
    return buf.getvalue()


def render(obj: Any, kind: str = "all", fmt: str = "png", *, dpi: float = 100, **kw: Any) -> bytes:
    """:func:`figure` as PNG or SVG bytes (what the service answers)."""
    if fmt not in FORMATS:  # before drawing
        raise InvalidPlotError(f"unknown plot format {fmt!r}: use png or svg", field="fmt")
    return figure_bytes(figure(obj, kind, **kw), fmt=fmt, dpi=dpi)


LOOP_PLOTS = ("step", "bode", "nyquist")  # the figures of a loop (loop_plots), in the order they are drawn


def loop_plots(obj: Any, out_dir: str | Path, name: str, *, spec: Spec | None = None,
               cascade: CascadeResponse | None = None, fmt: str = "png",
               kinds: Sequence[str] = LOOP_PLOTS) -> dict[str, Path]:
    """The three plots of one loop as ``<name>_step.png``, ``<name>_bode.png``, ``<name>_nyquist.png`` (``kinds``:
    those of :data:`LOOP_PLOTS` to draw, e.g. one, where several processes share a loop's figures)."""
    from ..fileio import write_output

    unknown = [k for k in kinds if k not in LOOP_PLOTS]
    if unknown:
        raise InvalidPlotError(f"unknown loop plot {unknown[0]!r}: use {', '.join(LOOP_PLOTS)}", field="kind")
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    titles = {"step": f"{name}: unit step response", "bode": f"{name}: open loop L", "nyquist": f"{name}: Nyquist"}
    out = {}
    for kind, title in ((k, titles[k]) for k in LOOP_PLOTS if k in kinds):
        p = d / f"{name}_{kind}.{fmt}"
        write_output(p, render(obj, kind, fmt, dpi=110, spec=spec, cascade=cascade, title=title))
        out[kind] = p
    return out
