"""``tuner study run`` and ``tuner verify``: the command-line side of studies.

Registered in :mod:`tuner.cli` through ``_EXTRA_COMMANDS``. Exit codes as for the rest of
the CLI (:data:`tuner.cli.EXIT_CODES`): 0 success; 1 a loop fails its spec (``verify``, ``study run``)
or the study could not be finished; 2 bad input (one line naming the problem); 3 internal error.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import sys
import threading
import time
from datetime import datetime
from pathlib import Path
from typing import Any

from ..errors import TunerError

__all__ = ["add_parser", "run_study", "write_outputs"]


def add_parser(sub: Any) -> None:
    """Register ``tuner study`` (``run``, ``verify``, ...) on the subcommand parsers ``sub``."""
    s = sub.add_parser("study", help="tune every loop of a study file (TOML)")
    ssub = s.add_subparsers(dest="study_cmd", required=True, parser_class=type(s))
    r = ssub.add_parser("run", help="tune the study's loops, write results.json, report.md and plots")
    r.add_argument("file", help="study file (TOML), e.g. studies/quadrotor.toml")
    r.add_argument("--workers", type=int, default=1, metavar="N", help="worker processes on this machine (1)")
    r.add_argument("--storage", default=None, metavar="URL",
                   help="Optuna storage shared by the workers (default sqlite:///DIR/study.db); "
                        "postgresql://user@host:5432/db for several machines")
    r.add_argument("--out", default=None, metavar="DIR", help="output directory (default results/<study name>)")
    r.add_argument("--check", action="store_true",
                   help="kept for compatibility: the exit code is 1 whenever a loop does not meet its spec")
    r.add_argument("--heartbeat", type=int, default=2, metavar="S", help="claim heartbeat interval, s (2)")
    r.add_argument("--grace", type=int, default=30, metavar="S",
                   help="a claim without a heartbeat for this long is taken over, s (30)")
    r.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    r.set_defaults(handler=_cmd_study_run)

    v = sub.add_parser("verify", help="re-verify committed gains against each loop's spec (exit 1 if any fails)")
    v.add_argument("file", help="study file (TOML)")
    v.add_argument("--gains", required=True, metavar="GAINS.json", help="{loop: {structure, gains, dt}}")
    v.add_argument("--json", action="store_true", help="print JSON instead of a table")
    v.set_defaults(handler=_cmd_verify)


# -- study run ------------------------------------------------------------------------------------

# what every worker imports to tune and verify, module-level or inside its first tune: the search's engine, the
# verifier's and the report's modules. Not here: scipy.stats (about 0.55 s of CPU; engine._restart's Sobol points, only
# in a tune that restarts) and matplotlib (about 0.4 s; only in a worker that draws): paid before the fork they are on
# the critical path of every run, while a worker that pays them itself often does so while the other worker is still
# tuning its last loop (on process.toml at a load of 1.3-1.7, importing both before the fork made the 2-worker run
# about 1.4 s slower in wall, median of 6 pairs, for 1 s less CPU: bench/results/study_workers_issue41_prefork.md)
_STACK = ("tuner.tuning", "tuner.optimize.search", "tuner.optimize.engine", "tuner.optimize.nlp.refine",
          "tuner.studies.evaluate", "tuner.robust", "tuner.interop", "tuner.diagnose", "tuner.display",
          "tuner.analysis.plots")


def _preload_stack(plots: bool = False) -> None:
    """Import what every worker tunes with, once, before forking the workers (a module a forked worker inherits costs
    its CPU once for the study); the plots' module only if ``plots`` (see :data:`_STACK`)."""
    import importlib

    for mod in _STACK:
        if plots or mod != "tuner.analysis.plots":
            importlib.import_module(mod)


def _load_kernels() -> None:
    """A worker's start: the batch's compiled kernels loaded and warmed (:func:`tuner.optimize.batch.preload_kernels`,
    where this machine has them), so that numba has loaded their machine code from its cache before the first tune
    (loaded lazily inside the first batch, it made that batch look dear and the search cut the worker's first loop in
    round 0: bench/results/study_workers_issue41.md). A forked worker inherits them loaded and warm from
    :func:`_prepare_fork` (this is then a no-op); a spawned one loads them here."""
    from ..optimize.batch import preload_kernels

    preload_kernels()


