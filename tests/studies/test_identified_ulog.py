"""Study loops from PX4 ULog logs, with a verification log (issue 19, parts 4-5)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from flight import AXES, fly
from ulog_writer import Topic, write_ulog

from tuner.errors import TunerError
from tuner.studies.schema import identified, load_study, loop_key

IN, OUT = "vehicle_torque_setpoint.xyz[0]", "vehicle_angular_velocity.xyz[0]"


def _ulog(path: Path, log) -> Path:
    ts = np.round(log.t * 1e6).astype(int) + 1000
    vec = np.column_stack([log.u, np.zeros_like(log.u), np.zeros_like(log.u)])
    out = np.column_stack([log.y, np.zeros_like(log.y), np.zeros_like(log.y)])
    return write_ulog(path, [Topic("vehicle_torque_setpoint", [("float", "xyz", 3)], ts, {"xyz": vec}),
                             Topic("vehicle_angular_velocity", [("float", "xyz", 3)], ts + 2000, {"xyz": out})])


def _study(tmp_path: Path, output: str = OUT) -> Path:
    _ulog(tmp_path / "roll.ulg", fly(*AXES["roll"], seed=51, duration_s=60.0, sweep_fraction=1.0))
    _ulog(tmp_path / "doublets.ulg", fly(*AXES["roll"], seed=52, duration_s=30.0))
    p = tmp_path / "s.toml"
    p.write_text(f'name = "s"\n[[loop]]\nname = "roll"\ndt = 0.04\nstructure = "pid_z"\n'
                 f'data = {{ file = "roll.ulg", input = "{IN}", output = "{output}", poles = 2, '
                 f'verify = "doublets.ulg" }}\n')
    return p


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_a_ulog_data_loop_with_a_verification_log(tmp_path):
    study = load_study(_study(tmp_path))
    (lp,) = study.loop
    res = identified(lp)
    # a torque setpoint is a controller's output: flown under feedback as far as the log tells, so never "good"
    # without a reference (these synthetic data are open loop: J itself is good)
    assert res.rate_hz == pytest.approx(50.0) and res.quality == "closed-loop" and res.cost <= 50
    assert res.validation.source == "verify" and res.check != "poor"
    assert res.model.values()["pole_wn_1_rad_s"] == pytest.approx(14.8528, rel=0.05)
    key = loop_key(study, "roll")
    _ulog(tmp_path / "doublets.ulg", fly(*AXES["roll"], seed=53, duration_s=30.0))  # another verification log
    assert loop_key(load_study(tmp_path / "s.toml"), "roll") != key


def test_a_wrong_signal_names_the_data_field(tmp_path):
    with pytest.raises(TunerError, match=r"data.output \(roll.ulg\): output 'vehicle_angular_velocity.q': topic "
                                         r"'vehicle_angular_velocity' has no field 'q'; fields: \['xyz\[0\]'"):
        load_study(_study(tmp_path, output="vehicle_angular_velocity.q"))
