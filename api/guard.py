"""The outermost ASGI middleware: what is decided from the request line and headers, before any body is read.

In order, for every HTTP request:

0. **No key, loopback only**: without ``TUNER_API_KEY`` (and without ``TUNER_ALLOW_NO_KEY=1``), a request that
   reached the service on an address other than loopback (its connection's local address: a container's or a
   machine's LAN address) gets 403, ``/health`` excepted. A client that sets ``Host: localhost`` itself passes the
   host allow-list; it does not change the address it connected to.
1. **Host allow-list** (``TUNER_ALLOWED_HOSTS``, loopback by default): another ``Host`` gets 400.
   Without it a page on another site could reach a service on 127.0.0.1 by DNS rebinding (the
   browser then sends that site's name as ``Host``). ``*`` allows any host (behind a proxy that
   checks it).
2. **API key** (when ``TUNER_API_KEY`` is set): every path but the public ones (the page and its
   assets, ``/health``, ``/docs``, ``/redoc``, ``/openapi.json``) needs a matching ``X-API-Key``;
   otherwise 401 at once, the body unread (the routes check it again, as a dependency).
3. **Per-client limit**: a ``POST`` to a route that runs in the solver pool, from a client that
   already has as many jobs waiting as it may, gets 429 with ``Retry-After`` at once, the body unread.
4. **Body read timeout** (``TUNER_BODY_TIMEOUT_S``): the whole body must arrive within that time
   from the start of the request, else 408 and the connection is closed (a client declaring
   1000 bytes and sending 1 does not hold a connection open).

Every answer gets ``X-Content-Type-Options: nosniff``, every answer behind the key
``Cache-Control: private`` (``public`` is made ``private``); ``/docs`` and ``/redoc`` get a
``Content-Security-Policy`` that allows only what their pages load from this server (their inline
script by its hash; ReDoc's styles and its worker).
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import ipaddress
import json
import logging
import re
import secrets
import time
from collections.abc import Callable
from typing import Any

__all__ = ["Guard", "PUBLIC_PATHS", "PUBLIC_PREFIXES", "POOL_PATHS", "docs_csp", "host_name", "is_loopback"]

log = logging.getLogger("api")

PUBLIC_PATHS = frozenset({"/", "/health", "/docs", "/docs/oauth2-redirect", "/redoc", "/openapi.json"})
PUBLIC_PREFIXES = ("/web/", "/static-offline-docs/")
POOL_PATHS = frozenset({"/tune", "/analyze", "/identify", "/ulog/signals"})  # POSTs that wait for a solver
DOCS_PATHS = frozenset({"/docs", "/docs/oauth2-redirect", "/redoc"})

_INLINE = re.compile(rb"<(script|style)>(.*?)</\1>", re.S)


def docs_csp(html: bytes) -> str:
    """The policy of a docs page: its own inline ``<script>``/``<style>`` blocks by hash, the rest from self."""
    hashes = {"script": [], "style": []}
    for kind, body in _INLINE.findall(html):
        digest = base64.b64encode(hashlib.sha256(body).digest()).decode()
        hashes[kind.decode()].append(f"'sha256-{digest}'")
    scripts = " ".join(["'self'", *hashes["script"]])
    # Swagger UI and ReDoc set style attributes and ReDoc inserts <style> elements: styles need 'unsafe-inline'
    # (a style cannot run code); ReDoc searches in a worker it starts from a blob: URL
    return (f"default-src 'self'; script-src {scripts}; style-src 'self' 'unsafe-inline'; img-src 'self' data: "
            "blob:; worker-src 'self' blob:; connect-src 'self'; font-src 'self' data:; object-src 'none'; "
            "base-uri 'none'; frame-ancestors 'none'; form-action 'self'")


def host_name(value: str) -> str:
    """The host of a ``Host`` header, without the port (``[::1]:8000`` -> ``::1``), lower case."""
    v = value.strip().lower()
    if v.startswith("["):
        return v[1:v.find("]")] if "]" in v else v
    if v.count(":") == 1:
        return v.split(":", 1)[0]
    return v


def _headers(scope: dict[str, Any]) -> dict[bytes, bytes]:
    return {k.lower(): v for k, v in scope.get("headers", ())}


class _BodyTimeout(Exception):
    pass


class Guard:
    def __init__(self, app: Callable[..., Any], *, allowed_hosts: frozenset[str] | None, api_key: str | None,
                 body_timeout_s: float, client_of: Callable[[str, str | None], str] | None = None,
                 pool_of: Callable[[], Any] | None = None, loopback_only: bool = False) -> None:
        self.app = app
        self.loopback_only = loopback_only  # no key and no opt-in: answer connections to loopback addresses only
        self._said = False
        self.allowed_hosts = allowed_hosts  # None: any
        self.api_key = api_key.encode() if api_key is not None else None
        self.body_timeout_s = body_timeout_s
        self.client_of = client_of
        self.pool_of = pool_of

    async def __call__(self, scope: dict[str, Any], receive: Callable[..., Any], send: Callable[..., Any]) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        path = scope.get("path", "")
        headers = _headers(scope)
        send = self._headered(send, path)
        if self.loopback_only and path != "/health" and not _local(scope.get("server")):
            if not self._said:  # (once: a scan of the address would fill the log)
                self._said = True
                log.warning("a request to %s on %s refused: no TUNER_API_KEY, and only connections to a loopback "
                            "address are answered (TUNER_ALLOW_NO_KEY=1 to serve others without a key)", path,
                            scope["server"][0])
            await _answer(send, 403, "this service has no API key and answers only on its loopback address; its "
                                     "operator sets TUNER_API_KEY (then send it as X-API-Key), or TUNER_ALLOW_NO_KEY=1")
            return
        n_keys = sum(1 for k, _ in scope.get("headers", ()) if k.lower() == b"x-api-key")
        if n_keys > 1:  # one credential, read once: the guard and the route must not read different ones
            await _answer(send, 400, f"{n_keys} X-API-Key headers: send exactly one")
            return
        if self.allowed_hosts is not None:
            host = host_name(headers.get(b"host", b"").decode("latin-1"))
            if host not in self.allowed_hosts:
                await _answer(send, 400, f"Host {host!r} is not served here; allowed: "
                                         f"{', '.join(sorted(self.allowed_hosts))} (TUNER_ALLOWED_HOSTS)")
                return
        key = headers.get(b"x-api-key")
        if self.api_key is not None and not _public(path) and (
                key is None or not secrets.compare_digest(key, self.api_key)):
            await _answer(send, 401, "missing or invalid X-API-Key header", [(b"www-authenticate", b"X-API-Key")])
            return
        if scope.get("method") == "POST" and path in POOL_PATHS and self.client_of and self.pool_of:
            pool = self.pool_of()
            client = self.client_of(scope["client"][0] if scope.get("client") else "unknown",
                                    key.decode("latin-1") if key else None)
            if pool is not None and pool.would_refuse(client):
                retry = pool.retry_after_s(client)
                await _answer(send, 429, f"this client already has as many jobs waiting as it may; retry after "
                                         f"{retry} s", [(b"retry-after", str(retry).encode())])
                return
        started = [False]

        async def tracked(msg: dict[str, Any]) -> None:
            if msg["type"] == "http.response.start":
                started[0] = True
            await send(msg)

        try:
            await self.app(scope, self._timed(receive), tracked)
        except _BodyTimeout:
            if not started[0]:
                await _answer(send, 408, f"the request body did not arrive within {self.body_timeout_s:g} s "
                                         "(TUNER_BODY_TIMEOUT_S)")

    def _timed(self, receive: Callable[..., Any]) -> Callable[..., Any]:
        """``receive`` with a deadline until the body is complete (afterwards, e.g. waiting for a disconnect
        while a solve runs, it is not limited)."""
        end = time.monotonic() + self.body_timeout_s
        complete = [False]

        async def timed() -> dict[str, Any]:
            if complete[0]:
                return await receive()
            try:
                msg = await asyncio.wait_for(receive(), max(0.0, end - time.monotonic()))
            except TimeoutError:
                raise _BodyTimeout from None
            if msg["type"] != "http.request" or not msg.get("more_body", False):
                complete[0] = True
            return msg

        return timed

    def _headered(self, send: Callable[..., Any], path: str) -> Callable[..., Any]:
        docs = path in DOCS_PATHS
        protected = self.api_key is not None and not _public(path)
        held: list[dict[str, Any]] = []

        async def headered(msg: dict[str, Any]) -> None:
            if msg["type"] == "http.response.start":
                hs = [(k, v) for k, v in msg.get("headers", ()) if k.lower() != b"x-content-type-options"]
                hs.append((b"x-content-type-options", b"nosniff"))
                if protected:  # an answer behind the key is never kept by a shared cache
                    cc = [v for k, v in hs if k.lower() == b"cache-control"]
                    hs = [(k, v) for k, v in hs if k.lower() != b"cache-control"]
                    hs.append((b"cache-control", cc[0].replace(b"public", b"private") if cc else b"private"))
                msg = {**msg, "headers": hs}
                if docs:  # the policy depends on the page's inline script: hold the start until the body is in
                    held.append(msg)
                    return
            elif msg["type"] == "http.response.body" and held:
                held.append(msg)
                if msg.get("more_body", False):
                    return
                body = b"".join(m.get("body", b"") for m in held[1:])
                start = held[0]
                hs = [*start["headers"], (b"content-security-policy", docs_csp(body).encode())]
                held.clear()
                await send({**start, "headers": hs})
                await send({"type": "http.response.body", "body": body})
                return
            await send(msg)

        return headered


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or a name to listen on, or a connection's local address) is loopback only:
    ``127.0.0.0/8``, ``::1`` (also as ``::ffff:127.0.0.1``), ``localhost``. ``0.0.0.0`` and ``::`` are every
    address, not loopback."""
    h = host.strip().strip("[]").lower()
    if h in ("localhost", "localhost.", "ip6-localhost"):
        return True
    try:
        ip = ipaddress.ip_address(h.split("%", 1)[0])
    except ValueError:
        return False
    mapped = getattr(ip, "ipv4_mapped", None)
    return bool((mapped or ip).is_loopback)


def _local(server: Any) -> bool:
    """Whether a connection's local address (ASGI ``server``) is loopback; a name that is no address (a Unix socket,
    a test client's) is local: only this machine reaches it."""
    if not server:
        return True
    try:
        ipaddress.ip_address(str(server[0]).split("%", 1)[0])
    except ValueError:
        return True
    return is_loopback(str(server[0]))


def _public(path: str) -> bool:
    return path in PUBLIC_PATHS or path.startswith(PUBLIC_PREFIXES)


async def _answer(send: Callable[..., Any], status: int, detail: str,
                  extra: list[tuple[bytes, bytes]] | None = None) -> None:
    body = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close"), *(extra or [])]})
    await send({"type": "http.response.body", "body": body})
