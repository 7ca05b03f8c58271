"""The Dockerfile, without a Docker engine (none runs on these machines).

What the image would do is done here for real: its COPY lines build a fresh source
directory, its ``RUN pip install`` line runs in a fresh virtual environment, its ``CMD``
starts the service (from an empty working directory, so the installed package is what
runs), and its ``HEALTHCHECK`` command must succeed against it. The rest of the file is
checked as text: slim Python base, non-root user, the exposed port.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCKERFILE = ROOT / "Dockerfile"


def instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with line continuations joined and comments dropped."""
    text = re.sub(r"\\\n", " ", DOCKERFILE.read_text())
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            op, _, args = line.partition(" ")
            out.append((op.upper(), args.strip()))
    return out


def one(op: str) -> str:
    found = [a for o, a in instructions() if o == op]
    assert len(found) == 1, f"expected one {op}, found {found}"
    return found[0]


def env_vars() -> dict[str, str]:
    env: dict[str, str] = {}
    for op, args in instructions():
        if op == "ENV":
            for item in shlex.split(args):
                k, _, v = item.partition("=")
                env[k] = v
    return env


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_dockerfile_shape():
    assert one("FROM") == "python:3.11-slim"
    user = one("USER")
    assert user not in ("root", "0") and any(o == "RUN" and "useradd" in a and user in a for o, a in instructions())
    assert one("EXPOSE") == "8000"
    cmd = json.loads(one("CMD"))
    assert cmd[:4] == ["python", "-m", "api", "--host"] and cmd[-2:] == ["--port", "8000"]
    hc = one("HEALTHCHECK")
    assert "CMD" in hc and "http://127.0.0.1:8000/health" in hc
    readme = (ROOT / "README.md").read_text()
    assert ".venv/bin/python -m api --host 127.0.0.1 --port 8000" in readme  # the one documented start command
    # the documented docker run publishes on this machine only, with the explicit opt-in the image needs
    assert "docker run -p 127.0.0.1:8000:8000 -e TUNER_ALLOW_NO_KEY=1 -v tuner-data:/data tuner" in readme
    assert "docker run -p 127.0.0.1:8000:8000 -e TUNER_ALLOW_NO_KEY=1 -v tuner-data:/data tuner" in \
        DOCKERFILE.read_text()


@pytest.mark.slow
@pytest.mark.timeout(1200)  # a pip install into a fresh environment (bounded by its own 900 s below), then the start
def test_install_and_start_as_the_image_would(tmp_path):
    # the build context: what the COPY lines take
    src = tmp_path / "src"
    src.mkdir()
    for op, args in instructions():
        if op == "COPY":
            *sources, _dest = shlex.split(args)
            for s in sources:
                p = ROOT / s
                if p.is_dir():
                    shutil.copytree(p, src / s, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
                else:
                    shutil.copy2(p, src / s)
    # the install: the RUN line's pip command, in a fresh virtual environment
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    bindir = venv / "bin"
    (run_pip,) = [a for o, a in instructions() if o == "RUN" and "pip install" in a]
    pip_cmd = shlex.split(run_pip.split("&&")[0])
    assert pip_cmd[:2] == ["pip", "install"] and pip_cmd[-1] == "."
    subprocess.run([str(bindir / "python"), "-m", *pip_cmd, "-q"], cwd=src, check=True, timeout=900)

    # the start: CMD from an empty working directory (no source tree to import from), on loopback
    data = tmp_path / "data"
    data.mkdir()
    port = free_port()
    cmd = json.loads(one("CMD"))
    cmd[0] = str(bindir / cmd[0])
    cmd[cmd.index("--host") + 1] = "127.0.0.1"
    cmd[cmd.index("--port") + 1] = str(port)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("TUNER_", "PYTHON"))}
    env.update(env_vars())
    env["TUNER_NLP_COMPILE"] = os.environ.get("TUNER_NLP_COMPILE", "off")  # (no background gcc from a test)
    env.update(TUNER_DATABASE_URL=f"sqlite:///{data / 'tuner.db'}", TUNER_WORKERS="1",
               PATH=f"{bindir}{os.pathsep}{env.get('PATH', '')}")
    log = open(tmp_path / "server.log", "wb")
    proc = subprocess.Popen(cmd, cwd=data, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        url = f"http://127.0.0.1:{port}/health"
        body = None
        for _ in range(600):
            assert proc.poll() is None, (tmp_path / "server.log").read_text()
            try:
                with urllib.request.urlopen(url, timeout=2) as r:
                    body = json.loads(r.read())
                    break
            except OSError:
                time.sleep(0.1)
        assert body is not None, "no answer from /health"
        assert body["status"] == "ok" and body["database"] == "ok"
        assert body["versions"]["tuner"]
        # the image's HEALTHCHECK command, as written, against this server
        hc = one("HEALTHCHECK")
        check = shlex.split(hc[hc.index("CMD") + 3:].replace("127.0.0.1:8000", f"127.0.0.1:{port}"))
        assert check[0] == "python"
        check[0] = str(bindir / "python")
        assert subprocess.run(check, env=env, timeout=30).returncode == 0
        # it is the installed package that runs, not the source tree
        where = subprocess.run([str(bindir / "python"), "-c", "import api; print(api.__file__)"], cwd=data,
                               env=env, capture_output=True, text=True, check=True).stdout
        assert str(venv) in where
        assert (data / "tuner.db").exists()
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
        log.close()


def test_the_image_does_not_start_without_a_key_or_the_opt_in(tmp_path):
    """Issue 42: the image started with no key on 0.0.0.0. Its CMD, with its ENV and nothing else, refuses to start
    (the documented docker run gives TUNER_ALLOW_NO_KEY=1, and publishes on 127.0.0.1 only)."""
    cmd = json.loads(one("CMD"))
    assert cmd[cmd.index("--host") + 1] == "0.0.0.0"
    env = {k: v for k, v in os.environ.items() if not k.startswith(("TUNER_", "PYTHON"))}
    env.update(env_vars())
    env["TUNER_NLP_COMPILE"] = os.environ.get("TUNER_NLP_COMPILE", "off")  # (no background gcc from a test)
    env["TUNER_DATABASE_URL"] = f"sqlite:///{tmp_path / 'tuner.db'}"
    p = subprocess.run([sys.executable, *cmd[1:]], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and "TUNER_API_KEY is not set" in p.stderr, (p.returncode, p.stderr)
