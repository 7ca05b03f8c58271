"""The figures of one design on one airframe, computed here (independently of tuner's verifier).

From the exact linear loop as flown (:func:`h2h.sim.lift` and the law's own linear matrices,
:func:`h2h.laws.law_matrices`), broken at the plant input:

    L(z) = -K(z) G(z),   G = Cy (zI - F)^-1 G_v  (2 outputs: w_f, wdot),   K = the law's response to (w_f, wdot)

- stability: the closed-loop eigenvalues (all inside the unit circle);
- PM: the smallest phase margin over every gain crossing |L| = 1 on a dense log grid up to the loop's Nyquist
  frequency, each crossing refined by root finding;
- GM: the smallest distance in dB of |L| from 1 at the phase crossings (arg L = -180 deg): upper and lower margins
  alike (a lower margin, |L| > 1 at a crossing, counts as a gain reduction that destabilises);
- DRB: the lowest frequency where |S| = |1/(1 + L)| rises to -3 dB (the disturbance rejection bandwidth, Berger
  et al., AHS Forum 72, 2016).

From the loop flown sample by sample (:func:`h2h.sim.fly`, the law with its clamps):

- overshoot and 2 % settling of a unit rate step (1 rad/s), on the true rate at the IMU between samples;
- load peak and recovery: a 0.2 torque step at the plant input (before the delay, as the tuner's load step),
  r = 0; the peak |w|, and the time after which |w| stays within 10 % of that peak.

Non-finite values mean something: inf settling/recovery = not within the horizon, nan = unstable.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import brentq

from .airframes import Airframe
from .laws import law_matrices, make_law
from .sim import Lifted, fly, lift

__all__ = ["Figures", "evaluate", "loop_response", "closed_loop_poles", "LOAD", "SETTLE_BAND", "RECOVERY_SHARE"]

LOAD = 0.2  # torque step at the plant input
SETTLE_BAND = 0.02
RECOVERY_SHARE = 0.10
HORIZON_CAP_S = 40.0


@dataclass
class Figures:
    stable: bool
    pm_deg: float
    gm_db: float
    overshoot_pct: float
    settling_s: float
    drb_rad_s: float
    load_peak: float
    load_recovery_s: float
    int_clamped: bool = False

    def to_dict(self) -> dict:
        return asdict(self)


def _law_lin(firmware: str, gains: dict, dt: float):
    A, B, C, D = law_matrices(firmware, gains, dt)
    return A, B, C, D


def closed_loop_poles(lifted: Lifted, firmware: str, gains: dict) -> np.ndarray:
    """Eigenvalues of the lifted closed loop (plant, sensors, registers and the law's states)."""
    Al, Bl, Cl, Dl = _law_lin(firmware, gains, lifted.af.dt)
    keep = np.delete(np.arange(lifted.nx), lifted.i_angle)
    F, G, Cy = lifted.F[np.ix_(keep, keep)], lifted.G[keep], lifted.Cy[:, keep]
    By = Bl[:, 1:3]
    Dy = Dl[:, 1:3]
    top = np.hstack([F + G @ Dy @ Cy, G @ Cl])
    bot = np.hstack([By @ Cy, Al])
    return np.linalg.eigvals(np.vstack([top, bot]))


def loop_response(lifted: Lifted, firmware: str, gains: dict, w: np.ndarray) -> np.ndarray:
    """``L(e^{j w T})`` of the loop broken at the plant input (negative feedback convention: 1 + L = 0)."""
    T = lifted.af.dt
    Al, Bl, Cl, Dl = _law_lin(firmware, gains, T)
    By, Dy = Bl[:, 1:3], Dl[0, 1:3]
    F, G, Cy = lifted.F, lifted.G[:, 0], lifted.Cy
    nx, nl = F.shape[0], Al.shape[0]
    out = np.empty(w.size, complex)
    Ix, Il = np.eye(nx), np.eye(nl)
    for i, wi in enumerate(w):
        z = np.exp(1j * wi * T)
        gy = Cy @ np.linalg.solve(z * Ix - F, G)  # (2,)
        ky = Cl @ np.linalg.solve(z * Il - Al, By) + Dy  # (1, 2)
        out[i] = -(ky @ gy).item()
    return out


def _margins(lifted: Lifted, firmware: str, gains: dict) -> tuple[float, float, float]:
    """``(PM deg, GM dB, DRB rad/s)`` on a dense grid with root-refined crossings."""
    T = lifted.af.dt
    wn = math.pi / T
    w = np.geomspace(1e-2, 0.9995 * wn, 3000)
    L = loop_response(lifted, firmware, gains, w)
    mag = np.abs(L)
    ph = np.unwrap(np.angle(L))
    # put the low-frequency phase in (-270, 90] deg (type 1: -90, type 2: -180)
    ph -= 2 * math.pi * math.floor((ph[0] + 1.5 * math.pi) / (2 * math.pi))

    def L_at(x: float) -> complex:
        return loop_response(lifted, firmware, gains, np.array([x]))[0]

    pms = []
    lm = np.log(mag)
    for i in np.flatnonzero(np.sign(lm[:-1]) != np.sign(lm[1:])):
        x = brentq(lambda x: math.log(abs(L_at(x))), w[i], w[i + 1], xtol=1e-10 * w[i])
        p = math.degrees(math.atan2(L_at(x).imag, L_at(x).real)) + 180.0
        p = (p + 180.0) % 360.0 - 180.0
        pms.append(p)
    pm = min(pms) if pms else math.inf
    gms = []
    for k in range(-5, 6):
        target = -math.pi + 2 * math.pi * k
        s = ph - target
        for i in np.flatnonzero(np.sign(s[:-1]) != np.sign(s[1:])):
            # refine on the continuous phase near the grid segment
            def f(x, i=i, target=target):
                a = np.angle(L_at(x))
                ref = ph[i]
                a += 2 * math.pi * round((ref - a) / (2 * math.pi))
                return a - target
            try:
                x = brentq(f, w[i], w[i + 1], xtol=1e-10 * w[i])
            except ValueError:
                x = w[i]
            gms.append(abs(20 * math.log10(abs(L_at(x)))))
    gm = min(gms) if gms else math.inf
    S = np.abs(1.0 / (1.0 + L))
    thr = 10 ** (-3 / 20)
    above = np.flatnonzero(thr <= S)
    if above.size == 0:
        drb = math.inf
    elif above[0] == 0:
        drb = w[0]
    else:
        i = above[0] - 1
        x = brentq(lambda x: abs(1 / (1 + L_at(x))) - thr, w[i], w[i + 1], xtol=1e-10 * w[i])
        drb = x
    return pm, gm, drb


def _settling(t: np.ndarray, y: np.ndarray, final: float, band: float) -> float:
    out = np.flatnonzero(np.abs(y - final) > band * abs(final))
    if out.size == 0:
        return 0.0
    if out[-1] >= y.size - 1:
        return math.inf
    return float(t[out[-1] + 1])


def _flown(af: Airframe, lifted: Lifted, firmware: str, gains: dict, *, r: float, d: float):
    """Fly until the response has settled (settling / recovery finite with a quarter of the run to spare), the
    horizon doubling from the airframe's up to HORIZON_CAP_S."""
    horizon = af.horizon_s
    while True:
        n = int(round(horizon * af.loop_hz))
        law = make_law(firmware, gains, af.dt)
        fl = fly(lifted, law, n, r=r, d=d)
        if not np.all(np.isfinite(fl.wf)) or np.max(np.abs(fl.wf)) > 1e6:
            return fl, False
        s = _settling(fl.tf, fl.wf, r, SETTLE_BAND) if r else _rec(fl.tf, fl.wf)
        if (math.isfinite(s) and s < 0.75 * horizon) or horizon >= HORIZON_CAP_S:
            return fl, True
        horizon *= 2


def _rec(t: np.ndarray, y: np.ndarray) -> float:
    a = np.abs(y)
    pk = a.max()
    out = np.flatnonzero(a > RECOVERY_SHARE * pk)
    if out.size == 0:
        return 0.0
    if out[-1] >= y.size - 1:
        return math.inf
    return float(t[out[-1] + 1])


def evaluate(af: Airframe, firmware: str, gains: dict, *, lifted: Lifted | None = None) -> Figures:
    """All the figures of ``gains`` (the law's parameters over the firmware's defaults) on ``af``."""
    lifted = lifted or lift(af, firmware, dgyro_hz=gains.get("dgyro_hz"))
    poles = closed_loop_poles(lifted, firmware, gains)
    stable = bool(np.max(np.abs(poles)) < 1.0 - 1e-12)
    if not stable:
        return Figures(False, math.nan, math.nan, math.nan, math.nan, math.nan, math.nan, math.nan)
    pm, gm, drb = _margins(lifted, firmware, gains)
    fl, _ = _flown(af, lifted, firmware, gains, r=1.0, d=0.0)
    overshoot = 100.0 * max(0.0, float(fl.wf.max()) - 1.0)
    settling = _settling(fl.tf, fl.wf, 1.0, SETTLE_BAND)
    fl2, _ = _flown(af, lifted, firmware, gains, r=0.0, d=LOAD)
    peak = float(np.max(np.abs(fl2.wf)))
    rec = _rec(fl2.tf, fl2.wf)
    return Figures(True, pm, gm, overshoot, settling, drb, peak, rec, fl.int_clamped or fl2.int_clamped)
