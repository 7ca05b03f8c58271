"""Correctness of the CasADi local stage (tuner.nlp), piece by piece, against independent numbers.

* ``lift``: the lifted sampled-data plant model reproduces an independent simulation of the
  continuous plant driven through a ZOH (matrix exponential of a scipy realisation, evaluated
  at the between-sample instants), for an arbitrary input sequence; its discrete num/den are
  the ZOH equivalent computed here.
* The symbolic controller (space.to_params with CasADi's exp/sinh and the gain units as
  symbols, then the structure's coefficient formulas, exactly as ``transcribe._build`` does)
  equals the numeric structure TF for random coordinates, for every structure.
* The symbolic frequency-response and Tustin helpers of ``transcribe`` against numpy/python-control.
* ``refine`` on roll pid_z from the structure's initial guess returns a candidate that the
  verifier (``analyze``) says meets the spec and settles faster than the start.
* The CasADi problem is built once per structure key: re-solving from another start, or for
  another plant of the same order and horizon, does not rebuild (``BUILDS["count"]``), a new
  structure does.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict

import casadi as cs
import control as ct
import numpy as np
import pytest
import reference as ref
from quadrotor import DT, PITCH, ROLL
from scipy import linalg, signal

from tuner.analysis.response import step_response
from tuner.analysis.verify import analyze
from tuner.controllers import STRUCTURES, ControllerTF, get_structure
from tuner.loop import build_loop
from tuner.optimize.batch import BatchEvaluator
from tuner.optimize.design import initial_guess
from tuner.optimize.nlp import refine as refine_mod
from tuner.optimize.nlp import transcribe
from tuner.optimize.nlp.plantdata import lift
from tuner.optimize.nlp.refine import refine
from tuner.optimize.scoring import Evaluator
from tuner.optimize.space import make_space
from tuner.plant import make_plant, plant_from_expr
from tuner.problem import TuningProblem
from tuner.spec import Spec
from tuner.tuning import tune

BUDGET = 120.0

# raw coefficients (quadrotor.md), written out here on purpose
ROLL_G = ([0.2655 * 14.8528**2], [1, 14.195, 14.8528**2])
PITCH_G = ([0.377568 * 3.5184**2], [1, 2 * 0.5006 * 3.5184, 3.5184**2])
LIFT_PLANTS = {
    "roll": ROLL_G,
    "pitch": PITCH_G,
    "yaw": ([0.2843 * 18.611], [1, 18.611]),
    "nmp_third_order": ([-0.5, 1], ref.polyprod([1, 1], [0.5, 1], [0.1, 1])),
    "biproper": ([2, 3], [1, 4]),  # direct feedthrough D != 0
    "unstable": ([1], [1, -1]),
    "integrator": ([1], [1, 1, 0]),
}


def _exact_between_samples(num, den, u, dt, N):
    """Output of num/den (continuous) driven by the staircase u through a ZOH, at t_k + j dt/N.

    Independent of the library: scipy's tf2ss realisation, the state propagated over each
    sample with expm(A dt) and evaluated inside the sample with the augmented expm at j dt/N.
    """
    A, B, C, D = signal.tf2ss(np.asarray(num, float), np.asarray(den, float))
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n:] = A, B
    Es = [linalg.expm(M * (j * dt / N)) for j in range(N)]
    Edt = linalg.expm(M * dt)
    x = np.zeros((n, 1))
    y = []
    for uk in u:
        for E in Es:
            xj = E[:n, :n] @ x + E[:n, n:] * uk
            y.append(float((C @ xj + D * uk)[0, 0]))
        x = Edt[:n, :n] @ x + Edt[:n, n:] * uk
    return np.array(y)


def _lifted_output(lf, u):
    x = np.zeros(lf.n)
    y = []
    for uk in u:
        y.extend(lf.Cf @ x + lf.Df * uk)
        x = lf.Phi @ x + lf.Gam * uk
    return np.array(y)


@pytest.mark.parametrize("dt,N", [(DT, 4), (DT, 7), (0.013, 5)])
@pytest.mark.parametrize("name", sorted(LIFT_PLANTS))
def test_lift_reproduces_the_continuous_output_between_samples(name, dt, N):
    num, den = LIFT_PLANTS[name]
    plant = make_plant(num, den)
    loop = build_loop(plant, ControllerTF(num=np.ones(1), den=np.ones(1), dt=dt))
    lf = lift(loop, N)
    assert lf.Cf.shape == (N, lf.n) and lf.Df.shape == (N,) and lf.n == len(den) - 1
    rng = np.random.default_rng(0)
    u = np.concatenate([[1.0], rng.normal(size=40)])  # a step then noise: every mode excited
    y_lib = _lifted_output(lf, u)
    y_ref = _exact_between_samples(num, den, u, dt, N)
    scale = max(1.0, float(np.max(np.abs(y_ref))))
    np.testing.assert_allclose(y_lib, y_ref, rtol=0, atol=1e-10 * scale)
    # the first point of each sample is the sample-instant output C x + D u
    x = np.zeros(lf.n)
    for uk in u[:10]:
        assert lf.Cf[0] @ x + lf.Df[0] * uk == pytest.approx(lf.C @ x + lf.D * uk, abs=1e-12 * scale)
        x = lf.Phi @ x + lf.Gam * uk
    # the factored form carried for the frequency constraints is the ZOH equivalent at dt (these plants
    # are low order: the independent polynomial construction is accurate)
    bz, az = ref.zoh(num, den, dt)
    z = np.exp(1j * np.linspace(0.05, 3.0, 25))
    g = lf.gain * np.prod(z[:, None] - lf.zeros[None, :], axis=1) / np.prod(z[:, None] - lf.poles[None, :], axis=1)
    np.testing.assert_allclose(g, np.polyval(bz, z) / np.polyval(az, z), rtol=1e-7)


def test_lift_of_the_thesis_roll_gives_the_printed_discrete_model():
    """quadrotor.md: ZOH of roll at 0.04 s is (0.03802 z + 0.03141)/(z^2 - 1.305 z + 0.5668)."""
    plant = make_plant(*ROLL_G)
    lf = lift(build_loop(plant, ControllerTF(num=np.ones(1), den=np.ones(1), dt=DT)), 4)
    np.testing.assert_allclose(np.real(np.poly(lf.poles)), [1, -1.305, 0.5668], atol=6e-4)
    np.testing.assert_allclose(lf.gain * np.real(np.poly(lf.zeros)), [0.03802, 0.03141], atol=6e-5)
    # and the lifted steady state of a unit input is the DC gain 0.2655
    x = np.linalg.solve(np.eye(2) - lf.Phi, lf.Gam)
    np.testing.assert_allclose(lf.Cf @ x + lf.Df, 0.2655, rtol=1e-9)


def test_lift_refuses_continuous_loops():
    plant = make_plant(*ROLL_G)
    with pytest.raises(ValueError):
        lift(build_loop(plant, ControllerTF(num=np.ones(1), den=np.ones(1), dt=None)), 4)


# -- the symbolic controller -------------------------------------------------------------------

def _symbolic_tf(space, dt):
    """The controller coefficients as a CasADi function of (v, units, dt), built as transcribe does."""
    st = space.structure
    nv = len(st.params)
    v = cs.SX.sym("v", nv)
    units = cs.SX.sym("units", nv)
    dts = cs.SX.sym("dt")
    x_par = space.to_params([v[i] for i in range(nv)], exp=cs.exp, sinh=cs.sinh, units=units)
    num, den = st.coeffs(x_par, None if dt is None else dts, cs.exp)
    f = cs.Function("c", [v, units, dts], [cs.vertcat(*[cs.SX(c) for c in num]), cs.vertcat(*[cs.SX(c) for c in den])])

    def evaluate(vv):
        n, d = f(vv, np.array(space.units), 0.0 if dt is None else dt)
        return np.asarray(n).ravel(), np.asarray(d).ravel()

    return evaluate


CTRL_CASES = [(s, DT) for s in STRUCTURES] + [(s, None) for s, st in STRUCTURES.items() if not st.discrete_only]


@pytest.mark.parametrize("name,dt", CTRL_CASES, ids=[f"{s}-{'ct' if d is None else 'dt'}" for s, d in CTRL_CASES])
def test_symbolic_controller_equals_the_numeric_structure_tf(name, dt):
    st = get_structure(name)
    plant = make_plant(*ROLL_G)
    space = make_space(st, plant, dt)
    sym = _symbolic_tf(space, dt)
    rng = np.random.default_rng(42)
    for _ in range(25):
        v = space.lo + rng.random(space.lo.size) * (space.hi - space.lo)
        num, den = sym(v)
        c = st.tf(space.params(v), dt)
        assert c.dt == dt
        np.testing.assert_allclose(num / den[0], c.num, rtol=1e-12, atol=1e-12 * np.max(np.abs(c.num)))
        np.testing.assert_allclose(den / den[0], c.den, rtol=1e-12, atol=1e-14)
        if st.firmware not in (None, "px4", "ardupilot"):  # another registered firmware's law: checked against
            continue  # its own update equations by tests/firmware/test_contract.py (and its source by its own tests)
        # and both are the same function of frequency as the structure's textbook form
        w = np.array([0.3, 3.0, 30.0]) if dt is None else np.array([0.3, 3.0, 30.0, 70.0])
        x = st.named(space.params(v))
        np.testing.assert_allclose(c.freqresp(w), _textbook(name, x, dt, w), rtol=1e-9)


def _textbook(name, x, dt, w):
    """C at frequencies w from the formulas in tuner/controllers.py's table, evaluated directly."""
    if dt is None:
        s = 1j * w
        integ, deriv = 1 / s, lambda kd, tf: kd * s / (tf * s + 1)

        def first(k, wz, wp):
            return k * (s / wz + 1) / (s / wp + 1)
    else:
        z = np.exp(1j * w * dt)
        integ, deriv = dt * z / (z - 1), lambda kd, tf: kd * (z - 1) / ((tf + dt) * z - tf)

        def first(k, wz, wp):
            zd, pd = math.exp(-wz * dt), math.exp(-wp * dt)
            return k * (1 - pd) / (1 - zd) * (z - zd) / (z - pd)
    if name == "p":
        return x["Kp"] + 0 * w
    if name == "pi":
        return x["Kp"] + x["Ki"] * integ
    if name == "pd":
        return x["Kp"] + deriv(x["Kd"], x["Tf"])
    if name in ("pid", "pid2"):  # pid2: the feedback part
        return x["Kp"] + x["Ki"] * integ + deriv(x["Kd"], x["Tf"])
    if name == "pid_z":
        return x["K"] * (z**2 + x["a1"] * z + x["a2"]) / (z * (z - 1))
    if name in ("lead", "lag"):
        return first(x["K"], x["wz"], x["wp"])
    if name == "pid_mf2":
        tf = x["Tf"]
        if dt is None:
            return (x["Kp"] + x["Ki"] / s + x["Kd"] * s) / (tf**2 * s**2 + math.sqrt(2) * tf * s + 1)
        sv = 2 / dt * (z - 1) / (z + 1)  # the filter by Tustin; the PID with a one-sample derivative
        pid = x["Kp"] + x["Ki"] * dt * z / (z - 1) + x["Kd"] * (z - 1) / (dt * z)
        return pid / (tf**2 * sv**2 + math.sqrt(2) * tf * sv + 1)
    if name in ("px4_rate", "ardupilot_rate"):  # the laws' feedback paths, firmware.md (and tuner.firmware.laws)
        def lp(f):  # first-order low-pass a z/(z - (1 - a)), a = dt/(dt + 1/(2 pi f)); 1 when off
            a = dt / (dt + 1 / (2 * math.pi * f)) if f > 0 else 1.0
            return a * z / (z - (1 - a))

        dterm = lambda f: lp(f) * (z - 1) / (dt * z)
        if name == "px4_rate":  # K [P + I dt/(z - 1) + D d/dt(filtered)], forward-Euler integrator
            return x["K"] * (x["P"] + x["I"] * dt / (z - 1) + x["D"] * dterm(x["dgyro_hz"]))
        return (x["P"] + x["I"] * dt * z / (z - 1) + x["D"] * dterm(x["fltd_hz"])) * lp(x["flte_hz"])
    assert name == "leadlag"
    return first(x["K"], x["wz1"], x["wp1"]) * first(1.0, x["wz2"], x["wp2"])


