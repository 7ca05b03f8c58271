"""The text of results, for every layer: short ``repr`` lines and the HTML tables (bottom layer: imports nothing of
the package; the objects are read by their attributes).

:class:`~tuner.analysis.Metrics`, :class:`~tuner.analysis.margins.Margins`, :class:`~tuner.spec.Check`,
:class:`~tuner.analysis.response.StepResponse` and :class:`~tuner.analysis.Analysis` format themselves with these;
:mod:`tuner.display` adds a tune's text and HTML (its bounds and thumbnails) and re-exports these.
"""

from __future__ import annotations

import html
import math
from typing import Any

__all__ = ["metrics_line", "verdict", "verdict_met", "verdict_basis", "changes_line", "metrics_repr", "margins_repr",
           "check_repr", "loop_eval_repr", "step_response_repr", "analysis_repr", "optimality_line", "design_lines"]

_MAX_LISTED = 4  # plants listed in a repr; the rest counted


def _g(v: Any, digits: int = 4) -> str:
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, float)):
        if math.isnan(v):
            return "n/a"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return f"{v:.{digits}g}"
    return str(v)


def metrics_line(a: Any) -> str:
    """The main metrics of one analysis on one line."""
    m = a.metrics
    if not m.stable:
        return "closed loop UNSTABLE"
    gm = f"GM {_g(m.gain_margin_db, 3)} dB"
    if math.isfinite(m.gain_margin_lower_db):
        gm += f" (lower {_g(m.gain_margin_lower_db, 3)} dB)"
    return " | ".join([f"PM {_g(m.phase_margin_deg, 3)} deg at {_g(m.crossover_rad_s, 3)} rad/s", gm,
                       f"overshoot {_g(m.overshoot_pct, 3)} %", f"settling {_g(m.settling_time_s, 3)} s",
                       f"Ms {_g(m.ms, 3)}", f"peak |u| {_g(m.control_peak, 3)}"])


def _freq_lines(m: Any) -> list[str]:
    gm = f"GM {_g(m.gain_margin_db, 3)} dB"
    if math.isfinite(m.gain_margin_lower_db):
        gm += f" (lower {_g(m.gain_margin_lower_db, 3)} dB)"
    return [f"PM {_g(m.phase_margin_deg, 4)} deg at {_g(m.crossover_rad_s, 4)} rad/s, {gm}",
            f"  Ms {_g(m.ms, 3)} | Mt {_g(m.mt, 3)} | Mks {_g(m.mks, 3)} | bandwidth {_g(m.bandwidth_rad_s, 3)} rad/s"
            f" | disk margin {_g(m.disk_margin, 3)}"]


def metrics_repr(m: Any) -> str:
    """A :class:`~tuner.analysis.Metrics` in three lines: margins, peaks, step metrics."""
    head, peaks = _freq_lines(m)
    step = (f"  step: overshoot {_g(m.overshoot_pct, 3)} % | settling {_g(m.settling_time_s, 3)} s | rise "
            f"{_g(m.rise_time_s, 3)} s | error {_g(m.steady_state_error, 3)} | peak |u| {_g(m.control_peak, 3)}")
    load = (f"  disturbance: rejection bandwidth {_g(m.disturbance_rejection_bandwidth_rad_s, 3)} rad/s | peak "
            f"{_g(m.disturbance_rejection_peak_db, 3)} dB | load step: IAE {_g(m.load_iae, 3)} | peak "
            f"{_g(m.load_peak, 3)} | recovered {_g(m.load_recovery_s, 3)} s")
    return f"Metrics({'stable' if m.stable else 'UNSTABLE'}, {head}\n{peaks}\n{step}\n{load})"


def margins_repr(m: Any) -> str:
    """A :class:`~tuner.analysis.margins.Margins` in two lines."""
    head, peaks = _freq_lines(m)
    if math.isfinite(m.phase_crossover_rad_s):
        head += f" at {_g(m.phase_crossover_rad_s, 4)} rad/s"
    return f"Margins({head}\n{peaks})"


