"""Betaflight's rate PID (``pidController``) behind the firmware seam (:class:`~tuner.firmware.base.Firmware`).

Source: ``src/main/flight/pid.c`` of betaflight/betaflight at 47f44857501505ae8fef7c8b98140f38b35b4b8b (the 4.3/4.4
generation: ``dterm_lpf1/2``, ``pidRuntime``); the scaling constants and defaults as ``src/main/flight/pid.h`` of
that generation defines them (``PTERM_SCALE 0.032029f``, ``ITERM_SCALE 0.244381f``, ``DTERM_SCALE 0.000529f``,
``FEEDFORWARD_SCALE 0.013754f``, ``PID_GAIN_MAX 250``, ``F_GAIN_MAX 1000``, ``PID_ROLL_DEFAULT {45, 80, 40, 120}``,
``PID_PITCH_DEFAULT {47, 84, 46, 125}``, ``PID_YAW_DEFAULT {45, 80, 0, 120}``, ``DTERM_LPF1_DYN_MIN_HZ_DEFAULT 75``,
``DTERM_LPF1_DYN_MAX_HZ_DEFAULT 150``, ``DTERM_LPF2_HZ_DEFAULT 150``), ``pidInitConfig`` (``pid_init.c``: ``Kp =
PTERM_SCALE * P``, ``Ki = ITERM_SCALE * I``, ``Kd = DTERM_SCALE * D``, ``Kf = FEEDFORWARD_SCALE * (F * 0.01f)``, and
yaw's ``Ki *= 2.5f`` unless ``use_integrated_yaw``), and the mixer's ``constrainf(pidData[axis].Sum,
-pidSumLimit, pidSumLimit) / PID_MIXER_SCALING`` (``mixer.c``, ``PID_MIXER_SCALING`` 1000) that turns the PID sum
into the motor mix's normalised command. The CLI ranges (``settings.c``): ``iterm_limit`` 0-500, ``yaw_lowpass_hz``
0-500; P, I, D 0-250 and F 0-1000 (``PID_GAIN_MAX``, ``F_GAIN_MAX``); the D-term low-pass cutoffs are >= 0 (their
upper end is not transcribed here). P, I, D, F are stored as integers (``uint8_t``, ``uint16_t``).

What ``pidController`` computes each PID loop, per axis, in deg/s (``gyro.gyroADCf``, ``getSetpointRate``), and what
the law here holds (the tuner's units: the rate in rad/s, the output the mixer's normalised command, so every gain is
times ``(180/pi)/1000``)::

    P   = Kp e                          e = setpoint - gyro   (yaw: P through the PT1 at yaw_lowpass_hz)
    I  += Ki dt e;  I = clamp(I, +-iterm_limit)                (updated before the sum: backward Euler)
    D   = -Kd (g_k - g_k-1)/dt          g: the gyro through the D-term notch, lowpass 1 and lowpass 2 (D on the
                                        measurement)
    F   = Kf (r_k - r_k-1)/dt           (the setpoint's change per loop, feedforwardApply's pidSetpointDelta)
    sum = P + I + D + F,  u = sum/1000

    C_fb(z) = c [Kp H_Y + Ki dt z/(z - 1) + Kd (z - 1)/(dt z) H_1 H_2]      acting on -w
    C_r(z)  = c [Kp H_Y + Ki dt z/(z - 1) + Kf (z - 1)/(dt z)]             acting on the setpoint

with ``H_f = a z/(z - (1 - a))`` Betaflight's ``pt1FilterApply`` (``k = dT/(dT + 1/(2 pi f))``), ``c =
(180/pi)/1000``. Both paths over one denominator ``(z - 1) z D_Y D_1 D_2``.

**Left out** (said on reading a vehicle's file, or refused by name where it would change the linear law): TPA
(``tpa_rate`` above ``tpa_breakpoint``: D, or P and D, lowered at high throttle; the law is hover's, below the
breakpoint), ``iterm_relax`` (the I term's error cut while the setpoint moves fast: the load response is the law's,
a setpoint step's I differs), anti-gravity (I and P boosted on throttle changes), ``d_min`` (D between ``d_min`` and
``d``, raised on sharp moves: the law holds ``d``), the feedforward's RC-frame smoothing, jitter reduction, boost,
averaging and limits (the law's F is the basic ``Kf`` times the setpoint's change), the dynamic D-term low-pass (its
cutoff moves with throttle from ``dterm_lpf1_dyn_min_hz`` to ``..._max_hz``: the law holds the minimum, the most lag),
the gyro's filters, dynamic notches and RPM filter (upstream: part of an identified plant), ``pidsum_limit`` (a clamp:
the saturated step's actuator limits), ``itermWindup`` (``dynCi`` from the motors' mix range: the saturated step
holds the integrator while the output is clamped), crash recovery, launch control, acro trainer, absolute control,
``use_integrated_yaw``. D-term low-pass types other than PT1 and a D-term notch are refused by name.

The loop rate: the gyro's rate over ``pid_process_denom``; a CLI dump does not say the gyro's rate: 8 kHz is assumed
(the MPU6000's and ICM-426xx's; a BMI270 runs at 3.2 kHz: give dt) and said.

Parameter files: Betaflight's CLI ``dump`` / ``diff`` text, ``set NAME = VALUE`` lines (``#`` comments; ``profile N``
sections: the profile selected last is read), written the same way for its CLI to paste (then ``save``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

from ..errors import TunerError
from .base import Firmware
from .laws import alpha, poly_add, poly_mul

__all__ = ["FIRMWARE", "Simulator", "PTERM_SCALE", "ITERM_SCALE", "DTERM_SCALE", "FEEDFORWARD_SCALE",
           "PID_MIXER_SCALING", "read_cli"]

PTERM_SCALE = 0.032029
ITERM_SCALE = 0.244381
DTERM_SCALE = 0.000529
FEEDFORWARD_SCALE = 0.013754
PID_MIXER_SCALING = 1000.0
YAW_KI_FACTOR = 2.5  # pid_init.c: pidCoefficient[FD_YAW].Ki *= 2.5f
_C = (180.0 / math.pi) / PID_MIXER_SCALING  # rad/s in, the mixer's normalised command out
#: settings.c: dterm_lpf1_static_hz and dterm_lpf2_static_hz take 0-LPF_MAX_HZ (sensors/gyro.h: 1000, "so little
#: filtering above 1000hz that if the user wants less delay, they must disable the filter")
LPF_MAX_HZ = 1000.0
_AX = {"roll": "roll", "pitch": "pitch", "yaw": "yaw"}
_FILES = ("Betaflight parameters (its CLI dump: set NAME = VALUE lines, a .txt; a diff lists only what differs from "
          "the defaults, so a stock PID is missing from it: give the dump)")
#: the D-term low-pass types (settings.c lookupTableDtermLowpassType): only PT1 is modelled
_LPF_TYPES = {"PT1": 0.0, "BIQUAD": 1.0, "PT2": 2.0, "PT3": 3.0}
#: settings whose value is a word, read as 0 (OFF) or 1 (any other: on)
_SWITCHES = ("iterm_relax",)


#: the law's fixed values (roll's defaults; yaw: :data:`_YAW`): the D-term low-passes 1 and 2 (PT1, Hz; 0 = off),
#: yaw's P-term low-pass (roll and pitch have none), the I-term limit (PID units) and the I gain's factor (yaw 2.5)
FIXED: tuple[tuple[str, float], ...] = (("dlpf1_hz", 75.0), ("dlpf2_hz", 150.0), ("yaw_lpf_hz", 0.0),
                                        ("iterm_limit", 400.0), ("i_mult", 1.0))
_YAW = {"yaw_lpf_hz": 100.0, "i_mult": YAW_KI_FACTOR}


def _names(axis: str) -> dict[str, str]:
    a = _AX[axis]
    return {"P": f"p_{a}", "I": f"i_{a}", "D": f"d_{a}", "FF": f"f_{a}", "iterm_limit": "iterm_limit",
            "dlpf1_hz": "dterm_lpf1_static_hz", "dlpf2_hz": "dterm_lpf2_static_hz", "loop_hz": "pid_process_denom",
            **({"yaw_lpf_hz": "yaw_lowpass_hz"} if axis == "yaw" else {})}


#: the settings the law reads as numbers, and the checks' D-min and dynamic-filter settings (every axis): a word
#: there is refused, never skipped (the settings behind the checks' notes alone, anti_gravity_gain, tpa_rate and
#: feedforward_boost, are not: a word there is skipped like any setting the law does not read)
_LAW_SETTINGS = frozenset(v for a in _AX for v in _names(a).values()) | {f"d_min_{a}" for a in _AX} | {
    "dterm_lpf1_dyn_min_hz", "dterm_lpf1_dyn_max_hz", "dterm_notch_hz"}


def _ranges(axis: str) -> dict[str, tuple[float, float]]:
    return {"P": (0.0, 250.0), "I": (0.0, 250.0), "D": (0.0, 250.0), "FF": (0.0, 1000.0),
            "iterm_limit": (0.0, 500.0), "dlpf1_hz": (0.0, LPF_MAX_HZ),
            "dlpf2_hz": (0.0, LPF_MAX_HZ),
            **({"yaw_lpf_hz": (0.0, 500.0)} if axis == "yaw" else {})}


def _scale(axis: str) -> dict[str, float]:
    return {"P": 250.0, "I": 250.0, "D": 250.0, "FF": 1000.0, "iterm_limit": 500.0}


def _lp(f_hz: float, dt: Any) -> tuple[list, list]:
    if f_hz <= 0:
        return [1], [1]
    a = alpha(f_hz, dt)
    return [a, 0], [1, -(1 - a)]


def _parts(x: Any, dt: Any, fixed: dict[str, float]) -> tuple[list, list, list]:
    """The P+I numerator, the denominator (z - 1) z D_Y D_1 D_2, and the filter polynomials for D."""
    kp = _C * PTERM_SCALE * x[0]
    ki = _C * ITERM_SCALE * fixed["i_mult"] * x[1]
    ny, dy = _lp(fixed["yaw_lpf_hz"], dt)
    n1, d1 = _lp(fixed["dlpf1_hz"], dt)
    n2, d2 = _lp(fixed["dlpf2_hz"], dt)
    d12 = poly_mul(d1, d2)
    den = poly_mul(poly_mul([1, -1], [1, 0]), poly_mul(dy, d12))
    p = poly_mul([kp * c for c in ny], poly_mul(poly_mul([1, -1], [1, 0]), d12))  # Kp N_Y (z - 1) z D_1 D_2
    i = poly_mul([ki * dt, 0, 0], poly_mul(dy, d12))  # Ki dt z^2 D_Y D_1 D_2
    return poly_add(p, i), den, [dy, poly_mul(n1, n2), d12]


def coeffs(x: Any, dt: Any, fixed: dict[str, float]) -> tuple[list, list]:
    """The feedback path ``C_fb`` (on the measured rate; D on the measurement through the D-term low-passes)."""
    pi, den, (dy, n12, _) = _parts(x, dt, fixed)
    kd = _C * DTERM_SCALE * x[2]
    d = poly_mul([kd / dt * c for c in poly_mul([1, -1], [1, -1])], poly_mul(dy, n12))  # Kd/dt (z-1)^2 D_Y N_1 N_2
    return poly_add(pi, d), den


def ref_coeffs(x: Any, dt: Any, fixed: dict[str, float]) -> tuple[list, list]:
    """The setpoint path ``C_r``: P and I on the error, F on the setpoint's change per loop."""
    pi, den, (dy, _, d12) = _parts(x, dt, fixed)
    kf = _C * FEEDFORWARD_SCALE * 0.01 * x[3]
    f = poly_mul([kf / dt * c for c in poly_mul([1, -1], [1, -1])], poly_mul(dy, d12))  # Kf/dt (z-1)^2 D_Y D_1 D_2
    return poly_add(pi, f), den


