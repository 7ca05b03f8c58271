"""Independent checks for the issue-10 benches (bench/lund.py, bench/ah_batch.py, bench/seeds.py).

Nothing here uses the tuner's verifier: the frequency responses are polynomials evaluated with numpy
(the delay as exp(-j w tau), exactly), the load-step response is simulated here (python-control for a
delay-free loop; a first-order-hold recurrence with the delay as a whole number of steps otherwise),
and the IAE is the trapezoidal integral of |y| on that grid.

Also the small output helpers the three scripts share (Markdown table, results files).
"""

from __future__ import annotations

import json
import math
import os
import platform
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"

#: the dense check grid: 200,000 log-spaced points from 1e-4 to 1e4 rad/s (see dense_grid)
DENSE_W = np.logspace(-4, 4, 200_000)


def dense_grid(*polys: Sequence[float], n: int = 200_000) -> np.ndarray:
    """DENSE_W, extended above 1e4 rad/s to 100 times the fastest root of the given polynomials (a
    controller's filter at 1/Tf = 25,000 rad/s has its |C S| peak above 1e4), same density per decade."""
    mags = [np.abs(np.roots(np.trim_zeros(np.asarray(p, float), "f"))) for p in polys if len(p) > 1]
    top = max([4.0] + [math.log10(100 * float(np.max(m))) for m in mags if m.size and np.max(m) > 0])
    return np.logspace(-4, top, int(n * (top + 4) / 8))


@dataclass(frozen=True)
class Rational:
    """num/den (highest power first) times exp(-s delay_s); continuous."""

    num: np.ndarray
    den: np.ndarray
    delay_s: float = 0.0

    def freq(self, w: np.ndarray) -> np.ndarray:
        s = 1j * w
        return np.polyval(self.num, s) / np.polyval(self.den, s) * np.exp(-s * self.delay_s)


def rational(num: Sequence[float], den: Sequence[float], delay_s: float = 0.0) -> Rational:
    return Rational(np.asarray(num, dtype=float), np.asarray(den, dtype=float), float(delay_s))


def controller_freq(num: Sequence[float], den: Sequence[float], dt: float | None, w: np.ndarray) -> np.ndarray:
    """C(j w) of a controller given by coefficients, continuous (dt None) or at dt (z = exp(j w dt))."""
    x = 1j * w if dt is None else np.exp(1j * w * dt)
    return np.polyval(np.asarray(num, float), x) / np.polyval(np.asarray(den, float), x)


@dataclass(frozen=True)
class Peaks:
    ms: float
    mt: float
    mks: float


def peaks(P: np.ndarray, C: np.ndarray) -> Peaks:
    """max |S|, |T|, |C S| over the grid on which P and C were evaluated."""
    with np.errstate(all="ignore"):
        S = 1.0 / (1.0 + P * C)
        vals = [np.abs(S), np.abs(P * C * S), np.abs(C * S)]
    return Peaks(*(float(np.max(np.where(np.isfinite(v), v, np.inf))) for v in vals))


@dataclass(frozen=True)
class LoadStep:
    t: np.ndarray
    y: np.ndarray
    iae: float
    settled: bool  # the tail is quiet: max |y| over the last 10 % <= 1e-4 of the peak (stable, horizon long enough)


def _ss(num: np.ndarray, den: np.ndarray):
    import control

    return control.ss(control.tf(list(num), list(den)))