def step_response_repr(r: Any) -> str:
    """A :class:`~tuner.analysis.response.StepResponse` on one line (its arrays summarised)."""
    t = r.t
    span = f"{t.size} points over {_g(float(t[0]))}..{_g(float(t[-1]))} s" if t.size else "no points"
    where = "between samples" if r.between_samples else "at the sample instants"
    samples = f", {r.t_samples.size} samples" if r.t_samples is not None else ""
    return f"StepResponse({span}{samples}, final value {_g(r.y_final)}, {where}; arrays t, y, u)"


def check_repr(c: Any) -> str:
    """A :class:`~tuner.spec.Check` on one line: ``Check(phase_margin_deg 71.2 >= 60: ok)``."""
    state = "ok" if c.ok else f"FAILS by {_g(c.violation)}"
    return f"Check({c.name} {_g(c.achieved)} {c.op} {_g(c.required)}: {state})"


#: the checks of a result from an identification that judge the airframe, not the model (tuner.analysis.measured)
_MEASURED = {"measured_phase_margin_deg": ("phase margin", " deg"), "measured_gain_margin_db": ("gain margin", " dB"),
             "measured_ms": ("Ms", "")}
_IDENTIFICATION = "identification_quality"


def _failing(analyses: Any) -> list[str]:
    seen, out = set(), []
    for a in analyses:
        for c in a.failing:
            if c.name not in seen and c.name not in _MEASURED and c.name != _IDENTIFICATION:
                seen.add(c.name)
                out.append(f"{c.name} = {_g(c.achieved)} (required {c.op} {_g(c.required)})")
    return out


def _airframe(analyses: Any) -> tuple[list[Any], list[Any], Any]:
    """The measured-response checks, those failing, and the identification's check (None without one)."""
    checks = [c for a in analyses for c in a.checks]
    measured = [c for c in checks if c.name in _MEASURED]
    ident = next((c for c in checks if c.name == _IDENTIFICATION), None)
    return measured, [c for c in measured if not c.ok], ident


def _measured_text(c: Any) -> str:
    what, unit = _MEASURED[c.name]
    if isinstance(c.achieved, float) and math.isnan(c.achieved):
        return f"{what} not measured (its crossing lies outside the coherent data)"
    end = "lower" if c.op == ">=" else "upper"
    return f"{what} {_g(c.achieved)}{unit} at the {end} end of its error range (required {c.op} {_g(c.required)}{unit})"


def verdict(analyses: Any) -> str:
    """The verdict in words: ``meets the spec``, or ``does NOT meet the spec:`` and every failing check (once) with
    its values. A result from an identification (its checks on the measured response and of the identification's
    rating, :mod:`tuner.analysis.measured`) is judged on the airframe too: ``meets the spec, on the model and on the
    measured response``; ``does NOT meet the spec on the measured response: ...`` (a figure below the spec at the
    worst end of its error range, or not measured); ``... on the model only: the identification is rated poor``."""
    fails = _failing(analyses)
    measured, mfails, ident = _airframe(analyses)
    poor = ident is not None and not ident.ok
    on_data = "; ".join(_measured_text(c) for c in mfails)
    if fails:
        text = "does NOT meet the spec: " + "; ".join(fails) + (f"; nor on the measured response: {on_data}"
                                                                if mfails else "")
    elif mfails:
        text = f"does NOT meet the spec on the measured response: {on_data}"
    elif poor:
        text = "meets the spec on the model only"
    else:
        text = "meets the spec" + (", on the model and on the measured response" if measured else "")
    if poor:
        text += (f"{'; on the model only' if fails or mfails else ''}: the identification is rated {ident.achieved} "
                 "(below acceptable): neither its model nor its measured response is confirmed to be the airframe")
    return text


def verdict_basis(analyses: Any) -> str:
    """What a verdict rests on: ``model`` (no flight data), ``model and measured response`` (checked on an
    identification's measured response too), ``model only`` (its identification is rated below acceptable)."""
    measured, _, ident = _airframe(analyses)
    if ident is not None and not ident.ok:
        return "model only"
    return "model and measured response" if measured else "model"


