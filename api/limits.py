"""Plain ASGI middleware: the request-body size cap, and ``HEAD`` on every ``GET`` route.

:class:`BodySizeLimit`: a declared ``Content-Length`` above the cap is refused at once; a body
sent without one (chunked) is counted as it arrives and refused as soon as it passes the cap.
Either way: 413 with a JSON body. Accepted bodies are replayed to the app. ``path_limits``
gives some paths a cap of their own (e.g. ``/identify``, whose bodies are flight logs); every
other path has ``max_bytes``.

:class:`HeadAsGet`: FastAPI's routes answer ``HEAD`` with 405; this answers it as the ``GET`` of
the same URL would (status and headers, ``Content-Length`` included), without the body.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

__all__ = ["BodySizeLimit", "HeadAsGet"]


_RECORD_PATHS = frozenset({"/identify"})  # bodies that carry a flight record (their 413 says how to send more)


class BodySizeLimit:
    def __init__(self, app: Callable[..., Any], *, max_bytes: int, path_limits: dict[str, int] | None = None) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.path_limits = dict(path_limits or {})

    async def __call__(self, scope: dict[str, Any], receive: Callable[..., Any], send: Callable[..., Any]) -> None:
        if scope["type"] != "http" or scope["method"] in ("GET", "HEAD", "OPTIONS", "DELETE"):
            await self.app(scope, receive, send)
            return
        cap = self.path_limits.get(scope.get("path", ""), self.max_bytes)
        for name, value in scope.get("headers", ()):
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    declared = -1
                if declared > cap:
                    await self._refuse(send, cap, scope.get("path", ""))
                    return
        chunks: list[bytes] = []
        size = 0
        while True:
            msg = await receive()
            if msg["type"] == "http.disconnect":
                return
            body = msg.get("body", b"")
            size += len(body)
            if size > cap:
                await self._refuse(send, cap, scope.get("path", ""))
                return
            chunks.append(body)
            if not msg.get("more_body", False):
                break
        data = b"".join(chunks)
        replayed = False

        async def replay() -> dict[str, Any]:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": data, "more_body": False}
            return await receive()

        await self.app(scope, replay, send)

    async def _refuse(self, send: Callable[..., Any], cap: int, path: str = "") -> None:
        more = (": samples that many go as a ULog upload (ulog.data, base64), a longer log through the command "
                "line ('tuner identify', the same record limit)") if path in _RECORD_PATHS else ""
        body = json.dumps({"detail": f"request body larger than {cap} bytes{more}"}).encode()
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                                (b"connection", b"close")]})
        await send({"type": "http.response.body", "body": body})


class HeadAsGet:
    def __init__(self, app: Callable[..., Any]) -> None:
        self.app = app

    async def __call__(self, scope: dict[str, Any], receive: Callable[..., Any], send: Callable[..., Any]) -> None:
        if scope["type"] != "http" or scope["method"] != "HEAD":
            await self.app(scope, receive, send)
            return

        async def send_headers_only(msg: dict[str, Any]) -> None:
            if msg["type"] == "http.response.body":
                if not msg.get("more_body", False):
                    await send({"type": "http.response.body", "body": b"", "more_body": False})
                return
            await send(msg)

        await self.app({**scope, "method": "GET"}, receive, send_headers_only)
