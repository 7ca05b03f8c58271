"""Closed-loop step responses, evaluated on the continuous plant output, and closed-loop poles.

Everything runs on the closed loop's state-space model (:meth:`tuner.loop.Loop.closed_loop`),
built from the cascade realisations of plant and controller; no characteristic polynomial is
expanded and no high-order difference equation is run.

* Sampled-data loop: the closed-loop state recursion at ``dt`` is exact at the samples; the plant
  output between samples is ``y(t_k + j dt/N) = Cf[j] x_k + Df[j] u_k`` from the continuous
  plant's realisation in the same coordinates (exact at the ``N`` points per sample; a delay that
  is not whole samples included: the held input switches ``phi`` after each sample).
* Continuous loop without delay: the closed loop discretised exactly (matrix exponential) at a
  fine step ``h``; exact at every fine instant for a step input.
* Continuous loop with delay: a sampled model at a fine step ``h`` (plant: exact ZOH with the delay
  on a shifted grid; controller: Tustin, an approximation of order ``h^2``; ``h`` is horizon/4000).
  Its closed-loop poles come from the same model at 40 steps per delay, the rightmost ones then
  refined by Newton's method on the exact characteristic equation ``1 + C(s) G(s) e^{-s tau} = 0``.

Metrics (unit step reference) follow the usual definitions, with "not defined"
as ``nan`` and "not settled within the horizon" as ``inf``:

* ``overshoot_pct``: ``100*(max y - y_final)/|y_final|``, at least 0;
* ``settling_time_s``: last time ``|y - y_final| > band*|y_final|`` (linear
  interpolation between fine instants); ``inf`` if still outside at the horizon;
* ``rise_time_s``: 10 % to 90 % of ``y_final``;
* ``steady_state_error``: ``1 - y_final`` from the closed loop's exact steady state;
* ``control_peak``: ``max |u|`` of the controller's output.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import linalg

from ..errors import InvalidPlantError
from ..loop import FineDelayLoop, Loop, _continuous_loop
from ..lti import lifted_outputs, switch_output
from ..tolerances import ROOT_POLISH_RTOL, SAMPLE_FRACTION_TOL, STABILITY_MARGIN

__all__ = ["StepResponse", "StepMetrics", "closed_loop_poles", "is_stable", "stability", "step_response",
           "step_metrics", "default_horizon", "steady_state", "lifted"]

SAMPLES_PER_DT = 20
CONTINUOUS_POINTS = 4000
MAX_SAMPLES = 20000
STABILITY_STEPS_PER_DELAY = 40


@dataclass(frozen=True, eq=False)
class StepResponse:
    """The unit reference step of a loop: the plant output ``y`` and control ``u`` on a fine grid ``t``
    (between samples for a sampled-data loop), the sample instants, the final value."""

    t: np.ndarray  # fine time grid of the plant output
    y: np.ndarray
    u: np.ndarray  # control signal on the same grid
    t_samples: np.ndarray | None  # sample instants (sampled-data loops)
    y_samples: np.ndarray | None
    y_final: float
    between_samples: bool  # False when only sample instants are known
    # instants where the output has a corner other than the sample instants (a fractional delay's input switch at
    # t_k + phi): in the grid t, and never the centre of a parabolic peak refinement
    corners: np.ndarray | None = None

    def __repr__(self) -> str:
        from ..text import step_response_repr

        return step_response_repr(self)


@dataclass(frozen=True)
class StepMetrics:
    """Overshoot (%), settling time into the band (s), 10-90 % rise time (s), steady-state error and peak |u|."""

    overshoot_pct: float
    settling_time_s: float
    rise_time_s: float
    steady_state_error: float
    control_peak: float


# -- poles and stability -------------------------------------------------------------------------

def _delay_characteristic(loop: Loop, s: np.ndarray) -> np.ndarray:
    """The characteristic function ``prod(s - p) (1 + L(s))`` of a continuous loop with delay, from the
    factored forms (``p``: every open-loop pole; finite everywhere, zero at the closed-loop poles)."""
    zc, zg = loop.controller.zpk, loop.plant.zpk
    poles = np.concatenate([zc.poles, zg.poles])
    zeros = np.concatenate([zc.zeros, zg.zeros])
    s = np.asarray(s, dtype=complex)
    dp = np.ones_like(s)
    for p in poles:
        dp = dp * (s - p)
    nz = np.ones_like(s) * zc.gain * zg.gain
    for z in zeros:
        nz = nz * (s - z)
    return dp + nz * np.exp(-s * loop.delay_s)


def _refine_delay_roots(loop: Loop, roots: np.ndarray, count: int = 6) -> np.ndarray:
    """Newton on the exact characteristic equation for the rightmost ``count`` approximate roots."""
    roots = np.asarray(roots, dtype=complex)
    order = np.argsort(-roots.real)
    out = roots.copy()
    for i in order[:count]:
        s = roots[i]
        for _ in range(30):
            with np.errstate(over="ignore", invalid="ignore"):  # e^{-s tau} beyond double range: no step (below)
                f = _delay_characteristic(loop, np.array([s]))[0]
                ds = 1e-7 * max(1.0, abs(s))
                df = (_delay_characteristic(loop, np.array([s + ds]))[0] - f) / ds
            if not np.isfinite(df) or df == 0:
                break
            step = f / df
            s = s - step
            if abs(step) < ROOT_POLISH_RTOL * max(1.0, abs(s)):
                break
        if np.isfinite(s) and abs(s - roots[i]) < 0.1 * max(1.0, abs(roots[i])):
            out[i] = s
    return out


def closed_loop_poles(loop: Loop) -> np.ndarray:
    """Closed-loop poles (s-plane for continuous loops, z-plane for discrete ones): the eigenvalues of the
    closed-loop state-space model. Continuous loops with delay: see the module docstring."""
    if loop.delay_s:
        h = loop.delay_s / STABILITY_STEPS_PER_DELAY
        Ad = loop.closed_loop(h).dense().A
        if not np.all(np.isfinite(Ad)):
            raise InvalidPlantError(
                f"the loop's dynamics span too many decades to discretise at the delay's step ({h:g} s): its "
                "fastest pole overflows the matrix exponential; rescale the plant, or model the fast pole as "
                "static", field="plant")
        z = np.linalg.eigvals(Ad)
        z = z[np.abs(z) > 1e-300]
        return _refine_delay_roots(loop, np.log(z.astype(complex)) / h)
    A = loop.closed_loop().A
    return np.linalg.eigvals(A) if A.size else np.zeros(0, complex)


def stability(loop: Loop, poles: np.ndarray | None = None) -> bool | None:
    """``True`` stable, ``False`` unstable (or marginal), ``None`` when double precision cannot tell.

    Each pole must be inside by ``STABILITY_MARGIN * max(1, |p|)`` (``tuner.tolerances``; its own
    magnitude: a pole at -1 beside one at -1e10 is as stable as alone), and by the precision of the
    eigenvalues, ``1e3 eps ||A||`` of the
    balanced closed-loop matrix. A pole within that precision of the boundary but clear of the
    ``STABILITY_MARGIN`` band is undecidable (``None``): the loop's dynamics span too many decades (a gain of
    1e150 on 1/(s+1) with integral action puts poles at -1 and -1e150).
    """
    p = closed_loop_poles(loop) if poles is None else poles
    if p.size == 0:
        return True
    if loop.dt is None:
        margin, own = -p.real, STABILITY_MARGIN * np.maximum(1.0, np.abs(p))
    else:
        margin, own = 1.0 - np.abs(p), np.full(p.size, STABILITY_MARGIN)
    prec = _eig_precision(loop)
    if np.all(margin > np.maximum(own, prec)):
        return True
    if np.any(margin < -np.maximum(own, prec)):
        return False
    undecided = (np.abs(margin) <= prec) & (prec > own)
    if np.any((np.abs(margin) <= own) & ~undecided):  # marginal, and precision can tell
        return False
    return None


def _eig_precision(loop: Loop) -> float:
    """Absolute accuracy of the closed-loop eigenvalues: ``1e3 eps ||A||_1`` of the balanced matrix (the
    delay model's poles are refined on the exact equation: their own tolerance applies)."""
    if loop.delay_s:
        return 0.0
    key = "eig_precision"
    if key not in loop._cache:
        A = loop.closed_loop().A
        if A.size == 0:
            prec = 0.0
        else:
            with np.errstate(all="ignore"):
                Ab = linalg.matrix_balance(A, permute=False)[0]
                prec = float(1e3 * np.finfo(float).eps * np.max(np.sum(np.abs(Ab), axis=0)))
        loop._cache[key] = prec if math.isfinite(prec) else math.inf
    return loop._cache[key]


def is_stable(loop: Loop, poles: np.ndarray | None = None) -> bool:
    """Stable for certain (:func:`stability` is ``True``); an undecidable loop is not."""
    return stability(loop, poles) is True


def default_horizon(loop: Loop, poles: np.ndarray | None = None) -> float:
    """Simulation horizon from the slowest closed-loop pole (10 time constants), bounded."""
    p = closed_loop_poles(loop) if poles is None else poles
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


def steady_state(loop: Loop, *, load: bool = False) -> tuple[float, float]:
    """Exact steady state ``(y, u)`` after a unit step on the reference (or the load), stable loops."""
    inp = 1 if load else 0
    if loop.dt is None and loop.delay_s:  # e^{-s tau} = 1 at s = 0: the delay-free loop's steady state
        c = loop.controller
        return _continuous_loop(loop.plant.ss(), c.ss(), ref=c.ref_ss() if c.two_dof else None).dc(inp)
    return loop.closed_loop().dc(inp)


# -- simulation ----------------------------------------------------------------------------------

def _run(A: np.ndarray, b: np.ndarray, K: int) -> np.ndarray:
    """States z_0 = 0, z_{k+1} = A z_k + b for k < K (a unit step input), as a (K, n) array.

    In blocks of ``M`` (about sqrt(K)) states: ``z_{k0+j} = A^j z_{k0} + s_j`` (``s_j`` the states from zero, j < M),
    the powers ``A^j`` and ``s_j`` built once by the recursion itself, then one matrix-vector product per block
    instead of one per state. Each state is at most ``M`` steps of the recursion from the previous block's start:
    its rounding is that of stepping (no eigen-decomposition, no powers by squaring), and the block's start
    ``z_{k0+M} = A^M z_{k0} + s_M`` carries the recursion on."""
    n = A.shape[0]
    Z = np.zeros((K, n))
    if K <= 1 or n == 0:
        return Z
    M = max(1, min(K, math.isqrt(K - 1) + 1))
    P = np.empty((M, n, n))  # A^j
    S = np.zeros((M, n))  # s_j: the states from z_0 = 0
    P[0] = np.eye(n)
    for j in range(1, M):
        P[j] = A @ P[j - 1]
        S[j] = A @ S[j - 1] + b
    AM, sM = A @ P[M - 1], A @ S[M - 1] + b
    Q = P.reshape(M * n, n)
    z = np.zeros(n)
    for k0 in range(0, K, M):
        m = min(M, K - k0)
        Z[k0:k0 + m] = (Q[:m * n] @ z).reshape(m, n) + S[:m]
        z = AM @ z + sM
    return Z


def lifted(loop: Loop, N: int) -> tuple[np.ndarray, np.ndarray]:
    """``Cf`` (N, n), ``Df`` (N): the continuous plant's output at ``t_k + j dt/N`` from the ZOH plant's state
    at t_k and its held input (the realisation of ``loop.plant_ct``, the coordinates of the ZOH plant; with a
    fractional delay ``phi`` the ZOH plant's extra state is the previous input, acting until ``t_k + phi``,
    :func:`tuner.lti.lifted_outputs`)."""
    phi = loop.plant_d.zoh_fraction if loop.plant_d is not None else 0.0
    key = ("lifted", loop.dt, N, phi)
    pct = loop.plant_ct
    if key not in pct._cache:
        pct._cache[key] = lifted_outputs(pct.ss(), loop.dt, N, phi)
    return pct._cache[key]




def lifted_with_switch(loop: Loop, N: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float | None]:
    """:func:`lifted` with, for a fractional delay ``phi`` off the grid, one more row at ``t_k + phi`` where the
    plant's delayed input switches (the output's corner, where its peak can be; :func:`tuner.lti.switch_output`):
    ``(Cf, Df, offsets, phi)``, ``offsets`` the rows' instants within a sample, ``phi`` None without a switch row.
    The verifier's step response and the search's batch both use it."""
    Cf, Df = lifted(loop, N)
    dt = loop.dt
    offsets = np.arange(N) * (dt / N)
    phi = loop.plant_d.zoh_fraction if loop.plant_d is not None else 0.0
    if not (phi > 0 and abs(phi * N / dt - round(phi * N / dt)) > SAMPLE_FRACTION_TOL):
        return Cf, Df, offsets, None
    j = int(np.searchsorted(offsets, phi))
    return (np.insert(Cf, j, switch_output(loop.plant_ct.ss(), phi), axis=0), np.insert(Df, j, 0.0),
            np.insert(offsets, j, phi), phi)


def _simulate_fine_delay(fl: FineDelayLoop, K: int, inp: int) -> tuple[np.ndarray, np.ndarray]:
    """Output and controller output of the sampled delay model over K steps, with a ring buffer."""
    g, c, m = fl.plant, fl.ctrl, fl.m
    cr = fl.ctrl_r if fl.ctrl_r is not None else c  # 2-DOF: the reference path on the same states
    r, w = (1.0, 0.0) if inp == 0 else (0.0, 1.0)
    buf = np.zeros(m + 1)  # buf[(head + j) % (m+1)] = v[k-1-j]
    head = 0
    x, xc = np.zeros(g.n), np.zeros(c.n)
    y, u = np.zeros(K), np.zeros(K)
    nb = m + 1
    for k in range(K):
        held = buf[(head + (m - 1 if fl.f == 0.0 else m)) % nb]
        yk = g.C @ x + g.D * held
        e = r - yk
        uk = c.C @ xc + (c.D * e if fl.ctrl_r is None else cr.D * r - c.D * yk)
        v = uk + w
        old = buf[(head + m) % nb]
        new = buf[(head + m - 1) % nb] if m >= 1 else v
        x = fl.Phi @ x + fl.G_old * old + fl.G_new * new
        xc = c.A @ xc + (c.B * e if fl.ctrl_r is None else cr.B * r - c.B * yk)
        head = (head - 1) % nb
        buf[head] = v
        y[k], u[k] = yk, uk
    return y, u


def step_response(loop: Loop, *, horizon_s: float | None = None, samples_per_dt: int = SAMPLES_PER_DT,
                  load: bool = False) -> StepResponse:
    """Unit step response of the closed loop (assumed stable; the caller checks).

    ``load=True``: response to a unit step load disturbance added at the plant input (the
    reference stays 0); ``u`` is then the controller's output.
    """
    T = default_horizon(loop) if horizon_s is None else float(horizon_s)
    inp = 1 if load else 0
    yf = steady_state(loop, load=load)[0]
    if loop.dt is None:
        h = T / CONTINUOUS_POINTS
        K = CONTINUOUS_POINTS + 1
        t = np.arange(K) * h
        if loop.delay_s:
            y, u = _simulate_fine_delay(loop.closed_loop(h), K, inp)
        else:
            cl = loop.closed_loop()
            n = cl.A.shape[0]
            M = np.zeros((n + 1, n + 1))
            M[:n, :n], M[:n, n] = cl.A, cl.B[:, inp]
            E = linalg.expm(M * h)
            Z = _run(E[:n, :n], E[:n, n], K)
            y, u = Z @ cl.Cy + cl.Dy[inp], Z @ cl.Cu + cl.Du[inp]
        return StepResponse(t=t, y=y, u=u, t_samples=None, y_samples=None, y_final=yf, between_samples=True)
    dt = loop.dt
    cl = loop.closed_loop()
    K = int(math.ceil(T / dt)) + 1
    Z = _run(cl.A, cl.B[:, inp], K)
    ys = Z @ cl.Cy + cl.Dy[inp]
    u = Z @ cl.Cu + cl.Du[inp]
    ts = np.arange(K) * dt
    if loop.plant_ct is None or samples_per_dt <= 1:
        return StepResponse(t=ts, y=ys, u=u, t_samples=ts, y_samples=ys, y_final=yf,
                            between_samples=loop.plant_ct is not None)
    N = int(samples_per_dt)
    # (a fractional delay's input switch is a row too: a peak there missed by 4e-5 of the step put a settling time
    # 35 s early)
    Cf, Df, offsets, phi = lifted_with_switch(loop, N)
    ua = Z @ cl.Ca + cl.Da[inp]  # the plant's input over each sample
    yfine = (Z[:, :cl.n_plant] @ Cf.T + ua[:, None] * Df[None, :]).ravel()
    t = (ts[:, None] + offsets[None, :]).ravel()
    ufine = np.repeat(u, offsets.size)
    corners = None if phi is None else ts + phi
    return StepResponse(t=t, y=yfine, u=ufine, t_samples=ts, y_samples=ys, y_final=yf, between_samples=True,
                        corners=corners)


def _cross(t: np.ndarray, y: np.ndarray, i: int, level: float) -> float:
    """Time where the segment (i, i+1) meets ``level`` (linear interpolation)."""
    y0, y1 = y[i], y[i + 1]
    if y1 == y0:
        return float(t[i + 1])
    return float(t[i] + (level - y0) / (y1 - y0) * (t[i + 1] - t[i]))


def _at_sample(resp: StepResponse, i: int) -> bool:
    """Whether fine instant ``i`` is a sample instant of a sampled-data loop: there the held input jumps and
    the output has a corner, where a parabola through the neighbours over-estimates the peak (the yaw
    pid_z design peaking at the first sample: 1.12 % by the parabola, 0.719 % exactly)."""
    ts = resp.t_samples
    if ts is None or len(ts) < 2 or not resp.between_samples:
        return False
    if _at_corner(resp, i):
        return True
    dt = float(ts[1] - ts[0])
    k = round(float(resp.t[i] - ts[0]) / dt)
    return abs(float(resp.t[i]) - (float(ts[0]) + k * dt)) <= 1e-9 * max(dt, 1.0)


def _at_corner(resp: StepResponse, i: int) -> bool:
    """Whether fine instant ``i`` is one of ``resp.corners`` (a fractional delay's input switch): the grid is not
    equally spaced around it, and a parabola through it is no refinement."""
    if resp.corners is None or resp.t_samples is None or len(resp.t_samples) < 2:
        return False
    dt = float(resp.t_samples[1] - resp.t_samples[0])
    return bool(np.any(np.abs(resp.corners - resp.t[i]) <= 1e-9 * max(dt, 1.0)))


def step_metrics(resp: StepResponse, *, band_pct: float = 2.0) -> StepMetrics:
    """The step metrics of ``resp`` (see the module): overshoot, settling into ``band_pct`` % of the final value,
    rise, steady-state error, peak |u|."""
    t, y, yf = resp.t, resp.y, resp.y_final
    sse = 1.0 - yf
    cpk = float(np.max(np.abs(resp.u)))
    if not np.isfinite(yf) or yf == 0:
        return StepMetrics(math.nan, math.inf, math.nan, sse, cpk)
    yn = y / yf
    i = int(np.argmax(yn))
    peak = yn[i]
    if 0 < i < yn.size - 1 and not _at_sample(resp, i) and not _at_corner(resp, i - 1) and \
            not _at_corner(resp, i + 1):  # parabolic refinement of the peak between equally spaced fine instants
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
