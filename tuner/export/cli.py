"""``tuner export``: a controller as C99, a Python class or its difference equation.

Registered in :mod:`tuner.cli` through ``_EXTRA_COMMANDS``. Exit codes: 0 written; 2 bad input (one
line naming the argument), a parameter file refused included (another axis than the result's, a value no vehicle
can hold, and without ``--force`` a design that does not meet its spec or a value outside its documented range).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ..errors import TunerError
from ..firmware.registry import by_format, formats

__all__ = ["add_parser"]

_OPTION = {"name": "--name", "dt": "--dt", "method": "--method", "u_min": "--u-min", "u_max": "--u-max",
           "anti_windup": "--anti-windup", "tt": "--tt", "gains": "--result",
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
integrating would drive the saturated output further. The header of the output states all of this.
A 2-DOF pid2 result is exported with both inputs: N_update(N_state *s, double r, double y) (Python:
update(r, y)), u = Kp(b r - y) + I + D with I integrating r - y and D the filtered derivative of c r - y
(c = 0: D on the measurement); with limits, anti-windup by --anti-windup conditional (default) or
back-calculation (tracking time --tt, default sqrt(Ti*Td), Ti for a PI)."""


def add_parser(sub: Any) -> None:
    """Register ``tuner export`` on the subcommand parsers ``sub``."""
    p = sub.add_parser("export", help="the controller as C99, a Python class or its difference equation",
                       description=_DESCRIPTION)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--controller", metavar="EXPR", help="controller expression: in z (with --dt) or in s")
    src.add_argument("--result", metavar="FILE.json", help="a result: the output of 'tuner tune --json' or the "
                     "answer of GET /tunes/{id}")
    p.add_argument("--dt", type=float, default=None, help="sample time, s (of a z controller; to discretise an s one)")
    p.add_argument("--format", required=True, choices=["c", "python", "text", *formats()],
                   help="what to write: code (c, python, text), or the parameter file the ground station loads for a "
                        "px4_rate (px4: QGroundControl .params) or ardupilot_rate (ardupilot: .parm) result")
    p.add_argument("--axis", choices=("roll", "pitch", "yaw"), default=None,
                   help="px4/ardupilot: the axis whose parameters (default: the result's vehicle's, else roll)")
    p.add_argument("--att-p", type=float, default=None, metavar="P",
                   help="px4/ardupilot: the attitude loop's P of a cascade, written too (MC_ROLL_P, ATC_ANG_RLL_P)")
    p.add_argument("--force", action="store_true",
                   help="px4/ardupilot: write the file even for a design that does not meet its spec (or meets it on "
                        "the model only: its identification rated below acceptable), or with a value outside the "
                        "firmware's documented range; the header says so")
    p.add_argument("--name", default="controller", metavar="N", help="C identifier for N_state, N_init, "
                   "N_update (and the Python class) (controller)")
    p.add_argument("--method", default="tustin", choices=["tustin", "zoh", "structure"],
                   help="discretisation of a continuous controller (tustin)")
    p.add_argument("--u-min", type=float, default=None, metavar="U", help="lower output limit")
    p.add_argument("--u-max", type=float, default=None, metavar="U", help="upper output limit")
    p.add_argument("--anti-windup", default="conditional", choices=["conditional", "back-calculation"],
                   help="pid2 results (N_update(s, r, y)): conditional integration (default) or back-calculation "
                        "with tracking time --tt (default sqrt(Ti*Td), Ti for a PI; Astrom-Hagglund); active with "
                        "--u-min/--u-max. 1-DOF controllers: conditional integration")
    p.add_argument("--tt", type=float, default=None, metavar="S", help="back-calculation tracking time, s (>= dt)")
    p.add_argument("--out", metavar="FILE", help="write to FILE instead of stdout")
    p.set_defaults(handler=_cmd_export)


def _load(path: str) -> Any:
    """The result file, its fields checked against the schema export reads (:mod:`tuner.export.resultfile`) before
    anything is formatted: a crafted one is exit 2 naming the field."""
    from ..fileio import read_json
    from .resultfile import check_result

    doc = read_json(path, label=f"--result {path}", field="result",
                    hint="give the output of 'tuner tune --json' or the answer of GET /tunes/{id}")
    try:
        return check_result(doc)
    except TunerError as e:
        raise TunerError(f"--result {path}: {e}", field=("result", *e.field)) from None


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


def _cmd_param_file(a: argparse.Namespace) -> str:
    from .paramfile import make_param_file

    if a.result is None:
        raise TunerError(f"--format {a.format}: needs --result FILE.json (a {a.format} rate-law tune's result)")
    for flag, v in (("--dt", a.dt), ("--u-min", a.u_min), ("--u-max", a.u_max), ("--tt", a.tt)):
        if v is not None:
            raise TunerError(f"{flag}: not for --format {a.format} (a parameter file holds the law's gains only)")
    src = _load(a.result)
    try:
        pf = make_param_file(src, a.format, axis=a.axis, att_p=a.att_p, force=a.force)
    except TunerError as e:
        opt = {"axis": "--axis", "format": "--format"}.get(str(e.field[0]) if e.field else "")
        if opt is not None:
            raise TunerError(f"{opt}: {e}") from e
        raise TunerError(f"--result {a.result}: {e}", field=("result", *e.field)) from e
    for w in pf.warnings:  # said before the file is written (and in its header)
        print(f"tuner: warning: {w}", file=sys.stderr)
    return pf.text


def _cmd_export(a: argparse.Namespace) -> int:
    from .codegen import check_name, render
    from .source import clamp_note, equation_of

    if a.out is not None:  # a target that cannot take it is refused before the result is read
        from ..fileio import check_output

        check_output(a.out, label=f"--out {a.out}")
    if by_format(a.format) is not None:
        return _write(a, _cmd_param_file(a))
    if a.axis is not None or a.att_p is not None or a.force:
        flag = "--axis" if a.axis is not None else "--att-p" if a.att_p is not None else "--force"
        raise TunerError(f"{flag}: only for --format {' or '.join(formats())}")
    try:
        check_name(a.name)
        src = _source(a)
        de = equation_of(src, dt=a.dt, method=a.method, u_min=a.u_min, u_max=a.u_max,
                         anti_windup=a.anti_windup.replace("-", "_"), tt=a.tt)
        text = render(de, a.format, a.name)
        note = clamp_note(src, a.u_min, a.u_max, flag=True)
        if note:
            print(f"tuner: warning: {note}", file=sys.stderr)
    except TunerError as e:
        if str(e).startswith("-"):
            raise
        opt = next((_OPTION[str(f)] for f in e.field if str(f) in _OPTION), None)
        if a.result is not None and opt in (None, "--controller", "--result"):
            # about the result's content (its controller, structure, gains): name the file, never an option
            # the user did not give (such as --structure, which export does not have)
            part = str(e.field[0]) if e.field and str(e.field[0]) in ("structure", "gains") else ""
            raise TunerError(f"--result {a.result}: {'its ' + part + ': ' if part else ''}{e}",
                             field=("result", *e.field)) from e
        if opt is None:
            raise
        raise TunerError(f"{opt}: {e}") from e
    return _write(a, text)


def _write(a: argparse.Namespace, text: str) -> int:
    if a.out is None:
        print(text, end="")
        return 0
    from ..fileio import write_output

    write_output(a.out, text, label=f"--out {a.out}")  # a regular file, all of it, or exit 2 (never a FIFO's hang)
    return 0
