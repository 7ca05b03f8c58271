"""Cascades: an outer loop tuned around a tuned inner closed loop.

The quadrotor's X position loop wraps the pitch loop (Y wraps roll)::

    r --> (+) --> Co(z) --theta_ref--> (+) --> Ci(z) --> ZOH --> Gi(s) --theta--> Go(s) --> x
           ^-x[k]                       ^-theta[k]

Both controllers run at the same ``dt``. :func:`outer_plant` gives the plant the outer
controller sees at the sample instants,

    P(z) = Ci(z) Z[Gi Go](z) / (1 + Ci(z) Z[Gi](z)),            Z[.] = ZOH equivalent at dt,

which is exact at the samples: the position integrates the continuous angle, which is
driven by the inner controller's staircase. (The thesis's ``T_i(z) Z[Go](z)`` holds the
angle constant between samples; it is used only when the inner plant is given in z,
where ``Z[Gi Go]`` does not exist.) The order is inner plant + inner controller + outer
plant, at most :data:`tuner.plant.MAX_ORDER`.

It is built in state space, never from the polynomial products above: the physical
state of the inner and outer plants in series, discretised exactly, with the inner loop
closed around it (a minimal realisation: the inner plant's modes appear once).

The composite plant is a sampled model only: there is no continuous plant whose ZOH
it is (the position between samples follows the inner loop's staircase, not the outer
controller's), so it is marked as having no continuous equivalent and the verifier
evaluates the outer loop at the sample instants. The position between samples is then
checked by :func:`simulate_cascade`, an exact sampled-data simulation of the whole
cascade on the continuous plants.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import linalg

from ..controllers import ControllerTF
from ..errors import InvalidPlantError
from ..loop import _discrete_loop
from ..lti import SS, series, zoh, zoh_fractional, zpk_from_ss
from ..plant import MAX_ORDER, Plant, delay_in_samples, make_plant
from ..tolerances import SAME_DT_RTOL
from .response import StepMetrics, StepResponse, step_metrics

__all__ = ["outer_plant", "outer_plants", "simulate_cascade", "CascadeResponse", "EXACT_NOTE", "HELD_NOTE",
           "SKIPPED_NOTE"]

EXACT_NOTE = "exact at the samples; position between samples from a sampled-data simulation of the whole cascade"
HELD_NOTE = "inner plant given in z: angle held between samples (thesis model), sample instants only"
SKIPPED_NOTE = ("exact at the samples; the between-samples simulation of the whole cascade did not run (it needs "
                "delay-free continuous plants, both controllers at one sample time and a stable loop): sample "
                "instants only")


def _plant_from_ss(sysd: SS, dt: float) -> Plant:
    """A discrete plant known by its realisation (no continuous equivalent: sample instants only)."""
    if sysd.n > MAX_ORDER:
        raise InvalidPlantError(
            f"cascade: the outer loop's plant would have order {sysd.n}, above the limit {MAX_ORDER}; "
            "use a lower-order inner controller or plant"
        )
    zk = zpk_from_ss(sysd, discrete=True)
    num = np.real(np.poly(zk.zeros)) * zk.gain if zk.zeros.size else np.array([zk.gain])
    den = np.real(np.poly(zk.poles)) if zk.poles.size else np.ones(1)
    p = make_plant(num, den, dt=dt, zpk=zk)
    p._cache["ss"] = sysd  # compute with the realisation itself
    p._cache["ct"] = None  # the position between samples is not a continuous plant's (module docstring)
    return p


def _with_input_delay(sys: SS, d: int) -> SS:
    """``sys`` driven by its input delayed by ``d`` samples (a shift register in front)."""
    if d == 0:
        return sys
    reg = SS(np.eye(d, k=-1), np.eye(d)[:, 0], np.eye(d)[d - 1], 0.0)
    return series(reg, sys)


def outer_plant(inner: Plant, controller: ControllerTF, outer: Plant) -> Plant:
    """The plant seen by an outer controller wrapped around ``controller`` on ``inner``.

    ``inner`` is the inner loop's plant, ``controller`` its tuned controller (at ``dt``),
    ``outer`` the plant from the inner loop's output to the outer output (e.g. ``9.81/s^2``).
    Returns a discrete :class:`~tuner.plant.Plant` at ``dt`` (see the module docstring), built in state
    space: for continuous plants the physical state of the inner and outer plants in series (ZOH at dt,
    exact), the inner loop closed around it; for plants given in z, the inner closed loop's output held
    into the outer plant.
    """
    dt = controller.dt
    if dt is None:
        raise InvalidPlantError("cascade: the inner controller must be discrete (give the inner loop a dt)")
    if outer.is_discrete and abs(outer.dt - dt) > SAME_DT_RTOL * dt:
        raise InvalidPlantError(f"cascade: outer plant is discrete at dt={outer.dt}, the loops run at dt={dt}")
    zi = inner.zoh(dt)
    di = delay_in_samples(zi.delay_s, dt)
    if inner.is_discrete or outer.is_discrete or outer.delay_s:
        # theta at the samples, held into the outer plant's ZOH (exact at the samples when the outer plant is
        # given in z; the thesis's model otherwise)
        cl = _discrete_loop(zi.ss(), controller.ss(), di, ref=_ref(controller))
        theta = SS(cl.A, cl.B[:, 0], cl.Cy, float(cl.Dy[0]))
        zo = outer.zoh(dt)
        sysd = series(theta, _with_input_delay(zo.ss(), delay_in_samples(zo.delay_s, dt)))
        return _plant_from_ss(sysd, dt)
    gi, go = inner.ss(), outer.ss()
    both = series(gi, go)  # states [inner x, outer x]; output: the outer plant's
    phi = zi.zoh_fraction  # an inner delay that is not whole samples: its fraction is one more state
    phys = zoh(both, dt) if not phi else zoh_fractional(both, dt, phi)
    # the inner loop feeds back the inner plant's output, C_i x_i + D_i u (with a fraction: the previous u)
    if phi:
        gth = SS(phys.A, phys.B, np.concatenate([gi.C, np.zeros(go.n), [gi.D]]), 0.0)
    else:
        gth = SS(phys.A, phys.B, np.concatenate([gi.C, np.zeros(go.n)]), gi.D)
    cl = _discrete_loop(gth, controller.ss(), di, ref=_ref(controller))
    n = phys.n
    # outer output = both.C x + both.D ua: the plant-state part of the closed loop, plus the plant input
    Cx = np.zeros(cl.A.shape[0])
    Cx[:n] = phys.C
    Cx = Cx + phys.D * cl.Ca
    sysd = SS(cl.A, cl.B[:, 0], Cx, float(phys.D * cl.Da[0]))
    return _plant_from_ss(sysd, dt)


def outer_plants(inners: list[Plant], controller: ControllerTF, outers: list[Plant]) -> list[Plant]:
    """Every combination of inner and outer plant (nominal first): the outer loop's plant set."""
    return [outer_plant(gi, controller, go) for gi in inners for go in outers]


