"""Storage: one contract, run against SQLite (a file in a temporary directory) and the real
PostgreSQL on 127.0.0.1:5432 (database ``test``, a schema of its own per test, dropped after).

Then the service itself: results written, service restarted, results read back, on both.
"""

from __future__ import annotations

import datetime as dt
import threading
import uuid

import pytest
from fastapi.testclient import TestClient
from pg import pg_admin_engine, require_pg_base_url
from quadrotor import DT, ROLL

from api.deps import get_store
from api.main import create_app
from api.settings import Settings
from api.store import Store, StoreError
from api.testing import wait_for_workers


@pytest.fixture
def pg_url():
    """A URL whose connections use a fresh schema (``search_path``), dropped afterwards."""
    from sqlalchemy import text

    base = require_pg_base_url()
    schema = f"tuner_test_{uuid.uuid4().hex[:12]}"
    admin = pg_admin_engine(base)
    with admin.begin() as c:
        c.execute(text(f'CREATE SCHEMA "{schema}"'))
    try:
        yield f"{base}?options=-csearch_path%3D{schema}"
    finally:
        with admin.begin() as c:
            c.execute(text(f'DROP SCHEMA "{schema}" CASCADE'))
        admin.dispose()


@pytest.fixture
def sqlite_url(tmp_path):
    return f"sqlite:///{tmp_path / 'tuner.db'}"


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def url(request):
    return request.getfixturevalue("sqlite_url" if request.param == "sqlite" else "pg_url")


@pytest.fixture
def store(url):
    s = Store(url)
    s.create_schema()
    yield s
    s.dispose()


RESULT = {"structure": "pid_z", "gains": {"K": 3.868, "a1": -1.305, "a2": 0.5668}, "meets_spec": True,
          "metrics": {"gain_margin_lower_db": "-Infinity", "phase_margin_deg": 61.25, "crossover_rad_s": "NaN"},
          "controller": {"num": [3.868, -5.04774, 2.1923824], "den": [1.0, -1.0, 0.0], "dt": 0.04}}
PLANTS = [{"num": [58.57], "den": [1.0, 14.195, 220.6], "dt": None, "delay": 0.0}]
REQUEST = {"plant": {"expr": ROLL}, "dt": DT, "structure": "pid_z", "spec": None, "options": {"seed": 0}}


# -- the contract -------------------------------------------------------------------------

def test_round_trip_keeps_every_value(store):
    rec = store.add(request=REQUEST, plants=PLANTS, result=RESULT)
    got = store.get(rec.id)
    assert got is not None
    assert (got.request, got.plants, got.result) == (REQUEST, PLANTS, RESULT)  # "-Infinity"/"NaN" included
    assert got.structure == "pid_z" and got.meets_spec is True
    assert got.created_at == rec.created_at and got.created_at.tzinfo is not None
    assert abs(got.created_at - dt.datetime.now(dt.UTC)) < dt.timedelta(minutes=5)


def test_unknown_id_is_none(store):
    assert store.get(uuid.uuid4().hex) is None
    assert store.get("not-an-id") is None


def test_list_is_newest_first_with_total_and_paging(store):
    ids = [store.add(request=REQUEST, plants=PLANTS, result={**RESULT, "structure": f"s{i}"}).id for i in range(5)]
    items, total = store.list(limit=3, offset=0)
    assert total == 5
    assert [i.id for i in items] == ids[::-1][:3]
    items2, _ = store.list(limit=3, offset=3)
    assert [i.id for i in items2] == ids[::-1][3:]
    assert [i.structure for i in items2] == ["s1", "s0"]
    assert store.list(limit=3, offset=99)[0] == []


def test_results_survive_a_new_store_on_the_same_database(url):
    first = Store(url)
    first.create_schema()
    rec = first.add(request=REQUEST, plants=PLANTS, result=RESULT)
    first.dispose()
    second = Store(url)
    second.create_schema()  # idempotent on an existing database
    try:
        assert second.get(rec.id).result == RESULT
        assert second.list(limit=10, offset=0)[1] == 1
    finally:
        second.dispose()


def test_concurrent_writes_are_all_kept(store):
    errors: list[BaseException] = []
    ids: list[str] = []
    lock = threading.Lock()

    def write(k: int) -> None:
        try:
            for j in range(5):
                rid = store.add(request={**REQUEST, "k": k, "j": j}, plants=PLANTS, result=RESULT).id
                with lock:
                    ids.append(rid)
        except BaseException as e:
            errors.append(e)

    threads = [threading.Thread(target=write, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert len(set(ids)) == 40
    assert store.list(limit=100, offset=0)[1] == 40


def test_ping(store):
    assert store.ping() is True


def test_unreachable_database_raises_store_error_not_a_driver_error():
    s = Store("postgresql+psycopg://nobody@127.0.0.1:1/none")  # nothing listens on port 1
    try:
        assert s.ping() is False
        with pytest.raises(StoreError, match="database unreachable"):
            s.add(request=REQUEST, plants=PLANTS, result=RESULT)
        with pytest.raises(StoreError):
            s.get("x")
    finally:
        s.dispose()


# -- the service: write, restart, read back -----------------------------------------------

def _settings(url: str) -> Settings:
    return Settings(database_url=url, workers=1, queue_size=2, solve_grace_s=3.0)


@pytest.mark.slow
def test_results_survive_a_service_restart(url):
    body = {"plant": {"expr": ROLL}, "dt": DT, "structure": "pid_z", "options": {"seed": 3, "time_budget_s": 0.5}}
    with TestClient(create_app(_settings(url))) as c:
        wait_for_workers(c)
        posted = c.post("/tune", json=body)
        assert posted.status_code == 200, posted.text
        posted = posted.json()
        listed = c.get("/tunes").json()
    with TestClient(create_app(_settings(url))) as c:  # a new app, new engine, new solver processes
        got = c.get(f"/tunes/{posted['id']}")
        assert got.status_code == 200
        got = got.json()
        assert got.pop("request")["options"] == {"seed": 3, "time_budget_s": 0.5, "effort": "default"}
        assert got == posted
        assert c.get("/tunes").json() == listed
        wait_for_workers(c)
        png = c.get(f"/tunes/{posted['id']}/plot.png")
        assert png.status_code == 200 and png.content[:4] == b"\x89PNG"


def test_storage_outage_is_503_and_health_says_so(tmp_path):
    app = create_app(_settings(f"sqlite:///{tmp_path / 'ok.db'}"))
    down = Store("postgresql+psycopg://nobody@127.0.0.1:1/none")
    app.dependency_overrides[get_store] = lambda: down
    try:
        with TestClient(app) as c:
            h = c.get("/health")
            assert h.status_code == 503 and h.json()["status"] == "degraded" and h.json()["database"] == "unreachable"
            assert h.json()["nlp_code"]["mode"] == "off"  # (the rest of the body as ever)
            r = c.get("/tunes")
            assert r.status_code == 503 and "storage unavailable" in r.json()["detail"]
            assert r.headers["Retry-After"] == "5" and "Traceback" not in r.text
            assert c.get("/tunes/" + "0" * 32).status_code == 503
    finally:
        down.dispose()
