"""The ``tuner`` command line.

Exit codes, the same for every command (:data:`EXIT_CODES`, printed by ``--help``):

* 0: done, and every spec checked is met;
* 1: done, but a spec is not met (``analyze``, ``tune``, ``verify``, ``study run``): the output (also
  ``--json``, on stdout) says what fails; on an identification also a margin below the spec on the measured
  response, one not measured, or an identification rated below acceptable (the verdict "on the model only");
* 2: bad input: one line on stderr naming the argument and what to change, no traceback;
* 3: an internal error (a bug: please report it; ``-v`` prints the traceback).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from .errors import TunerError
from .limits import EFFORT_NAMES, LIMITS
from .objectives import OBJECTIVE_DEFINITIONS, ROBUST_NOTE

__all__ = ["main", "EXIT_OK", "EXIT_SPEC_NOT_MET", "EXIT_BAD_INPUT", "EXIT_INTERNAL", "EXIT_CODES"]

log = logging.getLogger("tuner")

EXIT_OK, EXIT_SPEC_NOT_MET, EXIT_BAD_INPUT, EXIT_INTERNAL = 0, 1, 2, 3
EXIT_CODES = """exit codes (every command):
  0  done, and every spec checked is met
  1  done, but a spec is not met (the output, --json included, says what fails); from an identification
     also on its measured response, or when it is rated below acceptable ("on the model only")
  2  bad input: one line on stderr naming the argument and what to change
  3  internal error (a bug: please report it; -v prints the traceback)"""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # argparse exits 2 with usage: keep, but no traceback
        self.print_usage(sys.stderr)
        self.exit(2, f"tuner: error: {message}\n")


def _add_spec_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group(
        "spec (defaults: the quadrotor thesis)",
        "'The thesis' is S. Fernandes, Guidance and Trajectory Following of an Autonomous Vision-Guided Micro "
        "QuadRotor, MSc thesis, Instituto Superior Tecnico, Lisbon, 2011: its attitude loops (roll, pitch, yaw at "
        "dt = 0.04 s, the digital PID 'pid_z') and its spec (PM >= 60 deg, GM >= 6 dB, overshoot <= 10 %, zero "
        "steady-state error, minimum settling time) are this tool's first workload and its defaults.")
    for lim in LIMITS:  # one flag per limit of the registry (tuner.limits)
        default = f" ({lim.default:g})" if lim.default is not None else ""
        g.add_argument(lim.flag, dest=lim.field, type=float, default=None, metavar=lim.metavar,
                       help=lim.help.replace("%", "%%") + default)
        if lim.field == "overshoot_max_pct":  # (not a limit: the band the settling time is measured in)
            g.add_argument("--band", type=float, default=None, metavar="PCT", help="settling band %% (2)")
    g.add_argument("--objective", default=None, choices=[*OBJECTIVE_DEFINITIONS, "auto"],
                   help="what tune optimises (each defined in 'tuner tune --help'); default auto: settling_time, and "
                   "for a law with its own setpoint path (pid2, px4_rate, ardupilot_rate) iae for the feedback, then "
                   "the setpoint path alone for the settling time")
    d = p.add_argument_group(
        "default design limits (tune; on unless lifted)",
        "A derivative filter N = Td/Tf <= 20 (Astrom & Hagglund, Advanced PID Control, 2006: N in 2..20) for pd, "
        "pid, pid2, pid_mf2; at --dt a filter corner at most the Nyquist frequency (Tf >= dt/pi); a noise budget "
        "Mks <= 10 K0 (K0: the plant's ultimate gain, 1/|G| at -135 deg if its phase never reaches -180, or "
        "1/|G(0)| if larger; 10 K0 is the noise gain of a "
        "Ziegler-Nichols PID with N of 10-20). The thesis's pid_z keeps its own form (only the noise budget).")
    d.add_argument("--filter-n", type=float, default=None, metavar="N", help="derivative filter rule N_max (20)")
    d.add_argument("--no-filter-nyquist", action="store_true", help="lift the filter's Nyquist rule (Tf >= 1e-3 dt)")
    d.add_argument("--noise-gain", type=float, default=None, metavar="X", help="noise budget: Mks <= X K0 (10)")
    d.add_argument("--gain-variation", type=float, nargs=2, default=None, metavar=("LO", "HI"),
                   help="the design holds with the nominal plant's gain times LO and HI too (every constraint on "
                   "each; default 0.8 1.25 for px4_rate and ardupilot_rate: a rate loop's control effectiveness "
                   "moves with battery voltage and payload, none otherwise)")
    d.add_argument("--no-gain-variation", action="store_true", help="lift the gain variation")
    d.add_argument("--no-default-limits", action="store_true",
                   help="the pure thesis spec: lift the default limits, and the settling time is the objective for "
                   "every structure (flags above still apply)")


def _add_vehicle_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("vehicle (the firmware rate laws: px4_rate, ardupilot_rate, betaflight_rate, ...)")
    g.add_argument("--params", metavar="FILE",
                   help="what the vehicle fixes: loop rate, filter cutoffs, integrator limit, PX4's K, and its current "
                   "gains; a QGroundControl .params or a ULog .ulg (PX4), a Mission Planner .parm or a DataFlash .bin "
                   "(ArduPilot), a CLI dump (Betaflight)")
    g.add_argument("--axis", choices=("roll", "pitch", "yaw"), default="roll", help="the axis whose rate law (roll)")


def _add_actuator_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("actuator limits (the step the actuator allows, simulated as the law runs it)")
    g.add_argument("--u-max", type=float, default=None, metavar="U", help="upper output limit (alone: |u| <= U)")
    g.add_argument("--u-min", type=float, default=None, metavar="U", help="lower output limit")
    g.add_argument("--step-size", type=float, default=None, metavar="A",
                   help="amplitude of the reference step simulated with the limits (1)")


def _actuator(a: argparse.Namespace) -> Any:
    """The Actuator of --u-min/--u-max/--step-size (None without a limit)."""
    if a.u_min is None and a.u_max is None:
        if a.step_size is not None:
            raise TunerError("--step-size: give the actuator's limit too (--u-max, and --u-min)")
        return None
    from .analysis.saturation import Actuator

    try:
        return Actuator.of(u_min=a.u_min, u_max=a.u_max, step_size=a.step_size)
    except TunerError as e:
        raise TunerError(f"--{str(e.field[0]).replace('_', '-')}: {e}") from None


def _read_vehicle(a: argparse.Namespace, structure: str | None) -> Any:
    """The vehicle of ``--params`` (None without it), for the law ``structure``."""
    if a.params is None:
        return None
    from .firmware.bind import FIRMWARE_OF, law_choices
    from .firmware.params import read_params

    if structure not in FIRMWARE_OF:
        raise TunerError(f"--params: sets a firmware rate law's vehicle; give --structure {law_choices()} "
                         f"(got {structure!r})")
    with field("--params"):
        return read_params(a.params, axis=a.axis, firmware=FIRMWARE_OF[structure])


def _add_plot_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--plot", metavar="OUT.png", help="write the plot of the loop (every plant), png or svg by the "
                   "suffix: the step response with u(t), Bode with the margins, Nyquist with 1/Ms")
    p.add_argument("--plot-kind", default="all", choices=["all", "step", "bode", "nyquist"],
                   help="which plot --plot writes (all: the three side by side)")


def _plot_format(a: argparse.Namespace) -> str | None:
    """The format of ``--plot`` (checked before any work), or None without it."""
    if not a.plot:
        return None
    suffix = a.plot.rsplit(".", 1)[-1].lower() if "." in a.plot else ""
    if suffix not in ("png", "svg"):
        raise TunerError(f"--plot {a.plot}: the file name must end in .png or .svg")
    from .fileio import check_output

    check_output(a.plot, label=f"--plot {a.plot}")  # a device, a FIFO or a directory: refused before the work
    return suffix


def _write_plot(obj: Any, a: argparse.Namespace, fmt: str | None, spec: Any) -> None:
    if fmt is None:
        return
    from .analysis.plots import render
    from .fileio import write_output

    write_output(a.plot, render(obj, a.plot_kind, fmt, spec=spec), label=f"--plot {a.plot}")  # a file, all of it
    if not a.json:
        print(f"wrote {a.plot}")


def _exact(x: float) -> str:
    """``x`` with the shortest digits that give back the same double (``repr``)."""
    return repr(float(x))


def _factored(c: Any, var: str) -> str:
    """``k (var - z1)... / ((var - 1)...)``: the controller's gain, zeros and poles (6 digits; a root within 1e-4 of
    the integrator's with all its digits, so that it cannot be read as one), the integrator's root written exactly
    (``var - 1`` at a sample time, ``s`` in continuous time), repeated factors as powers."""
    import numpy as np

    from .tolerances import ROOT_AT_DC_TOL

    zk = c.zpk
    at_dc = 1.0 if c.dt else 0.0

    def num(v: float) -> str:
        return repr(float(v)) if abs(abs(v) - at_dc) < 1e-4 and at_dc else f"{v:.6g}"

    def factors(roots: np.ndarray) -> list[str]:
        out: dict[str, int] = {}
        for r in sorted(roots, key=lambda r: (abs(r - at_dc) > ROOT_AT_DC_TOL, -abs(r))):
            if abs(r - at_dc) <= ROOT_AT_DC_TOL:
                f = f"({var} - 1)" if c.dt else var
            elif abs(r.imag) > 1e-12:
                if r.imag < 0:
                    continue
                b, k = -2 * r.real, abs(r) ** 2
                f = f"({var}^2 {'-' if b < 0 else '+'} {abs(b):.6g} {var} + {k:.6g})"
            elif abs(r) == 0:
                f = var
            else:
                f = f"({var} {'-' if r.real > 0 else '+'} {num(abs(r.real))})"
            out[f] = out.get(f, 0) + 1
        return [f if n == 1 else f"{f}^{n}" for f, n in out.items()]

    nf, df = factors(zk.zeros), factors(zk.poles)
    head = " ".join([f"{zk.gain:.6g}", *nf])
    if not df:
        return head
    return head + " / " + (f"({' '.join(df)})" if len(df) > 1 else df[0])


def _spec_from_args(a: argparse.Namespace):
    from pydantic import ValidationError

    from .spec import Spec

    fields = {lim.field: getattr(a, lim.field) for lim in LIMITS}
    fields.update({"settling_band_pct": a.band, "objective": a.objective, "filter_n_max": a.filter_n,
                   "noise_gain_max": a.noise_gain})
    gv = getattr(a, "gain_variation", None)
    if gv is not None:
        fields["gain_variation"] = tuple(gv)
    given = {k: v for k, v in fields.items() if v is not None}
    if a.no_default_limits:
        given = {"filter_n_max": None, "filter_nyquist": False, "noise_gain_max": None, "gain_variation": None,
                 "objective": "settling_time", **given}  # (Spec.thesis(): its objective for every structure)
    if a.no_filter_nyquist:
        given["filter_nyquist"] = False
    if getattr(a, "no_gain_variation", False):
        if gv is not None:
            raise TunerError("--no-gain-variation: lifts the gain variation that --gain-variation sets: give one")
        given["gain_variation"] = None
    try:
        return Spec(**given)
    except ValidationError as e:
        err = e.errors()[0]
        name = str(err["loc"][0]) if err.get("loc") else "spec"
        raise TunerError(f"{SPEC_FLAGS.get(name, name)}: {err['msg']}") from None


#: Spec field -> the command-line flag that sets it (errors and suggestions speak the caller's vocabulary)
SPEC_FLAGS = {
    **{lim.field: lim.flag for lim in LIMITS},
    "settling_band_pct": "--band", "objective": "--objective", "filter_n_max": "--filter-n",
    "noise_gain_max": "--noise-gain", "filter_nyquist": "--no-filter-nyquist", "gain_variation": "--gain-variation",
    "zero_steady_state_error": "zero_steady_state_error",
}


def in_flags(message: str) -> str:
    """A library message with its Spec field names written as the flags that set them (``ms_max = 1.5`` ->
    ``--ms 1.5``)."""
    import re

    for k in sorted(SPEC_FLAGS, key=len, reverse=True):
        flag = SPEC_FLAGS[k]
        if flag == k or k == "objective":
            continue
        message = re.sub(rf"\b{k} = ", f"{flag} ", message)
        message = re.sub(rf"\b{k}\b", flag, message)
    return message


def suggestion_flags(suggest: dict[str, Any]) -> str:
    """A suggestion (Spec field -> value) as command-line flags: ``--pm 62.5 --ms 1.5``; a lifted limit (None)
    as the flag that lifts it."""
    out = []
    for k, v in suggest.items():
        flag = SPEC_FLAGS.get(k, k)
        if k == "filter_nyquist":
            out.append("--no-filter-nyquist") if v is False else None
        elif k == "zero_steady_state_error":
            out.append("zero_steady_state_error = false (Python/HTTP spec field; no flag)") if v is False else None
        elif v is None:
            out.append(f"no {flag}" if k not in ("noise_gain_max", "filter_n_max") else "--no-default-limits")
        else:
            out.append(f"{flag} {fmt(v) if isinstance(v, float) else v}")
    return " ".join(x for x in out if x)


def build_parser() -> argparse.ArgumentParser:
    """The ``tuner`` argument parser (every subcommand; ``tuner --help`` prints it with the exit codes)."""
    from .firmware.registry import structures
    p = _Parser(prog="tuner", description="Optimisation-based controller tuning with an independent verifier.",
                epilog=EXIT_CODES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("-v", "--verbose", action="store_true", help="log progress; print the traceback of an "
                   "internal error")
    p.add_argument("--version", action=_VersionAction,
                   help="print the installed version (package metadata) and exit")
    sub = p.add_subparsers(dest="cmd", required=True, parser_class=_Parser)
    sub.add_parser = _with_exit_codes(sub.add_parser)

    a = sub.add_parser("analyze", help="verify a controller on a plant: margins, step metrics, spec checks")
    a.add_argument("--plant", help="plant expression in s, or in z with --dt")
    a.add_argument("--identified", metavar="ID.json",
                   help="instead of --plant: the model identified from a log (the JSON of 'tuner identify --json'); "
                   "the loop is then also evaluated on the measured frequency response")
    a.add_argument("--dt", type=float, default=None, help="sample time of the controller (and of a z plant)")
    a.add_argument("--delay", type=float, default=0.0, help="plant input delay, seconds")
    a.add_argument("--controller", help="controller expression (in z with --dt, else in s)")
    a.add_argument("--structure", choices=structures(),
                   help="instead of --controller: the firmware rate law with the vehicle's current gains (--params)")
    _add_vehicle_args(a)
    _add_actuator_args(a)
    a.add_argument("--json", action="store_true", help="print JSON instead of a table")
    a.add_argument("--check", action="store_true",
                   help="kept for compatibility: the exit code is 1 whenever the spec is not met")
    _add_plot_args(a)
    _add_spec_args(a)

    t = sub.add_parser("tune", help="tune a controller structure: minimum settling time subject to the spec",
                       epilog=_objectives_help() + "\n\n" + EXIT_CODES)
    t.add_argument("--plant", action="append",
                   help="plant expression; repeat for robust tuning over a plant set (nominal first)")
    t.add_argument("--identified", metavar="ID.json",
                   help="instead of --plant: the model identified from a log (the JSON of 'tuner identify --json'), "
                   "its delay as fitted (exact in a sampled-data loop)")
    t.add_argument("--robust", type=float, default=None, metavar="K",
                   help="with --identified: one controller for the plant set spanned by the identified parameters' "
                   "K-sigma Cramér–Rao bounds (nominal + corners of the dominant parameters), then a Monte Carlo "
                   "check on draws from their covariance")
    t.add_argument("--monte-carlo", type=int, default=None, metavar="N",
                   help="with --identified: draws of the Monte Carlo check (default 200 with --robust, else 0)")
    t.add_argument("--dt", type=float, default=None, help="controller sample time (and of z plants)")
    t.add_argument("--delay", type=float, default=0.0, help="plant input delay, seconds (all plants)")
    t.add_argument("--structure", required=True,
                   help="p, pi, pd, pid, pid2 (2-DOF PID: u = Kp(b r - y) + Ki/s (r - y) + Kd s/(Tf s+1)(c r - y), "
                        "b in [0, 2], c in [0, 1]; c = 0 puts D on the measurement), pid_z (digital, needs --dt), "
                        "pid_mf2 (PID with a second-order measurement filter; 'pidf2' is its deprecated name), "
                        "lead, lag, leadlag; the autopilots' rate laws px4_rate and ardupilot_rate (computed as the "
                        "firmware does; the tuner chooses P, I, D, FF; --params gives the vehicle)")
    _add_vehicle_args(t)
    _add_actuator_args(t)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--budget", type=float, default=None, metavar="S",
                   help="time budget, seconds, a hard wall-time limit (default: one that fits the problem: 10 s of "
                        "search, 20 s for pid2, the NLP builds not counted, 60 s in all at most)")
    t.add_argument("--effort", choices=EFFORT_NAMES, default="default",
                   help="how hard to search: fast (the first round alone), default (plus 4 independent restarts, "
                        "'converged' only where their draws all reach one optimum), thorough (4-8 restarts, more "
                        "starts, a finer polish: about 3x the default's time); the output's 'optimality' line says "
                        "what the search knows")
    t.add_argument("--json", action="store_true")
    _add_plot_args(t)
    _add_spec_args(t)

    o = sub.add_parser("tradeoff", help="the speed/robustness trade-off curve: verified optima from the fastest "
                       "design to the most robust (every point meets the rest of the spec)")
    o.add_argument("--plant", required=True, action="append", help="plant expression; repeat for a plant set")
    o.add_argument("--dt", type=float, default=None, help="controller sample time (and of z plants)")
    o.add_argument("--delay", type=float, default=0.0, help="plant input delay, seconds (all plants)")
    o.add_argument("--structure", required=True, help="the controller structure (as for tune)")
    o.add_argument("--x", default="settling_time", choices=["settling_time"], help="the speed axis")
    o.add_argument("--y", default="mks", choices=["mks", "control_peak"],
                   help="the robustness axis: noise sensitivity Mks, or the control peak of a unit step")
    o.add_argument("--points", type=int, default=8, metavar="N", help="how many points (8; 2..20)")
    o.add_argument("--seed", type=int, default=0)
    o.add_argument("--budget", type=float, default=30.0, metavar="S", help="time budget of the whole curve (30)")
    o.add_argument("--json", action="store_true")
    _add_spec_args(o)

    for mod in _EXTRA_COMMANDS:
        __import__(f"tuner.{mod}", fromlist=["add_parser"]).add_parser(sub)
    return p


class _VersionAction(argparse.Action):
    """``--version``: prints ``tuner VERSION`` and exits 0, as argparse's own version action does, the version read
    from the package metadata only when asked (reading it costs ~3 ms, on every run when the parser is built)."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS,
                 default: Any = argparse.SUPPRESS, help: str | None = None) -> None:
        super().__init__(option_strings=option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser: argparse.ArgumentParser, namespace: Any, values: Any,
                 option_string: str | None = None) -> None:
        from . import __version__

        print(f"tuner {__version__}")
        parser.exit()


