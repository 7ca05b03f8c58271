"""The page's routes through TestClient: ``/`` with its config and CSP, the two assets, no outside URL.

(The page itself, in Chromium: tests/e2e/test_page_browser.py.)"""

from __future__ import annotations

import json
import re

import pytest
from fastapi.testclient import TestClient
from pydantic import SecretStr

from api.main import create_app
from api.routes.page import WEB
from api.settings import Settings
from tuner.controllers import STRUCTURES
from tuner.spec import Spec


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    db = tmp_path_factory.mktemp("page") / "t.db"
    return TestClient(create_app(Settings(database_url=f"sqlite:///{db}", max_budget_s=30,
                                          api_key=SecretStr("k"))))  # no lifespan: the page needs no pool


def config_of(html: str) -> dict:
    m = re.search(r'<script id="config" type="application/json">(.*?)</script>', html, re.S)
    assert m, "no config in the page"
    return json.loads(m.group(1))


def test_the_page_is_public_and_carries_the_form_config(client):
    r = client.get("/")  # no X-API-Key, although the service has one
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    csp = r.headers["Content-Security-Policy"]
    assert "default-src 'self'" in csp and "script-src 'self'" in csp and "unsafe" not in csp
    cfg = config_of(r.text)
    assert [s["name"] for s in cfg["structures"]] == list(STRUCTURES)
    assert next(s for s in cfg["structures"] if s["name"] == "pid_z") == {
        "name": "pid_z", "params": ["K", "a1", "a2"], "discrete_only": True}
    assert cfg["spec_defaults"] == Spec().model_dump(mode="json")
    assert cfg["max_budget_s"] == 30 and cfg["api_key_required"] is True
    for name in Spec.model_fields:  # every spec field has its input in the form
        assert f'name="{name}"' in r.text, name
    assert client.get("/tunes").status_code == 401  # the API behind it still wants the key


def test_assets_are_served_with_an_etag_and_nothing_else_is(client):
    for name, media in (("app.js", "text/javascript"), ("style.css", "text/css")):
        r = client.get(f"/web/{name}")
        assert r.status_code == 200 and r.headers["content-type"].startswith(media)
        assert r.content == (WEB / name).read_bytes()
        again = client.get(f"/web/{name}", headers={"If-None-Match": r.headers["ETag"]})
        assert again.status_code == 304
    assert client.get("/web/index.html").status_code == 404
    assert client.get("/web/..%2Fmain.py").status_code == 404
    assert "/" not in client.get("/openapi.json").json()["paths"]


def test_no_outside_url_in_the_page():
    for f in ("index.html", "app.js", "style.css"):
        text = (WEB / f).read_text()
        assert not re.search(r"(https?:)?//[a-z0-9.-]+\.[a-z]{2,}", text, re.I), f
        assert "@import" not in text and "eval(" not in text, f
