"""A real uvicorn process serving the app on a free loopback port, for end-to-end and browser tests.

``python -m api --host 127.0.0.1 --port P`` (the documented command: uvicorn with the header deadline and the
connection cap of :mod:`api.server`) in its own process group, with the settings given as ``TUNER_*`` environment
variables; :meth:`Server.stop` sends SIGTERM and checks that nothing of the service (solver processes included) is
left.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx

__all__ = ["Server", "serving", "free_port", "ROOT"]

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """``python -m api`` in its own process group, settings by environment."""

    def __init__(self, tmp: Path, env: dict[str, str]) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log_path = tmp / f"server-{self.port}.log"
        full_env = {k: v for k, v in os.environ.items() if not k.startswith("TUNER_")}
        # (but the suite's NLP compile mode: no background gcc from a test's server, conftest.py)
        full_env["TUNER_NLP_COMPILE"] = os.environ.get("TUNER_NLP_COMPILE", "off")
        full_env.update(env)
        self.log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "api", "--host", "127.0.0.1", "--port", str(self.port)],
            cwd=ROOT, env=full_env, stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True)

    def wait_ready(self, timeout_s: float = 120.0, *, workers: bool = True) -> None:
        """Until /health answers (and, with ``workers``, every solver process is up)."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            assert self.proc.poll() is None, self.output()
            try:
                w = httpx.get(f"{self.url}/health", timeout=2).json()["workers"]
                if not workers or w["ready"] == w["size"]:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.1)
        raise TimeoutError(self.output())

    def stop(self) -> bool:
        """SIGTERM to the server (what a process manager sends); True if it and its solvers all exited."""
        clean = True
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                clean = False
                self.proc.kill()  # it ignored SIGTERM: a failure, but not one left running after the test
        self.proc.wait(10)
        end = time.monotonic() + 10
        while True:  # anything left in the group (solver processes) after 10 s is a leak
            try:
                os.killpg(self.proc.pid, 0)
            except ProcessLookupError:
                break
            if time.monotonic() > end:
                os.killpg(self.proc.pid, signal.SIGKILL)
                clean = False
                break
            time.sleep(0.1)
        self.log.close()
        return clean

    def pids(self) -> set[int]:
        """Every live process of the server's session (uvicorn, the forkserver, the solver processes)."""
        out = set()
        for name in os.listdir("/proc"):
            if name.isdigit():
                try:
                    alive = Path(f"/proc/{name}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
                    if alive and os.getsid(int(name)) == self.proc.pid:
                        out.add(int(name))
                except OSError:  # gone meanwhile
                    pass
        return out

    def output(self) -> str:
        if not self.log.closed:
            self.log.flush()
        return self.log_path.read_text(errors="replace")


@contextmanager
def serving(tmp: Path, env: dict[str, str]) -> Iterator[Server]:
    """A started server (every solver up) for the ``with`` block; stopped afterwards."""
    server = Server(tmp, env)
    try:
        server.wait_ready()
        yield server
    finally:
        server.stop()
