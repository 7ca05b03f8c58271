"""Named layouts of the NLP's flat vectors (parameters and decision variables).

CasADi takes one parameter vector ``p`` and one decision vector ``x``. A :class:`Layout` names
their blocks once, from the :class:`~tuner.optimize.nlp.transcribe.ProblemKey`; the same object
*packs* numbers (numpy, in :mod:`~tuner.optimize.nlp.refine`) and *unpacks* symbols (CasADi, in
:mod:`~tuner.optimize.nlp.transcribe`), so no block is ever matched by position by hand.
Matrices are packed row-major.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

__all__ = ["Layout"]

Shape = tuple[int, ...]


@dataclass(frozen=True)
class Layout:
    """Blocks ``(name, shape)`` of a flat vector, in order. ``()`` is a scalar."""

    blocks: tuple[tuple[str, Shape], ...]

    @cached_property
    def _index(self) -> dict[str, tuple[int, int, Shape]]:
        out: dict[str, tuple[int, int, Shape]] = {}
        off = 0
        for name, shape in self.blocks:
            if name in out:
                raise ValueError(f"layout block {name!r} twice")
            n = math.prod(shape)
            out[name] = (off, off + n, shape)
            off += n
        return out

    @property
    def size(self) -> int:
        """The length of the flat vector (every block's elements)."""
        return sum(math.prod(s) for _, s in self.blocks)

    def slice(self, name: str) -> slice:
        """Where block ``name`` lies in the flat vector."""
        a, b, _ = self._index[name]
        return slice(a, b)

    def pack(self, values: Mapping[str, Any]) -> np.ndarray:
        """Numbers for every block (shapes checked) -> the flat vector."""
        missing = [n for n, _ in self.blocks if n not in values]
        extra = sorted(set(values) - set(self._index))
        if missing or extra:
            raise ValueError(f"layout: missing {missing}, unknown {extra}")
        parts = []
        for name, shape in self.blocks:
            a = np.asarray(values[name], dtype=float)
            if a.shape != shape:
                raise ValueError(f"layout block {name!r}: shape {a.shape}, expected {shape}")
            parts.append(a.ravel())
        return np.concatenate(parts) if parts else np.zeros(0)

    def unpack(self, vec: Any) -> dict[str, Any]:
        """The blocks of ``vec`` (numpy or CasADi): scalars, vectors, and row-major matrices."""
        out: dict[str, Any] = {}
        for name, (a, b, shape) in self._index.items():
            part = vec[a:b]
            if len(shape) == 0:
                part = part[0]
            elif len(shape) == 2:
                rows, cols = shape
                if isinstance(part, np.ndarray):
                    part = part.reshape(rows, cols)
                else:  # CasADi reshapes column-major: build the transpose, then transpose
                    import casadi as cs

                    part = cs.reshape(part, cols, rows).T
            out[name] = part
        return out
