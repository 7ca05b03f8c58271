"""Drawn plots, kept per key (result id, kind and format) (a stored result never changes, nor does its plot).

Concurrent requests for a plot that is being drawn wait for that one drawing instead of
starting their own; the cache is bounded in bytes (least recently used plots go first).
"""

from __future__ import annotations

import asyncio
import collections
from collections.abc import Awaitable, Callable

__all__ = ["PlotCache"]


class PlotCache:
    """An in-memory LRU of images, with the drawings in progress shared."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max(0, int(max_bytes))
        self._items: collections.OrderedDict[tuple[str, ...], bytes] = collections.OrderedDict()
        self._bytes = 0
        self._drawing: dict[tuple[str, ...], asyncio.Future[bytes]] = {}  # drawings in progress
        self.hits = 0
        self.misses = 0

    def get(self, key: tuple[str, ...]) -> bytes | None:
        data = self._items.get(key)
        if data is not None:
            self._items.move_to_end(key)
        return data

    def _put(self, key: tuple[str, ...], data: bytes) -> None:
        if len(data) > self.max_bytes:
            return
        self._items[key] = data
        self._bytes += len(data)
        while self._bytes > self.max_bytes:
            _, old = self._items.popitem(last=False)
            self._bytes -= len(old)

    async def get_or_draw(self, key: tuple[str, ...], draw: Callable[[], Awaitable[bytes]]) -> bytes:
        """The cached image, else the drawing in progress, else a new drawing (whose errors propagate).

        The drawing is a task of its own: a requester that goes away does not stop it for the others."""
        data = self.get(key)
        if data is not None:
            self.hits += 1
            return data
        task = self._drawing.get(key)
        if task is None:
            self.misses += 1
            task = asyncio.ensure_future(self._draw_and_keep(key, draw))
            self._drawing[key] = task
        else:
            self.hits += 1
        return await asyncio.shield(task)

    async def _draw_and_keep(self, key: tuple[str, ...], draw: Callable[[], Awaitable[bytes]]) -> bytes:
        try:
            data = await draw()
        finally:
            del self._drawing[key]
        self._put(key, data)
        return data

    def stats(self) -> dict[str, int]:
        return {"items": len(self._items), "bytes": self._bytes, "hits": self.hits, "misses": self.misses}