class Simulator:
    """``pidController`` one PID loop per call (deg/s inside, as the firmware computes; rad/s and the normalised
    command outside): the D-term gyro through its PT1 low-passes, D on its change, P (yaw: low-passed), the I term
    updated before the sum and clamped to ``+-iterm_limit``, F on the setpoint's change. In saturation the I term is
    held while the output is clamped (the firmware's ``dynCi``, from the motors' mix range above ``iterm_windup``,
    is 0 when the mix is saturated: this approximates it by the axis' own output)."""

    def __init__(self, g: dict[str, float], dt: float, lo: float, hi: float) -> None:
        self.kp, self.kd = PTERM_SCALE * g["P"], DTERM_SCALE * g["D"]
        self.ki, self.kf = ITERM_SCALE * g["I"] * g["i_mult"], FEEDFORWARD_SCALE * g["FF"] * 0.01
        self.a1, self.a2, self.ay = (alpha(g[k], dt) for k in ("dlpf1_hz", "dlpf2_hz", "yaw_lpf_hz"))
        self.lim, self.dt, self.lo, self.hi = g["iterm_limit"], dt, lo, hi
        self.g1 = self.g2 = self.g2_prev = self.i = self.r_prev = self.p = 0.0
        self.clamped = False

    def __call__(self, r: float, y: float) -> tuple[float, bool]:
        rd, yd = math.degrees(r), math.degrees(y)
        self.g1 += self.a1 * (yd - self.g1)  # pt1FilterApply: state += k (input - state)
        self.g2 += self.a2 * (self.g1 - self.g2)
        e = rd - yd
        self.p += self.ay * (self.kp * e - self.p)  # (ay = 1: no P low-pass)
        if not self.clamped:
            self.i = min(max(self.i + self.ki * self.dt * e, -self.lim), self.lim)
        d = -self.kd * (self.g2 - self.g2_prev) / self.dt
        self.g2_prev = self.g2
        f = self.kf * (rd - self.r_prev) / self.dt
        self.r_prev = rd
        v = (self.p + self.i + d + f) / PID_MIXER_SCALING
        u = min(max(v, self.lo), self.hi)
        self.clamped = u != v
        return u, self.clamped


