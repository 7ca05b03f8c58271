"""A tuned firmware rate law as the parameter file its ground station loads.

* ``px4``: QGroundControl ``.params`` lines, ``vehicle-id<TAB>component-id<TAB>NAME<TAB>value<TAB>type`` (type 9 =
  float), for the axis: ``MC_<AXIS>RATE_P/I/D/FF/K`` and ``MC_<A>R_INT_LIM`` (and the attitude ``MC_<AXIS>_P`` when
  one is given);
* ``ardupilot``: Mission Planner ``NAME,value`` lines: ``ATC_RAT_<AX>_P/I/D/FF/IMAX/FLTT/FLTE/FLTD`` (and
  ``ATC_ANG_<AX>_P`` when one is given).

What is written, and what is refused (:class:`~tuner.errors.TunerError` naming the field: exit 2, HTTP 422):

* **The result's axis.** A result tuned for a vehicle's axis is written for that axis; another one is refused (the
  gains, ``K`` and the integrator limit are that axis's). A result without a vehicle is written for ``axis``
  (default roll).
* **What the firmware stores.** Each value as the firmware holds it, in single precision (both firmwares store these
  parameters as float32), written with the fewest digits that read back to it; a value no vehicle can hold (not
  finite, beyond float32's range) is refused. The zero rule (:func:`tuner.firmware.names.stored_value`): a value
  below float32's resolution (2^-23) times the parameter's scale is written as 0 (a gain 0 at the optimum showed as
  ``6.16627746e-18``).
* **The documented ranges** (:data:`tuner.firmware.names.RANGES`, per firmware and axis, from the firmware's parameter
  metadata): a value outside is refused, saying what is true of it (the ranges are what ground stations check edits
  against; neither firmware enforces them) and what would bring it inside; ``force`` writes it anyway, named in the
  header.
* **The verdict.** A result that does not meet its spec, or meets it on the model only (its identification rated
  below acceptable), is refused unless ``force``; then the header says so.

A ``#`` header states the tool's version and the date, the vehicle (or that the firmware's defaults were assumed) and
every warning about its parameters, the loop rate and the filters the design assumed, and what was verified where:
the figures on the model, those on the measured response (only these, where they pass, are called verified: the
airframe's data confirmed them), the identification's rating, the verdict, and a change of the crossover or a gain
by more than 3x against the vehicle's current tune. Every text from a file or a log (a vehicle's file name, a
warning) is sanitised: no control character (a newline, a tab) reaches a line of the file.
"""

from __future__ import annotations

import datetime as _dt
import math
import unicodedata
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._lazy import installed_version
from ..errors import TunerError
from ..firmware.laws import LATER_FIXED
from ..firmware.names import AXES, law_names, range_problem, stored_value
from ..firmware.registry import by_format, formats, get_firmware

__all__ = ["PARAM_FORMATS", "ParamFile", "param_file", "make_param_file", "clean"]



class _Formats(Mapping):
    """export format -> (the law it writes, the firmware), for every registered firmware."""

    def __getitem__(self, fmt: str) -> tuple[str, str]:
        fw = by_format(fmt)
        if fw is None:
            raise KeyError(fmt)
        return fw.structure, fw.name

    def __iter__(self) -> Iterator[str]:
        return iter(formats())

    def __len__(self) -> int:
        return len(formats())


#: export format -> (the law it writes, the firmware)
PARAM_FORMATS: Mapping[str, tuple[str, str]] = _Formats()
#: a gain stored as a whole number (Betaflight's P, I, D, F) that moves by more than this share is said in a warning
ROUNDING_SAID = 0.01
_MAX_TEXT = 300  # a header's text from a file or a log, at most (characters)


@dataclass(frozen=True)
class ParamFile:
    """A parameter file: its ``text``, the file ``name`` to save it as, and the ``warnings`` to say before it is
    written (each also in the header)."""

    text: str
    name: str
    warnings: tuple[str, ...] = ()


def clean(text: Any, limit: int = _MAX_TEXT) -> str:
    """``text`` for one line of a file: every control or separator character (a newline, a tab, a carriage return,
    U+2028) shown as its escape, at most ``limit`` characters.

    Examples
    --------
    >>> from tuner.export.paramfile import clean
    >>> clean("quad.params\\n1\\t1\\tMC_ROLLRATE_P\\t9")
    'quad.params\\\\x0a1\\\\x091\\\\x09MC_ROLLRATE_P\\\\x099'
    """
    out = []
    for c in str(text):
        cat = unicodedata.category(c)
        out.append(c if cat[0] != "C" and cat not in ("Zl", "Zp") else f"\\x{ord(c):02x}" if ord(c) < 256
                   else f"\\u{ord(c):04x}")
    s = "".join(out)
    return s if len(s) <= limit else s[: limit - 3] + "..."


