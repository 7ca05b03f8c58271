"""Damaged ULog logs cannot hold a reader (issue 42, item 2): pyulog steps through a region with no valid message
one byte at a time (a valid header followed by 100 MB of zeros held `tuner identify` for 102 s, `--params` for 43 s
and a solver of the service for 15-22 s per 17 MB upload). The log is read through a bounded reader
(tuner.identify.ulog._Bounded): such a region is refused as damage, naming where it begins, after a bounded number
of pyulog's reads. The counts below are pyulog's reads of the file (no timing is asserted)."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from ulog_writer import Topic, write_ulog

from tuner.cli import main
from tuner.errors import InvalidDataError
from tuner.firmware import read_params
from tuner.identify.ulog import CORRUPT_SPAN_MESSAGES, LogHandle, read_parameters, read_ulog, signals

IN, OUT = "vehicle_torque_setpoint.xyz[1]", "vehicle_angular_velocity.xyz[1]"
HEADER = b"ULog\x01\x12\x35\x01" + struct.pack("<Q", 0)
SYNC = b"\x2f\x73\x13\x20\x25\x0c\xbb\x12"  # the ULog sync sequence (PX4's ULog file format)


class Counting:
    """A file whose reads are counted (what pyulog does to it)."""

    def __init__(self, data: bytes) -> None:
        import io

        self.f, self.reads = io.BytesIO(data), 0

    def read(self, n: int = -1) -> bytes:
        self.reads += 1
        return self.f.read(n)

    def seek(self, pos: int, whence: int = 0) -> int:
        return self.f.seek(pos, whence)

    def tell(self) -> int:
        return self.f.tell()


def _log(n: int = 20000, params: dict | None = None) -> bytes:
    """A valid log: two topics at 250 Hz, 25 bytes a message."""
    import tempfile
    from pathlib import Path

    rng = np.random.default_rng(0)
    t = 5_000_000 + np.arange(n) * 4000
    xyz = [("float", "xyz", 3)]
    with tempfile.TemporaryDirectory() as d:
        p = write_ulog(Path(d) / "x.ulg", [Topic("vehicle_torque_setpoint", xyz, t, {"xyz": rng.normal(size=(n, 3))}),
                                          Topic("vehicle_angular_velocity", xyz, t + 100,
                                                {"xyz": rng.normal(size=(n, 3))})], params=params)
        return p.read_bytes()


def _read(data: bytes) -> tuple[Counting, Exception | None]:
    f = Counting(data)
    try:
        read_ulog(LogHandle(f, "x.ulg"), {"input": IN, "output": OUT})
    except InvalidDataError as e:
        return f, e
    return f, None


def test_zeros_after_the_header_are_refused_as_damage_after_a_bounded_number_of_reads():
    data = HEADER + bytes(4_000_000)
    f, e = _read(data)
    assert e is not None and e.field == ("file",)
    assert "a damaged ULog file: no readable message in bytes 0-" in str(e) and "after its header" in str(e), e
    # pyulog read the file 2 times a byte (8 million reads without the bound); refused within one span
    assert f.reads < 3 * CORRUPT_SPAN_MESSAGES, f.reads


def test_a_log_written_over_in_the_middle_is_refused_naming_where_the_damage_begins():
    good = _log()
    mid = len(good) // 2
    f, e = _read(good[:mid] + bytes(100_000) + good[mid:])
    assert e is not None and e.field == ("file",)
    start = int(str(e).split("from about byte ")[1].split(" ")[0])
    assert mid - 25 * 4096 <= start <= mid + 4096, (start, mid)  # within a block of messages of where it begins
    assert f.reads < 4 * CORRUPT_SPAN_MESSAGES


def test_a_zero_tail_is_refused_and_a_small_hole_is_read_around():
    good = _log()
    _, e = _read(good + bytes(200_000))
    assert e is not None and "from about byte" in str(e)
    mid = len(good) // 2
    _, e = _read(good[:mid] + bytes(1000) + good[mid:])  # pyulog steps over 1 kB: a gap in the record, not damage
    assert e is None


LOGGED = b"\x0a\x00L6" + bytes(8) + b"x"  # a logged string: the data section begins


@pytest.mark.parametrize("body", [b"\0\0D" * 300_000, LOGGED + (struct.pack("<HB", 10000, ord("Z")) + SYNC) * 100_000],
                         ids=["empty data messages", "a sync sequence in every message"])
def test_crafted_bodies_that_make_pyulog_reread_are_refused(body):
    """Data messages of size 0 in the definitions section (pyulog steps a byte at a time, reading up to 17 kB for
    each), and unknown messages in the data section whose payload starts with the sync sequence (pyulog searches each
    one's 10,000 bytes again and resumes 11 bytes further on)."""
    f, e = _read(HEADER + body)
    assert e is not None and "a damaged ULog file" in str(e), e
    assert f.reads < 4 * CORRUPT_SPAN_MESSAGES, f.reads


def test_random_bytes_after_the_header_say_the_log_holds_no_data_not_a_missing_topic():
    _, e = _read(HEADER + np.random.default_rng(1).bytes(3_000_000))
    assert e is not None and e.field == ("file",) and "which holds no data" in str(e), e


def test_the_command_line_says_damaged_with_exit_2(tmp_path, capsys):
    p = tmp_path / "zeros.ulg"
    with open(p, "wb") as f:
        f.write(HEADER)
        f.truncate(50_000_000)  # sparse: 50 MB read as zeros (before: 50 s)
    assert main(["identify", str(p), "--input", IN, "--output", OUT, "--poles", "2"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"tuner: error: {p}: a damaged ULog file") and "no topic" not in err, err


def test_params_read_only_the_definitions_section_and_refuse_damage(tmp_path, capsys):
    params = {"MC_ROLLRATE_P": 0.15, "MC_ROLLRATE_I": 0.2, "MC_ROLLRATE_D": 0.003, "IMU_GYRO_RATEMAX": 800}
    good = _log(params=params)
    f = Counting(good + bytes(2_000_000))  # damage after the data: never read
    got = read_parameters(LogHandle(f, "x.ulg"))
    assert got["MC_ROLLRATE_P"] == pytest.approx(0.15) and got["IMU_GYRO_RATEMAX"] == 800
    assert f.reads < 100, f.reads  # the header, the flags, the formats, the info and the parameters
    p = tmp_path / "zeros.ulg"
    p.write_bytes(HEADER + bytes(3_000_000))
    with pytest.raises(Exception, match="a damaged ULog file"):
        read_params(p, axis="roll")
    assert main(["tune", "--plant", "1/(s+1)", "--structure", "px4_rate", "--params", str(p)]) == 2
    assert "a damaged ULog file" in capsys.readouterr().err


def test_signals_refuse_damage():
    with pytest.raises(InvalidDataError, match="a damaged ULog file") as e:
        signals(HEADER + bytes(1_000_000))
    assert e.value.field == ("file",)
