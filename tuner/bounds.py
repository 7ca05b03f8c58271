"""Which of a design's parameters sit on a search bound or a default limit, said in words.

A design whose filter time constant is on its floor, or whose gain is at the edge of the search box, is decided
by that bound, not by the spec's trade-offs: an engineer must know. :func:`at_bounds` lists them for a tuned
result (``TuneResult.at_bounds``); :func:`describe` is the sentence the CLI, the repr, the page and HTTP show.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["at_bounds", "describe", "range_reason", "REL_TOL"]

REL_TOL = 1e-3  # a coordinate within this share of its box's width from an edge is on the bound
LIMIT_TOL = 0.01  # a default limit within 1 % of its value is active


def _fmt(v: float) -> str:
    return f"{v:.4g}"


def at_bounds(problem: Any, space: Any, x: np.ndarray, analyses: Any) -> list[dict[str, Any]]:
    """Parameters of ``x`` on a bound of ``space`` (the search box), and the default limits that decide the
    design: ``{"param", "value", "bound" ("lower"/"upper"), "limit", "rule"}`` (``param`` None for a limit on
    the loop, e.g. the noise budget)."""
    from . import rules
    from .optimize.space import _V_SPAN

    st, spec = problem.structure, problem.spec
    out: list[dict[str, Any]] = []
    v = space.from_params(np.asarray(x, float))
    lo, hi = space.lo, space.hi
    width = np.maximum(hi - lo, 1e-12)
    for i, (p, kind) in enumerate(zip(st.params, st.kinds)):
        if space._ratio_of[i] is not None:
            continue  # an ordering's ratio (a lead's pole over its zero): its box edge is the ordering itself
        val = float(x[i])
        for side, edge in (("lower", lo[i]), ("upper", hi[i])):
            if abs(v[i] - edge) > REL_TOL * width[i]:
                continue
            rng = st.param_range(p) if kind == "gain" else None
            if rng is not None and _on_range(space, i, edge, rng):
                lim = float(space.params(np.where(np.arange(v.size) == i, edge, v))[i])
                rule = _range_rule(st, p, rng)
            elif kind == "gain":
                if abs(edge) < _V_SPAN * 0.999:
                    continue
                lim = float(space.params(np.where(np.arange(v.size) == i, edge, v))[i])
                rule = "the search box (100 times the plant-based unit of this gain): the plant's scale decides"
            else:
                lim = float(space.params(np.where(np.arange(v.size) == i, edge, v))[i])
                if kind == "time" and side == "lower":
                    if problem.dt is not None and spec.filter_nyquist:
                        rule = "the sampling rule (filter corner at most the Nyquist frequency, Tf >= dt/pi) decides"
                    else:
                        rule = "the filter floor (1e-3 dt, or 1e-3/w0 continuous) decides"
                else:
                    rule = "the search box decides"
            out.append({"param": p, "value": val, "bound": side, "limit": lim, "rule": rule})
    if rules.applies(st, spec):
        n = rules.filter_n(st, x)
        if n >= spec.filter_n_max * (1 - LIMIT_TOL):
            kp, kd = x[st.params.index("Kp")], x[st.params.index("Kd")]
            lim = abs(kd / kp) / spec.filter_n_max if kp else math.inf
            beyond = not n <= spec.filter_n_max * (1 + 1e-6)
            out.append({"param": "Tf", "value": float(x[st.params.index("Tf")]), "bound": "lower",
                        "limit": float(lim), "beyond": beyond,
                        "rule": f"the derivative-filter rule N = Td/Tf <= {spec.filter_n_max:g} (N = {n:.4g}) "
                        + ("is violated" if beyond else "decides")})
    for lim in problem.limits:
        if lim["field"] != "mks_max":
            continue
        mks = max(a.metrics.mks for a in analyses)
        if math.isfinite(mks) and mks >= lim["value"] * (1 - LIMIT_TOL):
            beyond = mks > lim["value"] * (1 + 1e-6)
            out.append({"param": None, "value": float(mks), "bound": "upper", "limit": float(lim["value"]),
                        "beyond": beyond, "rule": "the noise budget " + ("is exceeded" if beyond else "decides")
                        + f" ({lim['rule'].removeprefix('noise budget: ')}; Mks = {mks:.4g})"})
    return out


def _on_range(space: Any, i: int, edge: float, rng: tuple[float, float]) -> bool:
    """Whether the box edge ``edge`` of gain coordinate ``i`` is an end of its documented range ``rng``."""
    val = float(space.params(np.full(space.lo.size, edge))[i])
    # (an end at 0 is the firmware gains' sign, the box's own edge: not a range that decides)
    return any(math.isfinite(r) and r != 0 and abs(val - r) <= 1e-9 * abs(r) for r in rng)


def _range_rule(st: Any, p: str, rng: tuple[float, float]) -> str:
    """Why a firmware law's gain on an end of its documented range stops there."""
    from .firmware.names import law_names

    name = law_names(st.firmware, st.axis or "roll").get(p, p)
    hi = f"{rng[1]:g}" if math.isfinite(rng[1]) else "no upper end"
    return (f"the documented range of {name} ({rng[0]:g} to {hi}: the ground station's parameter metadata, which "
            "the exported parameter file keeps to) decides")


def range_reason(st: Any, entries: list[dict[str, Any]], k0: float) -> str | None:
    """A failing design's gain held on an end of its documented range: what that means for the plant and what to
    change (PX4's ``K`` scales P, I and D together; ArduPilot has no such scale), or None."""
    from .firmware.names import law_names
    from .firmware.registry import get_firmware

    hits = [e for e in entries if e.get("param") in st.params and st.param_range(e["param"]) is not None
            and "documented range" in e.get("rule", "")]
    if not hits:
        return None
    names = law_names(st.firmware, st.axis or "roll")
    parts = [f"{names.get(e['param'], e['param'])} at the {e['bound']} end of its documented range "
             f"({_fmt(e['limit'])})" for e in hits]
    low = any(e["bound"] == "lower" for e in hits)
    fw = get_firmware(st.firmware)
    gs = fw.gain_scale
    if gs is not None:
        k = dict(st.fixed).get(gs, 1.0)
        lo_k, hi_k = fw.ranges(st.axis or "roll").get(gs, (0.01, 5.0))
        scale = (f"scale the whole law with {names[gs]} ({gs} = {k:g} now; it multiplies P, I and D, documented "
                 f"range {lo_k:g} to {hi_k:g}): " + (f"a smaller {gs}" if low else f"a larger {gs}") + " moves the "
                 "gains the plant needs into their ranges; set it on the vehicle and tune again with its parameters "
                 "(--params)")
    else:
        scale = fw.no_scale_advice
    need = "less" if low else "more"
    return (f"{' and '.join(parts)}: the design this plant needs lies outside what the vehicle's parameter file can "
            f"hold (this loop needs {need} gain there; the plant's ultimate gain K0 is {k0:.3g}); {scale}")


def describe(entry: dict[str, Any]) -> str:
    """One sentence: "Tf is at its lower bound 0.0127: the sampling rule ... decides"."""
    if entry.get("param") is None:
        where = "beyond" if entry.get("beyond") else "at"
        return f"Mks is {where} its limit {_fmt(entry['limit'])}: {entry['rule']}"
    where = "past" if entry.get("beyond") else "at"
    return f"{entry['param']} is {where} its {entry['bound']} bound {_fmt(entry['limit'])}: {entry['rule']}"
