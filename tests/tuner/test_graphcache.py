"""The NLPs' stored graphs (tuner.optimize.nlp.graphcache): a later process makes each shape's solver of the graph
an earlier one built, and it answers bitwise as the built one (every tune's gains and figures, every solve's
outputs); a corrupt entry is deleted and built again, never used; a cache root that is not private is not used."""

from __future__ import annotations

import os
import sys
from collections import OrderedDict

import numpy as np
import pytest

from tuner import tune
from tuner.optimize import batch
from tuner.optimize.nlp import graphcache, transcribe
from tuner.plant import make_plant

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX modes")


@pytest.fixture
def cache(tmp_path, monkeypatch):
    root = tmp_path / "cache"
    monkeypatch.setenv("TUNER_CACHE_DIR", str(root))
    monkeypatch.setenv("TUNER_NLP_GRAPHS", "on")
    monkeypatch.setenv("TUNER_NLP_COMPILE", "off")
    monkeypatch.setenv("TUNER_KERNELS", "off")  # (the NLP alone: the batch on one path throughout)
    monkeypatch.setitem(batch._KERNELS, "module", None)
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    return root


@pytest.fixture
def builds(monkeypatch):
    """The shapes built (not loaded) from now on."""
    built = []
    real = transcribe._build
    monkeypatch.setattr(transcribe, "_build", lambda key, st, space: built.append(key) or real(key, st, space))
    return built


def _tune(seed=3):
    r = tune(make_plant([1.0], [1.0, 2.0, 1.0]), structure="pid", dt=0.1, seed=seed, diagnose=False)
    return r.gains, r.metrics.settling_time_s, r.metrics.overshoot_pct


def _shape_of(key):
    from tuner.controllers import get_structure
    from tuner.optimize.space import make_space
    from tuner.problem import TuningProblem

    plant = make_plant([1.0], [1.0, 2.0, 1.0])
    problem = TuningProblem.build(plant, structure=get_structure("pid"), dt=0.1)
    return problem.structure, make_space(problem.structure, plant, 0.1, scale=problem.scale)


@pytest.mark.slow  # (over 2 s: the whole suite runs it)
def test_a_stored_graph_answers_bitwise_as_the_built_one(cache, builds, monkeypatch):
    with monkeypatch.context() as m:  # the reference: nothing stored, nothing loaded
        m.setenv("TUNER_NLP_GRAPHS", "off")
        ref = [_tune(seed) for seed in (3, 4)]
    assert not (cache / "nlp-graph").exists()
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    builds.clear()
    first = [_tune(seed) for seed in (3, 4)]  # builds, and stores each shape
    keys = list(dict.fromkeys(builds))
    assert keys and len(list((cache / "nlp-graph").glob("*.npz"))) == len(keys)
    assert not list((cache / "nlp-graph").glob("*.tmp"))
    # a fresh process's view: nothing in memory, every shape from the disk
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    builds.clear()
    second = [_tune(seed) for seed in (3, 4)]
    assert builds == []  # loaded, none built
    assert first == ref and second == ref  # bitwise
    # one solve (from a start away from the optimum), both ways, on the same inputs: every output bitwise
    key = keys[-1]
    st, space = _shape_of(key)
    built, loaded = transcribe._build(key, st, space), transcribe._load_graph(key, space)
    assert loaded is not None and loaded.nlp is not None
    rng = np.random.default_rng(0)
    for _ in range(3):
        x0 = rng.standard_normal(built.variables.size) * 0.3
        p = np.abs(rng.standard_normal(built.params.size)) + 0.5
        args = {"x0": x0, "p": p, "lbg": built.lbg, "ubg": built.ubg}
        rb, rl = built.solver(**args), loaded.solver(**args)
        for k in ("x", "f", "g", "lam_g", "lam_x"):
            assert np.array_equal(np.asarray(rb[k]), np.asarray(rl[k]), equal_nan=True), k
        assert built.solver.stats()["iter_count"] == loaded.solver.stats()["iter_count"]
        assert np.array_equal(np.asarray(built.step(x0, p)), np.asarray(loaded.step(x0, p)), equal_nan=True)
    assert np.array_equal(built.lbg, loaded.lbg) and np.array_equal(built.ubg, loaded.ubg)