def _objectives_help() -> str:
    """The objectives' definitions (tuner.objectives), one line each (the terminal wraps them)."""
    lines = ["objectives (--objective):"]
    lines += [f"  {k}: {v}" for k, v in OBJECTIVE_DEFINITIONS.items()]
    return "\n".join(lines + [f"  {ROBUST_NOTE}"])


def _with_exit_codes(add_parser: Any) -> Any:
    """Every sub-command's ``--help`` ends with the exit codes (nested sub-commands too)."""

    def add(*args: Any, **kw: Any) -> argparse.ArgumentParser:
        kw.setdefault("epilog", EXIT_CODES)
        kw.setdefault("formatter_class", argparse.RawDescriptionHelpFormatter)
        parser = add_parser(*args, **kw)
        parser.add_subparsers = _nested(parser.add_subparsers)
        return parser

    return add


def _nested(add_subparsers: Any) -> Any:
    def make(*args: Any, **kw: Any) -> Any:
        action = add_subparsers(*args, **kw)
        action.add_parser = _with_exit_codes(action.add_parser)
        return action

    return make


# modules with add_parser(sub) registering more sub-commands
_EXTRA_COMMANDS: list[str] = ["studies.cli", "identify.cli", "export.cli"]


def print_table(title: str, rows: list[tuple[str, str]], checks: list[dict[str, Any]] | None = None) -> None:
    """Print ``rows`` (metric, value) and the spec ``checks`` as a table under ``title`` (rich)."""
    from rich.console import Console
    from rich.table import Table

    con = Console(highlight=False)
    t = Table(title=title, show_header=True)
    t.add_column("figure")
    t.add_column("value", justify="right")
    for k, v in rows:
        t.add_row(k, v)
    con.print(t)
    if checks:
        c = Table(title="checks", show_header=True)
        for col in ("constraint", "required", "achieved", "ok"):
            c.add_column(col)
        for ch in checks:
            got = ch["achieved"]
            unmeasured = ch["name"].startswith("measured_") and isinstance(got, float) and math.isnan(got)
            c.add_row(ch["name"], f"{ch['op']} {fmt(ch['required'])}", "not measured" if unmeasured else fmt(got),
                      "[green]ok[/green]" if ch["ok"] else "[red]FAIL[/red]")
        con.print(c)


