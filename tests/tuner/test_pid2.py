"""pid2, the 2-DOF PID: u = Kp(b r - y) + Ki/s (r - y) + Kd s/(Tf s+1) (c r - y).

References are independent of the library's loop code: python-control's own interconnection of the two
transfer functions written here from the formula (C_r G/(1 + C G) for r -> y, C_r/(1 + C G) for r -> u), and
the discrete difference equations of the law simulated sample by sample in the test.
"""

from __future__ import annotations

import warnings

import control
import numpy as np
import pytest

from tuner import tune
from tuner.analysis import analyze
from tuner.analysis.response import step_response
from tuner.controllers import controller_tf, get_structure
from tuner.loop import build_loop
from tuner.optimize.batch import BatchEvaluator
from tuner.optimize.nlp import refine as rf
from tuner.optimize.nlp.transcribe import ProblemKey, get_problem
from tuner.optimize.space import make_space
from tuner.plant import make_plant
from tuner.problem import TuningProblem
from tuner.spec import Spec

PITCH = ([4.674], [1.0, 3.523, 12.38])
GAINS = dict(Kp=2.0, Ki=3.0, Kd=0.2, Tf=0.02)


def _formula_tfs(g: dict[str, float], dt: float | None):
    """C (on -y) and C_r (on r) as python-control transfer functions, from the law term by term."""
    kp, ki, kd, tf, b, c = (g[k] for k in ("Kp", "Ki", "Kd", "Tf", "b", "c"))
    if dt is None:
        s = control.tf("s")
        integ, der = 1 / s, s / (tf * s + 1)
    else:
        z = control.tf([1, 0], [1], dt)
        integ, der = dt * z / (z - 1), (z - 1) / ((tf + dt) * z - tf)
    return kp + ki * integ + kd * der, kp * b + ki * integ + kd * c * der


@pytest.mark.parametrize("dt", [None, 0.04])
@pytest.mark.parametrize("bc", [(1.0, 1.0), (0.5, 0.0), (1.6, 0.3)])
def test_reference_and_load_responses_match_python_control(dt, bc):
    g = dict(GAINS, b=bc[0], c=bc[1])
    ctrl = controller_tf("pid2", g, dt=dt)
    plant = make_plant(*PITCH)
    loop = build_loop(plant, ctrl)
    r = step_response(loop, horizon_s=3.0, samples_per_dt=1)
    rl = step_response(loop, horizon_s=3.0, samples_per_dt=1, load=True)
    C, Cr = _formula_tfs(g, dt)
    G = control.tf(*PITCH)
    if dt is not None:
        G = control.c2d(G, dt, "zoh")
    t = r.t
    _, y_ref = control.step_response(Cr * G / (1 + C * G), t)
    _, u_ref = control.step_response(Cr / (1 + C * G), t)
    _, yl_ref = control.step_response(G / (1 + C * G), t)
    assert np.max(np.abs(r.y - y_ref)) < 1e-7
    assert np.max(np.abs(r.u - u_ref)) < 1e-7 * max(1.0, np.max(np.abs(u_ref)))
    assert np.max(np.abs(rl.y - yl_ref)) < 1e-7


@pytest.mark.parametrize("dt", [None, 0.04])
def test_feedback_part_is_pid_and_b_c_one_is_pid(dt):
    """Margins, Ms, Mks and the load response come from C (= pid's controller); at b = c = 1 pid2 is pid."""
    plant = make_plant(*PITCH)
    spec = Spec(objective="iae")
    a_pid = analyze(plant, controller_tf("pid", GAINS, dt=dt), spec)
    a_11 = analyze(plant, controller_tf("pid2", dict(GAINS, b=1.0, c=1.0), dt=dt), spec)
    a_w = analyze(plant, controller_tf("pid2", dict(GAINS, b=0.3, c=0.0), dt=dt), spec)
    for a in (a_11, a_w):
        for k in ("phase_margin_deg", "gain_margin_db", "ms", "mt", "mks", "disk_margin"):
            assert getattr(a.metrics, k) == pytest.approx(getattr(a_pid.metrics, k), rel=1e-9), k
    for k in ("overshoot_pct", "settling_time_s", "control_peak"):
        assert getattr(a_11.metrics, k) == pytest.approx(getattr(a_pid.metrics, k), rel=1e-7, abs=1e-9), k
    # setpoint weights change the reference response, not the feedback: the control peak of the kick drops
    assert a_w.metrics.control_peak < a_pid.metrics.control_peak