def _prepare_fork() -> Any:
    """The workers' shared start, once in this process before it forks them (about 0.4 s of CPU a worker paid
    again): the batch's kernels loaded and warmed (:func:`_load_kernels`), and the objects this process holds
    frozen out of the cyclic garbage collector (``gc.freeze()``), so that a worker's collections neither walk the
    inherited objects (a quarter to a half second of CPU a worker) nor write to their pages (which copied them into
    every worker). Returns what :func:`_after_fork` restores: the process that runs the study (a test's, a
    notebook's) keeps its own choice of the batch's path and its own collector."""
    import gc

    from ..optimize import batch

    saved = {k: batch._KERNELS[k] for k in ("module", "warm")}
    _load_kernels()
    gc.freeze()
    return saved


def _after_fork(saved: Any) -> None:
    """This process as it was before :func:`_prepare_fork`, once its workers are forked."""
    import gc

    from ..optimize import batch

    gc.unfreeze()
    batch._KERNELS.update(saved)


def _context() -> Any:
    """``fork`` where it is safe and cheap (Linux: the workers inherit the imported stack), else ``spawn``."""
    return mp.get_context("fork" if sys.platform.startswith("linux") else "spawn")


def _worker_entry(path: str, url: str, heartbeat_s: int, grace_s: int, parent_pid: int, wakeup: Any,
                  plots_dir: str | None) -> None:
    """A worker process: the same claim loop as every other worker, on its own connection."""
    from .._process import set_parent_death_signal
    from .runner import Coordinator, open_storage, work
    from .schema import load_study

    # a parent killed with SIGKILL cannot leave its workers running: the kernel ends them with it
    if not set_parent_death_signal() or os.getppid() != parent_pid:
        def watchdog() -> None:
            while os.getppid() == parent_pid:
                time.sleep(1.0)
            os._exit(3)

        threading.Thread(target=watchdog, daemon=True).start()
    from threadpoolctl import threadpool_limits

    _load_kernels()
    study = load_study(path)
    with threadpool_limits(limits=1):  # inherited when forked; a spawned worker (not Linux) sets it itself
        work(Coordinator(study, open_storage(url, heartbeat_s=heartbeat_s, grace_s=grace_s)), wakeup=wakeup,
             idle=_idle_plotter(study, plots_dir))


def _fingerprint(study: Any, lp: Any, result: dict[str, Any], results: dict[str, Any] | None = None) -> str:
    """What a loop's plots depend on: its definition (the loop key) and its gains; an outer loop's also the gains of
    the loops it wraps (``results``: every loop's result by name; a missing one counts as no gains)."""
    import hashlib

    from .schema import loop_key

    doc: dict[str, Any] = {"key": loop_key(study, lp.name), "gains": result.get("gains")}
    if lp.inner is not None:
        doc["inner"] = [((results or {}).get(i.name) or {}).get("gains") for i in study.chain(lp.name)[:-1]]
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


def _chain_results(study: Any, lp: Any, statuses: dict[str, Any]) -> dict[str, Any] | None:
    """The results of ``lp`` and of every loop it wraps, by name, if each is done with gains (else None)."""
    out = {}
    for x in study.chain(lp.name):
        st = statuses.get(x.name)
        r = st.result if st is not None and st.state == "done" else None
        if not isinstance(r, dict) or "gains" not in r:
            return None
        out[x.name] = r
    return out


# the figures of a loop, tuner.analysis.plots.LOOP_PLOTS, named here without importing matplotlib (half a second of
# CPU the parent would pay at the end, serially, to read the workers' marks; tests/studies/test_study_workers.py
# checks the two agree)
_FIGURES = ("step", "bode", "nyquist")
# the order idle workers draw them in, the dearest kind first (CPU a figure, studies/process.toml: Bode 0.41-0.45 s,
# step 0.22-0.32, Nyquist 0.13-0.17; bench/study_timeline.py): the figures are the last work of a run, drawn side by
# side, and the workers end within the last figure's cost of each other (a Nyquist's, not a Bode's)
_DRAW_ORDER = ("bode", "step", "nyquist")


def _marker(plots_dir: Path, name: str, kind: str) -> Path:
    """The file that says a figure of loop ``name`` was drawn early, and for which result (:func:`_idle_plotter`)."""
    return plots_dir / f"{name}_{kind}.plotted"


