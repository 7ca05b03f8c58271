"""The 2-DOF PID (``pid2``) as it runs on the target: ``u = N_update(s, r, y)``.

The law, per sample ``k`` (``e = r - y``, ``v = c r - y``)::

    P[k] = Kp (b r[k] - y[k])
    I[k] = I[k-1] + gi0 e[k] + gi1 e[k-1]          integral of r - y
    D[k] = ad D[k-1] + bd (v[k] - v[k-1])           filtered derivative of c r - y (c = 0: of -y only)
    u[k] = P[k] + I[k] + D[k]

with the structure's own discretisation (backward Euler, :mod:`tuner.controllers`): ``gi0 = Ki dt``,
``gi1 = 0``, ``ad = Tf/(Tf + dt)``, ``bd = Kd/(Tf + dt)`` (what was tuned at ``dt``), or Tustin for a continuous
result exported with ``method="tustin"``: ``gi0 = gi1 = Ki dt/2``, ``ad = (2 Tf - dt)/(2 Tf + dt)``,
``bd = 2 Kd/(2 Tf + dt)``. Inside the limits this is ``u = C_r(z) r - C(z) y`` exactly.

Output limits ``u_min``/``u_max`` clamp ``u``; the integrator then has anti-windup, one of
(:data:`ANTI_WINDUP`):

* ``"conditional"`` (conditional integration, clamping): this sample's increment of ``I`` is dropped when the
  output is saturated and the increment would drive it further into the limit;
* ``"back_calculation"`` (tracking, Astrom & Hagglund, *Advanced PID Control*, 2006, sec. 3.5): after the clamp,
  ``I[k] += (dt/Tt) (u[k] - w[k])`` (``w`` the unclamped output), so a saturated integrator is driven back to
  the value at which the output just reaches the limit with the time constant ``Tt``. Default
  ``Tt = sqrt(Ti Td)`` (``Ti = Kp/Ki``, ``Td = Kd/Kp``) for a PID, ``Tt = Ti`` for a PI (``Kd = 0``),
  never below ``dt`` (``dt/Tt = 1`` resets the integrator to the limit in one sample).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ..errors import TunerError
from ..plant import check_dt
from ..tolerances import SAME_DT_RTOL
from .names import check_name, header_comment

__all__ = ["ANTI_WINDUP", "TwoDofLaw", "two_dof_law", "default_tt", "to_c2", "to_python2", "to_text2"]

ANTI_WINDUP = ("conditional", "back_calculation")


@dataclass(frozen=True)
class TwoDofLaw:
    """pid2's difference equations at ``dt`` (see the module); ``tt`` is the tracking time of back-calculation."""

    kp: float
    b: float
    c: float
    gi0: float
    gi1: float
    ad: float
    bd: float
    dt: float
    source: str
    gains: dict
    u_min: float | None = None
    u_max: float | None = None
    anti_windup: str = "conditional"
    tt: float | None = None

    @property
    def limited(self) -> bool:
        """Whether output limits are given (then the anti-windup is active)."""
        return self.u_min is not None or self.u_max is not None


def default_tt(kp: float, ki: float, kd: float, dt: float) -> float:
    """Astrom & Hagglund's tracking time: ``sqrt(Ti Td)`` for a PID, ``Ti`` for a PI; at least ``dt``."""
    if ki == 0 or kp == 0 or kp / ki <= 0:
        raise TunerError("back-calculation's default tracking time Tt = sqrt(Ti Td) (Ti for a PI) needs "
                         f"Ti = Kp/Ki > 0 (Kp = {kp:g}, Ki = {ki:g}): give tt, seconds", field="tt")
    ti = kp / ki
    td = kd / kp
    tt = math.sqrt(ti * td) if td > 0 else ti
    return max(tt, dt)


