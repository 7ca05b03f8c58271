"""``tuner identify FILE.csv|FILE.ulg ...``: a transfer function from logged records.

Registered in :mod:`tuner.cli` through ``_EXTRA_COMMANDS``. Exit codes: 0 success; 1 with
``--check`` when the fit is poor (J > 100) or the time-domain check is poor; 2 bad input (one
line naming the problem).
"""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

from ..errors import TunerError

__all__ = ["add_parser", "parse_delay", "parse_holdout", "read_records"]

_OPTION = {"input": "--input", "output": "--output", "time": "--time", "rate_hz": "--rate", "band": "--band",
           "poles": "--poles", "zeros": "--zeros", "delay": "--delay", "delay_step": "--delay-step",
           "holdout": "--holdout", "coherence_min": "--coherence-min", "n_points": "--points", "seed": "--seed",
           "windows_s": "--windows", "verify": "--verify", "reference": "--reference", "hold": "--hold",
           "time_unit": "--time-unit"}


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


def parse_holdout(text: str) -> str | float:
    """``auto`` or a fraction."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto or a fraction (0 to 0.5), got {text!r}") from None


def read_records(files: list[str], a: argparse.Namespace) -> dict[str, Any]:
    """The records of CSV or ULog files as ``identify`` arguments (``input``, ``output``, ``time``, ``rate_hz``):
    one file, one record (a ULog log split at gaps may give several); several files are fitted together."""
    from .csvlog import read_columns
    from .feedback import signs_of
    from .ulog import open_log, read_ulog

    ref = getattr(a, "reference", None)
    us, ys, rs, ts, rate, csv_time = [], [], [], [], a.rate, False
    signs: list[str] = []
    params: dict[str, float] = {}
    kinds = set()
    flight: dict[str, Any] = {}
    biased = ""
    for f in files:
        with open_log(f) as (kind, fh):  # opened once: told CSV or ULog, and read, from one handle
            if kind in ("ulog", "dataflash"):
                kinds.add("ulog")  # (a log's input is held onto its grid, either kind)
                if a.time is not None:
                    raise TunerError(f"{f}: --time names a CSV column; a flight log is put on a grid at --rate HZ",
                                     field="time")
                cols = {"input": a.input, "output": a.output, **({"reference": ref} if ref is not None else {})}
                if kind == "dataflash":
                    from .dataflash import read_dataflash

                    r = read_dataflash(fh.name, cols, rate_hz=rate)
                else:
                    r = read_ulog(fh, cols, rate_hz=rate)
                if rate is None:
                    rate = r.rate_hz
                us += r.inputs
                ys += r.outputs
                rs += r.references or []
                ts += [None] * len(r.inputs)
                params = params or r.parameters
                flight = flight or r.flight
                biased = biased or r.flight.get("reference_biased", "")
                for n in r.flight.get("notes", ()):
                    _note(f"{f}: {n}")
                signs += [x for x in signs_of(a.input, r.parameters) if x not in signs]
                for lo, hi in r.dropped:
                    _note(f"{f}: {hi - lo:.3g} s between gaps ({lo:.3f}-{hi:.3f} s) is too short to use and was "
                          "dropped")
                if r.gaps:
                    _note(f"{f}: {r.describe()}")
            else:
                if (a.time is None) == (a.rate is None):
                    raise TunerError(f"{f}: a CSV log needs --time COL (a time column) or --rate HZ", field="time")
                kinds.add("csv")
                cols = {"input": a.input, "output": a.output, **({"time": a.time} if a.time is not None else {}),
                        **({"reference": ref} if ref is not None else {})}
                d = read_columns(f, cols, handle=fh)
                us.append(d["input"])
                ys.append(d["output"])
                if ref is not None:
                    rs.append(d["reference"])
                ts.append(d.get("time"))
                csv_time = csv_time or a.time is not None
                signs += [x for x in signs_of(a.input) if x not in signs]
    if csv_time and any(t is None for t in ts):
        raise TunerError("mixing CSV logs with a --time column and ULog logs: give --rate for all", field="time")
    extra = {"signs": signs, "parameters": params, "kinds": kinds, "reference_biased": biased,
             "firmware": flight.get("firmware")}
    if len(us) == 1:
        return {"input": us[0], "output": ys[0], "time": ts[0] if csv_time else None,
                "rate_hz": None if csv_time else rate, "reference": rs[0] if rs else None, **extra}
    return {"input": us, "output": ys, "time": ts if csv_time else None, "rate_hz": None if csv_time else rate,
            "reference": rs if rs else None, **extra}


def _note(text: str) -> None:
    import sys

    print(f"note: {text}", file=sys.stderr)


def add_parser(sub: Any) -> None:
    """Register ``tuner identify`` on the subcommand parsers ``sub``."""
    p = sub.add_parser("identify",
                       help="identify a transfer function from logged records (CSV, PX4 ULog, ArduPilot DataFlash)",
                       description="Frequency response with coherence (composite Welch windows), a transfer "
                                   "function fitted by CIFER's cost J over the coherent band, Cramér–Rao bounds, "
                                   "and a time-domain check (on a verification record, the held-out end of the "
                                   "log, or the fitted record), judged against the noise floor. Several files "
                                   "are fitted together (their spectra averaged).")
    p.add_argument("file", nargs="+", help="CSV log with a header row, a PX4 ULog log (.ulg) or an ArduPilot "
                                           "DataFlash log (.bin); several files: one fit from all of them (e.g. "
                                           "repeated sweeps)")
    p.add_argument("--file", dest="more_files", action="append", default=[], metavar="FILE",
                   help="another log fitted with the others (repeatable)")
    base = p.add_mutually_exclusive_group()
    base.add_argument("--time", metavar="COL", help="CSV: time column, s (uniformly sampled)")
    p.add_argument("--time-unit", choices=("auto", "s", "ms", "us"), default="auto",
                   help="CSV: the time column's unit: s, ms, or us (a microsecond timestamp, as PX4's CSV exports "
                        "have); auto (default): seconds, and a column whose steps look like another unit (whole "
                        "numbers of 100 and more, or 0.1 to 1) is refused until its unit is given")
    base.add_argument("--rate", type=float, metavar="HZ",
                      help="CSV: sample rate, when there is no time column; ULog: the grid the topics are "
                           "resampled onto (default: the slower topic's rate)")
    p.add_argument("--input", required=True, metavar="COL",
                   help="plant input: a CSV column, a ULog TOPIC[:INSTANCE].FIELD (e.g. "
                        "vehicle_torque_setpoint.xyz[0]) or a DataFlash MESSAGE.FIELD (e.g. RATE.ROut); held between "
                        "its samples")
    p.add_argument("--output", required=True, metavar="COL",
                   help="plant output: a CSV column, a ULog TOPIC[:INSTANCE].FIELD (e.g. "
                        "vehicle_angular_velocity.xyz[0]) or a DataFlash MESSAGE.FIELD (e.g. RATE.R); interpolated "
                        "linearly")
    p.add_argument("--reference", metavar="COL",
                   help="data flown under feedback (every flight log): the exogenous signal, an injected excitation "
                        "or the rate setpoint flown in a rate mode (CSV column or ULog TOPIC.FIELD, held); the "
                        "response is then the joint estimate S_ry/S_ru, unbiased by the feedback when the reference is "
                        "exogenous (a rate setpoint flown in an attitude mode is not: the estimate is then reported "
                        "biased by the outer loop)")
    p.add_argument("--hold", choices=("auto", "zoh", "none"), default="auto",
                   help="how the plant saw the input between samples: zoh (a controller's output, held), none (a "
                        "sampled continuous signal, e.g. a stick); auto (default): zoh for a ULog log, whose input "
                        "is held onto its grid, none for a CSV log. With zoh the model put back at the log's rate "
                        "with a zero-order hold reproduces the measured response (the hold counted once)")
    p.add_argument("--poles", required=True, type=int, metavar="N", help="number of poles (1-8)")
    p.add_argument("--zeros", type=int, default=0, metavar="M", help="number of zeros (0-N, default 0)")
    p.add_argument("--delay", type=parse_delay, default="auto", metavar="auto|none|S",
                   help="equivalent time delay: auto (estimate, default), none, or seconds")
    p.add_argument("--delay-step", type=float, default=None, metavar="DT",
                   help="restrict the delay to whole multiples of DT (optional: the tuner takes the delay as "
                   "fitted, exactly, also in a sampled-data loop)")
    p.add_argument("--band", type=float, nargs=2, default=None, metavar=("WMIN", "WMAX"),
                   help="fit band, rad/s (default: where the coherence >= 0.6)")
    p.add_argument("--holdout", type=parse_holdout, default="auto", metavar="auto|F",
                   help="time-domain check data: auto (default: the last 20 %% if it excites the band and "
                        "is not the top of the sweep, else the fitted record), a fraction held out at the end, "
                        "or 0 (no check)")
    p.add_argument("--verify", metavar="FILE", default=None,
                   help="a separate verification record (e.g. doublets; same columns or topics): the "
                        "time-domain check runs on it and nothing is held out")
    p.add_argument("--coherence-min", type=float, default=0.6, metavar="C", help="fit threshold (0.6)")
    p.add_argument("--points", type=int, default=25, metavar="N", help="fit frequencies in the band (25)")
    p.add_argument("--seed", type=int, default=0, help="seed of the fit's random starts (0)")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    p.add_argument("--plot", metavar="OUT.png", help="write the Bode/coherence plot (png, svg, pdf)")
    p.add_argument("--check", action="store_true",
                   help="exit 1 when the fit is poor (J > 100) or the time-domain check is poor")
    p.set_defaults(handler=_cmd_identify)


def _run(a: argparse.Namespace):
    from . import identify

    files = [*a.file, *a.more_files]
    try:
        data = read_records(files, a)
        verify = None
        if a.verify is not None:
            v = read_records([a.verify], argparse.Namespace(**{**vars(a), "reference": None}))
            if isinstance(v["input"], list):
                raise TunerError(f"--verify {a.verify}: the verification log has gaps; give one continuous record",
                                 field="verify")
            verify = {k: v[k] for k in ("input", "output", "time", "rate_hz") if v[k] is not None}
        hold = {"zoh": "zoh", "none": None}.get(a.hold, "zoh" if data["kinds"] == {"ulog"} else None)
        controller = None
        if data["parameters"]:
            from .feedback import known_controller

            rate = data["rate_hz"] or (1.0 / float(data["time"][1] - data["time"][0]) if data["time"] is not None
                                       else None)
            controller = known_controller(data["parameters"], a.input, 1.0 / rate) if rate else None
        return identify(data["input"], data["output"], time=data["time"], rate_hz=data["rate_hz"], poles=a.poles,
                        zeros=a.zeros, delay=a.delay, delay_step=a.delay_step, band=a.band, holdout=a.holdout,
                        verify=verify, coherence_min=a.coherence_min, n_points=a.points, seed=a.seed,
                        reference=data["reference"], controller=controller, closed_loop_signs=data["signs"],
                        hold=hold, time_unit=a.time_unit, reference_biased=data["reference_biased"],
                        firmware=data["firmware"])
    except TunerError as e:
        opt = _OPTION.get(str(e.field[0]) if e.field else "")
        if opt is None or any(str(e).startswith(str(f)) for f in files + [a.verify]):
            raise
        name = {"--input": a.input, "--output": a.output, "--time": a.time, "--verify": a.verify}.get(opt)
        raise TunerError(f"{opt}{' ' + name if name else ''}: {e}", field=e.field) from e


def _cmd_identify(a: argparse.Namespace) -> int:
    from ..jsonio import jsonable

    if a.plot:  # a target that cannot take it (a device, a FIFO, a directory) is refused before the work
        from ..fileio import check_output

        check_output(a.plot, label=f"--plot {a.plot}")
    res = _run(a)
    if a.plot:
        import io
        from pathlib import Path

        from ..fileio import write_output

        buf = io.BytesIO()
        try:  # the format from the name's suffix, as savefig to a path would (png without one)
            res.plot().savefig(buf, format=Path(a.plot).suffix[1:].lower() or None, dpi=110)
        except ValueError as e:
            raise TunerError(f"--plot {a.plot}: {e}") from None
        write_output(a.plot, buf.getvalue(), label=f"--plot {a.plot}")  # a regular file, all of it, or exit 2
    if a.json:
        print(json.dumps(jsonable(res.to_dict()), indent=2))
    else:
        _print(res, a)
    return 1 if (a.check and (res.quality in ("poor", "closed-loop") or res.check == "poor")) else 0


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
    est = res.options.get("estimate", "direct")
    con.print(f"band {lo:.4g}-{hi:.4g} rad/s, {res.fit_points.w.size} fit frequencies ({est} estimate); cost J = "
              f"{res.cost:.4g}: {res.quality} (CIFER: <= 50 good, <= 100 acceptable)")
    cl = res.closed_loop
    if cl.get("detected"):
        con.print(("[red]closed loop:[/red] " if res.unreliable_feedback else "closed loop: ") + cl["message"])
        if res.unreliable_feedback:
            con.print("  identify again with --reference COL (the exogenous signal's column or TOPIC.FIELD)")
    hc = res.options.get("hold_check")
    if hc and hc.get("checked"):
        con.print(f"hold counted once: the model with a zero-order hold at {1 / res.rate_hz:g} s against the measured "
                  f"response: median {hc['median_db']:.2g} dB, {hc['median_deg']:.2g} deg (max {hc['max_db']:.2g} dB, "
                  f"{hc['max_deg']:.2g} deg)")
    v = res.validation
    if v is not None:
        con.print(f"time-domain check {v.describe()}")
    else:
        con.print("time-domain check: none")
    for n in res.options.get("notes", ()):
        con.print(f"note: {n}")
    for w in res.warnings:
        if not (cl.get("detected") and w == cl.get("message")):
            con.print(f"[yellow]warning:[/yellow] {w}")
    if a.plot:
        con.print(f"wrote {a.plot}")
