"""The bench's sanity checks (reported by ``bench/autotune_h2h.py --checks``; nothing here is a test).

1. The lifted plant and sensor chain against a brute-force simulation written again here at the raw gyro rate
   (plant stepped ``sub`` times per raw sample, the biquad and the PX4 D path sample by sample, the delay taken
   from the time axis): the same outputs on a random input, every airframe and firmware.
2. The per-sample PX4 law (:mod:`h2h.laws`) flown with the raw gyro rate set equal to the loop rate (so that
   PX4's D path runs at the loop rate, as ``tuner``'s ``px4_rate`` assumes) against ``tuner``'s ``px4_rate``
   transfer functions (its two-input realisation ``u = C x + Dr r - D y``, ``x' = A x + Br r - B y``) flown on
   the same sampled plant: the step responses sample by sample; the same for ArduPilot's law and
   ``ardupilot_rate``.
3. GMVC on a hand example: ``den = 1 - 1.5 z^-1 + 0.5 z^-2`` (poles 1 and 0.5), ``b0 + b1 + b2 = 0.2``,
   ``delta = 0`` (``mu = 1/4``, ``sqrt(4 mu - 1) = 0``), ``sigma = 0.1``, ``dt = sigma ln(2)/2`` (so
   ``rho = ln 2 / 2``, ``exp(-rho/(2 mu)) = 1/2``): ``p1 = -1``, ``p2 = 1/4``, ``e1 = 1.5 - 1 + 1 = 1.5``,
   ``f0 = 2.25 - 1.5 - 0.5 + 1.5 + 0.25 = 2``, ``f1 = -2.25 - 0.75 + 0.5 = -2.5``, ``f2 = 0.75``,
   ``nu = 0.7 + 2.5 * 0.2 = 1.2``; ``kc = -(f1 + 2 f2)/nu = 1/1.2 = 5/6``, ``ki = -(f0 + f1 + f2)/(dt (f1 + 2 f2))
   / 5 = 0.25/dt/5 = 0.05/dt``, ``kd = -dt f2/(f1 + 2 f2) = 0.75 dt`` (lambda 0.7).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .airframes import AIRFRAMES
from .laws import AP_DEFAULTS, PX4_DEFAULTS, alpha, make_law
from .px4_autotune import gmvc
from .sim import _zoh, biquad, lift

__all__ = ["check_lift", "check_laws_against_tuner", "check_gmvc", "run_checks"]


def check_lift(n: int = 120, seed: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    out = []
    for af in AIRFRAMES.values():
        for fw in ("px4", "ardupilot"):
            L = lift(af, fw)
            v = rng.standard_normal(n)
            X = np.zeros(L.nx)
            ys, fines = [], []
            for k in range(n):
                ys.append(L.Cy @ X)
                fines.append(L.Cf @ np.r_[X, v[k]])
                X = L.F @ X + L.G[:, 0] * v[k]
            ys, fines = np.array(ys), np.concatenate(fines)
            T = af.dt
            h = T / L.R
            fh = h / L.sub
            A, B, C = af.body_ss()
            Phi, Gam = _zoh(A, B, fh)
            b0, b1, b2, a1, a2 = biquad(af.raw_hz, af.gyro_hz(fw))
            ad = alpha(PX4_DEFAULTS["dgyro_hz"], h)
            x = np.zeros(A.shape[0])
            d1 = d2 = wp = acc_f = 0.0
            ys2, f2 = [], []
            i = 0
            for _k in range(n):
                for j in range(L.R):
                    w = C[0] @ x
                    d0 = w - a1 * d1 - a2 * d2
                    o = b0 * d0 + b1 * d1 + b2 * d2
                    d2, d1 = d1, d0
                    acc_f += ad * ((o - wp) / h - acc_f)
                    wp = o
                    if j == 0:
                        ys2.append([o, acc_f if fw == "px4" else 0.0])
                    for _s in range(L.sub):
                        t = i * fh - af.delay_s
                        kk = math.floor(t / T + 1e-9)
                        vin = v[kk] if kk >= 0 else 0.0
                        f2.append(C[0] @ x)
                        x = Phi @ x + Gam[:, 0] * vin
                        i += 1
            ys2, f2 = np.array(ys2), np.array(f2)
            scale = max(1.0, float(np.max(np.abs(ys2))))
            out.append({"airframe": af.name, "firmware": fw,
                        "max_rel_diff_sampled": float(np.max(np.abs(ys - ys2)) / scale),
                        "max_abs_diff_fine": float(np.max(np.abs(fines - f2)))})
    return out


def _tuner_law(structure: str, gains: dict, dt: float):
    from tuner import get_structure

    c = get_structure(structure).tf(gains, dt)
    A, B, C, D, Br, Dr = c._two_input()
    return np.atleast_2d(A), np.ravel(B), np.ravel(C), float(np.ravel(D)[0]), np.ravel(Br), float(np.ravel(Dr)[0])


def check_laws_against_tuner(n: int = 800) -> list[dict]:
    """Step responses (r = 1 rad/s from rest) of the bench's law and of tuner's transfer functions on the same
    sampled plant (raw rate = loop rate), sample by sample."""
    out = []
    cases = [("px4", "px4_rate", {**PX4_DEFAULTS, "P": 0.18, "I": 0.5, "D": 0.005, "FF": 0.02}),
             ("ardupilot", "ardupilot_rate", {**AP_DEFAULTS, "P": 0.16, "I": 0.3, "D": 0.004, "FF": 0.02,
                                               "flte_hz": 5.0})]
    for af0 in AIRFRAMES.values():
        # the delay rounded to whole loop samples: with the raw rate at the loop rate it must be whole raw samples
        af = replace(af0, delay_s=round(af0.delay_s / af0.dt) * af0.dt)
        for fw, st, g0 in cases:
            g = {**g0, **{k: g0[k] * af.start_scale for k in ("P", "I", "D")}}  # flyable on the racer too
            L = lift(af, fw, raw_hz=af.loop_hz, dgyro_hz=g.get("dgyro_hz"))
            law = make_law(fw, g, af.dt, linear=True)
            fixed = ({k: g[k] for k in ("K", "dgyro_hz", "int_lim")} if fw == "px4"
                     else {k: g[k] for k in ("fltt_hz", "flte_hz", "fltd_hz", "imax")})
            A, B, C, D, Br, Dr = _tuner_law(st, {**{k: g[k] for k in ("P", "I", "D", "FF")}, **fixed}, af.dt)
            X1 = np.zeros(L.nx)
            X2 = np.zeros(L.nx)
            xc = np.zeros(A.shape[0])
            u1s, u2s, y1s, y2s = [], [], [], []
            for _k in range(n):
                y1 = L.Cy @ X1
                u1 = law.step(1.0, y1[0], y1[1])
                y2 = L.Cy @ X2
                u2 = C @ xc + Dr * 1.0 - D * y2[0]
                xc = A @ xc + Br * 1.0 - B * y2[0]
                X1 = L.F @ X1 + L.G[:, 0] * u1
                X2 = L.F @ X2 + L.G[:, 0] * u2
                u1s.append(u1)
                u2s.append(float(u2))
                y1s.append(y1[0])
                y2s.append(y2[0])
            u1s, u2s, y1s, y2s = map(np.array, (u1s, u2s, y1s, y2s))
            out.append({"airframe": af.name, "law": st,
                        "max_rel_diff_u": float(np.max(np.abs(u1s - u2s)) / np.max(np.abs(u1s))),
                        "max_rel_diff_y": float(np.max(np.abs(y1s - y2s)) / np.max(np.abs(y1s)))})
    return out


def check_gmvc() -> dict:
    sigma = 0.1
    dt = sigma * math.log(2) / 2
    kc, ki, kd = gmvc([0.1, 0.06, 0.04], [1.0, -1.5, 0.5], dt, sigma, 0.0, 0.7)
    hand = (5 / 6, 0.05 / dt, 0.75 * dt)
    return {"dt": dt, "port": [kc, ki, kd], "hand": list(hand),
            "max_rel_diff": max(abs(a - b) / abs(b) for a, b in zip((kc, ki, kd), hand))}


def run_checks() -> dict:
    return {"lift_vs_bruteforce": check_lift(), "laws_vs_tuner": check_laws_against_tuner(), "gmvc": check_gmvc()}
