"""``tuner export``: a controller as C99, a Python class or its difference equation.

Registered in :mod:`tuner.cli` through ``_EXTRA_COMMANDS``. Exit codes: 0 written; 2 bad input (one
line naming the argument).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from ..errors import TunerError

__all__ = ["add_parser"]

_OPTION = {"name": "--name", "dt": "--dt", "method": "--method", "u_min": "--u-min", "u_max": "--u-max",
           "format": "--format", "controller": "--controller", "expr": "--controller", "num": "--controller",
           "den": "--controller", "result": "--result"}

_DESCRIPTION = """\
The controller as it runs on the target, in direct form II transposed, double precision:
  c       C99: N_state, void N_init(N_state *s), double N_update(N_state *s, double e) returning u
  python  a class N with reset() and update(e) returning u (standalone, no import)
  text    the difference equation u[k] = ... and how it is realised
e = r - y. A discrete controller (in z, with --dt; or a result tuned at a dt) is exported as it is; a
continuous one (in s, or tuned without dt) is discretised at --dt by --method: tustin (default), zoh, or
structure (the structure's own discretisation of tuner.controllers: backward Euler for the integrator and the
filtered derivative, matched pole-zero for lead/lag; needs --result).
--u-min/--u-max clamp the output; a controller with integral action (PI, PID, pid_z, ...) then gets
anti-windup by conditional integration: the integrator (split off by partial fractions) is held while
integrating would drive the saturated output further. The header of the output states all of this."""


def add_parser(sub: Any) -> None:
    """Register ``tuner export`` on the subcommand parsers ``sub``."""
    p = sub.add_parser("export", help="the controller as C99, a Python class or its difference equation",
                       description=_DESCRIPTION)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--controller", metavar="EXPR", help="controller expression: in z (with --dt) or in s")
    src.add_argument("--result", metavar="FILE.json", help="a result: the output of 'tuner tune --json' or the "
                     "answer of GET /tunes/{id}")
    p.add_argument("--dt", type=float, default=None, help="sample time, s (of a z controller; to discretise an s one)")
    p.add_argument("--format", required=True, choices=["c", "python", "text"], help="what to write")
    p.add_argument("--name", default="controller", metavar="N", help="C identifier for N_state, N_init, "
                   "N_update (and the Python class) (controller)")
    p.add_argument("--method", default="tustin", choices=["tustin", "zoh", "structure"],
                   help="discretisation of a continuous controller (tustin)")
    p.add_argument("--u-min", type=float, default=None, metavar="U", help="lower output limit")
    p.add_argument("--u-max", type=float, default=None, metavar="U", help="upper output limit")
    p.add_argument("--out", metavar="FILE", help="write to FILE instead of stdout")
    p.set_defaults(handler=_cmd_export)


def _load(path: str) -> Any:
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except OSError as e:
        raise TunerError(f"--result {path}: cannot read: {e.strerror or e}") from None
    except UnicodeDecodeError:
        raise TunerError(f"--result {path}: not UTF-8 text (give the JSON of 'tuner tune --json')") from None
    except json.JSONDecodeError as e:
        raise TunerError(f"--result {path}: not JSON ({e.msg} at line {e.lineno}); give the output of "
                         "'tuner tune --json' or of GET /tunes/{id}") from None


def _source(a: argparse.Namespace) -> Any:
    if a.result is not None:
        return _load(a.result)
    from ..controllers import controller_from_expr
    from ..expr import parse_tf_expr

    try:
        var = parse_tf_expr(a.controller).var
    except TunerError as e:
        raise e.at("controller") from None
    return controller_from_expr(a.controller, dt=a.dt if var != "s" else None)


def _cmd_export(a: argparse.Namespace) -> int:
    from .codegen import check_name, render
    from .source import clamp_note, equation_of

    try:
        check_name(a.name)
        src = _source(a)
        de = equation_of(src, dt=a.dt, method=a.method, u_min=a.u_min, u_max=a.u_max)
        text = render(de, a.format, a.name)
        note = clamp_note(src, a.u_min, a.u_max)
        if note:
            print(f"tuner: warning: {note}", file=sys.stderr)
    except TunerError as e:
        opt = next((_OPTION[str(f)] for f in e.field if str(f) in _OPTION), None)
        if opt == "--controller" and a.result is not None:
            opt = "--result"
        if opt is None or str(e).startswith("-"):
            raise
        raise TunerError(f"{opt}: {e}") from e
    if a.out is None:
        print(text, end="")
        return 0
    try:
        with open(a.out, "w", encoding="utf-8") as f:
            f.write(text)
    except OSError as e:
        raise TunerError(f"--out {a.out}: cannot write: {e.strerror or e}") from None
    return 0