def two_dof_law(gains: dict[str, float], ctrl_dt: float | None, *, dt: float | None, method: str,
                u_min: float | None, u_max: float | None, anti_windup: str = "conditional",
                tt: float | None = None) -> TwoDofLaw:
    """The law of a pid2 with ``gains`` tuned at ``ctrl_dt`` (None: continuous), exported at ``dt``."""
    from .discrete import METHODS, check_limits

    if anti_windup not in ANTI_WINDUP:
        raise TunerError(f"anti_windup must be one of {list(ANTI_WINDUP)}, got {anti_windup!r}",
                         field="anti_windup")
    lo, hi = check_limits(u_min, u_max)
    try:
        kp, ki, kd, tf, b, c = (float(gains[k]) for k in ("Kp", "Ki", "Kd", "Tf", "b", "c"))
    except (KeyError, TypeError, ValueError) as e:
        raise TunerError("a pid2 result needs the gains Kp, Ki, Kd, Tf, b, c", field="gains") from e
    if ctrl_dt is not None:
        dt_in = check_dt(dt)
        if dt_in is not None and abs(dt_in - ctrl_dt) > SAME_DT_RTOL * ctrl_dt:
            raise TunerError(f"the controller is discrete at dt={ctrl_dt:g} s but dt={dt_in:g} s was given: "
                             "resampling a discrete controller is not supported; leave dt out or give its own",
                             field="dt")
        dt, use = ctrl_dt, "structure"
        source = "pid2 as tuned at this dt (backward Euler for I and the filtered D)"
    else:
        if dt is None:
            raise TunerError(f"the controller is continuous: give the sample time dt to discretise it at (method "
                             f"{method!r})", field="dt")
        dt = check_dt(dt)
        if method not in ("structure", "tustin"):
            raise TunerError(f"a 2-DOF pid2 is discretised term by term: method 'structure' (backward Euler) or "
                             f"'tustin', got {method!r}", field="method")
        use = method
        source = f"pid2 discretised at dt = {dt:g} s by {METHODS[method]}"
    if use == "structure":
        gi0, gi1, ad, bd = ki * dt, 0.0, tf / (tf + dt), kd / (tf + dt)
    else:
        if 2 * tf + dt == 0:
            raise TunerError("Tustin needs Tf > 0 or dt > 0", field="method")
        gi0 = gi1 = ki * dt / 2
        ad, bd = (2 * tf - dt) / (2 * tf + dt), 2 * kd / (2 * tf + dt)
    t_track = None
    if anti_windup == "back_calculation" and (lo is not None or hi is not None):
        if tt is None:
            t_track = default_tt(kp, ki, kd, dt)
        else:
            t_track = float(tt)
            if not (math.isfinite(t_track) and t_track >= dt):
                raise TunerError(f"tt must be a time of at least dt = {dt:g} s, got {tt!r}", field="tt")
    elif tt is not None and anti_windup != "back_calculation":
        raise TunerError("tt is the tracking time of back-calculation: give anti_windup='back_calculation'",
                         field="tt")
    return TwoDofLaw(kp=kp, b=b, c=c, gi0=gi0, gi1=gi1, ad=ad, bd=bd, dt=float(dt), source=source,
                     gains={"Kp": kp, "Ki": ki, "Kd": kd, "Tf": tf, "b": b, "c": c}, u_min=lo, u_max=hi,
                     anti_windup=anti_windup, tt=t_track)


def _n(x: float) -> str:
    return repr(float(x))