@contextmanager
def field(name: str) -> Iterator[None]:
    """Prefix a :class:`TunerError` raised inside with the argument it came from."""
    try:
        yield
    except TunerError as e:
        raise TunerError(f"{name}: {e}") from e


def fmt(v: Any) -> str:
    """A value for a table: ``yes``/``no``, a float to 4 significant digits, else ``str``."""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def analysis_rows(metrics: dict[str, Any]) -> list[tuple[str, str]]:
    """The metrics dict as (name, formatted value) rows."""
    return [(k, fmt(v)) for k, v in metrics.items()]


def _cmd_analyze(a: argparse.Namespace) -> int:
    from .analysis.verify import analyze
    from .controllers import controller_from_expr
    from .firmware.bind import law_choices
    from .firmware.registry import structures
    from .jsonio import jsonable
    from .plant import check_dt, plant_from_expr

    for flag, given in (("--filter-n", a.filter_n is not None), ("--noise-gain", a.noise_gain is not None),
                        ("--no-filter-nyquist", a.no_filter_nyquist), ("--no-default-limits", a.no_default_limits)):
        if given:
            raise TunerError(f"{flag}: the default design limits are the tune's (they act on a structure's "
                             "parameters and the plant's scale); analyze checks the limits you give: --mks, --ms, "
                             "--mt, --control-peak, ...")
    spec = _spec_from_args(a)
    plot_fmt = _plot_format(a)
    if (a.plant is None) == (a.identified is None):
        raise TunerError("give --plant (a model) or --identified ID.json (a model identified from a log), not both")
    if (a.controller is None) == (a.structure is None):
        raise TunerError(f"give --controller (an expression) or --structure {'|'.join(structures())} "
                         "with --params (the law the vehicle flies, with its current gains), not both")
    if a.structure is not None and a.params is None:
        raise TunerError(f"--structure {a.structure}: needs --params FILE (the vehicle's parameters: its current "
                         "gains, loop rate and filters)")
    if a.params is not None and a.structure is None:
        raise TunerError(f"--params: give --structure {law_choices()} (the law the parameters belong to)")
    with field("--dt"):  # name the right argument (an s-plant ignores dt, so it would surface at --controller)
        check_dt(a.dt)
    vehicle, dt = _read_vehicle(a, a.structure), a.dt
    if vehicle is not None:
        from .firmware.bind import bind_law

        st, dt, now = bind_law(a.structure, vehicle, a.dt)
    if a.identified is not None:
        if a.delay:
            raise TunerError("--delay: an identified model carries its fitted delay: leave --delay out")
        plant = _load_identified(a.identified)
        label = f"identified model ({a.identified})"
    else:
        with field("--plant"):
            plant = plant_from_expr(a.plant, dt=dt, delay=a.delay)
        if vehicle is not None:  # a typed plant: the vehicle's gyro low-pass added (an identified one holds it)
            import dataclasses

            from .firmware.bind import typed_plant

            plant, rec = typed_plant(plant, vehicle)
            vehicle = dataclasses.replace(vehicle, typed_plant=rec, notes=(*vehicle.notes, rec["note"]))
        label = f"plant {plant.describe()}"
    if vehicle is not None:
        ctrl = st.tf(now, dt)
    else:
        with field("--controller"):
            ctrl = controller_from_expr(a.controller, dt=a.dt)
    act = _actuator(a)
    if act is not None and ctrl.dt is None:
        raise TunerError("--u-max: the saturated step runs the law at its sample time: give --dt and the controller "
                         "in z")
    res = analyze(plant, ctrl, spec, actuator=act, **({"structure": st.name, "gains": now} if vehicle is not None
                                                      else {}))
    from .design import dt_note

    slip = dt_note(res.loop.plant, res.loop.dt)  # a sample time implausible for the plant: the likely unit slip
    if slip:
        print(f"warning: {slip}", file=sys.stderr)
    out = res.to_dict()
    from .text import verdict, verdict_basis

    out.update(verdict=verdict([res]), basis=verdict_basis([res]))
    ident_info = None
    if a.identified is not None:
        from .tuning import identification_summary

        ident_info = out["identification"] = identification_summary(plant)
    if vehicle is not None:
        from .firmware.bind import vehicle_dict

        out = {"structure": st.name, "gains": now, "controller": ctrl.to_dict(), **out,
               "vehicle": vehicle_dict(vehicle)}
    if a.json:
        print(json.dumps(jsonable(out), indent=2))
    else:
        if vehicle is not None:
            print(f"the loop the vehicle flies: {st.name}, " + ", ".join(f"{k} = {v:.6g}" for k, v in now.items())
                  + f", dt = {dt:g} s (from {vehicle.source})")
            _print_vehicle_basis(vehicle_dict(vehicle), dt)
            for w in getattr(vehicle, "warnings", ()):
                print(f"warning: {w}")
        print_table(label, analysis_rows(out["metrics"]), out["checks"])
        if res.saturated is not None:
            _print_saturated(res.saturated)
        if res.measured is not None:
            _print_measured(res.measured)
        if ident_info:
            print(_identification_line(ident_info))
        print(f"controller {out['verdict']}")
    _write_plot(res, a, plot_fmt, spec)
    return EXIT_OK if res.meets_spec else EXIT_SPEC_NOT_MET


