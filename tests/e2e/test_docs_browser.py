"""``/docs`` and ``/redoc`` under their Content-Security-Policy (issue 21, :mod:`api.guard`), in headless Chromium
against a real uvicorn: both render the API (Swagger UI's operations, ReDoc's menu) with no CSP violation and
nothing loaded from outside the service."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from uvicorn_server import serving

pytestmark = [pytest.mark.browser, pytest.mark.slow]

CHROMIUM = "/usr/bin/chromium"  # Debian's package, as in test_page_browser.py


@pytest.fixture(scope="module")
def browser():
    if not Path(CHROMIUM).exists():
        (pytest.fail if os.environ.get("CI") else pytest.skip)(f"{CHROMIUM} is missing: apt-get install -y chromium")
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM)
        yield b
        b.close()


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("docs")
    with serving(tmp, {"TUNER_DATABASE_URL": f"sqlite:///{tmp / 'tuner.db'}", "TUNER_WORKERS": "1"}) as s:
        yield s


@pytest.mark.parametrize("path, rendered", [("/docs", ".opblock-summary-path"),
                                            ("/redoc", "[role=menuitem], li label")])
def test_docs_render_under_their_csp(browser, server, path, rendered):
    ctx = browser.new_context()
    page = ctx.new_page()
    console, outside, errors = [], [], []
    page.on("console", lambda m: console.append(m.text))
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("request", lambda r: None if r.url.startswith((server.url, "blob:", "data:")) else outside.append(r.url))
    try:
        r = page.goto(server.url + path)
        assert "content-security-policy" in r.headers
        page.wait_for_selector(rendered, timeout=60_000)
        assert "/tune" in page.content()
    finally:
        ctx.close()
    violations = [m for m in console if "Content Security Policy" in m or "Refused to" in m]
    # ReDoc's footer logo is an image on cdn.redoc.ly: the policy blocks it (nothing leaves the machine), and
    # that is the only thing it may block: nothing the page needs from the service itself
    blocked_outside = [u for u in outside if any(u in m and "img-src" in m for m in violations)]
    assert outside == blocked_outside and len(violations) == len(blocked_outside), (violations, outside)
    assert all(u.startswith("https://cdn.redoc.ly/") for u in blocked_outside) and errors == [], (outside, errors)