def changes_line(changes: Any) -> str:
    """The changes against the vehicle's current tune by more than 3x (:func:`tuner.tuning.big_changes`) in one
    sentence, or ``""``."""
    if not changes:
        return ""
    return ("the proposal changes the vehicle's current tune by more than 3x: " + "; ".join(changes)
            + ": fly it in steps from the current tune, or check the identification (its units, its band, its rating)")


def verdict_met(analyses: Any) -> bool:
    """Every check holds on every analysis (the model's, the measured response's, the identification's)."""
    return all(c.ok for a in analyses for c in a.checks)


def _loop_kind(a: Any) -> str:
    lp = a.loop
    if lp.dt is None:
        return "continuous loop" + (f", delay {_g(lp.delay_s)} s" if lp.delay_s else "")
    kind = "discrete plant" if lp.plant.is_discrete else "sampled-data loop (ZOH)"
    return f"{kind} at dt = {_g(lp.dt)} s" + (f", delay {lp.delay_samples} samples" if lp.delay_samples else "")


def _plant_lines(analyses: Any) -> list[str]:
    n = len(analyses)
    if n == 1:
        return [f"  metrics  {metrics_line(analyses[0])}"]
    lines = []
    for i, a in enumerate(analyses[:_MAX_LISTED]):
        mark = "" if a.meets_spec else "  [fails]"
        lines.append(f"  {'nominal ' if i == 0 else f'plant {i + 1}':8} {metrics_line(a)}{mark}")
    if n > _MAX_LISTED:
        rest = analyses[_MAX_LISTED:]
        bad = sum(not a.meets_spec for a in rest)
        lines.append(f"  ... and {len(rest)} more plants ({bad} failing)")
    return lines


def design_lines(s: dict[str, Any] | None) -> list[str]:
    """What the stages after the search did to a 2-DOF design (``solver["load_design"]``, ``solver["setpoint_stage"]``),
    one line each, in words."""
    out = []
    s = s or {}
    ld = s.get("load_design")
    if ld:
        k = ld["integral"]
        b, a = ld["before"], ld["after"]
        moved = ", ".join(f"{p} {_g(b[p], 4)} -> {_g(a[p], 4)}" for p in a if p != k and a[p] != b[p])
        out.append(f"design: the fastest reference step (settling {_g(ld['fastest_settling_s'], 4)} s, worst over the "
                   f"plants), then its integral gain raised for the load to the balance of the two (the least of the "
                   f"later of the settling and the load recovery over 5, over {ld['levels']} integral levels): "
                   f"{k} {_g(b[k], 4)} -> {_g(a[k], 4)}" + (f" ({moved})" if moved else "")
                   + f", load IE {_g(ld['objective_before'], 4)} -> {_g(ld['objective_after'], 4)}, settling "
                   f"{_g(ld['settling_after_s'], 4)} s, balance {_g(ld['balance'], 4)} s")
    sp = s.get("setpoint_stage")
    if sp and sp["after"] != sp["before"]:
        ch = ", ".join(f"{p} {_g(sp['before'][p], 4)} -> {_g(sp['after'][p], 4)}" for p in sp["params"])
        out.append(f"design: the feedback for the load, then the setpoint path alone for the reference step: {ch}, "
                   f"settling {_g(sp['settling_before_s'], 4)} -> {_g(sp['settling_after_s'], 4)} s")
    return out


