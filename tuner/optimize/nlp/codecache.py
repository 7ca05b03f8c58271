"""The NLPs' compiled code, on disk: CasADi's generated C of each problem shape, compiled once per machine and
shared by the command line, the service and the study workers (:func:`tuner.optimize.cachedir.cache_root`
``/nlp``, ``TUNER_CACHE_DIR`` to move it).

A shape's first use builds the interpreted NLP as before (:func:`tuner.optimize.nlp.transcribe.get_problem`) and
asks for its compiled code (:func:`schedule`): a detached background process builds the same problem again,
generates its C (``generate_dependencies``, the step's ``generate``), compiles it with gcc (at most one compile at
a time per machine, each bounded by :data:`COMPILE_TIMEOUT_S`) and moves the finished entry into place by one
rename, so a reader sees a whole entry or none. The run that asked is not slowed by it. Later uses, in any process,
load the entry (:func:`load`) instead of building: the solver from the shared library, the constraint bounds from
the entry's ``meta.npz``. An entry whose files do not match the checksums written with it, or that CasADi cannot
load, is deleted and built again, never used. The compiled solver gives bitwise the interpreted solver's answers
(tests/tuner/test_codecache.py). ``TUNER_NLP_COMPILE``: ``auto`` (the default; ``on`` too) compiles in the
background as above, once per cache, bounded before gcc runs (a shape of more than :data:`MAX_SOURCE_BYTES` of C is
not compiled; at most :data:`MAX_PENDING` builds wait at once; the builder runs at the lowest priority) and reported
(``tuner tune`` and ``tuner tradeoff`` say on stderr how many they asked for, :func:`started`; ``tuner study run`` how
many are still being built when it ends, :func:`pending`); ``load`` uses the entries there are and starts no
compile; ``off`` keeps every NLP interpreted (the test suite's default). A shape whose compile failed or that was too
large is marked (``<entry>.failed``, JSON: why, and under which bound or compiler) and not tried again while the
marker holds (:func:`marker_holds`): a too-large shape until :data:`MAX_SOURCE_BYTES` is raised to its size, a
failed compile until the compiler or its flags change (or the NLP's sources: a new entry). A px4_rate shape's 60 MB
of C did not compile within the cap on a loaded 2-core machine. One whose compile ran out of time is not marked (a
busy machine's: a later use asks again). A compile that
runs out of time is killed with its whole process group (gcc's ``cc1`` too), so the next compile never starts beside
it. A build's ``<entry>.lock`` holds the builder's pid: a lock whose process is gone (a killed build) is stale at
once, not after :data:`STALE_LOCK_S`. The cache is used only in a root owned by the current user and not writable by
group or others (:func:`tuner.optimize.cachedir.trusted_root`); in any other it is off.

``python -m tuner.optimize.nlp.codecache`` lists the entries with their compile times and the marked shapes with
why; ``--wait`` returns when no compile is under way (the Docker image's build tunes its loops, then waits for their
code). :func:`status` is the same in numbers, for the service's ``/health``.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import pickle
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import TunerError
from ...fileio import open_input, read_head, read_json
from ..cachedir import cache_root, trusted_root

__all__ = ["enabled", "entry_dir", "load", "schedule", "build_entry", "mode", "started", "pending", "status",
           "marker", "marker_holds", "COMPILE_TIMEOUT_S", "CFLAGS", "MAX_SOURCE_BYTES"]

CFLAGS = ("-O1", "-fPIC", "-shared")  # -O1: 1.85-2.2x the interpreted evaluation; -O2 compiles far longer
COMPILE_TIMEOUT_S = 1800.0  # a compile that takes longer is abandoned (the shape stays interpreted)
# a shape whose generated C is larger than this is not compiled (marked, as a failed compile is; checked before gcc
# runs): gcc -O1 takes about 42 s here on the roll loop's largest shape (2.5 MB) and grows faster than the size;
# px4_rate's six shapes are 2.8-60 MB (nlp.c and step.c), the largest did not compile within COMPILE_TIMEOUT_S
# (bench/results/nlp_code_sizes_stop49.txt)
MAX_SOURCE_BYTES = 4_000_000
# background builds waiting or running in one cache at most (each one a process: its own Python and CasADi)
MAX_PENDING = 8
STALE_LOCK_S = 2 * COMPILE_TIMEOUT_S
FILES = ("nlp.so", "step.so", "meta.npz")
_SCHEDULED: set[str] = set()  # the entries this process asked for (each once)
_STARTED: list[str] = []  # ... and those whose background build it started (what the command line reports)
# what writes the NLP: its transcription, the search space, the structures' coefficients and the firmware laws they
# call (every module of tuner/firmware: a law's scaling or filter changed there changes the NLP; review of issue 41)
_SOURCES = ("transcribe.py", "layout.py", "../space.py", "../../controllers.py", "../../lti.py")


def sources_digest() -> str:
    """The hash of the code that writes the NLPs (:data:`_SOURCES` and every module of ``tuner/firmware``), once per
    process: the key of every compiled or stored entry, so that a change there makes new entries."""
    if "src" not in _MEMO:
        here = Path(__file__).parent
        files = [(here / f).resolve() for f in _SOURCES] + sorted((here / "../../firmware").resolve().glob("*.py"))
        h = hashlib.sha256()
        for f in files:
            h.update(f.name.encode() + b"\0" + f.read_bytes())
        _MEMO["src"] = h.hexdigest()
    return _MEMO["src"]
FORMAT = 1  # the entry's files and how they are compiled (a change here: bump it)


_MEMO: dict[Any, Any] = {}  # the sources' hash, gcc's presence, each shape's entry name (per process)


def enabled() -> bool:
    """The compiled-code cache is on (``TUNER_NLP_COMPILE`` not ``off``), gcc is there and the cache's root is safe
    to load code from (:func:`tuner.optimize.cachedir.trusted_root`)."""
    if os.environ.get("TUNER_NLP_COMPILE", "auto").strip().lower() in ("off", "0", "no", "false"):
        return False
    if trusted_root() is None:
        return False
    cc = os.environ.get("CC", "gcc")
    if ("cc", cc) not in _MEMO:
        _MEMO[("cc", cc)] = shutil.which(cc) is not None
    return _MEMO[("cc", cc)]


def shape_digest(key: Any, space: Any, extra: tuple[Any, ...], n: int) -> str:
    """A problem shape's cache name (``n`` hex digits): the hash of :func:`sources_digest`, the shape ``key``, the
    search space's coordinates, CasADi's version and the cache's own ``extra`` fields (its format, its compiler
    flags), once per process."""
    memo = (key, space.names, space._ratio_of)
    if (memo, extra, n) not in _MEMO:
        import casadi

        h = hashlib.sha256((sources_digest() + repr((*memo, casadi.__version__, *extra))).encode())
        _MEMO[(memo, extra, n)] = h.hexdigest()[:n]
    return _MEMO[(memo, extra, n)]


def _digest(key: Any, space: Any) -> str:
    return shape_digest(key, space, (CFLAGS, FORMAT), 24)


def entry_dir(key: Any, st: Any, space: Any) -> Path:
    """The cache entry of the problem shape ``key`` (structure ``st``, search space ``space``)."""
    return cache_root() / "nlp" / _digest(key, space)


def _sha(path: Path) -> str:
    """The SHA-256 of an entry's file, streamed through the bounded reader (:func:`tuner.fileio.open_input`: a
    regular file of at most :data:`MAX_ENTRY_FILE_BYTES`, never a FIFO or a device that would hold a tune)."""
    with open_input(path, limit=MAX_ENTRY_FILE_BYTES) as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


MAX_ENTRY_FILE_BYTES = 256 << 20  # an entry's shared library, far above any a shape under MAX_SOURCE_BYTES makes


def load(key: Any, st: Any, space: Any, assemble: Any) -> Any:
    """The compiled problem of ``key`` from the cache, or None (not there, or corrupt: then deleted, to be built
    again). ``assemble(nlp_so, step, lbg, ubg, n_v)`` makes the problem of the entry's parts (the shared library's
    path, the step Function, the constraint bounds, the number of structure parameters); whatever it raises marks
    the entry as corrupt too."""
    if not enabled():
        return None
    d = entry_dir(key, st, space)
    if not (d / "sums.json").exists():
        return None
    try:
        import casadi as cs

        sums = read_json(d / "sums.json", limit=1 << 16)
        if any(_sha(d / f) != sums[f] for f in FILES):  # (regular files only: a FIFO there would hold the tune)
            raise ValueError("checksum")
        meta = np.load(d / "meta.npz")
        return assemble(str(d / "nlp.so"), cs.external("step", str(d / "step.so")), np.array(meta["lbg"], float),
                        np.array(meta["ubg"], float), int(meta["n_v"]))
    except Exception:  # a corrupt or foreign entry: never trusted, built again
        shutil.rmtree(d, ignore_errors=True)
        return None


def _lock_stale(lock: Path) -> bool:
    """The lock ``lock`` is left by a build that is no longer running: its builder's pid (written in it) is not a
    live process, or it is older than :data:`STALE_LOCK_S`."""
    try:
        if time.time() - lock.stat().st_mtime > STALE_LOCK_S:
            return True
        text = read_head(lock, 64).decode().strip()
    except (OSError, TunerError, UnicodeDecodeError):
        return False  # gone (or unreadable, or not a file): not ours to remove
    if not (text.isascii() and text.isdigit()) or len(text) > 10:
        return False  # (being written, or written before locks held a pid, or not a pid: the age decides)
    try:
        os.kill(int(text), 0)
    except ProcessLookupError:
        return True
    except (OSError, OverflowError, ValueError):
        return False  # alive, another user's (or no pid the system knows: the age decides)
    return False


def schedule(key: Any, st: Any, space: Any) -> bool:
    """Ask for the compiled code of ``key`` in the background (a detached process; nothing if it is in the cache,
    being built, marked by a marker that holds (:func:`marker_holds`), or asked for already by this process). True if
    a build was started."""
    if not enabled() or mode() != "auto":
        return False
    d = entry_dir(key, st, space)
    if d.name in _SCHEDULED or (d / "sums.json").exists():
        return False
    info = marker(d)
    if info is not None and marker_holds(info):
        return False
    _SCHEDULED.add(d.name)
    # (a bound, not a strict one: two processes may count at once, and a lock older than STALE_LOCK_S counts as stale)
    if _live_builds(d.parent) >= MAX_PENDING:
        return False  # enough builds wait already: a later use in another process asks again
    lock = d.with_name(d.name + ".lock")
    try:
        d.parent.mkdir(parents=True, exist_ok=True)
        if lock.exists() and _lock_stale(lock):
            lock.unlink(missing_ok=True)
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
        try:
            os.write(fd, str(os.getpid()).encode())  # until the builder writes its own
        finally:
            os.close(fd)
    except OSError:
        return False  # another process builds it (or the cache is not writable)
    job = d.with_name(d.name + ".job")
    try:
        job.write_bytes(pickle.dumps((key, st, space)))
        p = subprocess.Popen([sys.executable, "-m", "tuner.optimize.nlp.transcribe", "--build", str(job)],
                             stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                             start_new_session=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
        _write_pid(lock, p.pid)
    except (OSError, pickle.PicklingError):
        lock.unlink(missing_ok=True)
        job.unlink(missing_ok=True)
        return False
    _STARTED.append(d.name)
    return True


def mode() -> str:
    """``TUNER_NLP_COMPILE``'s mode: ``auto`` (unset, ``auto``, ``on``, ``1``, ``yes``: a new shape is compiled in the
    background), ``load`` (the entries there are, no new compile) or ``off`` (every NLP interpreted)."""
    v = os.environ.get("TUNER_NLP_COMPILE", "auto").strip().lower()
    if v in ("off", "0", "no", "false"):
        return "off"
    return "load" if v == "load" else "auto"


def started() -> int:
    """How many background builds this process started (:func:`schedule`)."""
    return len(_STARTED)


def pending() -> int:
    """How many background builds wait or run in this cache now (any process's: a study's workers', say)."""
    if not enabled():
        return 0
    return _live_builds(cache_root() / "nlp")


def status() -> dict[str, Any]:
    """The cache's state in numbers (the service's ``/health``): ``mode`` (:func:`mode`; ``off`` too where the cache
    is off: no compiler, or a root that is not private), ``pending`` (:func:`pending`), ``compiled`` (the entries
    there are) and ``marked`` (the shapes a marker that holds keeps interpreted). Directory globs and small reads;
    with the cache off, nothing is read."""
    m = mode()
    if m == "off" or not enabled():
        return {"mode": "off", "pending": 0, "compiled": 0, "marked": 0}
    root = cache_root() / "nlp"
    if not root.exists():
        return {"mode": m, "pending": 0, "compiled": 0, "marked": 0}
    marks = [marker(f.with_suffix("")) for f in root.glob("*.failed")]
    return {"mode": m, "pending": _live_builds(root), "compiled": sum(1 for _ in root.glob("*/sums.json")),
            "marked": sum(1 for i in marks if i is not None and marker_holds(i))}


def marker(d: Path) -> dict[str, Any] | None:
    """What the marker of the entry ``d`` (``<entry>.failed``) says, or None (no marker): ``reason`` ``too_large``
    (with the C's ``bytes`` and the ``bound`` then), ``compile_failed`` (with the ``cflags``, the ``compilers`` it
    failed with (each :func:`_compiler_id`) and the ``error``), or ``failed`` (with its text as ``detail``): a marker
    that cannot be read, or plain text of the first format that does not say under which bound or compiler it was
    written. The first format's too-large text ("not compiled: 60.4 MB of C, above the 4 MB bound") does say the size:
    it reads as ``too_large`` with the least size that rounds to it (``legacy``: its text). Never raises: whatever is
    there (garbage, a directory, a FIFO, deep JSON) is a ``failed`` marker."""
    try:
        path = d.with_name(d.name + ".failed")
        if not os.path.lexists(path):
            return None
        text = read_head(path, MARKER_MAX_BYTES).decode()  # (the bounded reader: a regular file only)
    except (OSError, TunerError, UnicodeDecodeError):
        text = ""
    try:
        info = json.loads(text)
    except (ValueError, RecursionError):
        info = None
    if isinstance(info, dict) and isinstance(info.get("reason"), str):
        return info
    m = _LEGACY_TOO_LARGE.match(text.strip())
    if m:
        return {"reason": "too_large", "bytes": max(0, math.floor((float(m.group(1)) - 0.05) * 1e6)),
                "bound": None, "legacy": text.strip()}
    return {"reason": "failed", "detail": text.strip()}


MARKER_MAX_BYTES = 4096  # a marker is a line of JSON; more is not read
# the first format's too-large marker (stop 49): its size rounded to 0.1 MB
_LEGACY_TOO_LARGE = re.compile(r"not compiled: ([0-9]{1,6}\.[0-9]) MB of C, above the [0-9.]+ MB bound\Z")


def marker_holds(info: dict[str, Any]) -> bool:
    """The marker ``info`` (:func:`marker`) still keeps its shape from being compiled: a ``too_large`` one while the
    shape's C is above :data:`MAX_SOURCE_BYTES` (raise the bound to its size, and the shape is asked for again), a
    ``compile_failed`` one while the flags are those it failed with and the compiler is one it failed with (a new
    gcc, or another ``CC``, tries again; the last 8 compilers that failed are kept, so that two environments sharing
    a cache do not take turns retrying). Any other holds, as does one whose fields cannot be read: a plain-text
    marker of the first format does not say why it was written, and retrying it blindly could start again the
    compile that ran 30 min and failed; delete it to try again."""
    try:
        if info["reason"] == "too_large":
            return not float(info["bytes"]) <= MAX_SOURCE_BYTES  # (NaN holds)
        if info["reason"] == "compile_failed":
            cflags, ids = info["cflags"], _failed_compilers(info)
            if not isinstance(cflags, list) or not ids:
                return True
            return cflags == list(CFLAGS) and _compiler_id() in ids
    except (KeyError, TypeError, ValueError, ArithmeticError):
        pass
    return True


def _failed_compilers(info: dict[str, Any] | None) -> list[Any]:
    """The compilers a ``compile_failed`` marker ``info`` failed with (``compilers``; ``compiler``: one, as the
    marker's first JSON form wrote it)."""
    if not isinstance(info, dict) or info.get("reason") != "compile_failed":
        return []
    ids = info.get("compilers", [info["compiler"]] if "compiler" in info else [])
    return [c for c in ids if isinstance(c, dict)] if isinstance(ids, list) else []


def _compiler_id() -> dict[str, Any]:
    """The compiler a compile runs now (``CC``, else gcc): its resolved path, size and modification time, recorded in
    a failed compile's marker, so that another compiler (``CC``, a new default gcc) or the same one upgraded (its
    file replaced) tries the shape again. A stat, not ``gcc --version``: :func:`schedule` runs in the tune's
    foreground."""
    cc = os.environ.get("CC", "gcc")
    path = shutil.which(cc)
    if path is None:
        return {"path": cc}
    real = Path(path).resolve()
    try:
        st = real.stat()
    except OSError:
        return {"path": str(real)}
    return {"path": str(real), "size": st.st_size, "mtime_ns": st.st_mtime_ns}


def _mark(d: Path, info: dict[str, Any]) -> None:
    """Mark the shape of the entry ``d`` not to be compiled while ``info`` holds (:func:`marker_holds`): JSON, written
    whole (a temporary file renamed over it)."""
    m = d.with_name(d.name + ".failed")
    tmp = m.with_name(f"{m.name}.{os.getpid()}.tmp")
    # what marker() reads whole (MARKER_MAX_BYTES): the error cut, then the oldest compilers dropped (a marker still
    # longer, a compiler path of kilobytes, reads as one that cannot be read: it holds, the safe side)
    text = json.dumps(info) + "\n"
    if len(text.encode()) > MARKER_MAX_BYTES and "error" in info:
        info = {**info, "error": str(info["error"])[:80]}
        text = json.dumps(info) + "\n"
    while len(text.encode()) > MARKER_MAX_BYTES and isinstance(info.get("compilers"), list) and \
            len(info["compilers"]) > 1:
        info = {**info, "compilers": info["compilers"][1:]}
        text = json.dumps(info) + "\n"
    try:
        tmp.write_text(text)
        os.replace(tmp, m)
    except OSError:
        tmp.unlink(missing_ok=True)


def _live_builds(root: Path) -> int:
    """The builds waiting or running in the cache folder ``root``: its locks that are not stale."""
    return sum(not _lock_stale(f) for f in root.glob("*.lock")) if root.exists() else 0


def _write_pid(lock: Path, pid: int) -> None:
    """Write the builder's pid into its lock (whole: a temporary file renamed over it)."""
    tmp = lock.with_name(f"{lock.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(str(pid))
        os.replace(tmp, lock)
    except OSError:
        tmp.unlink(missing_ok=True)


def _compile(cmd: list[str], timeout_s: float) -> None:
    """Run the compiler ``cmd`` in its own process group; on time out kill the whole group (the driver and its
    ``cc1``), so no compile outlives its call. Raises TimeoutExpired or CalledProcessError. (A process group in the
    caller's session, not a session of its own: where the kernel groups processes by session (autogroup), gcc then
    shares the builder's lowered group rather than a new one at nice 0.)"""
    p = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         process_group=0)
    try:
        p.communicate(timeout=timeout_s)
    except BaseException:  # the time out (or an interrupt): no part of the compile is left running
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except OSError:
            pass
        p.wait()
        raise
    if p.returncode:
        raise subprocess.CalledProcessError(p.returncode, cmd)


def build_entry(key: Any, st: Any, space: Any, build: Any, *, timeout_s: float = COMPILE_TIMEOUT_S
                ) -> dict[str, float]:
    """Build (``build(key, st, space)``: the interpreted problem), generate and compile the entry of ``key`` now
    (what the background process does): the seconds each step took. At most one compile at a time per machine (a
    lock on ``nlp/compile.flock``); the entry is moved into place whole."""
    import fcntl

    d = entry_dir(key, st, space)
    root = d.parent
    root.mkdir(parents=True, exist_ok=True)
    with open(root / "compile.flock", "w") as lk:
        fcntl.flock(lk, fcntl.LOCK_EX)
        if (d / "sums.json").exists():
            return {}
        tmp = Path(__import__("tempfile").mkdtemp(prefix=d.name + ".", suffix=".tmp", dir=root))
        try:
            t0 = time.perf_counter()
            prob = build(key, st, space)
            t1 = time.perf_counter()
            cwd = os.getcwd()
            os.chdir(tmp)
            try:
                prob.solver.generate_dependencies("nlp.c")
                prob.step.generate("step.c")
            finally:
                os.chdir(cwd)
            t2 = time.perf_counter()
            size = sum((tmp / f).stat().st_size for f in ("nlp.c", "step.c"))
            if size > MAX_SOURCE_BYTES:  # not asked for again while the bound is below its size (schedule)
                _mark(d, {"reason": "too_large", "bytes": size, "bound": MAX_SOURCE_BYTES})
                return {"build_s": t1 - t0, "generate_s": t2 - t1, "skipped_bytes": float(size)}
            cc = os.environ.get("CC", "gcc")
            deadline = t2 + timeout_s
            try:
                for src, out in (("step.c", "step.so"), ("nlp.c", "nlp.so")):
                    _compile([cc, *CFLAGS, str(tmp / src), "-o", str(tmp / out), "-lm"],
                             max(1.0, deadline - time.perf_counter()))
            except subprocess.TimeoutExpired:
                raise  # (not marked: a machine too busy to give the compile its CPU; a later use asks again)
            except (subprocess.SubprocessError, OSError) as e:  # not asked for again with this compiler (schedule)
                prev, now = marker(d), _compiler_id()  # (the compilers that failed before with these flags: kept)
                ids = _failed_compilers(prev) if isinstance(prev, dict) and prev.get("cflags") == list(CFLAGS) else []
                _mark(d, {"reason": "compile_failed", "cflags": list(CFLAGS),
                          "compilers": [*[c for c in ids if c != now], now][-8:],
                          "error": f"{type(e).__name__}: {e}"[:500]})
                raise
            t3 = time.perf_counter()
            np.savez(tmp / "meta.npz", lbg=prob.lbg, ubg=prob.ubg, n_v=prob.n_v)
            for f in ("nlp.c", "step.c"):
                (tmp / f).unlink()
            times = {"build_s": t1 - t0, "generate_s": t2 - t1, "compile_s": t3 - t2}
            (tmp / "build.json").write_text(json.dumps({"key": repr(key), **times}))
            (tmp / "sums.json").write_text(json.dumps({f: _sha(tmp / f) for f in FILES}))
            os.chmod(tmp, 0o755)
            os.rename(tmp, d)  # whole or not at all
            d.with_name(d.name + ".failed").unlink(missing_ok=True)  # (a marker that no longer held)
            return times
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


def run_job(job: Path, build: Any) -> None:
    """The background process's work (``python -m tuner.optimize.nlp.transcribe --build JOB``): the entry of the
    job file that :func:`schedule` wrote, then the job and its lock removed."""
    lock = job.with_suffix(".lock")
    try:
        root = trusted_root()
        if root is None or root.resolve() not in job.resolve().parents:
            return  # a job outside a private cache is never unpickled
        if lock.exists():
            _write_pid(lock, os.getpid())
        # behind whatever the machine runs in the foreground (the tune that asked, the next one): the lowest priority,
        # and where the kernel groups processes by session (autogroup: this builder has a session of its own, whose
        # group would otherwise compete at nice 0 with the user's) its group's too
        for lower in (lambda: os.nice(19), lambda: Path("/proc/self/autogroup").write_text("19")):
            try:
                lower()
            except OSError:
                pass
        key, st, space = pickle.loads(job.read_bytes())  # (written by schedule, in the cache's own folder)
        build_entry(key, st, space, build)
    finally:
        job.unlink(missing_ok=True)
        lock.unlink(missing_ok=True)


def _main(argv: list[str]) -> int:
    if argv == ["--wait"]:  # until no compile is under way (the Docker image's build: after its tunes)
        root = cache_root() / "nlp"
        deadline = time.time() + STALE_LOCK_S
        while root.exists() and any(not _lock_stale(f) for f in root.glob("*.lock")):
            if time.time() > deadline:
                return 1
            time.sleep(1.0)
    root = cache_root() / "nlp"
    entries = sorted(root.glob("*/build.json")) if root.exists() else []
    for b in entries:
        try:
            info = read_json(b, limit=1 << 16)
            line = f"build {float(info['build_s']):.1f} s  generate {float(info['generate_s']):.1f} s  " \
                   f"compile {float(info['compile_s']):.1f} s  {info['key']}"
        except (TunerError, KeyError, TypeError, ValueError, ArithmeticError) as e:
            line = f"its build.json cannot be read ({type(e).__name__})"
        _print(f"{b.parent.name}  {line}")
    marks = sorted(root.glob("*.failed")) if root.exists() else []
    held = 0
    for f in marks:
        info = marker(f.with_suffix(""))
        if info is None:
            continue  # (removed meanwhile)
        holds = marker_holds(info)
        held += holds
        _print(f"{f.stem}  not compiled: {_why(info)}; "
              f"{'marked' if holds else 'no longer holds: asked for again at its next use'}")
    pending = _live_builds(root) if root.exists() else 0
    print(f"{len(entries)} compiled NLP shapes in {root}; {pending} being compiled; {held} marked not to compile")
    return 0


def _print(line: str) -> None:
    """A line of the listing, whatever a marker's text holds (a lone surrogate from a path that is not UTF-8 would
    make a strict stdout raise)."""
    print(line.encode("utf-8", "backslashreplace").decode("utf-8"))


def _why(info: dict[str, Any]) -> str:
    """A marker's reason, for the listing (whatever the file holds: never a traceback)."""
    try:
        if info["reason"] == "too_large" and "legacy" in info:
            return f"\"{info['legacy']}\" (a marker of the first format)"
        if info["reason"] == "too_large":
            return f"{float(info['bytes']) / 1e6:.1f} MB of C, above the {float(info['bound']) / 1e6:.1f} MB bound " \
                   f"then ({MAX_SOURCE_BYTES / 1e6:.1f} MB now)"
        if info["reason"] == "compile_failed":
            paths = ", ".join(str(c.get("path")) for c in _failed_compilers(info)) or "?"
            flags = " ".join(map(str, info["cflags"])) if isinstance(info["cflags"], list) else str(info["cflags"])
            return f"the compile failed ({str(info['error'])[:300]}) with {flags} and " \
                   f"{paths}; delete the marker to retry"
    except (KeyError, TypeError, ValueError, ArithmeticError):
        pass
    if info.get("reason") == "failed":
        return f"\"{str(info.get('detail') or '')[:300]}\" (unreadable, or a marker of the first format: it does " \
               "not say under which bound or compiler; delete it to retry)"
    return f"{json.dumps(info, default=str)[:300]} (a marker this version cannot read: delete it to retry)"


if __name__ == "__main__":
    raise SystemExit(_main(sys.argv[1:]))
