"""Results that show themselves (issue 14): a compact ``repr``, ``_repr_html_`` with gains, checks and
thumbnails, ``.plot()`` returning a Figure without pyplot; numpydoc docstrings listing every parameter; the
README's "From Python" block run as a doctest.
"""

from __future__ import annotations

import base64
import doctest
import inspect
import re
import subprocess
import sys
from pathlib import Path

import pytest
from matplotlib.figure import Figure
from quadrotor import DT, ROLL, ROLL_C

from tuner import analyze, controller_from_expr, identify, plant_from_expr, tune

ROOT = Path(__file__).resolve().parents[2]
PLANT = plant_from_expr("4/(s^2+2*s+4)")


@pytest.fixture(scope="module")
def res():
    return tune(PLANT, structure="pi", dt=0.05, time_budget_s=120)  # converges (~3 s): never cut by the clock


@pytest.fixture(scope="module")
def robust():
    plants = [plant_from_expr(f"{k}/(s^2+2*s+4)") for k in (4, 5, 3, 4.5, 3.5, 6)]
    return tune(plants, structure="pi", dt=0.05, time_budget_s=1)  # only its layout is tested: any verified result


@pytest.fixture(scope="module")
def failing():
    return analyze(PLANT, controller_from_expr("50*(1+1/s)", dt=None))


# -- repr -------------------------------------------------------------------------------------------------------

def test_repr_is_a_few_lines_with_gains_verdict_and_metrics(res):
    text = repr(res)
    lines = text.splitlines()
    assert 3 <= len(lines) <= 6, text
    assert lines[0].startswith("TuneResult(pi, ") and "dt = 0.05 s" in lines[0]
    assert ("meets the spec" in lines[0]) == res.meets_spec
    for k, v in res.gains.items():
        assert f"{k} = {v:.6g}" in text
    m = res.analyses[0].metrics
    assert f"PM {m.phase_margin_deg:.3g} deg" in text and f"settling {m.settling_time_s:.3g} s" in text
    assert f"GM {m.gain_margin_db:.3g} dB" in text and f"peak |u| {m.control_peak:.3g}" in text
    assert str(res) == text


def test_repr_of_a_failing_analysis_names_what_fails(failing):
    text = repr(failing)
    assert len(text.splitlines()) == 3
    assert "does NOT meet the spec" in text
    for c in failing.failing:
        assert c.name in text and f"{c.achieved:.4g}" in text
    assert "closed-loop poles" in text


def test_robust_repr_lists_a_few_plants_and_counts_the_rest(robust):
    text = repr(robust)
    assert "6 plants" in text.splitlines()[0]
    assert "nominal" in text and "plant 4" in text and "plant 5" not in text
    assert re.search(r"\.\.\. and 2 more plants \(\d+ failing\)", text)
    assert len(text.splitlines()) <= 9  # (8 + the optimality line)


# -- HTML -------------------------------------------------------------------------------------------------------

def test_html_has_gains_checks_and_png_thumbnails(res):
    h = res._repr_html_()
    for k, v in res.gains.items():
        assert f"<td class=\"l\">{k}</td><td>{v:.6g}</td>" in h
    a = res.analyses[0]
    for c in a.checks:
        assert f">{c.name}<" in h
    assert h.count("&#10003;") == sum(c.ok for c in a.checks)
    assert h.count("&#10007;") == sum(not c.ok for c in a.checks)
    imgs = re.findall(r'src="data:image/png;base64,([^"]+)"', h)
    assert len(imgs) == 2
    assert all(base64.b64decode(i)[:8] == b"\x89PNG\r\n\x1a\n" for i in imgs)


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_robust_html_has_a_column_per_plant(robust):
    h = robust._repr_html_()
    assert "<th>nominal</th>" in h and "<th>plant 6</th>" in h
    n_checks = len(robust.analyses[0].checks)
    marks = h.count("&#10003;") + h.count("&#10007;")
    assert marks == n_checks * 6


def test_analysis_html_marks_the_failures(failing):
    h = failing._repr_html_()
    assert h.count("&#10007;") == len(failing.failing) and "does NOT meet the spec" in h


# -- plot -------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["all", "step", "bode", "nyquist"])
def test_plot_returns_a_figure(res, kind):
    fig = res.plot(kind)
    assert isinstance(fig, Figure) and fig.get_axes()
    fig2 = res.analyses[0].plot(kind)
    assert isinstance(fig2, Figure) and fig2.get_axes()


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_no_pyplot_and_no_backend_chosen():
    """Results are drawn without pyplot and without choosing a backend (a notebook's stays its own)."""
    code = """
import sys, matplotlib
before = dict.__getitem__(matplotlib.rcParams, "backend")
from tuner import analyze, controller_from_expr, plant_from_expr
a = analyze(plant_from_expr("4/(s^2+2*s+4)"), controller_from_expr("1+2/s", dt=None))
a.plot(); a._repr_html_(); repr(a)
after = dict.__getitem__(matplotlib.rcParams, "backend")
print("matplotlib.pyplot" in sys.modules, before is after)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "True"], out.stdout


# -- docstrings -------------------------------------------------------------------------------------------------

def _documented(doc: str) -> set[str]:
    """Parameter names of a numpydoc "Parameters" section (``a, b : type`` lines)."""
    sec = doc.split("Parameters\n    ----------\n", 1)[1].split("\n\n    Returns", 1)[0]
    names = set()
    for line in sec.splitlines():
        m = re.match(r"^    (\w[\w, ]*?) ?(?::|$)", line)
        if m and not line.startswith("     "):
            names.update(n.strip() for n in m.group(1).split(","))
    return names


@pytest.mark.parametrize("fn", [tune, analyze, identify], ids=["tune", "analyze", "identify"])
def test_numpydoc_lists_every_parameter(fn):
    doc = inspect.getdoc(fn) and fn.__doc__
    assert "Parameters\n    ----------" in doc and "Returns\n    -------" in doc
    params = set(inspect.signature(fn).parameters)
    assert params <= _documented(doc), params - _documented(doc)


# -- the README's "From Python" ---------------------------------------------------------------------------------

@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_readme_from_python_block_runs():
    text = (ROOT / "README.md").read_text()
    section = text.split("## From Python", 1)[1].split("\n## ", 1)[0]
    block = section.split("```pycon\n", 1)[1].split("```", 1)[0]
    assert len([ln for ln in block.splitlines() if ln.startswith(">>> ")]) == 5
    test = doctest.DocTestParser().get_doctest(block, {}, "README From Python", "README.md", 0)
    runner = doctest.DocTestRunner(optionflags=doctest.NORMALIZE_WHITESPACE)
    runner.run(test)
    assert runner.failures == 0 and runner.tries == 5


def test_the_thesis_roll_loop_shows_itself():
    a = analyze(plant_from_expr(ROLL), controller_from_expr(ROLL_C, dt=DT))
    assert "sampled-data loop (ZOH) at dt = 0.04 s" in repr(a)
