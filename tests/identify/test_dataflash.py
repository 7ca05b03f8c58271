"""ArduPilot DataFlash logs (issue 40 item 4): identify from RATE/PIDR/SIDD, the parameters from PARM, what was flown
from ARM/EV/MODE, damaged logs refused at once. The logs are written here (tests/dataflash_writer.py, from
ArduPilot's LogStructure.h), from a flight simulated with a rate law in the loop (tests/closed_loop.py); the values
expected are the ones written."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from closed_loop import fly
from dataflash_writer import Message, arm, events, modes, parameters, rate_message, write_dataflash

from tuner.cli import main
from tuner.errors import InvalidDataError, TunerError
from tuner.firmware import read_params
from tuner.identify.dataflash import read_dataflash, read_dataflash_parameters, signals

T0 = 1_000_000  # µs: the first RATE sample
AP_PARAMS = {"ATC_RAT_RLL_P": 0.135, "ATC_RAT_RLL_I": 0.135, "ATC_RAT_RLL_D": 0.0036, "ATC_RAT_RLL_FF": 0.0,
             "ATC_RAT_RLL_IMAX": 0.5, "ATC_RAT_RLL_FLTT": 20.0, "ATC_RAT_RLL_FLTE": 0.0, "ATC_RAT_RLL_FLTD": 20.0,
             "SCHED_LOOP_RATE": 400, "INS_GYRO_FILTER": 20.0}


@pytest.fixture(scope="module")
def sweep():
    return fly("sweep", seconds=60, seed=2, sweep_amplitude=3.0, turbulence=0.03)


def _log(path, log, *, took_off_s=5.0, landed_s=None, mode=1, armed=True, extra=(), params=None):
    t_us = (T0 + np.round(log.t * 1e6)).astype(np.int64)
    ev = [(T0 - 500_000, 10)] if armed else []
    ev += [(T0 + int(took_off_s * 1e6), 28)] if took_off_s is not None else []
    ev += [(T0 + int(landed_s * 1e6), 18)] if landed_s is not None else []
    msgs = [rate_message(t_us, log.r, log.y, log.u), params or parameters(AP_PARAMS),
            arm([(T0 - 500_000, 1 if armed else 0)]), modes([(T0 - 600_000, mode)]), *extra]
    if ev:
        msgs.append(events(ev))
    return write_dataflash(path, msgs), t_us


def test_the_rate_message_on_the_grid_is_what_was_written_over_the_flight(sweep, tmp_path):
    path, t_us = _log(tmp_path / "f.bin", sweep, took_off_s=5.0, landed_s=55.0)
    rec = read_dataflash(path, {"input": "RATE.ROut", "output": "RATE.R", "reference": "RATE.RDes"})
    t = t_us * 1e-6
    # the flown stretch: from the take-off event to the landing event; RATE is logged at 400 Hz on one clock, so the
    # grid is its samples there (float32 in the file)
    sel = (t >= (T0 * 1e-6 + 5.0) - 1e-9) & (t <= T0 * 1e-6 + 55.0 + 1e-9)
    assert rec.rate_hz == 400.0 and len(rec.inputs) == 1
    n = rec.inputs[0].size
    assert abs(n - sel.sum()) <= 1
    np.testing.assert_allclose(rec.inputs[0], sweep.u.astype(np.float32)[sel][:n], rtol=0, atol=0)
    np.testing.assert_allclose(rec.outputs[0], sweep.y.astype(np.float32)[sel][:n], rtol=0, atol=1e-6)
    np.testing.assert_allclose(rec.references[0], sweep.r.astype(np.float32)[sel][:n], rtol=0, atol=0)
    assert rec.parameters["ATC_RAT_RLL_P"] == pytest.approx(0.135) and rec.flight["firmware"] == "ardupilot"
    assert rec.flight["reference_biased"] == ""  # flown in ACRO
    assert any("exogenous: flown in a rate (ACRO) mode" in n for n in rec.flight["notes"])


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_identify_and_tune_params_from_a_dataflash_log(sweep, tmp_path, capsys):
    path, _ = _log(tmp_path / "acro.bin", sweep)
    code = main(["identify", str(path), "--input", "RATE.ROut", "--output", "RATE.R", "--reference", "RATE.RDes",
                 "--poles", "2", "--json"])
    out = capsys.readouterr()
    assert code == 0, out.err
    d = json.loads(out.out)
    assert d["options"]["estimate"] == "joint (reference)" and d["rate_hz"] == 400.0
    assert "ATC_RAT_RLL_P" in " ".join(d["closed_loop"]["signs"])
    v = read_params(path, axis="roll")  # tune --params FILE.bin: PARM
    assert v.firmware == "ardupilot" and v.loop_hz == 400.0
    assert v.gains["P"] == pytest.approx(0.135) and v.gains["D"] == pytest.approx(0.0036)
    assert read_dataflash_parameters(path)["INS_GYRO_FILTER"] == 20.0


def test_a_rate_setpoint_outside_acro_or_systemid_is_biased(sweep, tmp_path):
    cols = {"input": "RATE.ROut", "output": "RATE.R", "reference": "RATE.RDes"}
    stab, _ = _log(tmp_path / "stab.bin", sweep, mode=0)
    assert "STABILIZE" in read_dataflash(stab, cols).flight["reference_biased"]
    sid, _ = _log(tmp_path / "sid.bin", sweep, mode=25)
    rec = read_dataflash(sid, cols)
    assert rec.flight["reference_biased"] == "" and "SystemID" in " ".join(rec.flight["notes"])


def test_a_log_never_flown_is_refused_saying_what_was_seen(sweep, tmp_path, capsys):
    # ArduPilot writes ARM when the state changes: a disarm first says the log began armed, here until 0.5 s before
    # the signals begin
    ground, _ = _log(tmp_path / "ground.bin", sweep, armed=False, took_off_s=None)
    with pytest.raises(InvalidDataError, match=r"armed and airborne only at 0\.0-0\.5 s, outside the signals'") as e:
        read_dataflash(ground, {"input": "RATE.ROut", "output": "RATE.R"})
    assert "ARM.ArmState [0]" in str(e.value) and e.value.field == ("file",)
    assert main(["identify", str(ground), "--input", "RATE.ROut", "--output", "RATE.R", "--poles", "2"]) == 2
    assert "no flight to identify from" in capsys.readouterr().err


def test_wrong_names_are_refused_with_what_the_log_holds(sweep, tmp_path):
    path, _ = _log(tmp_path / "f.bin", sweep)
    with pytest.raises(InvalidDataError, match=r"message 'PIDR' is not in the log; messages logged: .*'RATE'"):
        read_dataflash(path, {"input": "PIDR.Tar", "output": "RATE.R"})
    with pytest.raises(InvalidDataError, match=r"has no field 'Rx'; fields: \['RDes', 'R', 'ROut'"):
        read_dataflash(path, {"input": "RATE.ROut", "output": "RATE.Rx"})
    with pytest.raises(InvalidDataError, match=r"faster than the input RATE.ROut is logged: RATE at 400 Hz"):
        read_dataflash(path, {"input": "RATE.ROut", "output": "RATE.R"}, rate_hz=1000)


def test_signals_list_the_fields_and_the_law_parameters(sweep, tmp_path):
    path, _ = _log(tmp_path / "f.bin", sweep)
    s = signals(path.read_bytes())
    names = {x["name"]: x["rate_hz"] for x in s["signals"]}
    assert names["RATE.R"] == pytest.approx(400.0) and "PARM.Value" not in names
    assert s["firmware"] == "ardupilot" and s["loop_hz"] == 400 and "ATC_RAT_RLL_P,0.135" in s["params_text"]


def test_sidd_and_pidr_are_read(tmp_path):
    n = 400
    t = T0 + np.arange(n) * 2500
    x = np.sin(np.arange(n) * 0.1)
    sidd = Message("SIDD", "Qfffffffff", ["TimeUS", "Time", "Targ", "F", "Gx", "Gy", "Gz", "Ax", "Ay", "Az"],
                   {"TimeUS": t, "Time": t * 1e-6, "Targ": x, "F": np.ones(n), "Gx": 2 * x, "Gy": 0 * x, "Gz": 0 * x,
                    "Ax": 0 * x, "Ay": 0 * x, "Az": 0 * x})
    pidr = Message("PIDR", "Qffffffff", ["TimeUS", "Tar", "Act", "Err", "P", "I", "D", "FF", "DFF"],
                   {"TimeUS": t, "Tar": x, "Act": 3 * x, "Err": 0 * x, "P": x, "I": x, "D": x, "FF": x, "DFF": x})
    path = write_dataflash(tmp_path / "sid.bin", [sidd, pidr, events([(T0 - 1000, 10), (T0 - 500, 28)]),
                                                  modes([(T0 - 2000, 25)])])
    rec = read_dataflash(path, {"input": "SIDD.Targ", "output": "PIDR.Act"})
    np.testing.assert_allclose(rec.outputs[0], 3 * x.astype(np.float32)[:rec.outputs[0].size], atol=1e-6)


@pytest.mark.parametrize("junk", [b"\0" * (3 << 20), bytes(range(256)) * 12_000])
def test_a_damaged_log_is_refused_naming_the_bytes(sweep, tmp_path, junk):
    path, _ = _log(tmp_path / "f.bin", sweep)
    raw = path.read_bytes()
    bad = tmp_path / "bad.bin"
    bad.write_bytes(raw[:5000] + junk + raw[5000:])
    with pytest.raises(InvalidDataError, match=r"a damaged DataFlash log: no readable message in bytes \d+-\d+"):
        read_dataflash(bad, {"input": "RATE.ROut", "output": "RATE.R"})
    with pytest.raises(TunerError, match="damaged DataFlash"):
        read_params(bad)
    with pytest.raises(InvalidDataError, match="not a DataFlash log"):
        read_dataflash(b"\0" * 100, {"input": "RATE.ROut", "output": "RATE.R"})


def _rate_fmt_at(raw: bytes, length: int) -> int:
    """Where RATE's FMT is in a log tests/dataflash_writer.py wrote (RATE the first message given: type 130)."""
    at = raw.find(b"\xa3\x95\x80" + bytes([130, length]) + b"RATE")
    assert at > 0
    return at


