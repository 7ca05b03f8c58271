"""Numbers that enter the NLP as parameters: the plant's lifted sampled-data model and factored form.

For a continuous plant driven through a ZOH at ``dt`` the output at ``t_k + j*dt/N``
(``j = 0..N-1``) is exactly ``Cf[j] @ x_k + Df[j] * u_k``, with ``x_{k+1} = Phi @ x_k + Gam * u_k``
(the ZOH of the plant's cascade realisation, :mod:`tuner.lti`). The frequency response the NLP
needs at its crossover frequencies comes from the plant's zeros, poles and gain (of the ZOH plant
for sampled-data loops), never from expanded polynomials. Everything here is numeric; the
symbolic side never sees the plant, only these arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...analysis.response import lifted
from ...loop import Loop

__all__ = ["LiftedPlant", "lift"]


@dataclass(frozen=True)
class LiftedPlant:
    """One plant as the NLP's parameters: the exact lifted ZOH model (sample instants and ``N`` points
    between samples) and the factored form whose frequency response the NLP evaluates."""

    Phi: np.ndarray  # n x n
    Gam: np.ndarray  # n
    C: np.ndarray  # n (sample-instant output row)
    D: float
    Cf: np.ndarray  # N x n (outputs between samples)
    Df: np.ndarray  # N
    zeros: np.ndarray  # of the plant whose frequency response the NLP evaluates (complex)
    poles: np.ndarray
    gain: float
    delay_samples: int

    @property
    def n(self) -> int:
        """The number of plant states."""
        return self.Phi.shape[0]

    def blocks(self, i: int, *, delay_s: float = 0.0) -> dict[str, np.ndarray | float]:
        """This plant's parameter blocks as plant ``i`` of the NLP (names of
        :func:`~tuner.optimize.nlp.transcribe.parameter_layout`); ``delay_s``: a continuous delay."""
        return {f"Phi{i}": self.Phi, f"Gam{i}": self.Gam, f"C{i}": self.C, f"D{i}": self.D, f"Cf{i}": self.Cf,
                f"Df{i}": self.Df, f"zr{i}": self.zeros.real, f"zi{i}": self.zeros.imag, f"pr{i}": self.poles.real,
                f"pi{i}": self.poles.imag, f"k{i}": self.gain, f"tau{i}": delay_s}

    def with_response_of(self, zpk) -> LiftedPlant:
        """The same simulation model, with another plant's factored form for the frequency response."""
        return LiftedPlant(self.Phi, self.Gam, self.C, self.D, self.Cf, self.Df, np.asarray(zpk.zeros, complex),
                           np.asarray(zpk.poles, complex), float(zpk.gain), self.delay_samples)


def lift(loop: Loop, N: int) -> LiftedPlant:
    """Lifted model of ``loop``'s plant at the loop's dt (sampled-data loops only); ``N = 1`` (or a plant
    known only at the samples) gives the sample instants only."""
    if loop.dt is None or loop.plant_d is None:
        raise ValueError("lift() needs a sampled-data loop")
    pd = loop.plant_d
    g = pd.ss()
    zk = pd.zpk
    if loop.plant_ct is None or N <= 1:
        Cf, Df = g.C[None, :].copy(), np.array([g.D])
    else:
        Cf, Df = lifted(loop, N)
    return LiftedPlant(g.A, g.B, g.C, float(g.D), Cf, Df, np.asarray(zk.zeros, complex),
                       np.asarray(zk.poles, complex), float(zk.gain), loop.delay_samples)
