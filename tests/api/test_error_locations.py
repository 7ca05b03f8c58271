"""Every 422 names a field the request has, and its advice applies to the request as sent (issue 31): a stiff plant
without dt is tuned (the NLP's internal model of it is the search's business, not the request's), a plant whose gain
scale leaves double precision is refused at the plant, an identification's loop error points at the
identification, and no command-line flag appears in an answer."""

from __future__ import annotations

import numpy as np
import pytest

from api.settings import Settings


@pytest.fixture(scope="module")
def settings(tmp_path_factory):
    db = tmp_path_factory.mktemp("loc") / "tuner.db"
    return Settings(database_url=f"sqlite:///{db}", workers=1, queue_size=4, default_budget_s=2.0, solve_grace_s=10.0)


def test_a_stiff_plant_without_dt_is_not_a_dt_error(client):
    r = client.post("/tune", json={"plant": {"expr": "1/((s+1)*(1e-9*s+1)*(1e-8*s+1))"}, "structure": "pid",
                                   "options": {"time_budget_s": 2}})
    assert r.status_code == 200, r.text  # (whether the NLP got to try within the budget depends on the machine)
    assert "meets_spec" in r.json()


def test_the_nlp_that_cannot_model_a_loop_is_a_note():
    """The library: the local NLP's internal model of a stiff continuous loop fails; the tune goes on and says so."""
    from tuner import tune
    from tuner.plant import plant_from_expr

    r = tune(plant_from_expr("1/((s+1)*(1e-9*s+1)*(1e-8*s+1))"), structure="pid", time_budget_s=30, effort="fast")
    assert any("local NLP could not model" in n for n in r.solver.get("notes", []))


def test_a_gain_beyond_double_precision_is_the_plants(client):
    r = client.post("/tune", json={"plant": {"num": [1e-300], "den": [1, 1]}, "structure": "pi"})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "plant"], r.text


def test_an_identifications_loop_error_points_at_it(client):
    rng = np.random.default_rng(0)
    u = rng.standard_normal(3000)
    y = np.convolve(u, [0.5, 0.3, 0.1])[:3000] + 0.01 * rng.standard_normal(3000)
    r = client.post("/identify", json={"input": u.tolist(), "output": y.tolist(), "rate_hz": 100.0, "poles": 1,
                                       "delay": 5.0})
    assert r.status_code == 200, r.text
    ident = r.json()["id"]
    r = client.post("/tune", json={"identification_id": ident, "structure": "pi", "dt": 0.001})
    assert r.status_code == 422, r.text
    d = r.json()["detail"][0]
    assert d["loc"] == ["body", "identification_id"] and "dt null" not in d["msg"], d


def test_the_closed_loop_verdict_names_no_flag(client):
    from closed_loop import fly

    lg = fly("hover", seconds=20, seed=3)
    body = {"input": lg.u.tolist(), "output": lg.y.tolist(), "rate_hz": 400.0, "poles": 2}
    r = client.post("/identify", json=body)
    assert r.status_code == 200
    d = r.json()
    assert "--" not in d["verdict"] and all("--" not in w for w in d["warnings"])


@pytest.mark.parametrize("controller, loc", [
    ({"structure": "pi", "gains": {"Kp": 1e-300, "Ki": 1e300}}, ["body", "controller", "gains"]),
    ({"expr": "(1e-300*s + 1e300)/s"}, ["body", "controller", "expr"]),
])
def test_a_controller_zero_beyond_double_precision_is_a_422_at_the_controller(client, controller, loc):
    r = client.post("/analyze", json={"plant": {"expr": "1/(s + 1)"}, "controller": controller})
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == loc, r.text
    assert "double precision" in r.json()["detail"][0]["msg"], r.text


@pytest.mark.parametrize("body, loc, kind", [
    ({"actuator": {"u_max": 1.0, "step_size": 0.0}}, ["body", "actuator", "step_size"], "value_error"),
    ({"actuator": {"u_min": 1.0, "u_max": 0.5}}, ["body", "actuator", "u_min"], "value_error"),
    ({"actuator": {"step_size": 2.0}}, ["body", "actuator", "u_max"], "missing"),
    ({"controller": {"num": [1.0]}}, ["body", "controller", "den"], "missing"),
    ({"controller": {"gains": {"Kp": 1.0}}}, ["body", "controller", "structure"], "missing"),
    ({"plant": {"den": [1.0, 1.0]}}, ["body", "plant", "num"], "missing"),
])
def test_a_check_across_fields_points_at_the_field_it_is_about(client, body, loc, kind):
    """Issue 42: these 422s named the object (["body", "actuator"], with "Value error, " before the message), not the
    field to change; the page shows a 422 at the field its loc names."""
    base = {"plant": {"expr": "1/(s+1)"}, "dt": 0.1, "controller": {"expr": "2"}}
    r = client.post("/analyze", json={**base, **body})
    assert r.status_code == 422, r.text
    d = r.json()["detail"][0]
    assert d["loc"] == loc and d["type"] == kind and not d["msg"].startswith("Value error"), d
