"""Closed-loop step response, evaluated on the continuous plant output.

* Continuous loop without delay: the closed loop is discretised with a ZOH at a
  fine step ``h``; for a step input this is exact at every fine instant.
* Sampled-data loop: the control sequence ``u[k]`` is exact from the discrete
  closed loop; the plant output between samples is the continuous plant driven
  by that staircase (ZOH at ``h = dt/N``, again exact at the fine instants).
* Continuous loop with delay: simulated as a sampled-data loop at a fine step
  ``h`` that divides the delay exactly, the controller discretised by Tustin
  (an approximation of order ``h^2``; ``h`` is horizon/4000 by default).

Metrics (unit step reference) follow the usual definitions, with "not defined"
as ``nan`` and "not settled within the horizon" as ``inf``:

* ``overshoot_pct``: ``100*(max y - y_final)/|y_final|``, at least 0;
* ``settling_time_s``: last time ``|y - y_final| > band*|y_final|`` (linear
  interpolation between fine instants); ``inf`` if still outside at the horizon;
* ``rise_time_s``: 10 % to 90 % of ``y_final``;
* ``steady_state_error``: ``1 - y_final`` from the closed-loop DC gain (exact);
* ``control_peak``: ``max |u|``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import control as ct
import numpy as np
from scipy import linalg, signal

from ..controllers import ControllerTF
from ..loop import Loop, build_loop
from ..plant import Plant

__all__ = ["StepResponse", "StepMetrics", "closed_loop_poles", "is_stable", "step_response", "step_metrics",
           "default_horizon"]

SAMPLES_PER_DT = 20
CONTINUOUS_POINTS = 4000
MAX_SAMPLES = 20000
STABILITY_STEPS_PER_DELAY = 40


@dataclass(frozen=True, eq=False)
class StepResponse:
    t: np.ndarray  # fine time grid of the plant output
    y: np.ndarray
    u: np.ndarray  # control signal on the same grid
    t_samples: np.ndarray | None  # sample instants (sampled-data loops)
    y_samples: np.ndarray | None
    y_final: float
    between_samples: bool  # False when only sample instants are known


@dataclass(frozen=True)
class StepMetrics:
    overshoot_pct: float
    settling_time_s: float
    rise_time_s: float
    steady_state_error: float
    control_peak: float


def _delay_pade_loop(loop: Loop) -> np.ndarray:
    """Characteristic polynomial with the delay replaced by a (5,5) Pade approximant."""
    pn, pd = ct.pade(loop.delay_s, 5)
    return np.polyadd(np.polymul(loop.ld, pd), np.polymul(loop.ln, pn))


def closed_loop_poles(loop: Loop) -> np.ndarray:
    """Closed-loop poles (s-plane for continuous loops, z-plane for discrete ones).

    Continuous loops with delay use the fine-step sampled-data model of the
    simulation (delay exact), mapped back with ``s = log(z)/h``.
    """
    if loop.delay_s:
        # the delay as STABILITY_STEPS_PER_DELAY whole steps (Tustin controller, ZOH plant): a
        # polynomial of modest degree, so this stays cheap inside the search
        fine = _fine_delay_loop(loop, loop.delay_s / STABILITY_STEPS_PER_DELAY * CONTINUOUS_POINTS)
        z = np.roots(fine.charpoly)
        z = z[np.abs(z) > 1e-300]
        return np.log(z.astype(complex)) / fine.dt
    return np.roots(loop.charpoly)


def is_stable(loop: Loop, poles: np.ndarray | None = None) -> bool:
    p = closed_loop_poles(loop) if poles is None else poles
    if p.size == 0:
        return True
    if loop.dt is None:
        return bool(np.max(p.real) < -1e-9 * max(1.0, np.max(np.abs(p))))
    return bool(np.max(np.abs(p)) < 1.0 - 1e-9)


def default_horizon(loop: Loop, poles: np.ndarray | None = None) -> float:
    """Simulation horizon from the slowest closed-loop pole (10 time constants), bounded.

    ``poles``: the loop's closed-loop poles if already computed (delay-free loops only)."""
    if loop.delay_s:
        p = np.roots(_delay_pade_loop(loop))
    else:
        p = np.roots(loop.charpoly) if poles is None else poles
    if loop.dt is None:
        sig = -p.real
        fast = max(np.max(np.abs(p)) if p.size else 1.0, 1e-6)
    else:
        mag = np.abs(p)
        sig = -np.log(np.maximum(mag, 1e-300)) / loop.dt
        fast = math.pi / loop.dt
    sig = sig[sig > 0] if p.size else np.array([1.0])
    smin = float(np.min(sig)) if sig.size else 1.0
    t = 10.0 / smin + 2.0 * loop.delay_s
    t = max(t, 20.0 / fast)
    if loop.dt is not None:
        t = max(t, 20 * loop.dt)
        t = min(t, MAX_SAMPLES * loop.dt)
    else:
        t = min(t, 1e4 * (1.0 / fast + loop.delay_s) + 1e-9)
    return t


