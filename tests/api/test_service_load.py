"""The service under load and outages: fair sharing of the solvers between clients (429 past a
client's queue), plots drawn apart from the solvers and cached, ``Cache-Control`` private behind a
key, ``HEAD`` on every ``GET`` route, and a database unreachable at start-up (the service starts,
says so, answers 503 and recovers).

Sleeping jobs are injected (:mod:`api.testing`) so that who holds a solver is known; the client's
identity is taken from a test header (:func:`api.deps.client_id` is overridden). No test asserts a
duration: each waits for events with generous bounds.
"""

from __future__ import annotations

import threading
import uuid
from concurrent.futures import ThreadPoolExecutor

import pytest
from fastapi import Request
from fastapi.testclient import TestClient
from netproxy import TcpProxy
from pg import PG_HOSTPORT, pg_admin_engine, require_pg_base_url
from pydantic import SecretStr
from quadrotor import DT, ROLL, YAW

from api import testing
from api.deps import client_id, get_tune_job
from api.main import create_app
from api.settings import Settings, get_settings
from api.testing import wait_for_workers, wait_until


def _by_header(request: Request) -> str:
    return request.headers.get("x-test-client", "anonymous")


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    db = tmp_path_factory.mktemp("load") / "tuner.db"
    settings = Settings(database_url=f"sqlite:///{db}", workers=2, queue_size=8, max_queued_per_client=2,
                        queue_timeout_s=120, solve_grace_s=30, worker_memory_mb=2048)
    a = create_app(settings)
    a.dependency_overrides[client_id] = _by_header
    return a


@pytest.fixture(scope="module")
def client(app):
    with TestClient(app) as c:
        wait_for_workers(c)
        yield c


@pytest.fixture(scope="module")
def roll(client):
    r = client.post("/tune", json={"plant": {"expr": ROLL}, "dt": DT, "structure": "pid_z",
                                   "options": {"seed": 0, "time_budget_s": 2}})
    assert r.status_code == 200, r.text
    return r.json()


def sleeping(budget_s: float) -> dict:
    return {"plant": {"expr": YAW}, "structure": "pi", "options": {"time_budget_s": budget_s}}


@pytest.mark.slow
def test_one_client_never_holds_every_solver_and_others_are_served(app, client):
    """Client A sends 3 jobs to 2 solvers: one runs, two wait although a solver is free; a 4th is
    429; client B's job takes the free solver at once, while A's jobs are still queued."""
    app.dependency_overrides[get_tune_job] = lambda: testing.sleep_job
    pool = app.state.pool
    a_answers: list = []
    try:
        def post_a():
            a_answers.append(client.post("/tune", json=sleeping(2.0), headers={"x-test-client": "A"}))

        threads = [threading.Thread(target=post_a) for _ in range(3)]
        for t in threads:
            t.start()
        wait_until(lambda: pool.stats()["busy"] == 1 and pool.stats()["waiting"] == 2, what="A: 1 running, 2 waiting")
        assert pool.stats()["busy"] == 1  # the second solver stays free for others

        over = client.post("/tune", json=sleeping(2.0), headers={"x-test-client": "A"})
        assert over.status_code == 429, over.text
        assert 1 <= int(over.headers["Retry-After"]) <= 60
        assert "waiting" in over.json()["detail"] and "retry after" in over.json()["detail"]

        b = client.post("/tune", json=sleeping(0.1), headers={"x-test-client": "B"})
        assert b.status_code == 200 and b.json()["slept_s"] == 0.1
        assert len(a_answers) < 3  # B was served before A's queue drained: A's third job waits for two others
    finally:
        for t in threads:
            t.join(60)
        app.dependency_overrides.pop(get_tune_job, None)
    assert [r.status_code for r in a_answers] == [200] * 3