def _written(v: float) -> str:
    """A stored (float32) value with the fewest digits that read back to it."""
    f = np.float32(v)
    if f == 0:
        return "0.0"
    if 1e-4 <= abs(float(f)) < 1e7:
        return np.format_float_positional(f, unique=True, trim="0")
    return np.format_float_scientific(f, unique=True, trim="-")


def _num(v: Any) -> float:
    """A number from a result's JSON (the strings of non-finite numbers included); nan when it is none."""
    if isinstance(v, bool):
        return math.nan
    if isinstance(v, (int, float)):
        return float(v)
    return {"Infinity": math.inf, "-Infinity": -math.inf}.get(v, math.nan) if isinstance(v, str) else math.nan


def _g(v: Any, unit: str = "") -> str:
    x = _num(v)
    return "n/a" if math.isnan(x) else f"{x:.4g}{unit}"


def _advice(fw: str, key: str, side: str) -> str:
    """What brings a tuned gain back inside its documented range (the direction a value outside points to)."""
    if key in ("P", "D", "FF") and side == "low":
        return ("a gain below the range means the identified plant's gain is high: check the identification's units "
                f"({fw}'s law takes the rate in rad/s and gives a normalised torque, -1..1; a rate logged in deg/s "
                "makes the plant 57 times too strong and the gains 57 times too small), or that its input is the "
                "torque the law commands")
    if key in ("P", "D", "FF") and side == "high":
        return ("a gain above the range means the identified plant's gain is low (check the identification's units and "
                "input) or that the spec asks for more than the vehicle gives: a lower bandwidth or crossover "
                "(--wc, --settling-max) brings it down")
    if key == "I" and side == "low":
        return ("the design needs (almost) no integral action; demand it with --ki-min, or tune for the load response "
                "(--objective iae)")
    if key == "I" and side == "high":
        return "a slower integral action: a lower crossover (--wc), or a settling-time limit (--settling-max)"
    if key == "att_p":
        return "give an attitude P inside the range (--att-p)"
    return "this value is the vehicle's own (its parameter file): correct it there and tune again"


def _refuse_value(fw: str, name: str, key: str, v: float, prob: dict, k_law: tuple[str, float] | None = None
                  ) -> TunerError:
    """A tuned value outside its documented range, refused; ``k_law``: the law's gain scale (PX4's ``K``)."""
    lo, hi = prob["lo"], prob["hi"]
    rng = f"[{lo:g}, {hi:g}]" if math.isfinite(hi) else f">= {lo:g}"
    scaled = (f" ({get_firmware(fw).title} multiplies P, I and D by {k_law[0]} = {k_law[1]:g}: the law's gains are "
              "these times it)"
              if k_law is not None and key in ("P", "I", "D") and k_law[1] != 1 else "")
    return TunerError(
        f"{name} = {v:.6g} is outside {fw}'s documented range {rng} ({prob['source']}): the range is the parameter "
        "metadata that ground stations check edits against (neither firmware enforces it), so a ground station may "
        "refuse the file or the value; " + _advice(fw, key, prob["side"]) + scaled
        + "; --force (HTTP force=true) writes it anyway, named in the header", field=("gains", key))


