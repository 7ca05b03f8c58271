"""The verifier: everything a user is told about a loop comes from here.

``verify`` (metrics, checks, :func:`analyze`), ``margins`` (phase, gain, disk margins, Ms),
``response`` (step responses between samples, step metrics), ``cascade`` (outer loops around a
tuned inner loop) and ``plots``. numpy/scipy and python-control only: no CasADi, no Optuna.
"""

from __future__ import annotations

from .verify import Analysis, Metrics, analyze, analyze_loop

__all__ = ["Analysis", "Metrics", "analyze", "analyze_loop"]