@pytest.mark.slow
def test_plots_are_drawn_apart_from_the_solvers_and_once_per_result(app, client, roll):
    """30 concurrent plot requests beside a /tune: the tune is served, the plot drawn once."""
    cache = app.state.plot_cache
    misses = cache.stats()["misses"]
    tune_box: dict = {}

    def tune():
        tune_box["r"] = client.post("/tune", json={"plant": {"expr": YAW}, "structure": "pi",
                                                   "options": {"seed": 1, "time_budget_s": 1}},
                                    headers={"x-test-client": "tuner"})

    t = threading.Thread(target=tune)
    t.start()
    with ThreadPoolExecutor(30) as ex:
        plots = list(ex.map(lambda i: client.get(f"/tunes/{roll['id']}/plot.png",
                                                 headers={"x-test-client": f"viewer{i}"}), range(30)))
    t.join(120)
    assert tune_box["r"].status_code == 200, tune_box["r"].text
    assert [p.status_code for p in plots] == [200] * 30
    assert len({p.content for p in plots}) == 1 and plots[0].content[:4] == b"\x89PNG"
    assert cache.stats()["misses"] == misses + 1  # drawn once, the other 29 shared it
    assert app.state.plot_pool.stats()["crashes"] == 0


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_plot_cache_headers_and_etag(client, roll):
    r = client.get(f"/tunes/{roll['id']}/plot.svg")
    assert r.status_code == 200
    assert r.headers["Cache-Control"].startswith("public")
    again = client.get(f"/tunes/{roll['id']}/plot.svg", headers={"If-None-Match": r.headers["ETag"]})
    assert again.status_code == 304 and again.content == b""
    other = client.get(f"/tunes/{roll['id']}/plot.svg", params={"kind": "bode"},
                       headers={"If-None-Match": r.headers["ETag"]})
    assert other.status_code == 200 and other.headers["ETag"] != r.headers["ETag"]  # another kind, another tag


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_plot_cache_keeps_each_kind_apart(app, client, roll):
    """Each kind is drawn once and cached under its own key: a second request for a kind is a hit and
    answers that kind's image, not another kind's."""
    cache = app.state.plot_cache
    first = {}
    for kind in ("step", "bode", "nyquist", "all"):
        before = cache.stats()
        first[kind] = client.get(f"/tunes/{roll['id']}/plot.png", params={"kind": kind}).content
        after = cache.stats()
        assert (after["misses"], after["hits"]) in {(before["misses"] + 1, before["hits"]),  # drawn now
                                                    (before["misses"], before["hits"] + 1)}  # by an earlier test
        assert cache.get((roll["id"], kind, "png")) == first[kind]
    assert len(set(first.values())) == 4
    for kind in ("nyquist", "step"):
        hits = cache.stats()["hits"]
        assert client.get(f"/tunes/{roll['id']}/plot.png", params={"kind": kind}).content == first[kind]
        assert cache.stats()["hits"] == hits + 1


def test_plots_behind_a_key_are_private(app, client, roll):
    settings = app.state.settings.model_copy(update={"api_key": SecretStr("s3cret")})
    app.dependency_overrides[get_settings] = lambda: settings
    try:
        r = client.get(f"/tunes/{roll['id']}/plot.png", headers={"X-API-Key": "s3cret"})
    finally:
        app.dependency_overrides.pop(get_settings)
    assert r.status_code == 200
    assert r.headers["Cache-Control"].split(",")[0] == "private"


@pytest.mark.parametrize("path", ["/tunes", "/tunes/{id}", "/tunes/{id}/plot.png", "/health", "/openapi.json"])
def test_head_answers_as_get_without_a_body(client, roll, path):
    url = path.format(id=roll["id"])
    got = client.get(url)
    head = client.head(url)
    assert head.status_code == got.status_code == 200
    assert head.content == b""
    assert head.headers["content-type"] == got.headers["content-type"]
    assert int(head.headers["content-length"]) == len(got.content)


def test_head_on_a_post_route_is_405(client):
    assert client.head("/tune").status_code == 405


# -- the database unreachable at start-up --------------------------------------------------------

def _check_down(c: TestClient) -> None:
    h = c.get("/health")
    assert h.status_code == 503 and h.json()["database"] == "unreachable" and h.json()["status"] == "degraded"
    for r in (c.get("/tunes"), c.get("/tunes/" + "0" * 32),
              c.post("/tune", json={"plant": {"expr": YAW}, "structure": "pi", "options": {"time_budget_s": 1}})):
        assert r.status_code == 503, r.text
        assert "database unreachable" in r.json()["detail"] and r.headers["Retry-After"] == "5"


