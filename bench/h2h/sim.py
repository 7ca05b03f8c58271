"""The airframe and its sensor chain lifted to the loop rate, and the per-sample closed loop.

Between two loop samples the firmware's sensor code runs on every raw gyro sample (rate ``raw_hz``):

- the gyro low-pass, a second-order Butterworth biquad designed by the bilinear transform with prewarping (PX4
  ``math::LowPassFilter2p::set_cutoff_frequency``/``apply``, src/lib/mathlib/math/filter/LowPassFilter2p.cpp and
  .hpp @ 911f8528342435cf472f25ed6b3bb96be1ea2adb: ``ohm = tan(pi fc/fs)``, ``c = 1 + 2 cos(pi/4) ohm + ohm^2``,
  ``b0 = ohm^2/c``, ``b1 = 2 b0``, ``b2 = b0``, ``a1 = 2 (ohm^2 - 1)/c``, ``a2 = (1 - 2 cos(pi/4) ohm + ohm^2)/c``,
  direct form II; ArduPilot's ``LowPassFilter2p`` / ``DigitalBiquadFilter`` designs the same biquad for
  ``INS_GYRO_FILTER``);
- PX4 only: the D path, ``(w_f[n] - w_f[n-1]) * fs`` through an ``AlphaFilter`` at ``IMU_DGYRO_CUTOFF`` (see
  :mod:`h2h.laws`).

The loop reads the last filtered sample at each loop instant and its output reaches the plant after the delay
``tau = q T + r`` (``r`` a whole number of raw samples). The plant runs continuously: its exact ZOH map over
``h/sub`` (``h`` the raw period) advances it, so the rate at the IMU is known between samples (``sub`` points per
raw sample; the "true rate between samples" of the step metrics). Over one loop period all of this is linear
with the input held, so it is propagated once into matrices (the "lifted" model, exact, no approximation):

    X[k+1] = F X[k] + G v[k]      (v = u + d: the law's output plus a load at the plant input, before the delay)
    (w_f, wdot)[k] = Cy X[k]      (what the law reads at sample k; no feedthrough from v[k])
    w_imu(kT + i h/sub) = Cf [X[k]; v[k]]   (the fine output, R*sub points per period)
    angle(kT) = Ca X[k]

X = [plant states, biquad d1 d2, (PX4) w_f previous and the D filter, input registers v[k-1] .. v[k-q-1]].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from .airframes import Airframe
from .laws import alpha

__all__ = ["biquad", "Lifted", "lift", "fly", "Flight", "PX4_DGYRO"]

PX4_DGYRO = 20.0  # IMU_DGYRO_CUTOFF default (imu_gyro_parameters.yaml @ 21a553621f7a2ab923bf0c8881cfde0b9f6e3d2b)


def biquad(fs: float, fc: float) -> tuple[float, float, float, float, float]:
    """``(b0, b1, b2, a1, a2)`` of the firmware's second-order Butterworth at sample rate ``fs``, cutoff ``fc``
    (``fc <= 0``: no filter)."""
    if fc <= 0:
        return 1.0, 0.0, 0.0, 0.0, 0.0
    ohm = math.tan(math.pi * fc / fs)
    c = 1.0 + 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm
    b0 = ohm * ohm / c
    return b0, 2 * b0, b0, 2.0 * (ohm * ohm - 1.0) / c, (1.0 - 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm) / c


def _zoh(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A * h
    M[:n, n:] = B * h
    E = expm(M)
    return E[:n, :n], E[:n, n:]


@dataclass
class Lifted:
    """The lifted airframe + sensor chain for one firmware (see the module docstring)."""

    af: Airframe
    firmware: str
    F: np.ndarray
    G: np.ndarray
    Cy: np.ndarray  # (2, nX): w_f, wdot (0 for ArduPilot)
    Cf: np.ndarray  # (R*sub, nX+1): w_imu at the fine instants of the period
    Ca: np.ndarray  # (1, nX): angle at the sample instant
    fine_dt: float
    R: int
    sub: int
    i_angle: int  # the angle state (an integrator nothing else reads: left out of the loop's poles)

    @property
    def nx(self) -> int:
        return self.F.shape[0]


def lift(af: Airframe, firmware: str, *, dgyro_hz: float | None = None, raw_hz: float | None = None,
         gyro_hz: float | None = None, sub: int | None = None, dgyro_order: int = 1) -> Lifted:
    """Lift ``af`` for ``firmware`` (``"px4"``: with the raw-rate D path at ``dgyro_hz``; ``"ardupilot"``).

    ``dgyro_order`` 2: the D path's filter is the 2021-era ``LowPassFilter2p`` (the biquad above at the raw rate,
    ``VehicleAngularVelocity.hpp``'s ``math::LowPassFilter2p _lp_filter_acceleration[3]`` of that generation) instead
    of today's ``AlphaFilter``.

    ``raw_hz`` overrides the airframe's raw gyro rate (the sanity check sets it to the loop rate), ``gyro_hz`` its
    gyro low-pass; ``sub`` plant points per raw sample for the fine output (default: at least 16 points per loop
    period)."""
    T = 1.0 / af.loop_hz
    raw = af.raw_hz if raw_hz is None else raw_hz
    R = int(round(raw / af.loop_hz))
    if R < 1 or abs(R * af.loop_hz - raw) > 1e-6 * raw:
        raise ValueError(f"{af.name}: the raw rate {raw} Hz must be a whole multiple of the loop rate {af.loop_hz} Hz")
    h = T / R
    if sub is None:
        sub = max(1, math.ceil(16 / R))
    q, rem = divmod(af.delay_s, T)
    q = int(round(q))
    m = rem / h
    if abs(m - round(m)) > 1e-6:
        raise ValueError(f"{af.name}: the delay {af.delay_s} s must be a whole number of raw samples ({h} s)")
    m = int(round(m))
    if m >= R:  # rounding put the remainder on a whole period
        q, m = q + 1, 0
    Ac, Bc, Cc = af.body_ss()
    n = Ac.shape[0]
    Phi, Gam = _zoh(Ac, Bc, h / sub)
    fc = af.gyro_hz(firmware) if gyro_hz is None else gyro_hz
    b0, b1, b2, a1, a2 = biquad(raw, fc)
    px4 = firmware == "px4"
    fd = PX4_DGYRO if dgyro_hz is None else dgyro_hz
    # AlphaFilter::setCutoffFreq refuses 0 or >= fs/2; VehicleAngularVelocity then sets alpha 1 (no filter)
    ad = alpha(fd, h) if 0 < fd < raw / 2 else 1.0
    # indices
    i_d1, i_d2 = n, n + 1
    i_wp, i_af = (n + 2, n + 3) if px4 else (None, None)
    two = px4 and dgyro_order == 2 and 0 < fd < raw / 2
    i_e1, i_e2 = n + 4, n + 5  # the D biquad's delay elements (second order only)
    i_reg = n + (4 + 2 * two if px4 else 2)
    nreg = q + 1
    nx = i_reg + nreg
    nz = nx + 1
    iv = nx  # the held input v[k] in Z

    # processing of one raw sample, as a map on Z (and the row of the filtered sample / the D value after it)
    row_w = np.zeros(nz)
    row_w[:n] = Cc[0]
    row_d0 = row_w.copy()
    row_d0[i_d1] -= a1
    row_d0[i_d2] -= a2
    row_out = b0 * row_d0
    row_out[i_d1] += b1
    row_out[i_d2] += b2
    Pm = np.eye(nz)
    Pm[i_d1] = row_d0
    Pm[i_d2] = 0.0
    Pm[i_d2, i_d1] = 1.0
    if px4:
        acc = (row_out - np.eye(nz)[i_wp]) * raw  # (w_f - w_prev) * fs
        if two:  # LowPassFilter2p::apply on the difference (direct form II, as the gyro's)
            e0, e1, e2, ea1, ea2 = biquad(raw, fd)
            row_e0 = acc.copy()
            row_e0[i_e1] -= ea1
            row_e0[i_e2] -= ea2
            row_af = e0 * row_e0
            row_af[i_e1] += e1
            row_af[i_e2] += e2
            Pm[i_e2] = np.eye(nz)[i_e1]
            Pm[i_e1] = row_e0
        else:
            row_af = np.eye(nz)[i_af] * (1 - ad) + ad * acc
        Pm[i_af] = row_af
        Pm[i_wp] = row_out
    # the outputs the law reads, from Z before the processing at the loop instant
    Cy = np.zeros((2, nz))
    Cy[0] = row_out
    if px4:
        Cy[1] = row_af

    def advance(j: int) -> np.ndarray:
        """One raw step j of the period (the plant over h in ``sub`` steps), as a map on Z; also the fine rows."""
        src = np.zeros(nz)
        if j >= m:  # t >= r within the period: v[k - q] (the current input if q = 0, else register q - 1)
            src[iv if q == 0 else i_reg + q - 1] = 1.0
        else:
            src[i_reg + q] = 1.0  # v[k - q - 1]
        M = np.eye(nz)
        rows = []
        for _ in range(sub):
            rows.append(np.concatenate([Cc[0], np.zeros(nz - n)]) @ M)
            S = np.eye(nz)
            S[:n, :n] = Phi
            S[:n] += np.outer(Gam[:, 0], src)
            M = S @ M
        return M, rows

    Z = np.eye(nz)
    fine_rows = []
    for j in range(R):
        Z = Pm @ Z
        Mj, rows = advance(j)
        fine_rows.extend(r @ Z for r in rows)
        Z = Mj @ Z
    # shift the registers: [v, v[k-1], .., v[k-q]]
    Sh = np.eye(nz)
    for i in range(nreg - 1, 0, -1):
        Sh[i_reg + i] = np.eye(nz)[i_reg + i - 1]
    Sh[i_reg] = np.eye(nz)[iv]
    Z = Sh @ Z
    F = Z[:nx, :nx]
    G = Z[:nx, nx:]
    Ca = np.zeros((1, nx))
    Ca[0, :n] = Cc[1]
    return Lifted(af, firmware, F, G, Cy[:, :nx], np.array(fine_rows), Ca, h / sub, R, sub, n - 1)


@dataclass
class Flight:
    """A flown loop: sample instants ``t``, the law's output ``u``, what it read ``y`` (w_f, wdot), the fine
    instants ``tf`` and the true rate at the IMU ``wf`` there, the angle at the samples."""

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    tf: np.ndarray
    wf: np.ndarray
    angle: np.ndarray
    int_clamped: bool


def fly(lifted: Lifted, law, n: int, r=0.0, d=0.0, x0: np.ndarray | None = None) -> Flight:
    """Fly ``law`` (a :mod:`h2h.laws` law, stepped once per sample) on ``lifted`` for ``n`` samples. ``r`` and
    ``d`` (load torque at the plant input): numbers or arrays of ``n`` samples."""
    r = np.broadcast_to(np.asarray(r, float), (n,))
    d = np.broadcast_to(np.asarray(d, float), (n,))
    F, G, Cy = lifted.F, lifted.G[:, 0], lifted.Cy
    X = np.zeros(lifted.nx) if x0 is None else np.array(x0, float)
    Zs = np.empty((n, lifted.nx + 1))
    ys = np.empty((n, 2))
    us = np.empty(n)
    for k in range(n):
        y = Cy @ X
        u = law.step(r[k], y[0], y[1])
        v = u + d[k]
        Zs[k, :-1] = X
        Zs[k, -1] = v
        ys[k] = y
        us[k] = u
        X = F @ X + G * v
    T = 1.0 / lifted.af.loop_hz
    wf = (Zs @ lifted.Cf.T).ravel()
    tf = (np.arange(n)[:, None] * T + np.arange(lifted.Cf.shape[0])[None, :] * lifted.fine_dt).ravel()
    angle = Zs[:, :-1] @ lifted.Ca[0]
    return Flight(np.arange(n) * T, us, ys, tf, wf, angle, bool(getattr(law, "int_clamped", False)))
