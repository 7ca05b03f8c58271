"""Independent reference computations for the tests.

Nothing here imports ``tuner``: every figure is recomputed with numpy/scipy
directly from open-loop numerator/denominator polynomials (highest power first),
so a test that compares the library against these functions compares two
independent code paths.

* :func:`nyquist_margins` evaluates ``L`` on a dense grid (200k+ points by
  default), finds where ``|L|`` crosses 1 and where ``L`` crosses the negative
  real axis by sign changes and linear interpolation, and derives the worst phase
  margin and the upper/lower gain margins from them.
* :func:`stable_at_gain` decides closed-loop stability of ``k*L`` from the roots of
  ``den + k*num``, which checks the gain margins a second, unrelated way.
* :func:`fine_step` simulates a sampled-data loop on a fine grid by the matrix
  exponential of the plant driven by the staircase control signal.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import linalg, signal

GRID_POINTS = 250_000


def _shift_to_one(p):
    """Coefficients of q(x) = p(x + 1): polynomials in x = z - 1."""
    q = np.zeros(1)
    for c in np.asarray(p, float):  # Horner: q <- q*(x+1) + c
        q = np.polyadd(np.polymul(q, [1.0, 1.0]), [c])
    return q


def eval_L(num, den, w, dt=None):
    """L at frequencies ``w`` (rad/s).

    Discrete loops are evaluated in x = z - 1 = 2j sin(theta/2) exp(j theta/2), theta = w dt,
    which has no cancellation near z = 1 (where the expanded polynomials of a type-2 loop lose
    every digit), and gives z = -1 exactly at theta = pi.
    """
    w = np.asarray(w, dtype=float)
    if dt is None:
        x = 1j * w
        return np.polyval(num, x) / np.polyval(den, x)
    th = w * dt
    x = 2j * np.sin(th / 2) * np.exp(0.5j * th)
    x[np.isclose(th, math.pi, rtol=0, atol=1e-15)] = -2.0
    return np.polyval(_shift_to_one(num), x) / np.polyval(_shift_to_one(den), x)


def dense_grid(dt=None, wmin=1e-5, wmax=1e5, n=GRID_POINTS):
    if dt is not None:
        wmax = math.pi / dt
        g = np.logspace(math.log10(wmin), math.log10(wmax), n)
        g[-1] = wmax
        return g
    return np.logspace(math.log10(wmin), math.log10(wmax), n)


def _wrap180(deg):
    return (np.asarray(deg) + 180.0) % 360.0 - 180.0


def nyquist_margins(num, den, dt=None, *, wmin=1e-5, wmax=1e5, n=GRID_POINTS):
    """Brute-force margins from a dense Nyquist evaluation.

    Returns a dict: ``pm`` (the smallest distance in phase from -1 over all gain crossings, deg, inf if none),
    ``wc`` (its frequency), ``gm_db`` (upper, +inf if none), ``gml_db`` (lower,
    -inf if none), ``real_points`` (the negative-real-axis crossings found).
    """
    num = np.asarray(num, float)
    den = np.asarray(den, float)
    w = dense_grid(dt, wmin, wmax, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        L = eval_L(num, den, w, dt)
    fin = np.isfinite(L)

    # gain crossings |L| = 1
    m = np.log(np.abs(L))
    i = np.flatnonzero((np.sign(m[:-1]) * np.sign(m[1:]) < 0) & fin[:-1] & fin[1:])
    pms, wcs = [], []
    for k in i:
        t = m[k] / (m[k] - m[k + 1])
        ph0 = np.angle(L[k])
        dph = np.angle(L[k + 1] / L[k])
        ph = ph0 + t * dph
        pms.append(abs(float(_wrap180(math.degrees(ph) + 180.0))))  # distance in phase from -1
        wcs.append(float(w[k] + t * (w[k + 1] - w[k])))
    if pms:
        j = int(np.argmin(pms))
        pm, wc = pms[j], wcs[j]
    else:
        pm, wc = math.inf, math.nan

    # negative-real-axis crossings: Im L changes sign with Re L < 0, not through infinity
    im, re = L.imag, L.real
    i = np.flatnonzero((np.sign(im[:-1]) * np.sign(im[1:]) < 0) & fin[:-1] & fin[1:])
    xs = []
    for k in i:
        if max(abs(L[k]), abs(L[k + 1])) > 1e9:
            continue
        t = im[k] / (im[k] - im[k + 1])
        x = re[k] + t * (re[k + 1] - re[k])
        xs.append(float(x))
    # endpoints where L is real
    if dt is None:
        if abs(np.polyval(den, 0.0)) > 0:
            xs.append(float(np.polyval(num, 0.0) / np.polyval(den, 0.0)))
        if num.size == den.size:
            xs.append(float(num[0] / den[0]))
    else:
        if abs(np.polyval(den, 1.0)) > 1e-12:
            xs.append(float(np.polyval(num, 1.0) / np.polyval(den, 1.0)))
        if abs(np.polyval(den, -1.0)) > 1e-12:
            xs.append(float(np.polyval(num, -1.0) / np.polyval(den, -1.0)))
    ks = [-1.0 / x for x in xs if x < 0]
    up = [k for k in ks if k > 1.0]
    lo = [k for k in ks if k < 1.0]
    gm_db = 20 * math.log10(min(up)) if up else math.inf
    gml_db = 20 * math.log10(max(lo)) if lo else -math.inf
    return {"pm": pm, "wc": wc, "gm_db": gm_db, "gml_db": gml_db, "real_points": xs, "w": w, "L": L}


def closed_loop_roots(num, den, k=1.0):
    """Roots of the characteristic polynomial den + k*num (no cancellation)."""
    return np.roots(np.polyadd(np.asarray(den, float), k * np.asarray(num, float)))


def stable_at_gain(num, den, k=1.0, dt=None):
    r = closed_loop_roots(num, den, k)
    if dt is None:
        return bool(np.all(r.real < 0))
    return bool(np.all(np.abs(r) < 1.0))


def disk_margin_bruteforce(L):
    """Balanced (skew 0) disk margin: min over w of 2|1+L|/|1-L|."""
    L = L[np.isfinite(L)]
    return float(np.min(2 * np.abs(1 + L) / np.abs(1 - L)))


def ms_bruteforce(L):
    L = L[np.isfinite(L)]
    return float(np.max(1 / np.abs(1 + L)))


# -- time domain -----------------------------------------------------------------------

def settling_time(t, y, yfinal, band=0.02):
    """Last time |y - yf| > band*|yf| (linear interpolation on the given grid); 0 if always inside."""
    e = np.abs(y / yfinal - 1.0)
    out = np.flatnonzero(e > band)
    if out.size == 0:
        return 0.0
    j = int(out[-1])
    assert j < y.size - 1, "not settled within the simulated horizon"
    yn = y / yfinal
    level = 1 + band if yn[j] > 1 else 1 - band
    return float(t[j] + (level - yn[j]) / (yn[j + 1] - yn[j]) * (t[j + 1] - t[j]))


def ss_of_tf(num, den):
    """Controllable-canonical state space of a strictly proper or proper num/den (scipy)."""
    A, B, C, D = signal.tf2ss(num, den)
    return A, B, C, D


def fine_step(plant_num, plant_den, u, dt, n_per_sample):
    """Continuous plant driven through a ZOH by the sequence ``u`` (one value per ``dt``).

    Exact at ``n_per_sample`` instants per sample, via the matrix exponential.
    Returns (t, y) with t = 0, h, 2h, ... (len(u)*n_per_sample points).
    """
    A, B, C, D = ss_of_tf(plant_num, plant_den)
    nx = A.shape[0]
    h = dt / n_per_sample
    M = np.zeros((nx + 1, nx + 1))
    M[:nx, :nx] = A
    M[:nx, nx:] = B
    E = linalg.expm(M * h)
    Ad, Bd = E[:nx, :nx], E[:nx, nx:]
    x = np.zeros((nx, 1))
    ys = []
    for uk in u:
        for _ in range(n_per_sample):
            ys.append(float((C @ x + D * uk)[0, 0]))
            x = Ad @ x + Bd * uk
    t = np.arange(len(ys)) * h
    return t, np.asarray(ys)


# -- loops built without the library ---------------------------------------------------------

def zoh(num, den, dt):
    """ZOH equivalent of a continuous num/den by the augmented matrix exponential.

    Returns (numd, dend), dend monic, numd with leading zeros removed.
    """
    A, B, C, D = signal.tf2ss(np.asarray(num, float), np.asarray(den, float))
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n:] = A, B
    E = linalg.expm(M * dt)
    b, a = signal.ss2tf(E[:n, :n], E[:n, n:], C, D)
    b = np.atleast_1d(np.squeeze(b))
    b[np.abs(b) < 1e-14 * np.max(np.abs(b))] = 0.0
    return np.trim_zeros(b, "f") / a[0], a / a[0]


def open_loop(plant_num, plant_den, c_num, c_den, dt=None, plant_is_discrete=False):
    """Open-loop num/den of C*G (sampled-data: C(z) * ZOH[G](z)), no cancellation."""
    gn, gd = np.asarray(plant_num, float), np.asarray(plant_den, float)
    if dt is not None and not plant_is_discrete:
        gn, gd = zoh(gn, gd, dt)
    return np.polymul(np.asarray(c_num, float), gn), np.polymul(np.asarray(c_den, float), gd)


def polyprod(*factors):
    """Product of polynomials given as coefficient lists."""
    out = np.ones(1)
    for f in factors:
        out = np.polymul(out, np.asarray(f, float))
    return out


def pid_backward_euler(g, dt):
    """The backward-Euler PID of tuner/controllers.py written out: Kp + Ki dt z/(z-1) + Kd (z-1)/((Tf+dt) z - Tf)
    (num, den in z, highest power first)."""
    kp, ki, kd, tf = g["Kp"], g["Ki"], g["Kd"], g["Tf"]
    a = [tf + dt, -tf]
    num = np.polyadd(np.polyadd(np.polymul([kp], np.polymul([1, -1], a)), np.polymul([ki * dt, 0], a)),
                     np.polymul([kd, -kd], [1, -1]))
    return num, np.polymul([1, -1], a)


def mks_sampled(c_num, c_den, plant_num, plant_den, dt, n=GRID_POINTS):
    """max |C/(1 + C G_zoh)| on a dense grid up to the Nyquist frequency (the plant's ZOH built here)."""
    w = dense_grid(dt, n=n)
    L = eval_L(*open_loop(plant_num, plant_den, c_num, c_den, dt=dt), w, dt=dt)
    C = eval_L(c_num, c_den, w, dt=dt)
    return float(np.max(np.abs(C / (1 + L))))


def closed_loop_step(plant_num, plant_den, c_num, c_den, dt, *, delay_samples=0, n_per_sample=20, samples=2000):
    """Unit-step response of the sampled-data loop: the discrete controller ``c_num/c_den`` (in z, highest power
    first) acting on e = 1 - y(k dt), its output held (ZOH) and delayed by ``delay_samples`` samples into the
    continuous plant, which is integrated exactly (matrix exponential) at ``n_per_sample`` points per sample.
    Returns (t, y) over ``samples`` samples."""
    A, B, C, D = signal.tf2ss(np.asarray(c_num, float), np.asarray(c_den, float))
    An, Bn, Cn, _ = ss_of_tf(plant_num, plant_den)
    nx = An.shape[0]
    h = dt / n_per_sample
    M = np.zeros((nx + 1, nx + 1))
    M[:nx, :nx], M[:nx, nx:] = An, Bn
    E = linalg.expm(M * h)
    Ad, Bd = E[:nx, :nx], E[:nx, nx:]
    xc = np.zeros((A.shape[0], 1))
    xp = np.zeros((nx, 1))
    ubuf = [0.0] * int(delay_samples)
    ys = np.empty(samples * n_per_sample)
    for k in range(samples):
        e = 1.0 - float((Cn @ xp)[0, 0])
        u = (float((C @ xc)[0, 0]) if A.size else 0.0) + float(D[0, 0]) * e
        if A.size:
            xc = A @ xc + B * e
        ubuf.append(u)
        ua = ubuf.pop(0)
        for j in range(n_per_sample):
            ys[k * n_per_sample + j] = float((Cn @ xp)[0, 0])
            xp = Ad @ xp + Bd * ua
    return np.arange(ys.size) * h, ys
