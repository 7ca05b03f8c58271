"""How the service is started: ``python -m api [--host 127.0.0.1] [--port 8000]`` (what the README and the Dockerfile
run), uvicorn with the limits a service facing clients needs, decided before it listens:

* **Closed by default.** On an address other than loopback (``0.0.0.0``, ``::``, a LAN address, a name other than
  ``localhost``) it does not start without ``TUNER_API_KEY``, unless ``TUNER_ALLOW_NO_KEY=1`` says so (logged at
  start: anyone who reaches the address can then tune and read every stored result and log). The app refuses the
  same per connection (``api.guard``), however it is started.
* **A deadline for request headers** (``TUNER_HEADER_TIMEOUT_S``, 10 s): uvicorn has none (its keep-alive timeout
  stops at the first byte of a request), so a client that opens a connection and never finishes its headers held
  it for good. :class:`HeaderDeadlineH11` (uvicorn's h11 protocol) closes a connection whose request headers are
  not complete that long after it opened or after its last answer (408, then closed).
* **A cap on connections** (``TUNER_MAX_CONNECTIONS``, 512): a connection beyond it is answered 503 and closed at
  once, before its headers are read (each open connection holds a file descriptor and memory).

Plain ``uvicorn api.main:create_app --factory`` still works (with the per-connection key rule); to have the header
deadline and the cap there too, add ``--http api.server:HeaderDeadlineH11``, or put a proxy in front that has a
header timeout (nginx: ``client_header_timeout``).
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Any

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

from .guard import is_loopback

__all__ = ["HeaderDeadlineH11", "is_loopback", "main"]

log = logging.getLogger("api")


class HeaderDeadlineH11(H11Protocol):
    """uvicorn's h11 protocol with a deadline for request headers and a cap on open connections (see the module's
    notes); the limits are class attributes, set from the settings by :func:`main` (or read from ``TUNER_*`` at
    import when uvicorn is given this class with ``--http``)."""

    header_timeout_s: float = 10.0
    max_connections: int = 512

    def connection_made(self, transport: Any) -> None:
        super().connection_made(transport)
        self._deadline = None
        if len(self.connections) > self.max_connections:
            transport.write(_raw(503, "Service Unavailable", "too many open connections; retry", b"retry-after: 5\r\n"))
            transport.close()
            return
        self._arm()

    def _arm(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
        self._deadline = self.loop.call_later(self.header_timeout_s, self._headers_late)

    def _headers_late(self) -> None:
        """The deadline: a connection still waiting for a request's headers is answered 408 and closed."""
        self._deadline = None
        if self.transport.is_closing() or self.conn.their_state is not h11.IDLE:
            return  # closed, or a request is being read or answered (its body has a deadline of its own)
        if self.cycle is not None and not self.cycle.response_complete:
            return
        self.transport.write(_raw(408, "Request Timeout", f"the request headers did not arrive within "
                                                          f"{self.header_timeout_s:g} s (TUNER_HEADER_TIMEOUT_S)"))
        self.transport.close()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing():
            self._arm()  # the next request's headers, on a kept-alive connection

    def connection_lost(self, exc: Exception | None) -> None:
        if getattr(self, "_deadline", None) is not None:
            self._deadline.cancel()
            self._deadline = None
        super().connection_lost(exc)


def _raw(status: int, reason: str, text: str, extra: bytes = b"") -> bytes:
    """A whole HTTP/1.1 answer, written before any request was parsed (h11 has none to answer)."""
    body = (text + "\n").encode()
    return (f"HTTP/1.1 {status} {reason}\r\ncontent-type: text/plain; charset=utf-8\r\nconnection: close\r\n"
            f"content-length: {len(body)}\r\n").encode() + extra + b"\r\n" + body


def _configure(settings: Any) -> None:
    HeaderDeadlineH11.header_timeout_s = settings.header_timeout_s
    HeaderDeadlineH11.max_connections = settings.max_connections


def main(argv: list[str] | None = None) -> int:
    """``python -m api``: check the address against the key, then run uvicorn with :class:`HeaderDeadlineH11`."""
    ap = argparse.ArgumentParser(prog="python -m api", description=__doc__.split("\n\n")[0])
    ap.add_argument("--host", default="127.0.0.1", help="address to listen on (127.0.0.1)")
    ap.add_argument("--port", type=int, default=8000, help="port (8000)")
    ap.add_argument("--proxy-headers", action=argparse.BooleanOptionalAction, default=True,
                    help="take the client's address from X-Forwarded-For when a trusted proxy sends it (uvicorn's "
                         "default: on, trusting 127.0.0.1 unless --forwarded-allow-ips says otherwise)")
    ap.add_argument("--forwarded-allow-ips", default=None, metavar="IPS",
                    help="the proxies whose X-Forwarded-For is trusted (comma-separated; uvicorn's default 127.0.0.1)")
    ap.add_argument("--log-level", default="info", choices=("critical", "error", "warning", "info", "debug"))
    a = ap.parse_args(argv)
    from pydantic import ValidationError

    from .settings import Settings

    try:
        settings = Settings()
    except ValidationError as e:
        err = e.errors(include_url=False)[0]
        print(f"python -m api: error: TUNER_{str(err['loc'][0]).upper()}: {err['msg']}", file=sys.stderr)
        return 2
    if settings.api_key is None and not settings.allow_no_key and not is_loopback(a.host):
        print(f"python -m api: error: --host {a.host} is not a loopback address and TUNER_API_KEY is not set: anyone "
              "who reaches it could tune, and read every stored result and log. Set TUNER_API_KEY (clients send it as "
              "X-API-Key), listen on 127.0.0.1, or set TUNER_ALLOW_NO_KEY=1 to serve without a key on purpose",
              file=sys.stderr)
        return 2
    _configure(settings)
    import uvicorn

    uvicorn.run("api.main:create_app", factory=True, host=a.host, port=a.port, http=HeaderDeadlineH11,
                proxy_headers=a.proxy_headers, forwarded_allow_ips=a.forwarded_allow_ips, log_level=a.log_level,
                timeout_keep_alive=5)
    return 0


def _from_environment() -> None:
    """The limits from ``TUNER_*`` when uvicorn imports the class itself (``--http api.server:HeaderDeadlineH11``)."""
    try:
        from .settings import Settings

        _configure(Settings())
    except Exception:  # (the app reports bad settings itself, when it starts)
        pass


_from_environment()