def _identification_line(info: dict[str, Any]) -> str:
    """The identification a result rests on, in one line: its rating, J, the time-domain check."""
    q = info.get("quality")
    line = (f"identification: rated {q} (J {fmt(float(info['cost'])) if 'cost' in info else 'n/a'}, time-domain check "
            f"{info.get('check', 'none')})")
    if q not in ("good", "acceptable"):
        line += ": below acceptable, so every figure here is the model's only"
    return line


def _print_measured(m: Any) -> None:
    """The loop on the measured frequency response next to the model's (analyze/tune with --identified)."""
    lo, hi = m.band_rad_s
    rows = []
    for name, key, rng in (("phase margin, deg", "phase_margin_deg", "phase_margin_range"),
                           ("gain margin, dB", "gain_margin_db", "gain_margin_range"), ("Ms", "ms", "ms_range")):
        a, b = getattr(m.measured, rng)
        rows.append((name, f"{fmt(getattr(m.model, key))}", f"{fmt(getattr(m.measured, key))}"
                     + (f" ({fmt(a)}..{fmt(b)})" if a == a else "")))
    print(f"on the measured response ({lo:.3g}-{hi:.3g} rad/s, {m.points} coherent points): figure, model, "
          "measured (its error range)")
    for r in rows:
        print(f"  {r[0]:<18} {r[1]:>10}   {r[2]}")
    for w in m.warnings:
        print(f"warning: {w}")
    for n in m.notes:
        print(f"note: {n}")