def test_continuous_loop_with_delay_matches_an_independent_simulation():
    """With a delay (the verifier's fine-step model), r -> y of pid2 agrees with the law integrated here by
    forward Euler at a small step, the delayed input from a buffer (the parallel form of the formula)."""
    g = dict(GAINS, b=0.6, c=0.0)
    tau, T, h = 0.05, 3.0, 1e-4
    r = step_response(build_loop(make_plant(*PITCH, delay=tau), controller_tf("pid2", g, dt=None)), horizon_s=T)
    a1, a0, k = PITCH[1][1], PITCH[1][2], PITCH[0][0]
    x1 = x2 = xi = xf = 0.0  # plant y'' + a1 y' + a0 y = k u(t - tau); integrator; D filter state
    nd = int(round(tau / h))
    buf = [0.0] * nd
    ys = []
    for _ in range(int(round(T / h)) + 1):
        y = x1
        ys.append(y)
        v = g["c"] * 1.0 - y
        u = g["Kp"] * (g["b"] * 1.0 - y) + g["Ki"] * xi + g["Kd"] / g["Tf"] * (v - xf)
        buf.append(u)
        ud = buf.pop(0)
        x1, x2 = x1 + h * x2, x2 + h * (k * ud - a1 * x2 - a0 * x1)
        xi += h * (1.0 - y)
        xf += h * (v - xf) / g["Tf"]
    t = np.arange(len(ys)) * h
    assert np.max(np.abs(np.interp(r.t, t, ys) - r.y)) < 2e-3


@pytest.mark.parametrize("dt,delay", [(0.04, 0.0), (0.04, 0.08), (None, 0.0), (None, 0.1)])
def test_batched_verifier_agrees_with_the_verifier(dt, delay):
    plant = make_plant(*PITCH, delay=delay)
    prob = TuningProblem.build([plant], structure="pid2", spec=Spec(objective="itae"), dt=dt)
    space = make_space(prob.structure, prob.nominal, dt, scale=prob.scale)
    be = BatchEvaluator(prob, space)
    X = np.array([[2.0, 3.0, 0.2, 0.02, b, c] for b, c in ((1, 1), (0.5, 0), (1.5, 0.3))])
    res = be.evaluate(X)
    for j, x in enumerate(X):
        a = analyze(plant, get_structure("pid2").tf(x, dt), prob.spec)
        m = res.per_plant[0]
        if dt is None and delay:  # a continuous delay: the batch's coarse fine step (as for every structure)
            assert m["settling_time_s"][j] == pytest.approx(a.metrics.settling_time_s, rel=0.02)
            assert m["overshoot_pct"][j] == pytest.approx(a.metrics.overshoot_pct, abs=2.0)
            continue
        assert m["settling_time_s"][j] == pytest.approx(a.metrics.settling_time_s, rel=1e-3)
        assert m["overshoot_pct"][j] == pytest.approx(a.metrics.overshoot_pct, abs=0.05)
        assert m["control_peak"][j] == pytest.approx(a.metrics.control_peak, rel=1e-3)  # peak at the horizon