@pytest.mark.parametrize("continuous", [False, True])
def test_symbolic_polynomial_evaluation(continuous):
    """transcribe._cplx_poly: Re/Im of p(jw) or p(exp(jw dt)), against numpy."""
    rng = np.random.default_rng(3)
    coeffs = list(rng.normal(size=5))
    for w in (0.1, 2.0, 40.0, math.pi / DT):
        re, im = transcribe._cplx_poly(coeffs, cs.DM(w), cs.DM(DT), continuous)
        x = 1j * w if continuous else np.exp(1j * w * DT)
        val = np.polyval(coeffs, x)
        assert float(re) == pytest.approx(val.real, rel=1e-12, abs=1e-12 * abs(val))
        assert float(im) == pytest.approx(val.imag, rel=1e-12, abs=1e-12 * abs(val))


def test_symbolic_tustin_matches_python_control():
    """transcribe._tustin (used for continuous loops) against control.sample_system(method='tustin')."""
    num, den, h = [2.0, 3.0, 1.5], [1.0, 4.0, 0.5, 0.0], 0.01
    n, d = transcribe._tustin(num, den, h)
    n, d = np.array(n, float), np.array(d, float)
    g = ct.sample_system(ct.tf(num, den), h, method="tustin")
    np.testing.assert_allclose(n / d[0], np.ravel(g.num[0][0]) / g.den[0][0][0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(d / d[0], np.ravel(g.den[0][0]) / g.den[0][0][0], rtol=1e-9, atol=1e-12)


# -- refine -------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def roll_refined():
    plant = plant_from_expr(ROLL)
    st = get_structure("pid_z")
    batch, space = _batch(plant, "pid_z")
    x0 = st.vector(initial_guess(st, plant, DT))
    v0 = space.from_params(x0)
    res = refine(batch, space, v0, deadline=time.perf_counter() + BUDGET)
    return plant, st, space, x0, res


def test_refine_improves_on_the_initial_guess(roll_refined):
    plant, st, space, x0, res = roll_refined
    start = analyze(plant, st.tf(x0, DT))
    assert res.iterations > 0 and res.evaluations > 0
    assert res.candidates, res.status
    verified = [analyze(plant, st.tf(space.params(c), DT)) for c in res.candidates]
    good = [a.metrics.settling_time_s for a in verified if a.meets_spec]
    assert good, [[c.name for c in a.failing] for a in verified]
    # at the time of writing: start 0.206 s -> 0.118 s
    assert min(good) < start.metrics.settling_time_s
    if start.meets_spec:
        assert min(good) < 0.9 * start.metrics.settling_time_s


_SOLVE = refine_mod._Solves.__call__


def _polish_solves(monkeypatch, batch, space, candidates, detail):
    """The fine polish (``refine(fine=True)`` at ``detail``) of the batch's best of ``candidates``: every solve it made,
    as (the solves, the Ts asked, the result)."""
    scores = batch.evaluate(np.array([space.params(c) for c in candidates])).score
    v, incumbent = candidates[int(np.argmin(scores))], float(np.min(scores))
    seen: list = []

    def recording(self, ts, x):
        r = _SOLVE(self, ts, x)
        if r is not None:
            seen.append((self, ts, r))
        return r

    monkeypatch.setattr(refine_mod._Solves, "__call__", recording)
    out = refine(batch, space, v, deadline=time.perf_counter() + BUDGET, incumbent=incumbent, fine=True, detail=detail)
    assert out.candidates, out.status
    return seen


def test_sharp_polish_constrains_the_output_at_ts_between_grid_points(roll_refined, monkeypatch):
    """The polish at ``detail`` 2 (effort thorough) interpolates the settling envelope's first row at Ts, as the
    verifier interpolates its settling time: every solve keeps the output, linearly interpolated at its Ts between
    two grid points, inside the band less the slack (at detail 1 the envelope starts at the next grid point, and
    the output at Ts is outside), and the bisection asks for settling times between the grid's points."""
    plant, st, space, x0, res = roll_refined
    batch, _ = _batch(plant, "pid_z")

    def polish(detail):
        rows = []
        for solves, ts, (slack, x) in _polish_solves(monkeypatch, batch, space, res.candidates, detail):
            t = solves.tgrid
            off = float(np.min(np.abs(t - ts))) / (t[1] - t[0])  # the distance to the grid, in grid steps
            excess = abs(float(np.interp(ts, t, solves._step(x)[0])) - 1.0) - (solves.values["band"] - slack)
            rows.append((solves.interp, off, excess))
        return rows

    sharp = polish(2)
    assert all(interp for interp, _, _ in sharp)
    assert sum(off > 0.05 for _, off, _ in sharp) >= 3  # settling times between the grid's points
    assert max(excess for _, _, excess in sharp) <= 1e-7
    plain = polish(1)
    assert not any(interp for interp, _, _ in plain)
    assert max(excess for _, off, excess in plain if off > 0.05) > 1e-4


def test_sharp_polish_bisects_on_only_from_what_the_verifier_confirms(monkeypatch):
    """At the band's edge the sharp polish leaves no slack for what its grid does not see: a PI on a lag with a
    fractional delay (the suite's fracdelay-04), 2.0000 % on the NLP's grid at 0.3270 s, peaks at 2.0007 % at the
    delay's input switch and settles at 0.404 s. Every solution its bisection takes as feasible settles, by the
    full verifier, no later than asked (a grid step's tolerance)."""
    plant = make_plant([0.36741548115569433], [0.15883447505105652, 1.0], delay=0.0936233203)
    dt, spec = 0.01106, Spec.thesis()
    problem = TuningProblem.build(plant, structure="pi", dt=dt, spec=spec)
    space = make_space(problem.structure, plant, dt, scale=problem.scale)
    batch, st = BatchEvaluator(problem, space), problem.structure
    res = refine(batch, space, space.from_params(st.vector(initial_guess(st, plant, dt))),
                 deadline=time.perf_counter() + BUDGET)
    taken = [(ts, space.params(r[1][solves.prob.variables.slice("v")], linear_gains=True), solves.tgrid[1])
             for solves, ts, r in _polish_solves(monkeypatch, batch, space, res.candidates, 2) if r[0] >= 0]
    verifier = Evaluator([plant], st, dt, spec)
    for ts, x, step in taken:
        s = verifier.score(x)
        assert s.feasible and s.score <= ts + step, (ts, s.score)
    assert len(taken) >= 3  # (the bisection went on below the refused 0.3270 s: 0.3271 s)


# -- the problem cache ---------------------------------------------------------------------------

def _slow_start(plant, st, decades):
    """The structure's initial guess with the gains scaled by 10**decades: a slow loop."""
    space = make_space(st, plant, DT)
    x = st.vector(initial_guess(st, plant, DT))
    for i, kind in enumerate(st.kinds):
        if kind == "gain":
            x[i] *= 10.0**decades
    return space, space.from_params(x)


def _batch(plant, st, spec=None):
    problem = TuningProblem.build(plant, structure=st, dt=DT, spec=spec)
    space = make_space(problem.structure, plant, DT, scale=problem.scale)
    return BatchEvaluator(problem, space), space


def test_problem_is_built_once_per_structure(monkeypatch):
    """One build per problem structure: another start or another plant of the same sizes only changes the
    parameters. (The horizon is pinned to 64 samples here so that both starts share it.)"""
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())  # a clean cache: counts do not depend on test order
    monkeypatch.setattr(refine_mod, "_bucket", lambda k: 64)
    got: list = []
    real = refine_mod.get_problem

    def recording(key, st, space):
        p = real(key, st, space)
        got.append(p)
        return p

    monkeypatch.setattr(refine_mod, "get_problem", recording)
    roll, pitch = plant_from_expr(ROLL), plant_from_expr(PITCH)

    def run(plant, structure, decades):
        s = get_structure(structure)
        _, v0 = _slow_start(plant, s, decades)
        batch, space = _batch(plant, structure)
        before = transcribe.BUILDS["count"]
        res = refine(batch, space, v0, deadline=time.perf_counter() + BUDGET)
        assert res.candidates, res.status
        return transcribe.BUILDS["count"] - before, got[-1]

    built, p1 = run(roll, "pid_z", -1.0)
    assert built == 1 and p1.key.K == 64
    # another start, same plant
    built, p2 = run(roll, "pid_z", -1.2)
    assert p2.key == p1.key, "precondition: the same structure key"
    assert built == 0 and p2 is p1
    # another plant of the same order (pitch), same horizon: plant data are parameters
    built, p3 = run(pitch, "pid_z", -1.0)
    assert p3.key == p1.key, "precondition: the same structure key"
    assert built == 0 and p3 is p1
    # a different structure is a different problem
    built, p4 = run(roll, "pid", -1.0)
    assert built == 1 and p4 is not p1 and p4.key.structure == "pid"


def test_the_build_cache_keeps_the_most_recently_used_problems_within_its_memory_bound(monkeypatch):
    """A long-lived process (a study worker, a service solver) meets a new problem shape with nearly every plant: the
    cache drops the least recently used problems beyond ``CACHE_MB`` (estimated from their size) and always keeps
    the newest, however large."""
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    built: list = []
    monkeypatch.setattr(transcribe, "_build", lambda key, st, space: built.append(key) or object())
    st = get_structure("pid")

    def key(delay: int, K: int = 64) -> transcribe.ProblemKey:  # the delay changes the key, not the size
        return transcribe.ProblemKey(structure="pid", continuous=True, orders=(2,), zeros=(0,), poles=(2,),
                                     delays=(delay,), K=K, N=4, phase_cross=(True,), control_peak=False,
                                     objective="settling_time")

    size = transcribe.BYTES_PER_NODE * transcribe._estimated_nodes(key(0), len(st.params))
    monkeypatch.setattr(transcribe, "CACHE_MB", 2.5 * size / 2**20)  # room for two
    p0, p1 = transcribe.get_problem(key(0), st, None), transcribe.get_problem(key(1), st, None)
    assert transcribe.get_problem(key(0), st, None) is p0  # a hit: key 0 is now the most recently used
    transcribe.get_problem(key(2), st, None)
    assert [transcribe.is_built(key(d)) for d in (0, 1, 2)] == [True, False, True]  # key 1 was the least recent
    assert transcribe.get_problem(key(1), st, None) is not p1 and built.count(key(1)) == 2  # built again
    big = key(0, K=4096)
    transcribe.get_problem(big, st, None)
    assert list(transcribe._CACHE) == [big]  # over the bound alone, and kept
    # a tune keeps every problem it used until it ends (it comes back to them), then the bound applies again
    with transcribe.working_set():
        for d in (3, 4, 5):
            transcribe.get_problem(key(d), st, None)
        with transcribe.working_set():  # a nested tune (a diagnosis) does not end the outer one's scope
            transcribe.get_problem(key(6), st, None)
        assert all(transcribe.is_built(key(d)) for d in (3, 4, 5, 6))
    assert list(transcribe._CACHE) == [key(5), key(6)]


def test_a_tune_keeps_the_problems_it_builds_until_it_ends(monkeypatch):
    """tune() is one working_set scope: with no room in the cache at all, every problem the tune builds is still
    there while it runs, and the bound applies again once it returns."""
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    monkeypatch.setattr(transcribe, "CACHE_MB", 0.0)
    seen: list[tuple[int, int]] = []
    real = transcribe._build

    def build(key, st, space):
        seen.append((transcribe._PINNED["depth"], len(transcribe._CACHE)))
        return real(key, st, space)

    monkeypatch.setattr(transcribe, "_build", build)
    tune(make_plant([1.0], [1.0, 1.0]), structure="pi", dt=0.1, seed=0, time_budget_s=5.0)
    assert len(seen) >= 2, "precondition: the tune built more than one problem"
    assert all(depth >= 1 for depth, _ in seen)
    assert [n for _, n in seen] == list(range(len(seen)))  # none dropped while the tune ran
    assert len(transcribe._CACHE) == 1 and transcribe._PINNED["depth"] == 0  # then only the newest stays


@pytest.mark.slow
def test_second_tune_does_not_rebuild(monkeypatch):
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    plant = plant_from_expr(ROLL)
    c0 = transcribe.BUILDS["count"]
    r1 = tune(plant, structure="pid_z", dt=DT, seed=0, time_budget_s=BUDGET)
    c1 = transcribe.BUILDS["count"]
    assert c1 > c0  # the clean cache had to build
    r2 = tune(plant_from_expr(ROLL), structure="pid_z", dt=DT, seed=0, time_budget_s=BUDGET)
    assert transcribe.BUILDS["count"] == c1
    assert r2.solver["starts_tried"] == r1.solver["starts_tried"] > 0
    assert r2.gains == r1.gains
    # the structure changes: new problems (pid: a pd could not meet zero steady-state error here, and such a spec
    # is answered at once, after a short search)
    tune(plant, structure="pid", dt=DT, seed=0, time_budget_s=BUDGET)
    assert transcribe.BUILDS["count"] > c1


# PID on an unstable plant at wc dt = 1.0, settling over 240 samples (bench/quality.py's unstable-13)
FAST_CROSS_SLOW_TAIL = (([0.6477009424993394], [6.444179644262706e-05, 0.10765766050280373, -1.0]), 0.008538)


def _unstable_pid(x0):
    (num, den), dt = FAST_CROSS_SLOW_TAIL
    plant = make_plant(num, den)
    problem = TuningProblem.build(plant, structure="pid", dt=dt, spec=Spec.thesis())
    space = make_space(problem.structure, plant, dt, scale=problem.scale)
    ev = BatchEvaluator(problem, space)
    return plant, dt, problem, space, ev, refine_mod.Start.of(ev, np.asarray(x0, float))


def test_head_grid_step_response_is_the_verifiers():
    """A head grid (N points a sample over the first samples, fewer after them) simulates the same loop: at each of
    its points the NLP's step response is the verifier's, at the same instants; its trapezoid weights integrate
    over the whole horizon."""
    x0 = np.array([17.84, 13.09, 0.0244, 0.00058])
    plant, dt, problem, space, ev, start = _unstable_pid(x0)
    grid = refine_mod._Grid(K=96, N=8, step=dt, h=None, head=16, tail_N=2)
    t = grid.t
    assert t.size == 16 * 8 + 80 * 2 and np.all(np.diff(t) > 0)
    assert grid.spacing(15.5 * dt) == pytest.approx(dt / 8) and grid.spacing(16 * dt) == pytest.approx(dt / 2)
    assert np.sum(refine_mod._time_weights(grid, "iae")) == pytest.approx(t[-1])
    ctrl0 = problem.structure.tf(x0, dt)
    data = refine_mod._plant_data(ev, start, ctrl0, grid, space.w0)
    key = transcribe.ProblemKey(structure="pid", continuous=False, orders=tuple(lf.n for lf in data.lifted),
                                zeros=tuple(lf.zeros.size for lf in data.lifted),
                                poles=tuple(lf.poles.size for lf in data.lifted), delays=(0,), K=grid.K, N=grid.N,
                                phase_cross=tuple(data.has_pc), control_peak=True, objective="settling_time",
                                head=grid.head, tail_N=grid.tail_N)
    assert key.points == t.size
    nlp = transcribe.get_problem(key, space.structure, space)
    values = refine_mod._values(ev, space, grid, data, key)
    xs, _, _ = refine_mod._box(nlp, space, x0, data, values["band"], refine_mod._wmax(ev, space.w0))
    y_nlp = np.asarray(nlp.step(xs, nlp.params.pack({**values, "mask": np.zeros(t.size)}))).ravel()
    r = step_response(build_loop(plant, ctrl0), horizon_s=float(t[-1]) + dt, samples_per_dt=8)
    assert np.max(np.abs(y_nlp - np.interp(t, r.t, r.y))) < 1e-9


def test_polish_resolves_the_peak_of_a_fast_crossover_with_a_slow_tail():
    """The loop crosses over at wc dt = 1.0 and settles over 240 samples: under MAX_GRID_POINTS a uniform grid has
    one point a sample and misses its peak, so the polish's looser overshoot limit was never tried (2.039 s, the
    optimum 1.861 s with the overshoot at its limit). The head grid resolves the peak over the first samples; the
    polish from the old answer reaches 1.88 s, and the batch (the judge) finds it within the overshoot limit."""
    x0 = np.array([17.844420901583025, 13.089155150474955, 0.024370599461504792, 0.0005763735168064338])
    _, dt, _, space, ev, start = _unstable_pid(x0)
    assert start.settle[0] == pytest.approx(2.0388, abs=1e-3)
    grid = refine_mod._grid(ev, start, space.w0, float(start.settle[0]), fine=True)
    assert grid.N == 1 and not refine_mod._resolves_peak(start, grid), "precondition: the uniform grid is coarse"
    head = refine_mod._head_grid(start, grid)
    assert head is not None and head.head < head.K and refine_mod._resolves_peak(start, head)
    res = refine(ev, space, space.from_params(x0), incumbent=float(start.settle[0]), start=start, fine=True,
                 deadline=time.perf_counter() + BUDGET)
    b = ev.evaluate(np.array([space.params(v) for v in res.candidates]))
    assert np.min(b.score) < 1.9 and np.all(b.feasible[b.score < 1.9])


def test_polish_grid_is_dense_where_the_settling_time_is_decided(monkeypatch):
    """A PID on an integrating plant settles in 3.5 samples, but its slow zero's tail makes the polish's horizon 192
    samples: a uniform fine grid under MAX_GRID_POINTS had 8 points a sample everywhere (1536 points). The settle-head
    grid has the fine rule's 32 a sample over the first 16 samples (past SETTLE_HEAD settling times) and 4 after them:
    fewer points in all, four times the detail where the bisection decides, and the polish reaches at least what the
    uniform grid's reaches (bench/quality.py's integrating-02)."""
    plant = make_plant([0.3384051889376903], [0.8064168585526714, 1.0, 0.0])
    dt = 0.02776
    problem = TuningProblem.build(plant, structure="pid", dt=dt, spec=Spec.thesis())
    space = make_space(problem.structure, plant, dt, scale=problem.scale)
    ev = BatchEvaluator(problem, space)
    x0 = np.array([32.8393, 16.343, 41.4358, 2.776e-05])
    start = refine_mod.Start.of(ev, x0)
    inc = float(start.settle[0])
    uniform = refine_mod._grid(ev, start, space.w0, inc, fine=True)
    head = refine_mod._settle_head(ev, start, inc, uniform, 1)
    assert (uniform.K, uniform.N, uniform.head) == (192, 8, 0)
    assert head.head * dt >= refine_mod.SETTLE_HEAD * inc and head.N == 32 and head.tail_N == 4
    assert head.t.size < uniform.t.size and abs(head.t[-1] - uniform.t[-1]) < dt  # the same horizon
    reached = {}
    for name, at in (("uniform", 1e9), ("head", refine_mod.SETTLE_HEAD)):
        monkeypatch.setattr(refine_mod, "SETTLE_HEAD", at)
        res = refine(ev, space, space.from_params(x0), incumbent=inc, start=start, fine=True,
                     deadline=time.perf_counter() + BUDGET)
        b = ev.evaluate(np.array([space.params(v) for v in res.candidates]))
        reached[name] = float(np.min(b.score))
    assert reached["head"] <= reached["uniform"] and reached["head"] <= inc * (1 + 1e-5)


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_the_default_budget_does_not_count_the_nlp_builds(monkeypatch):
    """Issue 30: a budget that fits the problem. A build that takes longer than the whole search time (a 250 Hz
    loop's NLP takes seconds) ends a tune on an explicit budget before its first refinement, and the result says so
    with what was left; the default budget counts work (issue 41), only a 60 s wall-clock cap, and the refinement
    runs."""
    import time as _time

    real = transcribe._build

    def slow_build(key, st, space):
        _time.sleep(0.6)  # a build dearer than the search time below
        return real(key, st, space)

    monkeypatch.setattr(transcribe, "_build", slow_build)
    monkeypatch.setattr(transcribe, "estimated_build_s", lambda key, n: 0.6)
    monkeypatch.setattr(refine_mod, "estimated_build_s", lambda key, n: 0.6)
    plant = make_plant([1.0], [1.0, 3.0, 3.0, 1.0])

    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    given = tune(plant, structure="pid", dt=0.1, seed=0, time_budget_s=0.4)
    assert given.solver["nlp_solves"] == 0 and given.solver["stop"] == "budget"
    assert given.solver["optimality"]["unbuilt_s"] == pytest.approx(0.6)
    assert "before the local refinement could build its NLP" in given.solver["optimality"]["summary"]
    assert given.solver["budget_auto"] is False

    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    # the default budget counts work, not seconds: the slow build delays it, never cuts it (its cap is 60 s)
    auto = tune(plant, structure="pid", dt=0.1, seed=0)
    assert auto.solver["budget_auto"] is True and auto.solver["stop"] != "budget" and auto.solver["cut"] is None
    assert auto.solver["nlp_solves"] > 0 and auto.solver["build_s"] >= 0.6
    assert auto.solver["wall_time_s"] > 0.4 + 0.6  # past the given budget: the builds cut nothing
    assert auto.objective <= given.objective


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_restart_refinements_share_one_shape(monkeypatch):
    """A restart's own refinement (``refine(reach=)``) runs on the horizon of ``reach``, whatever its start's settling
    time: starts that settle 3x apart get one horizon K (ceil(3 reach / dt), bucketed) and, with the same points a
    sample, one build; without ``reach`` their horizons differ (the precondition)."""
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    keys: list = []
    real = refine_mod.get_problem

    def recording(key, st, space):
        keys.append(key)
        return real(key, st, space)

    monkeypatch.setattr(refine_mod, "get_problem", recording)
    plant = plant_from_expr(ROLL)
    batch, space = _batch(plant, "pid_z")
    starts = [_slow_start(plant, get_structure("pid_z"), d)[1] for d in (-1.0, -1.5)]
    settles = [float(np.max(batch.evaluate(space.params(v)[None]).per_plant[0]["settling_time_s"])) for v in starts]
    assert settles[1] > 2 * settles[0], "precondition: the starts settle far apart"
    for v in starts:
        refine(batch, space, v, deadline=time.perf_counter() + BUDGET)
    assert keys[0].K != keys[1].K, "precondition: their own horizons differ"
    reach = 0.5
    keys.clear()
    before = transcribe.BUILDS["count"]
    for v in starts:
        res = refine(batch, space, v, deadline=time.perf_counter() + BUDGET, reach=reach)
        assert res.candidates, res.status
    assert keys[0].K == keys[1].K == refine_mod._bucket(math.ceil(refine_mod.REACH_HORIZON * reach / DT))
    assert keys[0] == keys[1] and transcribe.BUILDS["count"] - before <= 1  # (these starts' crossovers: one N)


def test_grid_bisection_finds_the_first_feasible_grid_point():
    """The bisection's steps on the grid (``_grid_step``, ``_grid_gap``) against a brute-force scan: a slack that is a
    step function of Ts on the grid (the envelope starts at the first grid point at or after Ts) and linear in that
    point; the bracket closes on the first feasible grid point, asking only grid points, in fewer solves than
    halving the time axis to the grid's spacing."""
    t = np.arange(200) * 0.01
    for root in (0.0137, 0.362, 0.8951, 1.2049):
        def slack(ts, root=root):
            g = t[np.searchsorted(t, ts - 1e-12)]
            return 0.2 * (g - root) + (0.03 * (g - root) ** 2 if g > root else 0.0)
        first = float(t[np.flatnonzero([slack(x) >= 0 for x in t])[0]])  # brute force
        lo, hi = 0.003, 1.9
        s_lo, s_hi, kept, asked = slack(lo), slack(hi), 0, []
        while refine_mod._grid_gap(t, lo, hi) > 1:
            mid = refine_mod._grid_step(t, lo, hi, s_lo, s_hi, kept)
            assert np.any(np.isclose(t, mid, rtol=0, atol=1e-12)) and lo < mid < hi
            asked.append(mid)
            s = slack(mid)
            if s >= 0:
                hi, s_hi, kept = mid, s, kept + 1 if kept >= 0 else 1
            else:
                lo, s_lo, kept = mid, s, kept - 1 if kept <= 0 else -1
        assert math.isclose(t[np.searchsorted(t, hi - 1e-12)], first), (root, hi, first)
        halvings = math.ceil(math.log2((1.9 - 0.003) / 0.01))
        assert len(asked) < halvings, (root, asked)


@pytest.mark.slow
def test_warm_tunes_of_other_seeds_do_not_rebuild(monkeypatch):
    """Round 0 is the same for every seed, and a restart's own refinement runs on the horizon of a multiple of the
    incumbent's settling time (``engine.OWN_REACH``), not of its random start's: once a process has tuned the roll
    loop with two seeds, other seeds build nothing (before, each restart's start brought its own horizon: seeds 0-5
    built 7 more problems after a first tune)."""
    monkeypatch.setattr(transcribe, "_CACHE", OrderedDict())
    plant = plant_from_expr(ROLL)
    for seed in (100, 101):
        tune(plant, structure="pid_z", dt=DT, seed=seed, time_budget_s=BUDGET)
    c0 = transcribe.BUILDS["count"]
    for seed in range(4):
        r = tune(plant_from_expr(ROLL), structure="pid_z", dt=DT, seed=seed, time_budget_s=BUDGET)
        assert r.solver["optimality"]["restarts"] >= 2, "precondition: restarts ran"
    assert transcribe.BUILDS["count"] == c0