@pytest.mark.slow  # (over 2 s: the whole suite runs it)
def test_a_corrupt_entry_is_deleted_and_rebuilt_not_used(cache, builds, monkeypatch):
    _tune()
    key = builds[0]
    st, space = _shape_of(key)
    path = graphcache.entry_path(key, space)
    good = path.read_bytes()
    assert graphcache.load(key, space) is not None
    for damage in ("flip", "truncate", "foreign"):
        blob = bytearray(good)
        if damage == "flip":  # a byte of the serialized graph changed: the checksum no longer matches
            blob[len(blob) // 2] ^= 0xFF
        elif damage == "truncate":
            blob = blob[: len(blob) // 3]
        else:  # a consistent checksum over something that is not this shape's NLP: the signature check
            import hashlib
            import io

            import casadi as cs

            x = cs.SX.sym("x")
            buf = io.BytesIO()
            np.savez(buf, fg=np.frombuffer(cs.Function("f", [x], [x]).serialize().encode(), np.uint8),
                     step=np.frombuffer(cs.Function("s", [x], [x]).serialize().encode(), np.uint8),
                     lbg=np.zeros(1), ubg=np.zeros(1), n_v=np.int64(1))
            blob = bytearray(hashlib.sha256(buf.getvalue()).hexdigest().encode() + b"\n" + buf.getvalue())
        path.write_bytes(bytes(blob))
        assert graphcache.load(key, space) is None, damage
        assert not path.exists(), damage  # deleted: the next use builds it again
        # the tune's view: built (not loaded), stored again whole
        path.write_bytes(bytes(blob))
        monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
        builds.clear()
        transcribe.get_problem(key, st, space)
        assert builds == [key], damage
        assert graphcache.load(key, space) is not None


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_a_root_that_is_not_private_is_not_used(cache, builds, monkeypatch):
    _tune()
    key = builds[0]
    st, space = _shape_of(key)
    path = graphcache.entry_path(key, space)
    assert path.exists() and graphcache.load(key, space) is not None
    os.chmod(cache, 0o777)  # writable by others: what is in it may be anyone's
    try:
        assert not graphcache.enabled()
        assert graphcache.load(key, space) is None
        monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
        builds.clear()
        transcribe.get_problem(key, st, space)
        assert builds == [key]  # built, the stored graph not read (nor touched)
        assert path.exists()
        path.unlink()
        prob = transcribe._CACHE[key][0]
        assert not graphcache.save(key, space, prob.nlp, prob.step, prob.lbg, prob.ubg, prob.n_v)
        assert not path.exists()  # (nothing written there either)
    finally:
        os.chmod(cache, 0o700)
    assert graphcache.enabled() and graphcache.save(key, space, prob.nlp, prob.step, prob.lbg, prob.ubg, prob.n_v)
    assert graphcache.load(key, space) is not None  # (private again: used)


def test_the_entries_are_bounded_least_recently_used_first(cache, monkeypatch):
    root = cache / "nlp-graph"
    root.mkdir(parents=True)
    for i, name in enumerate(("a", "b", "c")):
        f = root / f"{name}.npz"
        f.write_bytes(b"0" * 2**20)
        os.utime(f, (1000 + i, 1000 + i))
    os.utime(root / "a.npz", (5000, 5000))  # a used last
    monkeypatch.setenv("TUNER_NLP_GRAPH_MB", "2.5")
    graphcache._trim(root)
    assert sorted(p.name for p in root.glob("*.npz")) == ["a.npz", "c.npz"]


@pytest.mark.slow  # (over 2 s: the whole suite runs it)
def test_only_an_entry_this_user_wrote_is_read_and_a_folder_that_cannot_be_written_is_no_crash(cache, builds,
                                                                                                 monkeypatch):
    """A deserialized CasADi Function can load a shared library, so the entry itself is checked on what is opened
    (review of issue 41): a symlink in its place, or a file others may write, is not read (the shape is built); an
    entry that is corrupt in a folder where it cannot be deleted (a read-only image) is not used, and the tune goes
    on."""
    reference = _tune()
    files = sorted((cache / "nlp-graph").glob("*.npz"))
    assert len(files) >= 2  # (this tune's shapes: one made a symlink, another writable by others)
    # a symlink in an entry's place (to a good entry's bytes elsewhere): not followed
    elsewhere = cache.parent / "elsewhere.npz"
    elsewhere.write_bytes(files[0].read_bytes())
    files[0].unlink()
    files[0].symlink_to(elsewhere)
    # another entry made writable by others
    os.chmod(files[-1], 0o666)
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    builds.clear()
    assert _tune() == reference
    assert len(builds) == 2  # those two shapes built, neither read; every other entry read
    assert files[0].is_symlink() and elsewhere.exists()  # (and nothing done to what is not ours)
    # a corrupt entry that cannot be deleted: not used, no error
    os.chmod(files[-1], 0o600)
    good = [f for f in files if not f.is_symlink()]
    good[-1].write_bytes(good[-1].read_bytes()[:-50])
    real_unlink = type(good[-1]).unlink

    refused = []

    def refuse(self, missing_ok=False):
        if self.parent.name == "nlp-graph":
            refused.append(self)
            raise PermissionError(13, "Read-only file system", str(self))
        return real_unlink(self, missing_ok=missing_ok)

    monkeypatch.setattr(type(good[-1]), "unlink", refuse)
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    builds.clear()
    assert _tune() == reference
    assert good[-1] in refused and builds  # (its deletion was tried and refused; its shape built instead)


@pytest.mark.slow  # (over 2 s: the whole suite runs it)
def test_a_graph_that_cannot_be_stored_or_made_a_solver_of_is_built_and_the_tune_goes_on(cache, builds, monkeypatch):
    """(Final read of issue 41.) The graph cache is on by default: a serialization that fails (a graph CasADi cannot
    serialize, no memory) or a stored graph CasADi will not make a solver of must never fail the tune."""
    reference = _tune()
    files = sorted((cache / "nlp-graph").glob("*.npz"))
    for f in files:
        f.unlink()
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())

    class Unserializable:
        def __init__(self, fn):
            self.fn = fn

        def serialize(self):
            raise RuntimeError("not serializable")

    real_save = graphcache.save
    monkeypatch.setattr(graphcache, "save", lambda key, space, fg, *a: real_save(key, space, Unserializable(fg), *a))
    assert _tune() == reference and not any((cache / "nlp-graph").glob("*.npz"))
    monkeypatch.setattr(graphcache, "save", real_save)
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    assert _tune() == reference and any((cache / "nlp-graph").glob("*.npz"))  # stored again
    real_solver, real_load, loading = transcribe._solver, transcribe._load_graph, []

    def refuse(key, nlp):
        if loading:  # (a stored graph's solver: refused; a build's: made)
            raise RuntimeError("no solver of this graph")
        return real_solver(key, nlp)

    def load(key, space):
        loading.append(1)
        try:
            return real_load(key, space)
        finally:
            loading.pop()

    monkeypatch.setattr(transcribe, "_solver", refuse)
    monkeypatch.setattr(transcribe, "_load_graph", load)
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    builds.clear()
    assert _tune() == reference and builds  # built instead


def test_an_entry_that_is_a_fifo_or_larger_than_the_cache_is_not_read(tmp_path, monkeypatch):
    """The entry reader neither blocks on a FIFO placed at an entry's path (the open is non-blocking, the file-type
    check refuses it) nor reads an entry larger than the whole cache may hold (a sparse 64 MiB file under a 1 MiB
    cache): None, promptly, for both; a private regular entry within the limit is read whole."""
    import threading

    from tuner.optimize.nlp import graphcache

    folder = tmp_path / "nlp-graph"
    folder.mkdir(mode=0o700)
    fifo = folder / "fifo.npz"
    os.mkfifo(fifo, 0o600)
    got = []
    t = threading.Thread(target=lambda: got.append(graphcache._read_own(fifo)), daemon=True)
    t.start()
    t.join(10)
    assert not t.is_alive() and got == [None]
    monkeypatch.setenv("TUNER_NLP_GRAPH_MB", "1")
    big = folder / "big.npz"
    with open(big, "wb") as f:
        f.truncate(64 * 2 ** 20)
    os.chmod(big, 0o600)
    assert graphcache._read_own(big) is None
    small = folder / "small.npz"
    small.write_bytes(b"x" * 1000)
    os.chmod(small, 0o600)
    assert graphcache._read_own(small) == b"x" * 1000
