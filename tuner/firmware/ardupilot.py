"""ArduPilot Copter's rate law (``AC_PID``) behind the firmware seam (:class:`~tuner.firmware.base.Firmware`).

The law's arithmetic is :func:`tuner.firmware.laws.ardupilot_coeffs` / :func:`~tuner.firmware.laws.ardupilot_ref_coeffs`
(``libraries/AC_PID/AC_PID.cpp``, ``AC_PID::update_all``; the sources are named there); the names and documented
ranges are :data:`tuner.firmware.names.ARDUPILOT` and ``RANGES["ardupilot"]``. Here: the loop rate
(``SCHED_LOOP_RATE``, the fast-rate thread), the AC_PID terms the linear law does not hold (refused by name), the
integrator's behaviour in saturation (:class:`Simulator`), the ``NAME,value`` lines, and what to fly.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from ..errors import TunerError
from . import laws
from . import names as _names
from .base import Firmware

__all__ = ["FIRMWARE", "Simulator"]

_FILES = "ArduPilot parameters (a Mission Planner .parm file)"
_AX = {"roll": "RLL", "pitch": "PIT", "yaw": "YAW"}


class Simulator:
    """ArduPilot's ``AC_PID`` one sample per call: the integrator updated before the output, clamped to ``+-IMAX``,
    and while the mixer reports a limit it only shrinks (``AC_PID::update_i`` with ``limit`` set)."""

    def __init__(self, g: dict[str, float], dt: float, lo: float, hi: float) -> None:
        def alpha(f: float) -> float:
            return 1.0 if f <= 0 else dt / (dt + 1.0 / (2.0 * math.pi * f))

        self.p, self.i, self.d, self.ff, self.imax = g["P"], g["I"], g["D"], g["FF"], g["imax"]
        self.at, self.ae, self.ad = alpha(g["fltt_hz"]), alpha(g["flte_hz"]), alpha(g["fltd_hz"])
        self.dt, self.lo, self.hi = dt, lo, hi
        self.dff = g.get("dff", 0.0)
        self.t = self.e = self.de = self.integ = self.e_prev = 0.0
        self.limit = False

    def __call__(self, r: float, y: float) -> tuple[float, bool]:
        t_prev = self.t
        self.t += self.at * (r - self.t)
        self.e += self.ae * ((self.t - y) - self.e)
        self.de += self.ad * ((self.e - self.e_prev) / self.dt - self.de)
        self.e_prev = self.e
        step = self.i * self.e * self.dt
        if not self.limit or (self.integ > 0 > step) or (self.integ < 0 < step):  # only shrink while limited
            self.integ = min(max(self.integ + step, -self.imax), self.imax)
        v = self.p * self.e + self.d * self.de + self.integ + self.ff * self.t + self.dff * (self.t - t_prev) / self.dt
        u = min(max(v, self.lo), self.hi)
        self.limit = u != v
        return u, self.limit


def loop_rate(raw: Mapping[str, float], names: Mapping[str, str], source: str, log: Mapping[str, Any] | None,
              notes: list[str], fld: str) -> tuple[float | None, str] | None:
    """ArduPilot's loop rate (None: not told): ``SCHED_LOOP_RATE``; with the fast-rate thread (``FSTRATE_ENABLE``
    > 0, ArduCopter ``Parameters.cpp``: "the actual rate is the gyro rate in Hz divided by" ``FSTRATE_DIV``) the
    gyro's rate ``INS_GYRO_RATE`` (0: 1 kHz, 1: 2 kHz, 2: 4 kHz, 3: 8 kHz, ``AP_InertialSensor.cpp``) over
    ``FSTRATE_DIV``."""
    name = names["loop_hz"]
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
    return None


def _loop_fix(loop_hz: float | None, loop_source: str, names: Mapping[str, str], notes: list[str],
              rng: tuple[float, float]) -> tuple[float | None, str]:
    """What the vehicle runs: ``AP_Scheduler`` clamps ``SCHED_LOOP_RATE`` to its range when it starts."""
    lo_hz, hi_hz = rng
    if loop_hz is not None and loop_hz > 0 and not lo_hz <= loop_hz <= hi_hz:
        loop_hz = min(max(loop_hz, lo_hz), hi_hz)
    return loop_hz, loop_source


def _unmodelled(raw: Mapping[str, float], axis: str, source: str, fld: str) -> list[str]:
    """ArduPilot's AC_PID terms outside the linear law: PDMX, NTF, NEF set (non-zero) are refused, naming the
    parameter; SMAX is read and what it does said (see :data:`tuner.firmware.names.ARDUPILOT_UNMODELLED`)."""
    a = _AX[axis]
    what = {"PDMX": "the P+D output limit (a clamp on |P + D| in AC_PID::update_all)",
            "NTF": "a notch filter on the target (AP_Filter, FILTn_*)", "NEF": "a notch filter on the error "
            "(AP_Filter, FILTn_*)"}
    for suffix in _names.ARDUPILOT_UNMODELLED:
        name = f"ATC_RAT_{a}_{suffix}"
        if float(raw.get(name, 0.0)) != 0:
            raise TunerError(f"{source}: {name} = {float(raw[name]):g} sets {what[suffix]}, which the tuner's model "
                             f"of the {axis} rate law does not hold, so its margins would not be the vehicle's: set "
                             f"{name} to 0 in the file given to the tuner (and fly the design with it off), or tune "
                             "without it", field=fld)
    smax = f"ATC_RAT_{a}_{_names.ARDUPILOT_SLEW}"
    if float(raw.get(smax, 0.0)) > 0:
        return [f"{smax} = {float(raw[smax]):g}: ArduPilot's slew limiter lowers P and D only when the P+D output "
                "slews faster than that in alternating directions (an oscillation); a loop that does not oscillate "
                "flies the linear law designed here, which does not include it"]
    return []


def _filters_header(values: Mapping[str, float], gyro_words: str) -> str:
    dff = values.get("dff", 0.0)
    return (f"filters assumed (written): FLTT {values['fltt_hz']:g} Hz, FLTE {values['flte_hz']:g} Hz, "
            f"FLTD {values['fltd_hz']:g} Hz" + (f"; D_FF {dff:g} in the designed loop (not written)" if dff
                                                else "") + "; " + gyro_words)


def _log_signals(axis: str) -> dict[str, str]:
    r = {"roll": "R", "pitch": "P", "yaw": "Y"}[axis]
    return {"input": f"RATE.{r}Out", "output": f"RATE.{r}", "reference": f"RATE.{r}Des"}


def what_to_fly(axis: str | None) -> str:
    """What to fly and log on ArduPilot (ArduCopter ``mode_systemid.cpp`` SID_*, ``Copter.h``'s LOG_BITMASK bits)."""
    from ..identify.flight import SWEEP

    ax = axis or "roll"
    ap_axis = {"roll": 7, "pitch": 8, "yaw": 9}.get(ax, 7)
    s = _log_signals(ax)
    return ("ArduPilot: hover in a stabilised mode and switch to SystemID mode (mode 25) with SID_AXIS "
            f"{ap_axis} (rate {ax}), SID_MAGNITUDE 10-30 (deg/s), SID_F_START_HZ 0.05, SID_F_STOP_HZ 10, SID_T_REC "
            "60-90 s, SID_T_FADE_IN 5 and SID_T_FADE_OUT 2 (or fly ACRO with " + SWEEP + "); log with LOG_BITMASK "
            "bits 0 and 1 (attitude fast and medium: RATE and SIDD at the loop rate) and 12 (PID: PIDR/PIDP/PIDY) set; "
            f"identify {s['input']} -> {s['output']} with {s['reference']} (or SIDD.Targ) as the reference")


FIRMWARE = Firmware(
    name="ardupilot", title="ArduPilot", structure="ardupilot_rate", coeffs=laws.ardupilot_coeffs,
    ref_coeffs=laws.ardupilot_ref_coeffs, fixed=laws.ARDUPILOT_FIXED,
    axis_defaults={"yaw": laws._AXIS_DEFAULTS[("ardupilot", "yaw")]},
    names=lambda ax: _names.ARDUPILOT[ax], ranges=lambda ax: _names.RANGES["ardupilot"][ax],
    scale=lambda ax: _names.SCALE["ardupilot"][ax], integer=_names.INTEGER["ardupilot"],
    clamped=_names.CLAMPED["ardupilot"], range_source=_names.SOURCE["ardupilot"],
    export_format="ardupilot", suffix="parm", files=_FILES,
    export_order=("P", "I", "D", "FF", "imax", "fltt_hz", "flte_hz", "fltd_hz"),
    write_line=lambda name, value, ids: f"{name},{value}", filters_header=_filters_header,
    gyro_param="INS_GYRO_FILTER",
    detect_prefixes=("ATC_RAT_", "ATC_ANG_", "SCHED_LOOP_RATE", "INS_GYRO_FILTER", "FRAME_CLASS"),
    default_loop_hz=400.0,  # SCHED_LOOP_RATE's default (firmware.md)
    loop_rate=loop_rate, loop_fix=_loop_fix, vehicle_checks=_unmodelled, formats=("parm", "qgc"),
    simulator=Simulator, simulator_words="ArduPilot's AC_PID (IMAX; the integrator only shrinks while limited)",
    what_to_fly=what_to_fly, log_signals=_log_signals, integrator_limit="imax",
    no_scale_advice=("ArduPilot's rate law has no gain scale: check the plant's units (the identified input is the "
                     "mixer's normalised command, the output the body rate in rad/s)"),
)
