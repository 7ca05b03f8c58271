"""What the service decides from the headers before it reads a body (issue 21, :mod:`api.guard`): the Host
allow-list, the API key, the per-client limit; the body read timeout; the headers of every answer."""

from __future__ import annotations

import asyncio
import base64
import hashlib
import re

import httpx
import pytest
from fastapi.testclient import TestClient
from pydantic import SecretStr

from api.guard import Guard, docs_csp, host_name
from api.main import create_app
from api.settings import Settings


def _settings(tmp_path, **kw) -> Settings:
    return Settings(database_url=f"sqlite:///{tmp_path / 'tuner.db'}", workers=1, queue_size=2, **kw)


class CountingBody:
    """A request body that records how much of it the server pulled."""

    def __init__(self, chunks: int, size: int = 100_000, fill: bytes = b" ") -> None:
        self.chunks, self.size, self.fill, self.sent = chunks, size, fill, 0

    async def __aiter__(self):
        for _ in range(self.chunks):
            self.sent += self.size
            yield self.fill * self.size


def _post(app, path: str, body: CountingBody, headers: dict[str, str]) -> httpx.Response:
    async def go() -> httpx.Response:
        transport = httpx.ASGITransport(app=app, client=("127.0.0.1", 5000))
        async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as c:
            return await c.post(path, content=body, headers={"content-type": "application/json", **headers})

    return asyncio.run(go())


def test_a_keyless_large_body_is_refused_with_401_unread(tmp_path):
    app = create_app(_settings(tmp_path, api_key=SecretStr("k")))
    body = CountingBody(chunks=200)  # 20 MB, under the /identify cap
    r = _post(app, "/identify", body, {})
    assert r.status_code == 401 and r.headers["www-authenticate"] == "X-API-Key"
    assert body.sent == 0  # not one byte was pulled
    wrong = CountingBody(chunks=200)
    assert _post(app, "/identify", wrong, {"X-API-Key": "not-it"}).status_code == 401 and wrong.sent == 0
    # control: with the key the same body is read (and refused as JSON only once it is all in)
    right = CountingBody(chunks=200)
    r = _post(app, "/identify", right, {"X-API-Key": "k"})
    assert r.status_code == 422 and right.sent == 200 * 100_000


class _FullPool:
    """A pool in which this client already has as many jobs waiting as it may."""

    def __init__(self) -> None:
        self.asked: list[str] = []

    def would_refuse(self, client: str) -> bool:
        self.asked.append(client)
        return True

    def retry_after_s(self, client: str | None = None) -> int:
        return 7


def test_a_client_over_its_limit_gets_429_before_its_body_is_read(tmp_path):
    app = create_app(_settings(tmp_path, api_key=SecretStr("k")))
    app.state.pool = pool = _FullPool()
    body = CountingBody(chunks=5)
    r = _post(app, "/tune", body, {"X-API-Key": "k"})
    assert r.status_code == 429 and r.headers["retry-after"] == "7" and body.sent == 0
    from api.deps import client_key

    assert pool.asked == [client_key("127.0.0.1", "k")]  # the same identity as the pool's (api.deps.client_id)


def test_would_refuse_agrees_with_the_pool(tmp_path):
    from api.pool import ClientBusy, WorkerPool

    pool = WorkerPool(size=1, queue_size=4, queue_timeout_s=5, max_waiting_per_client=1)
    pool._free = 0  # every solver busy: a first job waits, a second is refused
    assert not pool.would_refuse("a")

    async def go() -> None:
        first = asyncio.ensure_future(pool._acquire("a"))
        await asyncio.sleep(0)
        assert pool.would_refuse("a") and not pool.would_refuse("b")
        with pytest.raises(ClientBusy):
            await pool._acquire("a")
        first.cancel()

    asyncio.run(go())


@pytest.fixture
def plain(tmp_path):
    return TestClient(create_app(_settings(tmp_path)))  # no lifespan: these answers need no pool


@pytest.mark.parametrize("host, ok", [("testserver", True), ("127.0.0.1:8000", True), ("localhost", True),
                                      ("[::1]:8000", True), ("evil.example", False), ("127.0.0.1.evil.example", False),
                                      ("", False)])
def test_host_allow_list(plain, host, ok):
    r = plain.get("/openapi.json", headers={"host": host})
    if ok:
        assert r.status_code == 200
    else:
        assert r.status_code == 400 and "TUNER_ALLOWED_HOSTS" in r.json()["detail"]
        assert r.headers["x-content-type-options"] == "nosniff"


def test_host_allow_list_is_configurable(tmp_path):
    c = TestClient(create_app(_settings(tmp_path, allowed_hosts="tuner.example.com, testserver")))
    assert c.get("/docs", headers={"host": "tuner.example.com"}).status_code == 200
    assert c.get("/docs", headers={"host": "localhost"}).status_code == 400
    anyhost = TestClient(create_app(_settings(tmp_path, allowed_hosts="*")))
    assert anyhost.get("/docs", headers={"host": "whatever.example"}).status_code == 200
    assert Settings().allowed_host_set >= {"127.0.0.1", "localhost", "::1"}
    assert host_name("LOCALHOST:80") == "localhost" and host_name("[::1]") == "::1"


