"""A package's public names loaded on first use (PEP 562): ``__getattr__ = lazy_getattr(__name__, WHERE)``; and the
installed version, read from the package metadata on first use (:func:`installed_version`)."""

from __future__ import annotations

import functools
import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_getattr", "is_instance_of", "is_identification", "installed_version"]


def lazy_getattr(package: str, where: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` that imports ``package.<where[name]>`` for ``name`` and keeps the value."""

    def __getattr__(name: str) -> Any:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f".{where[name]}", package), name)
        vars(sys.modules[package])[name] = value
        return value

    return __getattr__


def is_instance_of(obj: Any, module: str, name: str) -> bool:
    """``isinstance(obj, module.name)`` without importing ``module``: a lower layer that accepts a higher layer's
    result (``export`` takes a ``TuneResult``, ``make_plant`` an ``IdentifyResult``) recognises it without
    depending on that layer. An instance can only exist once its class's module is loaded, so looking the class
    up in ``sys.modules`` answers exactly as ``isinstance`` would."""
    mod = sys.modules.get(module)
    cls = getattr(mod, name, None) if mod is not None else None
    return isinstance(cls, type) and isinstance(obj, cls)


def is_identification(obj: Any) -> bool:
    """``obj`` is an :class:`~tuner.identify.IdentifyResult` (checked without importing the package)."""
    return is_instance_of(obj, "tuner.identify.result", "IdentifyResult")


@functools.cache  # (read once per process: ~3 ms each time)
def installed_version(fallback: str) -> str:
    """The installed ``tuner`` package's version (its metadata), or ``fallback`` where there is none (a source tree
    without metadata): ``tuner.__version__``, the exported files' headers."""
    from importlib import metadata

    try:
        return metadata.version("tuner")
    except metadata.PackageNotFoundError:  # pragma: no cover - a source tree without metadata
        return fallback
