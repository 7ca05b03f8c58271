"""The NLP code cache's safety (tuner.optimize.nlp.codecache, tuner.optimize.cachedir), quick, without a compile: a
timed-out compile leaves no process of its group running; a lock whose builder is gone is stale at once; a cache root
that is not private is not used (the cache is off, silently); the background work is bounded before it starts (a
shape with too much C is not compiled, at most MAX_PENDING builds wait) and ``tuner tune`` says what it started."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tuner.optimize import cachedir
from tuner.optimize.nlp import codecache

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX process groups and modes")


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def _gone(pid: int) -> bool:
    """The process ``pid`` has exited (gone, or a zombie its new parent has not reaped yet)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        return False
    return state in ("Z", "X")


def test_a_lock_whose_builder_is_gone_is_stale_and_a_live_ones_is_not(tmp_path):
    lock = tmp_path / "x.lock"
    lock.write_text(str(_dead_pid()))
    assert codecache._lock_stale(lock)
    lock.write_text(str(os.getpid()))
    assert not codecache._lock_stale(lock)
    lock.write_text("")  # (a lock without a pid: its age decides)
    assert not codecache._lock_stale(lock)
    old = time.time() - codecache.STALE_LOCK_S - 10
    os.utime(lock, (old, old))
    assert codecache._lock_stale(lock)


