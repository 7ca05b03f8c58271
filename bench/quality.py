"""The quality suite: generated plants, independent reference optima, and the tuner's ratio to them.

    python bench/quality.py generate                            # bench/quality_suite.json (seeded: the same file)
    nice -n 19 python bench/quality.py reference --evals 8000 --case-cap-s 16             # thesis-spec references
    nice -n 19 python bench/quality.py reference --defaults --evals 8000 --case-cap-s 16  # the new defaults'
    python bench/quality.py adopt --from bench/quality_reference_defaults.json  # the other set's better designs
    python bench/quality.py adopt --defaults --from bench/quality_reference.json
    python bench/quality.py run [--defaults] [--effort default]  # bench/results/quality_<effort>[_defaults].json
    python bench/quality.py report [--defaults]                  # bench/QUALITY_TABLES[_DEFAULTS].md

**Plants** (:func:`generate`, seed ``SUITE_SEED``, 35 per class, 280 in all): lag chains of order 1-5,
underdamped (zeta 0.05-0.4, with a lag), integrating ``K/(s(tau s + 1))``, one right-half-plane pole, one
right-half-plane zero, dead time 0.15-1.6 tau (whole samples), then two classes added later from their own random
stream (``default_rng([seed, 1])``, appended: the first 210 cases are unchanged): ``fracdelay``, a first- or
second-order lag with a dead time 0.15-1.6 tau that is **not** a whole number of samples (its fraction of a sample
kept in 0.1-0.9; the plant's exact delay at ``dt``, the modified z-transform), and ``twodof``, the 2-DOF PID
``pid2`` (Kp, Ki, Kd, Tf and the setpoint weights b, c) on plants drawn round-robin from the lag, underdamped,
nmp, delay and unstable generators (their ranges; ``plant_class`` names which). Each case at ``dt = tau_dom / k``,
``k`` log-uniform in 5...50, with a structure (round-robin per class, :data:`STRUCTURES`) of ``pid, pi, pd,
pid_z, lead, pid2`` that can meet the spec's zero steady-state error on that class (``pd`` and ``lead`` have no
integrator: integrating plants only).

**References** (:func:`reference_case`), two sets, each file stating its spec and the command that made it:
``bench/quality_reference.json`` for the thesis spec (``Spec.thesis()``: no default filter/noise limits) and
``bench/quality_reference_defaults.json`` for the new defaults (``Spec()``: derivative filter N <= 20, the filter
corner at most the Nyquist frequency (Tf >= dt/pi), the noise budget Mks <= 10 K0, resolved per plant into
``mks_max`` by ``TuningProblem.build``; each reference stores the limits in force as ``limits``). For each case:
independent global searches on the search-resolution scorer (:class:`tuner.optimize.batch.BatchEvaluator`, the
objective's definition, for the spec in force; none of the engine's starts, rounds or NLP): scipy's differential
evolution (two seeds, Sobol initialisation; ``pid_z``: a third over the equivalent backward-Euler PID's gains) and
CMA-ES with increasing-population restarts (the ``cmaes`` package), then a bounded Nelder-Mead polish of the best,
over every parameter (``pid2``: all six, b and c linearly over their ranges; with the Nyquist rule the box's
floor of Tf is dt/pi, as the tuner's). The best distinct candidates are verified at full resolution by
``tuner.analyze`` against the spec in force plus the filter rules (``tuner.rules.checks``), and the best feasible
one is **also checked independently** (:func:`independent_check`: numpy/scipy and ``tests/reference.py`` only,
nothing of tuner): margins on a dense Nyquist grid of the loop built without the library (a fractional delay by
the modified z-transform written here, :func:`zoh_delayed`), the step response by a matrix-exponential simulation
of the sampled-data loop (``reference.closed_loop_step``; for a fractional delay or a 2-DOF controller
:func:`step_sampled`, which switches the delayed held input inside the sample and drives the loop through the
reference path ``C_r``), settling and overshoot recomputed; ``pid2``'s two paths rebuilt from its gains by
``reference.pid_backward_euler`` (C = PID(Kp, Ki, Kd, Tf), C_r = PID(b Kp, Ki, c Kd, Tf)) and compared with the
library's; with the default limits also Mks = max |C/(1+L)| on the dense grid against the ``mks_max`` in force
(that limit's value, 10 K0, is the library's ``plant_scale``: not recomputed), N = |Kd|/(|Kp| Tf) and Tf >= dt/pi
from the gains. A reference that fails the independent check is stored with ``"independent_ok": false`` and
excluded from the ratios. ``--spec JSON`` computes a set for any other spec (``--out FILE``).

**Adoption** (:func:`cmd_adopt`): the thesis spec is looser than the defaults (a design meeting the defaults meets
it), so either set's search can find a design better than the other's own; ``adopt --from OTHER`` takes the other
set's design for a case where it verifies better for this set's spec (the same verification and independent
check), recording ``adopted_from`` and the set's own search result (``own_search``). The references are upper
bounds of uneven strength (budget-capped searches; slow loops get few evaluations in the cap).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
for p in (str(ROOT), str(ROOT / "tests")):
    if p not in sys.path:
        sys.path.insert(0, p)

from tuner import Spec, analyze, get_structure, tune  # noqa: E402
from tuner.plant import Plant  # noqa: E402
from tuner.problem import TuningProblem  # noqa: E402

SUITE_SEED = 20261202
SUITE = HERE / "quality_suite.json"
REFERENCE = HERE / "quality_reference.json"  # the thesis spec's references (Spec.thesis())
REFERENCE_DEFAULTS = HERE / "quality_reference_defaults.json"  # the new defaults' (Spec(), its design limits)
RESULTS = HERE / "results"
CLASSES = ("lag", "underdamped", "integrating", "unstable", "nmp", "delay", "fracdelay", "twodof")
STRUCTURES = {  # structures that can give zero steady-state error to a step on the class
    "lag": ("pid", "pi", "pid_z"),
    "underdamped": ("pid", "pi", "pid_z"),
    "integrating": ("pd", "lead", "pid", "pi"),
    "unstable": ("pi", "pid", "pid_z"),
    "nmp": ("pi", "pid", "pid_z"),
    "delay": ("pi", "pid", "pid_z"),
    "fracdelay": ("pi", "pid", "pid_z", "pid2"),
    "twodof": ("pid2",),
}


# -- the plants ---------------------------------------------------------------------------------------------

def _poly(*factors) -> list[float]:
    out = np.ones(1)
    for f in factors:
        out = np.polymul(out, np.asarray(f, float))
    return [float(c) for c in out]


def _draw(cls: str, i: int, rng: np.random.Generator) -> tuple[list[float], list[float], float, float]:
    """One plant of class ``cls`` (index ``i`` within it): ``(num, den, tau_dom, delay_s)``, the delay before it
    is made whole samples. The draws and their order are the suite's: changing them changes every case."""
    K = float(10 ** rng.uniform(-0.5, 0.7))
    T = float(10 ** rng.uniform(-1, 1.3))  # the dominant time constant, s
    delay = 0.0
    if cls == "lag":
        n = 1 + i % 5
        taus = [T] + [T * float(rng.uniform(0.15, 1.0)) for _ in range(n - 1)]
        num, den, tau_dom = [K], _poly(*[[t, 1.0] for t in taus]), T
    elif cls == "underdamped":
        z, wn = float(rng.uniform(0.05, 0.4)), 1.0 / T
        lag = float(rng.uniform(0.0, 0.5)) * T
        facs = [[1.0, 2 * z * wn, wn * wn]] + ([[lag, 1.0]] if i % 2 else [])
        num, den, tau_dom = [K * wn * wn], _poly(*facs), T
    elif cls == "integrating":
        num, den, tau_dom = [K], _poly([1.0, 0.0], [T, 1.0]), T
    elif cls == "unstable":
        lag = float(rng.uniform(0.0, 0.3)) * T
        facs = [[T, -1.0]] + ([[lag, 1.0]] if i % 2 else [])
        num, den, tau_dom = [K], _poly(*facs), T
    elif cls == "nmp":
        beta = float(rng.uniform(0.1, 0.5)) * T
        num, den, tau_dom = _poly([-K * beta, K]), _poly([T, 1.0], [T * float(rng.uniform(0.2, 1.0)), 1.0]), T
    elif cls in ("delay", "fracdelay"):
        second = i % 2 == 1
        facs = [[T, 1.0]] + ([[T * float(rng.uniform(0.1, 0.6)), 1.0]] if second else [])
        num, den, tau_dom = [K], _poly(*facs), T
        delay = float(rng.uniform(0.15, 1.6)) * T
    else:
        raise ValueError(cls)
    return num, den, tau_dom, delay


