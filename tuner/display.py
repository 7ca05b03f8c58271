"""Results that show themselves: a few lines for ``repr``, an HTML summary for Jupyter.

``repr`` of a :class:`~tuner.TuneResult` or an :class:`~tuner.analysis.Analysis`: the structure and
gains, the verdict (and what fails), the main metrics; a robust tune lists its plants (a few). The parts
have short reprs too: :class:`~tuner.analysis.Metrics` and :class:`~tuner.analysis.margins.Margins` (two or
three lines), :class:`~tuner.spec.Check` and :class:`~tuner.analysis.response.StepResponse` (one), and a
study's :class:`~tuner.studies.evaluate.LoopEval` (a few). HTML:
the same as tables (gains; checks with required / achieved / met, one column per plant) and thumbnails
of the step response and the Bode plot drawn by :mod:`tuner.analysis.plots` (PNG, base64, no pyplot).
"""

from __future__ import annotations

import math
from typing import Any

from .analysis.html import analysis_html
from .analysis.html import figures_html as _thumbnails
from .text import (
    _CSS,
    _checks_table,
    _e,
    _g,
    _loop_kind,
    _plant_lines,
    _table,
    _verdict_html,
    analysis_repr,
    check_repr,
    design_lines,
    loop_eval_repr,
    margins_repr,
    metrics_line,
    metrics_repr,
    optimality_line,
    step_response_repr,
    verdict,
)

__all__ = ["analysis_repr", "tune_repr", "analysis_html", "tune_html", "metrics_line", "verdict", "metrics_repr",
           "margins_repr", "check_repr", "loop_eval_repr", "step_response_repr", "optimality_line", "design_lines"]


def tune_repr(r: Any) -> str:
    """The few-line ``repr`` of a :class:`~tuner.TuneResult`."""
    gains = ", ".join(f"{k} = {_g(v, 6)}" for k, v in r.gains.items())
    robust = f", {len(r.analyses)} plants" if len(r.analyses) > 1 else ""
    s = r.solver
    lines = [f"TuneResult({r.structure}, {_loop_kind(r.analyses[0])}{robust}: {verdict(r.analyses)})",
             f"  gains    {gains}", *_plant_lines(r.analyses)]
    for e in getattr(r, "at_bounds", ()):
        from .bounds import describe

        lines.append(f"  bound    {describe(e)}")
    if s:
        lines.append(f"  solver   {s.get('method')}, {_g(s.get('wall_time_s', math.nan), 3)} s, {s.get('stop')}, "
                     f"seed {s.get('seed')}")
        if optimality_line(s):
            lines.append(f"  {optimality_line(s)}")
        lines.extend(f"  {d}" for d in design_lines(s))
    rd = getattr(r, "robust", None)
    if rd is not None:
        lines.append(f"  robust   {'nominal model' if rd.k is None else f'{rd.k:g}-sigma set of {rd.n_plants} plants'}"
                     + (f"; {rd.monte_carlo.summary()}" if rd.monte_carlo is not None else ""))
    return "\n".join(lines)


def tune_html(r: Any, *, thumbnails: bool = True) -> str:
    """The HTML summary of a :class:`~tuner.TuneResult` (Jupyter): gains, checks per plant, thumbnails."""
    robust = f", {len(r.analyses)} plants" if len(r.analyses) > 1 else ""
    head = (f"<b>TuneResult</b> {_e(r.structure)}, {_e(_loop_kind(r.analyses[0]))}{_e(robust)}: "
            f"{_verdict_html(r.analyses)}")
    gains = _table(["gain", "value"], [[_e(k), _e(_g(v, 6))] for k, v in r.gains.items()])
    s = r.solver
    solver = (f"<p>solver {_e(s.get('method'))}, {_e(_g(s.get('wall_time_s', math.nan), 3))} s, "
              f"{_e(s.get('stop'))}, seed {_e(s.get('seed'))}</p>"
              + (f"<p class=\"optimality\">{_e(optimality_line(s))}</p>" if optimality_line(s) else "")) if s else ""
    pics = _thumbnails(r) if thumbnails else ""
    from .bounds import describe

    bounds = "".join(f"<p>{_e(describe(e))}</p>" for e in getattr(r, "at_bounds", ()))
    return (f'{_CSS}<div class="tuner-r"><p>{head}</p><div style="display:flex;flex-wrap:wrap;align-items:flex-start">'
            f"{gains}{_checks_table(r.analyses)}</div>{bounds}{pics}{solver}</div>")