@dataclass(frozen=True, eq=False)
class CascadeResponse:
    """Unit step on the outer reference, simulated on the continuous plants."""

    response: StepResponse  # y = outer output x(t) between samples, u = outer controller output
    inner_output: np.ndarray  # the inner plant's output (e.g. the angle) on the same grid
    metrics: StepMetrics

    def __repr__(self) -> str:
        from ..text import step_response_repr

        m = self.metrics
        return (f"CascadeResponse(overshoot {m.overshoot_pct:.3g} %, settling {m.settling_time_s:.3g} s;\n  "
                f"{step_response_repr(self.response)})")


def _ref(c: ControllerTF) -> SS | None:
    """A 2-DOF controller's reference path on its states (pid2), or None."""
    return c.ref_ss() if c.two_dof else None


def _mats(sys: SS) -> tuple[np.ndarray, ...]:
    """(A, B, C, D) as 2-D arrays (B a column, C a row)."""
    n = sys.n
    return (sys.A.reshape(n, n), sys.B.reshape(n, 1), sys.C.reshape(1, n), np.array([[sys.D]]))


def simulate_cascade(
    inner: Plant, inner_ctrl: ControllerTF, outer: Plant, outer_ctrl: ControllerTF, *, horizon_s: float,
    samples_per_dt: int = 20, band_pct: float = 2.0, y_final: float | None = None,
) -> CascadeResponse | None:
    """Exact sampled-data simulation of the cascade after a unit step on the outer reference.

    Both plants continuous and without delay (``None`` otherwise): the inner and outer plants
    in series are discretised with a ZOH at ``dt/samples_per_dt`` (exact for the staircase
    input), the controllers run at ``dt``. At the sample instants the output equals the
    outer loop's response on :func:`outer_plant`; between samples it is the true output.
    ``y_final`` is the closed loop's exact final value (the verifier's); default: the last sample.
    """
    dt = inner_ctrl.dt
    if dt is None or outer_ctrl.dt is None or abs(outer_ctrl.dt - dt) > SAME_DT_RTOL * dt:
        return None
    if inner.is_discrete or outer.is_discrete or inner.delay_s or outer.delay_s:
        return None
    Ai, Bi, Ci, Di = _mats(inner.ss())
    Ao, Bo, Co, Do = _mats(outer.ss())
    ni, no = Ai.shape[0], Ao.shape[0]
    A = np.block([[Ai, np.zeros((ni, no))], [Bo @ Ci, Ao]])
    B = np.vstack([Bi, Bo @ Di])
    Cth = np.hstack([Ci, np.zeros((1, no))])
    Cx = np.hstack([Do @ Ci, Co])
    Dth, Dx = Di, Do @ Di
    n = A.shape[0]
    N = int(samples_per_dt)
    h = dt / N
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n:] = A, B
    E = linalg.expm(M * h)
    Ah, Bh = E[:n, :n], E[:n, n:]
    # state after j fine steps within one sample, input held: x_j = Phi_j x0 + Gam_j u
    Phi = [np.eye(n)]
    Gam = [np.zeros((n, 1))]
    for _ in range(N):
        Phi.append(Ah @ Phi[-1])
        Gam.append(Ah @ Gam[-1] + Bh)
    Phi, Gam = np.array(Phi[:-1]), np.array(Gam[:-1])  # j = 0..N-1 within the sample
    Ad, Bd = Ah @ Phi[-1], Ah @ Gam[-1] + Bh  # one whole sample
    Aco, Bco, Cco, Dco = _mats(outer_ctrl.ss())
    Aci, Bci, Cci, Dci = _mats(inner_ctrl.ss())
    # 2-DOF controllers (pid2): the reference enters through their own path on the same states
    _, Bro, _, Dro = _mats(outer_ctrl.ref_ss())
    _, Bri, _, Dri = _mats(inner_ctrl.ref_ss())
    K = int(math.ceil(horizon_s / dt)) + 1
    # At sample k, with x the plants' state and xo, xi the controllers': position p = Cx x + Dx u, angle
    # th = Cth x + Dth u (a biproper plant feeds the held input through at the sample: the loop is algebraic there, as
    # outer_plant closes it); the outer controller's output, the inner loop's reference, ref = Cco xo + Dro r - Dco p;
    # u = Cci xi + Dri ref - Dci th (2-DOF: Dr, Br the reference path; 1-DOF: D, B); r = 1.
    # All of it is linear in z = [x; xo; xi]: u = (Uz z + u0) / den with den = 1 + Dri Dco Dx + Dci Dth (1 for
    # strictly proper plants), ref = Rz z + r0, z+ = F z + g, iterated once a sample (a matrix-vector product each;
    # the per-sample loop of separate products took 0.8 s on the quadrotor's x loop)
    nco, nci = Aco.shape[0], Aci.shape[0]
    zo, zi = slice(n, n + nco), slice(n + nco, n + nco + nci)
    dx, dth = float(Dx[0, 0]), float(Dth[0, 0])
    Rz = np.zeros((1, n + nco + nci))
    Rz[:, :n], Rz[:, zo] = -Dco @ Cx, Cco
    Uz = Dri @ Rz
    Uz[:, :n] -= Dci @ Cth
    Uz[:, zi] += Cci
    u0 = float((Dri @ Dro)[0, 0])
    r0 = float(Dro[0, 0])
    den = 1.0 + float((Dri @ Dco)[0, 0]) * dx + float(Dci[0, 0]) * dth  # (1 exactly for strictly proper plants)
    Uz, u0 = Uz / den, u0 / den
    Rz, r0 = Rz - float(Dco[0, 0]) * dx * Uz, r0 - float(Dco[0, 0]) * dx * u0
    F = np.zeros((n + nco + nci, n + nco + nci))
    F[:n] = Bd @ Uz
    F[:n, :n] += Ad
    F[zo, :n], F[zo, zo] = -Bco @ Cx, Aco
    F[zi] = Bri @ Rz
    F[zi, :n] -= Bci @ Cth
    F[zi, zi] += Aci
    g = np.zeros(n + nco + nci)
    g[:n], g[zo], g[zi] = (Bd * u0)[:, 0], Bro[:, 0], (Bri * r0)[:, 0]
    # the feedthrough of u into the fed-back p and th (none for strictly proper plants)
    F[zo] -= (Bco * dx) @ Uz
    F[zi] -= (Bci * dth) @ Uz
    g[zo] -= Bco[:, 0] * dx * u0
    g[zi] -= Bci[:, 0] * dth * u0
    Z = np.empty((K, n + nco + nci))
    z = np.zeros(n + nco + nci)
    for k in range(K):
        Z[k] = z
        z = F @ z + g
    X = Z[:, :n]
    ref = Z @ Rz[0] + r0
    u = Z @ Uz[0] + u0
    ys = X @ Cx[0] + dx * u
    # within sample k, u_k held: x_j = Phi_j x_k + Gam_j u_k (j = 0..N-1), so p_j = (Cx Phi_j) x_k + (Cx Gam_j) u_k
    y_fine = (X @ (Cx[0] @ Phi).T + np.outer(u, (Cx[0] @ Gam)[:, 0] + Dx[0, 0])).ravel()
    th_fine = (X @ (Cth[0] @ Phi).T + np.outer(u, (Cth[0] @ Gam)[:, 0] + Dth[0, 0])).ravel()
    u_fine = np.repeat(ref, N)
    t = np.arange(K * N) * h
    ts = np.arange(K) * dt
    yf = float(ys[-1]) if y_final is None else float(y_final)
    resp = StepResponse(t=t, y=y_fine, u=u_fine, t_samples=ts, y_samples=ys, y_final=yf, between_samples=True)
    return CascadeResponse(response=resp, inner_output=th_fine, metrics=step_metrics(resp, band_pct=band_pct))