def _drawn(plots_dir: Path, name: str, kind: str, fingerprint: str) -> Path | None:
    """The figure of ``kind`` drawn early for the result with ``fingerprint``, if it was (and is still there)."""
    try:
        doc = json.loads(_marker(plots_dir, name, kind).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("fingerprint") != fingerprint or not isinstance(doc.get("figure"), str):
        return None
    p = plots_dir / doc["figure"]
    return p if p.exists() else None


def _idle_plotter(study: Any, plots_dir: str | None) -> Any:
    """``idle`` of a worker (:func:`tuner.studies.runner.work`): draw one figure of a loop that is done and whose
    figure nobody has drawn, whichever worker tuned it; True if it drew one (False: nothing left to draw here).

    A worker runs it only when no loop is free to tune, so the figures fill the time a worker would otherwise wait
    while the others tune the last loops, and once every loop is done the workers draw what is left side by side:
    the figures are small units of work (a quarter to a third of a second each), so the workers end together. A
    figure is taken by creating its lock file (``O_EXCL``: one process draws it); a ``<name>_<kind>.plotted`` file
    names the figure and the result it shows (:func:`_fingerprint`), and :func:`write_outputs` uses the figure for
    that result only, drawing whatever is missing (a worker killed while drawing leaves its lock and no mark).
    An outer loop's figures once every loop it wraps is done too (its evaluation needs theirs, see
    :func:`_evaluate_chain`; its fingerprint holds their gains)."""
    if plots_dir is None:
        return None
    pdir = Path(plots_dir)
    tried: set[tuple[str, str, str]] = set()
    evals: dict[tuple[str, str], Any] = {}  # this process's evaluations (a loop's figures may fall to one process)

    def draw(statuses: dict[str, Any]) -> bool:
        done = []
        for lp in study.order():
            results = _chain_results(study, lp, statuses)
            if results is None:
                continue
            done.append((lp, results, _fingerprint(study, lp, results[lp.name], results)))
        for kind in _DRAW_ORDER:
            for lp, results, fp in done:
                if (lp.name, kind, fp) in tried:
                    continue
                tried.add((lp.name, kind, fp))
                if _drawn(pdir, lp.name, kind, fp) is not None:
                    continue
                lock = pdir / f"{lp.name}_{kind}.{fp}.lock"
                try:
                    pdir.mkdir(parents=True, exist_ok=True)
                    os.close(os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644))
                except OSError:  # another process draws it (or the folder is not writable: the parent says so)
                    continue
                try:
                    if _drawn(pdir, lp.name, kind, fp) is None:  # (not drawn between the check and the lock)
                        _draw_figure(study, lp, results, kind, fp, pdir, evals)
                    return True
                except Exception:  # the parent draws what is missing
                    import logging

                    logging.getLogger(__name__).exception("plot %s of loop %s not drawn early", kind, lp.name)
                    return True
                finally:
                    lock.unlink(missing_ok=True)
        return False

    return draw


def _draw_figure(study: Any, lp: Any, results: dict[str, Any], kind: str, fp: str, pdir: Path,
                 evals: dict[tuple[str, str], Any]) -> None:
    """One figure of a loop drawn early, and its mark (:func:`_idle_plotter`); ``results``: the loop's and those of the
    loops it wraps, by name."""
    from ..analysis.plots import loop_plots

    e = evals.get((lp.name, fp))
    if e is None:
        e = evals[(lp.name, fp)] = _evaluate_chain(study, lp, results)
    path = loop_plots(e, pdir, lp.name, kinds=(kind,))[kind]
    marker = _marker(pdir, lp.name, kind)
    tmp = marker.with_suffix(f".tmp{os.getpid()}")
    tmp.write_text(json.dumps({"fingerprint": fp, "figure": path.name}))
    tmp.replace(marker)


def _evaluate_chain(study: Any, lp: Any, results: dict[str, Any]) -> Any:
    """``lp``'s evaluation as :func:`_evaluate_all` makes it: around the loops it wraps, with the bandwidth of the
    loop it wraps directly (that loop evaluated the same way)."""
    from .evaluate import evaluate_gains
    from .schema import controller_of

    chain = study.chain(lp.name)
    ctrls = {x.name: controller_of(x, results[x.name]["gains"]) for x in chain}
    return evaluate_gains(study, ctrls, loops=chain)[lp.name]


#: a figure's lock (:func:`_idle_plotter`) older than this was left by a worker killed while drawing: a figure takes
#: seconds, so no live process holds one this long
STALE_LOCK_S = 600.0