def _nlp_step(structure: str, x0: np.ndarray, dt: float | None) -> tuple[np.ndarray, np.ndarray]:
    """The NLP's simulated reference step at ``x0`` (its `step` function, as refine sets it up) and the
    verifier's r -> y on the NLP's time grid."""
    plant = make_plant(*PITCH)
    prob = TuningProblem.build([plant], structure=structure, spec=Spec(objective="iae"), dt=dt)
    space = make_space(prob.structure, prob.nominal, dt, scale=prob.scale)
    ev = BatchEvaluator(prob, space)
    ctrl0 = prob.structure.tf(x0, dt)
    start = rf.Start.of(ev, x0)
    grid = rf._grid(ev, start, space.w0, None)
    data = rf._plant_data(ev, start, ctrl0, grid, space.w0)
    key = ProblemKey(structure=structure, continuous=dt is None, orders=tuple(lf.n for lf in data.lifted),
                     zeros=tuple(lf.zeros.size for lf in data.lifted), poles=tuple(lf.poles.size for lf in data.lifted),
                     delays=tuple(lf.delay_samples for lf in data.lifted), K=grid.K, N=grid.N,
                     phase_cross=tuple(data.has_pc), control_peak=False, objective="iae", pm=True, gm=True)
    nlp = get_problem(key, space.structure, space)
    values = rf._values(ev, space, grid, data, key)
    xs, _, _ = rf._box(nlp, space, x0, data, values["band"], rf._wmax(ev, space.w0))
    y_nlp = np.asarray(nlp.step(xs, nlp.params.pack({**values, "mask": np.zeros(grid.t.size)}))).ravel()
    r = step_response(build_loop(plant, ctrl0), horizon_s=float(grid.t[-1]) + 1.0, samples_per_dt=grid.N)
    return y_nlp, np.interp(grid.t, r.t, r.y)


@pytest.mark.slow
@pytest.mark.parametrize("dt", [0.04, None])
def test_nlp_step_response_is_the_2dof_loop(dt):
    """The NLP's reference step is the verifier's r -> y of the 2-DOF loop: exact at dt; in continuous time to
    the NLP's own Tustin step, exactly as for pid (whose b = c = 1 response pid2 reproduces)."""
    y_nlp, y_ver = _nlp_step("pid2", np.array([2.0, 3.0, 0.2, 0.02, 0.4, 0.0]), dt)
    y_pid, y_pid_ver = _nlp_step("pid", np.array([2.0, 3.0, 0.2, 0.02]), dt)
    y_11, _ = _nlp_step("pid2", np.array([2.0, 3.0, 0.2, 0.02, 1.0, 1.0]), dt)
    assert np.max(np.abs(y_11 - y_pid)) < 1e-9
    if dt is not None:
        assert np.max(np.abs(y_nlp - y_ver)) < 1e-9
    else:
        assert np.max(np.abs(y_nlp - y_ver)) <= max(np.max(np.abs(y_pid - y_pid_ver)), 1e-3)
    assert np.max(np.abs(y_nlp - y_pid)) > 0.05  # the weights do change the reference response


CASES = [
    ("pitch-dt", PITCH, 0.04, dict(objective="iae", phase_margin_min_deg=0, gain_margin_min_db=0, ms_max=2,
                                   mks_max=20)),
    # (the settling time asked for: "auto" would design pid2 for the load and pid for the settling time)
    ("pitch-dt-settling", PITCH, 0.04, dict(objective="settling_time")),
    ("lag3-ct", ([1.0], [1.0, 3.0, 3.0, 1.0]), None, dict(objective="itae")),
    ("matlab-pidtune-ct", ([1.0], [1.0, 0.5, 0.1]), None, dict(objective="settling_time")),  # the batch ranks
    # this one's answers apart
]


@pytest.mark.slow
@pytest.mark.parametrize("name,plant,dt,spec", CASES, ids=[c[0] for c in CASES])
def test_pid2_is_never_worse_than_pid(name, plant, dt, spec):
    p = make_plant(*plant)
    sp = Spec(**spec)
    r_pid = tune(p, structure="pid", spec=sp, dt=dt, seed=0, time_budget_s=20)
    r_2 = tune(p, structure="pid2", spec=sp, dt=dt, seed=0, time_budget_s=20)
    assert r_pid.meets_spec and r_2.meets_spec
    assert r_2.objective <= r_pid.objective * (1 + 1e-3)
    assert r_2.solver["seeded_from"] == "pid"