def to_text2(law: TwoDofLaw, name: str = "controller") -> str:
    """The 2-DOF law as its difference equations in text (u from r and y, anti-windup said)."""
    check_name(name)
    g = law.gains
    lines = [
        f"{name}: 2-DOF PID (pid2) at dt = {_n(law.dt)} s ({1.0 / law.dt:.6g} Hz); {law.source}",
        "gains: " + ", ".join(f"{k} = {_n(v)}" for k, v in g.items())
        + f"; setpoint feed-forward Kp (b - 1) = {_n(g['Kp'] * (g['b'] - 1))}",
        "Inputs r (reference) and y (measurement); e = r - y, v = c r - y "
        + ("(c = 0: D on the measurement only)" if law.c == 0 else "(D on c r - y)") + ":",
        f"  P[k] = {_n(law.kp)} * ({_n(law.b)} * r[k] - y[k])",
        f"  I[k] = I[k-1] + {_n(law.gi0)} * e[k]" + (f" + {_n(law.gi1)} * e[k-1]" if law.gi1 else ""),
        f"  D[k] = {_n(law.ad)} * D[k-1] + {_n(law.bd)} * (v[k] - v[k-1])",
        "  w[k] = P[k] + I[k] + D[k]",
    ]
    if not law.limited:
        lines.append("  u[k] = w[k]   (zero initial state: I, D, v[-1], e[-1] = 0)")
        return "\n".join(lines) + "\n"
    sat = "w[k]"
    if law.u_min is not None:
        sat = f"max({sat}, {_n(law.u_min)})"
    if law.u_max is not None:
        sat = f"min({sat}, {_n(law.u_max)})"
    lines.append(f"  u[k] = {sat}")
    if law.anti_windup == "conditional":
        cond = []
        if law.u_max is not None:
            cond.append(f"w[k] > {_n(law.u_max)} and the I increment > 0")
        if law.u_min is not None:
            cond.append(f"w[k] < {_n(law.u_min)} and the I increment < 0")
        lines += ["Anti-windup by conditional integration: the I increment of this sample is dropped (I[k] = I[k-1],",
                  "then w and u again) when " + ", or ".join(cond) + "."]
    else:
        lines += [f"Anti-windup by back-calculation (tracking time Tt = {_n(law.tt)} s; default sqrt(Ti Td), Ti for "
                  "a PI, Astrom & Hagglund):",
                  f"  I[k] <- I[k] + {_n(law.dt / law.tt)} * (u[k] - w[k])   (dt/Tt, after the clamp)"]
    lines.append("Inside the limits, u = C_r(z) r - C(z) y exactly.")
    return "\n".join(lines) + "\n"


def _lines(law: TwoDofLaw, lang: str) -> list[str]:
    """The update's statements (C or Python; the state is s->... or self._...), without the return."""
    s = "s->{}" if lang == "c" else "self._{}"
    d = "const double " if lang == "c" else ""
    m = "double " if lang == "c" else ""
    end = ";" if lang == "c" else ""
    out = [
        f"{d}e = r - y{end}",
        f"{d}p = {_n(law.kp)} * ({_n(law.b)} * r - y){end}",
        f"{d}v = {_n(law.c)} * r - y{end}",
        f"{d}dd = {_n(law.ad)} * {s.format('d')} + {_n(law.bd)} * (v - {s.format('v1')}){end}",
        f"{d}di = {_n(law.gi0)} * e" + (f" + {_n(law.gi1)} * {s.format('e1')}" if law.gi1 else "") + end,
        f"{m}i = {s.format('i')} + di{end}",
        f"{m}w = p + i + dd{end}",
        f"{m}u = w{end}",
    ]

    def clamp() -> list[str]:
        res = []
        for op, lim in ((">", law.u_max), ("<", law.u_min)):
            if lim is not None:
                res.append(f"if (u {op} {_n(lim)}) u = {_n(lim)};" if lang == "c"
                           else f"if u {op} {_n(lim)}:\n            u = {_n(lim)}")
        return res

    if law.limited:
        out += clamp()
        if law.anti_windup == "conditional":
            conj, disj = (" && ", " || ") if lang == "c" else (" and ", " or ")
            parts = []
            if law.u_max is not None:
                parts.append(f"(w > {_n(law.u_max)}{conj}di > 0.0)")
            if law.u_min is not None:
                parts.append(f"(w < {_n(law.u_min)}{conj}di < 0.0)")
            cond = disj.join(parts)
            if lang == "c":
                out.append(f"if ({cond}) {{  /* hold the integrator */")
                out += ["    i = s->i;", "    w = p + i + dd;", "    u = w;"] + [f"    {x}" for x in clamp()]
                out.append("}")
            else:
                out.append(f"if {cond}:  # hold the integrator")
                out += ["    i = self._i", "    w = p + i + dd", "    u = w"]
                out += ["    " + x.replace("\n            ", "\n                ") for x in clamp()]
        else:
            out.append(f"i += {_n(law.dt / law.tt)} * (u - w){end}  " + ("/* back-calculation, dt/Tt */" if lang == "c"
                                                                       else "# back-calculation, dt/Tt"))
    out += [f"{s.format('i')} = i{end}", f"{s.format('d')} = dd{end}", f"{s.format('v1')} = v{end}"]
    if law.gi1:
        out.append(f"{s.format('e1')} = e{end}")
    return out


