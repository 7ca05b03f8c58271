"""The study report (Markdown): what was tuned, how it verifies, and how it compares.

Every figure comes from the verifier re-run on the stored gains (:mod:`tuner.studies.evaluate`),
so the report, ``results.json`` and ``tuner verify`` agree. Text from the study file or the user (its description,
notes, file and column names, the storage URL, error messages) is written as text: HTML and Markdown's markup
escaped (:func:`text`), expressions as code spans (:func:`code`), so a report rendered as HTML shows it as written.
"""

from __future__ import annotations

import html
import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .evaluate import LoopEval
from .schema import StudyDef

__all__ = ["render_report", "num", "text", "code"]


def num(v: Any, digits: int = 3) -> str:
    """A figure for a table: ``inf`` as ∞, ``nan``/missing as —."""
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "**NO**"
    if isinstance(v, str):
        v = {"Infinity": math.inf, "-Infinity": -math.inf, "NaN": math.nan}.get(v, v)
        if isinstance(v, str):
            return v
    x = float(v)
    if math.isnan(x):
        return "—"
    if math.isinf(x):
        return "∞" if x > 0 else "−∞"
    if x != 0 and (abs(x) >= 1e5 or abs(x) < 1e-3):
        return f"{x:.{digits}e}"
    return f"{x:.{digits}g}"


def text(s: Any, *, inline: bool = False) -> str:
    """User text as Markdown text: ``&``, ``<``, ``>`` as HTML entities, Markdown's markup characters and ``|``
    backslash-escaped (no tag, link, image, emphasis or table is made of it); ``inline``: on one line.

    Examples
    --------
    >>> from tuner.studies.report import text
    >>> text("<script>x</script> *a* [b](c)")
    '&lt;script&gt;x&lt;/script&gt; \\\\*a\\\\* \\\\[b\\\\](c)'
    """
    t = re.sub(r"([\\`*_\[\]#!~|])", r"\\\1", html.escape(str(s), quote=False))
    return " ".join(t.split("\n")) if inline else t


def code(s: Any) -> str:
    """User text as a Markdown code span (shown as written, HTML included), on one line: fenced by more backticks
    than it holds in a row."""
    t = " ".join(str(s).splitlines())
    fence = "`" * (max((len(m) for m in re.findall(r"`+", t)), default=0) + 1)
    pad = " " if t.startswith("`") or t.endswith("`") else ""
    return f"{fence}{pad}{t}{pad}{fence}"


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(" ".join(c.splitlines()).replace("\\|", "|").replace("|", "\\|") for c in cells) + " |"


def _table(head: list[str], rows: list[list[str]]) -> list[str]:
    return [_row(head), _row(["---"] * len(head)), *(_row(r) for r in rows), ""]


def _gains(g: Mapping[str, float]) -> str:
    return ", ".join(f"{k} = {v:.5g}" for k, v in g.items())


def _ratio(a: float, b: float) -> str:
    if not (math.isfinite(a) and math.isfinite(b)) or b <= 0:
        return "—"
    return f"{a / b:.2f}"