TWODOF_PLANTS = ("lag", "underdamped", "nmp", "delay", "unstable")  # the twodof class's plants, round-robin


def generate(n_per_class: int = 35, seed: int = SUITE_SEED) -> list[dict[str, Any]]:
    """The suite's cases (deterministic in ``seed``): plant (num, den, delay), dt, structure, class.

    The first six classes come from the stream ``default_rng(seed)`` (the original 210 cases, unchanged); the
    classes added later (``fracdelay``, ``twodof``) from their own stream ``default_rng([seed, 1])``, appended
    after them, so adding them changed no earlier case."""
    cases = []
    for stream, classes in ((np.random.default_rng(seed), CLASSES[:6]),
                            (np.random.default_rng([seed, 1]), CLASSES[6:])):
        rng = stream
        for cls in classes:
            for i in range(n_per_class):
                # twodof: the plant generators round-robin, each at its own index (lag orders 1-5, ...)
                gen, gi = (TWODOF_PLANTS[i % 5], i // 5) if cls == "twodof" else (cls, i)
                num, den, tau_dom, delay = _draw(gen, gi, rng)
                k = float(10 ** rng.uniform(math.log10(5), math.log10(50)))
                dt = float(f"{tau_dom / k:.4g}")
                if delay and cls == "fracdelay":
                    # never a whole number of samples: the fraction past the whole samples kept in 0.1-0.9
                    d = delay / dt
                    delay = (math.floor(d) + min(max(d - math.floor(d), 0.1), 0.9)) * dt
                elif delay:
                    delay = max(1, round(delay / dt)) * dt  # whole samples
                sts = STRUCTURES[cls]
                case = {"id": f"{cls}-{i:02d}", "class": cls, "structure": sts[i % len(sts)], "num": num,
                        "den": den, "delay_s": float(f"{delay:.10g}"), "dt": dt, "tau_dom": tau_dom,
                        "order": len(den) - 1}
                if cls == "twodof":
                    case["plant_class"] = gen
                cases.append(case)
    return cases


def load_suite() -> list[dict[str, Any]]:
    return json.loads(SUITE.read_text())["cases"]


def plant_of(c: dict[str, Any]) -> Plant:
    return Plant(np.array(c["num"], float), np.array(c["den"], float), delay_s=float(c["delay_s"]))


def spec_of(d: dict[str, Any] | None) -> Spec:
    """The spec of a stored run or reference; none given: the thesis spec (no default design limits)."""
    return Spec(**d) if d else Spec.thesis()


def spec_choice(a: argparse.Namespace) -> tuple[Spec, str]:
    """The spec of a command line and its name: ``--defaults`` the new defaults (``Spec()``: filter N <= 20, the
    Nyquist filter floor, the noise budget 10 K0), ``--spec JSON`` those fields on the thesis spec's defaults
    (``Spec(**fields)``), neither: the thesis spec (``Spec.thesis()``)."""
    if getattr(a, "defaults", False):
        if a.spec:
            raise SystemExit("--defaults and --spec exclude each other")
        return Spec(), ("the new defaults (`Spec()`: filter_n_max 20, filter_nyquist, noise_gain_max 10, the noise "
                        "budget resolved per plant into mks_max)")
    if a.spec:
        return spec_of(json.loads(a.spec)), f"`Spec(**{a.spec})`"
    return Spec.thesis(), "the thesis spec (`Spec.thesis()`: no default filter/noise limits)"


def same_spec(stored: dict[str, Any], spec: Any) -> bool:
    """Whether a stored spec (a reference file's) is ``spec``: every stored field as it is, and any field added
    since (a limit of the registry) unset."""
    now = spec.model_dump(mode="json")
    return all(now.get(k) == v for k, v in stored.items()) and all(now[k] is None for k in now.keys() - stored.keys())


def spec_name(spec_d: dict[str, Any]) -> str:
    """How a stored spec (a reference file's) is named in the report."""
    if same_spec(spec_d, Spec.thesis()):
        return "the thesis spec (`Spec.thesis()`: no default filter/noise limits)"
    if same_spec(spec_d, Spec()):
        return ("the new defaults (`Spec()`: filter_n_max 20, filter_nyquist, noise_gain_max 10, the noise budget "
                "resolved per plant into mks_max)")
    return f"`Spec(**{json.dumps(spec_d)})`"


def reference_path(a: argparse.Namespace, given: str) -> Path:
    """A command's reference file: ``given``, else the defaults' file with ``--defaults``, else the thesis one."""
    return Path(given) if given else (REFERENCE_DEFAULTS if getattr(a, "defaults", False) else REFERENCE)


def problem_of(c: dict[str, Any], spec: Spec) -> TuningProblem:
    return TuningProblem.build(plant_of(c), structure=c["structure"], spec=spec, dt=c["dt"])


# -- the independent check (numpy/scipy and tests/reference.py only: nothing of tuner) ---------------------

def _zoh_frac(num, den, dt: float, phi: float) -> tuple[np.ndarray, np.ndarray]:
    """ZOH equivalent at ``dt`` of ``num/den`` delayed by ``0 < phi < dt`` (the modified z-transform), written
    out here: over a sample the held input is the previous sample's value for ``phi`` s, then the current one, so
    ``x+ = Phi x + Gamma1 u[k-1] + Gamma0 u[k]`` with ``Phi = e^{A dt}``, ``Gamma0 = int_0^{dt-phi} e^{As} ds B``,
    ``Gamma1 = e^{A(dt-phi)} int_0^phi e^{As} ds B``; ``u[k-1]`` is one extra state. (num, den) in z, den monic."""
    from scipy import linalg, signal

    A, B, C, D = signal.tf2ss(np.asarray(num, float), np.asarray(den, float))
    assert np.all(D == 0), "a strictly proper plant"
    n = A.shape[0]

    def gam(h: float) -> tuple[np.ndarray, np.ndarray]:
        M = np.zeros((n + 1, n + 1))
        M[:n, :n], M[:n, n:] = A, B
        E = linalg.expm(M * h)
        return E[:n, :n], E[:n, n:]

    Phi, _ = gam(dt)
    E2, G0 = gam(dt - phi)
    _, Gp = gam(phi)
    G1 = E2 @ Gp
    Aa = np.zeros((n + 1, n + 1))
    Aa[:n, :n], Aa[:n, n:] = Phi, G1
    Ba = np.r_[G0, [[1.0]]]
    Ca = np.c_[C, [[0.0]]]
    b, a = signal.ss2tf(Aa, Ba, Ca, np.zeros((1, 1)))
    b = np.atleast_1d(np.squeeze(b))
    b[np.abs(b) < 1e-14 * np.max(np.abs(b))] = 0.0
    return np.trim_zeros(b, "f") / a[0], a / a[0]


def zoh_delayed(num, den, dt: float, delay_s: float) -> tuple[np.ndarray, np.ndarray, int, float]:
    """``(gn, gd, m, phi)``: the sampled plant ``gn/gd`` in z with its whole delay ``z^-m`` folded into gd and
    the fraction ``phi`` in the modified z-transform (``delay_s = m dt + phi``)."""
    import reference as ref  # tests/reference.py

    d = delay_s / dt
    m = int(math.floor(d + 1e-9))
    phi = max(0.0, delay_s - m * dt)
    if phi < 1e-9 * dt:
        phi = 0.0
    gn, gd = ref.zoh(num, den, dt) if phi == 0 else _zoh_frac(num, den, dt, phi)
    return gn, np.polymul(gd, np.r_[1.0, np.zeros(m)]), m, phi


def _controller_ss(num_r, num, den):
    """One realisation of ``u = (num_r/den) r - (num/den) y`` on shared states (the dual of scipy's controllable
    form of the one-input two-output [num_r; num]/den): ``(A, B (n x 2), C, D (2,))``, inputs ``[r, -y]``."""
    from scipy import signal

    L = len(den)
    pad = lambda p: np.r_[np.zeros(L - len(p)), np.asarray(p, float)]
    A, B, C, D = signal.tf2ss(np.vstack([pad(num_r), pad(num)]), np.asarray(den, float))
    return A.T, C.T, B.T, np.asarray(D, float).reshape(2)


def step_sampled(plant_num, plant_den, num_r, num, den, dt: float, *, m: int, phi: float, n_per_sample: int = 20,
                 samples: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """Unit-step response of the sampled-data loop with a 1- or 2-DOF controller ``u = C_r r - C y`` (``num_r`` =
    ``num`` for a 1-DOF one), its output held and delayed by ``m dt + phi`` into the continuous plant, which is
    integrated exactly (matrix exponential) at ``n_per_sample`` points per sample plus the instant ``phi`` into
    every sample where the delayed held input switches. Returns (t, y) (the grid is uniform but for those
    instants)."""
    from scipy import linalg, signal

    Ac, Bc, Cc, Dc = _controller_ss(num_r, num, den)
    An, Bn, Cn, _ = signal.tf2ss(np.asarray(plant_num, float), np.asarray(plant_den, float))
    nx = An.shape[0]
    h = dt / n_per_sample
    pts = sorted({j * h for j in range(n_per_sample)} | ({phi} if phi > 0 else set()))
    segs = []  # (start within the sample, Ad, Bd, the new input?)
    for j, t0 in enumerate(pts):
        t1 = pts[j + 1] if j + 1 < len(pts) else dt
        M = np.zeros((nx + 1, nx + 1))
        M[:nx, :nx], M[:nx, nx:] = An, Bn
        E = linalg.expm(M * (t1 - t0))
        segs.append((t0, E[:nx, :nx], E[:nx, nx:], t0 >= phi - 1e-15 * dt))
    xc = np.zeros(Ac.shape[0])
    xp = np.zeros((nx, 1))
    ubuf = [0.0] * (m + 1)  # u[k-m-1], ..., u[k-1]
    ts, ys = [], []
    for k in range(samples):
        y = float((Cn @ xp)[0, 0])
        e = np.array([1.0, -y])
        u = float(Cc.reshape(-1) @ xc + Dc @ e) if Ac.size else float(Dc @ e)
        if Ac.size:
            xc = Ac @ xc + Bc @ e
        ubuf.append(u)
        u_old, u_new = ubuf[0], ubuf[1]  # u[k-m-1] until phi into the sample, then u[k-m]
        ubuf.pop(0)
        for t0, Ad, Bd, new in segs:
            ts.append(k * dt + t0)
            ys.append(float((Cn @ xp)[0, 0]))
            xp = Ad @ xp + Bd * (u_new if new else u_old)
    return np.asarray(ts), np.asarray(ys)


def _gains_controller(c: dict[str, Any], gains: dict[str, float]):
    """pid2's two paths from its gains by tests/reference.py's backward-Euler PID (nothing of tuner):
    C = PID(Kp, Ki, Kd, Tf), C_r = PID(b Kp, Ki, c Kd, Tf); ``(num_r, num, den)`` over one monic denominator."""
    import reference as ref  # tests/reference.py

    g = dict(gains)
    num, den = ref.pid_backward_euler(g, c["dt"])
    num_r, den_r = ref.pid_backward_euler(g | {"Kp": g["b"] * g["Kp"], "Kd": g["c"] * g["Kd"]}, c["dt"])
    assert np.allclose(den, den_r)
    return num_r / den[0], num / den[0], den / den[0]


def _rel(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = max(len(a), len(b))
    a, b = np.r_[np.zeros(n - len(a)), a], np.r_[np.zeros(n - len(b)), b]
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def independent_check(c: dict[str, Any], ctl: dict[str, Any], spec: Spec, gains: dict[str, float] | None = None,
                      ) -> dict[str, Any]:
    """Margins, stability, the step response of the sampled-data loop and the spec's limits, recomputed without the
    library from the controller's coefficients ``ctl`` (``num``, ``den``; a 2-DOF one's reference path
    ``num_r``) or, for ``pid2``, from its ``gains`` by tests/reference.py's backward-Euler PID (checked against
    ``ctl``). The plant's sampled model with a fractional delay: :func:`zoh_delayed`. ``spec`` is the spec in
    force (the noise budget resolved into ``mks_max``); its filter rules are checked on ``gains``."""
    import reference as ref  # tests/reference.py

    dt = c["dt"]
    out: dict[str, Any] = {}
    cnum, cden = np.asarray(ctl["num"], float), np.asarray(ctl["den"], float)
    cnum_r = np.asarray(ctl.get("num_r") or ctl["num"], float)
    if c["structure"] == "pid2":
        cnum_r, cnum, cden = _gains_controller(c, gains)
        out["controller_rel_diff"] = max(_rel(cnum, ctl["num"]), _rel(cnum_r, ctl["num_r"]), _rel(cden, ctl["den"]))
    gn, gd, m, phi = zoh_delayed(c["num"], c["den"], dt, c["delay_s"])
    num, den = np.polymul(cnum, gn), np.polymul(cden, gd)
    stable = bool(np.all(np.abs(np.roots(np.polyadd(den, num))) < 1 - 1e-9))
    out["stable"] = stable
    if not stable:
        return out | {"ok": False}
    nm = ref.nyquist_margins(num, den, dt, n=60_000)
    pm, gm_up, gm_lo = nm["pm"], nm["gm_db"], nm["gml_db"]
    out.update(pm_deg=float(pm), gm_db=float(gm_up), gm_lower_db=float(gm_lo))
    # the sampled-data step, long enough for the slowest closed-loop pole: tests/reference.py's simulation for a
    # 1-DOF loop with whole samples of delay, step_sampled (written here) for a 2-DOF one or a fractional delay
    poles = np.abs(np.roots(np.polyadd(den, num)))
    rho = float(np.max(poles)) if len(poles) else 0.0
    K = int(min(40_000, max(200, 12 * math.log(1e-4) / math.log(max(rho, 1e-6)))))
    if phi == 0 and c["structure"] != "pid2":
        t, y = ref.closed_loop_step(c["num"], c["den"], cnum, cden, dt, delay_samples=m, samples=K)
    else:
        t, y = step_sampled(c["num"], c["den"], cnum_r, cnum, cden, dt, m=m, phi=phi, samples=K)
    yf = 1.0
    try:
        settle = ref.settling_time(t, y, yf, band=spec.settling_band_pct / 100)
    except AssertionError:
        settle = math.inf
    over = max(0.0, float(np.max(y) - yf) * 100)
    out.update(settling_s=float(settle), overshoot_pct=over)
    ok = (pm >= spec.phase_margin_min_deg - 0.05 and (spec.gain_margin_min_db is None
          or min(gm_up, -gm_lo if math.isfinite(gm_lo) else math.inf) >= spec.gain_margin_min_db - 0.02)
          and (spec.overshoot_max_pct is None or over <= spec.overshoot_max_pct + 0.02))
    if "controller_rel_diff" in out:
        ok = ok and out["controller_rel_diff"] < 1e-9
    # the default design limits: Mks on a dense grid (C on -y, the plant's sampled model above), the filter rules
    # on the gains (N = |Kd|/(|Kp| Tf), Tf >= dt/pi)
    if spec.mks_max is not None:
        w = ref.dense_grid(dt, n=60_000)
        with np.errstate(all="ignore"):
            mks = float(np.max(np.abs(ref.eval_L(cnum, cden, w, dt) / (1 + ref.eval_L(num, den, w, dt)))))
        out.update(mks=mks, mks_max=float(spec.mks_max))
        ok = ok and mks <= spec.mks_max * (1 + 1e-3)
    if gains is not None and spec.filter_n_max is not None and {"Kp", "Kd", "Tf"} <= set(gains):
        kp, kd, tf = abs(gains["Kp"]), abs(gains["Kd"]), gains["Tf"]
        n_f = 0.0 if kd == 0 else (kd / (kp * tf) if kp > 0 and tf > 0 else math.inf)
        out["filter_n"] = n_f
        ok = ok and n_f <= spec.filter_n_max * (1 + 1e-6)
    if gains is not None and spec.filter_nyquist and "Tf" in gains:
        out["tf_over_nyquist_floor"] = float(gains["Tf"] / (dt / math.pi))
        ok = ok and gains["Tf"] >= dt / math.pi * (1 - 1e-6)
    return out | {"ok": bool(ok)}


# -- the references -----------------------------------------------------------------------------------------

VERIFY = 16  # distinct candidates verified at full resolution per case


class _OutOfTime(Exception):
    pass


def reference_case(c: dict[str, Any], spec: Spec, *, evals: int, seed: int = 0, cap_s: float = math.inf
                   ) -> dict[str, Any]:
    """Independent global optimisation of one case (see the module docstring); each of the four searches gets a
    quarter of ``evals`` evaluations and of ``cap_s`` seconds (slow loops simulate long horizons)."""
    from scipy.optimize import differential_evolution, minimize

    from tuner import rules
    from tuner.optimize.batch import BatchEvaluator
    from tuner.optimize.scoring import Evaluator
    from tuner.optimize.space import make_space

    t0 = time.perf_counter()
    prob = problem_of(c, spec)
    # the spec in force: the asked one with the default limits resolved (the noise budget as mks_max); the
    # search's box has the Nyquist filter floor when the spec asks for it (as the tuner's), the batch scores the
    # filter-N rule and Mks, the verification below checks all of them
    sp = prob.spec
    space = make_space(prob.structure, prob.nominal, prob.dt, scale=prob.scale, nyquist=sp.filter_nyquist)
    batch = BatchEvaluator(prob, space)
    lo, hi = space.lo, space.hi
    pool: list[tuple[float, np.ndarray]] = []
    n = [0]
    stage_end = [math.inf]

    def f(V: np.ndarray) -> np.ndarray:
        if time.perf_counter() > stage_end[0]:
            raise _OutOfTime
        V = np.clip(np.atleast_2d(V), lo, hi)
        X = np.array([space.params(v) for v in V])
        s = batch.evaluate(X).score
        n[0] += len(V)
        for v, si in zip(V, s):
            pool.append((float(si), v.copy()))
        return s

    dim = lo.size
    per = evals // 4
    methods: dict[str, float] = {}
    stage = cap_s / 4

    def best_since(before: int) -> float:
        return float(min((s for s, _ in pool[before:]), default=math.inf))

    for k in range(2):  # DE, two seeds
        pop = 15
        gens = max(5, per // (pop * dim) - 1)
        before = n[0]
        stage_end[0] = time.perf_counter() + stage
        try:
            differential_evolution(lambda X: f(X.T), list(zip(lo, hi)), seed=seed + k, popsize=pop, maxiter=gens,
                                   tol=0, atol=0, polish=False, init="sobol", vectorized=True,
                                   updating="deferred", mutation=(0.5, 1.0), recombination=0.9)
        except _OutOfTime:
            methods[f"de{k}_capped"] = True
        methods[f"de{k}"] = best_since(before)
        methods[f"de{k}_evals"] = n[0] - before
    if c["structure"] == "pid_z":
        # the thesis form K (z^2 + a1 z + a2) / (z (z - 1)) is the backward-Euler PID: DE over (Kp, Ki, Kd) in the
        # pid's own box too (a random (a1, a2) rarely lands in the small stabilising region)
        pid = get_structure("pid")
        psp = make_space(pid, prob.nominal, prob.dt, scale=prob.scale)
        dtc = prob.dt

        def to_pidz(W: np.ndarray) -> np.ndarray:
            G = np.array([psp.params(np.r_[w, psp.lo[3]])[:3] for w in W])
            kp, ki, kd = G[:, 0], G[:, 1], G[:, 2]
            K = kp + ki * dtc + kd / dtc
            with np.errstate(all="ignore"):
                a1, a2 = -(kp + 2 * kd / dtc) / K, (kd / dtc) / K
            X = np.c_[K, a1, a2]
            V = np.array([space.from_params(x) if np.all(np.isfinite(x)) else np.full(3, np.nan) for x in X])
            return V

        def fp(W: np.ndarray) -> np.ndarray:
            V = to_pidz(W.T)
            ok = np.all(np.isfinite(V), axis=1) & np.all((lo <= V) & (hi >= V), axis=1)
            out = np.full(len(V), 1e7)
            if ok.any():
                out[ok] = f(V[ok])
            return out

        before = n[0]
        stage_end[0] = time.perf_counter() + stage
        try:
            differential_evolution(fp, list(zip(psp.lo[:3], psp.hi[:3])), seed=seed + 5, popsize=15,
                                   maxiter=max(5, per // 45 - 1), tol=0, atol=0, polish=False, init="sobol",
                                   vectorized=True, updating="deferred", mutation=(0.5, 1.0), recombination=0.9)
        except _OutOfTime:
            methods["de_pid_form_capped"] = True
        methods["de_pid_form"] = best_since(before)
        methods["de_pid_form_evals"] = n[0] - before
    from cmaes import CMA

    rng = np.random.default_rng(seed + 7)
    used, popsize, cm_best, k = 0, 4 + int(3 * math.log(dim)), math.inf, 0
    stage_end[0] = time.perf_counter() + stage
    # BIPOP-like restarts from random points: a large-population wide one, then small local ones
    while used < per and time.perf_counter() < stage_end[0]:
        wide = k % 3 == 0
        opt = CMA(mean=lo + rng.random(dim) * (hi - lo), sigma=(0.25 if wide else 0.05) * float(np.min(hi - lo)),
                  bounds=np.c_[lo, hi], seed=int(rng.integers(1 << 30)),
                  population_size=popsize * 2 ** (k // 3) if wide else popsize)
        k += 1
        while used < per and not opt.should_stop() and time.perf_counter() < stage_end[0]:
            X = np.array([opt.ask() for _ in range(opt.population_size)])
            try:  # the stage's time can run out between the loop's test and the evaluation
                s = f(X)
            except _OutOfTime:
                methods["cmaes_capped"] = True
                break
            used += len(X)
            opt.tell(list(zip(X, s)))
            cm_best = min(cm_best, float(np.min(s)))
    methods["cmaes"] = cm_best
    methods["cmaes_evals"] = used
    best = min(pool, key=lambda t: t[0])
    before = len(pool)
    stage_end[0] = time.perf_counter() + stage
    try:
        minimize(lambda v: float(f(v[None])[0]), best[1], method="Nelder-Mead", bounds=list(zip(lo, hi)),
                 options={"maxfev": per, "xatol": 1e-6, "fatol": 0})
    except _OutOfTime:
        methods["polish_capped"] = True
    methods["polish"] = min(best[0], best_since(before))
    stage_end[0] = math.inf
    # verify the best distinct candidates at full resolution; the first feasible one is the reference
    ev = Evaluator(list(prob.plants), prob.structure, prob.dt, sp, w0=space.w0)
    span = np.maximum(hi - lo, 1e-12)
    chosen: list[np.ndarray] = []
    ref: dict[str, Any] | None = None
    for s, v in sorted(pool, key=lambda t: t[0]):
        if s >= 1e3 or len(chosen) >= VERIFY:  # the settling time is discontinuous: the best may verify later
            break
        if any(np.max(np.abs(v - w) / span) < 1e-3 for w in chosen):
            continue
        chosen.append(v)
        x = space.params(v)
        ctl = ev.controller(x)
        a = analyze(plant_of(c), ctl, sp)
        if not (a.meets_spec and all(k.ok for k in rules.checks(prob.structure, sp, x, prob.dt))):
            continue
        from tuner.optimize.scoring import objective_value

        obj = float(objective_value(a, sp))
        if ref is None or obj < ref["objective"]:
            cd = {"num": [float(q) for q in ctl.num], "den": [float(q) for q in ctl.den]}
            if getattr(ctl, "num_r", None) is not None:  # a 2-DOF controller's reference path
                cd["num_r"] = [float(q) for q in ctl.num_r]
            ref = {"objective": obj, "gains": prob.structure.named(x), "search_score": s, "controller": cd}
    out = {"id": c["id"], "evaluations": n[0], "evals_budget": evals, "case_cap_s": cap_s, "methods": methods,
           "wall_s": time.perf_counter() - t0}
    if prob.limits:
        out["limits"] = [dict(d) for d in prob.limits]
    if ref is None:
        return out | {"feasible": False}
    chk = independent_check(c, ref["controller"], sp, gains=ref["gains"])
    if spec.objective == "settling_time" and "settling_s" in chk:
        chk["settling_agrees"] = bool(abs(chk["settling_s"] - ref["objective"]) <= 0.01 * ref["objective"]
                                      + 0.5 * c["dt"] / 20 + 1e-9)
    return out | {"feasible": True, **ref, "independent": chk,
                  "independent_ok": bool(chk.get("ok") and chk.get("settling_agrees", True))}


def cmd_reference(a: argparse.Namespace) -> None:
    cases = load_suite()
    spec, _ = spec_choice(a)
    out_path = reference_path(a, a.out)
    done: dict[str, Any] = {}
    if out_path.exists() and not a.fresh:
        old = json.loads(out_path.read_text())
        if not same_spec(old.get("spec", {}), spec):
            raise SystemExit(f"{out_path} holds references for another spec: give another --out, or --fresh")
        done = {r["id"]: r for r in old["references"]}
    only = set(a.only.split(",")) if a.only else None
    t_end = time.time() + a.cap_s if a.cap_s else math.inf
    todo = [c for c in cases if c["id"] not in done and (only is None or c["id"] in only)]
    # round-robin over the classes, so that a capped run covers every class
    todo.sort(key=_round_robin)
    for c in todo:
        if time.time() > t_end:
            break
        r = reference_case(c, spec, evals=a.evals, cap_s=a.case_cap_s)
        done[c["id"]] = r
        print(f"{c['id']:16s} {c['structure']:6s} obj {r.get('objective', math.nan):.5g} "
              f"indep {r.get('independent_ok')} {r['wall_s']:.1f}s", flush=True)
        _write_ref(out_path, spec, done, a)
    _write_ref(out_path, spec, done, a)


def _write_ref(path: Path, spec: Spec, done: dict[str, Any], a: argparse.Namespace) -> None:
    cmd = ("nice -n 19 python bench/quality.py reference" + (" --defaults" if a.defaults else "")
           + (f" --spec '{a.spec}'" if a.spec else "") + f" --evals {a.evals} --case-cap-s {a.case_cap_s:g}"
           + (f" --out {os.path.relpath(path, ROOT)}" if path.resolve() != reference_path(a, "").resolve() else ""))
    data = {"command": cmd, "spec_name": spec_name(spec.model_dump(mode="json")),
            "spec": spec.model_dump(mode="json"), "evals_per_case": a.evals,
            "method": "scipy differential_evolution x2 (popsize 15, Sobol; pid_z: a third over the equivalent "
                      "backward-Euler PID's gains) + CMA-ES restarts (wide large-population and small local) + "
                      "Nelder-Mead polish, on tuner.optimize.batch scores (pid2: all six parameters, the setpoint "
                      "weights b, c linearly over their ranges; the search box has the Nyquist filter floor when the "
                      "spec has it); verified by tuner.analyze against the spec in force (the noise budget resolved "
                      "into mks_max) and the filter rules (tuner.rules.checks) (best of 16 distinct candidates) and "
                      "independently by bench/quality.py independent_check (numpy/scipy and tests/reference.py: "
                      "margins, step, Mks, filter N and Tf floor; fractional delays by the modified z-transform and "
                      "a simulation with the delayed hold's switch inside the sample; pid2's two paths from its "
                      "gains, the step from the reference path)",
            "references": [done[k] for k in sorted(done)]}
    caps = {}
    for r in done.values():  # a set resumed with another cap: say which cap made which references
        caps.setdefault(f"{r.get('evals_budget', '?')} evals, cap {r.get('case_cap_s', '?')} s", []).append(r["id"])
    if len(caps) > 1:
        data["mixed_budgets"] = {k: len(v) for k, v in caps.items()}
        data["note"] = ("resumed with different budgets: each reference's evals_budget and case_cap_s say which "
                        "made it")
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1, allow_nan=True))
    os.replace(tmp, path)


def cmd_adopt(a: argparse.Namespace) -> None:
    """Each case's design from another reference set (``--from``), verified for this set's spec, replaces this
    set's reference where it is better: the thesis spec is looser than the defaults (every design meeting the
    defaults meets it), so a defaults search that found a better design shows the thesis search fell short. The
    adopted design goes through the same verification (tuner.analyze for the spec in force plus the filter
    rules, then :func:`independent_check`); its record says where it came from (``adopted_from``)."""
    from tuner import rules
    from tuner.optimize.scoring import objective_value

    spec, _ = spec_choice(a)
    path = reference_path(a, a.out)
    doc = json.loads(path.read_text())
    if not same_spec(doc["spec"], spec):
        raise SystemExit(f"{path} holds references for another spec")
    src = json.loads(Path(a.source).read_text())
    other = {r["id"]: r for r in src["references"]}
    mine = {r["id"]: r for r in doc["references"]}
    cases = {c["id"]: c for c in load_suite()}
    adopted = list(doc.get("adopted", []))
    for cid in sorted(mine, key=lambda k: _round_robin(cases[k])):
        r, o, c = mine[cid], other.get(cid), cases[cid]
        good = bool(r.get("feasible") and r.get("independent_ok"))
        if not (o and o.get("feasible") and o.get("independent_ok")):
            continue
        if good and o["objective"] >= r["objective"] * (1 - 1e-4):
            continue
        prob = problem_of(c, spec)
        sp, st = prob.spec, prob.structure
        x = st.vector(o["gains"])
        if not all(k.ok for k in rules.checks(st, sp, x, prob.dt)):
            continue
        ctl = st.tf(x, prob.dt)
        an = analyze(plant_of(c), ctl, sp)
        if not an.meets_spec:
            continue
        obj = float(objective_value(an, sp))
        if good and obj >= r["objective"] * (1 - 1e-4):
            continue
        cd = {"num": [float(q) for q in ctl.num], "den": [float(q) for q in ctl.den]}
        if getattr(ctl, "num_r", None) is not None:
            cd["num_r"] = [float(q) for q in ctl.num_r]
        chk = independent_check(c, cd, sp, gains=dict(o["gains"]))
        if sp.objective == "settling_time" and "settling_s" in chk:
            chk["settling_agrees"] = bool(abs(chk["settling_s"] - obj) <= 0.01 * obj + 0.5 * c["dt"] / 20 + 1e-9)
        ok = bool(chk.get("ok") and chk.get("settling_agrees", True))
        print(f"{cid:16s} {c['structure']:6s} {r.get('objective', math.nan):.5g} -> {obj:.5g} indep {ok}", flush=True)
        if not ok:
            continue
        mine[cid] = r | {"feasible": True, "objective": obj, "gains": dict(o["gains"]), "controller": cd,
                         "search_score": None, "independent": chk, "independent_ok": True,
                         "adopted_from": {"file": os.path.relpath(Path(a.source).resolve(), ROOT),
                                          "command": src["command"]},
                         "own_search": {k: r.get(k) for k in ("objective", "gains", "feasible", "independent_ok")}}
        adopted.append(cid)
        doc["references"] = [mine[k] for k in sorted(mine)]
        doc["adopted"] = sorted(set(adopted))
        doc["adopt_command"] = ("python bench/quality.py adopt" + (" --defaults" if a.defaults else "")
                                + f" --from {os.path.relpath(Path(a.source).resolve(), ROOT)}")
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(doc, indent=1, allow_nan=True))
        os.replace(tmp, path)
    print(f"{len(set(adopted))} adopted in {path}")


# -- the tuner on the suite -----------------------------------------------------------------------------------

def load_reference(path: Path = REFERENCE) -> dict[str, dict[str, Any]]:
    if not path.exists():
        return {}
    return {r["id"]: r for r in json.loads(path.read_text())["references"]}


def tune_case(c: dict[str, Any], spec: Spec, *, effort: str = "default", seed: int = 0,
              budget: float = 10.0) -> dict[str, Any]:
    t0 = time.perf_counter()
    kw = {"effort": effort} if effort else {}
    res = tune(plant_of(c), structure=c["structure"], dt=c["dt"], spec=spec, seed=seed, time_budget_s=budget,
               diagnose=False, **kw)
    wall = time.perf_counter() - t0
    return {"id": c["id"], "objective": float(res.objective) if res.meets_spec else math.inf,
            "meets": bool(res.meets_spec), "wall_s": wall, "gains": dict(res.gains),
            "stop": res.solver.get("stop"), "optimality": res.solver.get("optimality")}


def ratio(t: dict[str, Any], r: dict[str, Any] | None) -> float | None:
    if r is None or not r.get("feasible") or not r.get("independent_ok"):
        return None
    if not t["meets"]:
        return math.inf
    return t["objective"] / r["objective"]


def cmd_run(a: argparse.Namespace) -> None:
    cases = load_suite()
    spec, _ = spec_choice(a)
    ref_path = reference_path(a, a.reference)
    if ref_path.exists() and not same_spec(json.loads(ref_path.read_text())["spec"], spec):
        raise SystemExit(f"{ref_path} holds references for another spec than the run's (--defaults / --spec / "
                         "--reference)")
    refs = load_reference(ref_path)
    only = set(a.only.split(",")) if a.only else None
    rows = []
    RESULTS.mkdir(exist_ok=True)
    out = Path(a.out) if a.out else RESULTS / f"quality_{a.effort or 'baseline'}{_suffix(a)}.json"
    if a.append and out.exists():  # keep what is there, tune only the cases it lacks
        rows = json.loads(out.read_text())["rows"]
        have = {r["id"] for r in rows}
        cases = [c for c in cases if c["id"] not in have]
    cases = sorted(cases, key=_round_robin)  # every class early: a run stopped part-way covers them all
    for c in cases:
        if only and c["id"] not in only:
            continue
        t = tune_case(c, spec, effort=a.effort, seed=a.seed, budget=a.budget)
        t["ratio"] = ratio(t, refs.get(c["id"]))
        t |= {"class": c["class"], "structure": c["structure"], "order": c["order"]}
        rows.append(t)
        print(f"{c['id']:16s} {c['structure']:6s} {t['objective']:.5g} ratio {t['ratio']} {t['wall_s']*1e3:.0f} ms "
              f"{t['stop']}", flush=True)
        _write_run(out, a, rows)
    _write_run(out, a, rows)
    print(table(rows))


def _suffix(a: argparse.Namespace) -> str:
    """Run files of the new defaults: ``results/quality_<effort>_defaults.json`` (the thesis spec's: no suffix)."""
    return "_defaults" if getattr(a, "defaults", False) else ""


def _round_robin(c: dict[str, Any]) -> tuple[int, int]:
    return int(c["id"].split("-")[1]), CLASSES.index(c["class"])


def _write_run(out: Path, a: argparse.Namespace, rows: list[dict[str, Any]]) -> None:
    load = os.getloadavg()
    out.write_text(json.dumps({"command": "python bench/quality.py " + " ".join(sys.argv[1:]), "effort": a.effort,
                               "seed": a.seed, "machine": f"load average at the end {load[0]:.1f}/{load[1]:.1f}/"
                               f"{load[2]:.1f} on {os.cpu_count()} cores", "rows": rows}, indent=1, allow_nan=True))


def _q(xs: list[float], q: float) -> float:
    return float(np.quantile(xs, q)) if xs else math.nan


def table(rows: list[dict[str, Any]]) -> str:
    lines = ["| group | n | median | p90 | worst | ≤1.01 | ≤1.03 | ≤1.005 | median wall ms |",
             "|---|---|---|---|---|---|---|---|---|"]

    def line(name: str, rs: list[dict[str, Any]]) -> None:
        xs = [r["ratio"] for r in rs if r["ratio"] is not None]
        if not xs:
            return
        w = [r["wall_s"] * 1e3 for r in rs]
        share = lambda lim: f"{np.mean([x <= lim for x in xs]) * 100:.1f} %"
        lines.append(f"| {name} | {len(xs)} | {_q(xs, .5):.4f} | {_q(xs, .9):.4f} | {max(xs):.4f} | "
                     f"{share(1.01)} | {share(1.03)} | {share(1.005)} | {_q(w, .5):.0f} |")

    line("all", rows)
    for cls in CLASSES:
        line(cls, [r for r in rows if r["class"] == cls])
    for st in sorted({r["structure"] for r in rows}):
        line(st, [r for r in rows if r["structure"] == st])
    line("order ≤ 4", [r for r in rows if r["order"] <= 4])
    return "\n".join(lines)


STUDY = HERE / "quality_study.toml"
RUNS = ("baseline", "fast", "default", "thorough")


def cmd_report(a: argparse.Namespace) -> None:
    """bench/QUALITY.md: every stored run against the current references (ratios recomputed here)."""
    cases = {c["id"]: c for c in load_suite()}
    ref_path = reference_path(a, a.reference)
    refdoc = json.loads(ref_path.read_text())
    refs = {r["id"]: r for r in refdoc["references"]}
    ok = {k for k, r in refs.items() if r.get("feasible") and r.get("independent_ok")}
    L = ["# Quality suite: the tuner against independent reference optima", "",
         f"Suite: {len(cases)} plants (`bench/quality_suite.json`, `python bench/quality.py generate`, seed "
         f"{SUITE_SEED}); references for {len(refs)} of them (`{os.path.relpath(ref_path.resolve(), ROOT)}`, "
         f"`{refdoc['command']}`" + (f"; budgets {refdoc['mixed_budgets']}" if refdoc.get("mixed_budgets") else "")
         + f"), {len(ok)} feasible and verified twice (tuner.analyze and tests/reference.py); "
         f"{sum(1 for r in refs.values() if not r.get('feasible'))} with no feasible design found by the references, "
         f"{sum(1 for r in refs.values() if r.get('feasible') and not r.get('independent_ok'))} whose independent "
         "check disagreed (both excluded from the ratios).", "",
         f"Reference method: {refdoc['method']}. Spec: {spec_name(refdoc['spec'])}: {refdoc['spec']}.", "",
         "Ratio = the tuner's verified objective / the reference's (lower is better; < 1: the tuner beat the "
         "reference). A tune that does not meet the spec counts as ratio ∞.", ""]
    runs = a.runs.split(",") if a.runs else RUNS
    sfx = _suffix(a)
    docs = {n: json.loads((RESULTS / f"quality_{n}{sfx}.json").read_text()) for n in runs
            if (RESULTS / f"quality_{n}{sfx}.json").exists()}
    # every run is compared on the cases all of them tuned (and that have a verified reference)
    common = set.intersection(*({r["id"] for r in d["rows"]} for d in docs.values())) & ok if docs else set()
    L += [f"Every table below is over the same {len(common)} cases: those every run tuned and that have a "
          "verified reference.", ""]
    for name, doc in docs.items():
        rows = []
        for t in doc["rows"]:
            if t["id"] not in common:
                continue
            t = dict(t)
            t["ratio"] = ratio(t, refs.get(t["id"]))
            rows.append(t)
        xs = [r["ratio"] for r in rows if r["ratio"] is not None]
        L += [f"## {name}", "", f"`{doc['command']}` ({len(rows)} tunes; {len(xs)} with a verified reference; "
              f"{doc.get('machine', '')})", "", table(rows), ""]
        if xs:
            w4 = [r["wall_s"] * 1e3 for r in rows if r["order"] <= 4]
            L += [f"- within 1 %: {np.mean([x <= 1.01 for x in xs]) * 100:.1f} %; within 0.5 %: "
                  f"{np.mean([x <= 1.005 for x in xs]) * 100:.1f} %; within 3 %: "
                  f"{np.mean([x <= 1.03 for x in xs]) * 100:.1f} %; tuner better than the reference by > 1 %: "
                  f"{sum(x < 0.99 for x in xs)}; median wall (order ≤ 4): {_q(w4, .5):.0f} ms", ""]
            bad = sorted((r for r in rows if r["ratio"] is not None and r["ratio"] > 1.01), key=lambda r: -r["ratio"])
            if bad:
                L += ["Above 1 %:", "", "| case | structure | tuner | reference | ratio | stop |",
                      "|---|---|---|---|---|---|"]
                L += [f"| {r['id']} | {r['structure']} | {r['objective']:.5g} | {refs[r['id']]['objective']:.5g} | "
                      f"{r['ratio']:.4f} | {r['stop']} |" for r in bad]
                L.append("")
    out = Path(a.out) if a.out else HERE / f"QUALITY_TABLES{sfx.upper()}.md"
    out.write_text("\n".join(L) + "\n")
    print(f"-> {out}")


def study_toml(cases: list[dict[str, Any]], *, name: str = "quality", budget: float = 10.0, effort: str = "default",
               spec: dict[str, Any] | None = None) -> str:
    """The suite as a study file (``tuner study run``): one loop per case, the same plant, dt and structure."""
    lines = ["# The quality suite as a study (bench/quality.py study): one loop per case of bench/quality_suite.json.",
             "# Scale out: every worker, on this machine or another, runs",
             "#   tuner study run bench/quality_study.toml --storage postgresql+psycopg://USER@HOST:5432/DB",
             f'name = "{name}"', "seed = 0", f"time_budget_s = {budget:g}", f'effort = "{effort}"', ""]
    for c in cases:
        lines += ["[[loop]]", f'name = "{c["id"]}"',
                  f"plant = {{num = {json.dumps(c['num'])}, den = {json.dumps(c['den'])}}}",
                  f"delay = {c['delay_s']!r}", f"dt = {c['dt']!r}", f'structure = "{c["structure"]}"']
        if spec:
            lines.append("[loop.spec]")
            lines += [f"{k} = {json.dumps(v)}" for k, v in spec.items()]
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    g = sub.add_parser("generate", help="write bench/quality_suite.json")
    g.add_argument("--per-class", type=int, default=35)
    r = sub.add_parser("reference", help="compute the reference optima (resumable: done cases are kept)")
    r.add_argument("--evals", type=int, default=20000, help="batch evaluations per case over the four searches")
    r.add_argument("--defaults", action="store_true", help="the new defaults' references (Spec(): filter N <= 20, "
                   "the Nyquist filter floor, the noise budget); default out bench/quality_reference_defaults.json")
    r.add_argument("--spec", default="", help="Spec fields as JSON (default: the thesis spec, Spec.thesis())")
    r.add_argument("--out", default="", help="default bench/quality_reference.json (--defaults: "
                   "bench/quality_reference_defaults.json)")
    r.add_argument("--only", default="", help="comma-separated case ids")
    r.add_argument("--cap-s", type=float, default=0.0, help="stop starting new cases after this many seconds")
    r.add_argument("--fresh", action="store_true", help="recompute the cases already stored")
    r.add_argument("--case-cap-s", type=float, default=math.inf,
                   help="at most this many seconds per case (a quarter per search; slow loops)")
    ad = sub.add_parser("adopt", help="take another reference set's design where it verifies better for this spec")
    ad.add_argument("--defaults", action="store_true", help="adopt into bench/quality_reference_defaults.json")
    ad.add_argument("--spec", default="")
    ad.add_argument("--out", default="", help="the set adopted into (default: the spec's reference file)")
    ad.add_argument("--from", dest="source", required=True, help="the other reference set")
    u = sub.add_parser("run", help="tune every case and compare with the references")
    u.add_argument("--effort", default="default")
    u.add_argument("--seed", type=int, default=0)
    u.add_argument("--defaults", action="store_true", help="tune for the new defaults (Spec()) and compare with "
                   "bench/quality_reference_defaults.json; default out bench/results/quality_<effort>_defaults.json")
    u.add_argument("--spec", default="")
    u.add_argument("--reference", default="", help="default: the spec's reference file (see --defaults)")
    u.add_argument("--only", default="")
    u.add_argument("--out", default="", help="default bench/results/quality_<effort>[_defaults].json")
    u.add_argument("--budget", type=float, default=10.0)
    u.add_argument("--append", action="store_true", help="keep the stored run's rows, tune the missing cases")
    rp = sub.add_parser("report", help="bench/QUALITY.md from the stored runs and references")
    rp.add_argument("--defaults", action="store_true", help="the new defaults' runs (results/quality_<run>"
                    "_defaults.json) against bench/quality_reference_defaults.json; default out "
                    "bench/QUALITY_TABLES_DEFAULTS.md")
    rp.add_argument("--reference", default="", help="default: bench/quality_reference.json (--defaults: "
                    "bench/quality_reference_defaults.json)")
    rp.add_argument("--out", default="", help="default bench/QUALITY_TABLES.md (--defaults: "
                    "QUALITY_TABLES_DEFAULTS.md)")
    rp.add_argument("--runs", default="", help="comma-separated runs to compare (default: all stored)")
    s = sub.add_parser("study", help="write bench/quality_study.toml (the suite as a study)")
    s.add_argument("--out", default=str(STUDY))
    s.add_argument("--only", default="", help="comma-separated case ids (default: every case)")
    s.add_argument("--name", default="quality")
    s.add_argument("--effort", default="default")
    a = ap.parse_args()
    if a.cmd == "report":
        cmd_report(a)
    elif a.cmd == "study":
        only = set(a.only.split(",")) if a.only else None
        cases = [c for c in load_suite() if only is None or c["id"] in only]
        Path(a.out).write_text(study_toml(cases, name=a.name, effort=a.effort))
        print(f"{len(cases)} loops -> {a.out}")
    elif a.cmd == "generate":
        cases = generate(a.per_class)
        SUITE.write_text(json.dumps({"command": f"python bench/quality.py generate --per-class {a.per_class}",
                                     "seed": SUITE_SEED, "cases": cases}, indent=1))
        print(f"{len(cases)} cases -> {SUITE}")
    elif a.cmd == "reference":
        cmd_reference(a)
    elif a.cmd == "run":
        cmd_run(a)
    elif a.cmd == "adopt":
        cmd_adopt(a)


if __name__ == "__main__":
    main()
