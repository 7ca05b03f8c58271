"""Code for the target from a :class:`~tuner.export.discrete.DifferenceEquation`: C99, Python, plain text.

All three say the same thing: the text (:func:`to_text`) is the comment at the head of the C file and
the docstring of the Python class. Coefficients are written with ``repr`` (the shortest decimal that
reads back to the same double), so the C, the Python and the library hold the same numbers.

C99: ``N_state``, ``void N_init(N_state *s)`` (zero state), ``double N_update(N_state *s, double e)``
(one sample: the error in, the output out), direct form II transposed in ``double``; no library, no
allocation, no global state. Python: a class ``N`` with ``reset()`` and ``update(e)``, the same step.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import TunerError
from .discrete import DifferenceEquation
from .names import MAX_NAME, check_name, header_comment  # noqa: F401  (re-exported: their names here before names.py)

__all__ = ["FORMATS", "check_name", "to_c", "to_python", "to_text", "render"]

FORMATS = ("c", "python", "text")


def _num(c: float) -> str:
    return repr(float(c))


def _linear(terms: Sequence[tuple[float, str]], extra: str | None = None) -> str:
    """``c1 * x1 + c2 * x2 + extra``, zero coefficients left out, signs folded."""
    parts: list[str] = []
    for c, x in terms:
        if c == 0:
            continue
        if not parts:
            parts.append(f"{_num(c)} * {x}")
        else:
            parts.append(f"{'-' if c < 0 else '+'} {_num(abs(c))} * {x}")
    if extra is not None:
        parts.append(f"+ {extra}" if parts else extra)
    return " ".join(parts) if parts else "0.0"


def _df2t(b: np.ndarray, a: np.ndarray, out: str, z: str) -> tuple[str, list[tuple[str, str]]]:
    """Direct form II transposed of ``b/a`` (powers of z^-1): the output's expression and the state updates
    ``(z[i], expression)``; ``z`` formats a state index, ``out`` names the output."""
    n = a.size - 1
    y = _linear([(b[0], "e")], z.format(0) if n else None)
    upd = []
    for i in range(n):
        nxt = z.format(i + 1) if i + 1 < n else None
        upd.append((z.format(i), _linear([(b[i + 1], "e"), (-a[i + 1], out)], nxt)))
    return y, upd


def _poly_z1(c: np.ndarray, var: str) -> str:
    """``c0 * var[k] + c1 * var[k-1] + ...``"""
    return _linear([(float(x), f"{var}[k]" if i == 0 else f"{var}[k-{i}]") for i, x in enumerate(c)])


def to_text(de: DifferenceEquation, name: str = "controller") -> str:
    """The difference equation and how the code realises it, as plain text."""
    check_name(name)
    n = de.order
    fb = " ".join(f"{'-' if -x < 0 else '+'} {_num(abs(x))} * u[k-{i}]" for i, x in enumerate(de.a) if i and x)
    lines = [
        f"{name}: discrete controller at dt = {_num(de.dt)} s ({1.0 / de.dt:.6g} Hz), order {n}; "
        f"{de.source}",
        "C(z) = (" + ", ".join(_num(x) for x in de.b) + ") / (" + ", ".join(_num(x) for x in de.a)
        + ")   [coefficients of z^0, z^-1, ...]",
        "e = r - y (reference minus measurement), u = the controller's output:",
        f"  u[k] = {_poly_z1(de.b, 'e')}" + (f" {fb}" if fb else ""),
        "Realised in direct form II transposed, double precision (as scipy.signal.lfilter).",
    ]
    lim = _limits_text(de)
    if lim:
        lines.append(f"Output limits: {lim}.")
    if de.anti_windup:
        it = de.integrator
        assert it is not None
        qfb = " ".join(f"{'-' if -x < 0 else '+'} {_num(abs(x))} * w[k-{i}]" for i, x in enumerate(it.a) if i and x)
        sat, cond = "v[k]", []
        if de.u_min is not None:
            sat = f"max({sat}, {_num(de.u_min)})"
            cond.append(f"v[k] < {_num(de.u_min)} and r * e[k] < 0")
        if de.u_max is not None:
            sat = f"min({sat}, {_num(de.u_max)})"
            cond.insert(0, f"v[k] > {_num(de.u_max)} and r * e[k] > 0")
        lines += [
            "Anti-windup by conditional integration (clamping): C(z) = r/(z - 1) + Q(z)/A'(z) (partial fractions)",
            f"with r = {_num(it.r)}; Q/A' in direct form II transposed, the integrator's state x apart:",
            f"  w[k] = {_poly_z1(it.q, 'e')}" + (f" {qfb}" if qfb else ""),
            "  v[k] = w[k] + x[k]",
            f"  u[k] = {sat}",
            "  x[k+1] = x[k] + r * e[k], except when " + ", or ".join(cond),
            "(the integrator is held while integrating would drive the saturated output further). Inside the "
            "limits, u = C(z) e exactly.",
        ]
    elif de.limited:
        lines.append("No integrator: the output is clamped; the controller's state is its own (stable) and "
                     "does not wind up.")
    return "\n".join(lines) + "\n"


def _limits_text(de: DifferenceEquation) -> str:
    parts = []
    if de.u_min is not None:
        parts.append(f"u >= {_num(de.u_min)}")
    if de.u_max is not None:
        parts.append(f"u <= {_num(de.u_max)}")
    return " and ".join(parts)


_IF = {"c": "if ({cond}) {u} = {x};", "python": "if {cond}:\n            {u} = {x}"}


def _clamp(de: DifferenceEquation, v: str, u: str, lang: str) -> list[str]:
    """Statements setting ``u`` to ``v`` clamped to the limits (the same in C and Python, but the syntax)."""
    out = [f"double {u} = {v};" if lang == "c" else f"{u} = {v}"]
    for op, lim in ((">", de.u_max), ("<", de.u_min)):
        if lim is not None:
            out.append(_IF[lang].format(cond=f"{u} {op} {_num(lim)}", u=u, x=_num(lim)))
    return out


def _hold_condition(de: DifferenceEquation, lang: str) -> str:
    """When the integrator is held: saturated and integrating further into the limit."""
    conj, disj = (" && ", " || ") if lang == "c" else (" and ", " or ")
    parts = []
    if de.u_max is not None:
        parts.append(f"(v > {_num(de.u_max)}{conj}de > 0.0)")
    if de.u_min is not None:
        parts.append(f"(v < {_num(de.u_min)}{conj}de < 0.0)")
    return disj.join(parts)


def _body(de: DifferenceEquation, lang: str) -> tuple[list[str], int]:
    """The update's statements (without the return) and the number of DF2T states."""
    st = "s->z[{}]" if lang == "c" else "z[{}]"
    end = ";" if lang == "c" else ""
    decl = "const double " if lang == "c" else ""
    if not de.anti_windup:
        y, upd = _df2t(de.b, de.a, "v" if de.limited else "u", st)
        out = [f"{decl}{'v' if de.limited else 'u'} = {y}{end}"] + [f"{lhs} = {rhs}{end}" for lhs, rhs in upd]
        if de.limited:
            out += _clamp(de, "v", "u", lang)
        if lang == "c" and de.order == 0:
            out.insert(0, "(void)s;  /* a static gain: no state */")
        return out, de.order
    it = de.integrator
    assert it is not None
    xi = "s->xi" if lang == "c" else "self._xi"
    y, upd = _df2t(it.q, it.a, "w", st)
    out = [f"{decl}w = {y}{end}"] + [f"{lhs} = {rhs}{end}" for lhs, rhs in upd]
    out += [f"{decl}v = w + {xi}{end}", f"{decl}de = {_num(it.r)} * e{end}"]
    out += _clamp(de, "v", "u", lang)
    cond = _hold_condition(de, lang)
    out.append(f"if (!({cond})) {xi} += de;" if lang == "c" else f"if not ({cond}):\n            {xi} += de")
    return out, it.a.size - 1


