"""Separately started ``tuner study run`` workers for the distributed-study tests (shared helper)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

__all__ = ["start_worker", "finish_worker", "worker_ids"]


def start_worker(f: Path, url: str, out: Path) -> subprocess.Popen:
    """One worker on study file ``f`` and storage ``url``, results in ``out``; its output goes to ``out``'s
    ``.log`` file, which the test reads at the end (and which stays there to read, whatever happens)."""
    cmd = [sys.executable, "-m", "tuner.cli", "study", "run", str(f), "--storage", url, "--out", str(out),
           "--heartbeat", "1", "--grace", "4", "--no-plots"]
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.parent / f"{out.name}.log", "w") as log:
        return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT,
                                env={**os.environ, "PYTHONPATH": str(ROOT)})


def finish_worker(p: subprocess.Popen, out: Path, timeout: float) -> str:
    """Wait for the worker writing to ``out``; what it printed (a worker still running at ``timeout`` fails the test
    with the end of its output)."""
    try:
        p.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        pytest.fail(f"the worker did not finish in {timeout} s; its output ends:\n"
                    f"{(out.parent / f'{out.name}.log').read_text()[-3000:]}")
    return (out.parent / f"{out.name}.log").read_text()


def worker_ids(p: subprocess.Popen) -> set[str]:
    """The ids (``host:pid``) under which a ``tuner study run`` command's workers claim loops: its child processes
    (every worker count forks its workers, the single one included); empty once it has ended."""
    try:
        kids = Path(f"/proc/{p.pid}/task/{p.pid}/children").read_text().split()
    except OSError:
        return set()
    return {f"{socket.gethostname()}:{k}" for k in kids}