@pytest.mark.parametrize("path", ["/docs", "/redoc", "/openapi.json", "/", "/nowhere", "/web/app.js"])
def test_every_answer_has_nosniff(plain, path):
    assert plain.get(path).headers["x-content-type-options"] == "nosniff"


def test_protected_answers_are_private(tmp_path):
    c = TestClient(create_app(_settings(tmp_path, api_key=SecretStr("k"))))
    r = c.get("/nowhere", headers={"X-API-Key": "k"})
    assert r.status_code == 404 and r.headers["cache-control"] == "private"
    assert "cache-control" not in c.get("/openapi.json").headers  # public answers are left as they are


@pytest.mark.parametrize("path", ["/docs", "/redoc"])
def test_docs_pages_have_a_csp_that_allows_exactly_their_inline_code(plain, path):
    r = plain.get(path)
    csp = r.headers["content-security-policy"]
    directives = dict(d.strip().split(" ", 1) for d in csp.split(";"))
    assert "'unsafe-inline'" not in directives["script-src"] and "'unsafe-eval'" not in directives["script-src"]
    assert directives["default-src"] == "'self'" and directives["object-src"] == "'none'"
    for block in re.findall(r"<script>(.*?)</script>", r.text, re.S):  # every inline script, by its own hash
        h = base64.b64encode(hashlib.sha256(block.encode()).digest()).decode()
        assert f"'sha256-{h}'" in directives["script-src"]
    assert r.headers["content-length"] == str(len(r.content))
    assert "'sha256-" not in docs_csp(b"<script src='/x.js'></script>")


def test_a_body_that_stops_arriving_gets_408():
    """Event-based: the body's second part never comes; the guard answers 408 after its timeout."""
    sent: list[dict] = []

    async def app(scope, receive, send):
        while (await receive()).get("more_body"):
            pass
        raise AssertionError("the body was never complete")

    async def go() -> None:
        parts = [{"type": "http.request", "body": b"{", "more_body": True}]
        never = asyncio.Event()

        async def receive():
            if parts:
                return parts.pop()
            await never.wait()

        async def send(msg):
            sent.append(msg)

        guard = Guard(app, allowed_hosts=None, api_key=None, body_timeout_s=0.05)
        await guard({"type": "http", "method": "POST", "path": "/tune", "headers": [(b"content-length", b"1000")]},
                    receive, send)

    asyncio.run(go())
    assert sent[0]["status"] == 408 and (b"connection", b"close") in sent[0]["headers"]
    assert b"TUNER_BODY_TIMEOUT_S" in sent[1]["body"]


def _at(app, server_host: str, path: str, headers: dict[str, str] | None = None) -> httpx.Response:
    """A request that reached the service on ``server_host`` (its connection's local address), from 127.0.0.1."""
    async def go() -> httpx.Response:
        transport = httpx.ASGITransport(app=app, client=("127.0.0.1", 5000))
        async with httpx.AsyncClient(transport=transport, base_url=f"http://{server_host}:8000") as c:
            return await c.get(path, headers=headers or {})
    return asyncio.run(go())


@pytest.mark.parametrize("server_host", ["10.1.2.3", "172.17.0.2", "[2001:db8::1]"])
def test_without_a_key_only_connections_to_loopback_are_answered(tmp_path, server_host):
    """Issue 42: the Docker image started with no key on 0.0.0.0, and a client that set Host: localhost itself was
    answered. Without a key (and without TUNER_ALLOW_NO_KEY) a request that reached another address is 403,
    whatever its Host; /health stays open (a health check from outside the container)."""
    app = create_app(_settings(tmp_path))
    r = _at(app, server_host, "/tunes", {"Host": "localhost"})
    assert r.status_code == 403 and "TUNER_API_KEY" in r.json()["detail"], r.text
    assert _at(app, "127.0.0.1", "/nowhere").status_code == 404  # loopback: served (no such route)
    assert _at(app, "[::1]", "/nowhere").status_code == 404
    assert _at(app, server_host, "/health").status_code != 403
    keyed = create_app(_settings(tmp_path, api_key=SecretStr("k")))  # a key: every address, behind the key
    assert _at(keyed, server_host, "/nowhere", {"Host": "localhost", "X-API-Key": "k"}).status_code == 404
    open_ = create_app(_settings(tmp_path, allow_no_key=True))  # the explicit opt-in
    assert _at(open_, server_host, "/nowhere", {"Host": "localhost"}).status_code == 404


def test_is_loopback():
    from api.guard import is_loopback

    for h in ("127.0.0.1", "127.5.6.7", "::1", "[::1]", "::ffff:127.0.0.1", "localhost"):
        assert is_loopback(h), h
    for h in ("0.0.0.0", "::", "10.0.0.1", "example.com", "::ffff:10.0.0.1", ""):
        assert not is_loopback(h), h