def _print_saturated(s: Any) -> None:
    """The step the actuator allows (--u-max with --step-size)."""
    m, act = s.metrics, s.actuator
    print(f"step of {act.step_size:g} with {act.u_min:g} <= u <= {act.u_max:g} ({s.law}): saturated "
          f"{100 * s.saturated_fraction:.1f} % of the step (up to settling; {s.saturated_time_s:.3g} s); "
          f"overshoot {fmt(m.overshoot_pct)} %, settling {fmt(m.settling_time_s)} s, rise {fmt(m.rise_time_s)} s, "
          f"peak |u| {fmt(m.control_peak)}")
    for n in s.notes:
        print(f"note: {n}")


def _print_vehicle_basis(vehicle: dict[str, Any], dt: float | None = None) -> None:
    """Where the loop rate came from, and every value assumed or read with a note (not only in the JSON)."""
    src = vehicle.get("loop_source")
    loop_hz = vehicle.get("loop_hz")
    if dt is not None and loop_hz and abs(1.0 / dt - loop_hz) > 1e-6 * loop_hz:
        print(f"loop rate: {1.0 / dt:g} Hz (the dt given)")
    elif src:
        print(f"loop rate: {fmt(loop_hz)} Hz from {src}")
    for n in vehicle.get("notes", ()):
        print(("assumed: " if "assumed" in n else "note: ") + n)