_SET = re.compile(r"^\s*set\s+([A-Za-z0-9_]+)\s*=\s*(\S+)\s*$")


def sniff(text: str) -> bool:
    """Whether ``text`` is a Betaflight CLI dump or diff (``set NAME = VALUE`` lines)."""
    return any(_SET.match(ln) for ln in text.splitlines()[:2000])


def read_cli(text: str, *, source: str = "parameters", field: str = "params") -> dict[str, float]:
    """``{name: value}`` of a CLI dump or diff: its ``set`` lines, those of the PID profile selected last (a ``diff
    all`` holds every profile and restores the selection at its end); the D-term low-pass types as numbers (PT1 0,
    BIQUAD 1, PT2 2, PT3 3), ``iterm_relax`` as 0 (OFF) or 1; other words (``ON``, ``OFF``, ...) are not read.

    Examples
    --------
    >>> from tuner.firmware.betaflight import read_cli
    >>> read_cli("# diff\\nprofile 1\\nset p_roll = 50\\nprofile 0\\nset p_roll = 45\\nset dterm_lpf1_type = PT1\\n")
    {'p_roll': 45.0, 'dterm_lpf1_type': 0.0}
    """
    by: dict[Any, dict[str, float]] = {}
    section: Any = None
    profile: Any = None
    for i, ln in enumerate(text.splitlines(), 1):
        s = ln.strip()
        if not s or s.startswith("#"):
            continue
        words = s.split()
        if words[0] == "profile" and len(words) == 2 and words[1].isdigit():
            section = profile = int(words[1])
            continue
        if words[0] == "rateprofile":
            section = None  # the rate profiles hold no PID values
            continue
        m = _SET.match(s)
        if m is None:
            continue
        name, value = m.group(1), m.group(2)
        if value.upper() in _LPF_TYPES and name.endswith("_type"):
            v = _LPF_TYPES[value.upper()]
        elif name in ("dterm_lpf1_type", "dterm_lpf2_type"):  # (a type the table does not name: never PT1 by default)
            raise TunerError(f"{source} line {i}: {name} = {value!r} is not a D-term low-pass type Betaflight names "
                             f"({', '.join(_LPF_TYPES)}); the tuner's model holds PT1", field=field)
        elif name in _SWITCHES and not value.replace(".", "", 1).isdigit():
            v = 0.0 if value.upper() == "OFF" else 1.0  # iterm_relax RP, RPY, ...: on
        else:
            try:
                v = float(value)
            except ValueError:
                if name in _LAW_SETTINGS:  # (a word where the law reads a number: never skipped silently)
                    raise TunerError(f"{source} line {i}: {name} = {value!r} is not a number", field=field) from None
                continue  # (settings the law does not read hold words: craft_name, gyro_to_use = FIRST, ...)
            if not math.isfinite(v):
                raise TunerError(f"{source} line {i}: {name} = {value!r} is not a finite number", field=field)
        by.setdefault(section, {})[name] = v
    out = {**by.get(None, {}), **by.get(profile, {})}
    if not out:
        raise TunerError(f"{source}: no set NAME = VALUE lines in it (a Betaflight CLI dump or diff)", field=field)
    return out


