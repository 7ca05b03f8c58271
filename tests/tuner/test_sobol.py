"""The restarts' scrambled Sobol' points (tuner.optimize.sobol) are SciPy's (scipy.stats.qmc.Sobol), bit for bit,
over dimensions, sizes and seeds (the reference: SciPy itself, imported here only); and a tune does not import
scipy.stats."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.stats import qmc

from tuner.optimize.sobol import Sobol


@pytest.mark.parametrize("d", [1, 2, 3, 4, 5, 6, 8, 13, 40])
def test_the_points_are_scipys(d):
    for m in (0, 1, 2, 4, 6, 7):
        for seed in ([0, 1, 20], [3, 2, 20], [2**40 + 7, 4, 20], 11):
            want = qmc.Sobol(d, scramble=True, seed=np.random.default_rng(seed)).random_base2(m)
            got = Sobol(d, seed=np.random.default_rng(seed)).random_base2(m)
            assert got.shape == want.shape == (2**m, d)
            assert np.array_equal(got, want), (d, m, seed)


def test_the_callers_generator_is_left_as_scipy_leaves_it():
    a, b = np.random.default_rng(5), np.random.default_rng(5)
    qmc.Sobol(3, scramble=True, seed=a).random_base2(3)
    Sobol(3, seed=b).random_base2(3)
    assert np.array_equal(a.integers(1 << 30, size=8), b.integers(1 << 30, size=8))
    s = Sobol(2, seed=np.random.default_rng(0))
    s.random_base2(2)
    with pytest.raises(ValueError):
        s.random_base2(2)


@pytest.mark.slow  # (over 2 s: the whole suite runs it)
def test_a_tune_does_not_import_scipy_stats():
    code = ("import sys; from tuner import tune; from tuner.plant import make_plant; "
            "tune(make_plant([1.0], [1.0, 2.0, 1.0]), structure='pi', dt=0.1, diagnose=False); "
            "print('scipy.stats' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "False"


def test_without_scipys_data_file_the_points_are_scipys_own(monkeypatch):
    """Where the direction numbers cannot be read here (SciPy's data file moved), ``scrambled`` is SciPy's own class:
    the same points (at the cost of importing scipy.stats)."""
    from tuner.optimize import sobol

    def missing(d):
        raise OSError("no such file")

    monkeypatch.setattr(sobol, "_directions", missing)
    got = sobol.scrambled(4, seed=np.random.default_rng(7))
    assert isinstance(got, qmc.Sobol)
    want = qmc.Sobol(4, scramble=True, seed=np.random.default_rng(7)).random_base2(5)
    assert np.array_equal(got.random_base2(5), want)