def _clear_stale_locks(plots_dir: Path) -> None:
    """Remove the figure locks a killed worker left (older than :data:`STALE_LOCK_S`), so that a later run's idle
    workers draw those figures again rather than leaving them to the parent."""
    import time

    now = time.time()
    for lock in plots_dir.glob("*.lock"):
        try:
            if now - lock.stat().st_mtime > STALE_LOCK_S:
                lock.unlink(missing_ok=True)
        except OSError:
            continue


def _drawn_early(study: Any, lp: Any, result: dict[str, Any], plots_dir: Path,
                 results: dict[str, Any] | None = None) -> dict[str, Path] | None:
    """The plots workers drew for this very result (and, for an outer loop, those of the loops it wraps: ``results``),
    if every one of them was (see :func:`_idle_plotter`)."""
    fp = _fingerprint(study, lp, result, results)
    figs = {kind: _drawn(plots_dir, lp.name, kind, fp) for kind in _FIGURES}
    return figs if all(p is not None for p in figs.values()) else None  # type: ignore[misc]


def _progress_loop(study: Any, storage: Any, stop: threading.Event) -> None:
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from .runner import Coordinator

    coord = Coordinator(study, storage, observe_only=True)
    cols = (TextColumn("{task.description:<12}"), BarColumn(), TextColumn("{task.fields[status]}"),
            TimeElapsedColumn())
    with Progress(*cols, console=Console(stderr=True), transient=False) as prog:
        tasks = {lp.name: prog.add_task(lp.name, total=100, status="queued") for lp in study.order()}
        while True:
            final = stop.is_set()
            try:
                sts = coord.statuses()
            except Exception:  # a transient storage hiccup must not stop the display
                sts = {}
            for lp in study.order():
                st = sts.get(lp.name)
                if st is None:
                    continue
                if st.state == "done":
                    r = st.result or {}
                    ts = (r.get("metrics") or {}).get("settling_time_s")
                    verdict = "meets spec" if r.get("meets_spec") else ("ERROR" if "error" in r else "FAILS spec")
                    if r.get("basis") == "model only":
                        verdict += " (on the model only)"
                    prog.update(tasks[lp.name], completed=100,
                                status=f"done: settling {_short(ts)} s, {verdict}")
                elif st.state == "running":
                    budget = lp.time_budget_s or study.time_budget_s
                    el = (datetime.now() - st.since).total_seconds() if st.since else 0.0
                    prog.update(tasks[lp.name], completed=min(95.0, 100.0 * el / budget),
                                status=f"tuning on {st.worker}")
                elif st.state == "blocked":
                    prog.update(tasks[lp.name], status=f"waiting for {lp.inner}")
                else:
                    again = f"re-queued (attempt {st.attempt + 1})"
                    prog.update(tasks[lp.name], status="queued" if st.attempt == 0 and st.epoch == 0 else again)
            if final:
                return
            stop.wait(0.5)


def _short(v: Any) -> str:
    return f"{v:.3g}" if isinstance(v, (int, float)) else str(v)


