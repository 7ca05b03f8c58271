"""A study loop from a flight log to a firmware law: the log's data identified with its reference, the law bound
to the vehicle's parameters (the same log), the actuator's limits simulated; and the fields' errors."""

from __future__ import annotations

import pytest
from closed_loop import fly, write

from tuner.studies.evaluate import tune_loop
from tuner.studies.schema import InvalidStudyError, load_study, loop_key, vehicle_of

LOOP = ('name = "fw"\n[[loop]]\nname = "roll_rate"\ndt = 0.0025\nstructure = "px4_rate"\nparams = "flight.ulg"\n'
        'axis = "roll"\ntime_budget_s = 5\nactuator = {{ u_max = 0.4, step_size = 8 }}\n'
        'data = {{ file = "flight.ulg", input = "vehicle_torque_setpoint.xyz[0]", '
        'output = "vehicle_angular_velocity.xyz[0]", reference = "vehicle_rates_setpoint.roll", poles = 3, '
        'zeros = 2 }}\n{extra}')


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    d = tmp_path_factory.mktemp("fw")
    write(fly("sweep", seconds=40, seed=2, sweep_amplitude=3.0, turbulence=0.03), d / "flight.ulg")
    p = d / "s.toml"
    p.write_text(LOOP.format(extra=""))
    return p


@pytest.mark.slow
def test_a_log_to_a_firmware_law_in_a_study(study):
    s = load_study(study)
    (lp,) = s.loop
    v = vehicle_of(lp)
    assert v.firmware == "px4" and v.loop_hz == 400
    out = tune_loop(s, lp, {})
    assert out["structure"] == "px4_rate" and out["gains"]["dgyro_hz"] == 20.0
    assert out["vehicle"]["source"].startswith("flight.ulg") and out["current"]["gains"]["P"] == pytest.approx(0.15)
    assert out["saturated_step"]["u_max"] == 0.4
    assert out["identification"]["quality"] in ("good", "acceptable")  # the joint estimate, with the reference


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_the_key_follows_the_vehicle(study):
    s = load_study(study)
    key = loop_key(s, "roll_rate")
    (study.parent / "quad.params").write_text("1\t1\tMC_ROLLRATE_P\t0.2\t9\n1\t1\tMC_ROLLRATE_I\t0.2\t9\n"
                                              "1\t1\tMC_ROLLRATE_D\t0.003\t9\n")
    other = study.parent / "s2.toml"
    other.write_text(LOOP.format(extra="").replace('params = "flight.ulg"', 'params = "quad.params"'))
    assert loop_key(load_study(other), "roll_rate") != key


@pytest.mark.parametrize("changes, words", [
    ([('structure = "px4_rate"', 'structure = "pid"')], "params: the vehicle's parameters set a firmware rate law"),
    ([("dt = 0.0025\n", ""), ('structure = "px4_rate"', 'structure = "pi"'), ('params = "flight.ulg"\n', "")],
     "actuator: the saturated step runs the law at its sample time"),
    ([("dt = 0.0025\n", "")], "px4_rate is discrete: give dt"),
    ([("u_max = 0.4", "u_max = -0.4")], "u_min"),
    ([('params = "flight.ulg"', 'params = "none.params"')], "params"),
])
def test_bad_fields_name_the_loop(study, changes, words):
    bad = study.parent / "bad.toml"
    text = LOOP.format(extra="")
    for old, new in changes:
        text = text.replace(old, new)
    bad.write_text(text)
    with pytest.raises(InvalidStudyError, match=words):
        load_study(bad)