def loop_rate(raw: Mapping[str, float], names: Mapping[str, str], source: str, log: Mapping[str, Any] | None,
              notes: list[str], fld: str) -> tuple[float | None, str] | None:
    """The PID loop's rate: the gyro's over ``pid_process_denom`` (the gyro's rate assumed 8 kHz, said)."""
    denom = raw.get("pid_process_denom")
    if denom is None:
        return None
    if denom < 1 or denom != round(denom):
        raise TunerError(f"{source}: pid_process_denom = {denom:g} is not a whole number >= 1", field=fld)
    notes.append("the gyro's rate is not in a CLI dump: 8 kHz assumed (MPU6000, ICM-426xx; a BMI270 runs at "
                 "3.2 kHz: then give dt)")
    return 8000.0 / denom, f"assumed: an 8 kHz gyro over pid_process_denom {denom:g} in {source}"


def _fixed_from(raw: Mapping[str, float], axis: str, fixed: dict[str, float], notes: list[str]) -> dict[str, float]:
    """The dynamic D-term low-pass 1 (``dterm_lpf1_dyn_min_hz`` > 0) overrides the static cutoff: its minimum."""
    lo = float(raw.get("dterm_lpf1_dyn_min_hz", 0.0))
    if lo > 0:
        hi = float(raw.get("dterm_lpf1_dyn_max_hz", lo))
        notes.append(f"dterm_lpf1_dyn_min_hz = {lo:g}: the D-term low-pass 1 moves with throttle from {lo:g} to "
                     f"{hi:g} Hz; the law holds {lo:g} Hz (the most lag)")
        return {**fixed, "dlpf1_hz": lo}
    return fixed


