"""What a service facing clients needs before any request is read (issue 42, item 4), on a real server started as
documented (``python -m api``) on loopback, with raw sockets:

* a deadline for request headers: a connection that never finishes its headers (or sends nothing) gets 408 and is
  closed (before: 300 such connections were still open after 90 s; uvicorn has no header timeout);
* a cap on open connections: one beyond it is answered 503 and closed at once;
* closed by default: ``python -m api`` does not start on a non-loopback address without a key.
"""

from __future__ import annotations

import http.client
import os
import socket
import subprocess
import sys

import pytest
from uvicorn_server import ROOT, serving

pytestmark = pytest.mark.slow


def _until_closed(s: socket.socket) -> bytes:
    answer = b""
    while chunk := s.recv(4096):  # until the server closes the connection (the socket's timeout: a hang guard)
        answer += chunk
    return answer


def test_unfinished_headers_get_408_and_the_cap_turns_extra_connections_away(tmp_path):
    env = {"TUNER_DATABASE_URL": f"sqlite:///{tmp_path / 'tuner.db'}", "TUNER_WORKERS": "1",
           "TUNER_HEADER_TIMEOUT_S": "1", "TUNER_MAX_CONNECTIONS": "4"}
    with serving(tmp_path, env) as server:
        addr = ("127.0.0.1", server.port)
        slow = [socket.create_connection(addr, timeout=60) for _ in range(4)]
        for s in slow[:3]:  # headers begun, never finished
            s.sendall(b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
        # (the fourth sends nothing at all)
        with socket.create_connection(addr, timeout=60) as extra:  # the fifth: beyond the cap
            assert _until_closed(extra).startswith(b"HTTP/1.1 503"), "a connection beyond the cap was served"
        for s in slow:
            answer = _until_closed(s)
            s.close()
            assert answer.startswith(b"HTTP/1.1 408") and b"TUNER_HEADER_TIMEOUT_S" in answer, answer
        # the slots are free again: an ordinary request, and two on one kept-alive connection
        c = http.client.HTTPConnection(*addr, timeout=60)
        for _ in range(2):
            c.request("GET", "/health")
            r = c.getresponse()
            assert r.status == 200 and r.read()
        c.close()


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "10.1.2.3"])
def test_no_start_on_a_non_loopback_address_without_a_key(host, tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("TUNER_")}
    env["TUNER_DATABASE_URL"] = f"sqlite:///{tmp_path / 'tuner.db'}"
    p = subprocess.run([sys.executable, "-m", "api", "--host", host, "--port", "9"], env=env, cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert f"--host {host} is not a loopback address and TUNER_API_KEY is not set" in p.stderr, p.stderr
    assert "TUNER_ALLOW_NO_KEY=1" in p.stderr and "Traceback" not in p.stderr