def run_study(study: Any, path: str, url: str, *, workers: int = 1, heartbeat_s: int = 2, grace_s: int = 30,
              progress: bool = True, plots_dir: Path | None = None) -> dict[str, Any]:
    """Run ``workers`` workers on this machine until every loop is done; returns the statuses.

    One path for every worker count: the workers (one included) are processes forked from this one once it has
    imported the tuning stack (:func:`_preload_stack`), and loaded and warmed the
    batch's compiled kernels (:func:`_prepare_fork`; none of them does any of it again), so that one worker tunes
    exactly as each of several does (the same seed gives bitwise the same gains whatever the count: the kernels'
    figures agree with numpy's only to rounding, and a study run in this process tuned on numpy where its forked
    workers tuned on the kernels); this process keeps its own choice of the batch's path (:func:`_after_fork`).
    This process opens the storage and starts its progress thread after the fork; the workers wake each
    other when a loop is done, and draw the figures of the loops that are done when no loop is left for them to
    tune (:func:`_idle_plotter`)."""
    from .runner import Coordinator, Wakeup, open_storage

    # Optuna creates its tables on first use: once, here (workers starting together would race), with no connection
    # left open across the fork; the workers inherit what opening it imported (alembic, SQLAlchemy's dialect: about
    # half a second of CPU that each worker would pay again)
    open_storage(url, heartbeat_s=heartbeat_s, grace_s=grace_s).engine.dispose()
    ctx = _context()
    forked = ctx.get_start_method() == "fork"
    _preload_stack()  # (matplotlib: a worker imports it when it first draws)
    wakeup = Wakeup(ctx)
    pdir = str(plots_dir) if plots_dir is not None else None
    procs = [ctx.Process(target=_worker_entry, args=(path, url, heartbeat_s, grace_s, os.getpid(), wakeup, pdir),
                         name=f"tuner-worker-{i}") for i in range(workers)]
    saved = _prepare_fork() if forked else None
    try:
        for p in procs:
            p.start()
    finally:
        if forked:
            _after_fork(saved)
    storage = open_storage(url, heartbeat_s=heartbeat_s, grace_s=grace_s)
    stop = threading.Event()
    mon = None
    if progress:
        mon = threading.Thread(target=_progress_loop, args=(study, open_storage(url, heartbeat_s=heartbeat_s,
                                                                                grace_s=grace_s), stop), daemon=True)
        mon.start()
    try:
        for p in procs:
            p.join()
    finally:
        stop.set()
        if mon is not None:
            mon.join(timeout=10)
    return Coordinator(study, storage, observe_only=True).statuses()


def _evaluate_and_plot(study: Any, lp: Any, ctrls: dict[str, Any], inner_bw: float | None, plots_dir: Path | None
                       ) -> tuple[Any, dict[str, Any]]:
    """One loop's re-verification (and its plots): the unit of work of :func:`write_outputs`."""
    from .evaluate import evaluate_loop

    e = evaluate_loop(study, lp, ctrls[lp.name], ctrls, inner_bandwidth_rad_s=inner_bw)
    figs: dict[str, Any] = {}
    if plots_dir is not None:
        from ..analysis.plots import loop_plots

        figs = loop_plots(e, plots_dir, lp.name)  # every plant of the loop, the cascade's between samples
    return e, figs


#: more loops to re-verify than this (none to draw) are spread over the report's processes
POOL_MIN_LOOPS = 16