def render_report(
    study: StudyDef, results: Mapping[str, dict[str, Any]], tuned: Mapping[str, LoopEval],
    thesis: Mapping[str, LoopEval], plots: Mapping[str, Mapping[str, Path]], *, out_dir: Path,
    storage: str,
) -> str:
    """The study's report as Markdown, from the loops' stored results, the verified tuned and published
    controllers (``tuned``, ``thesis``) and the plots."""
    L: list[str] = [f"# Study {code(study.name)}", ""]
    if study.description:
        L += [text(study.description), ""]
    n_ok = sum(1 for lp in study.loop if lp.name in tuned and tuned[lp.name].meets_spec)
    L += [f"{n_ok} of {len(study.loop)} loops meet their spec as judged by the verifier. "
          f"Storage: {code(storage)}; seed {study.seed}.", ""]

    L += _identified_section(study, results, plots, out_dir)
    L += _measured_section(study, tuned)
    L += _uncertainty_section(study, results)
    L += ["## Tuned loops", ""]
    rows = []
    for lp in study.order():
        r = results.get(lp.name, {})
        if lp.name not in tuned:
            rows.append([lp.name, lp.structure, f"error: {text(r.get('error', 'no result'))}"] + ["—"] * 9)
            continue
        m = tuned[lp.name].nominal.metrics
        rows.append([lp.name, f"{lp.structure} @ {num(lp.dt)} s" if lp.dt else lp.structure, _gains(r["gains"]),
                     num(m.phase_margin_deg), f"{num(m.gain_margin_db)} / {num(m.gain_margin_lower_db)}",
                     num(m.disk_margin), num(m.ms), num(m.mt), num(m.mks), num(m.control_peak),
                     num(m.bandwidth_rad_s), num(m.overshoot_pct),
                     num(m.settling_time_s), num(tuned[lp.name].meets_spec),
                     f"{num(r.get('wall_time_s'), 2)} s, {r.get('worker', '?')}, epoch {r.get('epoch', '?')}"])
    L += _table(["loop", "structure", "gains", "PM [°]", "GM upper / lower [dB]", "disk margin", "Ms", "Mt", "Mks",
                 "control peak", "bandwidth [rad/s]", "overshoot [%]", "settling [s]", "meets spec", "tuned in, by"],
                rows)
    L += ["Mt = max |T|, Mks = max |C S| (how much sensor noise reaches the actuator), control peak = max |u| "
          "after a unit reference step.", ""]
    L += ["### Disturbance rejection", "", "DRB: the lowest frequency where |S| rises to -3 dB; DRP: max |S| in dB; "
          "the unit load step at the plant input (r = 0): IAE, peak |y|, and when |y| is last above 2 % of its peak "
          "(inf: no integral action against the load).", ""]
    rows = [[lp.name, *(num(getattr(tuned[lp.name].nominal.metrics, k)) for k in (
        "disturbance_rejection_bandwidth_rad_s", "disturbance_rejection_peak_db", "load_iae", "load_peak",
        "load_recovery_s"))] for lp in study.order() if lp.name in tuned]
    L += _table(["loop", "DRB [rad/s]", "DRP [dB]", "load IAE", "load peak", "load recovery [s]"], rows)
    variants = [lp for lp in study.order() if lp.variant_of and lp.name in tuned and lp.variant_of in tuned]
    if variants:
        L += ["## What a spec change costs", "", "Each variant is its base loop (same plant and structure) with "
              "another spec; the ratio is the variant's settling time over the base loop's.", ""]
        rows = []
        for lp in variants:
            a, b = tuned[lp.variant_of].nominal.metrics, tuned[lp.name].nominal.metrics
            changed = ", ".join(f"{k} = {v}" for k, v in lp.spec.model_dump().items()
                                if v != study.get(lp.variant_of).spec.model_dump()[k])
            rows.append([lp.name, lp.variant_of, changed or "—", num(a.control_peak), num(b.control_peak),
                         num(a.mks), num(b.mks), num(a.ms), num(b.ms), num(a.settling_time_s),
                         num(b.settling_time_s), _ratio(b.settling_time_s, a.settling_time_s),
                         num(tuned[lp.name].meets_spec)])
        L += _table(["variant", "of", "spec change", "control peak (base)", "control peak", "Mks (base)", "Mks",
                     "Ms (base)", "Ms", "settling (base) [s]", "settling [s]", "settling ratio", "meets spec"], rows)
    fails = [(lp.name, tuned[lp.name].failing) for lp in study.order() if lp.name in tuned and tuned[lp.name].failing]
    if fails:
        L += ["Failing constraints: " + "; ".join(f"**{n}**: {', '.join(f)}" for n, f in fails) + ".", ""]
    specs = [(lp.name, lp.spec) for lp in study.loop if lp.spec != type(lp.spec)()]
    if specs:
        L += ["Loops with a spec other than the default: " + "; ".join(
            f"{n}: {', '.join(f'{k} = {v}' for k, v in s.model_dump().items() if v != type(s)().model_dump()[k])}"
            for n, s in specs) + ".", ""]

    if thesis:
        L += ["## Thesis as printed beside tuned", "",
              "The printed controllers evaluated as printed by the same verifier (sampled-data loop, output "
              "between samples), not the figures the thesis claims. Ratio = printed settling time / tuned.", ""]
        rows = []
        for lp in study.order():
            if lp.name not in thesis or lp.name not in tuned:
                continue
            a, b = thesis[lp.name].nominal.metrics, tuned[lp.name].nominal.metrics
            rows.append([lp.name, code(lp.thesis_controller), num(lp.thesis_settling_s),
                         num(a.phase_margin_deg), num(a.gain_margin_db), num(a.overshoot_pct), num(a.settling_time_s),
                         f"{num(a.mt)} / {num(a.mks)} / {num(a.control_peak)}", num(thesis[lp.name].meets_spec),
                         num(b.phase_margin_deg), num(b.gain_margin_db), num(b.overshoot_pct), num(b.settling_time_s),
                         f"{num(b.mt)} / {num(b.mks)} / {num(b.control_peak)}",
                         _ratio(a.settling_time_s, b.settling_time_s)])
        L += _table(["loop", "printed controller", "claimed settling [s]", "printed PM [°]", "printed GM [dB]",
                     "printed overshoot [%]", "printed settling [s]", "printed Mt / Mks / control peak",
                     "printed meets spec", "tuned PM [°]", "tuned GM [dB]", "tuned overshoot [%]", "tuned settling [s]",
                     "tuned Mt / Mks / control peak", "settling ratio"], rows)
        unstable = [n for n, e in thesis.items() if not e.nominal.metrics.stable]
        if unstable:
            L += ["Unstable as printed: " + ", ".join(unstable) + " (step metrics not defined).", ""]

    cascades = [lp for lp in study.order() if lp.inner is not None and lp.name in tuned]
    if cascades:
        L += ["## Cascades", "",
              "The outer loop is tuned on the plant it sees at the samples: the tuned inner closed loop in "
              "series with the outer plant (`tuner.analysis.cascade.outer_plant`, exact at the samples). The verifier "
              "evaluates that composite plant at the sample instants; the position between samples comes from "
              "an exact sampled-data simulation of the whole cascade on the continuous models "
              "(`tuner.analysis.cascade.simulate_cascade`), which must also keep the overshoot limit and settle. "
              "Ratio = inner bandwidth / outer bandwidth.", ""]
        rows = []
        for lp in cascades:
            e = tuned[lp.name]
            c = e.cascade_dict() or {}
            bs = c.get("between_samples") or {}
            rows.append([lp.name, lp.inner or "", num(c.get("inner_bandwidth_rad_s")),
                         num(c.get("outer_bandwidth_rad_s")), num(c.get("bandwidth_ratio"), 2),
                         num(bs.get("overshoot_pct")), num(bs.get("settling_time_s")),
                         num(e.meets_spec), c.get("evaluation") or ""])
        L += _table(["outer loop", "inner loop", "inner bandwidth [rad/s]", "outer bandwidth [rad/s]", "ratio",
                     "overshoot between samples [%]", "settling between samples [s]", "cascade meets spec",
                     "evaluation"], rows)

    notes = [(lp.name, lp.note) for lp in study.order() if lp.note]
    if notes:
        L += ["## Notes", ""] + [f"- **{n}**: {text(t, inline=True)}" for n, t in notes] + [""]

    L += ["## Plots", "", "Step response (continuous output and samples, settling band), Bode (gain and "
          "phase margins marked), Nyquist (unit circle and −1).", ""]
    for lp in study.order():
        if lp.name not in plots:
            continue
        L += [f"### {lp.name}", ""]
        for kind in ("step", "bode", "nyquist"):
            p = plots[lp.name][kind]
            L.append(f"![{lp.name} {kind}]({p.relative_to(out_dir).as_posix()})")
        L.append("")
    return "\n".join(L).rstrip() + "\n"