def test_schedule_replaces_a_dead_builders_lock(tmp_path, monkeypatch):
    dead = _dead_pid()
    monkeypatch.setenv("TUNER_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("TUNER_NLP_COMPILE", "auto")
    monkeypatch.setattr(codecache, "enabled", lambda: True)
    monkeypatch.setattr(codecache, "_SCHEDULED", set())
    d = tmp_path / "nlp" / "shape"
    monkeypatch.setattr(codecache, "entry_dir", lambda *a: d)
    started = []

    class FakePopen:
        def __init__(self, cmd, **kw):
            started.append(cmd)
            self.pid = os.getpid()

    monkeypatch.setattr(codecache.subprocess, "Popen", FakePopen)
    lock = d.with_name("shape.lock")
    lock.parent.mkdir(parents=True)
    lock.write_text(str(os.getpid()))  # a live builder: left alone
    assert codecache.schedule("k", None, None) is False and not started
    monkeypatch.setattr(codecache, "_SCHEDULED", set())
    lock.write_text(str(dead))  # a killed builder: its lock is taken over
    assert codecache.schedule("k", None, None) is True and len(started) == 1
    assert lock.read_text() == str(os.getpid())  # the new builder's pid


def test_a_timed_out_compile_kills_its_whole_process_group(tmp_path):
    pidfile = tmp_path / "child.pid"
    # a "compiler" whose child (as gcc's cc1) outlives the driver if only the driver is killed
    cmd = ["sh", "-c", f"sleep 60 & echo $! > {pidfile}; wait"]
    with pytest.raises(subprocess.TimeoutExpired):
        codecache._compile(cmd, 1.0)
    child = int(pidfile.read_text())
    for _ in range(100):  # (the orphan is reaped by its new parent: give it a moment)
        if _gone(child):
            break
        time.sleep(0.05)
    assert _gone(child)


def test_a_failing_compile_raises(tmp_path):
    with pytest.raises(subprocess.CalledProcessError):
        codecache._compile(["false"], 10.0)


def test_the_cache_root_is_private_and_a_shared_one_is_not_used(tmp_path, monkeypatch):
    root = tmp_path / "cache"
    monkeypatch.setenv("TUNER_CACHE_DIR", str(root))
    monkeypatch.setenv("TUNER_NLP_COMPILE", "auto")
    assert cachedir.trusted_root() == root
    assert root.stat().st_mode & 0o777 == 0o700  # created private
    root.chmod(0o770)  # group-writable: another user could plant code or a pickle
    assert cachedir.trusted_root() is None
    assert codecache.enabled() is False
    assert codecache.load("k", None, None, lambda *a: pytest.fail("loaded from a shared root")) is None
    assert codecache.schedule("k", None, None) is False
    job = root / "nlp" / "x.job"
    job.parent.mkdir()
    job.write_bytes(b"not a pickle")  # never unpickled: run_job returns without reading it
    codecache.run_job(job, lambda *a: pytest.fail("built from a shared root"))
    root.chmod(0o700)
    assert cachedir.trusted_root() == root


class _FakePopen:
    started: list = []

    def __init__(self, cmd, **kw):
        _FakePopen.started.append(cmd)
        self.pid = os.getpid()


def _scheduling(tmp_path, monkeypatch):
    monkeypatch.setenv("TUNER_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(codecache, "enabled", lambda: True)
    monkeypatch.setattr(codecache, "_SCHEDULED", set())
    monkeypatch.setattr(codecache, "_STARTED", [])
    monkeypatch.setattr(_FakePopen, "started", [])
    monkeypatch.setattr(codecache.subprocess, "Popen", _FakePopen)
    monkeypatch.setattr(codecache, "entry_dir", lambda key, *a: tmp_path / "nlp" / str(key))


def test_unset_compiles_in_the_background_and_load_and_off_do_not(tmp_path, monkeypatch):
    _scheduling(tmp_path, monkeypatch)
    monkeypatch.delenv("TUNER_NLP_COMPILE", raising=False)
    assert codecache.mode() == "auto" and codecache.schedule("a", None, None) is True
    assert codecache.started() == 1 and len(_FakePopen.started) == 1
    assert codecache.schedule("a", None, None) is False  # (once per process)
    for value, mode in (("load", "load"), ("off", "off"), ("on", "auto"), ("0", "off")):
        monkeypatch.setenv("TUNER_NLP_COMPILE", value)
        assert codecache.mode() == mode
    monkeypatch.setenv("TUNER_NLP_COMPILE", "load")
    assert codecache.schedule("b", None, None) is False and codecache.started() == 1


def test_at_most_max_pending_builds_wait_on_the_machine(tmp_path, monkeypatch):
    dead = _dead_pid()  # (before Popen is replaced)
    _scheduling(tmp_path, monkeypatch)
    monkeypatch.setenv("TUNER_NLP_COMPILE", "auto")
    root = tmp_path / "nlp"
    root.mkdir()
    for i in range(codecache.MAX_PENDING):
        (root / f"other{i}.lock").write_text(str(os.getpid()))  # live builders (this process stands in)
    assert codecache.schedule("a", None, None) is False and not _FakePopen.started
    (root / "other0.lock").write_text(str(dead))  # one of them gone: room for one more
    monkeypatch.setattr(codecache, "_SCHEDULED", set())
    assert codecache.schedule("a", None, None) is True and len(_FakePopen.started) == 1


class _Gen:
    """A problem's solver or step whose generated C is ``n`` bytes."""

    def __init__(self, n):
        self.n = n

    def generate_dependencies(self, name):
        Path(name).write_text("x" * self.n)

    generate = generate_dependencies


def _problem(nlp_bytes, step_bytes):
    """A build (``build(key, st, space)``) whose problem's solver and step generate so many bytes of C."""
    class Prob:
        solver, step = _Gen(nlp_bytes), _Gen(step_bytes)
        lbg, ubg, n_v = [0.0], [1.0], 1

    return lambda *a: Prob()


def _compiler(path: Path, exit_code: int) -> str:
    """A stand-in for gcc: writes its ``-o`` file (and exits 0), or fails (``exit_code`` != 0)."""
    path.write_text("#!/bin/sh\n" + (f"exit {exit_code}\n" if exit_code else
                                     'while [ $# -gt 0 ]; do [ "$1" = -o ] && echo so > "$2"; shift; done\n'))
    path.chmod(0o755)
    return str(path)


def test_a_shape_with_more_c_than_the_bound_is_marked_not_compiled(tmp_path, monkeypatch):
    monkeypatch.setenv("TUNER_CACHE_DIR", str(tmp_path))
    d = tmp_path / "nlp" / "shape"
    monkeypatch.setattr(codecache, "entry_dir", lambda *a: d)
    marker = tmp_path / "compiler-ran"
    cc = tmp_path / "cc.sh"
    cc.write_text(f"#!/bin/sh\ntouch {marker}\nexit 1\n")
    cc.chmod(0o755)
    monkeypatch.setenv("CC", str(cc))
    monkeypatch.setattr(codecache, "MAX_SOURCE_BYTES", 1000)
    times = codecache.build_entry("k", None, None, _problem(900, 200))  # 1100 bytes of C in all: above the bound
    assert times["skipped_bytes"] == 1100
    assert not marker.exists() and not d.exists()
    assert json.loads(d.with_name("shape.failed").read_text()) == {"reason": "too_large", "bytes": 1100,
                                                                     "bound": 1000}
    assert not list(d.parent.glob("*.tmp"))


def test_tune_says_on_stderr_how_many_compiles_it_started(tmp_path, monkeypatch, capsys):
    from collections import OrderedDict

    from tuner.cli import main
    from tuner.optimize.nlp import transcribe

    _scheduling(tmp_path, monkeypatch)
    monkeypatch.setattr(codecache, "entry_dir", lambda key, st, space: tmp_path / "nlp" / str(abs(hash(key))))
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())  # (every shape built here)
    args = ["tune", "--plant", "1/(s+1)", "--structure", "pi", "--dt", "0.2", "--json"]
    monkeypatch.setenv("TUNER_NLP_COMPILE", "load")
    assert main(args) == 0
    out_load, err = capsys.readouterr()
    assert "compiling" not in err and not _FakePopen.started
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    monkeypatch.setenv("TUNER_NLP_COMPILE", "auto")
    assert main(args) == 0
    out_auto, err = capsys.readouterr()
    n = len(_FakePopen.started)
    assert n >= 1 and codecache.started() == n
    assert f"note: asked for the compiled NLP code of {n} new problem shape" in err
    import json

    a, b = json.loads(out_load), json.loads(out_auto)  # (stdout, the JSON: the same answer as without)
    assert a["gains"] == b["gains"] and a["objective"] == b["objective"]


def test_pending_counts_the_live_builds_of_the_cache(tmp_path, monkeypatch):
    dead = _dead_pid()
    monkeypatch.setenv("TUNER_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(codecache, "enabled", lambda: True)
    assert codecache.pending() == 0  # (no nlp folder yet)
    root = tmp_path / "nlp"
    root.mkdir()
    (root / "a.lock").write_text(str(os.getpid()))
    (root / "b.lock").write_text(str(dead))  # a killed build: not pending
    (root / "compile.flock").write_text("")
    assert codecache.pending() == 1
    monkeypatch.setattr(codecache, "enabled", lambda: False)
    assert codecache.pending() == 0


_POPEN = subprocess.Popen  # (the real one: _scheduling replaces it, for schedule's background process)


def _build(key, build) -> None:
    """build_entry of ``key`` as the background process runs it (its compiler a real process: a script)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(codecache.subprocess, "Popen", _POPEN)
        codecache.build_entry(key, None, None, build)


def _asked_again(key) -> bool:
    """schedule() starts a build of ``key`` (this process not having asked for it yet); the build's lock and job are
    removed after it (as its builder does when it ends: the next call is not refused as a build under way)."""
    codecache._SCHEDULED.discard(key)
    started = codecache.schedule(key, None, None)
    for f in ("lock", "job"):
        codecache.entry_dir(key).with_name(f"{key}.{f}").unlink(missing_ok=True)
    return started


def test_a_too_large_marker_holds_until_the_bound_is_raised_above_the_size(tmp_path, monkeypatch):
    _scheduling(tmp_path, monkeypatch)
    monkeypatch.setenv("TUNER_NLP_COMPILE", "auto")
    monkeypatch.setenv("CC", _compiler(tmp_path / "cc.sh", 1))
    monkeypatch.setattr(codecache, "MAX_SOURCE_BYTES", 1000)
    _build("shape", _problem(900, 200))  # 1100 bytes: marked
    assert not _asked_again("shape") and not _FakePopen.started
    monkeypatch.setattr(codecache, "MAX_SOURCE_BYTES", 1099)  # raised, but still below its size
    assert not _asked_again("shape")
    monkeypatch.setattr(codecache, "MAX_SOURCE_BYTES", 500)  # a lower bound: still marked
    assert not _asked_again("shape")
    # raised to its size (build_entry compiles a shape of as many bytes as the bound): asked for again
    monkeypatch.setattr(codecache, "MAX_SOURCE_BYTES", 1100)
    assert _asked_again("shape") and len(_FakePopen.started) == 1


def test_a_failed_compile_marker_holds_for_the_same_compiler_and_flags_only(tmp_path, monkeypatch):
    _scheduling(tmp_path, monkeypatch)
    monkeypatch.setenv("TUNER_NLP_COMPILE", "auto")
    cc = _compiler(tmp_path / "cc.sh", 1)
    monkeypatch.setenv("CC", cc)
    with pytest.raises(subprocess.CalledProcessError):
        _build("shape", _problem(100, 100))
    info = codecache.marker(tmp_path / "nlp" / "shape")
    assert info["reason"] == "compile_failed" and info["cflags"] == list(codecache.CFLAGS)
    assert [c["path"] for c in info["compilers"]] == [str(Path(cc).resolve())] and "CalledProcessError" in info["error"]
    assert not _asked_again("shape") and not _FakePopen.started
    # another compiler (CC, or a new default gcc), the same one upgraded (its file replaced) or other flags: again
    cc2 = _compiler(tmp_path / "cc2.sh", 1)
    monkeypatch.setenv("CC", cc2)
    assert _asked_again("shape")
    monkeypatch.setenv("CC", cc)
    assert not _asked_again("shape")
    # the other compiler fails too: the marker keeps both, so two environments sharing the cache (CC set in one, not
    # in the other) do not take turns retrying it
    monkeypatch.setenv("CC", cc2)
    with pytest.raises(subprocess.CalledProcessError):
        _build("shape", _problem(100, 100))
    assert [c["path"] for c in codecache.marker(tmp_path / "nlp" / "shape")["compilers"]] == \
        [str(Path(cc).resolve()), str(Path(cc2).resolve())]
    assert not _asked_again("shape")
    monkeypatch.setenv("CC", cc)
    assert not _asked_again("shape")
    st = os.stat(cc)
    os.utime(cc, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert _asked_again("shape")
    os.utime(cc, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert not _asked_again("shape")
    monkeypatch.setattr(codecache, "CFLAGS", ("-O0", *codecache.CFLAGS[1:]))  # (the entry's name kept: entry_dir)
    assert _asked_again("shape") and len(_FakePopen.started) == 3


def test_a_marker_of_the_first_format_holds_and_a_compiled_shape_drops_a_stale_one(tmp_path, monkeypatch):
    _scheduling(tmp_path, monkeypatch)
    monkeypatch.setenv("TUNER_NLP_COMPILE", "auto")
    root = tmp_path / "nlp"
    root.mkdir()
    monkeypatch.setattr(codecache, "MAX_SOURCE_BYTES", 10**12)
    # plain text (it does not say under which bound or compiler it was written), or unreadable as JSON: never
    # retried blindly
    for text in ("CalledProcessError: ...\n", "{", "[1]", "not compiled: lots of C\n"):
        (root / "old.failed").write_text(text)
        assert codecache.marker(root / "old") == {"reason": "failed", "detail": text.strip()}
        assert not _asked_again("old")
    assert not _FakePopen.started
    # the first format's too-large text says the size (to 0.1 MB): it holds while the bound is below the least size
    # that rounds to it, 59.95 MB, and not once the bound is raised to that
    (root / "old.failed").write_text("not compiled: 60.0 MB of C, above the 4 MB bound\n")
    info = codecache.marker(root / "old")
    assert info["reason"] == "too_large" and info["bytes"] == 59_950_000 and info["legacy"].startswith("not comp")
    monkeypatch.setattr(codecache, "MAX_SOURCE_BYTES", 4_000_000)
    assert not _asked_again("old")
    monkeypatch.setattr(codecache, "MAX_SOURCE_BYTES", 59_949_999)
    assert not _asked_again("old") and not _FakePopen.started
    monkeypatch.setattr(codecache, "MAX_SOURCE_BYTES", 59_950_000)
    assert _asked_again("old") and len(_FakePopen.started) == 1
    monkeypatch.setattr(codecache, "MAX_SOURCE_BYTES", 10**12)
    # a marker that no longer holds: the shape compiles, and its marker goes
    monkeypatch.setattr(codecache, "MAX_SOURCE_BYTES", 1000)
    codecache._mark(root / "shape", {"reason": "too_large", "bytes": 900, "bound": 500})
    monkeypatch.setenv("CC", _compiler(tmp_path / "cc.sh", 0))
    _build("shape", _problem(400, 400))
    assert (root / "shape" / "sums.json").exists() and not (root / "shape.failed").exists()
    assert not list(root.glob("*.tmp"))


def _cache_with_every_state(tmp_path, monkeypatch):
    """A cache folder of: one compiled entry, one live build and a dead one's lock, a too-large marker that holds
    and one that does not, a failed compile's marker and one of the first format."""
    dead = _dead_pid()
    monkeypatch.setenv("TUNER_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("TUNER_NLP_COMPILE", "auto")
    monkeypatch.setattr(codecache, "enabled", lambda: True)
    monkeypatch.setattr(codecache, "MAX_SOURCE_BYTES", 4_000_000)
    monkeypatch.setenv("CC", _compiler(tmp_path / "cc.sh", 1))
    root = tmp_path / "nlp"
    (root / "done").mkdir(parents=True)
    (root / "done" / "sums.json").write_text("{}")
    (root / "done" / "build.json").write_text(json.dumps({"key": "K1", "build_s": 1.0, "generate_s": 2.0,
                                                          "compile_s": 3.0}))
    (root / "live.lock").write_text(str(os.getpid()))
    (root / "killed.lock").write_text(str(dead))
    codecache._mark(root / "big", {"reason": "too_large", "bytes": 60_000_000, "bound": 4_000_000})
    codecache._mark(root / "was_big", {"reason": "too_large", "bytes": 3_000_000, "bound": 2_000_000})
    codecache._mark(root / "broke", {"reason": "compile_failed", "cflags": list(codecache.CFLAGS),
                                     "compilers": [codecache._compiler_id()], "error": "CalledProcessError: status 1"})
    (root / "legacy.failed").write_text("not compiled: 5.0 MB of C, above the 4 MB bound\n")
    return root


def test_the_listing_shows_the_marked_shapes_with_why(tmp_path, monkeypatch, capsys):
    root = _cache_with_every_state(tmp_path, monkeypatch)
    assert codecache._main([]) == 0
    lines = capsys.readouterr().out.splitlines()
    by_name = {ln.split()[0]: ln for ln in lines}
    assert "compile 3.0 s  K1" in by_name["done"]
    assert "60.0 MB of C, above the 4.0 MB bound then" in by_name["big"] and by_name["big"].endswith("marked")
    assert "3.0 MB of C" in by_name["was_big"] and "no longer holds" in by_name["was_big"]
    assert "the compile failed (CalledProcessError: status 1)" in by_name["broke"] and "-O1" in by_name["broke"]
    assert "5.0 MB of C" in by_name["legacy"] and "first format" in by_name["legacy"]
    assert by_name["legacy"].endswith("marked")
    assert lines[-1] == f"1 compiled NLP shapes in {root}; 1 being compiled; 3 marked not to compile"


def test_status_counts_compiled_pending_and_marked_shapes(tmp_path, monkeypatch):
    _cache_with_every_state(tmp_path, monkeypatch)
    assert codecache.status() == {"mode": "auto", "pending": 1, "compiled": 1, "marked": 3}
    monkeypatch.setenv("TUNER_NLP_COMPILE", "load")
    assert codecache.status() == {"mode": "load", "pending": 1, "compiled": 1, "marked": 3}
    monkeypatch.setattr(codecache, "enabled", lambda: False)  # (no compiler, or a root that is not private)
    assert codecache.status() == {"mode": "off", "pending": 0, "compiled": 0, "marked": 0}
    monkeypatch.setattr(codecache, "enabled", lambda: True)
    monkeypatch.setenv("TUNER_NLP_COMPILE", "off")
    assert codecache.status() == {"mode": "off", "pending": 0, "compiled": 0, "marked": 0}


# what a reviewer put in a cache folder (stop 50): each once gave a traceback in status() (so /health answered 500),
# in schedule() (so every tune of that shape raised) or in the listing, or held the reader for good (a FIFO)
HOSTILE_MARKERS = {"inf": '{"reason": "too_large", "bytes": Infinity, "bound": 1}',
                   "huge": '{"reason": "too_large", "bytes": 1e400, "bound": 1}',
                   "nan": '{"reason": "too_large", "bytes": NaN, "bound": 1}',
                   "deep": "[" * 100_000, "empty": "", "binary": "\udcff",
                   "badflags": '{"reason": "compile_failed", "cflags": "-O1", "compilers": [], "error": 1}',
                   "nocompilers": '{"reason": "compile_failed", "cflags": ["-O1"], "compilers": "gcc"}',
                   "oddreason": '{"reason": "later", "bytes": 1}'}
HOSTILE_LOCKS = {"superscript": "\u00b2", "nines": "9" * 30, "negative": "-1"}


def _hostile_cache(root: Path) -> None:
    root.mkdir(parents=True, exist_ok=True)
    for name, text in HOSTILE_MARKERS.items():
        (root / f"{name}.failed").write_bytes(text.encode("utf-8", "surrogateescape"))
    (root / "adir.failed").mkdir()
    os.mkfifo(root / "fifo.failed")
    for name, text in HOSTILE_LOCKS.items():
        (root / f"{name}.lock").write_text(text)
    os.mkfifo(root / "pipe.lock")


def test_hostile_markers_and_locks_are_failed_markers_and_foreign_locks_never_a_traceback_or_a_hang(
        tmp_path, monkeypatch, capsys):
    _scheduling(tmp_path, monkeypatch)
    monkeypatch.setenv("TUNER_NLP_COMPILE", "auto")
    monkeypatch.setattr(codecache, "MAX_SOURCE_BYTES", 4_000_000)
    root = tmp_path / "nlp"
    _hostile_cache(root)
    # every marker reads as one that holds: nothing is retried on its account, nothing raises, nothing blocks
    for name in [*HOSTILE_MARKERS, "adir", "fifo"]:
        info = codecache.marker(root / name)
        assert isinstance(info, dict) and codecache.marker_holds(info), name
        assert not _asked_again(name), name
    assert not _FakePopen.started
    # a lock that does not hold a pid this system can have is not stale (its age decides) and counts as a build
    assert codecache.status() == {"mode": "auto", "pending": len(HOSTILE_LOCKS) + 1, "compiled": 0,
                                  "marked": len(HOSTILE_MARKERS) + 2}
    assert codecache._main([]) == 0
    out = capsys.readouterr().out
    assert "delete it to retry" in out and out.splitlines()[-1].endswith(
        f"0 compiled NLP shapes in {root}; {len(HOSTILE_LOCKS) + 1} being compiled; "
        f"{len(HOSTILE_MARKERS) + 2} marked not to compile")


def test_an_entry_whose_files_are_pipes_is_corrupt_not_a_hang_and_the_listing_reads_any_build_record(
        tmp_path, monkeypatch, capsys):
    """(second review, stop 50) A FIFO as an entry's sums.json held every tune of that shape in load(), and one as
    its build.json held the listing (and the Docker build's --wait); garbage there was a traceback."""
    _scheduling(tmp_path, monkeypatch)
    monkeypatch.setenv("TUNER_NLP_COMPILE", "load")
    root = tmp_path / "nlp"
    for name in ("piped", "piped_so"):
        (root / name).mkdir(parents=True)
        for f in codecache.FILES:
            (root / name / f).write_bytes(b"x")
    os.mkfifo(root / "piped" / "sums.json")
    (root / "piped_so" / "sums.json").write_text(json.dumps(dict.fromkeys(codecache.FILES, "0")))
    (root / "piped_so" / "nlp.so").unlink()
    os.mkfifo(root / "piped_so" / "nlp.so")
    (root / "sparse").mkdir()  # a 2 GB sparse library: refused by its size, not read
    for f in codecache.FILES:
        (root / "sparse" / f).write_bytes(b"x")
    os.truncate(root / "sparse" / "nlp.so", 2 << 30)
    (root / "sparse" / "sums.json").write_text(json.dumps(dict.fromkeys(codecache.FILES, "0")))
    (root / "zero.failed").symlink_to("/dev/zero")  # a marker that is a device: a marker that holds, not read
    assert codecache.marker(root / "zero")["reason"] == "failed"
    for name in ("piped", "piped_so", "sparse"):  # corrupt: deleted, to be built again; never assembled
        assert codecache.load(name, None, None, lambda *a: pytest.fail("assembled")) is None
        assert not (root / name).exists()
    for name, write in (("fifo", lambda p: os.mkfifo(p)), ("garbage", lambda p: p.write_text("{")),
                        ("wrong", lambda p: p.write_text('{"build_s": "x", "generate_s": 1, "compile_s": 1}')),
                        ("deep", lambda p: p.write_text("[" * 100_000))):
        (root / name).mkdir()
        write(root / name / "build.json")
    (root / "good").mkdir()
    (root / "good" / "build.json").write_text(json.dumps({"key": "K", "build_s": 1, "generate_s": 2,
                                                          "compile_s": 3}))
    assert codecache._main([]) == 0
    by_name = {ln.split()[0]: ln for ln in capsys.readouterr().out.splitlines()}
    for name in ("fifo", "garbage", "wrong", "deep"):
        assert "its build.json cannot be read" in by_name[name], by_name[name]
    assert "compile 3.0 s  K" in by_name["good"]


def test_a_marker_is_never_longer_than_what_marker_reads_whole(tmp_path, monkeypatch, capsys):
    """(second review, stop 50) An error of 500 characters and 8 compilers of long non-ASCII paths, JSON-escaped,
    could pass MARKER_MAX_BYTES: the marker then read as one that cannot be read (held for good, its compilers lost).
    The writer cuts the error, then drops the oldest compilers; the listing prints a lone surrogate escaped."""
    root = tmp_path / "nlp"
    root.mkdir()
    compilers = [{"path": "/nix/store/" + "\u7f16\u8bd1" * 60 + f"-gcc-{i}/bin/gcc", "size": i, "mtime_ns": i}
                 for i in range(8)]
    info = {"reason": "compile_failed", "cflags": list(codecache.CFLAGS), "compilers": compilers,
            "error": "CalledProcessError: " + "\u9519" * 480}
    assert len((json.dumps(info) + "\n").encode()) > codecache.MARKER_MAX_BYTES  # (what the writer used to write)
    codecache._mark(root / "long", info)
    assert len((root / "long.failed").read_bytes()) <= codecache.MARKER_MAX_BYTES
    back = codecache.marker(root / "long")
    assert back["reason"] == "compile_failed" and back["compilers"] == compilers[-len(back["compilers"]):]
    assert back["compilers"][-1] == compilers[-1] and back["error"].startswith("CalledProcessError")
    # a path that is not UTF-8 comes back from an OSError as a lone surrogate: the listing escapes it
    monkeypatch.setenv("TUNER_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(codecache, "enabled", lambda: True)
    codecache._mark(root / "odd", {"reason": "compile_failed", "cflags": list(codecache.CFLAGS),
                                   "compilers": [{"path": "/opt/\udcffcc"}], "error": "OSError: /opt/\udcffcc"})
    assert codecache._main([]) == 0
    out = capsys.readouterr().out
    assert "\\udcff" in out
    out.encode("utf-8")  # (strict: no lone surrogate left)
