"""Issue 42's hostile inputs to the command line, as files made here: each case's exit code, wall time and first
line of stderr, for one source tree (``--tree``: another checkout, e.g. the commit before the fixes, to measure
before and after in one session). Run through ``bench/hostile.py --files``; nothing here asserts a timing.

The cases: damaged PX4 ULog logs (a valid header then zeros, 10 and 100 MB; a written-over middle; a zero tail;
crafted bodies that make pyulog re-read; a flood of the smallest valid messages, the bound's worst case), the same
through ``--params``; CSV logs that stall the delimiter sniffer (a 64 kB and a 200 kB line); time columns in
microseconds and in milliseconds; crafted result files for ``export``; plots and exports to a FIFO and to
/dev/full; parameter files with a duplicate name or ``1_5``; a study whose free text holds HTML. Every process is
bounded by its own timeout (a hang is reported as rc None at the timeout).
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

HEADER = b"ULog\x01\x12\x35\x01" + struct.pack("<Q", 0)
SYNC = b"\x2f\x73\x13\x20\x25\x0c\xbb\x12"
LOGGED = b"\x0a\x00L6" + bytes(8) + b"x"  # a logged string: the data section begins
IN, OUT = "vehicle_torque_setpoint.xyz[0]", "vehicle_angular_velocity.xyz[0]"
PARAMS = ("1\t1\tMC_ROLLRATE_P\t0.15\t9\n1\t1\tMC_ROLLRATE_I\t0.2\t9\n1\t1\tMC_ROLLRATE_D\t0.003\t9\n"
          "1\t1\tIMU_GYRO_RATEMAX\t400\t6\n1\t1\tIMU_GYRO_CUTOFF\t40\t9\n")
RATE_PLANT = "200/(s*(0.02*s+1))"


@dataclass
class Case:
    name: str
    args: list[str]
    timeout_s: float = 300.0
    note: str = ""
    check: Any = None  # (work_dir) -> str: what the output holds, for cases judged by their output


def _sparse(path: Path, head: bytes, size: int) -> Path:
    with open(path, "wb") as f:
        f.write(head)
        f.truncate(size)
    return path


def _valid_log(path: Path) -> bytes:
    """A 60 s pitch sweep (tests/flight.py) logged at 250 Hz, two topics: about 1 MB."""
    from flight import AXES, fly
    from ulog_writer import Topic, write_ulog

    fl = fly(*AXES["pitch"], seed=8, duration_s=60.0, log_hz=250.0)
    t = 5_000_000 + np.round(fl.t * 1e6).astype(np.int64)
    vec = lambda x: np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    xyz = [("float", "xyz", 3)]
    p = write_ulog(path, [Topic("vehicle_torque_setpoint", xyz, t, {"xyz": vec(fl.u)}),
                          Topic("vehicle_angular_velocity", xyz, t + 100, {"xyz": vec(fl.y)})])
    return p.read_bytes()


def _tiny_flood(path: Path, size: int) -> Path:
    """A log that is valid in form: one topic with a timestamp only, and data messages of 13 bytes (the smallest a
    data message is) up to ``size`` bytes: pyulog's work per byte is the largest the bound lets through."""
    fmt = b"t:uint64_t timestamp;"
    head = HEADER + struct.pack("<HB", len(fmt), ord("F")) + fmt
    sub = struct.pack("<BH", 0, 0) + b"t"
    head += struct.pack("<HB", len(sub), ord("A")) + sub
    n = (size - len(head)) // 13
    rec = np.zeros(n, dtype=[("size", "<u2"), ("type", "u1"), ("id", "<u2"), ("ts", "<u8")])
    rec["size"], rec["type"], rec["ts"] = 10, ord("D"), 1_000_000 + 4000 * np.arange(n, dtype=np.uint64)
    with open(path, "wb") as f:
        f.write(head)
        f.write(rec.tobytes())
    return path