@pytest.mark.slow
def test_pid2_setpoint_weights_cut_the_load_iae_on_the_pitch_model():
    """Issue 18's target: on the Lund line with the overshoot limit, pid2's load IAE <= 0.6 x the 0.110 the issue
    measured with pid. The load IAE depends on the feedback part only, so the setpoint weights can remove the whole
    cost of the overshoot limit: pid2 must reach the optimum of pid with the overshoot limit lifted (the issue:
    0.048), and be better than pid under the limit."""
    p = make_plant(*PITCH)
    sp = Spec(objective="iae", phase_margin_min_deg=0, gain_margin_min_db=0, ms_max=2, mks_max=20)
    r_pid = tune(p, structure="pid", spec=sp, dt=0.04, seed=0, time_budget_s=60)
    r_free = tune(p, structure="pid", spec=sp.model_copy(update={"overshoot_max_pct": 100.0}), dt=0.04, seed=0,
                  time_budget_s=60)
    r_2 = tune(p, structure="pid2", spec=sp, dt=0.04, seed=0, time_budget_s=60)
    assert r_2.meets_spec and r_2.analyses[0].metrics.overshoot_pct <= 10.0
    assert r_2.objective <= 0.6 * 0.110  # the pid figure
    assert r_2.objective <= r_free.objective * 1.02  # the overshoot limit costs pid2 nothing
    assert r_2.objective < r_pid.objective


def test_deprecated_pidf2_alias():
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        st = get_structure("pidf2")
    assert st.name == "pid_mf2"
    assert any(issubclass(x.category, DeprecationWarning) and "pid_mf2" in str(x.message) for x in w)


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_deprecated_name_is_noted_in_the_tune_result():
    r = tune(make_plant([1.0], [1.0, 1.0]), structure="pidf2", seed=0, time_budget_s=3)
    assert r.structure == "pid_mf2"
    assert any("deprecated" in n for n in r.solver["notes"])


def test_weights_are_validated_and_bounded():
    from tuner.errors import InvalidControllerError
    from tuner.optimize.design import bounds

    with pytest.raises(InvalidControllerError, match="b is a setpoint weight"):
        controller_tf("pid2", dict(GAINS, b=-1.0, c=0.0), dt=0.04)
    st = get_structure("pid2")
    lo, hi = bounds(st, make_plant(*PITCH), 0.04)
    i, j = st.params.index("b"), st.params.index("c")
    assert (lo[i], hi[i], lo[j], hi[j]) == (0.0, 2.0, 0.0, 1.0)


def test_two_dof_controller_dict_round_trip_keeps_the_reference_path():
    c = controller_tf("pid2", dict(GAINS, b=0.5, c=0.0), dt=0.04)
    d = c.to_dict()
    assert "num_r" in d
    # the generic realisation from coefficients (no structure) gives the same loop
    from tuner.controllers import ControllerTF

    c2 = ControllerTF(num=np.array(d["num"]), den=np.array(d["den"]), dt=0.04, num_r=np.array(d["num_r"]))
    plant = make_plant(*PITCH)
    r1 = step_response(build_loop(plant, c), horizon_s=2.0)
    r2 = step_response(build_loop(plant, c2), horizon_s=2.0)
    assert np.max(np.abs(r1.y - r2.y)) < 1e-9


@pytest.mark.parametrize("dt", [None, 0.04])
def test_reference_tfs_are_the_2dof_responses(dt):
    """Analysis.reference_tfs: r -> y and r -> u of the 2-DOF loop (python-control objects), their step
    responses those of the verifier; loop_tfs stays the feedback loop L = C G."""
    g = dict(GAINS, b=0.4, c=0.0)
    a = analyze(make_plant(*PITCH), controller_tf("pid2", g, dt=dt), Spec())
    Tr, Ur = a.reference_tfs()
    r = step_response(a.loop, horizon_s=2.0, samples_per_dt=1)
    _, y = control.step_response(Tr, r.t)
    _, u = control.step_response(Ur, r.t)
    assert np.max(np.abs(y - r.y)) < 1e-7 and np.max(np.abs(u - r.u)) < 1e-6
    L = a.loop_tfs().L
    C, _ = _formula_tfs(g, dt)
    w = np.array([0.5, 3.0])
    Gp = control.tf(*PITCH) if dt is None else control.c2d(control.tf(*PITCH), dt, "zoh")
    np.testing.assert_allclose(np.squeeze(L(np.exp(1j * w * dt) if dt else 1j * w)),
                               np.squeeze((C * Gp)(np.exp(1j * w * dt) if dt else 1j * w)), rtol=1e-9)