def _print_current(res: Any, out: dict[str, Any]) -> None:
    """The vehicle's current tune next to the proposed one (tune with --params)."""
    cur = out["current"]
    print(f"vehicle: {res.vehicle.get('firmware')} {res.vehicle.get('axis')} rate loop at "
          f"{fmt(res.vehicle.get('loop_hz'))} Hz (from {res.vehicle.get('source')})")
    _print_vehicle_basis(res.vehicle)
    for w in res.vehicle.get("warnings", ()):
        print(f"  warning: {w}")
    print("  current  " + ", ".join(f"{k} = {v:.6g}" for k, v in cur["gains"].items()))
    print("  proposed " + ", ".join(f"{k} = {v:.6g}" for k, v in res.gains.items()))
    keys = [k for k in out["metrics"] if k in cur["metrics"]]
    print(f"  {'metric':<28} {'current':>12} {'proposed':>12}")
    for k in keys:
        print(f"  {k:<28} {fmt(cur['metrics'][k]):>12} {fmt(out['metrics'][k]):>12}")
    print(f"  current tune {cur['verdict']}")


def _weights_note(gains: dict[str, float]) -> str:
    """pid2's setpoint weights in words: b (P on b r - y; b > 1 is feed-forward, PX4's FF = Kp (b - 1)) and c."""
    b, c, kp = gains.get("b"), gains.get("c"), gains.get("Kp")
    if b is None or c is None:
        return ""
    d = "D on the measurement" if c == 0 else f"D on {c:.4g} r - y"
    return f"; b = {b:.4g} (feed-forward Kp (b - 1) = {kp * (b - 1):.4g}), c = {c:.4g}: {d}"


def _note_compiles() -> None:
    """Say on stderr how many NLP shapes this run asked to be compiled in the background
    (tuner.optimize.nlp.codecache)."""
    codecache = sys.modules.get("tuner.optimize.nlp.codecache")  # (imported only where the tune built an NLP)
    n = codecache.started() if codecache is not None else 0
    if n:
        print(f"note: asked for the compiled NLP code of {n} new problem shape{'s' if n > 1 else ''}: built in the "
              "background, once per cache, at low priority (a shape of more than "
              f"{codecache.MAX_SOURCE_BYTES / 1e6:.0f} MB of C stays interpreted); later tunes load "
              f"{'them' if n > 1 else 'it'} and run faster. `python -m tuner.optimize.nlp.codecache` lists the "
              "compiled shapes; TUNER_NLP_COMPILE=load starts no compile", file=sys.stderr)