def _checks(raw: Mapping[str, float], axis: str, source: str, fld: str) -> list[str]:
    """Refuse what would change the linear law unmodelled (a D-term low-pass other than PT1, the D-term notch); say
    what is left out."""
    for k in ("dterm_lpf1_type", "dterm_lpf2_type"):
        if raw.get(k, 0.0) != 0:
            kind = {v: n for n, v in _LPF_TYPES.items()}.get(raw[k], f"{raw[k]:g}")
            raise TunerError(f"{source}: {k} = {kind}: the tuner's model of Betaflight's D term holds PT1 "
                             f"low-passes only: set {k} = PT1 in the file given to the tuner (and fly it), or tune "
                             "without it", field=fld)
    if raw.get("dterm_notch_hz", 0.0) > 0:
        raise TunerError(f"{source}: dterm_notch_hz = {raw['dterm_notch_hz']:g} sets a notch on the D term, which the "
                         "tuner's model does not hold: set dterm_notch_hz = 0 in the file given to the tuner (and fly "
                         "it), or tune without it", field=fld)
    notes = []
    a = _AX[axis]
    if raw.get(f"d_min_{a}", 0.0) > 0:
        notes.append(f"d_min_{a} = {raw[f'd_min_{a}']:g}: Betaflight flies D between d_min and d_{a} (raised on sharp "
                     f"moves); the law holds d_{a}")
    left = [w for k, w in (("iterm_relax", "iterm_relax (the I term's error cut while the setpoint moves fast)"),
                           ("anti_gravity_gain", "anti-gravity (I and P boosted on throttle changes)"),
                           ("tpa_rate", "TPA (D lowered above tpa_breakpoint: the law is hover's)"),
                           ("feedforward_boost", "the feedforward's boost, smoothing and jitter reduction"))
            if raw.get(k, 0.0) > 0]
    if left:
        notes.append("left out of the linear law (they act on fast setpoint or throttle changes): " + "; ".join(left))
    return notes


