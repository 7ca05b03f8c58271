"""api.disconnect: a solve whose client has gone is cancelled, and the route answers 499.

(In a real server, with the browser's Cancel button: tests/e2e/test_page_browser.py.)"""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

import pytest
from fastapi.testclient import TestClient

from api.disconnect import CLIENT_CLOSED_REQUEST, ClientDisconnected, unless_disconnected
from api.main import create_app
from api.settings import Settings


class FakeRequest:
    """Connected for the first ``polls`` looks, then gone (never, with ``polls=None``)."""

    def __init__(self, polls: int | None) -> None:
        self.polls, self.looks = polls, 0
        self.url = SimpleNamespace(path="/tune")

    async def is_disconnected(self) -> bool:
        self.looks += 1
        return self.polls is not None and self.looks > self.polls


async def solve(log: list[str], *, seconds: float = 60.0, fail: bool = False) -> str:
    try:
        await asyncio.sleep(seconds)
        if fail:
            raise ValueError("bad input")
        return "result"
    except asyncio.CancelledError:
        log.append("cancelled")
        raise
    finally:
        log.append("cleaned up")


def test_a_client_that_goes_away_cancels_the_work():
    log: list[str] = []
    request = FakeRequest(polls=2)

    async def main():
        with pytest.raises(ClientDisconnected):
            await unless_disconnected(request, solve(log), poll_s=0.01)

    asyncio.run(main())
    assert log == ["cancelled", "cleaned up"]  # cancelled, and its clean-up ran before the route answered
    assert request.looks == 3


def test_a_connected_client_gets_the_result_or_the_error():
    log: list[str] = []

    async def main():
        assert await unless_disconnected(FakeRequest(None), solve(log, seconds=0.05), poll_s=0.01) == "result"
        with pytest.raises(ValueError, match="bad input"):
            await unless_disconnected(FakeRequest(None), solve(log, seconds=0.02, fail=True), poll_s=0.01)

    asyncio.run(main())
    assert log == ["cleaned up", "cleaned up"]


def test_cancelling_the_request_cancels_the_work():
    log: list[str] = []

    async def main():
        outer = asyncio.ensure_future(unless_disconnected(FakeRequest(None), solve(log), poll_s=0.01))
        await asyncio.sleep(0.05)
        outer.cancel()
        with pytest.raises(asyncio.CancelledError):
            await outer
        await asyncio.sleep(0)  # the work's cancellation is delivered

    asyncio.run(main())
    assert log == ["cancelled", "cleaned up"]


def test_the_route_answers_499(tmp_path):
    app = create_app(Settings(database_url=f"sqlite:///{tmp_path / 't.db'}"))

    @app.get("/gone")
    async def gone():
        raise ClientDisconnected

    r = TestClient(app).get("/gone")  # no lifespan: no pools needed
    assert r.status_code == CLIENT_CLOSED_REQUEST == 499
    assert "cancelled" in r.json()["detail"]