def optimality_line(s: dict[str, Any] | None) -> str:
    """One line on what the search knows about how close its answer is (``solver["optimality"]``)."""
    o = (s or {}).get("optimality")
    if not o:
        return ""
    parts = [f"{o['basins']} basin{'s' if o['basins'] != 1 else ''} refined"]
    n = o.get("restarts", 0)
    ev = o.get("evidence") or {}
    if n:
        imp = o.get("restart_improved", 0)
        parts.append(f"{n} independent restart{'s' if n != 1 else ''}, " +
                     ("none found better" if not imp else f"{imp} found better"
                      + (f" (round 0 was {o['round0_gap'] * 100:.2g} % worse)" if o.get("round0_gap") else "")))
        if ev.get("refinements"):
            parts.append(f"{ev['refound']} re-found the answer's basin")
    else:
        parts.append("no independent restart")
    gap = o.get("gap")
    parts.append("no distinct alternative" if gap is None else f"best distinct alternative {gap * 100:+.3g} %")
    if ev.get("unseen") is not None:
        w, n = ev.get("basins", 0), ev["refinements"]
        parts.append(f"unreached-basin estimate {ev['unseen']:.2g} (multistart's Bayesian rule, w(w+1)/(n(n-1)): "
                     f"{w} optim{'a' if w != 1 else 'um'} reached by {n} random restart draw{'s' if n != 1 else ''}"
                     f"; level {ev['level']:.2g})")
    claim = o.get("claim") or ("converged" if s.get("stop") == "converged" else "budget")
    verdict_ = {"converged": "converged", "not confirmed": "not confirmed"}.get(claim, "budget used (not confirmed)")
    return (f"optimality ({o.get('effort', 'default')} effort, {verdict_}): " + ", ".join(parts)
            + (_unconfirmed(o) if claim == "not confirmed" else _cut(s) + _left(s, o)))


def _unconfirmed(o: dict[str, Any]) -> str:
    """Why a search that was not cut does not claim convergence, and what more search would check."""
    why = []
    ev = o.get("evidence") or {}
    if not o.get("restarts"):
        why.append("no independent restart ran")
    elif not o.get("local"):
        why.append("without the local refinement the restarts reach no basins to count")
    else:
        if ev.get("refound", 0) < ev.get("refind", 2):
            why.append(f"{ev.get('refound', 0)} restart{'s' if ev.get('refound', 0) != 1 else ''} re-found the "
                       f"answer's basin, of the {ev.get('refind', 2)} the claim needs")
        if ev.get("unseen") is None or ev["unseen"] > ev.get("level", 0.2):
            est = "unknown" if ev.get("unseen") is None else f"{ev['unseen']:.2g}"
            why.append(f"the estimated share of the basins the restarts' draws have not reached is {est}, above the "
                       f"{ev.get('level', 0.2):.2g} level")
        if o.get("stop") == "work":
            why.append(f"the {o.get('max_restarts')} restarts the effort affords have run")
    more = "more starts and restarts" if o.get("effort") != "thorough" else "a longer search"
    return (f"; not confirmed: {' and '.join(why) or 'the evidence is thin'}: a better design may exist; "
            + ("thorough effort" if o.get("effort") != "thorough" else "a larger n_starts") + f" ({more}) checks it")


def _cut(s: dict[str, Any]) -> str:
    """What the time cap cut (``solver["cut"]``), if it cut anything."""
    c = (s or {}).get("cut")
    if not c:
        return ""
    return (f"; cut by the time cap ({c['cap_s']:.3g} s) at {c['step'] or 'the search'}, after "
            f"{c['restarts_done']} of at most {c['restarts_max']} restarts")


def _left(s: dict[str, Any], o: dict[str, Any]) -> str:
    """What a search the budget ended may have left on the table, as far as it can tell."""
    if s.get("stop") == "converged":
        return ""
    wall = float(s.get("wall_time_s") or 0.0)
    if o.get("unbuilt_s"):
        what = (f"; the budget ended before the local refinement could build its NLP (about {o['unbuilt_s']:.2g} s "
                "more): the answer is the global search's alone, typically well short of the refined optimum; ")
        if s.get("budget_auto"):
            return what + ("the build did not fit the default budget's 60 s cap: a larger time_budget_s (--budget) "
                           "would refine it")
        more = min(3600, math.ceil(wall + 2.0 * o["unbuilt_s"] + 5.0))
        return what + (f"the default budget (it counts work, within a 60 s cap) or time_budget_s={more} (--budget "
                       f"{more}) would refine it")
    if o.get("local") and not o.get("nlp_solves"):
        if o.get("contained_nlp_solves"):
            return ("; this structure's own refinement never ran (the contained structure's search did): the answer "
                    "is at best that structure's")
        return "; the local refinement never ran: the answer is the global search's alone"
    gain = o.get("last_gain")
    if gain is None:
        return "; no round completed after the first: what more search would find is unknown"
    if gain > 0:
        return (f"; the last round still improved the design by {gain * 100:.2g} %: more budget would likely find "
                "more")
    return "; the last completed round found nothing better: little is likely left, but no restart confirmed it"


