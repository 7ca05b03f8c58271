"""Named numerical tolerances, one source for the whole package (bottom layer: imports nothing).

Each constant says what a comparison *means*; modules import the name instead of typing the
literal, so that the same decision is taken with the same tolerance everywhere. A tolerance is
relative when the comparison multiplies it by a scale (``abs(a - b) > SAME_DT_RTOL * b``),
absolute otherwise; the comment on each says which.

Examples
--------
>>> from tuner.tolerances import SAME_DT_RTOL
>>> dt = 0.01
>>> abs(0.01 * (1 + 1e-12) - dt) <= SAME_DT_RTOL * dt  # the same sample time up to rounding
True
"""

from __future__ import annotations

__all__ = [
    "SAME_DT_RTOL",
    "ROOT_AT_DC_TOL",
    "EXACT_ROOT_TOL",
    "REAL_ROOT_TOL",
    "STABILITY_MARGIN",
    "ALGEBRAIC_LOOP_TOL",
    "ROOT_MAG_FLOOR",
    "SAMPLE_COUNT_TOL",
    "SAMPLE_FRACTION_TOL",
    "LIMIT_RTOL",
    "ROOT_POLISH_RTOL",
    "SAME_COEFF_RTOL",
    "CONSTANT_SIGNAL_RTOL",
]

SAME_DT_RTOL = 1e-9
"""Two sample times are the same when ``|a - b| <= SAME_DT_RTOL * b`` (relative)."""

ROOT_AT_DC_TOL = 1e-9
"""A pole or zero sits at DC (s = 0, z = 1) within this distance (times the roots' scale, or
``max(1, |p|)``, where the caller gives one): an integrator up to rounding."""

EXACT_ROOT_TOL = 1e-12
"""A root placed exactly at a point (an integrator written by the user, a delay pole at z = 0)
is there within this absolute distance: rounding only, nothing computed."""

REAL_ROOT_TOL = 1e-9
"""A root is real when ``|imag| <= REAL_ROOT_TOL`` (times ``max(1, |r|)`` where scaled)."""

STABILITY_MARGIN = 1e-9
"""A pole is stable when inside the stability boundary by this much (times ``max(1, |p|)`` in s,
absolute in z): closer than that is undecidable in floating point and counts as unstable."""

ALGEBRAIC_LOOP_TOL = 1e-12
"""The algebraic loop ``1 + D_c D_p`` (direct feedthroughs) is singular below this: the loop
cannot be formed."""

ROOT_MAG_FLOOR = 1e-9
"""Roots of magnitude below this are at 0 up to rounding: not frequencies (absolute)."""

SAMPLE_COUNT_TOL = 1e-9
"""``floor(x / h + SAMPLE_COUNT_TOL)``: a ratio this close below a whole number of samples is
that number (rounding must not lose a sample)."""

SAMPLE_FRACTION_TOL = 1e-12
"""A delay's fraction of a sample below ``SAMPLE_FRACTION_TOL * h`` is zero: the delay is a
whole number of samples."""

LIMIT_RTOL = 1e-9
"""A value at a limit up to this relative rounding counts as within the limit."""

ROOT_POLISH_RTOL = 1e-12
"""Newton polishing of a root stops when the step is below this times ``max(1, |s|)``."""

SAME_COEFF_RTOL = 1e-12
"""Two coefficient vectors computed two ways are the same polynomial within this (relative)."""

CONSTANT_SIGNAL_RTOL = 1e-12
"""A signal whose spread is below this share of its magnitude is constant (relative: its units
do not matter)."""
