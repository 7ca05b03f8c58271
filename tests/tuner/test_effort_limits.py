"""Issue 10: effort and noise limits (Mt, Mks, control peak), pidf2, objectives optimised by the local stage,
honest infeasibility with reasons. Reference values are computed here, independently of the library."""

from __future__ import annotations

import functools
import math

import control
import numpy as np
import pytest
from scipy import signal

from tuner import InvalidSpecError, Spec, analyze, controller_from_expr, plant_from_expr, tune
from tuner.diagnose import definitional_reasons
from tuner.problem import TuningProblem

ROLL = "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)"


def _peaks_continuous(num_g, den_g, num_c, den_c, w):
    s = 1j * w
    G = np.polyval(num_g, s) / np.polyval(den_g, s)
    C = np.polyval(num_c, s) / np.polyval(den_c, s)
    L = G * C
    S = 1 / (1 + L)
    return float(np.max(np.abs(S))), float(np.max(np.abs(L * S))), float(np.max(np.abs(C * S)))


def test_mt_mks_of_a_continuous_loop_match_a_dense_grid():
    """1/(s+1)^3 with a filtered PID: Ms, Mt, Mks against 400k log-spaced points evaluated here."""
    plant = plant_from_expr("1/(s+1)^3")
    c = controller_from_expr("(1.2 + 0.5/s + 0.8*s/(0.05*s+1))", dt=None)
    an = analyze(plant, c)
    num_c, den_c = np.asarray(c.num, float), np.asarray(c.den, float)
    w = np.logspace(-4, 4, 400_000)
    ms, mt, mks = _peaks_continuous([1.0], np.poly([-1, -1, -1]), num_c, den_c, w)
    m = an.metrics
    assert m.ms == pytest.approx(ms, rel=1e-4)
    assert m.mt == pytest.approx(mt, rel=1e-4)
    assert m.mks == pytest.approx(mks, rel=1e-4)


def test_mt_mks_of_a_sampled_data_loop_match_a_dense_grid():
    """The roll plant under the thesis's digital PID at 25 Hz: ZOH discretisation by scipy, then
    |S|, |T|, |C S| on 200k points of (0, pi/dt]."""
    dt = 0.04
    an = analyze(plant_from_expr(ROLL), controller_from_expr("3.868*(z^2-1.305*z+0.5668)/(z*(z-1))", dt=dt))
    wn, k = 14.8528, 0.2655
    numd, dend, _ = signal.cont2discrete(([k * wn**2], [1, 14.195, wn**2]), dt, method="zoh")
    numd = np.trim_zeros(np.ravel(numd), "f")
    w = np.linspace(1e-4, math.pi / dt, 200_000)
    z = np.exp(1j * w * dt)
    G = np.polyval(numd, z) / np.polyval(dend, z)
    C = 3.868 * (z**2 - 1.305 * z + 0.5668) / (z * (z - 1))
    S = 1 / (1 + G * C)
    m = an.metrics
    assert m.ms == pytest.approx(np.max(np.abs(S)), rel=1e-4)
    assert m.mt == pytest.approx(np.max(np.abs(G * C * S)), rel=1e-4)
    assert m.mks == pytest.approx(np.max(np.abs(C * S)), rel=1e-4)


def test_pid_mf2_is_the_documented_transfer_function():
    """(kp + ki/s + kd s) / (Tf^2 s^2 + sqrt2 Tf s + 1), evaluated here at a few frequencies."""
    from tuner import get_structure

    g = {"Kp": 2.0, "Ki": 0.7, "Kd": 0.3, "Tf": 0.05}
    c = get_structure("pid_mf2").tf(g, None)
    for w in (0.01, 0.3, 2.0, 30.0, 500.0):
        s = 1j * w
        ref = (g["Kp"] + g["Ki"] / s + g["Kd"] * s) / (g["Tf"] ** 2 * s**2 + math.sqrt(2) * g["Tf"] * s + 1)
        got = np.polyval(c.num, s) / np.polyval(c.den, s)
        assert got == pytest.approx(ref, rel=1e-12)


def _load_iae(plant_tf: control.TransferFunction, c, horizon: float) -> float:
    """IAE of y after a unit step load at the plant input: y = G/(1+CG) d, by python-control."""
    C = control.tf(np.asarray(c.num, float), np.asarray(c.den, float))
    t = np.linspace(0, horizon, 20001)
    _, y = control.step_response(control.feedback(plant_tf, C), t)
    return float(np.trapezoid(np.abs(y), t))


