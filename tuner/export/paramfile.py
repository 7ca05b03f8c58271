"""A tuned firmware rate law as the parameter file its ground station loads.

* ``px4``: QGroundControl ``.params`` lines, ``vehicle-id<TAB>component-id<TAB>NAME<TAB>value<TAB>type`` (type 9 =
  float), for the axis: ``MC_<AXIS>RATE_P/I/D/FF/K`` and ``MC_<A>R_INT_LIM`` (and the attitude ``MC_<AXIS>_P`` when
  one is given);
* ``ardupilot``: Mission Planner ``NAME,value`` lines: ``ATC_RAT_<AX>_P/I/D/FF/IMAX/FLTT/FLTE/FLTD`` (and
  ``ATC_ANG_<AX>_P`` when one is given).

Every value is checked against the firmware's documented range (:data:`tuner.firmware.names.RANGES`); one outside
it is refused, naming the parameter, the value and the range. A ``#`` header states the vehicle (or that the
firmware's defaults were assumed), the loop rate and the filters the design assumed, the figures the tuner verified,
the tool's version and the date.
"""

from __future__ import annotations

import datetime as _dt
import math
from collections.abc import Mapping
from typing import Any

from ..errors import TunerError
from ..firmware.names import AXES, RANGES, law_names

__all__ = ["PARAM_FORMATS", "param_file"]

#: export format -> (the law it writes, the firmware)
PARAM_FORMATS = {"px4": ("px4_rate", "px4"), "ardupilot": ("ardupilot_rate", "ardupilot")}
_SUFFIX = {"px4": "params", "ardupilot": "parm"}


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("tuner")
    except Exception:  # not installed (a source tree): say so rather than fail the export
        return "(source tree)"


def _fmt(v: float) -> str:
    return repr(float(v)) if abs(v) >= 1e-4 or v == 0 else f"{v:.9g}"