def _verified_lines(result: Mapping[str, Any]) -> list[str]:
    """What was verified where: the model's figures, the measured response's (called verified only where its checks
    pass), the identification's rating, the verdict."""
    m = result.get("metrics") if isinstance(result.get("metrics"), Mapping) else {}
    ident = result.get("identification") if isinstance(result.get("identification"), Mapping) else None
    raw_checks = result.get("checks")
    checks = [c for c in raw_checks if isinstance(c, Mapping)] if isinstance(raw_checks, list) else []
    measured_checks = [c for c in checks if str(c.get("name", "")).startswith("measured_")]
    out = []
    if m:
        what = ("the identified model's loop, not the airframe's" if ident is not None else
                "the model given: no flight data confirmed it")
        out.append(f"on the model ({what}): PM {_g(m.get('phase_margin_deg'), ' deg')}, GM "
                   f"{_g(m.get('gain_margin_db'), ' dB')}, overshoot {_g(m.get('overshoot_pct'), ' %')}, settling "
                   f"{_g(m.get('settling_time_s'), ' s')}")
    meas = result.get("measured") if isinstance(result.get("measured"), Mapping) else None
    if meas is not None and measured_checks:
        band = meas.get("band_rad_s") or [math.nan, math.nan]
        labels = {"measured_phase_margin_deg": ("PM", " deg"), "measured_gain_margin_db": ("GM", " dB"),
                  "measured_ms": ("Ms", "")}
        ok = [c for c in measured_checks if c.get("ok") is True]
        bad = [c for c in measured_checks if c.get("ok") is not True]

        def fig(c: Mapping[str, Any]) -> str:
            what, unit = labels.get(str(c.get("name")), (clean(c.get("name"), 40), ""))
            x = _num(c.get("achieved"))
            return f"{what} not measured" if math.isnan(x) else f"{what} {_g(x, unit)} at worst"

        where = (f"on the measured response ({_g(band[0])}-{_g(band[1])} rad/s, {_g(meas.get('points'))} coherent "
                 "points)")
        if ok:
            out.append(f"verified {where}, the worst end of each error range: " + ", ".join(fig(c) for c in ok))
        if bad:
            out.append(f"NOT verified {where}: " + ", ".join(
                fig(c) + f" (required {clean(c.get('op'), 4)} {_g(c.get('required'))})" for c in bad))
    if ident is not None:
        q = clean(ident.get("quality"), 40)
        line = (f"identification: rated {q} (J {_g(ident.get('cost'))}, time-domain check "
                f"{clean(ident.get('check'), 40)})")
        if q not in ("good", "acceptable"):
            line += ": below acceptable: nothing here is confirmed to be the airframe's"
        out.append(line)
    elif meas is None:
        out.append("no flight data: nothing here was confirmed on an airframe")
    if result.get("verdict"):
        out.append(f"verdict: {clean(result.get('verdict'), 600)}")
    return out


def _verdict_ok(result: Mapping[str, Any]) -> tuple[bool, str, str]:
    """Whether the result meets its spec as far as it says (on the airframe's evidence where it has some), what is
    wrong in a few words, and its verdict."""
    meets = result.get("meets_spec")
    verdict = clean(result.get("verdict") or "", 600)
    if meets is None:
        return False, "the result does not say whether it meets its spec", verdict
    if meets is not True:
        return False, "the design does not meet its spec", verdict
    if result.get("basis") == "model only":
        return False, "the design meets its spec on the model only", verdict
    return True, "", verdict


