"""Shared fixtures of the service tests: a module's app (from its own ``settings`` fixture), a client
whose solver processes are up, and settings changed for one test."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from api.main import create_app
from api.settings import get_settings
from api.testing import wait_for_workers


@pytest.fixture(scope="module")
def app(settings):
    return create_app(settings)


@pytest.fixture(scope="module")
def client(app):
    with TestClient(app) as c:
        wait_for_workers(c)
        yield c


@pytest.fixture
def override_settings(app, settings):
    """Run a test with changed settings, injected where the routes read them."""

    def apply(**changes):
        app.dependency_overrides[get_settings] = lambda: settings.model_copy(update=changes)

    yield apply
    app.dependency_overrides.pop(get_settings, None)