def _zoh(num: np.ndarray, den: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    num, den = np.atleast_1d(num), np.atleast_1d(den)
    if den.size == 1:
        return num / den, np.ones(1)
    b, a, _ = signal.cont2discrete((num, den), h, method="zoh")
    b = np.atleast_1d(np.squeeze(b))
    return b, np.atleast_1d(a)


def _lfilt(num: np.ndarray, den: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Filter ``x`` through ``num(z)/den(z)`` (polynomials in z, proper)."""
    num = np.concatenate([np.zeros(den.size - num.size), num]) if num.size < den.size else num
    return signal.lfilter(num, den, x)


def _fine_delay_loop(loop: Loop, horizon: float) -> Loop:
    m = max(1, int(round(loop.delay_s / (horizon / CONTINUOUS_POINTS))))
    h = loop.delay_s / m
    cn, cden = np.atleast_1d(loop.controller.num), np.atleast_1d(loop.controller.den)
    if cden.size == 1:
        # a static gain: control's Tustin returns it as k(z-1)/(z-1), and that uncancelled
        # pole at z = 1 made every P-controlled delay loop look unstable
        ctrl = ControllerTF(num=cn / cden[0], den=np.ones(1), dt=h)
    else:
        cd = ct.sample_system(ct.tf(cn, cden), h, method="tustin")
        ctrl = ControllerTF(num=np.atleast_1d(np.squeeze(cd.num[0][0])), den=np.atleast_1d(np.squeeze(cd.den[0][0])),
                            dt=h)
    return build_loop(loop.plant, ctrl)


def step_response(loop: Loop, *, horizon_s: float | None = None, samples_per_dt: int = SAMPLES_PER_DT,
                  load: bool = False) -> StepResponse:
    """Unit step response of the closed loop (assumed stable; the caller checks).

    ``load=True``: response to a unit step load disturbance added at the plant input (the
    reference stays 0); ``u`` is then the plant's total input, controller output + disturbance.
    """
    T = default_horizon(loop) if horizon_s is None else float(horizon_s)
    if loop.dt is None and loop.delay_s:
        fine = _fine_delay_loop(loop, T)
        r = step_response(fine, horizon_s=T, samples_per_dt=1, load=load)
        return StepResponse(t=r.t, y=r.y, u=r.u, t_samples=None, y_samples=None, y_final=_dc(loop, load=load),
                            between_samples=True)
    yf = _dc(loop, load=load)
    cp = loop.charpoly
    pl = loop.plant
    cn, cd = loop.controller.num, loop.controller.den
    if loop.dt is None:
        h = T / CONTINUOUS_POINTS
        n = CONTINUOUS_POINTS + 1
        step = np.ones(n)
        by, ay = _zoh(np.polymul(pl.num, cd) if load else loop.ln, cp, h)
        bu, au = _zoh(np.polymul(cd if load else cn, pl.den), cp, h)
        t = np.arange(n) * h
        return StepResponse(t=t, y=_lfilt(by, ay, step), u=_lfilt(bu, au, step), t_samples=None,
                            y_samples=None, y_final=yf, between_samples=True)
    dt = loop.dt
    K = int(math.ceil(T / dt)) + 1
    step = np.ones(K)
    nu = np.polymul(cd if load else cn, np.concatenate([loop.plant_d.den, np.zeros(loop.delay_samples)]))
    u = _lfilt(nu, cp, step)
    ys = _lfilt(np.polymul(loop.plant_d.num, cd) if load else loop.ln, cp, step)
    ts = np.arange(K) * dt
    if loop.plant_ct is None or samples_per_dt <= 1:
        return StepResponse(t=ts, y=ys, u=u, t_samples=ts, y_samples=ys, y_final=yf,
                            between_samples=loop.plant_ct is not None)
    N = int(samples_per_dt)
    ua = np.concatenate([np.zeros(loop.delay_samples), u[: u.size - loop.delay_samples]]) if loop.delay_samples else u
    yfine = _between_samples(loop.plant_ct, dt, N, ua)
    t = np.arange(yfine.size) * (dt / N)
    return StepResponse(t=t, y=yfine, u=np.repeat(u, N), t_samples=ts, y_samples=ys, y_final=yf,
                        between_samples=True)


def _lifted(plant: Plant, dt: float, N: int) -> tuple[np.ndarray, ...]:
    """State-space ZOH model of ``plant`` at ``dt`` with the outputs at ``N`` points per sample:
    ``x[k+1] = Phi x[k] + Gam u[k]`` and ``y(t_k + j dt/N) = Cf[j] x[k] + Df[j] u[k]`` (exact)."""
    key = ("lifted", dt, N)
    if key not in plant._cache:
        sys = ct.tf2ss(ct.tf(plant.num, plant.den))
        A = np.atleast_2d(np.asarray(sys.A, float))
        B = np.asarray(sys.B, float).reshape(-1)
        C = np.asarray(sys.C, float).reshape(-1)
        D = float(np.asarray(sys.D, float).reshape(-1)[0])
        n = A.shape[0]
        M = np.zeros((n + 1, n + 1))
        M[:n, :n], M[:n, n] = A, B
        E1 = linalg.expm(M * (dt / N))
        Cf, Df, E = np.zeros((N, n)), np.zeros(N), np.eye(n + 1)
        for j in range(N):
            Cf[j], Df[j] = C @ E[:n, :n], C @ E[:n, n] + D
            E = E @ E1
        plant._cache[key] = (E[:n, :n], E[:n, n], Cf, Df)
    return plant._cache[key]


def _between_samples(plant: Plant, dt: float, N: int, u: np.ndarray) -> np.ndarray:
    """Output of the continuous ``plant`` driven through a ZOH by ``u[k]``, at N points per sample.

    A state recursion at the sample rate (numerically sound even for poles clustered at z = 1,
    where a high-order difference equation at dt/N is not), then a matrix product."""
    Phi, Gam, Cf, Df = _lifted(plant, dt, N)
    n = Phi.shape[0]
    X = np.zeros((u.size, n))
    x = np.zeros(n)
    for k in range(u.size):
        X[k] = x
        x = Phi @ x + Gam * u[k]
    return (X @ Cf.T + u[:, None] * Df[None, :]).ravel()


def _dc(loop: Loop, *, load: bool = False) -> float:
    x = 0.0 if loop.dt is None else 1.0
    cp = np.polyval(loop.charpoly, x)
    pnum = loop.plant.num if loop.plant_d is None else loop.plant_d.num
    num = np.polymul(pnum, loop.controller.den) if load else loop.ln
    return float(np.polyval(num, x) / cp) if cp != 0 else math.nan


def _cross(t: np.ndarray, y: np.ndarray, i: int, level: float) -> float:
    """Time where the segment (i, i+1) meets ``level`` (linear interpolation)."""
    y0, y1 = y[i], y[i + 1]
    if y1 == y0:
        return float(t[i + 1])
    return float(t[i] + (level - y0) / (y1 - y0) * (t[i + 1] - t[i]))


def step_metrics(resp: StepResponse, *, band_pct: float = 2.0) -> StepMetrics:
    t, y, yf = resp.t, resp.y, resp.y_final
    sse = 1.0 - yf
    cpk = float(np.max(np.abs(resp.u)))
    if not np.isfinite(yf) or yf == 0:
        return StepMetrics(math.nan, math.inf, math.nan, sse, cpk)
    yn = y / yf
    i = int(np.argmax(yn))
    peak = yn[i]
    if 0 < i < yn.size - 1:  # parabolic refinement of the peak between fine instants
        a, b, c = yn[i - 1], yn[i], yn[i + 1]
        den = a - 2 * b + c
        if den < 0:
            peak = b - 0.125 * (c - a) ** 2 / den
    os_pct = max(0.0, (peak - 1.0) * 100.0)
    band = band_pct / 100.0
    err = np.abs(yn - 1.0)
    out = np.flatnonzero(err > band)
    if out.size == 0:
        ts = 0.0
    elif out[-1] == yn.size - 1:
        ts = math.inf
    else:
        j = int(out[-1])
        level = 1.0 + band if yn[j] > 1.0 else 1.0 - band
        ts = _cross(t, yn, j, level)
    rise = math.nan
    i10 = np.flatnonzero(yn >= 0.1)
    i90 = np.flatnonzero(yn >= 0.9)
    if i10.size and i90.size:
        a10 = _cross(t, yn, i10[0] - 1, 0.1) if i10[0] > 0 else float(t[0])
        a90 = _cross(t, yn, i90[0] - 1, 0.9) if i90[0] > 0 else float(t[0])
        rise = a90 - a10
    return StepMetrics(os_pct, ts, rise, sse, cpk)
