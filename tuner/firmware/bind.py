"""A firmware law bound to a vehicle: what ``--params`` fixes (loop rate, filters, K, integrator limit) applied
to ``px4_rate`` / ``ardupilot_rate``, and the vehicle's current gains as that law's parameters."""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from typing import Any

from ..errors import TunerError
from ..tolerances import SAME_DT_RTOL
from .registry import by_structure, get_firmware, names, structures

__all__ = ["FIRMWARE_OF", "bind_law", "vehicle_dict", "typed_plant", "law_choices"]



class _FirmwareOf(Mapping):
    """The firmware each law's parameters belong to (``px4_rate`` -> ``px4``), read from the registry."""

    def __getitem__(self, structure: str) -> str:
        fw = by_structure(structure)
        if fw is None:
            raise KeyError(structure)
        return fw.name

    def __iter__(self) -> Iterator[str]:
        return iter(structures())

    def __len__(self) -> int:
        return len(structures())


#: the firmware each law's parameters belong to (every registered firmware's structure)
FIRMWARE_OF: Mapping[str, str] = _FirmwareOf()


def law_choices(sep: str = " or ") -> str:
    """The registered rate laws in words: ``px4_rate or ardupilot_rate`` (``sep`` between the last two)."""
    st = structures()
    return st[0] if len(st) == 1 else ", ".join(st[:-1]) + sep + st[-1]


def bind_law(structure: Any, vehicle: Any, dt: float | None, *, field: str = "params"
             ) -> tuple[Any, float, dict[str, float]]:
    """``(structure bound to the vehicle, the loop's dt, the vehicle's current gains as the law's parameters)``.

    ``structure``: a :class:`~tuner.controllers.Structure` or its name (``px4_rate`` or ``ardupilot_rate``);
    ``vehicle``: a :class:`~tuner.firmware.params.VehicleParams`; ``dt``: the loop's sample time if given, which
    must agree with the vehicle's loop rate. Raises :class:`~tuner.errors.TunerError` naming the field:
    a structure that is no firmware law, parameters of the other firmware, a contradicting ``dt``.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> from tuner.firmware.bind import bind_law
    >>> v = SimpleNamespace(firmware="px4", loop_hz=400.0, fixed={"K": 1.0, "dgyro_hz": 30.0, "int_lim": 0.3},
    ...                     gains={"P": 0.15, "I": 0.2, "D": 0.003, "FF": 0.0}, source="x.params")
    >>> st, dt, now = bind_law("px4_rate", v, None)
    >>> st.fixed_values["dgyro_hz"], dt, now["P"], now["K"]
    (30.0, 0.0025, 0.15, 1.0)
    """
    from ..controllers import Structure, get_structure

    st = structure if isinstance(structure, Structure) else get_structure(structure)
    law = by_structure(st.name)
    if law is None:
        raise TunerError(f"vehicle parameters set a firmware rate law: give structure {law_choices()} "
                         f"(got {st.name!r})", field="structure")
    want = law.name
    fw = getattr(vehicle, "firmware", None)
    src = getattr(vehicle, "source", "the parameters")
    if fw != want:
        raise TunerError(f"{src} holds {fw or 'unknown'} parameters, but {st.name} is {want}'s law: give "
                         f"{law.files}", field=field)
    loop_hz = getattr(vehicle, "loop_hz", None)
    vdt = 1.0 / float(loop_hz) if loop_hz else None
    if dt is not None and vdt is not None and abs(dt - vdt) > SAME_DT_RTOL * vdt:
        raise TunerError(f"dt = {dt:g} s contradicts the vehicle's loop rate {float(loop_hz):g} Hz "
                         f"(dt = {vdt:g} s, from {src}): leave dt out, or give the rate the vehicle runs",
                         field="dt")
    loop_dt = dt if dt is not None else vdt
    if loop_dt is None or not math.isfinite(loop_dt) or loop_dt <= 0:
        raise TunerError(f"{src} does not give the loop rate: give dt (the rate loop's sample time)", field="dt")
    st = st.with_fixed({k: v for k, v in dict(getattr(vehicle, "fixed", {}) or {}).items()
                        if k in st.fixed_values})
    axis = getattr(vehicle, "axis", None)
    if axis:
        st = st.with_ranges(axis)  # the documented ranges of the vehicle's axis (the search stays inside them)
    now = {**{p: float(v) for p, v in dict(getattr(vehicle, "gains", {}) or {}).items() if p in st.params},
           **st.fixed_values}
    missing = [p for p in st.params if p not in now]
    if missing:
        raise TunerError(f"{src} lacks the current {', '.join(missing)} of the {st.name} law", field=field)
    return st, float(loop_dt), now


