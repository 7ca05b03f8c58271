"""The scrambled Sobol' points of the search's restarts (:meth:`tuner.optimize.engine.Engine._restart`), without
importing :mod:`scipy.stats`: its import (0.36-0.42 s of CPU, the docstrings of its hundreds of functions processed
at import) was a fifth of a cold ``tuner tune``'s command and a half of a cold ``tuner analyze``'s.

The same points as ``scipy.stats.qmc.Sobol(d, scramble=True, seed=rng).random_base2(m)``, bit for bit
(tests/tuner/test_sobol.py compares them over dimensions, sizes and seeds): the Joe-Kuo direction numbers
(new-joe-kuo-6.21201, read from the data file SciPy ships), 30 bits, a linear matrix scramble and a digital shift
drawn from a child of ``rng`` in the same order, and the points in Gray-code order."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["Sobol", "scrambled"]

BITS = 30
_DIRECTIONS: dict[str, np.ndarray] = {}


def _directions(d: int) -> tuple[np.ndarray, np.ndarray]:
    """The primitive polynomials and initial direction numbers of the first ``d`` dimensions."""
    if "poly" not in _DIRECTIONS:
        from pathlib import Path

        import scipy

        with np.load(Path(scipy.__file__).parent / "stats" / "_sobol_direction_numbers.npz") as z:
            _DIRECTIONS["poly"], _DIRECTIONS["vinit"] = np.array(z["poly"]), np.array(z["vinit"])
    if d > _DIRECTIONS["poly"].size:
        raise ValueError(f"at most {_DIRECTIONS['poly'].size} dimensions")
    return _DIRECTIONS["poly"][:d], _DIRECTIONS["vinit"][:d]


def _direction_matrix(d: int) -> np.ndarray:
    """``v[k, c]``: the ``c``-th direction number of dimension ``k``, as a ``BITS``-bit binary fraction."""
    poly, vinit = _directions(d)
    v = [[1] * BITS]
    for k in range(1, d):
        p = int(poly[k])
        m = p.bit_length() - 1
        row = [int(x) for x in vinit[k, :m]]
        for j in range(m, BITS):  # the recurrence of the polynomial's coefficients (Bratley and Fox 1988)
            new = row[j - m]
            for t in range(m):
                if (p >> (m - 1 - t)) & 1:
                    new ^= row[j - t - 1] << (t + 1)
            row.append(new)
        v.append(row)
    return np.array([[x << (BITS - 1 - c) for c, x in enumerate(row)] for row in v], dtype=np.uint32).reshape(d, BITS)


class Sobol:
    """``Sobol(d, seed=rng)``: a scrambled Sobol' sequence in ``[0, 1)^d``; ``random_base2(m)``: its first ``2^m``
    points (as SciPy's ``qmc.Sobol(d, scramble=True, seed=rng)`` gives them for a ``numpy.random.Generator`` ``rng``,
    what the engine passes; an int or None seed is made a Generator here and spawned from, which SciPy does not do)."""

    def __init__(self, d: int, *, seed: Any) -> None:
        self.d = int(d)
        v = _direction_matrix(self.d)  # (first: where it cannot be read, the caller's generator has spawned nothing)
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        bg = rng.bit_generator
        rng = np.random.Generator(type(bg)(bg.seed_seq.spawn(1)[0]))  # (a child: the caller's stream untouched)
        self.shift = np.dot(rng.integers(2, size=(self.d, BITS), dtype=np.uint32),
                            2 ** np.arange(BITS, dtype=np.uint32))
        ltm = np.tril(rng.integers(2, size=(self.d, BITS, BITS), dtype=np.uint32)).astype(np.int64)
        ltm[:, np.arange(BITS), np.arange(BITS)] = 1
        # the linear matrix scramble: each direction number's bits (most significant first) times the dimension's
        # lower-triangular matrix, over GF(2)
        w = 2 ** np.arange(BITS - 1, -1, -1, dtype=np.int64)
        vbits = (v[:, :, None].astype(np.int64) // w) % 2  # [k, j, c]
        out = np.einsum("kpc,kjc->kjp", ltm, vbits) % 2
        self.v = (out @ w).astype(np.uint32)
        self.generated = 0

    def random_base2(self, m: int) -> np.ndarray:
        """The sequence's first ``2^m`` points (once: a fresh instance for another draw), shape ``(2^m, d)``."""
        if self.generated:
            raise ValueError("only the first 2^m points are drawn")
        n = 2 ** int(m)
        quasi = self.shift.copy()
        out = np.empty((n, self.d))
        out[0] = quasi * (1.0 / 2 ** BITS)
        for i in range(n - 1):  # Gray-code order: the next point flips the direction of i's lowest zero bit
            low = (~i & (i + 1)).bit_length() - 1
            quasi ^= self.v[:, low]
            out[i + 1] = quasi * (1.0 / 2 ** BITS)
        self.generated = n
        return out


def scrambled(d: int, *, seed: Any) -> Any:
    """A scrambled Sobol' sequence in ``[0, 1)^d`` (``random_base2(m)``): :class:`Sobol`, or SciPy's own
    ``qmc.Sobol(d, scramble=True, seed=seed)`` (the same points, at the cost of importing :mod:`scipy.stats`) where
    the direction numbers cannot be read here (SciPy's data file moved or changed)."""
    try:
        return Sobol(d, seed=seed)
    except (OSError, KeyError, ValueError):
        from scipy.stats import qmc

        return qmc.Sobol(d, scramble=True, seed=seed)
