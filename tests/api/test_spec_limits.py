"""Issue 10 over HTTP: the new limits, impossible specs as 422 naming the field, reasons for an unmet spec."""

from __future__ import annotations

import pytest

from api.settings import Settings

ROLL = "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)"


@pytest.fixture(scope="module")
def settings(tmp_path_factory):
    db = tmp_path_factory.mktemp("api") / "tuner.db"
    return Settings(database_url=f"sqlite:///{db}", workers=1, queue_size=4, default_budget_s=5.0, solve_grace_s=5.0)


def _body(**spec):
    return {"plant": {"expr": ROLL}, "dt": 0.04, "structure": "pi", "spec": spec,
            "options": {"seed": 0, "time_budget_s": 5}}


@pytest.mark.parametrize("spec, loc", [
    ({"ms_max": 0.8}, ["body", "spec", "ms_max"]),               # Ms >= 1 by definition
    ({"mt_max": 0.9}, ["body", "spec", "mt_max"]),               # T(0) = 1 with zero steady-state error
    ({"mks_max": -1}, ["body", "spec", "mks_max"]),
    ({"disk_margin_min": 2.5}, ["body", "spec", "disk_margin_min"]),
])
def test_impossible_specs_are_422_at_the_field(client, spec, loc):
    r = client.post("/tune", json=_body(**spec))
    assert r.status_code == 422, r.text
    assert any(d["loc"] == loc for d in r.json()["detail"]), r.json()


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_limits_are_reported_and_an_unmet_spec_says_why(client):
    r = client.post("/tune", json=_body(control_peak_max=2.0, mt_max=1.3, mks_max=50))
    assert r.status_code == 200, r.text
    d = r.json()
    for k in ("mt", "mks", "control_peak"):
        assert k in d["metrics"]
    assert d["meets_spec"] is False and "control_peak" in d["failing"]
    why = [x for x in d["reasons"] if "control_peak" in x["constraints"]]
    assert why and why[0]["suggest"]["control_peak_max"] >= 1 / 0.2655
    assert d["objective"]["name"] == "settling_time"
