"""The verifier's state recursion in blocks (tuner.analysis.response._run) against the recursion stepped state by
state, written here: the same states to rounding, on stable loops of several kinds (a lightly damped mode, a
repeated pole whose matrix is a Jordan block, a fast and a slow mode together, a 400 Hz rate loop), at lengths that
are and are not whole blocks; and the step response of a PX4 rate loop against its own brute-force simulation."""

from __future__ import annotations

import numpy as np
import pytest

from tuner.analysis.response import _run, step_response
from tuner.controllers import get_structure
from tuner.loop import build_loop
from tuner.plant import plant_from_expr


def _stepped(A: np.ndarray, b: np.ndarray, K: int) -> np.ndarray:
    """z_0 = 0, z_{k+1} = A z_k + b, one state at a time (plain sums)."""
    n = A.shape[0]
    Z = np.zeros((K, n))
    z = [0.0] * n
    for k in range(K):
        Z[k] = z
        z = [sum(A[i, j] * z[j] for j in range(n)) + b[i] for i in range(n)]
    return Z


def _rotation(r: float, th: float) -> np.ndarray:
    return r * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])


def _similar(D: np.ndarray, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    T = rng.normal(size=D.shape) + 3 * np.eye(D.shape[0])
    return T @ D @ np.linalg.inv(T)


MATRICES = {
    "lightly damped": _similar(np.block([[_rotation(0.999, 0.05), np.zeros((2, 1))],
                                         [np.zeros((1, 2)), np.array([[0.5]])]]), 1),
    "jordan": _similar(np.array([[0.97, 1.0, 0.0], [0.0, 0.97, 1.0], [0.0, 0.0, 0.97]]), 2),
    "fast and slow": _similar(np.diag([0.9999, 0.01, -0.6, 0.3]), 3),
    "one state": np.array([[0.9]]),
}


@pytest.mark.parametrize("name", list(MATRICES))
@pytest.mark.parametrize("K", [1, 2, 3, 17, 64, 65, 1000, 1237])
def test_blocks_match_the_stepped_recursion(name, K):
    A = MATRICES[name]
    b = np.linspace(1.0, -0.5, A.shape[0])
    ref = _stepped(A, b, K)
    got = _run(A, b, K)
    assert got.shape == ref.shape
    scale = max(1.0, float(np.max(np.abs(ref))))
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-11 * scale)
    assert np.array_equal(got[:2], ref[:2])  # z_0 = 0, z_1 = b exactly


def test_px4_rate_step_response_matches_a_brute_force_simulation():
    plant = plant_from_expr("200/((s+2)*(0.03*s+1))")
    st = get_structure("px4_rate")
    gains = {"P": 0.29, "I": 1.17, "D": 0.0055, "FF": 0.0, "K": 1.0, "dgyro_hz": 20.0, "int_lim": 0.3, "tq_hz": 0.0,
             "dgyro_order": 1.0, "raw_hz": 0.0}
    loop = build_loop(plant, st.tf(gains, 0.0025))
    cl = loop.closed_loop()
    for load in (False, True):
        r = step_response(loop, horizon_s=4.0, load=load)
        K = r.t_samples.size
        inp = 1 if load else 0
        Z = _stepped(cl.A, cl.B[:, inp], K)
        ys = Z @ cl.Cy + cl.Dy[inp]
        np.testing.assert_allclose(r.y_samples, ys, rtol=0, atol=1e-12 * max(1.0, float(np.max(np.abs(ys)))))
        assert K > 1500  # many blocks