def _identified_section(study: StudyDef, results: Mapping[str, dict[str, Any]],
                        plots: Mapping[str, Mapping[str, Path]], out_dir: Path) -> list[str]:
    """Loops whose plant is a flight log: the fit (band, J, bounds, held-out check) and its plot."""
    loops = [lp for lp in study.order() if lp.data is not None]
    if not loops:
        return []
    L = ["## Identified plants", "",
         "Plants given as flight logs were identified before tuning (`tuner.identify`): frequency response and "
         "coherence from composite Welch windows, a transfer function fitted over the coherent band by CIFER's "
         "cost J (<= 50 good, <= 100 acceptable), Cramér–Rao bounds (guideline <= 20 %), and a time-domain check: "
         "the model simulated on a verification log, the held-out end of the log, or (when that end is the top of "
         "the sweep) the fitted log, Theil's inequality coefficient (guideline <= 0.3) judged beside the noise "
         "floor the data show (the rms error over the rms a perfect model would leave): good (Theil <= 0.3, error "
         "within 1.5 times the floor), fair (Theil <= 0.3, error above), noise-limited (Theil above, error within), "
         "poor (both above). J's verdict and the check's are reported side by side. The delay is used as "
         "fitted (exact in the sampled-data loop: the ZOH of the delayed plant), unless `data.delay_step` restricts "
         "it. The loops below were tuned and verified on these models.", ""]
    rows, notes = [], []
    for lp in loops:
        ident = results.get(lp.name, {}).get("identification")
        d = lp.data
        src = f"{code(d.file)}: {text(d.input)} → {text(d.output)}" if d else ""
        if not ident:
            rows.append([lp.name, src, f"error: {text(results.get(lp.name, {}).get('error', 'no result'))}"]
                        + ["—"] * 7)
            continue
        unc = ident.get("uncertainty", {})
        worst = max(unc.items(), key=lambda kv: _as_float(kv[1].get("cr_bound_pct")), default=None)
        val = ident.get("validation") or {}
        band = ident.get("band_rad_s") or [None, None]
        rows.append([lp.name, src, code(ident.get("plant", "")), f"{num(band[0])}–{num(band[1])}",
                     num(ident.get("cost")), ident.get("quality", "—"),
                     f"{num(worst[1].get('cr_bound_pct'))} ({worst[0]})" if worst else "—",
                     f"{ident.get('check', '—')} ({val.get('source', '—')})" if val else "none",
                     num(val.get("theil_u")), num(val.get("noise_ratio"))])
        notes += [f"- **{lp.name}**: {text(w, inline=True)}" for w in ident.get("warnings", [])]
    L += _table(["loop", "log", "identified model", "band [rad/s]", "J", "J's verdict", "largest CR bound [%]",
                 "time-domain check (on)", "Theil", "rms error / noise floor"], rows)
    if notes:
        L += ["Warnings of the fits:", "", *notes, ""]
    for lp in loops:
        p = plots.get(lp.name, {}).get("fit")
        if p is not None:
            L += [f"![{lp.name} fit]({p.relative_to(out_dir).as_posix()})", ""]
    return L


