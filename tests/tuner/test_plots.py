"""The one plotting module (tuner.analysis.plots): every kind renders, and what is drawn is what the
verifier found, checked against closed forms where there is one."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from numpy.testing import assert_allclose
from quadrotor import DT, ROLL, ROLL_C

from tuner import Spec, analyze, controller_from_expr, plant_from_expr
from tuner.analysis import plots
from tuner.tuning import TuneResult

K, TAU = 0.5, 1.0  # L = K e^{-s tau} / s: |L| = K/w, phase = -90 deg - w tau (closed forms)


@pytest.fixture(scope="module")
def roll():
    return analyze(plant_from_expr(ROLL), controller_from_expr(ROLL_C, dt=DT))


@pytest.fixture(scope="module")
def delayed():
    return analyze(plant_from_expr("1/s", delay=TAU), controller_from_expr(f"{K}", dt=None))


def texts(fig) -> list[str]:
    out = [t.get_text().strip() for t in fig.findobj(lambda o: hasattr(o, "get_text"))]
    return [t for t in out if t]


def line(ax, label: str):
    (ln,) = [ln for ln in ax.get_lines() if ln.get_label() == label]
    return ln


@pytest.mark.parametrize("kind", plots.KINDS)
@pytest.mark.parametrize("fmt", plots.FORMATS)
@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_each_kind_renders_a_valid_image(roll, kind, fmt):
    data = plots.render(roll, kind, fmt)
    w_in, h_in = plots._SIZES[kind]
    if fmt == "png":
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
        assert (int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")) == (w_in * 100, h_in * 100)
    else:
        root = ET.fromstring(data)
        assert root.tag == "{http://www.w3.org/2000/svg}svg"
        assert root.get("width") == f"{w_in * 72:g}pt"  # SVG sizes are in points
        assert plots.render(roll, kind, fmt) == data  # reproducible: no date, fixed ids


def test_step_plot_shows_the_output_between_samples_the_band_the_limit_and_u():
    roll = analyze(plant_from_expr(ROLL), controller_from_expr(ROLL_C, dt=DT), horizon_s=20.0)  # a long horizon
    fig = plots.step_figure(roll, spec=Spec(overshoot_max_pct=7.5, settling_band_pct=5, control_peak_max=5))
    ax_y, ax_u = fig.axes
    r, m = roll.response, roll.metrics
    between = line(ax_y, "output y(t) between samples")
    t = between.get_xdata()
    assert_allclose(np.diff(t), DT / 20, rtol=1e-9)  # 20 points per sample: the output between samples
    assert_allclose(between.get_ydata(), r.y[: t.size], rtol=1e-12)
    at = line(ax_y, "at the samples")
    assert_allclose(at.get_xdata(), np.arange(at.get_xdata().size) * DT, rtol=1e-12)
    levels = sorted(ln.get_ydata()[0] for ln in ax_y.get_lines() if ln.get_linestyle() in ("--", ":"))
    assert_allclose(levels, [0.95 * r.y_final, 1.05 * r.y_final, 1.075 * r.y_final], rtol=1e-12)
    assert f"settled at {m.settling_time_s:.3g} s" in texts(fig)
    # the time axis is sized to the response: past the settling time, far short of the simulated horizon
    t_end = ax_y.get_xlim()[1]
    assert m.settling_time_s < t_end <= 4 * m.settling_time_s and r.t[-1] == pytest.approx(20.0, abs=DT)
    u = line(ax_u, f"u(t), peak |u| {m.control_peak:.3g}")
    assert u.get_drawstyle() == "steps-post"
    assert_allclose(np.max(np.abs(u.get_ydata())), m.control_peak, rtol=1e-12)
    assert sorted(ln.get_ydata()[0] for ln in ax_u.get_lines() if ln.get_linestyle() == ":") == [-5, 5]


def test_bode_phase_of_a_delay_is_the_closed_form_and_the_axis_stays_near_the_crossover(delayed):
    fig = plots.bode_figure(delayed)
    ax_m, ax_p = fig.axes
    (mag,) = [ln for ln in ax_m.get_lines() if len(ln.get_xdata()) > 2]
    (ph,) = [ln for ln in ax_p.get_lines() if len(ln.get_xdata()) > 2]
    w = ph.get_xdata()
    assert_allclose(mag.get_ydata(), 20 * np.log10(K / w), atol=1e-9)
    assert_allclose(ph.get_ydata(), -90 - np.degrees(w * TAU), atol=1e-7)  # unwrapped, no turn lost or added
    wc, w180 = K, math.pi / (2 * TAU)  # |L(wc)| = 1; -90 - w180 tau = -180 deg
    pm, gm = 90 - math.degrees(wc * TAU), -20 * math.log10(K / w180)
    assert f"PM {pm:.1f}° at {wc:.3g} rad/s" in texts(fig)
    assert f"GM {gm:.1f} dB at {w180:.3g} rad/s" in texts(fig)
    lo, hi = ax_p.get_ylim()
    assert ph.get_ydata().min() < -2500  # the delay's phase runs on ...
    assert -640 < lo <= -540 and hi < 0  # ... the axis does not: 1.5 turns below, with -180 in view


def test_nyquist_circle_of_radius_one_over_ms_around_minus_one(delayed):
    w = np.logspace(-3, 3, 400_001)
    L = K * np.exp(-1j * w * TAU) / (1j * w)
    ms = np.max(np.abs(1 / (1 + L)))  # brute force on a dense grid
    fig = plots.nyquist_figure(delayed, spec=Spec(ms_max=2.0))
    (ax,) = fig.axes
    circle = line(ax, f"1/Ms = {1 / delayed.metrics.ms:.3g} (Ms {delayed.metrics.ms:.3g})")
    x, y = circle.get_xdata(), circle.get_ydata()
    assert_allclose([x[:-1].mean(), y[:-1].mean()], [-1, 0], atol=1e-12)  # 360 points, the first repeated
    assert_allclose(np.hypot(x + 1, y), 1 / ms, rtol=1e-4)
    limit = line(ax, "1/ms_max = 0.5")
    assert_allclose(np.hypot(limit.get_xdata() + 1, limit.get_ydata()), 0.5, rtol=1e-12)
    curve = line(ax, "L(jω), ω > 0")
    z = curve.get_xdata() + 1j * curve.get_ydata()
    wz = np.abs(K / z)  # |L| = K/w gives each point's frequency back
    assert_allclose(z, K * np.exp(-1j * wz * TAU) / (1j * wz), rtol=1e-9)


def test_robust_members_are_labelled_in_every_kind(roll):
    c = controller_from_expr(ROLL_C, dt=DT)
    members = [roll] + [analyze(plant_from_expr(f"{k}*{ROLL}"), c) for k in (0.8, 1.2)]
    result = TuneResult(structure="pid_z", gains={}, controller=c, analyses=tuple(members), solver={},
                        spec=Spec(settling_band_pct=3))
    for kind in ("step", "bode", "nyquist"):
        t = " ".join(texts(plots.figure(result, kind)))
        assert "nominal" in t and "plant 2" in t and "plant 3" in t, kind
    step = plots.step_figure(result)
    assert "settling band ±3 %" in texts(step)  # the result's spec
    assert "plant 2: output y(t) between samples" in texts(step)
    named = plots.figure(members, "bode", labels=["nominal", "light", "heavy"])
    assert {"light", "heavy"} <= set(texts(named))


def test_bad_kind_or_format_names_the_field(roll):
    with pytest.raises(plots.InvalidPlotError, match="step") as e:
        plots.render(roll, "polar")
    assert e.value.field == ("kind",)
    with pytest.raises(plots.InvalidPlotError, match="png or svg") as e:
        plots.render(roll, "step", "gif")
    assert e.value.field == ("fmt",)
    with pytest.raises(TypeError, match="Analysis"):
        plots.figure("not a result")


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_importing_and_drawing_leave_pyplot_and_the_backend_alone():
    """In a fresh interpreter: no pyplot import and no backend chosen by the module, even after drawing."""
    code = (
        "import sys, matplotlib\n"
        "import tuner.analysis.plots as p\n"
        "assert 'matplotlib.pyplot' not in sys.modules, 'imported pyplot'\n"
        "from tuner import analyze, plant_from_expr, controller_from_expr\n"
        "a = analyze(plant_from_expr('1/(s+1)'), controller_from_expr('2+1/s', dt=None))\n"
        "p.render(a, 'all', 'png'); p.render(a, 'step', 'svg')\n"
        "assert 'matplotlib.pyplot' not in sys.modules, 'pyplot after drawing'\n"
        "print(matplotlib.rcParams['backend'])\n"
    )
    env = {**os.environ, "MPLBACKEND": "pdf"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "pdf"
