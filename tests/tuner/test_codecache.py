"""The NLPs' compiled code on disk (tuner.optimize.nlp.codecache): a shape's first use is interpreted and asks for
its code in the background; the compiled problem then answers bitwise as the interpreted one did (every tune's
gains and verified figures, every solve); a corrupt entry is deleted, not used."""

from __future__ import annotations

import time
from collections import OrderedDict

import numpy as np
import pytest

from tuner import tune
from tuner.optimize import batch
from tuner.optimize.nlp import codecache, transcribe
from tuner.plant import make_plant

pytestmark = pytest.mark.slow  # (gcc: tens of seconds)


@pytest.fixture
def cache(tmp_path, monkeypatch):
    if not codecache.enabled() and __import__("shutil").which("gcc") is None:
        pytest.skip("no gcc")
    monkeypatch.setenv("TUNER_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("TUNER_NLP_COMPILE", "auto")
    monkeypatch.setenv("TUNER_KERNELS", "off")  # (the NLP alone: the batch on one path throughout)
    monkeypatch.setitem(batch._KERNELS, "module", None)
    monkeypatch.setattr(codecache, "_SCHEDULED", set())
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    return tmp_path


def _tune():
    r = tune(make_plant([1.0], [1.0, 1.0]), structure="pi", dt=0.2, seed=3, time_budget_s=10, diagnose=False)
    return r.gains, r.metrics.settling_time_s


def test_compiled_nlp_answers_bitwise_as_the_interpreted_one(cache, monkeypatch):
    asked = []
    real_schedule = codecache.schedule
    monkeypatch.setattr(codecache, "schedule", lambda *a: asked.append(a) or real_schedule(*a))
    gains0, ts0 = _tune()
    assert asked and all(not p.compiled for p, _ in transcribe._CACHE.values())
    keys = [a[0] for a in asked]
    # the background processes compile the shapes (one at a time); wait for every entry
    deadline = time.time() + 900
    while not all((codecache.entry_dir(*a) / "sums.json").exists() for a in asked):
        assert time.time() < deadline, "the background compile did not finish in 15 minutes"
        time.sleep(1.0)
    assert not list((cache / "nlp").glob("*.tmp"))  # (moved into place whole)
    # a fresh process's view: nothing built in memory, every shape from the disk
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    gains1, ts1 = _tune()
    # loaded, not built (a shape the first tune did not use, on a busy machine whose clock moved its search, is not
    # in the cache: built)
    used = [k for k in keys if k in transcribe._CACHE]
    assert used and all(transcribe._CACHE[k][0].compiled for k in used)
    assert gains1 == gains0 and ts1 == ts0  # bitwise
    # one solve, both ways, on the same inputs: every output bitwise
    a = asked[0]
    interp, comp = transcribe._build(*a), codecache.load(*a, transcribe._assembler(a[0]))
    rng = np.random.default_rng(0)
    x0 = rng.standard_normal(interp.variables.size) * 0.1
    p = np.abs(rng.standard_normal(interp.params.size)) + 0.5
    args = {"x0": x0, "p": p, "lbg": interp.lbg, "ubg": interp.ubg}
    ri, rc = interp.solver(**args), comp.solver(**args)
    for k in ("x", "f", "g", "lam_g"):
        assert np.array_equal(np.asarray(ri[k]), np.asarray(rc[k]), equal_nan=True), k
    assert np.array_equal(np.asarray(interp.step(x0, p)), np.asarray(comp.step(x0, p)), equal_nan=True)


def test_a_corrupt_entry_is_rebuilt_not_trusted(cache, monkeypatch):
    # its two compiles at -O0 (4.6 s each against -O1's 23 s): what is checked here, the checksums, the deletion
    # and the rebuild, is the same at any optimisation level (the flags are part of the entry's name, so the entry
    # is the -O0 one throughout); the product's -O1 code is compiled and checked bitwise by the test above
    monkeypatch.setattr(codecache, "CFLAGS", ("-O0", *codecache.CFLAGS[1:]))
    monkeypatch.setattr(codecache, "schedule", lambda *a: False)
    _tune()
    key, (prob, _) = next(iter(transcribe._CACHE.items()))
    st, space = _shape_of(key)
    codecache.build_entry(key, st, space, transcribe._build)
    d = codecache.entry_dir(key, st, space)
    assert codecache.load(key, st, space, transcribe._assembler(key)) is not None
    blob = bytearray((d / "nlp.so").read_bytes())
    blob[len(blob) // 2] ^= 0xFF
    (d / "nlp.so").write_bytes(bytes(blob))
    assert codecache.load(key, st, space, transcribe._assembler(key)) is None
    assert not d.exists()  # deleted: the next use builds it again
    codecache.build_entry(key, st, space, transcribe._build)
    assert codecache.load(key, st, space, transcribe._assembler(key)) is not None


def _shape_of(key):
    from tuner.controllers import get_structure
    from tuner.optimize.space import make_space
    from tuner.problem import TuningProblem

    plant = make_plant([1.0], [1.0, 1.0])
    problem = TuningProblem.build(plant, structure=get_structure("pi"), dt=0.2)
    return problem.structure, make_space(problem.structure, plant, 0.2, scale=problem.scale)


def test_a_failed_compile_is_marked_and_not_asked_for_again(cache, monkeypatch):
    """A compile that fails leaves a mark: no later run starts it again (one that runs out of time does not: a busy
    machine's, asked for again later); and with
    ``TUNER_NLP_COMPILE=load`` no run starts a compile at all (unset, the default, is ``auto``)."""
    monkeypatch.setattr(codecache, "schedule", lambda *a: False)
    _tune()
    key = next(iter(transcribe._CACHE))
    st, space = _shape_of(key)
    monkeypatch.undo()  # the real schedule again, and the fixture's settings
    monkeypatch.setenv("TUNER_CACHE_DIR", str(cache))
    monkeypatch.setattr(codecache, "_SCHEDULED", set())
    monkeypatch.setenv("CC", "false")  # a compiler that fails at once
    codecache._MEMO.clear()
    with pytest.raises(__import__("subprocess").CalledProcessError):
        codecache.build_entry(key, st, space, transcribe._build)
    d = codecache.entry_dir(key, st, space)
    assert d.with_name(d.name + ".failed").exists() and not d.exists()
    monkeypatch.setenv("TUNER_NLP_COMPILE", "auto")
    assert codecache.schedule(key, st, space) is False
    monkeypatch.setenv("TUNER_NLP_COMPILE", "load")
    d.with_name(d.name + ".failed").unlink()
    assert codecache.schedule(key, st, space) is False  # load compiles nothing