def loop_eval_repr(e: Any) -> str:
    """A study's :class:`~tuner.studies.evaluate.LoopEval`: the loop, the verdict, each plant's metrics (a few)."""
    robust = f", {len(e.analyses)} plants" if len(e.analyses) > 1 else ""
    state = e.verdict  # (a data loop's on the measured response too, a cascade's between samples)
    return "\n".join([f"LoopEval({e.loop.name}, {_loop_kind(e.analyses[0])}{robust}: {state})",
                      *_plant_lines(e.analyses)])


def analysis_repr(a: Any) -> str:
    """The few-line ``repr`` of an :class:`~tuner.analysis.Analysis`."""
    p = a.poles
    size = abs(p) if a.loop.dt is not None else p.real
    where = "max |z|" if a.loop.dt is not None else "max Re s"
    poles = f"{p.size} closed-loop poles, {where} = {_g(float(size.max()), 4)}" if p.size else "no closed-loop poles"
    return "\n".join([f"Analysis({_loop_kind(a)}: {verdict([a])})", f"  metrics  {metrics_line(a)}",
                      f"  poles    {poles}"])


# -- HTML -------------------------------------------------------------------------------------------------

_CSS = ("<style>.tuner-r table{border-collapse:collapse;margin:4px 12px 8px 0;font-size:12px}"
        ".tuner-r td,.tuner-r th{border:1px solid #ccc;padding:2px 6px;text-align:right}"
        ".tuner-r th{background:#f3f3f3}.tuner-r td.l,.tuner-r th.l{text-align:left}"
        ".tuner-r .ok{color:#1a7f37}.tuner-r .bad{color:#c62828;font-weight:bold}</style>")


def _e(v: Any) -> str:
    return html.escape(str(v))


def _table(head: list[str], rows: list[list[str]], left: int = 1) -> str:
    """``head`` (plain text) and ``rows`` (HTML cells); the first ``left`` columns aligned left."""
    def cls(i: int) -> str:
        return ' class="l"' if i < left else ""

    th = "".join(f"<th{cls(i)}>{_e(h)}</th>" for i, h in enumerate(head))
    body = "".join("<tr>" + "".join(f"<td{cls(i)}>{c}</td>" for i, c in enumerate(r)) + "</tr>" for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def _checks_table(analyses: Any) -> str:
    names = ["nominal", *(f"plant {i + 1}" for i in range(1, len(analyses)))] if len(analyses) > 1 else ["achieved"]
    rows = []
    for c in analyses[0].checks:  # (the checks on the measured response are the nominal plant's alone)
        cells = [_e(c.name), _e(f"{c.op} {_g(c.required)}")]
        for a in analyses:
            ck = next((k for k in a.checks if k.name == c.name), None)
            if ck is None:
                cells.append("")
                continue
            mark = '<span class="ok">&#10003;</span>' if ck.ok else '<span class="bad">&#10007;</span>'
            cells.append(f"{_e(_g(ck.achieved))} {mark}")
        rows.append(cells)
    head = ["constraint", "required", *names] if len(analyses) > 1 else ["constraint", "required", "achieved (met)"]
    return _table(head, rows)


def _verdict_html(analyses: Any) -> str:
    v = verdict(analyses)
    cls = "ok" if verdict_met(analyses) else "bad"
    return f'<span class="{cls}">{_e(v)}</span>'