def _measured_section(study: StudyDef, tuned: Mapping[str, LoopEval]) -> list[str]:
    """Data loops judged on the airframe: the tuned loop on the identification's measured response (the margins by
    the worst end of their error range, not measured where the crossing lies outside the coherent data) and the
    identification's rating; the verdict in words."""
    loops = [lp for lp in study.order() if lp.data is not None and lp.inner is None and lp.name in tuned
             and tuned[lp.name].nominal.measured is not None]
    if not loops:
        return []
    L = ["## On the airframe", "",
         "Each data loop's tuned controller on the identification's measured frequency response (the coherent "
         "points; `tuner.analysis.measured`): the phase and gain margins with the range their random error spans. "
         "They are checks: a margin below the spec at the worst end of its range, or not measured (its crossing "
         "outside the coherent data), fails the loop; an identification rated below acceptable makes its verdict "
         "one on the model only.", ""]
    rows = []
    for lp in loops:
        e = tuned[lp.name]
        m = e.nominal.measured.measured

        def fig(v: float, rng: tuple[float, float]) -> str:
            return "not measured" if math.isnan(v) else f"{num(v)} ({num(rng[0])}–{num(rng[1])})"

        q = next((c.achieved for c in e.nominal.checks if c.name == "identification_quality"), "—")
        rows.append([lp.name, str(q), fig(m.phase_margin_deg, m.phase_margin_range),
                     fig(m.gain_margin_db, m.gain_margin_range), e.verdict])
    L += _table(["loop", "identification", "measured PM [°] (range)", "measured GM [dB] (range)", "verdict"], rows)
    return L


