"""The Åström–Hägglund benchmark batch of issue 10 (K. J. Åström, T. Hägglund, "Benchmark systems for PID
control", IFAC Digital Control: Past, Present and Future of PID Control, Terrassa, 2000).

    .venv/bin/python bench/ah_batch.py [--quick] [--budget 120] [--de-evals 6000]

Plants: 1/(s+1)^n (n = 1, 2, 3, 4, 8); 1/((1+s)(1+as)(1+a^2 s)(1+a^3 s)) (a = 0.1, 0.2, 0.5);
(1-as)/(s+1)^3 (a = 0.1, 0.2, 0.5, 1, 2, 5); e^-s/(1+sT) and e^-s/(1+sT)^2 (T = 0.1, 0.2, 0.5, 1, 2, 5, 10);
e^-s/s and e^-s/(s(1+sT)) (T = 0.1, 0.5, 1, 2).

(a) PI, continuous, objective ``iae`` (unit load step at the plant input), Ms <= 1.4 and Ms <= 2.0, no other
limit (PM 0, GM 0 dB, overshoot 100 %). Compared with a MIGO design computed here: maximise ki subject to
Ms <= limit, by brute force over a grid of 400 kp (then a bounded scalar search between the best grid
point's neighbours), for each kp the largest ki with max |S| <= limit on 200,000 log-spaced frequencies
(1e-4..1e4 rad/s, the delay as exp(-j w tau)). For a fixed kp and w, |1 + (kp + ki/(jw)) P(jw)| >= 1/Ms is a
quadratic inequality in ki, so the largest ki of the feasible interval that starts at ki = 0 is the
smallest positive lower root over the grid: what bisection on ki converges to, computed exactly on the
grid (bisection on ki is run at the optimum as a cross-check and reported). Both IAEs are simulated here
(bench/loadstep.py) on the same horizon, doubled until both responses have settled. Target: tuner's IAE
no worse than MIGO's (ratio <= 1).

(b) Spec() defaults (PM >= 60 deg, GM >= 6 dB, overshoot <= 10 %, zero steady-state error, minimum 2 %
settling time), structure pid, sampled at dt = Tar/20 (Tar = sum of the time constants + delay + RHP
zero's 1/|z|; for the integrating plants delay + T), adjusted so that the delay is a whole number of
samples. Where the tuner reports no verified design, scipy's differential evolution over
log10(Kp, Ki, Kd, Tf) with the library's verifier ``tuner.analyze`` as the judge looks for one
("feasible but reported infeasible" if it finds one).

Nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from loadstep import Rational, controller_freq, dense_grid, fmt, load_step, peaks, table, write_results  # noqa: E402

from tuner import Spec, analyze, controller_tf, make_plant, tune  # noqa: E402
from tuner.errors import TunerError  # noqa: E402

MS_LIMITS = (1.4, 2.0)
KP_GRID = 400
RATIO_TOL = 1e-3  # "no worse": tuner IAE <= MIGO IAE x (1 + this): the search's own convergence tolerance (0.1 %)


@dataclass(frozen=True)
class Bench:
    name: str
    plant: Rational
    tar: float  # the plant's time scale (average residence time)
    integrating: bool


def _poly(*factors) -> np.ndarray:
    out = np.array([1.0])
    for f in factors:
        out = np.polymul(out, f)
    return out


def batch() -> list[Bench]:
    B: list[Bench] = []
    for n in (1, 2, 3, 4, 8):
        B.append(Bench(f"1/(s+1)^{n}", Rational(np.array([1.0]), _poly(*[[1, 1]] * n)), float(n), False))
    for a in (0.1, 0.2, 0.5):
        B.append(Bench(f"4 lags a={a}", Rational(np.array([1.0]), _poly([1, 1], [a, 1], [a**2, 1], [a**3, 1])),
                       1 + a + a**2 + a**3, False))
    for a in (0.1, 0.2, 0.5, 1, 2, 5):
        B.append(Bench(f"(1-{a}s)/(s+1)^3", Rational(np.array([-a, 1.0]), _poly(*[[1, 1]] * 3)), 3.0 + a, False))
    for T in (0.1, 0.2, 0.5, 1, 2, 5, 10):
        B.append(Bench(f"e^-s/(1+{T}s)", Rational(np.array([1.0]), np.array([T, 1.0]), 1.0), 1.0 + T, False))
    for T in (0.1, 0.2, 0.5, 1, 2, 5, 10):
        B.append(Bench(f"e^-s/(1+{T}s)^2", Rational(np.array([1.0]), _poly([T, 1], [T, 1]), 1.0), 1.0 + 2 * T,
                       False))
    B.append(Bench("e^-s/s", Rational(np.array([1.0]), np.array([1.0, 0.0]), 1.0), 1.0, True))
    for T in (0.1, 0.5, 1, 2):
        B.append(Bench(f"e^-s/(s(1+{T}s))", Rational(np.array([1.0]), _poly([T, 1], [1, 0]), 1.0), 1.0 + T, True))
    return B


QUICK = ("1/(s+1)^2", "(1-1s)/(s+1)^3", "e^-s/(1+1s)", "e^-s/s")


def tplant(b: Bench):
    return make_plant(b.plant.num, b.plant.den, delay=b.plant.delay_s)


def solver_summary(res) -> dict:
    s = res.solver
    return {k: s[k] for k in ("stop", "budget_exhausted", "wall_time_s", "rounds", "nlp_solves", "nlp_solves_ok")}


# -- (a) MIGO, computed here -------------------------------------------------------------------------------

KP_UNBOUNDED = 1e3  # no Ms limit on kp (e.g. 1/(s+1)): the scan stops here and the row says "unbounded"


def _kp_range(P: np.ndarray, r: float, integrating: bool) -> tuple[float, float]:
    """kp interval around 0 where the P controller alone keeps |1 + kp P| >= r on the grid."""
    a2, re = np.abs(P) ** 2, P.real
    disc = re**2 - a2 * (1 - r * r)
    ok = disc > 0
    k1 = (-re[ok] - np.sqrt(disc[ok])) / a2[ok]
    k2 = (-re[ok] + np.sqrt(disc[ok])) / a2[ok]
    hi = float(np.min(k1[k1 > 0])) if np.any(k1 > 0) else KP_UNBOUNDED
    lo = float(np.max(k2[k2 < 0])) if np.any(k2 < 0) else -KP_UNBOUNDED
    return (hi * 1e-6 if integrating else lo), hi


def ki_max(P: np.ndarray, w: np.ndarray, kp: float, r: float) -> float:
    """Largest ki >= 0 such that |1 + (kp + ki/(jw)) P| >= r at every grid point, along ki from 0."""
    a = 1.0 + kp * P
    if np.min(np.abs(a)) < r:
        return 0.0
    b = P / (1j * w)
    b2 = np.abs(b) ** 2
    q = (a * np.conj(b)).real
    disc = q * q - b2 * (np.abs(a) ** 2 - r * r)
    sel = (disc > 0) & (q < 0)
    if not np.any(sel):
        return math.inf
    return float(np.min((-q[sel] - np.sqrt(disc[sel])) / b2[sel]))


def ms_of(P: np.ndarray, w: np.ndarray, kp: float, ki: float) -> float:
    return float(np.max(1.0 / np.abs(1.0 + (kp + ki / (1j * w)) * P)))


def migo(b: Bench, ms: float, P: np.ndarray, w: np.ndarray) -> dict:
    from scipy.optimize import minimize_scalar

    r = 1.0 / ms
    lo, hi = _kp_range(P, r, b.integrating)
    kps = np.linspace(lo, hi, KP_GRID + 2)[1:-1]
    kis = np.array([ki_max(P, w, k, r) for k in kps])
    kis[~np.isfinite(kis)] = 0.0
    i = int(np.argmax(kis))
    a_, z_ = kps[max(i - 1, 0)], kps[min(i + 1, len(kps) - 1)]
    opt = minimize_scalar(lambda k: -ki_max(P, w, k, r), bounds=(a_, z_), method="bounded",
                          options={"xatol": 1e-9 * max(1.0, abs(kps[i]))})
    kp, ki = (float(opt.x), -float(opt.fun)) if -opt.fun > kis[i] else (float(kps[i]), float(kis[i]))
    ki *= 1 - 1e-9  # just inside the boundary
    # cross-check: bisection on ki at this kp with max |S| computed directly
    blo, bhi = 0.0, 2 * ki
    for _ in range(60):
        mid = 0.5 * (blo + bhi)
        blo, bhi = (mid, bhi) if ms_of(P, w, kp, mid) <= ms else (blo, mid)
    return {"kp": kp, "ki": ki, "kp_range": [lo, hi], "unbounded": hi >= KP_UNBOUNDED,
            "ms_dense": ms_of(P, w, kp, ki), "ki_bisection": blo,
            "bisection_rel_diff": abs(blo - ki) / ki if ki > 0 else math.nan,
            "w_binding": float(w[np.argmax(1.0 / np.abs(1.0 + (kp + ki / (1j * w)) * P))])}


def iae_pair(b: Bench, designs: list[tuple[list[float], list[float]]]) -> tuple[list, float]:
    """Load-step IAEs of the designs on one horizon, doubled until every response has settled (max 32x)."""
    H = 40.0 * b.tar
    h = 5e-3 if b.plant.delay_s else max(1e-3, b.tar / 4000)
    for _ in range(6):
        sims = [load_step(b.plant, n, d, H, h=h) for n, d in designs]
        if all(s.settled for s in sims):
            break
        H *= 2
    return sims, H


def part_a(b: Bench, budget: float, seed: int) -> list[dict]:
    w = dense_grid(b.plant.den)
    P = b.plant.freq(w)
    rows = []
    for ms in MS_LIMITS:
        spec = Spec(phase_margin_min_deg=0, gain_margin_min_db=0, overshoot_max_pct=100, objective="iae", ms_max=ms)
        t0 = time.perf_counter()
        res = tune(tplant(b), structure="pi", spec=spec, seed=seed, time_budget_s=budget)
        wall = time.perf_counter() - t0
        m = migo(b, ms, P, w)
        kp, ki = res.gains["Kp"], res.gains["Ki"]
        sims, H = iae_pair(b, [([kp, ki], [1.0, 0.0]), ([m["kp"], m["ki"]], [1.0, 0.0])])
        ours, theirs = sims
        t_ms = peaks(P, controller_freq([kp, ki], [1.0, 0.0], None, w)).ms
        ratio = ours.iae / theirs.iae if theirs.iae > 0 else math.inf
        ok = bool(res.meets_spec and ours.settled and t_ms <= ms * (1 + 1e-6) and ratio <= 1 + RATIO_TOL)
        if m["unbounded"]:  # the Ms limit bounds no gain: IAE -> 0 as the gains grow; no optimum to compare
            ok = None
        rows.append({"plant": b.name, "ms_max": ms, "tuner": {"kp": kp, "ki": ki, "iae": ours.iae, "ms_dense": t_ms,
                                                             "settled": ours.settled, "meets_spec": res.meets_spec},
                     "migo": {**m, "iae": theirs.iae, "settled": theirs.settled}, "horizon_s": H, "ratio": ratio,
                     "target_met": ok, "solver": solver_summary(res), "tune_wall_s": wall})
        print(f"  (a) {b.name:22s} Ms<={ms}: tuner IAE {ours.iae:.4g}, MIGO {theirs.iae:.4g}, ratio {ratio:.4f} "
              f"({res.solver['stop']})", flush=True)
    return rows


# -- (b) default spec, pid, sampled -------------------------------------------------------------------------

def sample_time(b: Bench) -> float:
    dt = b.tar / 20
    if b.plant.delay_s:
        n = max(1, round(b.plant.delay_s / dt))
        return b.plant.delay_s / n
    return float(f"{dt:.3g}")


def _penalty(a) -> float:
    """Settling time if the spec is met, else 1e3 + the summed relative violations (unstable 1e4)."""
    if not a.metrics.stable:
        return 1e4
    if a.meets_spec:
        return float(a.metrics.settling_time_s)
    tot = 0.0
    for c in a.failing:
        req = c.required if isinstance(c.required, (int, float)) and not isinstance(c.required, bool) else 1.0
        v = c.violation / max(abs(float(req)), 1.0) if math.isfinite(c.violation) else 10.0
        tot += min(v, 10.0)
    return 1e3 + tot


def brute_force(b: Bench, dt: float, evals: int, seed: int, *, first_feasible: bool = True) -> dict:
    """Differential evolution over log10 of (Kp, Ki, Kd, Tf), judged by tuner.analyze; stops at the first
    design that meets the spec if ``first_feasible`` (the question is whether one exists), else minimises
    the settling time; at most ``evals`` evaluations."""
    from scipy.optimize import differential_evolution

    p = tplant(b)
    k = 1.0 / abs(float(np.polyval(b.plant.num, 0.0) / np.polyval(b.plant.den, 0.0))) if not b.integrating else 1.0
    box = [(math.log10(k) - 3, math.log10(k) + 2), (-4, 2), (-4, 2), (math.log10(dt) - 3, math.log10(10 * b.tar))]
    best = {"penalty": math.inf, "x": None, "n": 0}

    class Found(Exception):
        pass

    def f(v):
        best["n"] += 1
        g = dict(zip(("Kp", "Ki", "Kd", "Tf"), (10.0 ** np.asarray(v)).tolist()))
        try:
            a = analyze(p, controller_tf("pid", g, dt=dt), Spec())
        except TunerError:
            return 1e5
        pen = _penalty(a)
        if pen < best["penalty"]:
            best.update(penalty=pen, x=g, failing=[c.name for c in a.failing], settling=a.metrics.settling_time_s)
        if (a.meets_spec and first_feasible) or best["n"] >= evals:
            raise Found
        return pen

    t0 = time.perf_counter()
    try:
        differential_evolution(f, box, seed=seed, popsize=20, maxiter=10_000, tol=0, atol=0, polish=False,
                               init="sobol")
    except Found:
        pass
    return {"evaluations": best["n"], "feasible": best["penalty"] < 1e3, "best_penalty": best["penalty"],
            "gains": best["x"], "failing": best.get("failing"), "settling_s": best.get("settling"),
            "wall_s": time.perf_counter() - t0}


def part_b(b: Bench, budget: float, seed: int, de_evals: int) -> dict:
    dt = sample_time(b)
    res = tune(tplant(b), structure="pid", dt=dt, seed=seed, time_budget_s=budget)
    m = res.analyses[0].metrics
    row = {"plant": b.name, "dt": dt, "meets_spec": res.meets_spec, "settling_s": m.settling_time_s,
           "pm_deg": m.phase_margin_deg, "gm_db": m.gain_margin_db, "overshoot_pct": m.overshoot_pct,
           "failing": [c.name for c in res.analyses[0].failing], "gains": res.gains, "solver": solver_summary(res),
           "brute_force": None}
    if not res.meets_spec and de_evals > 0:
        row["brute_force"] = brute_force(b, dt, de_evals, seed)
    bf = row["brute_force"]
    row["feasible_but_reported_infeasible"] = bool(bf and bf["feasible"])
    print(f"  (b) {b.name:22s} dt={dt:.4g}: meets {res.meets_spec}, settling {m.settling_time_s:.4g} s "
          f"({res.solver['stop']})" + (f"; DE feasible={bf['feasible']} after {bf['evaluations']}" if bf else ""),
          flush=True)
    return row


def markdown(A: list[dict], Bs: list[dict], a: argparse.Namespace) -> str:
    L = ["# Åström–Hägglund benchmark batch (issue 10)", "",
         f"`bench/ah_batch.py` (seed {a.seed}, budget {a.budget:.0f} s per tune). See the script's docstring for "
         "the method.", "",
         "## (a) PI, continuous, objective iae, Ms limit only: tuner vs MIGO computed here", "",
         "IAE of a unit load step at the plant input, simulated here on one horizon per row (both responses "
         "settled); Ms on 200,000 points. Target: tuner IAE / MIGO IAE <= 1 "
         f"(+{RATIO_TOL:g}: the search's own convergence tolerance of 0.1 %; the simulation's error is below 1e-5) "
         "with the tuner's Ms within the limit.", ""]
    L.append(table(["plant", "Ms ≤", "tuner kp", "tuner ki", "tuner Ms", "tuner IAE", "MIGO kp", "MIGO ki",
                    "MIGO Ms", "MIGO IAE", "ratio", "target met", "horizon s", "stop", "budget exhausted",
                    "bisection Δki"],
                   [[r["plant"], r["ms_max"], r["tuner"]["kp"], r["tuner"]["ki"], r["tuner"]["ms_dense"],
                     r["tuner"]["iae"], r["migo"]["kp"], r["migo"]["ki"], r["migo"]["ms_dense"], r["migo"]["iae"],
                     r["ratio"], r["target_met"], r["horizon_s"], r["solver"]["stop"],
                     str(r["solver"]["budget_exhausted"]), r["migo"]["bisection_rel_diff"]] for r in A]))
    miss = [f"{r['plant']} (Ms ≤ {r['ms_max']}, ratio {r['ratio']:.4f})" for r in A if r["target_met"] is False]
    unb = [f"{r['plant']} (Ms ≤ {r['ms_max']})" for r in A if r["target_met"] is None]
    ratios = [r["ratio"] for r in A if r["target_met"] is not None and math.isfinite(r["ratio"])]
    L += ["", f"Rows: {len(A)}; compared {len(A) - len(unb)}; target met on {len(A) - len(unb) - len(miss)}; "
          f"ratio median {np.median(ratios):.4f}, min {min(ratios):.4f}, max {max(ratios):.4f}, "
          f"above 1: {sum(x > 1 for x in ratios)}." if ratios else "", "",
          "Missed: " + (", ".join(miss) if miss else "none") + ".", "",
          "Not compared (target met = —): " + (", ".join(unb) if unb else "none") + ": no Ms limit bounds kp "
          "(|1 + kp P| >= 1/Ms for every kp >= 0), so the IAE goes to 0 as the gains grow and neither side has an "
          f"optimum; MIGO stops at kp = {KP_UNBOUNDED:g}, the tuner at its gain box.", ""]
    L += ["## (b) Default spec, pid, sampled at dt = Tar/20 (delay a whole number of samples)", "",
          "Verified = `meets_spec` of the tuner's result (its verifier). Where the tuner has no verified design, "
          f"differential evolution (up to {a.de_evals} evaluations of `tuner.analyze`, log10 of Kp, Ki, Kd, Tf) "
          "looks for one.", ""]
    L.append(table(["plant", "dt", "verified", "settling s", "PM °", "GM dB", "overshoot %", "failing", "stop",
                    "budget exhausted", "wall s", "DE: feasible found", "DE evals", "DE settling s"],
                   [[r["plant"], r["dt"], r["meets_spec"], r["settling_s"], r["pm_deg"], r["gm_db"],
                     r["overshoot_pct"], ", ".join(r["failing"]) or "—", r["solver"]["stop"],
                     str(r["solver"]["budget_exhausted"]), r["solver"]["wall_time_s"],
                     r["brute_force"]["feasible"] if r["brute_force"] else "—",
                     r["brute_force"]["evaluations"] if r["brute_force"] else "—",
                     r["brute_force"]["settling_s"] if r["brute_force"] and r["brute_force"]["feasible"] else "—"]
                    for r in Bs]))
    fb = [r["plant"] for r in Bs if r["feasible_but_reported_infeasible"]]
    inf = [r["plant"] for r in Bs if not r["meets_spec"]]
    L += ["", f"Verified designs: {len(Bs) - len(inf)} of {len(Bs)}. Reported infeasible: "
          + (", ".join(inf) if inf else "none") + ". Feasible but reported infeasible: "
          + (", ".join(fb) if fb else "none") + ".", ""]
    return "\n".join(L) + "\n"


def check(a: argparse.Namespace, plants: list[Bench]) -> None:
    """Is the tuner's verified default-spec design near the best? A minimising DE judged by tuner.analyze."""
    rows = []
    for b in plants:
        print(f"[ah check] {b.name}", flush=True)
        row = part_b(b, a.budget, a.seed, 0)
        row["brute_force"] = brute_force(b, row["dt"], a.de_evals, a.seed, first_feasible=False)
        rows.append(row)
    L = ["# Åström–Hägglund batch (b): default-spec pid, tuner vs a minimising differential evolution", "",
         f"`bench/ah_batch.py --de-check ...` (seed {a.seed}, budget {a.budget:.0f} s, DE: {a.de_evals} evaluations "
         "of `tuner.analyze`, log10 of Kp, Ki, Kd, Tf). Settling times are the library verifier's.", ""]
    L.append(table(["plant", "dt", "tuner verified", "tuner settling s", "tuner stop", "DE feasible", "DE settling s",
                    "tuner / DE", "DE gains"],
                   [[r["plant"], r["dt"], r["meets_spec"], r["settling_s"], r["solver"]["stop"],
                     r["brute_force"]["feasible"], r["brute_force"]["settling_s"],
                     r["settling_s"] / r["brute_force"]["settling_s"] if r["brute_force"]["feasible"] else None,
                     ", ".join(f"{k} {fmt(v)}" for k, v in (r["brute_force"]["gains"] or {}).items())]
                    for r in rows]))
    md = "\n".join(L) + "\n"
    print(md)
    js, mdp = write_results("ah_batch_check", {"seed": a.seed, "budget_s": a.budget, "de_evals": a.de_evals,
                                               "rows": rows}, md, quick=a.quick)
    print(f"wrote {js} and {mdp}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help=f"plants {', '.join(QUICK)} only, short budgets")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--budget", type=float, default=120.0, help="time_budget_s of each tune")
    ap.add_argument("--de-evals", type=int, default=6000, help="brute-force evaluations per reported-infeasible plant")
    ap.add_argument("--only", default="ab", help="parts to run: a, b or ab")
    ap.add_argument("--de-check", nargs="+", metavar="PLANT", help="instead: part (b) on these plants with a "
                    "minimising differential evolution (--de-evals) beside the tuner; writes ah_batch_check.*")
    a = ap.parse_args()
    plants = batch()
    if a.de_check:
        if a.quick:
            a.budget, a.de_evals = min(a.budget, 15.0), min(a.de_evals, 300)
        check(a, [b for b in plants if b.name in a.de_check])
        return
    if a.quick:
        plants = [b for b in plants if b.name in QUICK]
        a.budget, a.de_evals = min(a.budget, 15.0), min(a.de_evals, 300)
    A, Bs = [], []
    for b in plants:
        print(f"[ah] {b.name}", flush=True)
        if "a" in a.only:
            A += part_a(b, a.budget, a.seed)
        if "b" in a.only:
            Bs.append(part_b(b, a.budget, a.seed, a.de_evals))
    md = markdown(A, Bs, a)
    print(md)
    js, mdp = write_results("ah_batch", {"seed": a.seed, "budget_s": a.budget, "de_evals": a.de_evals,
                                         "part_a": A, "part_b": Bs}, md, quick=a.quick)
    print(f"wrote {js} and {mdp}")


if __name__ == "__main__":
    main()