def _evaluate_all(study: Any, ctrls: dict[str, Any], plots_dir: Path | None, jobs: int,
                  drawn: dict[str, dict[str, Path]] | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
    """Every tuned loop re-verified and plotted (unless ``drawn`` already), inner loops first (an outer
    loop's evaluation needs its inner loop's bandwidth), ``jobs`` loops at a time in forked processes."""
    drawn = drawn or {}
    from concurrent.futures import ProcessPoolExecutor

    from .._process import set_parent_death_signal

    tuned: dict[str, Any] = {}
    figs: dict[str, Any] = {}
    todo = [lp for lp in study.order() if lp.name in ctrls]
    # processes for loops to draw here, or for many loops: a re-verification alone takes about 10 ms (studies/
    # process.toml's loops), and the report's processes about 0.1 s to start and be sent the study; the workers drew
    # every figure they could (at the end of a study run, most often every one)
    to_draw = [lp for lp in todo if plots_dir is not None and lp.name not in drawn]
    # the report's processes end with this one (like the study's workers): an idle one waits on its queue for good
    ex = ProcessPoolExecutor(min(jobs, len(todo)), mp_context=_context(), initializer=set_parent_death_signal) \
        if jobs > 1 and (len(to_draw) > 1 or len(todo) > POOL_MIN_LOOPS) else None
    try:
        while todo:
            wave = [lp for lp in todo if lp.inner is None or lp.inner in tuned]
            if not wave:  # its inner loop has no result
                break
            args = [(study, lp, ctrls, tuned[lp.inner].nominal.metrics.bandwidth_rad_s if lp.inner else None,
                     None if lp.name in drawn else plots_dir) for lp in wave]
            outs = list(ex.map(_evaluate_and_plot, *zip(*args))) if ex is not None and len(wave) > 1 else \
                [_evaluate_and_plot(*a) for a in args]
            for lp, (e, f) in zip(wave, outs):
                tuned[lp.name] = e
                if f or lp.name in drawn:
                    figs[lp.name] = f or drawn[lp.name]
            todo = [lp for lp in todo if lp.name not in tuned]
    finally:
        if ex is not None:
            ex.shutdown()
    return tuned, figs


def write_outputs(study: Any, statuses: dict[str, Any], out_dir: Path, *, storage: str, source: str,
                  plots: bool = True, jobs: int = 1) -> dict[str, Any]:
    """results.json, gains.json, report.md and plots/ from the stored results (re-verified, ``jobs``
    loops at a time)."""
    import io

    from ..fileio import write_output
    from ..jsonio import jsonable
    from .evaluate import evaluate_thesis, gains_entry
    from .report import render_report
    from .schema import controller_of, identified

    make_dir(out_dir, "--out")
    results = {name: (st.result or {"loop": name, "error": "not done"}) for name, st in statuses.items()}
    ctrls = {lp.name: controller_of(lp, results[lp.name]["gains"]) for lp in study.order()
             if "gains" in results[lp.name]}
    plots_dir = out_dir / "plots" if plots else None
    if plots_dir is not None:
        _clear_stale_locks(plots_dir)
    drawn = {} if plots_dir is None else {
        lp.name: f for lp in study.order() if lp.name in ctrls
        and (f := _drawn_early(study, lp, results[lp.name], plots_dir, results)) is not None}
    tuned, figs = _evaluate_all(study, ctrls, plots_dir, jobs, drawn)
    ctrls = {n: c for n, c in ctrls.items() if n in tuned}
    thesis = evaluate_thesis(study, ctrls)
    if plots:
        for lp in study.order():  # the identification of data loops: Bode of data and fit, coherence
            if lp.data is not None and lp.name in figs:
                path = out_dir / "plots" / f"{lp.name}_fit.png"
                buf = io.BytesIO()
                identified(lp).plot().savefig(buf, format="png", dpi=100)
                write_output(path, buf.getvalue())
                figs[lp.name] = {**figs[lp.name], "fit": path}
    doc = {"study": study.name, "file": source, "storage": storage,
           "meets_spec": all(e.meets_spec for e in tuned.values()) and len(tuned) == len(study.loop),
           "order": [lp.name for lp in study.order()], "loops": results,
           "thesis_as_printed": {n: e.to_dict() for n, e in thesis.items()}}
    write_output(out_dir / "results.json", json.dumps(jsonable(doc), indent=2) + "\n")
    gains = {lp.name: gains_entry(lp, results[lp.name]["gains"]) for lp in study.order() if "gains" in results[lp.name]}
    write_output(out_dir / "gains.json", json.dumps(gains, indent=2) + "\n")
    write_output(out_dir / "report.md", render_report(study, results, tuned, thesis, figs, out_dir=out_dir,
                                                      storage=storage))
    return doc


def _cmd_study_run(a: argparse.Namespace) -> int:
    from threadpoolctl import threadpool_limits

    from .runner import default_storage_url, redact
    from .schema import load_study

    study = load_study(a.file)
    if not 1 <= a.workers <= 64:
        raise TunerError("--workers: must be between 1 and 64")
    if a.heartbeat < 1 or a.grace <= a.heartbeat:
        raise TunerError("--heartbeat must be >= 1 s and --grace longer than it")
    out = Path(a.out or os.path.join("results", study.name))
    make_dir(out, "--out")
    url = a.storage or default_storage_url(str(out))
    t0 = time.perf_counter()
    # one worker = one core, as the service's solvers (api._preload): the parallelism is the workers (and the
    # report's processes). Left at OpenBLAS's default pool of two, the verifier's linear algebra between tunes
    # wakes threads that spin on the core the other worker tunes on: on the 280-loop suite two workers' tunes took
    # 38 % longer than one's, 15 % with one thread each (bench/quality_scale.py, one run each; bench/QUALITY.md,
    # "Scale-out"). The study file's plants have loaded numpy's and scipy's OpenBLAS by now (CasADi brings none)
    with threadpool_limits(limits=1):
        # the live progress only where someone watches it (a terminal): elsewhere rich draws nothing until the end,
        # and its thread would read the storage twice a second for nothing; the summary table comes at the end
        statuses = run_study(study, a.file, url, workers=a.workers, heartbeat_s=a.heartbeat, grace_s=a.grace,
                             progress=sys.stderr.isatty(), plots_dir=None if a.no_plots else out / "plots")
        missing = [n for n, s in statuses.items() if s.state != "done"]
        if missing:
            print(f"tuner: study {study.name!r} not finished: {', '.join(missing)} (workers stopped)",
                  file=sys.stderr)
            return 1
        doc = write_outputs(study, statuses, out, storage=redact(url), source=a.file, plots=not a.no_plots,
                            jobs=a.workers)
    _print_summary(doc, time.perf_counter() - t0, out)
    codecache = sys.modules.get("tuner.optimize.nlp.codecache")  # (the workers' NLP shapes, compiled in the background)
    n = codecache.pending() if codecache is not None and codecache.mode() == "auto" else 0
    if n:
        print(f"note: the compiled NLP code of {n} problem shape{'s' if n > 1 else ''} the workers asked for is being "
              "built in the background, once per cache, at low priority; later runs load it. `python -m "
              "tuner.optimize.nlp.codecache --wait` waits for it, TUNER_NLP_COMPILE=load starts no compile",
              file=sys.stderr)
    return 0 if doc["meets_spec"] else 1


def _print_summary(doc: dict[str, Any], wall: float, out: Path) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"study {doc['study']}: {wall:.1f} s", show_header=True)
    for c in ("loop", "structure", "settling [s]", "PM [deg]", "overshoot [%]", "meets spec"):
        t.add_column(c)
    for name in doc["order"]:
        r = doc["loops"][name]
        m = r.get("metrics") or {}
        ok = "[red]ERROR[/red]" if "error" in r else ("[green]yes[/green]" if r.get("meets_spec") else "[red]NO[/red]")
        t.add_row(name, r.get("structure", "?"), _short(m.get("settling_time_s")), _short(m.get("phase_margin_deg")),
                  _short(m.get("overshoot_pct")), ok)
    con = Console(highlight=False)
    con.print(t)
    con.print(f"wrote {out / 'results.json'}, {out / 'gains.json'}, {out / 'report.md'}")


