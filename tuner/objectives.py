"""What ``Spec.objective`` means, exactly: one definition per objective (stated in the registry,
:mod:`tuner.limits`), for the docs, ``--help`` and the schema.

Read off the code that computes them: the verifier's step metrics (:mod:`tuner.analysis.response`), the
objective of a verified analysis (:func:`tuner.optimize.scoring.objective_value`), the batched search
(:mod:`tuner.optimize.batch`) and the NLP (:mod:`tuner.optimize.nlp.transcribe`). No import: the command
line's ``--help`` reads this without numpy or pydantic.
"""

from __future__ import annotations

from .limits import OBJECTIVES

__all__ = ["OBJECTIVE_DEFINITIONS", "ROBUST_NOTE"]

OBJECTIVE_DEFINITIONS: dict[str, str] = {o.name: o.definition for o in OBJECTIVES}

ROBUST_NOTE = ("Every objective is optimised subject to every constraint of the spec. With several plants the worst "
               "case counts: the largest value over the plants (for bandwidth and disk_margin, the smallest).")
