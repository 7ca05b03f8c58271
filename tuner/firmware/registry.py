"""The registered firmwares: one entry per module (:data:`MODULES`), each module's ``FIRMWARE`` a
:class:`~tuner.firmware.base.Firmware`. Every other place looks a firmware up here; a name not registered is a
:class:`~tuner.errors.TunerError` naming the ones that are.

Adding a firmware is its module (a :class:`~tuner.firmware.base.Firmware` named ``FIRMWARE``) and its line below;
``tests/firmware/test_contract.py`` then runs the contract suite against it.
"""

from __future__ import annotations

import importlib
from functools import cache

from ..errors import TunerError
from .base import Firmware

__all__ = ["MODULES", "firmwares", "get_firmware", "by_structure", "by_format", "names", "structures", "formats"]

#: the firmware modules, in the order they are offered
MODULES = (
    "tuner.firmware.px4",
    "tuner.firmware.ardupilot",
    "tuner.firmware.betaflight",
)


@cache
def _registry() -> dict[str, Firmware]:
    out: dict[str, Firmware] = {}
    for mod in MODULES:
        fw = importlib.import_module(mod).FIRMWARE
        if fw.name in out:
            raise RuntimeError(f"two firmware modules are named {fw.name!r}")
        out[fw.name] = fw
    return out


def firmwares() -> tuple[Firmware, ...]:
    """Every registered firmware."""
    return tuple(_registry().values())


def names() -> tuple[str, ...]:
    """The registered firmwares' names (``px4``, ``ardupilot``, ...)."""
    return tuple(_registry())


def structures() -> tuple[str, ...]:
    """The registered firmwares' rate-law structures (``px4_rate``, ``ardupilot_rate``, ...)."""
    return tuple(f.structure for f in firmwares())


def formats() -> tuple[str, ...]:
    """The registered firmwares' export formats (``px4``, ``ardupilot``, ...)."""
    return tuple(f.export_format for f in firmwares())


def _known(what: str, have: tuple[str, ...]) -> str:
    return f"{what} must be one of {', '.join(have)}"


def get_firmware(name: str | None, *, field: str = "firmware") -> Firmware:
    """The registered firmware ``name``; a :class:`~tuner.errors.TunerError` naming the known ones otherwise.

    Examples
    --------
    >>> from tuner.firmware.registry import get_firmware
    >>> get_firmware("px4").structure
    'px4_rate'
    >>> get_firmware("inav")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    tuner.errors.TunerError: unknown firmware 'inav': firmware must be one of px4, ardupilot...
    """
    reg = _registry()
    if name not in reg:
        raise TunerError(f"unknown firmware {name!r}: {_known('firmware', names())}", field=field)
    return reg[name]


def by_structure(structure: str | None) -> Firmware | None:
    """The firmware whose rate law ``structure`` is (``px4_rate`` -> PX4), None for a generic structure."""
    return next((f for f in firmwares() if f.structure == structure), None)


def by_format(fmt: str | None) -> Firmware | None:
    """The firmware whose parameter file the export format ``fmt`` is, None for another format."""
    return next((f for f in firmwares() if f.export_format == fmt), None)