def _foh(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact step of x' = A x + B w over h for w linear on the step: x+ = Phi x + G w0 + L (w1 - w0)."""
    from scipy.linalg import expm

    n = A.shape[0]
    M = np.zeros((n + 2, n + 2))
    M[:n, :n], M[:n, n] = A * h, B[:, 0] * h
    M[n, n + 1] = 1.0
    E = expm(M)
    return E[:n, :n], E[:n, n], E[:n, n + 1]


def load_step(plant: Rational, cnum: Sequence[float], cden: Sequence[float], horizon_s: float,
              h: float = 1e-3) -> LoadStep:
    """Plant output after a unit load step at the plant input (before the delay), controller in the
    feedback path u = -C y, continuous controller; IAE = integral of |y| over [0, horizon_s].

    Delay-free: y = P/(1 + P C) d, python-control's step response (exact at the grid points).
    With a delay tau: plant and controller stepped exactly (matrix exponential) at a step h with tau/h
    whole, their inputs linear over each step (the controller's output and the plant's output are
    continuous), the load held constant over each step (its jump at t = tau is on a grid point); the
    delay breaks the algebraic loop: the plant's input over step k uses the controller's output tau/h
    steps earlier. Error O(h^2).
    """
    import control

    cnum, cden = np.asarray(cnum, float), np.asarray(cden, float)
    if plant.delay_s == 0.0:
        n = int(math.ceil(horizon_s / h))
        t = np.linspace(0.0, horizon_s, n + 1)
        g = control.feedback(_ss(plant.num, plant.den), _ss(cnum, cden))
        y = np.asarray(control.step_response(g, T=t).outputs, dtype=float).reshape(-1)
    else:
        d = max(1, int(round(plant.delay_s / h)))
        h = plant.delay_s / d
        n = int(math.ceil(horizon_s / h))
        t = np.arange(n + 1) * h
        p, c = _ss(plant.num, plant.den), _ss(cnum, cden)
        Pp, Gp, Lp = _foh(np.asarray(p.A), np.asarray(p.B), h)
        Pc, Gc, Lc = _foh(np.asarray(c.A), np.asarray(c.B), h)
        Cp, Dp = np.asarray(p.C)[0], float(np.asarray(p.D)[0, 0])
        Cc, Dc = np.asarray(c.C)[0], float(np.asarray(c.D)[0, 0])
        xp, xc = np.zeros(Pp.shape[0]), np.zeros(Pc.shape[0])
        u, y = np.zeros(n + 1), np.zeros(n + 1)
        for k in range(n):
            u0 = u[k - d] if k >= d else 0.0  # the controller's output, delayed, at both ends of the step
            u1 = u[k + 1 - d] if k + 1 >= d else 0.0
            load0, load1 = float(k >= d), float(k + 1 >= d)  # the load over the step and just after it
            xp = Pp @ xp + Gp * (u0 + load0) + Lp * (u1 - u0)
            y[k + 1] = Cp @ xp + Dp * (u1 + load1)
            xc = Pc @ xc - Gc * y[k] - Lc * (y[k + 1] - y[k])
            u[k + 1] = Cc @ xc - Dc * y[k + 1]
    a = np.abs(y)
    iae = float(np.trapezoid(a, t)) if hasattr(np, "trapezoid") else float(np.trapz(a, t))
    peak = float(np.max(a)) if a.size else 0.0
    tail = a[int(0.9 * a.size):]
    settled = bool(np.all(np.isfinite(a)) and peak > 0 and float(np.max(tail)) <= 1e-4 * peak)
    return LoadStep(t, y, iae, settled)


# -- output ------------------------------------------------------------------------------------------------

def fmt(x: Any, d: int = 4) -> str:
    if x is None:
        return "—"
    if isinstance(x, bool):
        return "yes" if x else "**no**"
    if isinstance(x, str):
        return x
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    x = float(x)
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "∞" if x > 0 else "-∞"
    if x != 0 and (abs(x) < 10 ** -(d - 1) or abs(x) >= 1e5):
        return f"{x:.{d - 1}e}"
    return f"{x:.{d}g}"


def table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(fmt(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def machine() -> dict[str, str]:
    import casadi
    import control
    import scipy

    return {"python": platform.python_version(), "cores": str(os.cpu_count()), "numpy": np.__version__,
            "scipy": scipy.__version__, "control": control.__version__, "casadi": casadi.__version__,
            "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        x = float(x)
        return x if math.isfinite(x) else ("NaN" if math.isnan(x) else ("Infinity" if x > 0 else "-Infinity"))
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def write_results(name: str, data: dict[str, Any], markdown: str, *, quick: bool) -> tuple[Path, Path]:
    """bench/results/<name>.json and .md (``<name>.quick.*`` for a --quick run, so a smoke run never
    overwrites the full one)."""
    RESULTS.mkdir(exist_ok=True)
    stem = f"{name}.quick" if quick else name
    js, md = RESULTS / f"{stem}.json", RESULTS / f"{stem}.md"
    js.write_text(json.dumps(_jsonable({"machine": machine(), **data}), indent=1) + "\n")
    md.write_text(markdown)
    return js, md
