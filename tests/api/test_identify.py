"""``POST /identify`` and the stored identifications, through FastAPI's TestClient (one solver)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from flight import AXES, fly

from api import testing
from api.deps import get_identify_job
from api.settings import Settings

MAX_BODY = 16_384  # every other route
MAX_IDENTIFY_BODY = 16_000_000


@pytest.fixture(scope="module")
def settings(tmp_path_factory):
    db = tmp_path_factory.mktemp("api-identify") / "tuner.db"
    return Settings(database_url=f"sqlite:///{db}", workers=1, queue_size=4, max_body_bytes=MAX_BODY,
                    max_identify_body_bytes=MAX_IDENTIFY_BODY)


@pytest.fixture(scope="module")
def log():
    return fly(*AXES["roll"], seed=9, duration_s=60.0)


@pytest.fixture(scope="module")
def body(log):
    return {"input": log.u.tolist(), "output": log.y.tolist(), "time": log.t.tolist(), "poles": 2,
            "delay_step": 0.04}


@pytest.fixture(scope="module")
def stored(client, body):
    r = client.post("/identify", json=body)
    assert r.status_code == 200, r.text
    return r.json()


def test_identify_answers_the_model_and_stores_it(client, stored, body):
    d = stored
    assert d["quality"] == "good" and d["cost"] < 50 and d["model"]["delay"] == pytest.approx(0.04)
    assert {"num", "den", "delay", "parameters"} <= set(d["model"])
    assert {"w", "mag_db", "phase_deg", "coherence"} <= set(d["frequency_response"])
    assert set(d["uncertainty"]) == {"gain", "pole_wn_1_rad_s", "pole_zeta_1", "delay_s"}
    assert d["validation"]["theil_u"] < 0.3 and d["n_samples"] == len(body["input"])
    listed = client.get("/identifications").json()
    assert listed["total"] >= 1 and listed["items"][0]["id"] == d["id"]
    assert listed["items"][0]["quality"] == "good" and listed["items"][0]["n_samples"] == len(body["input"])
    rec = client.get(f"/identifications/{d['id']}").json()
    assert rec["model"] == d["model"] and rec["cost"] == d["cost"]
    assert rec["request"]["poles"] == 2 and rec["request"]["sampling"] == "time" and "input" not in rec["request"]
    data = client.get(f"/identifications/{d['id']}/data").json()
    assert data["input"] == body["input"] and data["time"] == body["time"] and data["rate_hz"] is None


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_plots_of_a_stored_identification(client, stored):
    png = client.get(f"/identifications/{stored['id']}/plot.png")
    assert png.status_code == 200 and png.headers["content-type"] == "image/png" and png.content[:4] == b"\x89PNG"
    svg = client.get(f"/identifications/{stored['id']}/plot.svg")
    assert svg.status_code == 200 and b"<svg" in svg.content[:500] and b"coherence" in svg.content
    assert client.get("/identifications/" + "0" * 32).status_code == 404
    assert client.get("/identifications/" + "0" * 32 + "/plot.png").status_code == 404


def _422(client, body, loc, match, content: str | None = None):
    r = client.post("/identify", json=body) if content is None else client.post(
        "/identify", content=content, headers={"content-type": "application/json"})
    assert r.status_code == 422, r.text
    assert "Traceback" not in r.text
    item = r.json()["detail"][0]
    assert item["loc"] == loc, item
    assert match in item["msg"], item["msg"]
    return item


def test_bad_data_is_422_naming_the_field(client, body, log):
    n = len(body["input"])
    _422(client, {**body, "output": body["output"][:-1]}, ["body", "output"], f"output has {n - 1} samples")
    _422(client, {**body, "rate_hz": 50.0}, ["body", "time"], "give exactly one of time")
    _422(client, {k: v for k, v in body.items() if k != "time"}, ["body", "rate_hz"], "give exactly one of time")
    _422(client, {**body, "time": body["time"][:-1]}, ["body", "time"], f"time has {n - 1} samples")
    _422(client, {**body, "zeros": 3}, ["body", "zeros"], "zeros=3 is more than poles=2")
    _422(client, {**body, "band": [10.0, 1.0]}, ["body", "band"], "w_min < w_max")
    _422(client, {**body, "input": body["input"][:100], "output": body["output"][:100], "time": body["time"][:100]},
         ["body", "input"], "at least 128")
    _422(client, {**body, "poles": 9}, ["body", "poles"], "less than or equal to 8")
    _422(client, {**body, "delay": "soon"}, ["body", "delay", "literal['auto']"], "'auto'")
    _422(client, {**body, "extra": 1}, ["body", "extra"], "Extra inputs are not permitted")
    bad = dict(body, output=list(body["output"]))
    bad["output"][17] = float("nan")
    _422(client, None, ["body", "output", 17], "finite number", content=json.dumps(bad))  # NaN literal


def test_unusable_records_found_by_the_library_are_422(client, body, log):
    it = _422(client, {**body, "input": [0.25] * len(body["input"])}, ["body", "input"], "input is constant")
    assert it["type"] == "invalid_data"
    _422(client, {**body, "band": [0.05, 10.0]}, ["body", "band"], "too few cycles")
    t = list(body["time"])
    t[500:] = [x + 0.01 for x in t[500:]]
    _422(client, {**body, "time": t}, ["body", "time"], "not uniformly sampled")
    noise = np.random.default_rng(1).standard_normal(len(body["input"])).tolist()
    _422(client, {**body, "output": noise}, ["body", "output"], "no coherent band")
    _422(client, {**body, "delay": 0.05}, ["body", "delay"], "not a whole number of delay_step=0.04 s")


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_a_200000_sample_log_is_accepted_on_identify_but_other_routes_keep_their_cap(client):
    n = 200_000
    t = np.arange(n) / 1000.0  # 200 s at 1 kHz
    rng = np.random.default_rng(0)
    u = np.sin(0.4 * t + 0.5 * (30.0 / t[-1]) * t ** 2) + 0.05 * rng.standard_normal(n)
    y = np.empty(n)  # 5/(s+5), ZOH at 1 ms (a first-order recursion), plus noise
    a = np.exp(-5.0 / 1000.0)
    x = 0.0
    for k in range(n):
        y[k] = x
        x = a * x + (1 - a) * u[k]
    y += 0.01 * rng.standard_normal(n)
    content = json.dumps({"input": u.tolist(), "output": y.tolist(), "time": t.tolist(), "poles": 1})
    assert len(content) > 10_000_000
    r = client.post("/identify", content=content, headers={"content-type": "application/json"})
    assert r.status_code == 200, r.text[:500]
    d = r.json()
    assert d["n_samples"] == n and d["quality"] == "good"
    assert d["model"]["parameters"]["pole_1_rad_s"] == pytest.approx(5.0, rel=0.05)
    big = client.post("/identify", content=b"[" + b"0," * (MAX_IDENTIFY_BODY // 2) + b"0]",
                      headers={"content-type": "application/json"})
    assert big.status_code == 413
    detail = big.json()["detail"]  # the byte cap, and how to send a longer record (the record limit is the CLI's)
    assert detail.startswith(f"request body larger than {MAX_IDENTIFY_BODY} bytes") and "ULog upload" in detail
    assert "(ulog.data, base64)" in detail  # the field the body has (issue 42: it named ulog.data_base64)
    tune = client.post("/tune", content=b"x" * (MAX_BODY + 1), headers={"content-type": "application/json"})
    assert tune.status_code == 413 and tune.json() == {"detail": f"request body larger than {MAX_BODY} bytes"}


def test_the_service_and_the_command_line_state_the_same_record_limit():
    """Issue 31: one record limit (tuner.identify.data.MAX_SAMPLES) for a CSV's rows, a ULog's grid and the
    service's sample arrays."""
    from api.schemas_identify import MAX_SAMPLES as SERVICE
    from tuner.identify.csvlog import MAX_ROWS
    from tuner.identify.data import MAX_SAMPLES

    assert SERVICE == MAX_ROWS == MAX_SAMPLES == 2_000_000