def _csv_from(path: Path, t: np.ndarray, u: np.ndarray, y: np.ndarray, tfmt: str) -> Path:
    with open(path, "w") as f:
        f.write("t,u,y\n")
        for a, b, c in zip(t, u, y):
            f.write(f"{a:{tfmt}},{b:.6g},{c:.6g}\n")
    return path


def build(work: Path, big: bool = True) -> list[Case]:
    """The files in ``work`` and the cases that use them."""
    from flight import AXES, fly

    w = work
    cases: list[Case] = []
    ident = ["--input", IN, "--output", OUT, "--poles", "2"]
    # -- damaged ULog logs
    _sparse(w / "zeros10.ulg", HEADER, 10_000_016)
    cases.append(Case("ulog: header + 10 MB of zeros (identify)", ["identify", str(w / "zeros10.ulg"), *ident]))
    if big:
        _sparse(w / "zeros100.ulg", HEADER, 100_000_016)
        cases.append(Case("ulog: header + 100 MB of zeros (identify)", ["identify", str(w / "zeros100.ulg"), *ident],
                          timeout_s=900))
        cases.append(Case("ulog: header + 100 MB of zeros (tune --params)",
                          ["tune", "--plant", RATE_PLANT, "--structure", "px4_rate", "--params",
                           str(w / "zeros100.ulg"), "--budget", "3"], timeout_s=900))
    good = _valid_log(w / "good.ulg")
    mid = len(good) // 2
    (w / "hole.ulg").write_bytes(good[:mid] + bytes(2_000_000) + good[mid:])
    cases.append(Case("ulog: the valid log with 2 MB of zeros in the middle",
                      ["identify", str(w / "hole.ulg"), *ident]))
    (w / "tail.ulg").write_bytes(good + bytes(10_000_000))
    cases.append(Case("ulog: the valid log + a 10 MB zero tail", ["identify", str(w / "tail.ulg"), *ident]))
    (w / "nulld.ulg").write_bytes(HEADER + b"\0\0D" * 3_000_000)
    cases.append(Case("ulog: 9 MB of empty data messages", ["identify", str(w / "nulld.ulg"), *ident]))
    (w / "sync.ulg").write_bytes(HEADER + LOGGED + (struct.pack("<HB", 10000, ord("Z")) + SYNC) * 900_000)
    cases.append(Case("ulog: 10 MB of messages each holding a sync sequence", ["identify", str(w / "sync.ulg"),
                                                                                  *ident], timeout_s=600))
    _tiny_flood(w / "tiny100.ulg" if big else w / "tiny10.ulg", 100_000_000 if big else 10_000_000)
    cases.append(Case(f"ulog: {100 if big else 10} MB of 13-byte data messages (valid form)",
                      ["identify", str(w / ("tiny100.ulg" if big else "tiny10.ulg")), "--input", "t.x",
                       "--output", "t.y", "--poles", "2"], timeout_s=900,
                      note="the bound's worst case: one message per 13 bytes is read"))
    (w / "good.ulg").write_bytes(good)
    cases.append(Case("ulog: the valid log (baseline)", ["identify", str(w / "good.ulg"), *ident]))
    # -- CSV logs: the sniffer
    for kb in (64, 200):
        (w / f"sniff{kb}.csv").write_text("t,u,y\n" + '",' * (kb * 512) + "\n")
        cases.append(Case(f"csv: a {kb} kB line of '\",' (the delimiter sniffer)",
                          ["identify", str(w / f"sniff{kb}.csv"), "--time", "t", "--input", "u", "--output", "y",
                           "--poles", "2"]))
    # -- clocks
    fl = fly(*AXES["pitch"], seed=8, duration_s=40.0, log_hz=250.0)
    _csv_from(w / "us250.csv", np.round(fl.t * 1e6).astype(np.int64) + 1_234_000_000, fl.u, fl.y, "d")
    cases.append(Case("csv: a 250 Hz log timed in microseconds (PX4's CSV export)",
                      ["identify", str(w / "us250.csv"), "--time", "t", "--input", "u", "--output", "y", "--poles", "2",
                       "--json"], note="before: exit 0, time constants 1e6 too slow"))
    fk = fly(*AXES["pitch"], seed=8, duration_s=20.0, log_hz=2000.0, sim_hz=2000.0)
    _csv_from(w / "ms2k.csv", fk.t * 1e3, fk.u, fk.y, ".4f")
    cases.append(Case("csv: a 2 kHz log timed in milliseconds", ["identify", str(w / "ms2k.csv"), "--time", "t",
                                                                  "--input", "u", "--output", "y", "--poles", "2"],
                      note="before: exit 0, time constants 1000 too slow"))
    # -- crafted result files
    (w / "quad.params").write_text(PARAMS)
    res = subprocess.run([sys.executable, "-m", "tuner.cli", "tune", "--plant", RATE_PLANT, "--structure", "px4_rate",
                          "--params", str(w / "quad.params"), "--budget", "3", "--effort", "fast", "--json"],
                         capture_output=True, text=True, timeout=300, cwd=w, env=_env(ROOT))
    base = json.loads(res.stdout)
    for label, path, value, fmt in (("vehicle.gyro_cutoff_hz", ("vehicle", "gyro_cutoff_hz"), "fast", "px4"),
                                    ("vehicle.current_gains.P", ("vehicle", "current_gains", "P"), "x", "px4"),
                                    ("controller.dt", ("controller", "dt"), "x", "c"),
                                    ("gains.P a list", ("gains", "P"), [1, 2], "px4")):
        d = json.loads(json.dumps(base))
        node = d
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = value
        f = w / f"result_{label.replace(' ', '_')}.json"
        f.write_text(json.dumps(d))
        cases.append(Case(f"result: {label} = {value!r} (export --format {fmt})",
                          ["export", "--result", str(f), "--format", fmt]))
    # -- outputs
    os.mkfifo(w / "fifo.png")
    (w / "full.png").symlink_to("/dev/full")
    cases.append(Case("output: analyze --plot to a FIFO", ["analyze", "--plant", "1/(s+1)", "--controller", "2",
                                                           "--plot", str(w / "fifo.png")], timeout_s=60))
    cases.append(Case("output: export --out to a FIFO", ["export", "--controller", "2*(z-0.5)/(z-1)", "--dt", "0.01",
                                                         "--format", "c", "--out", str(w / "fifo.png")], timeout_s=60))
    # the issue's --plot /dev/full, through a link in the work directory: before, matplotlib appended '.png' to a
    # name without a suffix and wrote a new file beside it (run as root, /dev/full.png), saying 'wrote /dev/full'
    (w / "dev_full").symlink_to("/dev/full")
    cases.append(Case("output: identify --plot /dev/full", ["identify", str(ROOT / "studies/data/pitch_sweep.csv"),
                                                            "--time", "t", "--input", "pitch_cmd", "--output", "pitch",
                                                            "--poles", "2", "--plot", str(w / "dev_full")]))
    cases.append(Case("output: analyze --plot to a link to /dev/full", ["analyze", "--plant", "1/(s+1)",
                                                                         "--controller", "2", "--plot",
                                                                         str(w / "full.png")]))
    # -- parameter files
    (w / "dup.params").write_text(PARAMS + "1\t1\tMC_ROLLRATE_P\t0.9\t9\n")
    cases.append(Case("params: MC_ROLLRATE_P twice (0.15, then 0.9)",
                      ["analyze", "--plant", RATE_PLANT, "--structure", "px4_rate", "--params", str(w / "dup.params"),
                       "--json"], note="before: the second value taken silently"))
    (w / "underscore.params").write_text(PARAMS.replace("0.15", "1_5"))
    cases.append(Case("params: MC_ROLLRATE_P = 1_5", ["analyze", "--plant", RATE_PLANT, "--structure", "px4_rate",
                                                      "--params", str(w / "underscore.params"), "--json"],
                      note="before: read as 15"))
    # -- a study's free text
    (w / "study.toml").write_text(
        'name = "html"\ndescription = "<script>alert(1)</script> *bold* | pipe"\ntime_budget_s = 2\n[[loop]]\n'
        'name = "a"\nplant = "1/(s+1)"\nstructure = "pi"\nnote = "<img src=x onerror=alert(1)>"\n')
    cases.append(Case("study: free text with HTML in report.md", ["study", "run", str(w / "study.toml"), "--out",
                                                                  str(w / "study_out"), "--no-plots"],
                      check=lambda d: _report_html(d / "study_out" / "report.md")))
    return cases