def _uncertainty_section(study: StudyDef, results: Mapping[str, dict[str, Any]]) -> list[str]:
    """Data loops judged beyond the identified model: on the true plant of a synthetic log (``true_plant``) and on
    draws from the identified parameters' covariance (the Monte Carlo check)."""
    loops = [lp for lp in study.order() if lp.data is not None and (lp.true_plant is not None or lp.robust is not None
                                                                      or lp.monte_carlo)]
    if not loops:
        return []
    L = ["## Beyond the identified model", "",
         "Each controller was tuned on the identified model (with `robust = K`: on the plant set spanned by the "
         "identified parameters' K-sigma Cramér–Rao bounds, the nominal plus every corner of the dominant "
         "parameters; `tuner.robust`). Here the verifier judges it on the plant the log was made from (the "
         "synthetic log's truth, `true_plant`) and on draws from the identified parameters' covariance (the "
         "Monte Carlo check: the share of draws meeting the whole spec, and the worst margins).", ""]
    rows = []
    for lp in loops:
        r = results.get(lp.name, {})
        if "error" in r or not r:
            rows.append([lp.name, f"error: {text(r.get('error', 'no result'))}"] + ["—"] * 9)
            continue
        rb = r.get("robust")
        design = f"{num(rb['k'])}-sigma set, {rb['n_plants']} plants" if rb else "nominal model"
        t = r.get("true_plant")
        tm = t["metrics"] if t else {}
        mc = r.get("monte_carlo")
        mc_s = (f"{100 * float(mc['fraction_meeting_spec']):.1f} % of {mc['n']}" if mc else "—")
        worst = mc["worst"] if mc else {}
        rows.append([lp.name, design, code(t["plant"]) if t else "—", num(tm.get("phase_margin_deg")),
                     num(tm.get("gain_margin_db")), num(tm.get("overshoot_pct")), num(tm.get("settling_time_s")),
                     num(t["meets_spec"]) if t else "—", mc_s,
                     f"{num(worst.get('phase_margin_deg'))} / {num(worst.get('gain_margin_db'))}" if mc else "—",
                     num(worst.get("overshoot_pct")) if mc else "—"])
    L += _table(["loop", "designed for", "true plant", "PM [deg]", "GM [dB]", "overshoot [%]", "settling [s]",
                 "meets spec (true)", "Monte Carlo: meet spec", "worst PM / GM", "worst overshoot [%]"], rows)
    return L


def _as_float(v: Any) -> float:
    try:
        x = float({"Infinity": math.inf, "-Infinity": -math.inf, "NaN": math.nan}.get(v, v))
    except (TypeError, ValueError):
        return -math.inf
    return -math.inf if math.isnan(x) else x
