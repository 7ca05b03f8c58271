"""Every route of the service, and every bad-input answer, through FastAPI's TestClient.

One app for the module (two real solver processes, SQLite in a temporary directory);
per-test behaviour (settings, API key) comes in through ``dependency_overrides``.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from numpy.testing import assert_allclose
from quadrotor import DT, ROLL, ROLL_C, YAW

from api.settings import Settings

MAX_BODY = 16_384
BUDGET = 1.5  # s, per tune in this module


@pytest.fixture(scope="module")
def settings(tmp_path_factory):
    db = tmp_path_factory.mktemp("api") / "tuner.db"
    return Settings(database_url=f"sqlite:///{db}", workers=2, queue_size=8, default_budget_s=BUDGET,
                    solve_grace_s=5.0, max_body_bytes=MAX_BODY, max_plants=4)


ROLL_BODY = {"plant": {"expr": ROLL}, "dt": DT, "structure": "pid_z", "options": {"seed": 0, "time_budget_s": BUDGET}}


@pytest.fixture(scope="module")
def roll(client):
    r = client.post("/tune", json=ROLL_BODY)
    assert r.status_code == 200, r.text
    return r.json()


def no_traceback(r) -> None:
    assert "Traceback" not in r.text and 'File "' not in r.text


# -- /health and the docs -----------------------------------------------------------------

def test_health_reports_status_database_workers_and_versions(client):
    r = client.get("/health")
    assert r.status_code == 200
    body = r.json()
    assert body["status"] == "ok" and body["database"] == "ok"
    assert body["workers"]["size"] == 2
    for pkg in ("python", "tuner", "numpy", "scipy", "control", "casadi", "optuna", "fastapi", "sqlalchemy"):
        assert re.match(r"\d+\.\d+", body["versions"][pkg]), (pkg, body["versions"][pkg])
    # (the suite runs with TUNER_NLP_COMPILE=off: no compiled code, and the cache folder not read)
    assert body["nlp_code"] == {"mode": "off", "pending": 0, "compiled": 0, "marked": 0}


def test_health_says_how_many_nlp_compiles_are_pending(client, tmp_path, monkeypatch):
    """The solvers compile new NLP shapes in the background without saying so: /health counts them (and the
    compiled and marked shapes) from the cache folder; information only, the status stays 200."""
    import os

    from tuner.optimize.nlp import codecache

    monkeypatch.setenv("TUNER_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("TUNER_NLP_COMPILE", "auto")
    monkeypatch.setattr(codecache, "enabled", lambda: True)  # (whether or not this machine has gcc)
    monkeypatch.setattr(codecache, "MAX_SOURCE_BYTES", 4_000_000)
    root = tmp_path / "nlp"
    (root / "done").mkdir(parents=True)
    (root / "done" / "sums.json").write_text("{}")
    for name in ("a", "b"):  # two builds under way (this process stands in for their builders)
        (root / f"{name}.lock").write_text(str(os.getpid()))
    (root / "big.failed").write_text(json.dumps({"reason": "too_large", "bytes": 60_000_000, "bound": 4_000_000}))
    (root / "was_big.failed").write_text(json.dumps({"reason": "too_large", "bytes": 3_000_000, "bound": 2_000_000}))
    r = client.get("/health")
    assert r.status_code == 200 and r.json()["status"] == "ok"
    assert r.json()["nlp_code"] == {"mode": "auto", "pending": 2, "compiled": 1, "marked": 1}
    (root / "a.lock").unlink()  # (a build done)
    monkeypatch.setenv("TUNER_NLP_COMPILE", "load")
    assert client.get("/health").json()["nlp_code"] == {"mode": "load", "pending": 1, "compiled": 1, "marked": 1}


def test_health_stays_200_whatever_the_nlp_code_cache_holds(client, tmp_path, monkeypatch):
    """A cache folder of hostile markers and locks (a reviewer's: Infinity bytes, deep JSON, a FIFO, a lock holding
    a superscript digit) once made /health answer 500; and whatever the cache's reader raises is said in the
    answer, never the status code."""
    from tests.tuner.test_codecache_safety import HOSTILE_LOCKS, HOSTILE_MARKERS, _hostile_cache
    from tuner.optimize.nlp import codecache

    monkeypatch.setenv("TUNER_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("TUNER_NLP_COMPILE", "auto")
    monkeypatch.setattr(codecache, "enabled", lambda: True)
    _hostile_cache(tmp_path / "nlp")
    r = client.get("/health")
    assert r.status_code == 200 and r.json()["status"] == "ok"
    assert r.json()["nlp_code"] == {"mode": "auto", "pending": len(HOSTILE_LOCKS) + 1, "compiled": 0,
                                    "marked": len(HOSTILE_MARKERS) + 2}

    def unreadable():
        raise PermissionError("[Errno 13] Permission denied: 'nlp'")

    monkeypatch.setattr(codecache, "status", unreadable)
    r = client.get("/health")
    assert r.status_code == 200 and r.json()["status"] == "ok"
    assert r.json()["nlp_code"] == {"mode": "auto", "pending": None, "compiled": None, "marked": None,
                                    "error": "the NLP code cache could not be read: PermissionError"}


def test_openapi_lists_every_route_with_the_roll_model_as_example(client):
    schema = client.get("/openapi.json").json()
    paths = set(schema["paths"])
    assert {"/tune", "/analyze", "/tunes", "/tunes/{tune_id}", "/tunes/{tune_id}/plot.png",
            "/tunes/{tune_id}/plot.svg", "/health"} <= paths
    examples = schema["paths"]["/tune"]["post"]["requestBody"]["content"]["application/json"]["examples"]
    roll = examples["quadrotor roll"]["value"]
    assert roll["plant"]["expr"] == ROLL and roll["dt"] == DT and roll["structure"] == "pid_z"
    docs = client.get("/docs")
    assert docs.status_code == 200 and "swagger" in docs.text.lower()


# -- POST /tune ---------------------------------------------------------------------------

def test_tune_roll_answers_the_cli_fields_plus_id(roll):
    assert re.fullmatch(r"[0-9a-f]{32}", roll["id"])
    for key in ("structure", "gains", "controller", "metrics", "checks", "meets_spec", "failing", "solver", "spec"):
        assert key in roll
    assert roll["structure"] == "pid_z" and set(roll["gains"]) == {"K", "a1", "a2"}
    g, c = roll["gains"], roll["controller"]
    # C(z) = K (z^2 + a1 z + a2) / (z (z - 1)), re-derived from the gains
    assert_allclose(c["num"], [g["K"], g["K"] * g["a1"], g["K"] * g["a2"]], rtol=1e-12)
    assert_allclose(c["den"], [1.0, -1.0, 0.0], atol=1e-12)
    assert c["dt"] == DT
    assert roll["meets_spec"] == all(ch["ok"] for ch in roll["checks"])
    assert roll["failing"] == sorted(ch["name"] for ch in roll["checks"] if not ch["ok"])
    assert roll["spec"]["phase_margin_min_deg"] == 60.0  # the default spec was applied
    assert roll["solver"]["seed"] == 0


def test_tuned_controller_reverifies_to_the_same_metrics(client, roll):
    """/analyze on the returned coefficients gives the numbers /tune reported."""
    c = roll["controller"]
    r = client.post("/analyze", json={"plant": {"expr": ROLL}, "dt": DT,
                                      "controller": {"num": c["num"], "den": c["den"]}})
    assert r.status_code == 200, r.text
    again = r.json()["metrics"]
    for k, v in roll["metrics"].items():
        if isinstance(v, float):
            assert_allclose(again[k], v, rtol=1e-9, atol=1e-12, err_msg=k)
        else:
            assert again[k] == v, k


def test_robust_tune_reports_every_plant(client):
    heavier = "0.2655*1.3*14.8528^2/(s^2+14.195*s+14.8528^2)"  # 30 % more gain
    body = {**ROLL_BODY, "plants": [{"expr": heavier}]}
    r = client.post("/tune", json=body)
    assert r.status_code == 200, r.text
    out = r.json()
    assert len(out["plants"]) == 2
    assert out["meets_spec"] == all(p["meets_spec"] for p in out["plants"])
    assert out["metrics"] == out["plants"][0]["metrics"]  # nominal first


def test_continuous_tune_of_the_yaw_model(client):
    r = client.post("/tune", json={"plant": {"num": [0.2843 * 18.611], "den": [1, 18.611]}, "structure": "pi",
                                   "options": {"time_budget_s": 1.0}})
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["controller"]["dt"] is None and set(out["gains"]) == {"Kp", "Ki"}


# -- stored results -----------------------------------------------------------------------

def test_get_tune_returns_what_post_answered_and_the_request(client, roll):
    r = client.get(f"/tunes/{roll['id']}")
    assert r.status_code == 200
    got = r.json()
    request = got.pop("request")
    assert got == roll
    assert request["plant"]["expr"] == ROLL and request["structure"] == "pid_z"
    assert request["options"]["time_budget_s"] == BUDGET and request["spec"]["overshoot_max_pct"] == 10.0


def test_list_tunes_newest_first_with_paging(client, roll):
    second = client.post("/tune", json={**ROLL_BODY, "options": {"seed": 1, "time_budget_s": 0.5}}).json()
    page = client.get("/tunes", params={"limit": 1, "offset": 0}).json()
    assert page["limit"] == 1 and page["offset"] == 0 and page["total"] >= 2
    assert [i["id"] for i in page["items"]] == [second["id"]]
    ids = [i["id"] for i in client.get("/tunes", params={"limit": 100}).json()["items"]]
    assert ids.index(second["id"]) < ids.index(roll["id"])
    item = next(i for i in client.get("/tunes", params={"limit": 100}).json()["items"] if i["id"] == roll["id"])
    assert item == {"id": roll["id"], "created_at": roll["created_at"], "structure": "pid_z",
                    "meets_spec": roll["meets_spec"]}
    beyond = client.get("/tunes", params={"limit": 5, "offset": 10_000}).json()
    assert beyond["items"] == [] and beyond["total"] == page["total"]


PLOT_SIZE = {"all": (1900, 620), "step": (750, 540), "bode": (750, 560), "nyquist": (620, 580)}  # figsize x 100 dpi


@pytest.mark.parametrize("kind", [None, "all", "step", "bode", "nyquist"])
@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_plot_png_of_each_kind(client, roll, kind):
    r = client.get(f"/tunes/{roll['id']}/plot.png", params={} if kind is None else {"kind": kind})
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    assert r.content[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = int.from_bytes(r.content[16:20], "big"), int.from_bytes(r.content[20:24], "big")
    assert (width, height) == PLOT_SIZE[kind or "all"]


def _svg_text(svg: str) -> str:
    """The text of an SVG (text kept as text: svg.fonttype none), for looking up labels."""
    import xml.etree.ElementTree as ET

    root = ET.fromstring(svg)
    assert root.tag.endswith("svg")
    return " ".join("".join(el.itertext()) for el in root.iter() if el.tag.endswith("text"))


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_plot_svg_of_each_kind_shows_what_it_should(client, roll):
    m = roll["metrics"]
    pm = f"PM {m['phase_margin_deg']:.1f}° at {m['crossover_rad_s']:.3g} rad/s"
    expected = {
        "step": ["output y(t) between samples", "at the samples", "settling band ±2 %", "overshoot limit 10 %",
                 f"settled at {m['settling_time_s']:.3g} s", f"peak |u| {m['control_peak']:.3g}", "control u"],
        "bode": [pm, f"GM {m['gain_margin_db']:.1f} dB", "phase of L"],
        "nyquist": [f"1/Ms = {1 / m['ms']:.3g}", "unit circle", "Im L"],
    }
    texts = {}
    for kind in ("step", "bode", "nyquist", "all"):
        r = client.get(f"/tunes/{roll['id']}/plot.svg", params={"kind": kind})
        assert r.status_code == 200 and r.headers["content-type"].startswith("image/svg+xml")
        texts[kind] = _svg_text(r.text)
    for kind, labels in expected.items():
        for label in labels:
            assert label in texts[kind], (kind, label)
            assert label in texts["all"], ("all", label)
    assert "phase of L" not in texts["step"] and "control u" not in texts["bode"]


def test_bad_plot_kind_is_422_with_loc(client, roll):
    r = client.get(f"/tunes/{roll['id']}/plot.svg", params={"kind": "polar"})
    assert r.status_code == 422
    (item,) = r.json()["detail"]
    assert item["loc"] == ["query", "kind"] and "step" in item["msg"]


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_plot_of_a_robust_tune_labels_every_plant(client):
    lighter, heavier = (f"0.2655*{k}*14.8528^2/(s^2+14.195*s+14.8528^2)" for k in (0.8, 1.2))
    r = client.post("/tune", json={**ROLL_BODY, "plants": [{"expr": lighter}, {"expr": heavier}]})
    assert r.status_code == 200, r.text
    for kind in ("step", "bode", "nyquist"):
        svg = client.get(f"/tunes/{r.json()['id']}/plot.svg", params={"kind": kind})
        assert svg.status_code == 200
        text = _svg_text(svg.text)
        assert all(name in text for name in ("nominal", "plant 2", "plant 3")), kind
        assert "plant 4" not in text


@pytest.mark.parametrize("path", ["/tunes/{}", "/tunes/{}/plot.png", "/tunes/{}/plot.svg"])
def test_unknown_id_is_404(client, path):
    r = client.get(path.format("0" * 32))
    assert r.status_code == 404
    assert "no stored tune result" in r.json()["detail"]


# -- POST /analyze ------------------------------------------------------------------------

def test_analyze_the_thesis_roll_loop_three_ways(client):
    """Expression, coefficients and structure+gains describe the same controller: same numbers."""
    base = {"plant": {"expr": ROLL}, "dt": DT}
    by_expr = client.post("/analyze", json={**base, "controller": {"expr": ROLL_C}})
    k, a1, a2 = 3.868, -1.305, 0.5668
    by_coeffs = client.post("/analyze", json={**base, "controller": {"num": [k, k * a1, k * a2], "den": [1, -1, 0]}})
    by_gains = client.post("/analyze", json={**base, "controller": {"structure": "pid_z",
                                                                     "gains": {"K": k, "a1": a1, "a2": a2}}})
    outs = [r.json() for r in (by_expr, by_coeffs, by_gains)]
    assert [r.status_code for r in (by_expr, by_coeffs, by_gains)] == [200, 200, 200]
    for o in outs[1:]:
        for key, v in outs[0]["metrics"].items():
            if isinstance(v, float):
                assert_allclose(o["metrics"][key], v, rtol=1e-9, atol=1e-12, err_msg=key)
    m = outs[0]["metrics"]
    assert m["stable"] is True and m["gain_margin_lower_db"] == "-Infinity"  # the documented encoding
    assert outs[0]["controller"] == {"num": [k, k * a1, k * a2], "den": [1.0, -1.0, 0.0], "dt": DT}


def test_analyze_matches_the_library(client):
    from tuner.analysis.verify import analyze
    from tuner.controllers import controller_from_expr
    from tuner.jsonio import jsonable
    from tuner.plant import plant_from_expr

    ref = jsonable(analyze(plant_from_expr(YAW), controller_from_expr("2+40/s", dt=None)).to_dict())
    r = client.post("/analyze", json={"plant": {"expr": YAW}, "controller": {"expr": "2+40/s"}})
    assert r.status_code == 200
    got = r.json()
    assert got["meets_spec"] == ref["meets_spec"]
    assert [c["name"] for c in got["checks"]] == [c["name"] for c in ref["checks"]]
    for key, v in ref["metrics"].items():
        if isinstance(v, float):
            assert_allclose(got["metrics"][key], v, rtol=1e-12, err_msg=key)
        else:
            assert got["metrics"][key] == v


# -- 422: each names the field ------------------------------------------------------------

P = {"expr": ROLL}
T = {"plant": P, "dt": DT, "structure": "pid_z", "options": {"time_budget_s": 0.5}}
A = {"plant": P, "dt": DT, "controller": {"expr": ROLL_C}}
Z_PLANT = {"expr": "0.1/(z-0.9)", "dt": DT}


def _with(base, **changes):
    out = json.loads(json.dumps(base))
    out.update(changes)
    return out


INVALID = [
    # (id, route, body, loc, words the message must contain)
    ("missing-fields", "/tune", {}, ["body", "structure"], "required"),
    ("missing-plant", "/tune", {"structure": "pid_z", "dt": DT}, ["body", "plant"], "identification_id"),
    ("robust-without-identification", "/tune", _with(T, robust=2), ["body", "robust"], "identification_id"),
    ("plant-empty", "/tune", _with(T, plant={}), ["body", "plant"], "expr"),
    ("plant-both-forms", "/tune", _with(T, plant={"expr": ROLL, "num": [1], "den": [1, 1]}), ["body", "plant"],
     "either"),
    ("expr-syntax", "/tune", _with(T, plant={"expr": "1/(s+1"}), ["body", "plant", "expr"], "position"),
    ("expr-two-variables", "/tune", _with(T, plant={"expr": "1/(s+z)"}), ["body", "plant", "expr"], ""),
    ("expr-order-21", "/tune", _with(T, plant={"expr": "1/(s+1)^21"}), ["body", "plant", "expr"], "order 21"),
    ("improper", "/tune", _with(T, plant={"num": [1, 0, 0], "den": [1, 1]}), ["body", "plant", "num"], "improper"),
    ("den-zero", "/tune", _with(T, plant={"num": [1], "den": [0, 0]}), ["body", "plant", "den"], "zero"),
    ("order-21-coeffs", "/tune", _with(T, plant={"num": [1], "den": [1] * 22}), ["body", "plant", "den"], "at most 21"),
    ("coefficient-too-large", "/tune", _with(T, plant={"num": [1e101], "den": [1, 1]}), ["body", "plant", "num", 0],
     "less than or equal"),
    ("coefficients-overflow-when-normalised", "/tune", _with(T, plant={"num": [1e100], "den": [1e-300, 1]}),
     ["body", "plant", "den"], "overflow"),
    ("coefficient-string", "/tune", _with(T, plant={"num": ["Infinity"], "den": [1, 1]}),
     ["body", "plant", "num", 0], "number"),
    ("z-plant-needs-dt", "/tune", _with(T, plant={"expr": "0.1/(z-0.9)"}), ["body", "plant", "dt"], "dt"),
    ("s-plant-has-no-dt", "/tune", _with(T, plant={"expr": ROLL, "dt": 0.01}), ["body", "plant", "dt"], "continuous"),
    ("discrete-structure-needs-dt", "/tune", _with(T, dt=None), ["body", "dt"], "discrete"),
    ("dt-zero", "/tune", _with(T, dt=0), ["body", "dt"], "greater than or equal to 0.000001"),
    ("dt-mismatch", "/tune", _with(T, plant=Z_PLANT, dt=0.05), ["body", "dt"], "discrete at dt=0.04"),
    ("delay-not-whole-samples", "/tune", _with(T, plant={**Z_PLANT, "delay": 0.05}), ["body", "plant", "delay"],
     "a plant given in z needs a multiple of dt"),
    ("delay-negative", "/tune", _with(T, plant={"expr": ROLL, "delay": -1}), ["body", "plant", "delay"], ""),
    ("unknown-structure", "/tune", _with(T, structure="pidd"), ["body", "structure"], "pid_z"),
    ("spec-out-of-range", "/tune", _with(T, spec={"phase_margin_min_deg": 100}),
     ["body", "spec", "phase_margin_min_deg"], "90"),
    ("spec-unknown-field", "/tune", _with(T, spec={"pm": 60}), ["body", "spec", "pm"], "not permitted"),
    ("budget-above-60", "/tune", _with(T, options={"time_budget_s": 61}), ["body", "options", "time_budget_s"], "60"),
    ("budget-zero", "/tune", _with(T, options={"time_budget_s": 0}), ["body", "options", "time_budget_s"], ""),
    ("seed-negative", "/tune", _with(T, options={"seed": -1}), ["body", "options", "seed"], ""),
    ("too-many-plants", "/tune", _with(T, plants=[P] * 4), ["body", "plants"], "at most 4"),
    ("bad-robust-plant", "/tune", _with(T, plants=[P, {"expr": "1/(s+"}]), ["body", "plants", 1, "expr"], ""),
    ("robust-plants-at-two-dts", "/tune", _with(T, dt=None, plants=[Z_PLANT, {"expr": "0.1/(z-0.9)", "dt": 0.05}],
                                                plant=Z_PLANT), ["body", "plants", 1, "dt"], "different"),
    ("unknown-top-field", "/tune", _with(T, foo=1), ["body", "foo"], "not permitted"),
    ("controller-missing", "/analyze", {"plant": P, "dt": DT}, ["body", "controller"], "required"),
    ("controller-two-forms", "/analyze", _with(A, controller={"expr": ROLL_C, "num": [1], "den": [1]}),
     ["body", "controller"], "exactly one"),
    ("controller-in-s-with-dt", "/analyze", _with(A, controller={"expr": "2+40/s"}), ["body", "controller", "expr"],
     "in s"),
    ("controller-improper", "/analyze", _with(A, controller={"num": [1, 0, 0], "den": [1, 1]}),
     ["body", "controller", "num"], "improper"),
    ("controller-gains-missing", "/analyze", _with(A, controller={"structure": "pid_z", "gains": {"K": 1}}),
     ["body", "controller", "gains"], "missing"),
    ("controller-structure-needs-dt", "/analyze", _with(A, dt=None, controller={"structure": "pid_z",
                                                                                "gains": {"K": 1, "a1": 0, "a2": 0}}),
     ["body", "dt"], "discrete"),
    ("analyze-bad-plant", "/analyze", _with(A, plant={"expr": "s+"}), ["body", "plant", "expr"], ""),
]


@pytest.mark.parametrize("route, body, loc, words", [c[1:] for c in INVALID], ids=[c[0] for c in INVALID])
def test_invalid_input_is_422_naming_the_field(client, route, body, loc, words):
    r = client.post(route, json=body)
    assert r.status_code == 422, r.text
    no_traceback(r)
    detail = r.json()["detail"]
    hit = [d for d in detail if d["loc"] == loc]
    assert hit, f"no error at {loc}: {detail}"
    assert words.lower() in hit[0]["msg"].lower(), hit[0]["msg"]


@pytest.mark.parametrize("raw, loc", [
    ('{"plant": {"num": [NaN], "den": [1, 1]}, "structure": "pi"}', ["body", "plant", "num", 0]),
    ('{"plant": {"num": [1], "den": [1, Infinity]}, "structure": "pi"}', ["body", "plant", "den", 1]),
    ('{"plant": {"num": [1e400], "den": [1, 1]}, "structure": "pi"}', ["body", "plant", "num", 0]),
    ('{"plant": ', ["body", 10]),
])
def test_non_finite_numbers_and_broken_json_are_422(client, raw, loc):
    r = client.post("/tune", content=raw, headers={"content-type": "application/json"})
    assert r.status_code == 422, r.text
    assert loc in [d["loc"] for d in r.json()["detail"]], r.json()


def test_body_that_is_not_text_is_400_with_a_clear_body(client):
    r = client.post("/analyze", content=b"Z\xff\xfer", headers={"content-type": "application/json"})
    assert r.status_code == 400
    assert r.json() == {"detail": "There was an error parsing the body"}


@pytest.mark.parametrize("params, loc", [({"limit": 0}, ["query", "limit"]), ({"limit": 101}, ["query", "limit"]),
                                         ({"offset": -1}, ["query", "offset"]), ({"limit": "x"}, ["query", "limit"])])
def test_bad_paging_is_422(client, params, loc):
    r = client.get("/tunes", params=params)
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == loc


def test_budget_above_the_servers_maximum_is_422(client, override_settings):
    override_settings(max_budget_s=1.0)
    r = client.post("/tune", json=_with(T, options={"time_budget_s": 2.0}))
    assert r.status_code == 422
    assert r.json()["detail"] == [{"loc": ["body", "options", "time_budget_s"], "type": "value_error",
                                   "msg": "time_budget_s=2 is above this server's maximum of 1 s"}]


# -- 413 ----------------------------------------------------------------------------------

def test_body_over_the_cap_is_413(client):
    big = _with(T, plant={"expr": ROLL + "+0" * MAX_BODY})
    r = client.post("/tune", json=big)
    assert r.status_code == 413
    assert r.json() == {"detail": f"request body larger than {MAX_BODY} bytes"}


def test_chunked_body_over_the_cap_is_413(client):
    def chunks():  # no Content-Length: the cap is applied while the body arrives
        yield b'{"plant": {"expr": "'
        for _ in range(2 * MAX_BODY // 1000):
            yield b"1+" * 500
        yield b'1"}, "structure": "pi"}'

    r = client.post("/tune", content=chunks(), headers={"content-type": "application/json"})
    assert r.status_code == 413


def test_body_under_the_cap_passes_the_size_check(client):
    r = client.post("/tune", json=_with(T, plant={"expr": "1/(s+1" + " " * (MAX_BODY // 2)}))
    assert r.status_code == 422  # it reached validation


# -- 401 ----------------------------------------------------------------------------------

def test_api_key_guards_the_api_but_not_health(client, override_settings):
    from pydantic import SecretStr

    override_settings(api_key=SecretStr("s3cret"))
    for method, path, body in [("post", "/tune", T), ("post", "/analyze", A), ("get", "/tunes", None),
                               ("get", "/tunes/" + "0" * 32, None), ("get", "/tunes/x/plot.png", None)]:
        for headers in ({}, {"X-API-Key": "wrong"}, {"X-API-Key": ""}):
            r = client.request(method, path, json=body, headers=headers)
            assert r.status_code == 401, (path, headers, r.status_code)
            assert r.json() == {"detail": "missing or invalid X-API-Key header"}
    ok = client.get("/tunes", headers={"X-API-Key": "s3cret"})
    assert ok.status_code == 200
    assert client.get("/health").status_code == 200


def test_no_api_key_configured_means_open(client):
    assert client.get("/tunes").status_code == 200


def test_response_numbers_are_finite_or_the_documented_strings(roll):
    def walk(x):
        if isinstance(x, dict):
            for v in x.values():
                walk(v)
        elif isinstance(x, list):
            for v in x:
                walk(v)
        elif isinstance(x, float):
            assert np.isfinite(x)
        elif isinstance(x, str) and x.lower() in ("inf", "-inf", "nan"):
            raise AssertionError(f"non-standard encoding {x!r}")

    walk(roll)


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_tune_accepts_pid2_and_the_deprecated_pidf2(client):
    r = client.post("/tune", json={"plant": {"expr": "4.674/(s^2+3.523*s+12.38)"}, "dt": 0.04, "structure": "pid2",
                                   "options": {"time_budget_s": 2}})
    assert r.status_code == 200, r.text
    body = r.json()
    assert set(body["gains"]) == {"Kp", "Ki", "Kd", "Tf", "b", "c"} and "num_r" in body["controller"]
    r = client.post("/tune", json={"plant": {"expr": "1/(s+1)"}, "structure": "pidf2",
                                   "options": {"time_budget_s": 1}})
    assert r.status_code == 200, r.text
    assert r.json()["structure"] == "pid_mf2"
    assert any("deprecated" in n for n in r.json()["solver"]["notes"])


def test_tune_reports_optimality_and_takes_an_effort(client, roll):
    o = roll["solver"]["optimality"]
    assert o["effort"] == "default" and isinstance(o["summary"], str) and o["summary"].startswith("optimality")
    r = client.post("/tune", json={**ROLL_BODY, "options": {"seed": 0, "time_budget_s": BUDGET, "effort": "fast"}})
    assert r.status_code == 200, r.text
    assert r.json()["solver"]["optimality"]["effort"] == "fast"
    bad = client.post("/tune", json={**ROLL_BODY, "options": {"seed": 0, "effort": "max"}})
    assert bad.status_code == 422
    assert any(d["loc"][-1] == "effort" for d in bad.json()["detail"]), bad.text
