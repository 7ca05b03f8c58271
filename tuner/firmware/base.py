"""One seam for every autopilot: what the tuner knows of a firmware, behind one interface (:class:`Firmware`).

A firmware is one module (:mod:`tuner.firmware.px4`, :mod:`tuner.firmware.ardupilot`,
:mod:`tuner.firmware.betaflight`) that builds one :class:`Firmware`, and one entry in
:data:`tuner.firmware.registry.MODULES`. Everything else (the structures of :mod:`tuner.controllers`, the parameter
readers of :mod:`tuner.firmware.params`, the parameter files of :mod:`tuner.export.paramfile`, the saturated step of
:mod:`tuner.analysis.saturation`, the identification's advice, the command line's and the service's choices) looks
the firmware up in the registry (:func:`tuner.firmware.registry.get_firmware`); a name the registry does not hold is
an error naming the ones it does, never another firmware's law. ``tests/firmware/test_contract.py`` runs one contract
suite against every registered firmware.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["Firmware", "LawCoeffs"]

#: a law's coefficient function: ``(x = (P, I, D, FF), dt, fixed) -> (numerator, denominator)``, highest power first,
#: plain arithmetic so that numbers (numpy) and symbols (CasADi) both pass through
LawCoeffs = Callable[[Any, Any, dict], tuple[list, list]]


@dataclass(frozen=True)
class Firmware:
    """What the tuner knows of one autopilot's rate law.

    The law (per axis): ``coeffs`` (the feedback path ``C_fb``, acting on the measured rate) and ``ref_coeffs``
    (the setpoint path ``C_r``) of ``x = (P, I, D, FF)``, the loop's ``dt`` and what the vehicle ``fixed`` for it;
    ``fixed`` the roll axis's defaults of those values and ``axis_defaults`` where another axis differs.
    Names and ranges (per axis): ``names(axis)`` maps the law's quantities (``P``, ``I``, ``D``, ``FF``, the fixed
    values, ``loop_hz``, ``gyro_hz``, ``att_p``, ...) to the parameter names; ``ranges(axis)`` the documented
    ``(lo, hi)``; ``scale(axis)`` the magnitude the zero rule resolves against; ``integer`` the quantities stored as
    integers; ``clamped`` those the firmware clamps itself (and how); ``range_source`` the file documenting each range.
    Parameter files: ``formats`` it is read from (``qgc``, ``parm``, ``ulog``, ``cli``), ``export_format`` and
    ``suffix`` of the file written, ``export_order`` (the quantities written), ``write_line`` one line of it,
    ``read_text`` a reader of its own text format (None: the shared QGroundControl / ``NAME,value`` reader),
    ``sniff`` whether a text is in that format. The vehicle: ``detect_prefixes`` (names that tell its files apart),
    ``default_loop_hz``, ``loop_rate`` (the loop's rate and where it came from), ``loop_fix`` (what the firmware
    does with a rate outside its range), ``vehicle_checks`` (parameters outside the law refused or said),
    ``vehicle_notes``. Identification: ``log_signals(axis)`` (input, output, reference) and ``what_to_fly(axis)``.
    The integrator's saturation behaviour: ``simulator(gains, dt, u_min, u_max)`` returns ``law(r, y) -> (u,
    clamped)``, ``simulator_words`` says what it does.
    """

    name: str
    title: str
    structure: str
    coeffs: LawCoeffs
    ref_coeffs: LawCoeffs
    fixed: tuple[tuple[str, float], ...]
    names: Callable[[str], dict[str, str]]
    ranges: Callable[[str], dict[str, tuple[float, float]]]
    scale: Callable[[str], dict[str, float]]
    export_format: str
    suffix: str
    files: str
    export_order: tuple[str, ...]
    write_line: Callable[[str, str, tuple[int, int]], str]
    filters_header: Callable[[Mapping[str, float], str], str]
    gyro_param: str
    detect_prefixes: tuple[str, ...]
    default_loop_hz: float
    loop_rate: Callable[..., tuple[float | None, str]]
    simulator: Callable[[dict, float, float, float], Any]
    simulator_words: str
    what_to_fly: Callable[[str | None], str]
    log_signals: Callable[[str], dict[str, str]]
    axis_defaults: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    integer: tuple[str, ...] = ("loop_hz",)
    clamped: Mapping[str, str] = field(default_factory=dict)
    range_source: Mapping[str, str] = field(default_factory=dict)
    formats: tuple[str, ...] = ()
    refused_formats: Mapping[str, str] = field(default_factory=dict)
    read_text: Callable[..., dict[str, float]] | None = None
    sniff: Callable[[str], bool] | None = None
    loop_fix: Callable[..., tuple[float | None, str]] | None = None
    vehicle_checks: Callable[..., list[str]] | None = None
    vehicle_notes: Callable[[str, Mapping[str, float]], list[str]] | None = None
    #: fixed values that are the firmware's own constants per axis, not parameters (no name in a file)
    constants: tuple[str, ...] = ()
    #: ``(raw, axis, fixed, notes) -> fixed``: what the firmware flies where one parameter overrides another (a
    #: dynamic filter's cutoff over the static one), said in ``notes``; None: the parameters as read
    fixed_from: Callable[..., dict[str, float]] | None = None
    #: ``(log, loop_hz, raw, names, fixed, source, notes) -> {key: value}``: fixed values the log (or its absence)
    #: decides (PX4's D path generation and raw gyro rate), said in ``notes``; None: none
    log_fixed: Callable[..., dict[str, float]] | None = None
    #: the fixed value that limits the integrator (PX4's ``int_lim``, ArduPilot's ``imax``)
    integrator_limit: str | None = None
    #: the quantity that scales P, I and D together (PX4's ``K``), None when the law has none
    gain_scale: str | None = None
    #: what to say of a gain held on a range's end when the law has no gain scale
    no_scale_advice: str = ""
    #: the header written with an export's lines (the vehicle's ids): whether the file names the vehicle
    ids_in_file: bool = False

    def law_defaults(self, axis: str) -> dict[str, float]:
        """The defaults of what the law fixes on ``axis``."""
        return dict(self.fixed) | dict(self.axis_defaults.get(axis, {}))

    def axis_fixed(self, axis: str, fixed: Mapping[str, float]) -> dict[str, float]:
        """The values of ``fixed`` still at roll's default whose default differs on ``axis``, as ``axis``'s."""
        base = dict(self.fixed)
        return {k: v for k, v in self.axis_defaults.get(axis, {}).items() if fixed.get(k) == base[k]}

    def law_names(self, axis: str) -> dict[str, str]:
        """The law's parameter names on ``axis`` (a copy)."""
        return dict(self.names(axis))
