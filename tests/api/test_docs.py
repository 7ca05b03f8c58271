"""Offline docs (issue 14): ``/docs`` and ``/redoc`` load Swagger UI and ReDoc from the service itself (the
files shipped in fastapi-offline), so they work without internet; open even when an API key is required."""

from __future__ import annotations

import re

import pytest
from pydantic import SecretStr

from api.settings import Settings


@pytest.fixture(scope="module")
def settings(tmp_path_factory):
    db = tmp_path_factory.mktemp("docs") / "tuner.db"
    return Settings(database_url=f"sqlite:///{db}", workers=1, queue_size=2)


def urls(page: str) -> list[str]:
    """Every URL the page loads: src/href attributes and the spec's url in the inline script."""
    found = re.findall(r"""(?:src|href)\s*=\s*["']([^"']+)["']""", page)
    found += re.findall(r"""(?:url|spec-url)\s*[:=]\s*["']([^"']+)["']""", page)
    return found


@pytest.mark.parametrize("path, asset", [("/docs", "swagger-ui-bundle.js"), ("/redoc", "redoc.standalone.js")])
def test_docs_reference_no_external_url_and_their_assets_are_served(client, override_settings, path, asset):
    override_settings(api_key=SecretStr("s3cret"))  # the docs stay open
    r = client.get(path)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    page = r.text
    assert not re.search(r"https?://|//[a-z0-9.-]+\.[a-z]{2,}/", page, re.IGNORECASE), page
    found = urls(page)
    assert any(u.endswith(asset) for u in found), found
    assert "/openapi.json" in found
    for u in found:
        assert u.startswith("/"), u
        a = client.get(u)
        assert a.status_code == 200, (u, a.status_code)
        assert len(a.content) > 100, u
    js = client.get(next(u for u in found if u.endswith(asset)))
    assert "javascript" in js.headers["content-type"] and len(js.content) > 100_000


def test_swagger_ui_asks_no_online_validator(client):
    assert '"validatorUrl": null' in client.get("/docs").text