def _cmd_tune(a: argparse.Namespace) -> int:
    from .display import optimality_line
    from .plant import check_dt, plant_from_expr
    from .tuning import tune

    spec = _spec_from_args(a)
    plot_fmt = _plot_format(a)
    if (a.plant is None) == (a.identified is None):
        raise TunerError("give --plant (a model) or --identified ID.json (a model identified from a log), not both")
    if a.identified is None and (a.robust is not None or a.monte_carlo is not None):
        raise TunerError(f"{'--robust' if a.robust is not None else '--monte-carlo'}: needs --identified ID.json "
                         "(the uncertainty of an identified model)")
    plants: Any = []
    if a.identified is not None:
        if a.delay:
            raise TunerError("--delay: an identified model carries its fitted delay: leave --delay out")
        plants = _load_identified(a.identified)
    for i, text in enumerate(a.plant or ()):
        with field(f"--plant #{i + 1}" if len(a.plant) > 1 else "--plant"):
            plants.append(plant_from_expr(text, dt=a.dt, delay=a.delay))
    if a.budget is not None and not (0 < a.budget <= 3600):  # (nan fails too)
        raise TunerError("--budget: must be > 0 and <= 3600 seconds")
    with field("--dt"):
        check_dt(a.dt)
    if not (0 <= a.seed < 2**32):  # Optuna's sampler seeds numpy, which rejects anything else
        raise TunerError("--seed: must be an integer from 0 to 2**32 - 1")
    extra = {} if a.identified is None else {"robust": a.robust, "monte_carlo": a.monte_carlo}
    vehicle = _read_vehicle(a, a.structure)
    if vehicle is not None:
        extra["vehicle"] = vehicle
    from .firmware.bind import FIRMWARE_OF

    if a.structure in FIRMWARE_OF:  # the axis whose documented ranges the search keeps to (and the export writes)
        extra["axis"] = a.axis
    act = _actuator(a)
    if act is not None:
        extra["actuator"] = act
    res = tune(plants, structure=a.structure, spec=spec, dt=a.dt, seed=a.seed, time_budget_s=a.budget,
               effort=a.effort, **extra)
    _note_compiles()
    out = res.to_json()
    code = EXIT_OK if res.meets_spec else EXIT_SPEC_NOT_MET
    if a.json:
        print(json.dumps(out, indent=2))
        _write_plot(res, a, plot_fmt, res.spec)
        return code
    gains = ", ".join(f"{k} = {v:.6g}" for k, v in res.gains.items())
    c = res.controller
    var = "z" if c.dt else "s"
    for note in res.solver.get("notes", ()):
        print(f"note: {note}", file=sys.stderr)
    print(f"{res.structure}: {gains}")
    # every coefficient with the digits that round-trip (pasted back, the controller is the one verified: at 6
    # significant digits a PID's (z - 1) was lost, and with it the zero steady-state error), and the factored form
    # with the integrator exact
    print(f"C({var}) = [{', '.join(_exact(x) for x in c.num)}] / [{', '.join(_exact(x) for x in c.den)}]"
          + (f", dt = {_exact(c.dt)}" if c.dt else "") + (" (feedback part, on -y)" if c.two_dof else ""))
    print(f"       = {_factored(c, var)}")
    if c.two_dof:
        print(f"C_r({var}) = [{', '.join(_exact(x) for x in c.num_r)}] / [{', '.join(_exact(x) for x in c.den)}]"
              " (reference path, on r)" + _weights_note(res.gains))
    for i, an in enumerate(res.analyses):
        d = an.to_dict()
        title = res.label(i) + (" plant" if i == 0 and res.label(i) == "nominal" else "")
        print_table(title, analysis_rows(d["metrics"]), d["checks"])
    if res.analyses[0].saturated is not None:
        _print_saturated(res.analyses[0].saturated)
    if res.analyses[0].measured is not None:
        _print_measured(res.analyses[0].measured)
    if res.current:
        _print_current(res, out)
    s = res.solver
    print(f"solver: {s['method']}, {s['wall_time_s']:.2f} s, {s['global_evaluations']} global evaluations, "
          f"{s['starts_tried']} NLP starts, {s['nlp_iterations']} NLP iterations, seed {s['seed']}")
    print(optimality_line(s))
    from .display import design_lines

    for d in design_lines(s):
        print(d)
    many = len(res.analyses) > 1
    print(f"objective {res.spec.objective} = {fmt(out['objective']['value'])}"
          + (" (worst over the plants)" if many else ""))
    rd = res.robust
    if rd is not None and rd.k is not None:
        print(f"robust: {rd.k:g}-sigma set of {rd.n_plants} plants (corners of {', '.join(rd.corners)}"
              + (f"; +-{rd.k:g} sigma of {', '.join(rd.axes)}" if rd.axes else "") + ")")
    if rd is not None and rd.monte_carlo is not None:
        mc = rd.monte_carlo
        print(mc.summary())
        print("  meeting each constraint: " + ", ".join(f"{k} {100 * v:.1f} %" for k, v in mc.fraction_meeting.items()))
    for lim in res.limits:
        print(f"design limit: {lim['rule']}" + (" (a default; --no-default-limits lifts it)" if lim.get("default")
                                                 else ""))
    for e in out["at_bounds"]:
        print(f"at a bound: {e['text']}")
    if res.identification is not None:
        print(_identification_line(res.identification))
    text = res.verdict
    if many and res.meets_spec:
        text = text.replace("meets the spec", "meets the spec on every plant", 1)
    elif out["reasons"] or any(not c.name.startswith("measured_") and c.name != "identification_quality"
                               for c in res.failing):
        text += " (best found)"
    print(text)
    for r in out["reasons"]:
        hint = suggestion_flags(r["suggest"])
        print(f"  why: {in_flags(r['message'])}" + (f" [try {hint}]" if hint else ""))
    from .text import changes_line

    if res.vehicle and res.vehicle.get("changes"):
        print(f"warning: {changes_line(res.vehicle['changes'])}")
    _write_plot(res, a, plot_fmt, res.spec)
    return code


