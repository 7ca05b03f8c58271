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
    from tuner.limits import page_limits

    generated = {lim["field"] for lim in cfg["limits"]}  # the optional limits' inputs: app.js builds them from these
    assert cfg["limits"] == page_limits() and "drb_min_rad_s" in generated
    for name in Spec.model_fields:  # every spec field has its input in the form (or the config builds it)
        assert f'name="{name}"' in r.text or name in generated, name
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


def test_the_form_has_the_issue_18_fields_and_the_config_says_which_take_null(client):
    from typing import get_args

    from api.schemas import TradeoffRequest
    from tuner.spec import DEFAULT_LIMITS, OBJECTIVES

    r = client.get("/")
    cfg = config_of(r.text)
    # nullable: derived here from the Spec's annotations (a field whose type admits None), not from the schema
    nullable = [k for k, f in Spec.model_fields.items() if type(None) in get_args(f.annotation)]
    assert cfg["spec_nullable"] == nullable
    assert {"filter_n_max", "noise_gain_max", "settling_time_max", "crossover_rad_s"} <= set(nullable)
    assert "phase_margin_min_deg" not in nullable and "filter_nyquist" not in nullable
    assert cfg["default_limits"] == list(DEFAULT_LIMITS) == ["filter_n_max", "filter_nyquist", "noise_gain_max",
                                                             "gain_variation"]
    assert cfg["spec_defaults"]["filter_n_max"] == 20 and cfg["spec_defaults"]["noise_gain_max"] == 10
    assert cfg["spec_defaults"]["filter_nyquist"] is True
    assert cfg["objectives"] == ["auto", *OBJECTIVES] and {"mks", "disk_margin"} <= set(cfg["objectives"])
    assert cfg["spec_defaults"]["objective"] == "auto" and cfg["spec_defaults"]["gain_variation"] == "auto"
    y_axes = get_args(TradeoffRequest.model_fields["y"].annotation)
    assert cfg["tradeoff"] == {"y": list(y_axes), "max_points": 20,
                               "default_points": TradeoffRequest.model_fields["points"].default}

    html = r.text
    m = re.search(r'<fieldset id="limits-set"[^>]*>(.*?)</fieldset>', html, re.S)
    assert m, "no default design limits fieldset"
    limits = m.group(1)
    assert "<legend>default design limits</legend>" in limits
    for name in DEFAULT_LIMITS:  # the default limits live in it, each with its rule as a tooltip
        assert re.search(rf'title="[^"]+"[^>]*>[^<]*\s*<input[^>]*name="{name}"', limits), name
    assert 'type="checkbox" name="filter_nyquist"' in limits
    assert 'id="thesis"' in limits and "pure thesis spec (no default limits)" in limits
    for rule in ("Td/Tf", "Åström", "dt/π", "Nyquist", "K0", "Ziegler"):  # the README's reasoning, in the hints
        assert rule in limits, rule
    knob = {lim["field"] for lim in cfg["limits"] if lim["row"] == "speed"}  # built by app.js in #speed-knob
    assert knob == {"settling_time_max", "crossover_rad_s"} and 'id="speed-knob"' in html
    # the trade-off: its button next to tune, its axis and points, the plot and the slider, the result's bounds
    assert re.search(r'id="run-btn"[^>]*>tune</button>\s*<button type="button" id="tradeoff-btn"', html)
    assert re.search(r'<select name="y"', html) and re.search(r'<input type="number" name="points"', html)
    assert re.search(r'<svg id="curve"', html) and re.search(r'<input type="range" id="tradeoff-pick"', html)
    assert 'id="at-bounds"' in html and 'id="limits"' in html