def test_service_starts_without_its_database_and_recovers_sqlite(tmp_path, caplog):
    """SQLite in a folder that does not exist yet: the service starts, 503s, and serves once it appears."""
    folder = tmp_path / "not-yet"
    app = create_app(Settings(database_url=f"sqlite:///{folder / 'tuner.db'}", workers=1, db_retry_s=0.2))
    with caplog.at_level("WARNING", logger="api"), TestClient(app) as c:
        _check_down(c)
        assert any("database unreachable at start-up" in m for m in caplog.messages)
        folder.mkdir()
        wait_until(lambda: c.get("/health").status_code == 200, what="the database back")
        assert c.get("/tunes").json()["total"] == 0


@pytest.mark.postgres
def test_postgres_outage_at_start_up_then_recovery(caplog):
    """PostgreSQL behind a TCP proxy that is closed at start-up, opened, closed and opened again
    (the machine's server itself is never stopped)."""
    from sqlalchemy import text

    base = require_pg_base_url()
    schema = f"tuner_test_{uuid.uuid4().hex[:12]}"
    admin = pg_admin_engine(base)
    with admin.begin() as conn:
        conn.execute(text(f'CREATE SCHEMA "{schema}"'))
    host, port = PG_HOSTPORT.split(":")
    proxy = TcpProxy((host, int(port)))
    url = base.replace(PG_HOSTPORT, f"127.0.0.1:{proxy.port}") + f"?options=-csearch_path%3D{schema}"
    try:
        app = create_app(Settings(database_url=url, workers=1, db_retry_s=0.2))
        with caplog.at_level("WARNING", logger="api"), TestClient(app) as c:
            _check_down(c)
            assert any("database unreachable at start-up" in m for m in caplog.messages)
            proxy.open()
            wait_until(lambda: c.get("/health").status_code == 200, what="the database back")
            assert c.get("/tunes").status_code == 200
            proxy.close()  # an outage while running
            assert c.get("/tunes").status_code == 503
            proxy.open()
            wait_until(lambda: c.get("/tunes").status_code == 200, what="the database back again")
    finally:
        proxy.close()
        with admin.begin() as conn:
            conn.execute(text(f'DROP SCHEMA "{schema}" CASCADE'))
        admin.dispose()


# -- the plot cache on its own ---------------------------------------------------------------------

def test_plot_cache_shares_a_drawing_evicts_by_bytes_and_keeps_no_failure():
    import asyncio

    from api.plotcache import PlotCache

    async def scenario():
        cache = PlotCache(max_bytes=10)
        calls = []
        gate = asyncio.Event()

        async def draw(tag: bytes):
            calls.append(tag)
            await gate.wait()
            return tag * 4

        waiters = [asyncio.ensure_future(cache.get_or_draw(("a", "png"), lambda: draw(b"a"))) for _ in range(5)]
        await asyncio.sleep(0)
        waiters[0].cancel()  # a requester that goes away does not stop the drawing for the others
        gate.set()
        results = await asyncio.gather(*waiters[1:])
        assert results == [b"aaaa"] * 4 and calls == [b"a"]
        assert await cache.get_or_draw(("b", "png"), lambda: draw(b"b")) == b"bbbb"
        assert await cache.get_or_draw(("c", "png"), lambda: draw(b"c")) == b"cccc"  # 12 bytes > 10: "a" goes
        assert cache.get(("a", "png")) is None and cache.get(("c", "png")) == b"cccc"

        async def broken():
            raise RuntimeError("drawing failed")

        for _ in range(2):  # a failure is not cached: the next request draws again
            try:
                await cache.get_or_draw(("d", "svg"), broken)
            except RuntimeError as e:
                assert str(e) == "drawing failed"
            else:
                raise AssertionError("the failure was not raised")
        assert cache.stats()["misses"] == 5

    asyncio.run(scenario())
