"""The batch's compiled kernels (tuner.optimize.kernels) against its numpy path, the reference: every figure of
many random candidates on sampled-data loops (the thesis's roll loop with its lifted rows, a third-order lag, the
PX4 rate law with a fractional delay and its gain-variation members, the load stage's recovery), the signed phase
margin as the numpy path computes it (180 + the unwrapped phase within +-180, else the distance) among them. And
the kernels stay out of ``import tuner`` and ``tuner analyze``."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from tuner import Spec
from tuner.controllers import get_structure
from tuner.optimize import batch as batch_mod
from tuner.optimize.batch import BatchEvaluator
from tuner.optimize.space import make_space
from tuner.plant import make_plant, plant_from_expr
from tuner.problem import TuningProblem

pytest.importorskip("numba")

KEYS = ("pm", "gm", "gml", "wc", "wp", "settling_time_s", "overshoot_pct", "steady_state_error", "control_peak",
        "itae", "iae", "load_recovery_s", "horizon_s", "stable", "outside")


@pytest.fixture(scope="module")
def kern():
    # the kernels loaded here stay this module's: the process's choice is put back after it (a later test in the same
    # worker that compares gains with a fresh interpreter's, which runs numpy, would otherwise see rounding-level
    # differences)
    saved = dict(batch_mod._KERNELS)
    yield batch_mod.kernels(compile_now=True)
    batch_mod._KERNELS.clear()
    batch_mod._KERNELS.update(saved)


CASES = {
    "roll pid_z": (lambda: plant_from_expr("0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)"), "pid_z", 0.04, None),
    "lag3 pid": (lambda: plant_from_expr("1/(s+1)^3"), "pid", 0.1, None),
    "px4_rate 6 ms": (lambda: make_plant([200.0], [0.03, 1.06, 2.0], delay=0.006), "px4_rate", 0.0025, None),
    "nmp pi iae": (lambda: make_plant([-0.5, 1.0], [1.0, 3.0, 2.0], delay=0.05), "pi", 0.05, "iae"),
    # a lightly damped mode whose peak crosses |L| = 1 after a delay's lag of more than a turn: the distance stands
    "resonance delay pi": (lambda: make_plant([0.5 * 226.0**2], [1.0, 4.52, 226.0**2], delay=0.0765), "pi", 0.002,
                           None),
}


def _pair(name: str, load_recovery: bool):
    mk, structure, dt, obj = CASES[name]
    plant = mk()
    spec = Spec() if obj is None else Spec(objective=obj)
    problem = TuningProblem.build(plant, structure=get_structure(structure), dt=dt, spec=spec)
    space = make_space(problem.structure, plant, dt, scale=problem.scale)
    a, b = BatchEvaluator(problem, space), BatchEvaluator(problem, space)
    a.kernels, b.kernels = None, batch_mod.kernels(compile_now=True)
    a.load_recovery = b.load_recovery = load_recovery
    a.all_figures = b.all_figures = True  # (the ITAE too, whatever the objective)
    return a, b, space


def _same(x: np.ndarray, y: np.ndarray, key: str) -> None:
    x, y = np.asarray(x), np.asarray(y)
    assert x.shape == y.shape, key
    if x.dtype == bool:
        assert np.array_equal(x, y), key
        return
    both = np.isfinite(x) & np.isfinite(y)
    assert np.array_equal(np.isnan(x), np.isnan(y)), (key, np.flatnonzero(np.isnan(x) != np.isnan(y)))
    assert np.array_equal(np.isposinf(x), np.isposinf(y)), (key, x[np.isposinf(x) != np.isposinf(y)],
                                                              y[np.isposinf(x) != np.isposinf(y)])
    assert np.array_equal(np.isneginf(x), np.isneginf(y)), key
    # s, %, dB, deg: the kernel's sequential recursion against the numpy path's doubling
    np.testing.assert_allclose(y[both], x[both], rtol=1e-7, atol=1e-6, err_msg=key)


@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_kernels_match_the_numpy_path_on_random_candidates(kern, name):
    a, b, space = _pair(name, load_recovery=True)
    rng = np.random.default_rng(41)
    V = space.lo + rng.random((400, space.lo.size)) * (space.hi - space.lo)
    X = np.array([space.params(v) for v in V])
    ra, rb = a.evaluate(X), b.evaluate(X)
    assert len(ra.per_plant) == len(rb.per_plant) >= 1
    for ma, mb in zip(ra.per_plant, rb.per_plant):
        for k in KEYS:
            if k in ma:
                _same(ma[k], mb[k], k)
    _same(ra.score, rb.score, "score")
    _same(ra.feasible, rb.feasible, "feasible")
    # the sample is not degenerate: stable and unstable rows, finite margins, signed margins among them
    m = ra.per_plant[0]
    assert m["stable"].sum() >= 20 and (~m["stable"]).sum() >= 1
    assert np.isfinite(m["pm"]).sum() >= 20
    assert np.all(np.abs(m["pm"][np.isfinite(m["pm"])]) <= 180.0)
    if name == "px4_rate 6 ms":  # the gain-variation members and the load recovery are in the comparison
        assert len(ra.per_plant) == 3
        assert np.isfinite(m["load_recovery_s"]).sum() >= 10


def test_kernels_match_at_the_incumbent_horizon(kern):
    """The engine's incumbent bound on the horizon (rows cut at three times the incumbent's settling time)."""
    a, b, space = _pair("roll pid_z", load_recovery=False)
    rng = np.random.default_rng(7)
    X = np.array([space.params(space.lo + rng.random(space.lo.size) * (space.hi - space.lo)) for _ in range(300)])
    ra, rb = a.evaluate(X, incumbent_s=0.3), b.evaluate(X, incumbent_s=0.3)
    for k in ("settling_time_s", "overshoot_pct", "control_peak", "itae", "horizon_s"):
        _same(ra.per_plant[0][k], rb.per_plant[0][k], k)
    _same(ra.score, rb.score, "score")


def test_kernels_are_not_imported_by_tuner_or_analyze(tmp_path):
    code = ("import sys, tuner, tuner.cli\n"
            "from tuner.cli import main\n"
            "try:\n main(['analyze', '--plant', '1/(s+1)', '--dt', '0.1', '--controller', '2'])\n"
            "except SystemExit:\n pass\n"
            "print('numba' in sys.modules, 'tuner.optimize.kernels' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**__import__("os").environ, "TUNER_CACHE_DIR": str(tmp_path)})
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "False False"


def test_kernels_off_is_the_numpy_path(monkeypatch):
    monkeypatch.setenv("TUNER_KERNELS", "off")
    monkeypatch.setitem(batch_mod._KERNELS, "module", None)
    assert batch_mod.kernels() is None


def test_auto_uses_the_kernels_only_where_a_process_preloaded_them(monkeypatch, tmp_path):
    """``auto``: a batch uses the kernels only where its process preloaded them (a service solver, a study worker);
    preloading without the machine's ready mark asks for one background compile and stays on numpy."""
    monkeypatch.setenv("TUNER_KERNELS", "auto")
    monkeypatch.setenv("TUNER_CACHE_DIR", str(tmp_path))
    monkeypatch.setitem(batch_mod._KERNELS, "module", None)
    asked = []
    monkeypatch.setattr(batch_mod, "_spawn_kernel_build", lambda: asked.append(1))
    assert batch_mod.kernels() is None and not asked
    assert batch_mod.preload_kernels() is None and asked == [1]
    assert batch_mod.kernels() is None
    from tuner.optimize.cachedir import kernels_ready_mark

    mark = kernels_ready_mark()
    assert mark.parent.parent == tmp_path
    mark.parent.mkdir(parents=True)
    mark.write_text("x")
    assert batch_mod.preload_kernels() is not None and asked == [1]
    assert batch_mod.kernels() is not None


