"""``tuner identify FILE.csv ...``: a transfer function from a logged record.

Registered in :mod:`tuner.cli` through ``_EXTRA_COMMANDS``. Exit codes: 0 success; 1 with
``--check`` when the fit is poor (J > 100); 2 bad input (one line naming the problem).
"""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

from ..errors import TunerError

__all__ = ["add_parser", "parse_delay"]

_OPTION = {"input": "--input", "output": "--output", "time": "--time", "rate_hz": "--rate", "band": "--band",
           "poles": "--poles", "zeros": "--zeros", "delay": "--delay", "delay_step": "--delay-step",
           "holdout": "--holdout", "coherence_min": "--coherence-min", "n_points": "--points", "seed": "--seed",
           "windows_s": "--windows"}


def parse_delay(text: str) -> str | float | None:
    """``auto`` -> ``"auto"``, ``none`` -> ``None``, else seconds."""
    t = text.strip().lower()
    if t == "auto":
        return "auto"
    if t in ("none", "0"):
        return None
    try:
        v = float(t)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto, none or seconds, got {text!r}") from None
    if not math.isfinite(v) or v < 0:
        raise argparse.ArgumentTypeError(f"a delay must be finite and >= 0 s, got {text!r}")
    return v


def add_parser(sub: Any) -> None:
    """Register ``tuner identify`` on the subcommand parsers ``sub``."""
    p = sub.add_parser("identify", help="identify a transfer function from a logged record (CSV)",
                       description="Frequency response with coherence (composite Welch windows), a transfer "
                                   "function fitted by CIFER's cost J over the coherent band, Cramér–Rao bounds, "
                                   "and a check on held-out data.")
    p.add_argument("file", help="CSV log with a header row")
    base = p.add_mutually_exclusive_group(required=True)
    base.add_argument("--time", metavar="COL", help="time column, s (uniformly sampled)")
    base.add_argument("--rate", type=float, metavar="HZ", help="sample rate, when there is no time column")
    p.add_argument("--input", required=True, metavar="COL", help="plant input column (e.g. the command)")
    p.add_argument("--output", required=True, metavar="COL", help="plant output column (e.g. the angle)")
    p.add_argument("--poles", required=True, type=int, metavar="N", help="number of poles (1-8)")
    p.add_argument("--zeros", type=int, default=0, metavar="M", help="number of zeros (0-N, default 0)")
    p.add_argument("--delay", type=parse_delay, default="auto", metavar="auto|none|S",
                   help="equivalent time delay: auto (estimate, default), none, or seconds")
    p.add_argument("--delay-step", type=float, default=None, metavar="DT",
                   help="delay in whole multiples of DT (the loop's sample time)")
    p.add_argument("--band", type=float, nargs=2, default=None, metavar=("WMIN", "WMAX"),
                   help="fit band, rad/s (default: where the coherence >= 0.6)")
    p.add_argument("--holdout", type=float, default=0.2, metavar="F",
                   help="fraction at the end of the log kept for the time-domain check (0.2)")
    p.add_argument("--coherence-min", type=float, default=0.6, metavar="C", help="fit threshold (0.6)")
    p.add_argument("--points", type=int, default=25, metavar="N", help="fit frequencies in the band (25)")
    p.add_argument("--seed", type=int, default=0, help="seed of the fit's random starts (0)")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    p.add_argument("--plot", metavar="OUT.png", help="write the Bode/coherence plot (png, svg, pdf)")
    p.add_argument("--check", action="store_true", help="exit 1 when the fit is poor (J > 100)")
    p.set_defaults(handler=_cmd_identify)


def _run(a: argparse.Namespace):
    from . import identify
    from .csvlog import read_columns

    cols = {"input": a.input, "output": a.output}
    if a.time is not None:
        cols["time"] = a.time
    try:
        data = read_columns(a.file, cols)
        return identify(data["input"], data["output"], time=data.get("time"), rate_hz=a.rate, poles=a.poles,
                        zeros=a.zeros, delay=a.delay, delay_step=a.delay_step, band=a.band, holdout=a.holdout,
                        coherence_min=a.coherence_min, n_points=a.points, seed=a.seed)
    except TunerError as e:
        opt = _OPTION.get(str(e.field[0]) if e.field else "")
        if opt is None or str(e).startswith(str(a.file)):
            raise
        name = {"--input": a.input, "--output": a.output, "--time": a.time}.get(opt)
        raise TunerError(f"{opt}{' ' + name if name else ''}: {e}", field=e.field) from e


def _cmd_identify(a: argparse.Namespace) -> int:
    from ..jsonio import jsonable

    res = _run(a)
    if a.plot:
        fig = res.plot()
        try:
            fig.savefig(a.plot, dpi=110)
        except (ValueError, OSError) as e:
            raise TunerError(f"--plot {a.plot}: cannot write: {e}") from None
    if a.json:
        print(json.dumps(jsonable(res.to_dict()), indent=2))
    else:
        _print(res, a)
    return 1 if (a.check and res.quality == "poor") else 0


def _print(res: Any, a: argparse.Namespace) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console(highlight=False, soft_wrap=True)  # long lines (paths) are not broken
    con.print(f"G(s) = {res.describe()}")
    t = Table(title="parameters (1-sigma Cramér–Rao bound and insensitivity)")
    for c in ("parameter", "value", "CR bound", "CR %", "insensitivity %"):
        t.add_column(c, justify="left" if c == "parameter" else "right")
    for name, u in res.uncertainty.items():
        t.add_row(name, f"{u.value:.5g}", f"{u.cr_bound:.3g}", f"{u.cr_bound_pct:.3g}", f"{u.insensitivity_pct:.3g}")
    con.print(t)
    lo, hi = res.band_rad_s
    con.print(f"band {lo:.4g}-{hi:.4g} rad/s, {res.fit_points.w.size} fit frequencies; cost J = {res.cost:.4g} "
              f"({res.quality}; CIFER: <= 50 good, <= 100 acceptable)")
    v = res.validation
    if v is not None:
        con.print(f"held-out check ({v.t_start_s:.4g}-{v.t_start_s + v.duration_s:.4g} s): Theil {v.theil_u:.3g} "
                  f"(<= 0.3), NRMSE {v.nrmse:.3g} (fit {v.fit_pct:.3g} %), rms error {v.rms_error:.3g}")
    for w in res.warnings:
        con.print(f"[yellow]warning:[/yellow] {w}")
    if a.plot:
        con.print(f"wrote {a.plot}")