@pytest.mark.slow
def test_the_local_stage_improves_the_objective_it_is_asked_for():
    """IAE of a load step under Ms <= 1.4: the CasADi stage on vs off, judged by python-control here."""
    plant = plant_from_expr("1/(s+1)^3")
    spec = Spec(phase_margin_min_deg=0, gain_margin_min_db=0, overshoot_max_pct=100, ms_max=1.4, objective="iae")
    off = tune(plant, structure="pi", spec=spec, seed=0, time_budget_s=120, local=False)
    on = tune(plant, structure="pi", spec=spec, seed=0, time_budget_s=120)
    assert on.meets_spec and off.meets_spec
    G = control.tf([1.0], np.poly([-1, -1, -1]))
    iae_on, iae_off = _load_iae(G, on.controller, 60), _load_iae(G, off.controller, 60)
    assert iae_on < 0.97 * iae_off, (iae_on, iae_off)
    assert on.objective == pytest.approx(iae_on, rel=2e-2)  # the library's own figure agrees with python-control
    assert on.solver["nlp_solves"] > 0 and off.solver["nlp_solves"] == 0


@pytest.mark.slow
def test_ie_objective_reaches_the_brute_force_migo_design():
    """MIGO (max ki s.t. Ms <= 1.4) for PI on 1/(s+1)^3, by a kp grid and a bisection on ki written here."""
    w = np.logspace(-3, 2, 20000)
    s = 1j * w
    G = 1 / (s + 1) ** 3

    def ms(kp, ki):
        L = (kp + ki / s) * G
        poles = np.roots(np.polyadd(np.polymul([1, 0], np.poly([-1, -1, -1])), [kp, ki]))  # s(s+1)^3 + kp s + ki
        if np.any(poles.real >= 0):
            return math.inf
        return float(np.max(np.abs(1 / (1 + L))))

    best = 0.0
    for kp in np.linspace(0.0, 1.5, 151):
        lo, hi = 0.0, 3.0
        if ms(kp, 1e-6) > 1.4:
            continue
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ms(kp, mid) <= 1.4 else (lo, mid)
        best = max(best, lo)
    spec = Spec(phase_margin_min_deg=0, gain_margin_min_db=0, overshoot_max_pct=100, ms_max=1.4, objective="ie")
    res = tune(plant_from_expr("1/(s+1)^3"), structure="pi", spec=spec, seed=0, time_budget_s=120)
    assert res.meets_spec
    assert res.gains["Ki"] >= 0.99 * best, (res.gains, best)


@functools.lru_cache(maxsize=1)
def _brute_force_pi_double_lag() -> float:
    """Minimum 2 % settling time of PI on 1/(s+1)^2 under PM >= 60 deg, GM >= 6 dB, overshoot <= 10 %, by a
    grid over (Kp, Ki) judged here: margins by python-control, the step response in closed form from the
    residues of T(s)/s, T = (Kp s + Ki)/(s^3 + 2 s^2 + (1 + Kp) s + Ki), on 60k points."""
    G = control.tf([1.0], [1.0, 2.0, 1.0])
    t = np.linspace(0.0, 30.0, 60001)
    best = math.inf
    for kp in np.linspace(1.0, 1.6, 25):
        for ki in np.linspace(0.6, 0.9, 25):
            gm, pm, *_ = control.stability_margins(control.tf([kp, ki], [1.0, 0.0]) * G)
            if pm < 60 or (np.isfinite(gm) and 20 * np.log10(gm) < 6):
                continue
            r, p, k = signal.residue([kp, ki], [1.0, 2.0, 1.0 + kp, ki, 0.0])  # T(s)/s
            y = np.real(np.exp(np.outer(t, p)) @ r)
            if np.max(y) > 1.10:
                continue
            out = np.flatnonzero(np.abs(y - 1.0) > 0.02)
            best = min(best, float(t[out[-1] + 1]) if out.size else 0.0)
    return best