def _comment(law: TwoDofLaw, name: str, prefix: str) -> str:
    return header_comment(to_text2(law, name), prefix)


_STATE = (("i", "the integral term I[k-1]"), ("d", "the derivative term D[k-1]"), ("v1", "c r - y at k-1"),
          ("e1", "r - y at k-1 (Tustin)"))


def to_c2(law: TwoDofLaw, name: str = "controller") -> str:
    """The 2-DOF law as C99: ``name_state``, ``name_init``, ``name_update(s, r, y)`` returning u."""
    check_name(name)
    fields = [(f, w) for f, w in _STATE if f != "e1" or law.gi1]
    return (
        "/*\n" + _comment(law, name, " * ") + "\n *\n"
        f" * Use: {name}_state s; {name}_init(&s); then once per sample, u = {name}_update(&s, r, y);\n"
        f" * sample time {_n(law.dt)} s. C99, double precision, no library calls.\n */\n\n"
        "typedef struct {\n" + "\n".join(f"    double {f};  /* {w} */" for f, w in fields) + f"\n}} {name}_state;\n\n"
        f"void {name}_init({name}_state *s)\n{{\n" + "\n".join(f"    s->{f} = 0.0;" for f, _ in fields) + "\n}\n\n"
        f"double {name}_update({name}_state *s, double r, double y)\n{{\n"
        + "\n".join(f"    {line}" for line in _lines(law, "c")) + "\n    return u;\n}\n"
    )


def to_python2(law: TwoDofLaw, name: str = "controller") -> str:
    """The 2-DOF law as a standalone Python class ``name`` with ``update(r, y)``."""
    check_name(name)
    fields = [f for f, _ in _STATE if f != "e1" or law.gi1]
    return (
        f"class {name}:\n    \"\"\"\n" + _comment(law, name, "    ").replace("\\", "\\\\") + "\n\n"
        f"    Use: c = {name}(); then once per sample, u = c.update(r, y).\n    \"\"\"\n\n"
        f"    dt = {_n(law.dt)}\n\n"
        "    def __init__(self):\n        self.reset()\n\n"
        "    def reset(self):\n        \"\"\"Zero state (the controller at rest).\"\"\"\n"
        + "\n".join(f"        self._{f} = 0.0" for f in fields) + "\n\n"
        "    def update(self, r, y):\n"
        "        \"\"\"One sample: reference r and measurement y in, the output u out.\"\"\"\n"
        "        r = float(r)\n        y = float(y)\n"
        + "\n".join(f"        {line}" for line in _lines(law, "python")) + "\n        return u\n"
    )


def render2(law: TwoDofLaw, fmt: str, name: str) -> str:
    """The 2-DOF law in ``fmt`` (``c``, ``python`` or ``text``)."""
    return {"c": to_c2, "python": to_python2, "text": to_text2}[fmt](law, name)


def is_two_dof(structure: Any) -> bool:
    """Whether ``structure`` (a name) is exported with r and y (pid2)."""
    return structure == "pid2"
