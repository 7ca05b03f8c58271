"""``POST /ulog/signals``: what a PX4 ULog offers the page (its signals with their rates, the rate law's parameters
as a .params text, the loop rate), and every bad upload refused with the field, before or after the body is read."""

from __future__ import annotations

import base64

import numpy as np
import pytest
from ulog_writer import Topic, write_ulog

from api.settings import Settings
from tuner.firmware import vehicle_from_text


@pytest.fixture(scope="module")
def settings(tmp_path_factory):
    db = tmp_path_factory.mktemp("ulog-signals") / "tuner.db"
    return Settings(database_url=f"sqlite:///{db}", workers=1, queue_size=4, max_body_bytes=16_384,
                    max_identify_body_bytes=2_000_000)


@pytest.fixture(scope="module")
def ulog_b64(tmp_path_factory):
    n = 400
    ts = 1_000_000 + np.arange(n) * 2500  # 400 Hz
    z = np.zeros(n)
    p = write_ulog(tmp_path_factory.mktemp("ulog") / "f.ulg", [
        Topic("vehicle_torque_setpoint", [("float", "xyz", 3)], ts, {"xyz": np.stack([z, z, z], 1)}),
        Topic("vehicle_angular_velocity", [("float", "xyz", 3)], ts[::2], {"xyz": np.stack([z, z, z], 1)[::2]})],
        params={"MC_ROLLRATE_P": 0.18, "MC_ROLLRATE_I": 0.2, "MC_ROLLRATE_D": 0.004, "IMU_GYRO_RATEMAX": 400,
                "SYS_AUTOSTART": 4001})
    return base64.b64encode(p.read_bytes()).decode()


def test_the_signals_rates_and_parameters(client, ulog_b64):
    r = client.post("/ulog/signals", json={"data": ulog_b64})
    assert r.status_code == 200, r.text
    d = r.json()
    rates = {s["name"]: s["rate_hz"] for s in d["signals"]}
    assert rates["vehicle_torque_setpoint.xyz[0]"] == pytest.approx(400.0)
    assert rates["vehicle_angular_velocity.xyz[2]"] == pytest.approx(200.0)
    assert d["loop_hz"] == 400 and d["firmware"] == "px4"
    assert "SYS_AUTOSTART" not in d["params_text"]  # the rate law's parameters only
    v = vehicle_from_text(d["params_text"], axis="roll")  # the text a tune's vehicle.params takes
    assert v.gains["P"] == pytest.approx(0.18, rel=1e-6) and v.loop_hz == 400


@pytest.mark.parametrize("data, words", [("not base64!" * 4, "not base64"),
                                         (base64.b64encode(b"\x00" * 64).decode(), "not a readable ULog")])
def test_a_bad_upload_is_422_at_the_data(client, data, words):
    r = client.post("/ulog/signals", json={"data": data})
    assert r.status_code == 422, r.text
    item = r.json()["detail"][0]
    assert item["loc"] == ["body", "data"] and words in item["msg"], item


def test_an_upload_over_the_limit_is_refused_before_it_is_read(client):
    r = client.post("/ulog/signals", json={"data": "A" * 2_100_000})
    assert r.status_code == 413, r.text


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_a_damaged_log_is_422_at_the_data_at_once(client):
    """A valid header then 1.5 MB of zeros: pyulog would step through it byte by byte (issue 42: 17 MB held a
    solver 15-22 s); the bounded reader calls it damaged within its first 64 kB."""
    import struct

    data = b"ULog\x01\x12\x35\x01" + struct.pack("<Q", 0) + bytes(1_400_000)
    r = client.post("/ulog/signals", json={"data": base64.b64encode(data).decode()})
    assert r.status_code == 422, r.text
    item = r.json()["detail"][0]
    assert item["loc"] == ["body", "data"] and "a damaged ULog file" in item["msg"], item


def test_only_names_a_parameter_file_may_hold_are_passed_on(client, tmp_path):
    """Issue 42: a log's parameter names went raw into params_text; a name holding tabs and a newline added lines
    (here MC_ROLLRATE_K = 5) to the page's "vehicle from the log". Only [A-Z][A-Z0-9_]{0,15} names pass."""
    n = 50
    ts = 1_000_000 + np.arange(n) * 2500
    z = np.zeros((n, 3))
    crafted = "MC_ROLLRATE_D\t0.004\t9\n1\t1\tMC_ROLLRATE_K"
    p = write_ulog(tmp_path / "crafted.ulg", [Topic("vehicle_angular_velocity", [("float", "xyz", 3)], ts, {"xyz": z})],
                   params={"MC_ROLLRATE_P": 0.18, crafted: 5.0, "MC_ROLLRATE_I": 0.2, "MC_ROLLRATE_D": 0.004,
                           "mc_rollrate_ff": 0.1, "MC_ROLLRATE_FF_TOO_LONG_NAME": 0.3})
    r = client.post("/ulog/signals", json={"data": base64.b64encode(p.read_bytes()).decode()})
    assert r.status_code == 200, r.text
    text = r.json()["params_text"]
    names = [ln.split("\t")[2] for ln in text.splitlines()]
    assert names == ["MC_ROLLRATE_D", "MC_ROLLRATE_I", "MC_ROLLRATE_P"], text
    assert vehicle_from_text(text, axis="roll").fixed["K"] == 1.0  # the firmware's default, not the crafted 5