def make_param_file(result: Mapping[str, Any], format: str, *, axis: str | None = None, att_p: float | None = None,
                    force: bool = False, date: _dt.date | None = None) -> ParamFile:
    """The :class:`ParamFile` for a tune (or analyze) result of a firmware law (the module's docstring says what is
    written and what refused).

    ``result`` is the JSON of ``tuner tune --json`` (or ``TuneResult.to_dict()``): ``structure`` ``px4_rate`` or
    ``ardupilot_rate``, ``gains`` with the law's fixed values, ``controller.dt``, its verdict (``meets_spec``,
    ``verdict``, ``basis``) and ``vehicle`` when the tune had ``--params``. ``axis`` defaults to the vehicle's, else
    roll, and must be the vehicle's when the result has one; ``att_p`` is the attitude loop's P of a cascade (default:
    none written); ``force`` writes a design that does not meet its spec, or a value outside its documented range,
    the header saying so.
    """
    if format not in PARAM_FORMATS:
        raise TunerError(f"format must be one of {', '.join(PARAM_FORMATS)}, got {format!r}", field="format")
    law, fw = PARAM_FORMATS[format]
    firmware = get_firmware(fw)
    structure = result.get("structure")
    if structure != law:
        raise TunerError(f"a {format} parameter file holds the {law} law; this result's structure is "
                         f"{clean(structure, 40)!r}: tune the structure {law} (or export this one as code, format c)",
                         field="structure")
    gains = result.get("gains")
    if not isinstance(gains, Mapping):
        raise TunerError("the result has no gains", field="gains")
    vehicle = result.get("vehicle") if isinstance(result.get("vehicle"), Mapping) else None
    own = (vehicle or {}).get("axis")
    if vehicle is not None and own not in AXES:
        raise TunerError(f"the result's vehicle axis {clean(own, 20)!r} is not one of {', '.join(AXES)}: not a "
                         "result of tuner tune --params", field="result")
    if axis is not None and axis not in AXES:
        raise TunerError(f"axis must be one of {', '.join(AXES)}, got {clean(axis, 20)!r}", field="axis")
    tuned = result.get("axis")  # the axis whose documented ranges the search kept to (tune's axis, default roll)
    if own is None and tuned in AXES:
        if axis is not None and axis != tuned:
            raise TunerError(f"this result was tuned for the {tuned} axis (its gains kept to that axis' documented "
                             f"ranges): export it for {tuned} (leave the axis out), or tune the {axis} axis (--axis "
                             f"{axis})", field="axis")
        own = tuned
    if axis is not None and own is not None and axis != own:
        raise TunerError(f"this result was tuned for the vehicle's {own} axis: its gains, K and integrator limit are "
                         f"the {own} law's; written as {axis}'s they would replace that axis' tune. Export it for "
                         f"{own} (leave the axis out), or tune the {axis} axis (--params FILE --axis {axis})",
                         field="axis")
    ax = axis or own or "roll"
    from ..controllers import get_structure

    st = get_structure(law)
    need = list(st.params) + list(st.fixed_values)
    gains = {**{k: v for k, v in LATER_FIXED.items() if k in need}, **gains}  # a result written before they were held
    missing = [k for k in need if k not in gains]
    if missing:
        raise TunerError(f"the result's gains lack {', '.join(missing)} (a {law} result carries them)",
                         field="gains")
    values = {k: _num(gains[k]) for k in need}
    if att_p is None and vehicle is not None and vehicle.get("att_p") is not None and result.get("cascade"):
        att_p = _num(vehicle["att_p"])
    if att_p is not None:
        values["att_p"] = float(att_p)
    ok, why, verdict = _verdict_ok(result)
    if not ok and not force:
        raise TunerError(f"{why}" + (f" (its verdict: {verdict})" if verdict else "") + ": a parameter file is "
                         "written for it only with --force (HTTP force=true), and its header then says so",
                         field="force")
    names = law_names(fw, ax)
    order = list(firmware.export_order)
    if att_p is not None:
        order.append("att_p")
    stored, forced, rounded = {}, [], []
    for k in order:
        v = values[k]
        try:
            stored[k] = stored_value(fw, ax, k, v)
        except ValueError as e:
            raise TunerError(f"{names[k]} = {v:.6g}: {e}; the result's gains are not a design", field=("gains", k)) \
                from None
        if k in firmware.integer and stored[k] != v:  # (Betaflight's P, I, D, F: whole numbers)
            if stored[k] == 0 and v != 0 and not force:
                raise TunerError(f"{names[k]} = {v:.6g} is stored as a whole number, 0: the file would remove the term "
                                 "the design was verified with; retune with that gain at 0 or at least 1 (or write it "
                                 "anyway with --force, HTTP force=true, and its header then says so)",
                                 field=("gains", k))
            if abs(stored[k] - v) > ROUNDING_SAID * abs(v):
                rounded.append(f"{names[k]} {v:.6g} -> {stored[k]:g}")
        prob = range_problem(fw, ax, k, stored[k])
        if prob is not None:
            if not force:
                gs = firmware.gain_scale
                raise _refuse_value(fw, names[k], k, stored[k], prob, (names[gs], values[gs]) if gs else None)
            lo, hi = prob["lo"], prob["hi"]
            forced.append(f"{names[k]} = {stored[k]:.6g} is outside {fw}'s documented range "
                          f"[{lo:g}, {hi:g}] ({prob['source']}; ground-station metadata, not enforced by the firmware)")
    dt = _num((result.get("controller") or {}).get("dt") if isinstance(result.get("controller"), Mapping) else None)
    if math.isnan(dt):
        dt = _num(result.get("dt"))
    loop_hz = 1.0 / dt if math.isfinite(dt) and dt > 0 else None
    when = (date or _dt.date.today()).isoformat()
    version = clean(installed_version("(source tree)"), 40)
    head = [f"tuner {version}, {when}: the {law} law ({fw}, {ax} axis), as the firmware computes it",
            f"loop rate {loop_hz:g} Hz (dt {dt:g} s)" if loop_hz else "loop rate: not recorded"]
    head.append(firmware.filters_header(values, _gyro_words(result, vehicle, firmware.gyro_param)))
    warnings: list[str] = []
    if vehicle is not None:
        gyro = _num(vehicle.get("gyro_cutoff_hz"))
        head.append(f"vehicle: {clean(vehicle.get('source'))} ({fw}, {ax} axis"
                    + (f", gyro low-pass {gyro:g} Hz" if math.isfinite(gyro) and gyro > 0 else "") + ")")
        if vehicle.get("loop_source"):
            head.append(f"loop rate from {clean(vehicle.get('loop_source'), 300)}")
        for n in vehicle.get("notes") if isinstance(vehicle.get("notes"), list) else ():
            head.append(("assumed: " if "assumed" in str(n) else "note: ") + clean(n, 400))
        for w in vehicle.get("warnings") if isinstance(vehicle.get("warnings"), list) else ():
            warnings.append(f"the vehicle's parameters: {clean(w)}")
        cur = vehicle.get("current_gains") if isinstance(vehicle.get("current_gains"), Mapping) else {}
        if cur:
            head.append("current: " + ", ".join(f"{names[k]} {_num(v):.6g}" for k, v in cur.items() if k in names))
        changes = [clean(c) for c in vehicle.get("changes")] if isinstance(vehicle.get("changes"), list) else []
        if changes:
            warnings.append("the proposal changes the vehicle's current tune by more than 3x: " + "; ".join(changes))
    else:
        head.append("vehicle: none given (no --params): the firmware's default loop rate and filters assumed")
    head += _verified_lines(result)
    if not ok:
        warnings.append(f"written with --force: {why}" + (" (the verdict above)" if verdict else ""))
    warnings += [f"written with --force: {f}" for f in forced]
    if rounded:
        warnings.append(f"stored as the firmware stores them (whole numbers), by more than {100 * ROUNDING_SAID:g} %: "
                        + ", ".join(rounded) + "; the figures above are the tuned design's, not the stored values' "
                        "(tuner analyze with the stored gains checks them)")
    has = vehicle.get("has") if vehicle is not None and isinstance(vehicle.get("has"), list) else None
    skip = [k for k in order if has is not None and k not in ("P", "I", "D") and names[k] not in has]
    if skip:  # the vehicle's firmware lacks them (an older generation): a ground station would refuse the file
        head.append("not written (not in the vehicle's parameter list: its firmware does not have them; the design "
                    "assumed " + ", ".join(f"{names[k]} {stored[k]:.6g}" for k in skip) + ")")
    ids = vehicle.get("ids") if vehicle is not None else None
    sys_id, comp_id = (int(ids[0]), int(ids[1])) if isinstance(ids, list) and len(ids) == 2 else (1, 1)
    if firmware.ids_in_file:
        head.append(f"vehicle id {sys_id}, component id {comp_id}" + (" (from the vehicle's file)" if ids else
                                                                       " (assumed: no QGroundControl file given)"))
    head += [f"WARNING: {w}" for w in warnings]
    lines = []
    for k in order:
        if k in skip:
            continue
        lines.append(firmware.write_line(names[k], _written(stored[k]), (sys_id, comp_id)))
    text = "\n".join([f"# {clean(h, 2000)}" for h in head] + lines) + "\n"
    return ParamFile(text=text, name=f"{law}_{ax}.{firmware.suffix}", warnings=tuple(warnings))


