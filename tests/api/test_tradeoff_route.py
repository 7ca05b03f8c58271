"""POST /tradeoff (issue 18): the verified trade-off curve over HTTP, and its bad input at its fields."""

from __future__ import annotations

import pytest
from quadrotor import DT, ROLL

from api.settings import Settings


@pytest.fixture(scope="module")
def settings(tmp_path_factory):
    db = tmp_path_factory.mktemp("api") / "tuner.db"
    return Settings(database_url=f"sqlite:///{db}", workers=1, queue_size=4, default_budget_s=20.0,
                    solve_grace_s=10.0, max_budget_s=30.0)


@pytest.mark.slow
def test_tradeoff_points_are_verified_and_ordered(client):
    r = client.post("/tradeoff", json={"plant": {"expr": ROLL}, "dt": DT, "structure": "pid", "points": 3,
                                       "options": {"time_budget_s": 20}})
    assert r.status_code == 200, r.text
    d = r.json()
    pts = d["points"]
    assert d["y"] == "mks" and len(pts) >= 2
    assert all(p["meets_spec"] and p["result"]["meets_spec"] for p in pts)
    ts = [p["settling_time_s"] for p in pts]
    mk = [p["mks"] for p in pts]
    assert all(b > a for a, b in zip(ts, ts[1:])) and all(b < a for a, b in zip(mk, mk[1:]))
    for p in pts:  # the y value is the verified result's own
        assert p["mks"] == p["result"]["metrics"]["mks"]


@pytest.mark.parametrize("body,loc", [
    ({"points": 1}, ["body", "points"]),
    ({"y": "ms"}, ["body", "y"]),
    ({"spec": {"objective": "iae"}}, ["body", "spec", "objective"]),
    ({"structure": "nope"}, ["body", "structure"]),
])
def test_tradeoff_bad_input_is_422_at_its_field(client, body, loc):
    r = client.post("/tradeoff", json={"plant": {"expr": ROLL}, "dt": DT, "structure": "pi", **body})
    assert r.status_code == 422, r.text
    assert any(item["loc"][:len(loc)] == loc for item in r.json()["detail"]), r.text
