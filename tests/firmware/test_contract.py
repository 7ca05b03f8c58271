"""One contract suite, run against every registered firmware (tuner.firmware.registry), as Optuna runs one suite
against every sampler: a firmware added to the registry is tested here without a line of this file changing.

What every firmware's module must hold: its law's coefficients evaluate alike on numbers and on CasADi symbols; the
law's transfer functions agree, sample by sample, with the module's own run of the firmware's update equations
(its saturation simulator, with limits that never bind); its defaults lie inside its documented ranges; its
parameter names are unique per axis and name every quantity the law has; a parameter file written and read back
gives the values written; its parameters are told apart from every other firmware's; an unknown firmware, structure
or format is refused naming the known ones; and (slow) the law tunes a simple rate plant, the verifier passes, and
the tuned law's file, exported and read back, is the law that was tuned.
"""

from __future__ import annotations

import dataclasses
import datetime as dt_
import math

import numpy as np
import pytest
from scipy import signal

from tuner.controllers import STRUCTURES, get_structure
from tuner.errors import TunerError
from tuner.export.paramfile import PARAM_FORMATS, make_param_file
from tuner.firmware.names import AXES, law_names, range_problem, stored_value
from tuner.firmware.params import detect_firmware, read_params, vehicle_from_raw
from tuner.firmware.registry import by_format, by_structure, firmwares, get_firmware, names
from tuner.identify.flight import what_to_fly

FIRMWARES = firmwares()
IDS = [f.name for f in FIRMWARES]
DT = 0.0025  # 400 Hz
LAW = ("P", "I", "D", "FF")


def _gains(fw, axis: str, rng: np.random.Generator) -> dict[str, float]:
    """Gains inside the axis' documented ranges (a finite upper end, or 3x the zero rule's scale when open)."""
    rngs, scale = fw.ranges(axis), fw.scale(axis)
    out = {}
    for p in LAW:
        lo, hi = rngs.get(p, (0.0, math.inf))
        if not math.isfinite(hi):
            hi = lo + 3.0 * scale.get(p, 1.0)
        v = float(rng.uniform(max(lo, 0.0) + 0.05 * (hi - lo), hi - 0.05 * (hi - lo)))
        out[p] = round(v) if p in fw.integer else v
    return out


def _tf_output(ctrl, r, w):
    return signal.lfilter(ctrl.num_r, ctrl.den, r) - signal.lfilter(ctrl.num, ctrl.den, w)


def test_the_registry_holds_each_firmware_once_with_its_structure_and_format():
    assert len(set(names())) == len(FIRMWARES) >= 2
    for fw in FIRMWARES:
        assert by_structure(fw.structure) is fw and by_format(fw.export_format) is fw
        assert fw.structure in STRUCTURES and get_structure(fw.structure).firmware == fw.name
        assert PARAM_FORMATS[fw.export_format] == (fw.structure, fw.name)
    assert len({f.structure for f in FIRMWARES}) == len({f.export_format for f in FIRMWARES}) == len(FIRMWARES)