def _gyro_words(result: Mapping[str, Any], vehicle: Mapping[str, Any] | None, name: str) -> str:
    """Where the gyro low-pass stands: in the identified plant, or (a typed plant) added to the loop, or left out."""
    typed = (vehicle or {}).get("typed_plant")
    if not isinstance(typed, Mapping):
        return f"the gyro low-pass {name} is part of the identified plant"
    if typed.get("unmodelled") and isinstance(typed.get("note"), str):
        return clean(typed["note"], _MAX_TEXT)
    f = _num(typed.get("gyro_filter_hz"))
    if math.isfinite(f) and f > 0:
        return f"typed plant: the gyro low-pass {name} {f:g} Hz (second order) added to it in the designed loop"
    return (f"typed plant: the gyro low-pass {name} is not in the designed loop (the vehicle's file gives none, or "
            "the plant is in z): the plant typed must hold it")


def param_file(result: Mapping[str, Any], format: str, *, axis: str | None = None, att_p: float | None = None,
               force: bool = False, date: _dt.date | None = None) -> tuple[str, str]:
    """``(text, file name)`` of the parameter file for a tune (or analyze) result of a firmware law:
    :func:`make_param_file`'s text and name.

    Examples
    --------
    >>> from tuner.export.paramfile import param_file
    >>> res = {"structure": "px4_rate", "controller": {"dt": 0.0025}, "meets_spec": True,
    ...        "gains": {"P": 0.12, "I": 0.2, "D": 0.0021, "FF": 0.01, "K": 1.0, "dgyro_hz": 20.0, "int_lim": 0.3}}
    >>> text, name = param_file(res, "px4", date=__import__("datetime").date(2026, 1, 1))
    >>> name, [ln for ln in text.splitlines() if not ln.startswith("#")][0]
    ('px4_rate_roll.params', '1\\t1\\tMC_ROLLRATE_P\\t0.12\\t9')
    """
    pf = make_param_file(result, format, axis=axis, att_p=att_p, force=force, date=date)
    return pf.text, pf.name