def _report_html(p: Path) -> str:
    if not p.exists():
        return "no report"
    t = p.read_text()
    return "raw HTML in report.md" if ("<script>" in t or "<img" in t) else "escaped"


def _env(tree: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("TUNER_")}
    env["PYTHONPATH"] = str(tree)
    return env


def run(tree: Path, work: Path, big: bool = True, only: str | None = None) -> list[dict[str, Any]]:
    """Every case against ``tree``'s code: ``{case, rc, wall_s, stderr}`` (rc None: still running at the timeout)."""
    out = []
    for c in build(work, big):
        if only and only not in c.name:
            continue
        t0 = time.perf_counter()
        try:
            p = subprocess.run([sys.executable, "-m", "tuner.cli", *c.args], capture_output=True, text=True,
                               timeout=c.timeout_s, cwd=work, env=_env(tree))
            rc, err, stdout = p.returncode, p.stderr.strip().splitlines(), p.stdout
        except subprocess.TimeoutExpired:
            rc, err, stdout = None, [f"(no answer within {c.timeout_s:g} s)"], ""
        row = {"case": c.name, "rc": rc, "wall_s": round(time.perf_counter() - t0, 2),
               "stderr": next((ln for ln in err if ln.startswith("tuner: ")), err[-1] if err else "")[:300]}
        if c.note:
            row["note"] = c.note
        if c.check is not None:
            row["output"] = c.check(work)
        if rc in (0, 1) and stdout.lstrip().startswith("{"):
            row["stdout_head"] = _summary(stdout)
        out.append(row)
        print(json.dumps(row), flush=True)
    return out


