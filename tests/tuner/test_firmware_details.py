"""Issue 40 item 1: the firmware details that move a margin, in the law the tool designs and verifies.

Each law below is written here, per sample, from the firmware source named in its docstring (not from the tool's
transfer functions); the tool's structure must produce the same output sample for sample, and the phase margin the
verifier reports must be the one computed here from that per-sample law (its frequency response measured by running
it on a complex exponential) and the plant's exact zero-order-hold discretisation (scipy). The figures before (the
detail left out, as the tool had it) and after are checked on a comparison plant.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from tuner import analyze, make_plant
from tuner.cli import main
from tuner.controllers import get_structure
from tuner.errors import TunerError
from tuner.firmware import vehicle_from_text
from tuner.firmware.bind import bind_law

DT = 0.0025  # 400 Hz
YAW_PLANT = ([40.0], [0.02, 1.02, 1.0])  # 40/((s + 1)(0.02 s + 1)): yaw rate from normalised torque, 20 ms motors


def _alpha(f_hz: float, dt: float) -> float:
    return 1.0 if f_hz <= 0 else dt / (dt + 1.0 / (2.0 * math.pi * f_hz))


def px4_law(r, w, g, dt):
    """PX4 ``RateControl::update`` (``src/lib/rate_control/rate_control.cpp``), then ``MulticopterRateControl::Run``'s
    ``torque_setpoint(2) = _output_lpf_yaw.update(torque_setpoint(2), dt)``, an ``AlphaFilter`` at
    ``MC_YAW_TQ_CUTOFF`` (``src/modules/mc_rate_control/MulticopterRateControl.cpp``, PX4 main)."""
    kp, ki, kd = g["K"] * g["P"], g["K"] * g["I"], g["K"] * g["D"]
    a, aq = _alpha(g["dgyro_hz"], dt), _alpha(g.get("tq_hz", 0.0), dt)
    x_i = w_prev = wdot_f = q = 0.0
    u = np.zeros(len(r), dtype=complex)
    for k in range(len(r)):
        e = r[k] - w[k]
        wdot_f += a * ((w[k] - w_prev) / dt - wdot_f)
        w_prev = w[k]
        torque = kp * e + x_i - kd * wdot_f + g["FF"] * r[k]
        q += aq * (torque - q)  # the yaw output low-pass
        u[k] = q
        x_i += ki * e * dt
    return u


def ardupilot_law(target, w, g, dt):
    """ArduPilot ``AC_PID::update_all`` and ``get_ff`` (``libraries/AC_PID/AC_PID.cpp``): FLTT on the target, FLTE
    on the error, FLTD on the error's derivative, I before the output, ``FF * _target + D_FF * _target_derivative``
    with ``_target_derivative = (_target - target_last)/dt``."""
    at, ae, ad = _alpha(g["fltt_hz"], dt), _alpha(g["flte_hz"], dt), _alpha(g["fltd_hz"], dt)
    T = E = D = integ = e_prev = 0.0
    u = np.zeros(len(target), dtype=complex)
    for k in range(len(target)):
        t_last = T
        T += at * (target[k] - T)
        E += ae * ((T - w[k]) - E)
        D += ad * ((E - e_prev) / dt - D)
        e_prev = E
        integ += g["I"] * E * dt
        u[k] = g["P"] * E + g["D"] * D + integ + g["FF"] * T + g.get("dff", 0.0) * (T - t_last) / dt
    return u


def _feedback_response(law, g, w_rad, dt, n=6000):
    """``C_fb(e^{jwT})`` of the per-sample law: run on ``w[k] = z^k`` (r = 0); past the transients ``u[k] = -C z^k +
    c`` (the integrator's constant), so ``C = -(u[k] - u[k-1])/(z^(k-1) (z - 1))``."""
    z = np.exp(1j * w_rad * dt)
    w = z ** np.arange(n)
    u = law(np.zeros(n), w, g, dt)
    return -(u[-1] - u[-2]) / (z ** (n - 2) * (z - 1))


def _phase_margin(law, g, dt, plant=YAW_PLANT):
    """The phase margin (deg) of the per-sample law on the plant's ZOH model at ``dt`` (one gain crossing)."""
    bd, ad, _ = signal.cont2discrete((plant[0], plant[1]), dt, method="zoh")
    bd = np.ravel(bd)

    def loop(w):
        z = np.exp(1j * w * dt)
        return _feedback_response(law, g, w, dt) * np.polyval(bd, z) / np.polyval(ad, z)

    grid = np.geomspace(0.05, 0.99 * math.pi / dt, 80)
    mags = np.array([abs(loop(w)) for w in grid])
    i = int(np.flatnonzero((mags[:-1] >= 1) & (mags[1:] < 1))[0])
    lo, hi = grid[i], grid[i + 1]
    for _ in range(40):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if abs(loop(mid)) >= 1 else (lo, mid)
    return 180.0 + math.degrees(np.angle(loop(math.sqrt(lo * hi))))


def _tool_pm(structure, gains, plant=YAW_PLANT):
    c = get_structure(structure).tf(gains, DT)
    return analyze(make_plant(*plant), c, dt=DT).metrics.phase_margin_deg


PX4_YAW = {"P": 0.2, "I": 0.1, "D": 0.0, "FF": 0.0, "K": 1.0, "dgyro_hz": 20.0, "int_lim": 0.3}
AP_YAW = {"P": 0.18, "I": 0.018, "D": 0.0, "FF": 0.0, "fltt_hz": 20.0, "fltd_hz": 20.0, "imax": 0.5}


@pytest.mark.parametrize("tq_hz", [0.0, 2.0, 5.0])
def test_px4_yaw_torque_low_pass_is_in_the_law(tq_hz):
    g = {**PX4_YAW, "D": 0.002, "FF": 0.05, "tq_hz": tq_hz}
    rng = np.random.default_rng(3)
    r, w = rng.standard_normal(500), rng.standard_normal(500)
    c = get_structure("px4_rate").tf(g, DT)
    u = signal.lfilter(c.num_r, c.den, r) - signal.lfilter(c.num, c.den, w)
    np.testing.assert_allclose(u, px4_law(r, w, g, DT).real, rtol=1e-9, atol=1e-9)


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_px4_yaw_default_gains_phase_margin_with_the_filter():
    """PX4's default yaw gains (MC_YAWRATE_P 0.2, I 0.1) on the yaw plant: 84.1 deg without the 2 Hz torque filter
    (the tool before), 57.2 deg with it (what the vehicle flies); both as computed here from the per-sample law."""
    before = _tool_pm("px4_rate", {**PX4_YAW, "tq_hz": 0.0})
    after = _tool_pm("px4_rate", {**PX4_YAW, "tq_hz": 2.0})
    assert before == pytest.approx(_phase_margin(px4_law, {**PX4_YAW, "tq_hz": 0.0}, DT), abs=0.05)
    assert after == pytest.approx(_phase_margin(px4_law, {**PX4_YAW, "tq_hz": 2.0}, DT), abs=0.05)
    assert before - after > 20  # (84.1 -> 57.2 deg)
    v = vehicle_from_text("1\t1\tMC_YAWRATE_P\t0.2\t9\n1\t1\tMC_YAWRATE_I\t0.1\t9\n1\t1\tMC_YAWRATE_D\t0\t9\n",
                          axis="yaw")
    assert v.fixed["tq_hz"] == 2.0 and any("MC_YAW_TQ_CUTOFF not in" in n for n in v.notes)
    st, _, now = bind_law("px4_rate", v, DT)
    assert st.fixed_values["tq_hz"] == 2.0 and now["tq_hz"] == 2.0
    assert vehicle_from_text("MC_ROLLRATE_P,0.1\nMC_ROLLRATE_I,0.1\nMC_ROLLRATE_D,0.001\n").fixed["tq_hz"] == 0.0


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_ardupilot_yaw_flte_default_is_the_firmware_default():
    """A vehicle file without ATC_RAT_YAW_FLTE: ArduPilot flies AC_ATC_MULTI_RATE_YAW_FILT_HZ = 2.5 Hz
    (AC_AttitudeControl_Multi.h's Defaults block for _pid_rate_yaw); PM 88.7 deg with 0 (the tool before), 67.6 with
    2.5 on the yaw plant, both as computed here from the per-sample AC_PID."""
    v = vehicle_from_text("ATC_RAT_YAW_P,0.18\nATC_RAT_YAW_I,0.018\nATC_RAT_YAW_D,0\nSCHED_LOOP_RATE,400\n",
                          axis="yaw")
    assert v.fixed["flte_hz"] == 2.5 and any("ATC_RAT_YAW_FLTE not in" in n and "2.5" in n for n in v.notes)
    roll = vehicle_from_text("ATC_RAT_RLL_P,0.135\nATC_RAT_RLL_I,0.135\nATC_RAT_RLL_D,0.0036\n", axis="roll")
    assert roll.fixed == {"fltt_hz": 20.0, "flte_hz": 0.0, "fltd_hz": 20.0, "imax": 0.5, "dff": 0.0}
    before = _tool_pm("ardupilot_rate", {**AP_YAW, "flte_hz": 0.0})
    after = _tool_pm("ardupilot_rate", {**AP_YAW, "flte_hz": 2.5})
    assert before == pytest.approx(_phase_margin(ardupilot_law, {**AP_YAW, "flte_hz": 0.0}, DT), abs=0.05)
    assert after == pytest.approx(_phase_margin(ardupilot_law, {**AP_YAW, "flte_hz": 2.5}, DT), abs=0.05)
    assert before - after > 15  # (88.7 -> 67.6 deg)


@pytest.mark.parametrize("fltt", [20.0, 0.0])
def test_ardupilot_d_ff_is_the_target_derivative(fltt):
    g = {"P": 0.135, "I": 0.135, "D": 0.0036, "FF": 0.05, "fltt_hz": fltt, "flte_hz": 2.5, "fltd_hz": 20.0,
         "imax": 0.5, "dff": 0.01}
    rng = np.random.default_rng(4)
    r, w = rng.standard_normal(500), rng.standard_normal(500)
    c = get_structure("ardupilot_rate").tf(g, DT)
    u = signal.lfilter(c.num_r, c.den, r) - signal.lfilter(c.num, c.den, w)
    np.testing.assert_allclose(u, ardupilot_law(r, w, g, DT).real, rtol=1e-9, atol=1e-9)
    v = vehicle_from_text("ATC_RAT_RLL_P,0.135\nATC_RAT_RLL_I,0.135\nATC_RAT_RLL_D,0.0036\nATC_RAT_RLL_D_FF,0.01\n")
    assert v.fixed["dff"] == 0.01


@pytest.mark.parametrize("name", ["ATC_RAT_RLL_PDMX", "ATC_RAT_RLL_NTF", "ATC_RAT_RLL_NEF"])
def test_ardupilot_terms_outside_the_law_are_refused_by_name(name, tmp_path, capsys):
    text = f"ATC_RAT_RLL_P,0.135\nATC_RAT_RLL_I,0.135\nATC_RAT_RLL_D,0.0036\n{name},1\n"
    with pytest.raises(TunerError, match=name) as e:
        vehicle_from_text(text)
    assert e.value.field == ("params",)
    vehicle_from_text(text.replace(f"{name},1", f"{name},0"))  # 0: off, read
    p = tmp_path / "v.parm"
    p.write_text(text)
    code = main(["analyze", "--plant", "30/((s+1)*(0.03*s+1))", "--structure", "ardupilot_rate", "--params", str(p)])
    assert code == 2 and name in capsys.readouterr().err


def test_ardupilot_smax_is_read_and_its_effect_said():
    v = vehicle_from_text("ATC_RAT_RLL_P,0.135\nATC_RAT_RLL_I,0.135\nATC_RAT_RLL_D,0.0036\nATC_RAT_RLL_SMAX,30\n")
    assert any("ATC_RAT_RLL_SMAX = 30" in n and "oscillation" in n for n in v.notes)


# -- the loop rate from what the log shows (item 1d) and the parameters changed in flight (item 2) ----------------

ROLL_PLANT = ([250.0], [0.02, 1.0, 0.0])  # 250/(s (0.02 s + 1))
PX4_LOG_PARAMS = {"MC_ROLLRATE_P": 0.15, "MC_ROLLRATE_I": 0.2, "MC_ROLLRATE_D": 0.003, "MC_ROLLRATE_K": 1.0,
                  "IMU_DGYRO_CUTOFF": 30.0, "IMU_GYRO_RATEMAX": 800}


def _imu_log(path, gyro_hz, params, changed=(), topic="vehicle_imu_status"):
    from tests.ulog_writer import Topic, write_ulog

    n = 300
    if topic == "vehicle_imu_status":
        t = np.arange(n) * 10_000  # (the status is published at 100 Hz; it says the gyro's rate)
        tp = Topic(topic, [("float", "gyro_rate_hz", 0)], t, {"gyro_rate_hz": np.full(n, float(gyro_hz))})
    else:  # an older log: the gyro's samples themselves
        t = (np.arange(n) * 1e6 / gyro_hz).astype(int)
        tp = Topic(topic, [("float", "gyro_rad", 3)], t, {"gyro_rad": np.zeros((n, 3))})
    return write_ulog(path, [tp], params=params, changed=changed)


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_px4_loop_rate_is_the_gyros_not_the_cap(tmp_path):
    """PX4's rate loop runs on every vehicle_angular_velocity, which the gyro drives; IMU_GYRO_RATEMAX only caps it.
    A log whose gyro ran at 250 Hz under a cap of 800: the loop at 250 Hz, and the phase margin there (computed here
    from the per-sample law at dt = 4 ms) is 5 deg below the one at 800 Hz (the tool before)."""
    from tuner.firmware import read_params

    v = read_params(_imu_log(tmp_path / "a.ulg", 250.0, PX4_LOG_PARAMS), axis="roll")
    assert v.loop_hz == 250.0 and "vehicle_imu_status.gyro_rate_hz" in v.loop_source and "cap" in v.loop_source
    g = {"P": 0.15, "I": 0.2, "D": 0.003, "FF": 0.0, "K": 1.0, "dgyro_hz": 30.0, "int_lim": 0.3}
    c = get_structure("px4_rate").tf(g, 1 / 250)
    at_250 = analyze(make_plant(*ROLL_PLANT), c, dt=1 / 250).metrics.phase_margin_deg
    c800 = get_structure("px4_rate").tf(g, 1 / 800)
    at_800 = analyze(make_plant(*ROLL_PLANT), c800, dt=1 / 800).metrics.phase_margin_deg
    assert at_250 == pytest.approx(_phase_margin(px4_law, g, 1 / 250, ROLL_PLANT), abs=0.05)
    assert at_800 == pytest.approx(_phase_margin(px4_law, g, 1 / 800, ROLL_PLANT), abs=0.05)
    assert at_800 - at_250 > 3  # (80.6 -> 75.4 deg)
    # above the cap, VehicleAngularVelocity publishes every roundf(gyro / cap) samples (UpdateSampleRate): 1 kHz under
    # 400 every 3rd (333 Hz), 2 kHz under 800 every 3rd (667 Hz), 1 kHz under 800 every one (1 kHz: above the "cap")
    for gyro, cap, every in ((1000.0, 400, 3), (2000.0, 800, 3), (1000.0, 800, 1), (1200.0, 800, 2)):
        above = read_params(_imu_log(tmp_path / f"b{gyro:g}_{cap}.ulg", gyro,
                                     PX4_LOG_PARAMS | {"IMU_GYRO_RATEMAX": cap}))
        assert above.loop_hz == pytest.approx(gyro / every), (gyro, cap)
    old = dict(PX4_LOG_PARAMS)
    del old["IMU_GYRO_RATEMAX"]
    v = read_params(_imu_log(tmp_path / "c.ulg", 250.0, old, topic="sensor_combined"))
    assert v.loop_hz == 250.0 and "sensor_combined" in v.loop_source
    params_file = tmp_path / "q.params"
    params_file.write_text("".join(f"1\t1\t{k}\t{v}\t9\n" for k, v in PX4_LOG_PARAMS.items()))
    v = read_params(params_file)
    assert v.loop_hz == 800.0 and "a cap on the gyro's rate" in v.loop_source


def test_ardupilot_fast_rate_thread(tmp_path):
    base = "ATC_RAT_RLL_P,0.135\nATC_RAT_RLL_I,0.135\nATC_RAT_RLL_D,0.0036\nSCHED_LOOP_RATE,400\n"
    assert vehicle_from_text(base).loop_hz == 400.0
    v = vehicle_from_text(base + "FSTRATE_ENABLE,3\nFSTRATE_DIV,2\nINS_GYRO_RATE,1\n")
    assert v.loop_hz == 1000.0 and "FSTRATE_DIV 2" in v.loop_source  # 2 kHz / 2
    for bad in ("1e12", "4", "1.5", "-1"):  # (1000 * 2**int(1e12) held the reader for good)
        with pytest.raises(TunerError, match="INS_GYRO_RATE"):
            vehicle_from_text(base + f"FSTRATE_ENABLE,1\nINS_GYRO_RATE,{bad}\n")
    v = vehicle_from_text(base + "FSTRATE_ENABLE,1\n")
    assert v.loop_hz is None and any("INS_GYRO_RATE" in n for n in v.notes)
    with pytest.raises(TunerError, match="give dt"):
        bind_law("ardupilot_rate", v, None)


def test_px4_parameters_changed_in_flight_are_read(tmp_path, capsys):
    from tuner.firmware import read_params

    p = _imu_log(tmp_path / "f.ulg", 250.0, PX4_LOG_PARAMS, changed=[(1_500_000, "MC_ROLLRATE_P", 0.18)])
    v = read_params(p, axis="roll")
    assert v.gains["P"] == pytest.approx(0.18)
    assert any("MC_ROLLRATE_P changed in flight" in n and "0.18 at 1.5 s" in n for n in v.notes)
    code = main(["analyze", "--plant", "250/(s*(0.02*s+1))", "--structure", "px4_rate", "--params", str(p)])
    out = capsys.readouterr().out
    assert code in (0, 1) and "MC_ROLLRATE_P changed in flight" in out and "loop rate: 250 Hz from" in out
    assert "assumed: MC_RR_INT_LIM not in" in out  # what was assumed, in the text


# -- the vehicle's own file and generation (item 2) ----------------------------------------------------------------

def test_ardupilot_files_of_every_form(tmp_path):
    from tuner.firmware import read_params

    text = ("# saved by MAVProxy\nATC_RAT_RLL_P 0.12\nATC_RAT_RLL_I=0.1  # tuned\nATC_RAT_RLL_D,0.003\n"
            "FRAME_CLASS 1 @READONLY\nSCHED_LOOP_RATE,400\n")
    for suffix in (".parm", ".param", ".params", ".txt", ""):
        p = tmp_path / f"copter{suffix}"
        p.write_text(text)
        v = read_params(p, axis="roll")
        assert v.firmware == "ardupilot" and v.gains["P"] == 0.12 and v.gains["I"] == 0.1 and v.raw["FRAME_CLASS"] == 1
    with pytest.raises(TunerError, match="NAME,value"):
        vehicle_from_text("ATC_RAT_RLL_P,0.12 0.3\n")


def test_export_writes_the_vehicles_ids_and_only_its_parameters():
    """A vehicle id 3 file from an older PX4 (no MC_ROLLRATE_K, no MC_RR_INT_LIM): QGroundControl loads the export
    onto that vehicle (ids 3, 1) and it names no parameter that firmware lacks; the header says what was assumed."""
    from tuner.export.paramfile import param_file
    from tuner.firmware.bind import vehicle_dict

    qgc = "".join(f"3\t1\t{k}\t{v}\t9\n" for k, v in (("MC_ROLLRATE_P", 0.14), ("MC_ROLLRATE_I", 0.1),
                                                       ("MC_ROLLRATE_D", 0.004), ("MC_ROLLRATE_FF", 0.0)))
    v = vehicle_from_text(qgc, axis="roll")
    assert v.ids == (3, 1)
    res = {"structure": "px4_rate", "controller": {"dt": 0.0025}, "meets_spec": True, "vehicle": vehicle_dict(v),
           "gains": {"P": 0.12, "I": 0.2, "D": 0.002, "FF": 0.0, "K": 1.0, "dgyro_hz": 20.0, "int_lim": 0.3,
                     "tq_hz": 0.0}}
    text, _ = param_file(res, "px4", axis="roll")
    rows = [ln.split("\t") for ln in text.splitlines() if not ln.startswith("#")]
    assert {r[2] for r in rows} == {"MC_ROLLRATE_P", "MC_ROLLRATE_I", "MC_ROLLRATE_D", "MC_ROLLRATE_FF"}
    assert all(r[:2] == ["3", "1"] for r in rows)
    head = [ln for ln in text.splitlines() if ln.startswith("#")]
    assert any("not written" in h and "MC_ROLLRATE_K" in h and "MC_RR_INT_LIM" in h for h in head)
    assert any(h.startswith("# assumed: MC_ROLLRATE_K not in") for h in head)
    assert any("vehicle id 3, component id 1 (from the vehicle's file)" in h for h in head)


# -- a typed plant with the vehicle's gyro filter (item 1e) --------------------------------------------------------

def _butterworth_law(x, f_hz, rate_hz):
    """LowPassFilter2p (PX4 src/lib/mathlib/math/filter/LowPassFilter2p.hpp, ArduPilot libraries/Filter/
    LowPassFilter2p.cpp): the biquad from the bilinear transform with prewarping at the sample rate; at the gyro's
    rate (8 kHz here) its response matches the continuous Butterworth the tool adds."""
    fr = rate_hz / f_hz
    ohm = math.tan(math.pi / fr)
    c = 1.0 + 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm
    b0 = ohm * ohm / c
    a1 = 2.0 * (ohm * ohm - 1.0) / c
    a2 = (1.0 - 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm) / c
    return signal.freqz([b0, 2 * b0, b0], [1.0, a1, a2], worN=x, fs=rate_hz)[1]


def test_typed_plant_takes_the_vehicles_gyro_filter(tmp_path, capsys):
    """ArduPilot's INS_GYRO_FILTER 20 Hz on a typed roll plant: the filter is in the loop the tool verifies (its
    response against LowPassFilter2p's biquad at an 8 kHz gyro, written here from the source), PM 80.7 -> 52.1 deg;
    the text and the export header say "typed plant"."""
    import json

    from tuner.export.paramfile import param_file
    from tuner.firmware.bind import typed_plant, vehicle_dict

    parm = "ATC_RAT_RLL_P,0.135\nATC_RAT_RLL_I,0.135\nATC_RAT_RLL_D,0.0036\nSCHED_LOOP_RATE,400\nINS_GYRO_FILTER,20\n"
    v = vehicle_from_text(parm)
    p0 = make_plant(*ROLL_PLANT)
    p1, rec = typed_plant(p0, v)
    f = np.array([1.0, 10.0, 20.0, 60.0])
    ratio = p1.freqresp(2 * np.pi * f) / p0.freqresp(2 * np.pi * f)
    np.testing.assert_allclose(ratio, _butterworth_law(f, 20.0, 8000.0), rtol=2e-3, atol=1e-4)
    g = {"P": 0.135, "I": 0.135, "D": 0.0036, "FF": 0.0, **v.fixed}
    c = get_structure("ardupilot_rate").tf(g, DT)
    before = analyze(p0, c, dt=DT).metrics.phase_margin_deg
    after = analyze(p1, c, dt=DT).metrics.phase_margin_deg
    assert before - after > 20  # (80.7 -> 52.1 deg)
    f_path = tmp_path / "v.parm"
    f_path.write_text(parm)
    main(["analyze", "--plant", "250/(s*(0.02*s+1))", "--structure", "ardupilot_rate", "--params", str(f_path),
          "--json"])
    out = json.loads(capsys.readouterr().out)
    assert out["metrics"]["phase_margin_deg"] == pytest.approx(after, abs=1e-6)
    assert out["vehicle"]["typed_plant"]["gyro_filter_hz"] == 20.0
    main(["analyze", "--plant", "250/(s*(0.02*s+1))", "--structure", "ardupilot_rate", "--params", str(f_path)])
    assert "typed plant: the vehicle's gyro low-pass INS_GYRO_FILTER 20 Hz" in capsys.readouterr().out
    res = {"structure": "ardupilot_rate", "controller": {"dt": DT}, "meets_spec": True, "gains": g,
           "vehicle": {**vehicle_dict(v), "typed_plant": rec}}
    text, _ = param_file(res, "ardupilot", axis="roll")
    assert "typed plant: the gyro low-pass INS_GYRO_FILTER 20 Hz (second order) added" in text
    assert "part of the identified plant" not in text
