"""A body that never arrives does not hold a connection (issue 21): a real uvicorn on loopback, a raw socket
declaring ``Content-Length: 1000`` and sending 1 byte gets 408 and is closed after ``TUNER_BODY_TIMEOUT_S``."""

from __future__ import annotations

import socket

import pytest
from uvicorn_server import serving

pytestmark = pytest.mark.slow


def test_a_stalled_body_is_answered_408_and_the_connection_closed(tmp_path):
    env = {"TUNER_DATABASE_URL": f"sqlite:///{tmp_path / 'tuner.db'}", "TUNER_WORKERS": "1",
           "TUNER_BODY_TIMEOUT_S": "1"}
    with serving(tmp_path, env) as server:
        with socket.create_connection(("127.0.0.1", server.port), timeout=60) as s:  # 60 s: only a hang guard
            s.sendall(b"POST /tune HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                      b"Content-Length: 1000\r\n\r\n{")
            answer = b""
            while chunk := s.recv(4096):  # until the server closes the connection
                answer += chunk
        assert answer.startswith(b"HTTP/1.1 408"), answer
        assert b"TUNER_BODY_TIMEOUT_S" in answer
        # and an ordinary request still works on a new connection
        with socket.create_connection(("127.0.0.1", server.port), timeout=60) as s:
            s.sendall(b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
            assert s.recv(4096).startswith(b"HTTP/1.1 200")