@pytest.mark.timeout(60)  # a FMT of Length 0 made pymavlink's index pass loop for ever
@pytest.mark.parametrize("delta", [None, -4, 4, -1])
def test_a_fmt_whose_length_is_not_its_formats_size_is_refused(sweep, tmp_path, delta, capsys):
    path, _ = _log(tmp_path / "f.bin", sweep)
    raw = bytearray(path.read_bytes())
    size = 3 + struct.calcsize("<Q12f")  # RATE: TimeUS and 12 floats (LogStructure.h)
    at = _rate_fmt_at(bytes(raw), size)
    declared = 0 if delta is None else size + delta
    raw[at + 4] = declared
    bad = tmp_path / "bad.bin"
    bad.write_bytes(bytes(raw))
    want = rf"a damaged DataFlash log: the FMT of message type 130 \('RATE'\) declares a Length of {declared} bytes"
    with pytest.raises(InvalidDataError, match=want) as e:
        read_dataflash(bad, {"input": "RATE.ROut", "output": "RATE.R"})
    assert e.value.field == ("file",)
    assert main(["identify", str(bad), "--input", "RATE.ROut", "--output", "RATE.R", "--poles", "2"]) == 2
    assert "declares a Length" in capsys.readouterr().err


def test_a_field_past_its_messages_length_is_refused():
    from types import SimpleNamespace

    from tuner.identify.dataflash import _columns

    # a message whose FMT declares 7 bytes (header and a uint32) but whose format says a uint64
    fmt = SimpleNamespace(len=7, columns=["TimeUS"], format="Q")
    raw = b"\xa3\x95\x81" + (5).to_bytes(4, "little") + b"\xa3\x95\x81" + (6).to_bytes(4, "little")
    r = SimpleNamespace(name_to_id={"X": 0x81}, formats={0x81: fmt}, offsets={0x81: [0, 7]}, data_len=len(raw),
                        data_map=raw)
    with pytest.raises(InvalidDataError, match=r"message X's field 'TimeUS' ends at byte 11, past the 7 bytes"):
        _columns(r, "X")


