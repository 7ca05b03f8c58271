"""What ``Spec.objective`` means, exactly: one definition per objective, for the docs, ``--help`` and the schema.

Read off the code that computes them: the verifier's step metrics (:mod:`tuner.analysis.response`), the
objective of a verified analysis (:func:`tuner.optimize.scoring.objective_value`), the batched search
(:mod:`tuner.optimize.batch`) and the NLP (:mod:`tuner.optimize.nlp.transcribe`). No import: the command
line's ``--help`` reads this without numpy or pydantic.
"""

from __future__ import annotations

__all__ = ["OBJECTIVE_DEFINITIONS", "ROBUST_NOTE"]

_HORIZON = ("T is the verifier's simulation horizon (10 time constants of the slowest closed-loop pole plus twice "
            "the delay, bounded)")

OBJECTIVE_DEFINITIONS: dict[str, str] = {
    "settling_time": "minimise the settling time of the unit reference step: the last time the plant output y(t) "
                     "(continuous, between the samples too) is outside |y - y_final| <= band*|y_final| (settling "
                     "band, default 2 %), interpolated linearly between the fine instants",
    "itae": "minimise the ITAE of the unit reference step: the integral over [0, T] of t*|1 - y(t)| dt (trapezoid rule "
            f"on the fine grid of the continuous output); {_HORIZON}",
    "iae": "minimise the IAE after a unit step load disturbance added at the plant input (the plant gets u + 1, "
           "before its delay) with r = 0: the integral over [0, T] of |e(t)| dt = |y(t)| dt, e = r - y; T as for itae",
    "ie": "minimise the IE after that unit load step, |integral over [0, inf) of e(t) dt| = 1/Ki for a stable loop "
          "with integral action, Ki = lim s->0 of s*C(s) (continuous) or lim z->1 of (z - 1)*C(z)/dt (discrete): "
          "Ki is maximised (MIGO); infinite without integral action",
    "bandwidth": "maximise the closed-loop bandwidth: the lowest frequency where |T(jw)| falls below |T(0)|/sqrt(2) "
                 "(T = L/(1 + L); T(0) = 1 with integral action), found on the verifier's frequency grid (up to the "
                 "Nyquist frequency pi/dt at dt) and refined by root finding",
    "mks": "minimise the noise sensitivity Mks = max over w of |C/(1 + L)| (how much sensor noise reaches the "
           "actuator), on the verifier's frequency grid and w -> inf: with --settling-max or --wc, the most "
           "noise-robust design at that speed",
    "disk_margin": "maximise the balanced disk margin alpha = min over w of 2|1 + L|/|1 - L| (the largest "
                   "simultaneous gain and phase variation the loop tolerates): with --settling-max or --wc, the "
                   "most robust design at that speed",
}

ROBUST_NOTE = ("Every objective is optimised subject to every constraint of the spec. With several plants the worst "
               "case counts: the largest value over the plants (for bandwidth and disk_margin, the smallest).")