@pytest.mark.parametrize("fw", FIRMWARES, ids=IDS)
@pytest.mark.parametrize("axis", AXES)
def test_coefficients_alike_on_numbers_and_casadi_symbols(fw, axis):
    import casadi as ca

    fixed = fw.law_defaults(axis)
    x = [_gains(fw, axis, np.random.default_rng(3))[p] for p in LAW]
    xs = ca.SX.sym("x", 4)
    for law in (fw.coeffs, fw.ref_coeffs):
        num, den = law(x, DT, fixed)
        snum, sden = law([xs[i] for i in range(4)], DT, fixed)
        f = ca.Function("f", [xs], [ca.vertcat(*[ca.SX(c) for c in (*snum, *sden)])])
        got = np.asarray(f(x)).ravel()
        np.testing.assert_allclose(got, np.array([float(c) for c in (*num, *den)]), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("fw", FIRMWARES, ids=IDS)
@pytest.mark.parametrize("axis", AXES)
def test_the_law_is_its_own_update_equations_sample_by_sample(fw, axis):
    """The structure's ``u = C_r r - C_fb w`` against the module's simulator of the firmware's per-sample update, on
    random setpoints and rates small enough that no limit binds (PX4's fade is then 1 to 1e-8)."""
    rng = np.random.default_rng(7)
    g = {**fw.law_defaults(axis), **_gains(fw, axis, rng)}
    if fw.integrator_limit:
        g[fw.integrator_limit] = 1e9
    r, w = 1e-3 * rng.standard_normal(600), 1e-3 * rng.standard_normal(600)
    ctrl = get_structure(fw.structure).tf(g, DT)
    sim = fw.simulator(g, DT, -math.inf, math.inf)
    u = np.array([sim(float(a), float(b))[0] for a, b in zip(r, w)])
    ref = _tf_output(ctrl, r, w)
    np.testing.assert_allclose(ref, u, rtol=1e-6, atol=1e-7 * np.max(np.abs(u)))  # (PX4 fade: 2e-8 of I)


@pytest.mark.parametrize("fw", FIRMWARES, ids=IDS)
@pytest.mark.parametrize("axis", AXES)
def test_defaults_lie_inside_the_documented_ranges(fw, axis):
    rngs = fw.ranges(axis)
    for k, v in fw.law_defaults(axis).items():
        if k in rngs:
            assert range_problem(fw.name, axis, k, v) is None, (k, v, rngs[k])
    assert range_problem(fw.name, axis, "loop_hz", fw.default_loop_hz) is None
    st = get_structure(fw.structure).with_ranges(axis)
    for p in LAW:  # the search box keeps to the ranges
        r = st.param_range(p)
        if p in rngs:
            assert r is not None and tuple(r) == tuple(rngs[p])


@pytest.mark.parametrize("fw", FIRMWARES, ids=IDS)
@pytest.mark.parametrize("axis", AXES)
def test_names_are_unique_per_axis_and_name_every_quantity(fw, axis):
    n = law_names(fw.name, axis)
    # a fixed value without a parameter on this axis is one the firmware does not have there: off (0), as PX4's
    # yaw torque low-pass on roll and pitch
    law_keys = [*LAW, *(k for k, v in fw.law_defaults(axis).items()
                        if k not in fw.constants and (k in n or v != 0))]
    assert all(k in n for k in law_keys), [k for k in law_keys if k not in n]
    assert all(k in n for k in fw.export_order) and "loop_hz" in n
    own = [n[k] for k in law_keys]
    assert len(set(own)) == len(own)  # no two of the axis' law quantities share a parameter
    for other in AXES:  # the axis' gains are its own
        if other != axis:
            assert not {n[p] for p in LAW} & {law_names(fw.name, other)[p] for p in LAW}


@pytest.mark.parametrize("fw", FIRMWARES, ids=IDS)
def test_its_parameters_are_told_apart_from_every_other_firmwares(fw):
    n = law_names(fw.name, "roll")
    raw = {n[p]: 1.0 for p in ("P", "I", "D")}
    assert detect_firmware(raw) == fw.name
    v = vehicle_from_raw(raw, axis="roll")
    assert v.firmware == fw.name
    for other in FIRMWARES:
        if other is not fw:
            with pytest.raises(TunerError, match=f"holds {fw.name} parameters"):
                vehicle_from_raw(raw, axis="roll", firmware=other.name)


def _result(fw, axis: str, gains: dict[str, float]) -> dict:
    return {"structure": fw.structure, "axis": axis, "controller": {"dt": DT}, "meets_spec": True,
            "gains": {**fw.law_defaults(axis), **gains}}


@pytest.mark.parametrize("fw", FIRMWARES, ids=IDS)
@pytest.mark.parametrize("axis", AXES)
def test_a_parameter_file_written_then_read_gives_the_values_written(fw, axis, tmp_path):
    g = _gains(fw, axis, np.random.default_rng(11))
    pf = make_param_file(_result(fw, axis, g), fw.export_format, axis=axis, date=dt_.date(2026, 1, 1))
    p = tmp_path / pf.name
    p.write_text(pf.text)
    assert p.suffix == "." + fw.suffix
    v = read_params(p, axis=axis, firmware=fw.name)
    assert v.firmware == fw.name and v.axis == axis
    written = {**fw.law_defaults(axis), **g}
    for k in fw.export_order:
        want = stored_value(fw.name, axis, k, written[k])
        got = v.gains[k] if k in LAW else v.fixed[k]  # the file's decimal, which the firmware stores as `want`
        assert stored_value(fw.name, axis, k, got) == want, (k, got, want)


@pytest.mark.parametrize("fw", FIRMWARES, ids=IDS)
def test_unknown_firmware_names_are_refused_naming_the_known_ones(fw):
    for call in (lambda: get_firmware("inav"), lambda: stored_value("inav", "roll", "P", 0.1),
                 lambda: range_problem("inav", "roll", "P", 0.1), lambda: law_names("inav", "roll"),
                 lambda: what_to_fly("inav"), lambda: vehicle_from_raw({"X": 1.0}, firmware="inav")):
        with pytest.raises(TunerError, match="unknown firmware 'inav'") as e:
            call()
        assert fw.name in str(e.value)
    with pytest.raises(TunerError, match="format must be one of") as e:
        make_param_file(_result(fw, "roll", {}), "inav")
    assert fw.export_format in str(e.value)


@pytest.mark.parametrize("fw", FIRMWARES, ids=IDS)
@pytest.mark.parametrize("axis", AXES)
def test_what_to_fly_names_the_signals_to_identify(fw, axis):
    s = fw.log_signals(axis)
    assert set(s) == {"input", "output", "reference"} and len(set(s.values())) == 3
    text = what_to_fly(fw.name, axis)
    assert fw.title in text and all(v in text for v in s.values())
    assert fw.what_to_fly(axis) in what_to_fly(None, axis)


@pytest.mark.slow
@pytest.mark.parametrize("fw", FIRMWARES, ids=IDS)
def test_tune_verify_export_and_read_back(fw, tmp_path):
    """A roll-rate plant (normalised torque to rad/s, the gyro low-pass, a sample of delay) tuned at 400 Hz: the
    verifier passes; the exported file, read back, is the law that was tuned (the values as the firmware stores
    them), and the law re-bound to that file has the tuned law's margins."""
    import control as ct

    from tuner import analyze, tune
    from tuner.firmware.bind import bind_law

    G = ct.tf([25.0], [0.02, 1.0, 0.0]) * ct.tf([1.0], [1 / (2 * math.pi * 40) ** 2, 1.4 / (2 * math.pi * 40), 1])
    res = tune(G, structure=fw.structure, dt=DT, delay=DT, time_budget_s=10, seed=1)
    assert res.meets_spec, res.verdict
    d = res.to_dict()
    pf = make_param_file(d, fw.export_format, date=dt_.date(2026, 1, 1))
    p = tmp_path / pf.name
    p.write_text(pf.text)
    v = read_params(p, axis="roll", firmware=fw.name)
    for k in LAW:
        assert stored_value(fw.name, "roll", k, v.gains[k]) == stored_value(fw.name, "roll", k, res.gains[k])
    v = dataclasses.replace(v, loop_hz=1.0 / DT)  # the rate the tune assumed (the file need not name it)
    st, _, now = bind_law(fw.structure, v, DT)
    a = analyze(G, st.tf(now, DT), delay=DT)
    tuned_pm = res.analyses[0].margins.phase_margin_deg
    assert a.margins.phase_margin_deg == pytest.approx(tuned_pm, abs=3.0)  # (the stored values' rounding)