@pytest.mark.slow  # (over 2 s: the whole suite runs it)
def test_the_kernels_machine_code_is_never_loaded_from_a_cache_others_can_write(tmp_path):
    """numba's cache holds pickled indexes and machine code: like the NLP code cache, it is used only under a root
    trusted_root accepts. A root writable by others (mode 0o777 here): the kernels compile into a private folder of
    the process's own, write no ready mark there, and the service's preload (auto) stays on numpy without asking for
    a background compile into it."""
    import os
    import subprocess
    import sys

    root = tmp_path / "shared"
    root.mkdir()
    os.chmod(root, 0o777)
    code = ("import os\nfrom tuner.optimize import batch\nassert batch.preload_kernels() is None\n"
            "assert not batch._KERNELS['spawned']\n"
            "from tuner.optimize import kernels\nkernels.warm()\n"
            "print(os.environ['NUMBA_CACHE_DIR'])\n")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         env={**env, "TUNER_CACHE_DIR": str(root), "TUNER_KERNELS": "auto"})
    assert out.returncode == 0, out.stderr
    used = out.stdout.strip().splitlines()[-1]
    assert not used.startswith(str(root)) and os.path.basename(used).startswith("tuner-numba-")
    assert not any(root.rglob("*"))  # (nothing written into it: no numba index, no ready mark, no build lock)


def test_a_numba_cache_dir_set_beforehand_is_held_to_the_same_rule(tmp_path):
    """(Review of issue 41.) ``NUMBA_CACHE_DIR`` set to a folder others can write is not taken (numba would load its
    pickled indexes and machine code from it): the kernels go to the trusted root's folder; a private one is taken."""
    import os
    import subprocess
    import sys

    shared, mine, root = tmp_path / "shared", tmp_path / "mine", tmp_path / "root"
    shared.mkdir()
    os.chmod(shared, 0o777)
    code = "import os\nfrom tuner.optimize import kernels\nprint(os.environ['NUMBA_CACHE_DIR'])\n"
    for preset, expect in ((shared, root / "numba"), (mine, mine)):
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                             env={**os.environ, "TUNER_CACHE_DIR": str(root), "NUMBA_CACHE_DIR": str(preset)})
        assert out.returncode == 0, out.stderr
        assert out.stdout.strip().splitlines()[-1] == str(expect)
    assert not any(shared.iterdir())