def _comment(de: DifferenceEquation, name: str, prefix: str) -> str:
    return header_comment(to_text(de, name), prefix)


def to_c(de: DifferenceEquation, name: str = "controller") -> str:
    """C99 source: ``name_state``, ``name_init``, ``name_update`` (see the module)."""
    check_name(name)
    body, nz = _body(de, "c")
    fields = [f"    double z[{max(nz, 1)}];  /* direct form II transposed states{'' if nz else ' (none used)'} */"]
    inits = [f"    for (i = 0; i < {max(nz, 1)}; ++i) s->z[i] = 0.0;"]
    if de.anti_windup:
        fields.append("    double xi;    /* the integrator's state x */")
        inits.append("    s->xi = 0.0;")
    return (
        "/*\n" + _comment(de, name, " * ") + "\n *\n"
        f" * Use: {name}_state s; {name}_init(&s); then once per sample, u = {name}_update(&s, r - y);\n"
        f" * sample time {_num(de.dt)} s. C99, double precision, no library calls.\n */\n\n"
        f"typedef struct {{\n" + "\n".join(fields) + f"\n}} {name}_state;\n\n"
        f"void {name}_init({name}_state *s)\n{{\n    int i;\n" + "\n".join(inits) + "\n}\n\n"
        f"double {name}_update({name}_state *s, double e)\n{{\n"
        + "\n".join(f"    {line}" for line in body) + "\n    return u;\n}\n"
    )


def to_python(de: DifferenceEquation, name: str = "controller") -> str:
    """A Python class ``name`` with ``reset()`` and ``update(e)``, standalone (no import)."""
    check_name(name)
    body, nz = _body(de, "python")
    reset = [f"self._z = [0.0] * {nz}"] + (["self._xi = 0.0"] if de.anti_windup else [])
    lines = ["z = self._z"] if nz else []
    lines += body
    return (
        f"class {name}:\n    \"\"\"\n" + _comment(de, name, "    ").replace("\\", "\\\\") + "\n\n"
        f"    Use: c = {name}(); then once per sample, u = c.update(r - y).\n    \"\"\"\n\n"
        f"    dt = {_num(de.dt)}\n\n"
        "    def __init__(self):\n        self.reset()\n\n"
        "    def reset(self):\n        \"\"\"Zero state (the controller at rest).\"\"\"\n"
        + "\n".join(f"        {line}" for line in reset) + "\n\n"
        "    def update(self, e):\n        \"\"\"One sample: the error e = r - y in, the output u out.\"\"\"\n"
        "        e = float(e)\n"
        + "\n".join(f"        {line}" for line in lines) + "\n        return u\n"
    )


def render(de: DifferenceEquation, fmt: str, name: str = "controller") -> str:
    """``de`` as ``fmt`` (:data:`FORMATS`); a 2-DOF law (:mod:`tuner.export.twodof`) as its own code."""
    if fmt not in FORMATS:
        raise TunerError(f"format must be one of {list(FORMATS)}, got {fmt!r}", field="format")
    from .twodof import TwoDofLaw, render2

    if isinstance(de, TwoDofLaw):
        return render2(de, fmt, name)
    return {"c": to_c, "python": to_python, "text": to_text}[fmt](de, name)