@pytest.mark.slow
@pytest.mark.parametrize("tau", [10.0, 20.0])
def test_a_loop_that_settles_after_50_s_at_dt_01_is_found(tau):
    """1/(tau s+1)^2 with PI at dt = 0.1: the best design settles after about 2.7 tau (27 s = 270 samples and
    54 s = 540 samples; the old caps were 250 samples in the search and 80 in the NLP). The reference is the
    continuous loop's optimum on the normalised plant (brute force above: about 2.72 tau); the sampled loop at
    dt = tau/100 or finer is within a few per cent of it."""
    ref = _brute_force_pi_double_lag()
    assert 2.5 < ref < 2.9
    res = tune(plant_from_expr(f"1/({tau:g}s+1)^2"), structure="pi", dt=0.1, seed=0, time_budget_s=120)
    assert res.meets_spec
    ts = res.analyses[0].metrics.settling_time_s
    assert 2.4 * tau < ts < 1.04 * ref * tau, (ts, ref * tau)
    if tau == 20.0:
        assert ts > 50


def test_impossible_specs_are_refused_with_the_field():
    with pytest.raises(InvalidSpecError) as e:
        TuningProblem.build([plant_from_expr("1/(s+1)")], structure="pi", spec=Spec(mt_max=0.9))
    assert e.value.field == ("spec", "mt_max") and "T(0) = 1" in str(e.value)
    with pytest.raises(ValueError):  # pydantic: Ms < 1 is impossible by definition
        Spec(ms_max=0.8)
    # without zero steady-state error an Mt below 1 is a real limit
    TuningProblem.build([plant_from_expr("1/(s+1)")], structure="pd",
                        spec=Spec(mt_max=0.9, zero_steady_state_error=False))


def test_reasons_by_definition():
    """control_peak below 1/G(0) = 1/0.2655; Mks below 1/G(0); a pd asked for zero steady-state error."""
    p = plant_from_expr(ROLL)
    prob = TuningProblem.build([p], structure="pi", spec=Spec(control_peak_max=2.0, mks_max=1.0), dt=0.04)
    rs = {r.constraints[0]: r for r in definitional_reasons(prob)}
    assert set(rs) == {"control_peak", "mks"}
    assert "3.766" in rs["control_peak"].message and rs["control_peak"].suggest["control_peak_max"] >= 1 / 0.2655
    assert rs["mks"].suggest["mks_max"] >= 1 / 0.2655
    pd = TuningProblem.build([p], structure="pd", spec=Spec(), dt=0.04)
    assert [r.constraints for r in definitional_reasons(pd)] == [("steady_state_error",)]
    ok = TuningProblem.build([p], structure="pi", spec=Spec(control_peak_max=4.0), dt=0.04)
    assert definitional_reasons(ok) == []


@pytest.mark.slow
def test_an_unmet_spec_says_which_limit_and_what_would_do():
    """A closed-loop bandwidth of 5 rad/s from a PI on 1/(s+1)^3 with PM >= 60 deg: out of reach (its phase
    is -180 deg at sqrt(3) rad/s). The reason names the limit and a value that the search found feasible,
    and that value is feasible when asked for."""
    p = plant_from_expr("1/(s+1)^3")
    res = tune(p, structure="pi", spec=Spec(bandwidth_min_rad_s=5.0), seed=0, time_budget_s=120)
    assert not res.meets_spec and "bandwidth_rad_s" in res.to_json()["failing"]
    assert res.reasons, "an unmet spec must come with a reason"
    r = res.reasons[0]
    assert r.constraints == ("bandwidth_rad_s",) and 0 < r.suggest["bandwidth_min_rad_s"] < 5.0
    again = tune(p, structure="pi", spec=Spec(**r.suggest), seed=0, time_budget_s=120)
    assert again.meets_spec
    d = res.to_json()
    assert d["reasons"][0]["message"] == r.message and d["objective"]["name"] == "settling_time"


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_cli_limit_flags(capsys):
    """--mt/--mks/--disk-margin reach the spec; an impossible one is exit 2 with a line naming it."""
    import json

    from tuner.cli import main

    assert main(["tune", "--plant", "1/(s+1)", "--structure", "pi", "--mt", "0.9"]) == 2
    assert "mt_max" in capsys.readouterr().err
    code = main(["tune", "--plant", ROLL, "--dt", "0.04", "--structure", "pi", "--mt", "1.3", "--mks", "40",
                 "--disk-margin", "0.5", "--objective", "ie", "--budget", "3", "--json"])
    d = json.loads(capsys.readouterr().out)
    assert d["spec"]["mt_max"] == 1.3 and d["spec"]["mks_max"] == 40 and d["spec"]["disk_margin_min"] == 0.5
    assert d["spec"]["objective"] == "ie" and code == (0 if d["meets_spec"] else 1)
    names = {c["name"] for c in d["checks"]}
    assert {"mt", "mks", "disk_margin"} <= names