# -- verify ---------------------------------------------------------------------------------------

def _cmd_verify(a: argparse.Namespace) -> int:
    from ..jsonio import jsonable
    from .evaluate import check_gains_file, evaluate_gains
    from .schema import load_study

    study = load_study(a.file)
    from ..fileio import read_json

    data = read_json(a.gains, label=f"--gains {a.gains}", field="gains",
                     hint="give the gains file a study run wrote (UTF-8 JSON)")
    evals = evaluate_gains(study, check_gains_file(study, data, source=a.gains))
    failing = [(n, e.failing) for n, e in evals.items() if not e.meets_spec]
    if a.json:
        print(json.dumps(jsonable({n: e.to_dict() for n, e in evals.items()}), indent=2))
    else:
        _print_verify_table(study, evals)
    if failing:
        print(f"tuner: verify: {len(failing)} loop(s) fail their spec: "
              + "; ".join(f"{n} ({', '.join(f)})" for n, f in failing), file=sys.stderr)
        return 1
    if not a.json:
        print(f"all {len(evals)} loops of study {study.name!r} meet their spec")
    return 0


def _print_verify_table(study: Any, evals: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"tuner verify: study {study.name}", show_header=True)
    for c in ("loop", "structure", "PM [deg]", "GM [dB]", "overshoot [%]", "settling [s]", "ok"):
        t.add_column(c)
    for name, e in evals.items():
        m = e.nominal.metrics
        ts = m.settling_time_s
        if e.cascade is not None:  # the cascade's output between samples, when it is the worse figure
            ts = max(ts, e.cascade.metrics.settling_time_s) if math.isfinite(ts) else ts
        ok = "[green]ok[/green]" if e.meets_spec else "[red]FAIL[/red]"
        t.add_row(name, e.loop.structure, _short(m.phase_margin_deg), _short(m.gain_margin_db),
                  _short(m.overshoot_pct), _short(ts), ok)
    con = Console(highlight=False)
    con.print(t)
    for name, e in evals.items():
        if not e.meets_spec:
            con.print(f"{name}: {e.verdict}", markup=False)


def make_dir(path: Path, option: str) -> None:
    """``path`` as a directory (made with its parents), or a TunerError naming ``option`` (exit 2): an existing
    file, a path under a file (``/dev/null/x``), a place that cannot hold one (``/proc/x``), no permission."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise TunerError(f"{option} {path}: a file of that name exists; give a directory") from None
    except OSError as e:
        raise TunerError(f"{option} {path}: cannot make the directory: {e.strerror or e}") from None
    if not path.is_dir():
        raise TunerError(f"{option} {path}: not a directory")