@pytest.mark.slow
def test_cli_tune_pid2_shows_the_weights_and_pidf2_is_noted(capsys):
    from tuner.cli import main

    code = main(["tune", "--plant", "4.674/(s^2+3.523*s+12.38)", "--dt", "0.04", "--structure", "pid2",
                 "--budget", "3"])
    out = capsys.readouterr().out
    assert code in (0, 1)
    assert "b = " in out and "c = " in out and "C_r(z) = " in out and "feed-forward" in out
    code = main(["tune", "--plant", "1/(s+1)", "--structure", "pidf2", "--budget", "2"])
    cap = capsys.readouterr()
    assert "pid_mf2" in cap.out and "deprecated" in cap.err


def test_cascade_with_pid2_controllers_agrees_with_its_composite_plant():
    """A pid2 in the inner and the outer loop: the cascade's explicit simulation and the outer loop closed on
    the composite plant (two separate computations) agree at the samples."""
    from tuner.analysis.cascade import outer_plant, simulate_cascade

    dt = 0.01
    inner, outer = make_plant([20.0], [1.0, 20.0]), make_plant([1.0], [1.0, 0.0])
    ci = controller_tf("pid2", dict(Kp=0.8, Ki=4.0, Kd=0.01, Tf=0.005, b=0.5, c=0.0), dt=dt)
    co = controller_tf("pid2", dict(Kp=3.0, Ki=1.0, Kd=0.1, Tf=0.02, b=0.7, c=0.0), dt=dt)
    cas = simulate_cascade(inner, ci, outer, co, horizon_s=3.0)
    r = step_response(build_loop(outer_plant(inner, ci, outer), co), horizon_s=3.0, samples_per_dt=1)
    k = min(r.y.size, cas.response.y_samples.size)
    assert np.max(np.abs(cas.response.y_samples[:k] - r.y[:k])) < 1e-9
    c1 = controller_tf("pid2", dict(Kp=0.8, Ki=4.0, Kd=0.01, Tf=0.005, b=1.0, c=1.0), dt=dt)
    r1 = step_response(build_loop(outer_plant(inner, c1, outer), co), horizon_s=3.0, samples_per_dt=1)
    assert np.max(np.abs(r1.y[:k] - r.y[:k])) > 1e-3  # the inner weights do reach the composite plant


@pytest.mark.slow
def test_study_with_pid2_and_a_pidf2_loop_runs(tmp_path):
    """Studies take pid2 (and the deprecated pidf2): a two-loop study, a pid2 cascade inner loop included."""
    import json

    from tuner.cli import main

    f = tmp_path / "s.toml"
    f.write_text('name = "p2"\ntime_budget_s = 3\n'
                 '[[loop]]\nname = "pitch"\nplant = "4.674/(s^2+3.523*s+12.38)"\ndt = 0.04\nstructure = "pid2"\n'
                 '[[loop]]\nname = "x"\ninner = "pitch"\nplant = "1/s"\ndt = 0.04\nstructure = "pidf2"\n')
    out = tmp_path / "o"
    assert main(["study", "run", str(f), "--out", str(out), "--no-plots"]) in (0, 1)
    doc = json.loads((out / "results.json").read_text())
    assert set(doc["loops"]["pitch"]["gains"]) == {"Kp", "Ki", "Kd", "Tf", "b", "c"}
    assert doc["loops"]["pitch"]["meets_spec"] is True
    assert "error" not in doc["loops"]["x"] or not doc["loops"]["x"]["error"]
