"""Identification from flight data: from a logged input/output record to a fitted transfer function.

The steps of CIFER (Tischler & Remple), one module each:

* :mod:`~tuner.identify.data`: validating a record (lengths, non-finite values, a constant
  input, the time base), detrending, the fit/holdout split;
* :mod:`~tuner.identify.spectral`: the frequency response and coherence by Welch spectra with
  several windows, composited with coherence weighting (COMPOSITE), and the coherent band;
* :mod:`~tuner.identify.model` and :mod:`~tuner.identify.fit`: a gain, factored pole and zero
  sections and a delay, fitted by minimising CIFER's coherence-weighted cost ``J``;
* :mod:`~tuner.identify.uncertainty`: Cramér–Rao bounds and insensitivities at the optimum;
* :mod:`~tuner.identify.validate`: simulating the model on data that excite the band (Theil, NRMSE)
  against the noise floor;
* :mod:`~tuner.identify.result`: :class:`IdentifyResult` (``.plant()``, ``.plot()``, ``.to_dict()``);
* :mod:`~tuner.identify.csvlog`, :mod:`~tuner.identify.ulog` and :mod:`~tuner.identify.cli`: CSV logs,
  PX4 ULog logs (through pyulog: asynchronous topics on one grid, gaps) and ``tuner identify``.

The public entry point is :func:`identify`. Importing this package costs nothing (its names load on
first use: ``tuner --help`` registers ``tuner identify`` without numpy); numpy comes with them, scipy and
matplotlib when they are used.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_getattr

if TYPE_CHECKING:
    from .core import MAX_POLES, identify
    from .result import IdentifyResult

__all__ = ["MAX_POLES", "IdentifyResult", "identify"]
_WHERE = {"MAX_POLES": "core", "identify": "core", "IdentifyResult": "result"}


__getattr__ = lazy_getattr(__name__, _WHERE)