def typed_plant(plant: Any, vehicle: Any) -> tuple[Any, dict[str, Any]]:
    """A typed (not identified) plant with the vehicle's gyro low-pass added, and what was done, in words.

    The gyro low-pass (PX4 ``IMU_GYRO_CUTOFF``, ArduPilot ``INS_GYRO_FILTER``) acts on the rate the law reads; a plant
    identified from the logged rate holds it (PX4 logs ``vehicle_angular_velocity`` after it), a typed one does not.
    Both firmwares run it as a second-order Butterworth (``LowPassFilter2p``, PX4 ``src/lib/mathlib/math/filter``,
    ArduPilot ``libraries/Filter/LowPassFilter2p.cpp``) at the gyro's own rate (1-8 kHz, far above the loop's), so
    it is added in continuous time: ``wc^2/(s^2 + sqrt(2) wc s + wc^2)``, ``wc = 2 pi f``. A discrete plant is left
    as it is (said): the filter runs at the gyro's rate, not at the plant's.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> from tuner import make_plant
    >>> from tuner.firmware.bind import typed_plant
    >>> p, rec = typed_plant(make_plant([10.0], [1.0, 1.0]), SimpleNamespace(firmware="ardupilot", gyro_cutoff_hz=20.0))
    >>> p.order, rec["gyro_filter_hz"], rec["name"]
    (3, 20.0, 'INS_GYRO_FILTER')
    """
    import numpy as np

    from ..plant import make_plant_zpk

    fw = get_firmware(getattr(vehicle, "firmware", None))
    name = fw.gyro_param
    f = getattr(vehicle, "gyro_cutoff_hz", None)
    rec: dict[str, Any] = {"typed": True, "name": name, "gyro_filter_hz": None}
    if not fw.gyro_filter_modelled:
        rec["note"] = (f"typed plant: {fw.title}'s gyro filters ({name} and the rest of its chain) are not modelled, "
                       "so none is added: the plant typed must hold them (a plant identified from the logged, "
                       "filtered gyro does)")
        rec["unmodelled"] = True
        return plant, rec
    if not f or f <= 0:
        rec["note"] = (f"typed plant: the vehicle's file gives no gyro low-pass ({name}), so none is added: the plant "
                       "typed must hold it")
        return plant, rec
    if plant.is_discrete:
        rec["note"] = (f"typed plant in z: the gyro low-pass {name} {f:g} Hz runs at the gyro's rate, not at the "
                       "plant's, and is not added: the plant typed must hold it")
        return plant, rec
    wc = 2.0 * np.pi * float(f)
    bw = wc * np.exp(1j * np.array([0.75, -0.75]) * np.pi)  # the second-order Butterworth's poles
    zk = plant.zpk
    out = make_plant_zpk(zk.zeros, np.concatenate([zk.poles, bw]), zk.gain * wc * wc, delay=plant.delay_s)
    rec["gyro_filter_hz"] = float(f)
    rec["note"] = (f"typed plant: the vehicle's gyro low-pass {name} {f:g} Hz (second order) added to it in the "
                   "loop designed and verified (an identified plant holds it already)")
    return out, rec


def vehicle_dict(vehicle: Any) -> dict[str, Any]:
    """What a result records of the vehicle (for the export's header and the current-vs-proposed report)."""
    keys = ("firmware", "axis", "loop_hz", "loop_source", "gyro_cutoff_hz", "att_p", "rate_max_dps", "source")
    out = {k: getattr(vehicle, k, None) for k in keys}
    out["current_gains"] = {k: float(v) for k, v in dict(getattr(vehicle, "gains", {}) or {}).items()}
    out["fixed"] = {k: float(v) for k, v in dict(getattr(vehicle, "fixed", {}) or {}).items()}
    typed = getattr(vehicle, "typed_plant", None)
    if typed:
        out["typed_plant"] = dict(typed)
    ids = getattr(vehicle, "ids", None)
    if ids:
        out["ids"] = [int(ids[0]), int(ids[1])]
    raw = getattr(vehicle, "raw", None)
    fw, axis = getattr(vehicle, "firmware", None), getattr(vehicle, "axis", None)
    if raw and fw in names() and axis:  # which of the law's parameters the vehicle's list holds
        out["has"] = sorted(n for n in get_firmware(fw).law_names(axis).values() if n in raw)
    notes = getattr(vehicle, "notes", ())
    if notes:
        out["notes"] = list(notes)
    warnings = getattr(vehicle, "warnings", ())
    if warnings:
        out["warnings"] = list(warnings)
    return out
