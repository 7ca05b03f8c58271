"""A vehicle's parameters: what it fixes for its rate law (loop rate, filters, PX4's K, the integrator limit) and
its current gains, read from the files ground stations save and logs store.

* QGroundControl ``.params`` (PX4): tab-separated ``vehicle-id  component-id  NAME  value  type`` lines (type 9 =
  float, 6 = int32), ``#`` comments;
* ArduPilot parameter files (Mission Planner ``.parm``/``.param``, MAVProxy, defaults files; any suffix):
  ``NAME,value`` lines (a space, a tab or ``=`` also separates), ``#`` comments, ``@READONLY`` after the value;
* a PX4 ULog (``.ulg``): the parameters stored in its definitions section (pyulog's ``initial_parameters``) with
  the changes made in flight (``changed_parameters``: the last value), and the gyro's rate
  (``vehicle_imu_status``; :func:`tuner.identify.ulog.read_vehicle_log` parses those topics only).

Text files go through the bounded reader (:func:`tuner.fileio.read_text`, :data:`MAX_PARAMS_BYTES`); a ULog is
size-checked before it is opened. Every error is a :class:`~tuner.errors.TunerError` whose ``field`` is the
caller's (``"params"`` by default): a missing file, a file of neither format, a parameter the law needs that the
file lacks (named), ArduPilot parameters given for PX4's law (or the reverse), a value that is not a finite number
or that no vehicle can hold (beyond single precision: the firmware stores these as float32).

A value of the law's parameters outside the range the firmware documents for it
(:data:`tuner.firmware.names.RANGES`; ``K`` 50, ``IMAX`` 5, a loop rate of 0.001 Hz) is read and warned about, not
refused: it is the vehicle's own, flown as it is (the metadata is what ground stations check edits against; the
firmware does not enforce it), except ArduPilot's loop rate, which its scheduler clamps to 50-2000 Hz at start: that
clamped rate is taken. Each warning names the parameter, its value, the range and its source
(:attr:`VehicleParams.warnings`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import TunerError
from .laws import law_defaults
from .names import ARDUPILOT_SLEW, ARDUPILOT_UNMODELLED, AXES, FLOAT32_MAX, RANGES, law_names, range_problem

__all__ = ["MAX_PARAMS_BYTES", "VehicleParams", "parse_params_text", "read_params", "vehicle_from_text",
           "vehicle_from_raw", "detect_firmware"]

MAX_PARAMS_BYTES = 4 << 20  # a full PX4 .params is about 60 kB
_ULOG_MAGIC = b"ULog\x01\x12\x35"
_FILES = {"px4": "PX4 parameters (a QGroundControl .params file, or a ULog .ulg)",
          "ardupilot": "ArduPilot parameters (a Mission Planner .parm file)"}
_DEFAULT_LOOP_HZ = {"px4": 400.0, "ardupilot": 400.0}  # IMU_GYRO_RATEMAX, SCHED_LOOP_RATE defaults (firmware.md)


@dataclass(frozen=True)
class VehicleParams:
    """What a vehicle fixes for its rate law on one axis, and its current gains.

    ``gains`` are the current ``P``, ``I``, ``D``, ``FF`` in the firmware's units; ``fixed`` what the law fixes
    (PX4: ``K``, ``dgyro_hz``, ``int_lim``, ``tq_hz``; ArduPilot: ``fltt_hz``, ``flte_hz``, ``fltd_hz``, ``imax``,
    ``dff``; each missing one the firmware's default for the axis, :func:`~tuner.firmware.laws.law_defaults`);
    ``gyro_cutoff_hz`` is the gyro low-pass upstream of the logged rate (part of the plant, informational);
    ``notes`` say which values were missing and taken from the firmware's defaults.

    Examples
    --------
    >>> from tuner.firmware import vehicle_from_text
    >>> v = vehicle_from_text("ATC_RAT_RLL_P,0.12\\nATC_RAT_RLL_I,0.1\\nATC_RAT_RLL_D,0.003\\nSCHED_LOOP_RATE,400",
    ...                       axis="roll")
    >>> v.firmware, v.dt, v.gains["P"], v.fixed["fltt_hz"]
    ('ardupilot', 0.0025, 0.12, 20.0)
    """

    firmware: str
    axis: str
    loop_hz: float | None
    gains: dict[str, float]
    fixed: dict[str, float]
    gyro_cutoff_hz: float | None = None
    att_p: float | None = None
    rate_max_dps: float | None = None
    source: str = "parameters"
    raw: Mapping[str, float] = field(default_factory=dict, repr=False)
    notes: tuple[str, ...] = ()
    #: each value of the law's parameters outside its documented range (or not a whole number where the firmware
    #: stores an integer), in words: read as it is, not refused
    warnings: tuple[str, ...] = ()
    #: where the loop rate came from, in words (the log's gyro rate, a parameter, or the default assumed)
    loop_source: str = ""
    #: a QGroundControl file's vehicle and component ids (the export writes them), None otherwise
    ids: tuple[int, int] | None = None
    #: set when the plant was typed, not identified: the gyro low-pass added or not (tuner.firmware.bind.typed_plant)
    typed_plant: Mapping[str, Any] | None = None

    @property
    def dt(self) -> float | None:
        """The rate loop's sample time, s (``1/loop_hz``)."""
        return None if not self.loop_hz else 1.0 / self.loop_hz


def _num(text: str, name: str, where: str, fld: str) -> float:
    try:
        if "_" in text or not text.isascii():  # float() takes '1_5' as 15 and other scripts' digits: no file's number
            raise ValueError(text)
        v = float(text)
    except ValueError:
        raise TunerError(f"{where}: {name} = {text!r} is not a number", field=fld) from None
    if not math.isfinite(v):
        raise TunerError(f"{where}: {name} = {text!r} is not a finite number", field=fld)
    return v


def parse_params_text(text: str, fmt: str | None = None, *, source: str = "parameters", field: str = "params"
                      ) -> tuple[dict[str, float], str]:
    """``({NAME: value}, format)`` of a parameter file's text; ``fmt`` is ``"qgc"`` (QGroundControl ``.params``),
    ``"parm"`` (Mission Planner) or None (told by the lines: five tab-separated columns are QGroundControl's).

    Examples
    --------
    >>> from tuner.firmware.params import parse_params_text
    >>> parse_params_text("# Onboard parameters\\n1\\t1\\tMC_ROLLRATE_P\\t0.15\\t9\\n")
    ({'MC_ROLLRATE_P': 0.15}, 'qgc')
    >>> parse_params_text("ATC_RAT_RLL_P,0.135\\nATC_RAT_RLL_I 0.135\\n")
    ({'ATC_RAT_RLL_P': 0.135, 'ATC_RAT_RLL_I': 0.135}, 'parm')
    """
    lines = [(i + 1, ln.strip()) for i, ln in enumerate(text.splitlines())]
    lines = [(i, ln) for i, ln in lines if ln and not ln.startswith("#")]
    qgc = bool(lines) and len(lines[0][1].split("\t")) == 5
    if fmt is None or (fmt == "qgc" and not qgc):  # told by the lines (a .params of NAME,value lines is ArduPilot's)
        fmt = "qgc" if qgc else "parm"
    out: dict[str, float] = {}
    first: dict[str, int] = {}  # the line each name was first read on
    for i, ln in lines:
        where = f"{source} line {i}"
        if fmt == "qgc":
            cols = ln.split("\t")
            if len(cols) != 5:
                raise TunerError(f"{where}: a QGroundControl .params line has 5 tab-separated columns (vehicle-id, "
                                 f"component-id, NAME, value, type), got {len(cols)}", field=field)
            name, value = cols[2].strip(), cols[3].strip()
        else:  # NAME,value  NAME value  NAME=value, a trailing "# comment" or @READONLY (ArduPilot's defaults files)
            body = ln.split("#", 1)[0]
            cols = body.replace(",", " ").replace("=", " ").replace("\t", " ").split()
            if len(cols) == 3 and cols[2].upper() == "@READONLY":
                cols = cols[:2]
            if len(cols) != 2:
                raise TunerError(f"{where}: an ArduPilot parameter line is NAME,value (or NAME value, NAME=value, "
                                 f"with @READONLY after it), got {ln[:60]!r}", field=field)
            name, value = cols
        if not name.replace("_", "").isalnum() or len(name) > 64:
            raise TunerError(f"{where}: {name[:64]!r} is not a parameter name", field=field)
        v = _num(value, name, where, field)
        if name in out and v != out[name]:  # which one the vehicle flies cannot be told: the file is refused
            raise TunerError(f"{where}: {name} = {v:g} again, after {out[name]:g} on line {first[name]}: keep one "
                             "of the two lines", field=field)
        first.setdefault(name, i)
        out[name] = v
    if not out:
        raise TunerError(f"{source}: no parameters in it (lines NAME,value for ArduPilot, or QGroundControl's "
                         "tab-separated vehicle-id component-id NAME value type)", field=field)
    return out, fmt


def qgc_ids(text: str) -> tuple[int, int] | None:
    """The vehicle and component ids of a QGroundControl ``.params`` file (its first two columns: QGroundControl
    loads a file only onto the vehicle whose ``MAV_SYS_ID`` they name), the pair most lines carry; None for another
    format or ids that are not whole numbers.

    Examples
    --------
    >>> from tuner.firmware.params import qgc_ids
    >>> qgc_ids("# Vehicle-Id Component-Id Name Value Type\\n3\\t1\\tMC_ROLLRATE_P\\t0.15\\t9\\n")
    (3, 1)
    """
    from collections import Counter

    pairs: Counter = Counter()
    for ln in text.splitlines():
        cols = ln.strip().split("\t")
        if ln.strip().startswith("#") or len(cols) != 5:
            continue
        if not (cols[0].strip().isdigit() and cols[1].strip().isdigit()):
            return None
        pairs[(int(cols[0]), int(cols[1]))] += 1
    return pairs.most_common(1)[0][0] if pairs else None


def detect_firmware(raw: Mapping[str, float]) -> str | None:
    """``"px4"``, ``"ardupilot"`` or None, from the parameter names (rate-law names first, then typical ones)."""
    px4 = any(k.startswith(("MC_ROLLRATE_", "MC_PITCHRATE_", "MC_YAWRATE_", "IMU_GYRO_", "SYS_AUTOSTART"))
              for k in raw)
    ardu = any(k.startswith(("ATC_RAT_", "ATC_ANG_", "SCHED_LOOP_RATE", "INS_GYRO_FILTER", "FRAME_CLASS"))
               for k in raw)
    if px4 == ardu:
        return None
    return "px4" if px4 else "ardupilot"


def vehicle_from_raw(raw: Mapping[str, float], *, axis: str = "roll", firmware: str | None = None,
                     source: str = "parameters", fmt: str | None = None, field: str = "params",
                     log: Mapping[str, Any] | None = None) -> VehicleParams:
    """The :class:`VehicleParams` of ``axis`` from ``{NAME: value}``; ``firmware`` (``"px4"``, ``"ardupilot"``)
    is what the caller's law needs (None: told by the names); ``fmt`` is the file's format, for the messages;
    ``log``: what a ULog showed (:func:`tuner.identify.ulog.read_vehicle_log`: the gyro's rate, the in-flight
    changes, already applied to ``raw`` by the caller, in ``log["change_notes"]``)."""
    if axis not in AXES:
        raise TunerError(f"axis must be one of {', '.join(AXES)}, got {axis!r}", field="axis")
    found = detect_firmware(raw)
    if firmware is not None and fmt == "parm" and firmware == "px4":
        raise TunerError(f"{source}: a .parm file is ArduPilot's; px4_rate needs {_FILES['px4']}", field=field)
    if firmware is not None and found is not None and found != firmware:
        law = "px4_rate" if firmware == "px4" else "ardupilot_rate"
        raise TunerError(f"{source} holds {found} parameters; {law} needs {_FILES[firmware]}", field=field)
    fw = firmware or found
    if fw is None:
        raise TunerError(f"{source}: neither PX4's (MC_ROLLRATE_P, ...) nor ArduPilot's (ATC_RAT_RLL_P, ...) rate "
                         "parameters are in it: give the vehicle's parameter file", field=field)
    names = law_names(fw, axis)
    missing = [names[k] for k in ("P", "I", "D") if names[k] not in raw]
    if missing:
        raise TunerError(f"{source} has no {', '.join(missing)} (the {axis} rate law's gains): give the vehicle's "
                         f"full parameter file ({_FILES[fw]})", field=field)
    notes = []

    def get(key: str, default: float | None) -> float | None:
        name = names.get(key)
        if name is not None and name in raw:
            return float(raw[name])
        if default is not None and name is not None:
            notes.append(f"{name} not in {source}: the firmware's default {default:g} assumed")
        return default

    gains = {"P": get("P", None), "I": get("I", None), "D": get("D", None), "FF": get("FF", 0.0)}
    defaults = law_defaults(fw, axis)  # the axis's own defaults (ArduPilot's yaw FLTE 2.5 Hz, PX4's yaw filter 2 Hz)
    fixed = {k: get(k, v) for k, v in defaults.items()}
    if fw == "ardupilot":
        notes += _ardupilot_unmodelled(raw, axis, source, field)
    loop_hz, loop_source = _loop_rate(fw, raw, names, source, log, notes, field)
    if fw == "px4":
        fixed.update(_px4_dpath(log, loop_hz, fixed["dgyro_hz"] if names["dgyro_hz"] in raw else None, source,
                                notes))
    notes += list((log or {}).get("change_notes", ()))
    for name in names.values():  # no vehicle holds more than single precision
        if name in raw and abs(float(raw[name])) > FLOAT32_MAX:
            raise TunerError(f"{source}: {name} = {float(raw[name]):g} cannot be a {fw} parameter: the firmware stores "
                             f"it in single precision (at most {FLOAT32_MAX:.4g} in magnitude), so no vehicle holds "
                             "it; correct the file (a vehicle's own parameters, as its ground station saved them)",
                             field=field)
    warnings = _range_warnings(fw, axis, names, raw, source)
    if loop_hz is not None and fw == "px4" and loop_hz == 0:
        notes.append(f"{names['loop_hz']} = 0: PX4 then runs the rate loop at the gyro's own rate, which the "
                     "parameters do not say: give dt (the rate loop's sample time)")
        loop_hz, loop_source = None, ""
    if loop_hz is not None and not loop_hz > 0:
        raise TunerError(f"{source}: {names['loop_hz']} = {loop_hz:g}: a loop rate is > 0 Hz", field=field)
    lo_hz, hi_hz = RANGES[fw][axis]["loop_hz"]
    if loop_hz is not None and fw == "ardupilot" and not lo_hz <= loop_hz <= hi_hz:
        loop_hz = min(max(loop_hz, lo_hz), hi_hz)  # what the vehicle runs (AP_Scheduler's clamp, at start)
    for k, v in fixed.items():
        if v is not None and (v < 0 or (k == "K" and v <= 0)):
            raise TunerError(f"{source}: {names[k]} = {v:g} must be " + ("> 0" if k == "K" else ">= 0"), field=field)
    for k, v in gains.items():
        if v is not None and v < 0:
            raise TunerError(f"{source}: {names[k]} = {v:g}: the rate law's gains are >= 0", field=field)
    if fw == "px4" and axis == "yaw" and fixed["tq_hz"] > 0:
        notes.append(f"PX4 low-passes the yaw torque at MC_YAW_TQ_CUTOFF = {fixed['tq_hz']:g} Hz after the rate law "
                     "and before it publishes vehicle_torque_setpoint: the filter is part of the designed loop (a "
                     "plant identified from vehicle_torque_setpoint starts after it)")
    return VehicleParams(firmware=fw, axis=axis, loop_hz=loop_hz, gains=gains, fixed=fixed,
                         gyro_cutoff_hz=get("gyro_hz", None), att_p=get("att_p", None),
                         rate_max_dps=get("rate_max_dps", None) if "rate_max_dps" in names else None,
                         source=source, raw=dict(raw), notes=tuple(notes), warnings=tuple(warnings),
                         loop_source=loop_source)


def _loop_rate(fw: str, raw: Mapping[str, float], names: Mapping[str, str], source: str,
               log: Mapping[str, Any] | None, notes: list[str], fld: str) -> tuple[float | None, str]:
    """The rate loop's rate and where it came from, in words.

    * PX4: ``MulticopterRateControl::Run`` runs on every ``vehicle_angular_velocity``, which the gyro drives and
      ``VehicleAngularVelocity`` publishes from ``IMU_GYRO_RATEMAX`` ("maximum publication rate",
      ``imu_gyro_parameters.c``): every ``samples = roundf(gyro_rate / RATEMAX)`` (at least 1) gyro publications
      (``VehicleAngularVelocity::UpdateSampleRate``, ``src/modules/sensors/vehicle_angular_velocity/``, PX4-Autopilot
      main: ``set_required_updates(samples)`` and a minimum interval of ``1/RATEMAX - 1/(2 gyro_rate)``), so the loop
      runs at ``gyro_rate / samples``: a 2 kHz gyro under a cap of 800 at 667 Hz, a 1 kHz one at 1 kHz (above the
      "cap"). A log's ``vehicle_imu_status.gyro_rate_hz`` gives the gyro's rate (taken as its publication rate: a
      FIFO driver that publishes in batches runs the loop slower, said). The parameter alone is a stated fallback.
    * ArduPilot: ``SCHED_LOOP_RATE``; with the fast-rate thread (``FSTRATE_ENABLE`` > 0, ArduCopter
      ``Parameters.cpp``: "the actual rate is the gyro rate in Hz divided by" ``FSTRATE_DIV``) the gyro's rate
      ``INS_GYRO_RATE`` (0: 1 kHz, 1: 2 kHz, 2: 4 kHz, 3: 8 kHz, ``AP_InertialSensor.cpp``) over ``FSTRATE_DIV``.
    """
    name = names["loop_hz"]
    if fw == "px4":
        gyro = (log or {}).get("gyro_rate_hz")
        cap = raw.get(name)
        if gyro:
            where = f"vehicle_imu_status.gyro_rate_hz in {source}"
            if cap is None or cap <= 0:
                return float(round(gyro)), f"the gyro's rate {gyro:.1f} Hz ({where}; no {name} cap in it)"
            samples = max(1, math.floor(gyro / cap + 0.5))  # roundf: half away from zero (both positive here)
            if samples == 1:
                return float(round(gyro)), (f"the gyro's rate {gyro:.1f} Hz ({where}), every sample published under "
                                            f"the cap {name} {cap:g}")
            return float(gyro / samples), (f"the gyro's rate {gyro:.1f} Hz ({where}) over {samples}: "
                                           f"VehicleAngularVelocity publishes every {samples} samples under {name} "
                                           f"{cap:g} (a FIFO gyro that publishes in batches runs the loop slower)")
        logged = (log or {}).get("logged_gyro_hz")
        if cap is None and logged:
            notes.append(f"{name} not in {source} (older firmware): the loop rate is taken from the log's timing")
            return float(round(logged)), (f"the timing of sensor_combined in {source}: the gyro's samples as logged, "
                                          f"{logged:.1f} Hz (a lower bound if the logger thinned the topic; the "
                                          "log has no vehicle_imu_status)")
        if cap is not None:
            why = ("the log has no vehicle_imu_status" if log is not None else
                   "a parameter file; a ULog's vehicle_imu_status would give the gyro's rate")
            return float(cap), f"{name} {cap:g} Hz in {source}: a cap on the gyro's rate, taken as the loop's ({why})"
    else:
        fast = raw.get("FSTRATE_ENABLE", 0.0)
        if fast > 0:
            if "INS_GYRO_RATE" not in raw:
                notes.append(f"FSTRATE_ENABLE = {fast:g}: the rate loop runs in the fast-rate thread at the gyro's "
                             "rate over FSTRATE_DIV, and INS_GYRO_RATE is not in the file: give dt")
                return None, ""
            code = raw["INS_GYRO_RATE"]
            if code not in (0, 1, 2, 3):  # (AP_InertialSensor.cpp: 0: 1 kHz, 1: 2 kHz, 2: 4 kHz, 3: 8 kHz)
                raise TunerError(f"{source}: INS_GYRO_RATE = {code:g} is not one of ArduPilot's gyro rates (0: 1 kHz, "
                                 "1: 2 kHz, 2: 4 kHz, 3: 8 kHz): correct the file", field=fld)
            gyro_hz = 1000.0 * 2 ** int(code)
            div = max(1.0, float(raw.get("FSTRATE_DIV", 1.0)))
            how = ("a dynamic divisor from FSTRATE_DIV up: at most this rate" if fast == 1 else "a fixed divisor")
            return gyro_hz / div, (f"the fast-rate thread (FSTRATE_ENABLE {fast:g}, {how}): INS_GYRO_RATE "
                                   f"{gyro_hz:g} Hz / FSTRATE_DIV {div:g} in {source}")
        if name in raw:
            return float(raw[name]), f"{name} {float(raw[name]):g} Hz in {source}"
    default = _DEFAULT_LOOP_HZ[fw]
    notes.append(f"{name} not in {source}: the firmware's default {default:g} Hz assumed for the loop rate")
    return default, f"assumed: the firmware's default {default:g} Hz ({name} is not in {source})"


#: the first PX4 release whose D path is the first-order AlphaFilter (see :func:`_px4_dpath`)
PX4_ALPHA_DGYRO_RELEASE = (1, 13)


def _px4_dpath(log: Mapping[str, Any] | None, loop_hz: float | None, dgyro_hz: float | None, source: str,
               notes: list[str]) -> dict[str, float]:
    """PX4's D path for :func:`tuner.firmware.laws.dgyro_filter`: ``dgyro_order`` and ``raw_hz``, with a note for
    what was assumed. ``dgyro_hz`` is the vehicle's ``IMU_DGYRO_CUTOFF``, None where its parameters lack it.

    * Firmware without ``IMU_DGYRO_CUTOFF`` (before v1.11, which added ``vehicle_angular_acceleration``, PX4 PR
      #14034) computes the D term in the rate controller at the loop rate: the loop-rate law (first order, the
      loop rate), said; that generation's own D filter (``MC_DTERM_CUTOFF``) is not modelled.

    * The generation from the log's firmware version (``ver_sw_release``): releases before v1.13 filter the
      difference with a ``LowPassFilter2p`` (second order: v1.12 moved the D path onto the raw FIFO samples, PX4
      PR #15820, with ``IMU_DGYRO_CUTOFF`` 30 Hz by default, PR #16188); later ones with an ``AlphaFilter`` (first
      order; in main by October 2022, PR #20521 discussing "the delay from the AlphaFilter"). The boundary is taken as
      v1.13 (not checked against the v1.13.0 tag). Without a version (a parameter file, an old log): first order,
      the current firmware's, said.
    * The raw gyro rate: the log's ``vehicle_imu_status.gyro_raw_rate_hz`` (the FIFO's), else its ``gyro_rate_hz``
      (the gyro's publication rate: a FIFO driver's raw rate is higher, said), else the timing of
      ``sensor_combined``; without a log, the loop rate (0: the D path differenced at the loop rate, conservative
      for the first-order filter, not for the second-order one), said.
    """
    log = log or {}
    rel = log.get("ver_sw_release")
    if dgyro_hz is None:
        notes.append(f"IMU_DGYRO_CUTOFF is not in {source} (PX4 before v1.11): the D term is taken as differenced and "
                     "first-order filtered at the loop rate (that firmware computes it in the rate controller; its "
                     "MC_DTERM_CUTOFF filter is not modelled)")
        return {"dgyro_order": 1.0, "raw_hz": 0.0}
    if rel:
        major, minor, patch = (rel >> 24) & 0xFF, (rel >> 16) & 0xFF, (rel >> 8) & 0xFF
        order = 2.0 if (major, minor) < PX4_ALPHA_DGYRO_RELEASE else 1.0
        if dgyro_hz > 0:
            notes.append(f"PX4 v{major}.{minor}.{patch} (ver_sw_release in {source}): the D path's filter is "
                         + ("second order (LowPassFilter2p, the releases before v1.13)" if order == 2 else
                            "first order (AlphaFilter, v1.13 and later)"))
    else:
        order = 1.0
        if dgyro_hz > 0:
            notes.append(f"the firmware version is not in {source}: the D path's filter assumed first order "
                         "(AlphaFilter, PX4 v1.13 and later); releases before v1.13 filter it with a second-order "
                         "LowPassFilter2p (give a ULog of the vehicle, whose ver_sw_release says which)")
    raw, what = None, ""
    for key, words in (("gyro_raw_rate_hz", "vehicle_imu_status.gyro_raw_rate_hz"),
                       ("gyro_rate_hz", "vehicle_imu_status.gyro_rate_hz (the gyro's publication rate; a FIFO "
                                        "gyro's raw samples may be faster)"),
                       ("logged_gyro_hz", "the timing of sensor_combined (a lower bound)")):
        v = log.get(key)
        if v and v > 0:
            raw, what = float(v), words
            break
    if raw is None:
        notes.append(f"the raw gyro rate is not in {source}: PX4 differences and filters the D path on every raw "
                     "gyro sample (1-8 kHz); assumed at the loop rate (conservative for the first-order filter, not "
                     "for the second-order one; a ULog of the vehicle gives the rate)")
        return {"dgyro_order": order, "raw_hz": 0.0}
    if loop_hz and raw <= loop_hz * (1 + 1e-6):
        return {"dgyro_order": order, "raw_hz": 0.0}  # the D path runs at the loop rate: the law as it was
    notes.append(f"the D path is differenced and filtered at the raw gyro rate {raw:.0f} Hz ({what} in {source})")
    return {"dgyro_order": order, "raw_hz": float(round(raw))}


def _ardupilot_unmodelled(raw: Mapping[str, float], axis: str, source: str, fld: str) -> list[str]:
    """ArduPilot's AC_PID terms outside the linear law: PDMX, NTF, NEF set (non-zero) are refused, naming the
    parameter; SMAX is read and what it does said (see :data:`tuner.firmware.names.ARDUPILOT_UNMODELLED`)."""
    a = {"roll": "RLL", "pitch": "PIT", "yaw": "YAW"}[axis]
    what = {"PDMX": "the P+D output limit (a clamp on |P + D| in AC_PID::update_all)",
            "NTF": "a notch filter on the target (AP_Filter, FILTn_*)", "NEF": "a notch filter on the error "
            "(AP_Filter, FILTn_*)"}
    for suffix in ARDUPILOT_UNMODELLED:
        name = f"ATC_RAT_{a}_{suffix}"
        if float(raw.get(name, 0.0)) != 0:
            raise TunerError(f"{source}: {name} = {float(raw[name]):g} sets {what[suffix]}, which the tuner's model "
                             f"of the {axis} rate law does not hold, so its margins would not be the vehicle's: set "
                             f"{name} to 0 in the file given to the tuner (and fly the design with it off), or tune "
                             "without it", field=fld)
    smax = f"ATC_RAT_{a}_{ARDUPILOT_SLEW}"
    if float(raw.get(smax, 0.0)) > 0:
        return [f"{smax} = {float(raw[smax]):g}: ArduPilot's slew limiter lowers P and D only when the P+D output "
                "slews faster than that in alternating directions (an oscillation); a loop that does not oscillate "
                "flies the linear law designed here, which does not include it"]
    return []


def range_warning(fw: str, name: str, value: float, problem: dict, what: str = "the tune uses it as read") -> str:
    """A value outside its documented range (``problem``: :func:`tuner.firmware.names.range_problem`), in words."""
    lo, hi = problem["lo"], problem["hi"]
    if problem["side"] == "integer":
        return (f"{name} = {value:g} is not a whole number: the firmware stores it as an integer ({problem['source']}: "
                f"{lo:g}-{hi:g}); {what}")
    rng = f"[{lo:g}, {hi:g}]" if math.isfinite(hi) else f">= {lo:g}"
    where = (problem["enforced"] if problem.get("enforced") else
             "metadata that ground stations check edits against; the firmware flies the value as it is")
    return f"{name} = {value:g} is outside its documented range {rng} ({problem['source']}: {where}); {what}"


def _range_warnings(fw: str, axis: str, names: Mapping[str, str], raw: Mapping[str, float], source: str
                    ) -> list[str]:
    """Each value of the law's parameters in ``raw`` outside its documented range, in words (read, not refused)."""
    out = []
    for key in RANGES[fw][axis]:
        name = names.get(key)
        if name is None or name not in raw:
            continue
        v = float(raw[name])
        prob = range_problem(fw, axis, key, v)
        if prob is None or (fw == "px4" and key == "loop_hz" and v == 0):
            continue
        what = ("the vehicle runs at the clamped rate, and the tune too" if prob.get("enforced")
                else "the tune uses it as read")
        out.append(f"{source}: " + range_warning(fw, name, v, prob, what))
    return out


def vehicle_from_text(text: str | Mapping[str, float], *, axis: str = "roll", firmware: str | None = None,
                      fmt: str | None = None, source: str = "parameters", field: str = "params") -> VehicleParams:
    """:func:`vehicle_from_raw` of a parameter file's text (``fmt``: ``"qgc"``, ``"parm"``, None to tell), or of a
    ``{NAME: value}`` mapping already read (``fmt="ulog"``: a log's stored parameters)."""
    if isinstance(text, Mapping):
        raw = {str(k): _num(str(v), str(k), source, field) for k, v in text.items()}
        return vehicle_from_raw(raw, axis=axis, firmware=firmware, source=source, fmt=fmt, field=field)
    raw, fmt = parse_params_text(text, None if fmt == "ulog" else fmt, source=source, field=field)
    v = vehicle_from_raw(raw, axis=axis, firmware=firmware, source=source, fmt=fmt, field=field)
    ids = qgc_ids(text) if fmt == "qgc" else None
    return dataclasses.replace(v, ids=ids) if ids else v


def change_notes(raw: dict[str, float], changes: Sequence[tuple[float, str, float]], firmware: str, axis: str
                 ) -> list[str]:
    """Apply a log's in-flight parameter ``changes`` (``(t_s, NAME, value)`` in order) to ``raw`` (the values at the
    log's start), in place: the last value of each is what was flown at the log's end. Returns a note for each of the
    rate law's parameters on ``axis`` that changed, saying when and which value is used.

    Examples
    --------
    >>> from tuner.firmware.params import change_notes
    >>> raw = {"MC_ROLLRATE_P": 0.15}
    >>> change_notes(raw, [(12.0, "MC_ROLLRATE_P", 0.18), (30.0, "MC_PITCHRATE_P", 0.2)], "px4", "roll")[0][:48]
    'MC_ROLLRATE_P changed in flight (0.15 at 0.0 s, '
    >>> raw["MC_ROLLRATE_P"]
    0.18
    """
    law = set(law_names(firmware, axis if axis in AXES else "roll").values())
    seen: dict[str, list[tuple[float, float]]] = {}
    for t, name, v in changes:
        if name in raw and raw[name] != v or name in seen:
            seen.setdefault(name, [(0.0, raw.get(name, math.nan))]).append((t, v))
        raw[name] = v
    return [f"{name} changed in flight ({', '.join(f'{v:g} at {t:.1f} s' for t, v in hist)}): the last value "
            f"{hist[-1][1]:g} is used (what was flown from {hist[-1][0]:.1f} s); a stretch identified before that flew "
            "the earlier value: give --params a file with it"
            for name, hist in seen.items() if name in law]


def _ulog_vehicle(path: Path, axis: str, field: str) -> tuple[dict[str, float], dict[str, Any]]:
    """A ULog's parameters with the in-flight changes applied (the last value set in the log: what was flown at
    its end; each change of the law's parameters said), and what the log showed (the gyro's rate)."""
    from ..identify.ulog import read_vehicle_log  # vehicle_imu_status only, a damaged log refused at once

    log = dict(read_vehicle_log(path, field=field))
    raw = dict(log["parameters"])
    if not raw:
        raise TunerError(f"{path}: the log stores no parameters (a ULog logged with parameters, or the vehicle's "
                         ".params file)", field=field)
    log["change_notes"] = change_notes(raw, log["changes"], "px4", axis)
    return raw, log


def read_params(path: str | Path, *, axis: str = "roll", firmware: str | None = None, field: str = "params"
                ) -> VehicleParams:
    """The :class:`VehicleParams` of ``axis`` in the file at ``path``: a QGroundControl ``.params`` or a ULog (PX4),
    a Mission Planner ``.parm`` (ArduPilot); ``firmware`` is what the caller's law needs (None: told by the names).

    Raises :class:`~tuner.errors.TunerError` with ``field`` (see the module's docstring).

    Examples
    --------
    >>> import pathlib, tempfile
    >>> from tuner.firmware import read_params
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "quad.params"
    >>> _ = p.write_text("1\\t1\\tMC_ROLLRATE_P\\t0.18\\t9\\n1\\t1\\tMC_ROLLRATE_I\\t0.2\\t9\\n"
    ...                  "1\\t1\\tMC_ROLLRATE_D\\t0.004\\t9\\n1\\t1\\tIMU_GYRO_RATEMAX\\t800\\t6\\n")
    >>> v = read_params(p, axis="roll")
    >>> v.firmware, v.loop_hz, v.gains["D"], v.fixed["K"]
    ('px4', 800.0, 0.004, 1.0)
    """
    from ..fileio import read_head, read_text

    p = Path(path)
    head = read_head(p, len(_ULOG_MAGIC), field=field)  # a regular file only: nothing that could hang
    if head == _ULOG_MAGIC:
        raw, log = _ulog_vehicle(p, axis, field)
        return vehicle_from_raw(raw, axis=axis, firmware=firmware, source=f"{p.name} (ULog parameters)",
                                fmt="ulog", field=field, log=log)
    if head[:3] == b"\xa3\x95\x80":  # an ArduPilot DataFlash log: its PARM messages (tuner.identify.dataflash)
        from ..identify.dataflash import read_dataflash_parameters

        raw, changes = read_dataflash_parameters(p, field=field, history=True)
        return vehicle_from_raw(raw, axis=axis, firmware=firmware, source=f"{p.name} (DataFlash PARM)", fmt="parm",
                                field=field, log={"change_notes": change_notes(raw, changes, "ardupilot", axis)})
    text = read_text(p, limit=MAX_PARAMS_BYTES, field=field,
                     hint="give a QGroundControl .params, a Mission Planner .parm, a ULog .ulg or a DataFlash .bin")
    fmt = {".params": "qgc", ".parm": "parm"}.get(p.suffix.lower())
    if fmt == "parm" and firmware == "px4":
        raise TunerError(f"{p}: a .parm file is ArduPilot's; px4_rate needs {_FILES['px4']}", field=field)
    return vehicle_from_text(text, axis=axis, firmware=firmware, fmt=fmt, source=p.name, field=field)