def param_file(result: Mapping[str, Any], format: str, *, axis: str | None = None, att_p: float | None = None,
               date: _dt.date | None = None) -> tuple[str, str]:
    """``(text, file name)`` of the parameter file for a tune (or analyze) result of a firmware law.

    ``result`` is the JSON of ``tuner tune --json`` (or ``TuneResult.to_dict()``): ``structure`` ``px4_rate`` or
    ``ardupilot_rate``, ``gains`` with the law's fixed values, ``controller.dt``, and ``vehicle`` when the tune
    had ``--params``. ``axis`` defaults to the vehicle's, else roll; ``att_p`` is the attitude loop's P of a
    cascade (default: none written).

    Examples
    --------
    >>> from tuner.export.paramfile import param_file
    >>> res = {"structure": "px4_rate", "controller": {"dt": 0.0025},
    ...        "gains": {"P": 0.12, "I": 0.2, "D": 0.0021, "FF": 0.01, "K": 1.0, "dgyro_hz": 20.0, "int_lim": 0.3}}
    >>> text, name = param_file(res, "px4", date=__import__("datetime").date(2026, 1, 1))
    >>> name, [ln for ln in text.splitlines() if not ln.startswith("#")][0]
    ('px4_rate_roll.params', '1\\t1\\tMC_ROLLRATE_P\\t0.12\\t9')
    """
    if format not in PARAM_FORMATS:
        raise TunerError(f"format must be one of {', '.join(PARAM_FORMATS)}, got {format!r}", field="format")
    law, fw = PARAM_FORMATS[format]
    structure = result.get("structure")
    if structure != law:
        raise TunerError(f"a {format} parameter file holds the {law} law; this result's structure is "
                         f"{structure!r}: tune the structure {law} (or export this one as code, format c)",
                         field="structure")
    gains = result.get("gains")
    if not isinstance(gains, Mapping):
        raise TunerError("the result has no gains", field="gains")
    vehicle = result.get("vehicle") if isinstance(result.get("vehicle"), Mapping) else None
    ax = axis or (vehicle or {}).get("axis") or "roll"
    if ax not in AXES:
        raise TunerError(f"axis must be one of {', '.join(AXES)}, got {ax!r}", field="axis")
    from ..controllers import get_structure

    st = get_structure(law)
    need = list(st.params) + list(st.fixed_values)
    missing = [k for k in need if k not in gains]
    if missing:
        raise TunerError(f"the result's gains lack {', '.join(missing)} (a {law} result carries them)",
                         field="gains")
    values = {k: float(gains[k]) for k in need}
    if att_p is None and vehicle is not None and vehicle.get("att_p") is not None and result.get("cascade"):
        att_p = float(vehicle["att_p"])
    if att_p is not None:
        values["att_p"] = float(att_p)
    names = law_names(fw, ax)
    ranges = RANGES[fw][ax]
    order = ["P", "I", "D", "FF", "K", "int_lim"] if fw == "px4" else \
        ["P", "I", "D", "FF", "imax", "fltt_hz", "flte_hz", "fltd_hz"]
    if att_p is not None:
        order.append("att_p")
    for k in order:
        v = values[k]
        lo, hi = ranges.get(k, (-math.inf, math.inf))
        if not (math.isfinite(v) and lo <= v <= hi):
            raise TunerError(f"{names[k]} = {v:.6g} is outside {fw}'s documented range [{lo:g}, {hi:g}]: the "
                             "firmware would refuse or clamp it; tune with a spec the range allows (e.g. a lower "
                             "bandwidth), or check the plant's gain (the identified units)", field=("gains", k))
    dt = (result.get("controller") or {}).get("dt") or result.get("dt")
    loop_hz = 1.0 / float(dt) if dt else None
    when = (date or _dt.date.today()).isoformat()
    head = [f"# tuner {_version()}, {when}: the {law} law ({fw}, {ax} axis), as the firmware computes it",
            f"# loop rate {loop_hz:g} Hz (dt {float(dt):g} s)" if loop_hz else "# loop rate: not recorded"]
    if fw == "px4":
        head.append(f"# filters assumed: D-term low-pass IMU_DGYRO_CUTOFF {values['dgyro_hz']:g} Hz (not written: "
                    "set it to this value); the gyro low-pass IMU_GYRO_CUTOFF is part of the identified plant")
    else:
        head.append(f"# filters assumed (written): FLTT {values['fltt_hz']:g} Hz, FLTE {values['flte_hz']:g} Hz, "
                    f"FLTD {values['fltd_hz']:g} Hz; the gyro filter INS_GYRO_FILTER is part of the identified plant")
    if vehicle is not None:
        head.append(f"# vehicle: {vehicle.get('source')} ({fw}, {vehicle.get('axis')} axis"
                    + (f", gyro low-pass {vehicle['gyro_cutoff_hz']:g} Hz" if vehicle.get("gyro_cutoff_hz") else "")
                    + ")")
        cur = vehicle.get("current_gains") or {}
        if cur:
            head.append("# current: " + ", ".join(f"{names[k]} {float(v):.6g}" for k, v in cur.items()
                                                  if k in names))
    else:
        head.append("# vehicle: none given (no --params): the firmware's default loop rate and filters assumed")
    m = result.get("metrics") or {}
    if m:
        def num(k):
            v = m.get(k)
            return f"{v:.4g}" if isinstance(v, (int, float)) else str(v)

        head.append(f"# verified: PM {num('phase_margin_deg')} deg, GM {num('gain_margin_db')} dB, overshoot "
                    f"{num('overshoot_pct')} %, settling {num('settling_time_s')} s"
                    + ("" if result.get("meets_spec", True) else " (does NOT meet the spec)"))
    lines = []
    for k in order:
        if fw == "px4":
            lines.append(f"1\t1\t{names[k]}\t{_fmt(values[k])}\t9")
        else:
            lines.append(f"{names[k]},{_fmt(values[k])}")
    return "\n".join(head + lines) + "\n", f"{law}_{ax}.{_SUFFIX[format]}"
