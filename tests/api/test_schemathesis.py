"""Property-based testing of every operation from the OpenAPI schema (schemathesis).

Bounded: schemathesis's coverage phase (boundary values and invalid variants of every
field, a few hundred requests per POST route) and 25 generated requests per operation,
derandomized. The checks: no 5xx on any input (the issue's requirement), and every answer's
status code, content type and body as documented. Valid tune bodies run the real library
with a 0.15 s budget and few trials (:func:`api.testing.capped_tune_job`) to stay quick;
valid analyze bodies run the real analysis. One solver process (requests come one at a time).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from api import testing
from api.deps import get_tune_job
from api.main import create_app
from api.settings import Settings

pytestmark = pytest.mark.slow

_TMP = tempfile.TemporaryDirectory(prefix="tuner-schemathesis-")  # removed when the test process exits
_DB = Path(_TMP.name) / "tuner.db"
_app = create_app(Settings(database_url=f"sqlite:///{_DB}", workers=1, queue_size=8, queue_timeout_s=60,
                           solve_grace_s=3.0, max_plants=3))
_app.dependency_overrides[get_tune_job] = lambda: testing.capped_tune_job
schema = schemathesis.openapi.from_dict(_app.openapi())  # no lifespan (no solver) just to collect
schema.app, schema.location = _app, "/openapi.json"  # requests go to the app in-process, as from_asgi does


@schema.parametrize()
@settings(max_examples=25, deadline=None, derandomize=True, database=None,
          suppress_health_check=list(HealthCheck))
def test_no_server_error_and_answers_match_the_schema(case):
    case.call_and_validate(timeout=120, checks=[not_a_server_error, status_code_conformance, content_type_conformance,
                                                response_schema_conformance])


@pytest.mark.parametrize(("name", "path", "body"), testing.HOSTILE_REQUESTS,
                         ids=[c[0] for c in testing.HOSTILE_REQUESTS])
def test_hand_found_classes_answer_below_500(name, path, body):
    """Issue 11's hand-found classes (34 x 500 before), as explicit cases through the same checks."""
    case = schema[path]["POST"].Case(body=body, media_type="application/json")
    response = case.call_and_validate(timeout=120, checks=[not_a_server_error, status_code_conformance,
                                                           content_type_conformance, response_schema_conformance])
    assert response.status_code < 500, response.text
    if response.status_code == 422:
        detail = response.json()["detail"]
        assert detail and all(d["loc"][0] == "body" and d["msg"] for d in detail), detail