def test_an_unknown_message_type_mid_log_is_refused_naming_the_byte(sweep, tmp_path, capsys):
    path, t_us = _log(tmp_path / "f.bin", sweep)
    raw = bytearray(path.read_bytes())
    # the type byte of a RATE message about halfway through, flipped to a type no FMT describes
    rate = b"\xa3\x95\x82" + struct.pack("<Q", int(t_us[t_us.size // 2]))
    at = raw.find(rate)
    assert at > 0
    raw[at + 2] = 0x7F
    bad = tmp_path / "bad.bin"
    bad.write_bytes(bytes(raw))
    with pytest.raises(InvalidDataError, match=rf"a damaged DataFlash log: at byte {at} of {len(raw)}, a message of "
                                               r"type 127, which no FMT describes") as e:
        read_dataflash(bad, {"input": "RATE.ROut", "output": "RATE.R"})
    assert f"the {len(raw) - at} bytes from there" in str(e.value)
    assert main(["identify", str(bad), "--input", "RATE.ROut", "--output", "RATE.R", "--poles", "2"]) == 2
    assert "no FMT describes" in capsys.readouterr().err
    # the same in the log's last few bytes is its end: read, and said
    raw = bytearray(path.read_bytes())
    last = raw.rfind(b"\xa3\x95\x82")
    raw[last + 2] = 0x7F
    tail = tmp_path / "tail.bin"
    tail.write_bytes(bytes(raw))
    rec = read_dataflash(tail, {"input": "RATE.ROut", "output": "RATE.R"})
    assert any(f"last {len(raw) - last} bytes (from byte {last}) hold no whole message" in n
               for n in rec.flight["notes"])


@pytest.mark.parametrize(("arm_state", "ev", "until_s"), [
    ([50.0], [], 50.0),  # ARM: a disarm first (logging began armed), no take-off or landing events
    (None, [(50.0, 11)], 50.0),  # no ARM, EV 11 DISARMED first
    ([50.0], [(40.0, 18)], 40.0),  # a landing first: the log began in the air
])
def test_a_log_that_begins_armed_is_read_from_its_start(sweep, tmp_path, arm_state, ev, until_s):
    t_us = (T0 + np.round(sweep.t * 1e6)).astype(np.int64)
    msgs = [rate_message(t_us, sweep.r, sweep.y, sweep.u), parameters(AP_PARAMS), modes([(T0 - 600_000, 1)])]
    if arm_state is not None:
        msgs.append(arm([(T0 + int(s * 1e6), 0) for s in arm_state]))
    if ev:
        msgs.append(events([(T0 + int(s * 1e6), i) for s, i in ev]))
    path = write_dataflash(tmp_path / "f.bin", msgs)
    rec = read_dataflash(path, {"input": "RATE.ROut", "output": "RATE.R"})
    t = t_us * 1e-6
    sel = t <= T0 * 1e-6 + until_s + 1e-9  # from the first sample (the log's start) to the disarm or landing
    n = rec.inputs[0].size
    assert abs(n - sel.sum()) <= 1
    np.testing.assert_allclose(rec.inputs[0], sweep.u.astype(np.float32)[sel][:n], rtol=0, atol=0)


def test_overlapping_exogenous_stretches_are_merged():
    from types import SimpleNamespace

    from tuner.identify.flight import intersect, px4_flight, total

    def topic(name, t_s, **fields):
        data = {"timestamp": np.asarray(t_s, dtype=float) * 1e6} | {k: np.asarray(v) for k, v in fields.items()}
        return SimpleNamespace(name=name, multi_id=0, data=data)

    # armed from 0.5 s; acro from 1 to 6 s, the autotune's excitation from 1 to 5 s: together 1-6 s, 5 s of 9
    ul = SimpleNamespace(data_list=[
        topic("actuator_armed", [0.5], armed=[1]),
        topic("vehicle_control_mode", [0.5, 1.0, 6.0], flag_control_rates_enabled=[1, 1, 1],
              flag_control_attitude_enabled=[1, 0, 1]),
        topic("autotune_attitude_control_status", [0.5, 1.0, 5.0], state=[0, 2, 0])])
    f = px4_flight(ul, 10.0)
    assert f.exogenous == [(1.0, 6.0)]
    assert total(intersect([(1.0, 10.0)], f.exogenous)) == pytest.approx(5.0)
    from tuner.identify.flight import union

    assert union([(0, 2), (5, 6)], [(1, 3), (3, 4)]) == [(0, 4), (5, 6)]


def _fmtu(type_id: int, unit_ids: str) -> Message:
    """An FMTU message (``TimeUS,FmtType,UnitIds,MultIds``) giving message type ``type_id`` its units; a ``#`` marks
    the instance field (ArduPilot's LogStructure.h, ``LOG_FORMAT_UNITS_MSG``)."""
    return Message("FMTU", "QBNN", ["TimeUS", "FmtType", "UnitIds", "MultIds"],
                   {"TimeUS": [2], "FmtType": [type_id], "UnitIds": [unit_ids.encode()],
                    "MultIds": [("-" * len(unit_ids)).encode()]})


def test_a_message_with_instances_is_read_by_its_instance(sweep, tmp_path):
    # two gyros (IMU instance 0 and 1) logged at the RATE samples; the instance field is what FMTU marks with "#"
    t_us = (T0 + np.round(sweep.t * 1e6)).astype(np.int64)
    n = t_us.size
    imu = Message("IMU", "QBf", ["TimeUS", "I", "GyrX"],
                  {"TimeUS": np.r_[t_us, t_us], "I": np.r_[np.zeros(n, int), np.ones(n, int)],
                   "GyrX": np.r_[np.full(n, 5.0), sweep.y]})
    # write_dataflash numbers the types 129 (its MSG), 130, ... in the order given: IMU is 130
    path = write_dataflash(tmp_path / "imu.bin", [imu, _fmtu(130, "s#E"), rate_message(t_us, sweep.r, sweep.y, sweep.u),
                                                  parameters(AP_PARAMS), arm([(T0 - 500_000, 1)]),
                                                  modes([(T0 - 600_000, 1)]), events([(T0 - 500_000, 10)])])
    one = read_dataflash(path, {"input": "RATE.ROut", "output": "IMU:1.GyrX"})
    np.testing.assert_allclose(one.outputs[0], sweep.y.astype(np.float32)[:one.outputs[0].size], atol=1e-6)
    zero = read_dataflash(path, {"input": "RATE.ROut", "output": "IMU:0.GyrX"})
    assert np.all(zero.outputs[0] == 5.0)
    with pytest.raises(InvalidDataError, match=r"message 'IMU' has instances \[0, 1\], not 2"):
        read_dataflash(path, {"input": "RATE.ROut", "output": "IMU:2.GyrX"})
    with pytest.raises(InvalidDataError, match=r"message 'RATE' has no instances \(name it RATE.R\)"):
        read_dataflash(path, {"input": "RATE.ROut", "output": "RATE:1.R"})


def test_a_parameter_changed_in_flight_is_said_and_its_last_value_used(sweep, tmp_path):
    # ArduPilot logs every parameter at the start and each change after, as a PARM message at the change's time
    start = parameters(AP_PARAMS)
    parm = Message("PARM", start.format, start.columns,
                   {"TimeUS": [*start.rows["TimeUS"], T0 + 20_000_000, T0 + 40_000_000],
                    "Name": [*start.rows["Name"], b"ATC_RAT_RLL_P", b"ATC_RAT_PIT_P"],
                    "Value": [*start.rows["Value"], 0.2, 0.3]})
    path, _ = _log(tmp_path / "changed.bin", sweep, params=parm)
    v = read_params(path, axis="roll")
    assert v.gains["P"] == pytest.approx(0.2)
    said = [n for n in v.notes if "changed in flight" in n]
    assert len(said) == 1 and said[0].startswith("ATC_RAT_RLL_P changed in flight (0.135 at 0.0 s, 0.2 at 21.0 s)")
    first, later = read_dataflash_parameters(path, history=True)
    # ATC_RAT_PIT_P was not in the start's list: its one PARM is its value, not a change
    assert first["ATC_RAT_RLL_P"] == pytest.approx(0.135) and first["ATC_RAT_PIT_P"] == pytest.approx(0.3)
    assert [(t, n) for t, n, _ in later] == [(pytest.approx(T0 * 1e-6 + 20.0), "ATC_RAT_RLL_P")]
