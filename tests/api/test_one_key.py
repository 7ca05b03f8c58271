"""One key, read once: several X-API-Key headers are a 400 before anything else, at the guard (the app as served)
and at the route (the same checks without the guard), whatever their order."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from pydantic import SecretStr

from api.settings import Settings

BODY = {"plant": {"expr": "1/(s+1)"}, "structure": "pi", "options": {"time_budget_s": 1}}


@pytest.fixture(scope="module")
def settings(tmp_path_factory):
    db = tmp_path_factory.mktemp("key") / "tuner.db"
    return Settings(database_url=f"sqlite:///{db}", workers=1, queue_size=4, api_key=SecretStr("right"))


@pytest.mark.parametrize("keys", [[("x-api-key", "right"), ("x-api-key", "wrong")],
                                  [("x-api-key", "wrong"), ("x-api-key", "right")],
                                  [("x-api-key", "right"), ("X-API-Key", "right")]])
@pytest.mark.parametrize("method, path", [("GET", "/tunes"), ("POST", "/tune"), ("POST", "/identify")])
def test_duplicate_keys_are_a_400(client, keys, method, path):
    r = client.request(method, path, headers=keys, json=BODY if method == "POST" else None)
    assert r.status_code == 400 and "send exactly one" in r.json()["detail"], r.text


def test_one_right_key_passes_and_a_wrong_one_is_401(client):
    assert client.get("/tunes", headers={"x-api-key": "right"}).status_code == 200
    assert client.get("/tunes", headers={"x-api-key": "wrong"}).status_code == 401


def test_the_route_refuses_them_too_without_the_guard():
    """The routes' own dependencies (require_api_key, client_id) on an app without the guard middleware."""
    from fastapi import Depends, FastAPI

    from api.deps import client_id, require_api_key
    from api.settings import get_settings

    bare = FastAPI()
    bare.dependency_overrides[get_settings] = lambda: Settings(api_key=SecretStr("a"))

    @bare.get("/x", dependencies=[Depends(require_api_key)])
    def x(who: str = Depends(client_id)) -> dict:
        return {"who": who}

    with TestClient(bare) as c:
        assert c.get("/x", headers={"x-api-key": "a"}).status_code == 200
        r = c.get("/x", headers=[("x-api-key", "a"), ("x-api-key", "b")])
        assert r.status_code == 400 and "send exactly one" in r.json()["detail"]