def _cmd_tradeoff(a: argparse.Namespace) -> int:
    from .plant import check_dt, plant_from_expr
    from .tradeoff import tradeoff

    spec = _spec_from_args(a)
    with field("--dt"):
        check_dt(a.dt)
    plants = []
    for i, text in enumerate(a.plant):
        with field(f"--plant #{i + 1}" if len(a.plant) > 1 else "--plant"):
            plants.append(plant_from_expr(text, dt=a.dt, delay=a.delay))
    if not (0 < a.budget <= 3600):
        raise TunerError("--budget: must be > 0 and <= 3600 seconds")
    if not 2 <= a.points <= 20:
        raise TunerError("--points: must be from 2 to 20")
    if spec.objective not in ("settling_time", "auto"):
        raise TunerError("--objective: the trade-off's speed axis is the settling time; leave --objective out")
    res = tradeoff(plants, structure=a.structure, spec=spec, dt=a.dt, x=a.x, y=a.y, points=a.points, seed=a.seed,
                   time_budget_s=a.budget)
    _note_compiles()
    code = EXIT_OK if res.meets_spec else EXIT_SPEC_NOT_MET
    if a.json:
        print(json.dumps(res.to_json(), indent=2))
        return code
    if not res.meets_spec:
        print("the spec itself is not met: no trade-off curve (relax it first)")
        for r in res.reasons:
            hint = suggestion_flags(r.suggest)
            print(f"  why: {in_flags(r.message)}" + (f" [try {hint}]" if hint else ""))
        return code
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"{res.structure}: settling time vs {res.y}, fastest first (every point verified)")
    for col in ("#", "settling_time_s", res.y, f"{res.y} limit", "gains"):
        t.add_column(col)
    for k, ((ts, y), lim, r) in enumerate(zip(res.values(), res.limits, res.points)):
        t.add_row(str(k), fmt(ts), fmt(y), "spec" if lim is None else fmt(lim),
                  ", ".join(f"{n} = {v:.4g}" for n, v in r.gains.items()))
    Console(highlight=False).print(t)
    for sk in res.skipped:
        print(f"left out: {res.y} <= {fmt(sk['limit'])}: {sk['why']}")
    print(f"{len(res.points)} points in {res.wall_time_s:.2f} s")
    return code


def _load_identified(path: str) -> Any:
    """The :class:`~tuner.identify.IdentifyResult` in ``path`` (the JSON of ``tuner identify --json``), read by the
    bounded reader (a size limit, a regular file only, binary and deep nesting refused)."""
    from .fileio import read_json
    from .identify.result import IdentifyResult

    d = read_json(path, label=f"--identified {path}", field="identified",
                  hint="give the JSON of 'tuner identify --json'")
    if not isinstance(d, dict):
        raise TunerError(f"--identified {path}: not the JSON of 'tuner identify --json' (not an object)")
    try:
        return IdentifyResult.from_dict(d)  # its fields checked first (tuner.identify.resultfile)
    except TunerError as e:
        raise TunerError(f"--identified {path}: {e}; give the JSON of 'tuner identify --json'") from None
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as e:
        raise TunerError(f"--identified {path}: not the JSON of 'tuner identify --json' (missing or bad "
                         f"{e})") from None


_COMMANDS = {"analyze": _cmd_analyze, "tune": _cmd_tune, "tradeoff": _cmd_tradeoff}


_ARGUMENTS = {"controller": "--controller", "gains": "--controller", "dt": "--dt", "delay": "--delay",
              "structure": "--structure", "time_budget_s": "--budget", "seed": "--seed", "spec": "spec",
              "effort": "--effort", "points": "--points", "x": "--x", "y": "--y", "robust": "--robust",
              "monte_carlo": "--monte-carlo", "params": "--params", "vehicle": "--params", "actuator": "--u-max"}


def _argument_of(f: tuple[str | int, ...]) -> str | None:
    """The command-line argument a library error's ``field`` is about (``("plants", 1, "delay")`` -> --delay)."""
    if not f:
        return None
    if f[0] in ("plants", "plant"):
        rest = f[2:] if len(f) > 1 and isinstance(f[1], int) else f[1:]
        if rest[:1] in (("delay",), ("dt",)):
            return _ARGUMENTS[str(rest[0])]
        return f"--plant #{f[1] + 1}" if len(f) > 1 and isinstance(f[1], int) and f[1] > 0 else "--plant"
    return _ARGUMENTS.get(str(f[0]))


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``tuner`` with ``argv`` (default ``sys.argv[1:]``); returns the exit code (``tuner --help``: the codes)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")
    handler = _COMMANDS.get(args.cmd) or getattr(args, "handler", None)
    try:
        return int(handler(args))
    except TunerError as e:
        msg = str(e)
        arg = _argument_of(e.field)
        if arg and not msg.startswith("-"):
            msg = f"{arg}: {msg}"
        print(f"tuner: error: {msg}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("tuner: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # a bug, not the user's input: say so, and keep exit 1 meaning "spec not met"
        if args.verbose:
            log.exception("internal error")
        print(f"tuner: internal error ({type(e).__name__}: {e}); this is a bug, please report it "
              "(-v prints the traceback)", file=sys.stderr)
        return EXIT_INTERNAL


def entry() -> None:
    """The ``tuner`` command (and ``python -m tuner.cli``): :func:`main`, then the process ends.

    A process that built NLPs ends without freeing them: the build cache holds their CasADi expression graphs (up to
    tuner.optimize.nlp.transcribe.CACHE_MB), and taking them apart one node at a time at exit achieves nothing the
    kernel does not do at once (the 133 problems of a 40-loop study run: 1.7 s of a 43 s command). The exit
    handlers still run and the output is flushed; output that cannot be written is said on stderr with exit status
    120, as the interpreter's exit does; a thread still running (none is, after a command) gets the usual exit, which
    waits for it."""
    import os
    import threading

    rc = main()
    nlp = sys.modules.get("tuner.optimize.nlp.transcribe")
    alive = [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon and t.is_alive()]
    if nlp is not None and nlp.cached_count() and not alive:
        import atexit

        atexit._run_exitfuncs()  # (what the interpreter's own exit runs: logging's flush, multiprocessing's joins)
        # what the interpreter's exit would say of output it could not write (a full disk, a reader gone): the
        # message, and its exit status 120
        for stream in dict.fromkeys((sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__)):
            try:
                if stream is not None and not stream.closed:
                    stream.flush()
            except (OSError, ValueError) as e:
                rc = 120
                try:
                    os.write(2, f"tuner: error: output not written: {e}\n".encode())
                except OSError:
                    pass
        os._exit(rc)
    sys.exit(rc)


if __name__ == "__main__":  # pragma: no cover
    entry()