def test_identification_time_limit_is_504(app, client, body, override_settings):
    override_settings(identify_timeout_s=0.3)
    app.dependency_overrides[get_identify_job] = lambda: testing.sleep_job
    try:
        r = client.post("/identify", json=body)
    finally:
        app.dependency_overrides.pop(get_identify_job, None)
    assert r.status_code == 504 and "took longer than 0.3 s" in r.json()["detail"]


def test_api_key_guards_identification(client, body, stored, override_settings):
    from pydantic import SecretStr

    override_settings(api_key=SecretStr("k"))
    for method, path, payload in [("post", "/identify", body), ("get", "/identifications", None),
                                  ("get", f"/identifications/{stored['id']}", None),
                                  ("get", f"/identifications/{stored['id']}/data", None)]:
        assert client.request(method, path, json=payload).status_code == 401
    assert client.get("/identifications", headers={"X-API-Key": "k"}).status_code == 200


def test_a_fixed_delay_longer_than_the_record_is_422_naming_delay(client):
    from api.schemas_identify import IDENTIFY_EXAMPLE

    r = client.post("/identify", json={**IDENTIFY_EXAMPLE, "holdout": 0.2, "delay": 30.02})  # the /docs example
    assert r.status_code == 422, r.text
    (item,) = r.json()["detail"]
    assert item["loc"] == ["body", "delay"] and "quarter of the fitted part" in item["msg"]


def test_identification_plots_are_private_when_a_key_is_set(client, stored, override_settings):
    from pydantic import SecretStr

    override_settings(api_key=SecretStr("k"))
    r = client.get(f"/identifications/{stored['id']}/plot.svg", headers={"X-API-Key": "k"})
    assert r.status_code == 200 and r.headers["cache-control"].startswith("private")
    assert r.headers["x-content-type-options"] == "nosniff"


def test_stored_identifications_have_a_quota(client, body, stored, override_settings):
    listed = client.get("/identifications").json()["total"]
    override_settings(max_identifications=listed)
    r = client.post("/identify", json=body)
    assert r.status_code == 507 and "TUNER_MAX_IDENTIFICATIONS" in r.json()["detail"]
    override_settings(max_identifications=listed + 10, max_identification_samples=len(body["input"]))
    r = client.post("/identify", json=body)
    assert r.status_code == 507 and "TUNER_MAX_IDENTIFICATION_SAMPLES" in r.json()["detail"]
    assert client.get("/identifications").json()["total"] == listed  # nothing was stored


def test_a_time_column_in_microseconds_is_422_at_time_unit_until_said(client):
    """Issue 42: PX4's timestamps (µs) read as seconds; the unit is asked for, then used."""
    import numpy as np

    rng = np.random.default_rng(3)
    u = rng.standard_normal(600)
    y = np.convolve(u, [0.0, 0.5, 0.3, 0.1])[:600]
    body = {"input": u.tolist(), "output": y.tolist(), "time": (5_000_000 + 4000 * np.arange(600)).tolist(),
            "poles": 1, "holdout": 0}
    r = client.post("/identify", json=body)
    assert r.status_code == 422, r.text
    item = r.json()["detail"][0]
    assert item["loc"] == ["body", "time_unit"] and "microseconds" in item["msg"], item
    r = client.post("/identify", json={**body, "time_unit": "us"})
    assert r.status_code == 200, r.text
    assert r.json()["rate_hz"] == 250.0