def _summary(stdout: str) -> str:
    try:
        d = json.loads(stdout)
    except ValueError:
        return stdout[:200]
    if "model" in d:  # an identification: its time constants
        return f"plant {d.get('plant')}; rate {d.get('rate_hz')} Hz; warnings {len(d.get('warnings', []))}"
    if "vehicle" in d:
        return f"the vehicle's gains as read: {d['vehicle'].get('current_gains')}"
    return str(list(d))[:200]


def worker_share(mb: int = 100) -> None:
    """What a solver spends on a header and ``mb`` MB of zeros: the service's two ULog jobs run in this process (the
    code of whatever tree is first on the path); one JSON line each."""
    from api.jobs import identify_job, ulog_signals_job

    data = HEADER + bytes(mb * 1_000_000)
    for name, job, payload in (("ulog_signals_job", ulog_signals_job, {"data": data}),
                               ("identify_job", identify_job, {"ulog": {"data": data, "input": "a.b[0]",
                                                                        "output": "c.d[0]"}, "poles": 2})):
        t0 = time.perf_counter()
        try:
            job(payload)
            what = "answered"
        except Exception as e:
            what = f"{type(e).__name__}: {e}"
        print(json.dumps({"case": f"{mb} MB header + zeros: {name} in-process (a solver's share)",
                          "wall_s": round(time.perf_counter() - t0, 2), "answer": what[:300]}), flush=True)
