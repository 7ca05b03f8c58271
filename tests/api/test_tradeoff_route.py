"""POST /tradeoff (issue 18): the verified trade-off curve over HTTP, and its bad input at its fields."""

from __future__ import annotations

import pytest
import reference as ref
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
    rn, rd = [0.2655 * 14.8528 ** 2], [1, 14.195, 14.8528 ** 2]
    for p in pts:  # each point's Mks, recomputed here from its gains (tests/reference.py, not the library)
        num, den = ref.pid_backward_euler(p["gains"], DT)
        assert p["mks"] == pytest.approx(ref.mks_sampled(num, den, rn, rd, DT), rel=2e-3)


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