def _filters_header(values: Mapping[str, float], gyro_words: str) -> str:
    yaw = values.get("yaw_lpf_hz", 0.0)
    return (f"filters assumed (not written: set them): D-term low-pass 1 dterm_lpf1 {values['dlpf1_hz']:g} Hz and 2 "
            f"dterm_lpf2_static_hz {values['dlpf2_hz']:g} Hz, PT1" + (f", yaw P low-pass yaw_lowpass_hz {yaw:g} Hz"
                                                                      if yaw > 0 else "")
            + f"; I x{values.get('i_mult', 1.0):g} (pid_init.c); " + gyro_words
            + "; gains are whole numbers: written rounded; paste into the CLI, then save")


def _log_signals(axis: str) -> dict[str, str]:
    i = {"roll": 0, "pitch": 1, "yaw": 2}[axis]
    return {"input": f"(axisP[{i}] + axisI[{i}] + axisD[{i}] + axisF[{i}])/1000",
            "output": f"gyroADC[{i}] (deg/s: x pi/180)", "reference": f"setpoint[{i}]"}


def what_to_fly(axis: str | None) -> str:
    """What to fly and log on Betaflight: Acro, Blackbox at the PID loop's rate, the PID sum and the gyro."""
    from ..identify.flight import SWEEP

    s = _log_signals(axis or "roll")
    return ("Betaflight: fly Acro (no angle or horizon mode, air mode on) with " + SWEEP + "; log with Blackbox at the "
            "PID loop's rate (blackbox_sample_rate 1/1), iterm_relax and anti_gravity off for the flight; decode the "
            f"log to CSV (blackbox_decode) and identify {s['input']} -> {s['output']} with {s['reference']} as the "
            "reference (the tuner does not read Blackbox logs itself)")


FIRMWARE = Firmware(
    name="betaflight", title="Betaflight", structure="betaflight_rate", coeffs=coeffs, ref_coeffs=ref_coeffs,
    fixed=FIXED, axis_defaults={"yaw": _YAW}, constants=("i_mult",), names=_names, ranges=_ranges, scale=_scale,
    integer=("P", "I", "D", "FF", "iterm_limit", "loop_hz"),
    range_source={**dict.fromkeys(("P", "I", "D", "FF", "iterm_limit", "yaw_lpf_hz"),
                                  "Betaflight's pid.h / settings.c"),
                  **dict.fromkeys(("dlpf1_hz", "dlpf2_hz"), "Betaflight's settings.c, LPF_MAX_HZ in sensors/gyro.h")},
    export_format="betaflight", suffix="txt", files=_FILES, export_order=("P", "I", "D", "FF", "iterm_limit"),
    write_line=lambda name, value, ids: f"set {name} = {int(float(value)) if float(value).is_integer() else value}",
    filters_header=_filters_header, gyro_param="gyro_lpf1_static_hz", gyro_filter_modelled=False,
    detect_prefixes=("p_roll", "p_pitch", "p_yaw", "pid_process_denom", "dterm_lpf"),
    default_loop_hz=8000.0, loop_rate=loop_rate, formats=("cli",), read_text=read_cli, sniff=sniff,
    fixed_from=_fixed_from, vehicle_checks=_checks, simulator=Simulator,
    simulator_words="Betaflight's pidController (I clamped to iterm_limit, held while the output is clamped)",
    what_to_fly=what_to_fly, log_signals=_log_signals, integrator_limit="iterm_limit",
    no_scale_advice=("Betaflight's rate law has no gain scale: check the plant's units (the identified input is the "
                     "mixer's normalised command, PID sum/1000, the output the body rate in rad/s)"),
)
