"""Numbers that enter the NLP as parameters: the plant's lifted sampled-data model.

For a continuous plant ``(A, B, C, D)`` driven through a ZOH at ``dt``, the output
at ``t_k + j*dt/N`` (``j = 0..N-1``) is exactly ``Cf[j] @ x_k + Df[j] * u_k``, and
``x_{k+1} = Phi @ x_k + Gam * u_k``. Everything here is numeric (numpy/scipy);
the symbolic side never sees the plant, only these arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import control as ct
import numpy as np
from scipy import linalg

from ...loop import Loop

__all__ = ["LiftedPlant", "lift"]


@dataclass(frozen=True)
class LiftedPlant:
    Phi: np.ndarray  # n x n
    Gam: np.ndarray  # n
    C: np.ndarray  # n (sample-instant output row)
    D: float
    Cf: np.ndarray  # N x n (outputs between samples)
    Df: np.ndarray  # N
    num_d: np.ndarray  # discrete plant numerator at dt (for the frequency response), padded to n+1
    den_d: np.ndarray  # discrete plant denominator at dt, n+1 (delay not included)
    delay_samples: int

    @property
    def n(self) -> int:
        return self.Phi.shape[0]

    def blocks(self, i: int, *, delay_s: float = 0.0) -> dict[str, np.ndarray | float]:
        """This plant's parameter blocks as plant ``i`` of the NLP (names of
        :func:`~tuner.optimize.nlp.transcribe.parameter_layout`); ``delay_s``: a continuous delay."""
        return {f"Phi{i}": self.Phi, f"Gam{i}": self.Gam, f"C{i}": self.C, f"D{i}": self.D, f"Cf{i}": self.Cf,
                f"Df{i}": self.Df, f"num{i}": self.num_d, f"den{i}": self.den_d, f"tau{i}": delay_s}


def _ss(num: np.ndarray, den: np.ndarray, dt: float | None):
    sys = ct.tf2ss(ct.tf(num, den, 0 if dt is None else dt))
    A = np.atleast_2d(np.asarray(sys.A, float))
    B = np.asarray(sys.B, float).reshape(-1)
    C = np.asarray(sys.C, float).reshape(-1)
    D = float(np.asarray(sys.D, float).reshape(-1)[0])
    return A, B, C, D


def lift(loop: Loop, N: int) -> LiftedPlant:
    """Lifted model of ``loop``'s plant at the loop's dt (sampled-data loops only)."""
    if loop.dt is None or loop.plant_d is None:
        raise ValueError("lift() needs a sampled-data loop")
    dt = loop.dt
    pd = loop.plant_d
    n_ord = pd.den.size - 1
    num_d = np.concatenate([np.zeros(n_ord + 1 - pd.num.size), pd.num])
    if loop.plant_ct is None or N <= 1:
        A, B, C, D = _ss(pd.num, pd.den, dt)
        return LiftedPlant(A, B, C, D, C[None, :].copy(), np.array([D]), num_d, pd.den.copy(), loop.delay_samples)
    A, B, C, D = _ss(loop.plant_ct.num, loop.plant_ct.den, None)
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = A, B
    Cf = np.zeros((N, n))
    Df = np.zeros(N)
    for j in range(N):
        E = linalg.expm(M * (j * dt / N))
        Cf[j] = C @ E[:n, :n]
        Df[j] = C @ E[:n, n] + D
    E = linalg.expm(M * dt)
    return LiftedPlant(E[:n, :n], E[:n, n], C, D, Cf, Df, num_d, pd.den.copy(), loop.delay_samples)
