"""The feedback loop under analysis: plant + controller, continuous or sampled-data.

Unity negative feedback, controller in the forward path::

    r --> (+) --> C --> [ZOH] --> G (with delay) --+--> y
           ^-------------------------------------- |

A 2-DOF controller (``pid2``) is ``u = C_r r - C y`` on one set of states: ``C`` (the feedback part) is the
loop's ``controller`` for everything about ``L = C G`` (margins, Ms, Mt, Mks, the load response); the
reference path enters the closed loop's ``r`` column only (:meth:`ControllerTF.ref_ss`).

* continuous loop: ``C(s)`` and ``G(s)``, any delay (exact ``exp(-s*tau)``);
* sampled-data loop: ``C(z)`` at ``dt`` driving the continuous ``G(s)`` through a
  zero-order hold, any delay ``tau = d dt + phi``. The loop seen at the samples
  is ``C(z) * ZOH[G e^{-s phi}](z) * z^-d`` (exact; the fraction ``phi`` is one extra
  state of the ZOH plant, :meth:`tuner.plant.Plant.zoh`); the output between samples
  comes from ``G(s)`` with the delayed held input;
* discrete plant ``G(z)`` at the same ``dt``: between-sample output uses the
  continuous plant whose ZOH equivalent is ``G(z)``, when one exists.

Everything is computed from factored forms and state space (:mod:`tuner.lti`): the open loop
``L`` from the controller's and the plant's realisations (:meth:`Loop.freqresp`), the closed loop
as one state-space model (:meth:`Loop.closed_loop`) whose eigenvalues are the closed-loop poles,
uncancelled (a controller zero on a plant pole leaves that mode in the closed loop). No
characteristic polynomial is ever expanded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .controllers import ControllerTF
from .errors import InvalidControllerError, InvalidPlantError, TunerError
from .lti import SS, Zpk, freqresp, zoh_delayed
from .plant import Plant, delay_in_samples
from .tolerances import ALGEBRAIC_LOOP_TOL, ROOT_AT_DC_TOL

__all__ = ["Loop", "ClosedLoop", "FineDelayLoop", "build_loop", "tustin", "MIN_CONTINUOUS_DELAY_S",
           "MAX_DELAY_SAMPLES"]

MIN_CONTINUOUS_DELAY_S = 1e-6
MAX_DELAY_SAMPLES = 200  # a sampled-data loop's delay, in samples: d states, O(d^2) per simulated sample


@dataclass(frozen=True, eq=False)
class ClosedLoop:
    """``z+ = A z + B [r, w]`` (discrete; ``z' = ...`` continuous), ``y = Cy z + Dy [r, w]``, ``u = Cu z + Du [r, w]``.

    ``r`` is the reference, ``w`` a load disturbance added at the plant input (before its delay);
    ``u`` is the controller's output, ``ua`` (``Ca z + Da [r, w]``) the plant's actual input
    (delayed controller output plus the load). The plant's own state is ``z[:n_plant]``.
    """

    A: np.ndarray
    B: np.ndarray  # (nz, 2)
    Cy: np.ndarray
    Dy: np.ndarray  # (2,)
    Cu: np.ndarray
    Du: np.ndarray
    Ca: np.ndarray
    Da: np.ndarray
    n_plant: int
    discrete: bool
    h: float | None = None  # step of a sampled model of a continuous loop (with delay)

    def dc(self, inp: int) -> tuple[float, float]:
        """Steady-state ``(y, u)`` for a unit step on input ``inp`` (0 = reference, 1 = load); stable loops."""
        n = self.A.shape[0]
        M = (np.eye(n) - self.A) if self.discrete else -self.A
        try:
            z = np.linalg.solve(M, self.B[:, inp]) if n else np.zeros(0)
        except np.linalg.LinAlgError:
            return math.nan, math.nan
        return float(self.Cy @ z + self.Dy[inp]), float(self.Cu @ z + self.Du[inp])


@dataclass(frozen=True, eq=False)
class Loop:
    """A plant and a controller in unity feedback, with what analysis and simulation need."""

    plant: Plant
    controller: ControllerTF
    dt: float | None
    delay_s: float  # continuous delay; 0 in discrete time (delay_samples)
    delay_samples: int
    plant_ct: Plant | None  # continuous plant for between-sample output (its realisation; delay unused), or None
    plant_d: Plant | None  # discrete plant at dt (no delay folded), or None for continuous loops
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def is_discrete(self) -> bool:
        """The loop is sampled-data or discrete (a controller at ``dt``)."""
        return self.dt is not None

    @property
    def loop_plant(self) -> Plant:
        """The plant the controller sees: the ZOH plant at dt, or the continuous plant."""
        return self.plant_d if self.plant_d is not None else self.plant

    @property
    def zpk(self) -> Zpk:
        """Open-loop zeros, poles (the delay's ``z^-d`` as poles at 0) and gain, uncancelled."""
        if "zpk" not in self._cache:
            c, g = self.controller.zpk, self.loop_plant.zpk
            poles = np.concatenate([c.poles, g.poles, np.zeros(self.delay_samples, complex)])
            self._cache["zpk"] = Zpk(np.concatenate([c.zeros, g.zeros]), poles, c.gain * g.gain)
        return self._cache["zpk"]

    def freqresp(self, w: np.ndarray) -> np.ndarray:
        """Open-loop ``L`` at ``w`` rad/s (delay exact): continuous from the factors, sampled from the
        realisations (the zero-order-hold plant exists as a realisation)."""
        w = np.asarray(w, dtype=float)
        if self.dt is None:  # from the factors: exact to rounding at any frequency (see lti.Zpk)
            L = self.zpk(1j * w)
            return L * np.exp(-1j * w * self.delay_s) if self.delay_s else L
        x = np.exp(1j * w * self.dt)  # |x| = 1: the realisations' Schur form is accurate on the circle
        L = freqresp(self.controller.ss(), x) * freqresp(self.loop_plant.ss(), x)
        if self.delay_s:
            L = L * np.exp(-1j * w * self.delay_s)
        elif self.delay_samples:
            L = L * x ** (-self.delay_samples)
        return L

    def value_at(self, x: complex) -> complex:
        """``L`` at one point ``x`` of the s- or z-plane (``inf`` at an open-loop pole); no delay factor
        unless discrete (``x^-d``)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            c = freqresp(self.controller.ss(), np.array([x]))[0]
            g = freqresp(self.loop_plant.ss(), np.array([x]))[0]
            v = c * g * (x ** (-self.delay_samples) if self.delay_samples else 1.0)
        return complex(v)

    @property
    def integrating(self) -> bool:
        """An open-loop pole at DC (s = 0, z = 1)."""
        x = 0.0 if self.dt is None else 1.0
        p = self.zpk.poles
        return bool(np.any(np.abs(p - x) < ROOT_AT_DC_TOL * max(1.0, float(np.max(np.abs(p))) if p.size else 1.0)))

    def nyquist_w(self) -> float | None:
        """The Nyquist frequency ``pi/dt``, rad/s; None for a continuous loop."""
        return np.pi / self.dt if self.dt else None

    def closed_loop(self, h: float | None = None) -> ClosedLoop | FineDelayLoop:
        """The closed loop in state space (cached). Continuous loops with a delay need ``h``: they are
        modelled at that step (:class:`FineDelayLoop`)."""
        key = ("cl", h)
        if key not in self._cache:
            ref = self.controller.ref_ss() if self.controller.two_dof else None
            if self.dt is not None:
                self._cache[key] = _discrete_loop(self.loop_plant.ss(), self.controller.ss(), self.delay_samples,
                                                  ref=ref)
            elif not self.delay_s:
                self._cache[key] = _continuous_loop(self.plant.ss(), self.controller.ss(), ref=ref)
            else:
                if h is None:
                    raise ValueError("a continuous loop with a delay is modelled at a step h")
                self._cache[key] = _fine_delay_loop(self.plant.ss(), self.controller.ss(), self.delay_s, h, ref=ref)
        return self._cache[key]


def tustin(c: SS, h: float) -> SS:
    """Bilinear (Tustin) equivalent of a continuous realisation at step ``h``: ``C(2/h (z-1)/(z+1))``."""
    n = c.n
    if n == 0:
        return SS(np.zeros((0, 0)), np.zeros(0), np.zeros(0), c.D)
    ima = np.eye(n) - c.A * (h / 2)
    A = np.linalg.solve(ima, np.eye(n) + c.A * (h / 2))
    B = np.linalg.solve(ima, c.B * h)
    C = np.linalg.solve(ima.T, c.C)
    return SS(A, B, C, float(c.D + 0.5 * c.C @ B))


def _ref_column(B: np.ndarray, ic: slice, c: SS, De: np.ndarray, Dy: np.ndarray, ref: SS | None) -> None:
    """The controller's input columns: ``B e`` with ``e = r - y`` (1-DOF), or ``Br r - B y`` (2-DOF: ``ref`` has
    the reference path's ``B``, ``D`` on the controller's states)."""
    if ref is None:
        B[ic, :] += np.outer(c.B, De)
    else:
        B[ic, :] += np.outer(c.B, -Dy)
        B[ic, 0] += ref.B


def _feedthrough(g: SS, c: SS, nz: int, ix: slice, ic: slice, ref: SS | None):
    """The loop's output maps when the plant's input is ``u + w`` at once (no delay register): the algebraic loop
    ``u = (Cc xc + Dc (r - Cp x - Dp w)) / (1 + Dc Dp)``, ``ua = u + w``, ``y = Cp x + Dp ua``; raises when
    ``1 + Dc Dp`` vanishes. Returns ``Cu, Du, Ca, Da, Cy, Dy`` over the states ``[plant x, ..., controller xc]``."""
    den = 1.0 + c.D * g.D
    if abs(den) < ALGEBRAIC_LOOP_TOL:
        raise InvalidControllerError("the loop is algebraically singular (1 + C(inf) G(inf) = 0)")
    Cu = np.zeros(nz)
    Cu[ix] = -c.D * g.C / den
    Cu[ic] = c.C / den
    Du = np.array([c.D if ref is None else ref.D, -c.D * g.D]) / den
    Ca, Da = Cu.copy(), Du + np.array([0.0, 1.0])
    Cy = np.concatenate([g.C, np.zeros(nz - g.n)]) + g.D * Ca
    Dy = g.D * Da
    return Cu, Du, Ca, Da, Cy, Dy


def _plant_and_controller_rows(A: np.ndarray, B: np.ndarray, g: SS, c: SS, ix: slice, ic: slice, Ca: np.ndarray,
                               Da: np.ndarray, Cy: np.ndarray, Dy: np.ndarray, ref: SS | None) -> None:
    """Fill the plant's rows (driven by its input ``Ca z + Da [r, w]``) and the controller's (driven by
    ``e = r - y``, or a 2-DOF ``ref``) of the closed loop's ``A``, ``B``."""
    A[ix, :] += np.outer(g.B, Ca)
    A[ix, ix] += g.A
    B[ix, :] += np.outer(g.B, Da)
    A[ic, :] += np.outer(c.B, -Cy)
    A[ic, ic] += c.A
    _ref_column(B, ic, c, np.array([1.0, 0.0]) - Dy, Dy, ref)


def _discrete_loop(g: SS, c: SS, d: int, *, ref: SS | None = None) -> ClosedLoop:
    """States [plant x (n), input register s (d: s[0] = u[k-1] ... s[d-1] = u[k-d]), controller xc (m)].

    ``ref``: a 2-DOF controller's reference path on the states of ``c`` (``u = C xc + Dr r - D y``)."""
    n, m = g.n, c.n
    nz = n + d + m
    ix, ic = slice(0, n), slice(n + d, nz)
    # plant input ua = s[d-1] (+ 0) if d > 0; else u + w (solved below)
    A = np.zeros((nz, nz))
    B = np.zeros((nz, 2))
    if d > 0:
        Ca = np.zeros(nz)
        Ca[n + d - 1] = 1.0
        Da = np.zeros(2)
        Cy = np.concatenate([g.C, np.zeros(d + m)]) + g.D * Ca
        Dy = g.D * Da
        # e = r - y ; u = Cc xc + Dc e
        Cu = -c.D * Cy
        Cu[ic] += c.C
        Du = c.D * (np.array([1.0, 0.0]) - Dy) if ref is None else np.array([ref.D, 0.0]) - c.D * Dy
        # s+ = [u + w, s[0..d-2]]
        A[n, :] = Cu
        B[n, :] = Du + np.array([0.0, 1.0])
        for j in range(1, d):
            A[n + j, n + j - 1] = 1.0
    else:
        Cu, Du, Ca, Da, Cy, Dy = _feedthrough(g, c, nz, ix, ic, ref)
    _plant_and_controller_rows(A, B, g, c, ix, ic, Ca, Da, Cy, Dy, ref)
    return ClosedLoop(A, B, Cy, Dy, Cu, Du, Ca, Da, n_plant=n, discrete=True)


def _continuous_loop(g: SS, c: SS, *, ref: SS | None = None) -> ClosedLoop:
    """States [plant x (n), controller xc (m)] of the continuous loop without delay (``ref``: see
    :func:`_discrete_loop`)."""
    n, m = g.n, c.n
    nz = n + m
    ix, ic = slice(0, n), slice(n, nz)
    Cu, Du, Ca, Da, Cy, Dy = _feedthrough(g, c, nz, ix, ic, ref)
    A = np.zeros((nz, nz))
    B = np.zeros((nz, 2))
    _plant_and_controller_rows(A, B, g, c, ix, ic, Ca, Da, Cy, Dy, ref)
    return ClosedLoop(A, B, Cy, Dy, Cu, Du, Ca, Da, n_plant=n, discrete=False)


@dataclass(frozen=True, eq=False)
class FineDelayLoop:
    """A continuous loop with delay ``tau = m h + f`` as a sampled model at step ``h``.

    The plant's ZOH with the delay on a shifted grid is exact for a piecewise-constant input
    (:func:`tuner.lti.zoh_delayed`); the controller is Tustin at ``h`` (error O(h^2)). Simulated with a
    ring buffer of the plant's past inputs (``m + 1`` of them), so a long delay costs no large matrix;
    :meth:`dense` gives the closed-loop matrix for the eigenvalues when ``m`` is small.
    """

    plant: SS  # continuous plant (its C, D give the output)
    Phi: np.ndarray
    G_old: np.ndarray  # input (u + w)[k-m-1], over the first f of the step
    G_new: np.ndarray  # input (u + w)[k-m], over the last h - f
    m: int
    f: float
    ctrl: SS  # Tustin controller at h
    h: float
    ctrl_r: SS | None = None  # 2-DOF: the reference path on ctrl's states (Tustin at h), or None

    def dense(self) -> ClosedLoop:
        """States [plant x (n), register s (m+1: s[j] = (u + w)[k-1-j]), controller (nc)]."""
        g, cd, m, f = self.plant, self.ctrl, self.m, self.f
        n, nc, nr = g.n, cd.n, m + 1
        nz = n + nr + nc
        ix, ic = slice(0, n), slice(n + nr, nz)
        a_y = np.zeros(nz)  # the output at t_k sees the input held at k h - tau
        a_y[n + m - 1 if f == 0.0 else n + m] = 1.0
        Cy = np.concatenate([g.C, np.zeros(nr + nc)]) + g.D * a_y
        Dy = np.zeros(2)
        Cu = -cd.D * Cy
        Cu[ic] += cd.C
        Du = np.array([cd.D if self.ctrl_r is None else self.ctrl_r.D, 0.0])
        A = np.zeros((nz, nz))
        B = np.zeros((nz, 2))
        A[ix, ix] = self.Phi
        A[ix, n + m] += self.G_old
        if m >= 1:
            A[ix, n + m - 1] += self.G_new
        else:  # the newest input is this step's
            A[ix, :] += np.outer(self.G_new, Cu)
            B[ix, :] += np.outer(self.G_new, Du + np.array([0.0, 1.0]))
        A[n, :] += Cu  # s[0]+ = u + w
        B[n, :] += Du + np.array([0.0, 1.0])
        for j in range(1, nr):
            A[n + j, n + j - 1] = 1.0
        A[ic, :] += np.outer(cd.B, -Cy)
        A[ic, ic] += cd.A
        _ref_column(B, ic, cd, np.array([1.0, 0.0]) - Dy, Dy, self.ctrl_r)
        return ClosedLoop(A, B, Cy, Dy, Cu, Du, a_y.copy(), np.zeros(2), n_plant=n, discrete=True, h=self.h)


def _fine_delay_loop(g: SS, c: SS, tau: float, h: float, *, ref: SS | None = None) -> FineDelayLoop:
    Phi, G_old, G_new, m, f = zoh_delayed(g, h, tau)
    if m == 0 and f == 0.0:
        raise InvalidPlantError("delay too short for the simulation step", field=("plant", "delay"))
    return FineDelayLoop(g, Phi, G_old, G_new, m, f, tustin(c, h), h,
                         ctrl_r=None if ref is None else tustin(ref, h))


def build_loop(plant: Plant, controller: ControllerTF) -> Loop:
    """Combine a plant and a controller into a :class:`Loop`, with clear errors."""
    if controller.dt is None:
        if plant.is_discrete:
            raise InvalidControllerError(
                f"plant is discrete (dt={plant.dt}) but the controller is continuous: give a controller in z",
                field="dt",
            )
        if 0 < plant.delay_s < MIN_CONTINUOUS_DELAY_S:
            raise InvalidPlantError(
                f"delay {plant.delay_s:g} s is below {MIN_CONTINUOUS_DELAY_S:g} s, too short to simulate exactly "
                "in a continuous loop (the simulation step divides the delay); give 0 or a longer delay",
                field=("plant", "delay"))
        return _finite(Loop(plant=plant, controller=controller, dt=None, delay_s=plant.delay_s, delay_samples=0,
                            plant_ct=plant, plant_d=None))
    dt = controller.dt
    if not plant.delay_s / dt <= MAX_DELAY_SAMPLES + 1:  # before the discretisation (a delay of 1e308 s overflowed it)
        raise InvalidPlantError(
            f"delay of {plant.delay_s:g} s is {plant.delay_s / dt:.4g} samples of dt={dt:g} s, above the limit of "
            f"{MAX_DELAY_SAMPLES} samples (each sample of delay is a state of the closed loop): give a larger sample "
            "time, or a continuous controller", field=("plant", "delay"))
    try:
        pd = plant.zoh(dt)  # validates dt match for discrete plants; any delay (fraction in the realisation)
    except TunerError as e:
        raise (e if e.field == ("dt",) else e.at("plant")) from None
    d = delay_in_samples(pd.delay_s, dt)
    if d > MAX_DELAY_SAMPLES:
        raise InvalidPlantError(
            f"delay of {d} samples of dt={dt:g} s is above the limit of {MAX_DELAY_SAMPLES} samples (each sample "
            "of delay is a state of the closed loop): give a larger sample time, or a continuous controller",
            field=("plant", "delay"))
    pct = plant.continuous_equivalent() if plant.is_discrete else plant
    return _finite(Loop(plant=plant, controller=controller, dt=dt, delay_s=0.0, delay_samples=d,
                        plant_ct=pct, plant_d=pd))


def _finite(loop: Loop) -> Loop:
    """``loop`` if its closed-loop state-space model is finite (plant x controller gains can overflow although
    each is finite: 1e200/(s+1e100) with a controller gain of 1e200)."""
    c, g = loop.controller.zpk.gain, loop.loop_plant.zpk.gain
    if c != 0 and g != 0 and not -300 <= math.log10(abs(c)) + math.log10(abs(g)) <= 300:
        raise InvalidControllerError(f"the loop gain, the product of the plant's and the controller's gains "
                                     f"({g:g} x {c:g}), is beyond double precision; rescale the controller or "
                                     "the plant",
                                     field="controller")
    with np.errstate(all="ignore"):
        if loop.delay_s:  # the fine model is built from the same products as the delay-free loop
            cl = _continuous_loop(loop.plant.ss(), loop.controller.ss())
        else:
            cl = loop.closed_loop()
    if not all(np.all(np.isfinite(m)) for m in (cl.A, cl.B, cl.Cy, cl.Dy, cl.Cu, cl.Du)):
        raise InvalidControllerError("the loop's state-space model overflows: the product of the plant's and the "
                                     "controller's gains is beyond double precision; rescale the controller or "
                                     "the plant", field="controller")
    return loop
