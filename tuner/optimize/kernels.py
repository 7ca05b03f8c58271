"""The batch's compiled kernels (numba): the frequency responses and margins of a batch of candidates, and the
sampled-data step responses with their settling, overshoot, control peak, ITAE, IAE and load recovery.

Imported only through :func:`tuner.optimize.batch.kernels` (never by ``import tuner`` or ``tuner analyze``): numba
takes about half a second to import. Compiled with ``cache=True`` into ``<cache>/numba``
(:func:`tuner.optimize.cachedir.cache_root`, only where :func:`~tuner.optimize.cachedir.trusted_root` accepts it: else
into a private folder of the process's own), so a machine compiles them once; :func:`warm` compiles every kernel
and writes the ready mark the batch looks for (:func:`tuner.optimize.cachedir.kernels_ready_mark`).
Each kernel computes what :mod:`tuner.optimize.batch`'s numpy path computes, row by row, in the same order of
operations where it can (the state recursion is sequential here, by doubling there: the responses agree to
rounding); the numpy path stays the reference (tests/tuner/test_kernels.py) and the fallback.
"""

from __future__ import annotations

import math
import os

from .cachedir import kernels_ready_mark, trusted_dir, trusted_root

__all__ = ["c_and_l", "margins", "step_sampled", "warm"]


# numba's cache holds pickled indexes and machine code, loaded as they are: only from a root trusted_root accepts (the
# user's own, writable by no one else), as the NLP code cache; from any other, a private folder of this process's own
# (compiled again, never loaded from a folder someone else could write)
# (a NUMBA_CACHE_DIR set beforehand is held to the same rule: taken only if it is a folder of this user's that no one
# else can write; the private folder is removed when the process ends)
_ROOT = trusted_root()
_PRESET = os.environ.get("NUMBA_CACHE_DIR", "").strip()
if _PRESET and trusted_dir(_PRESET) is None:
    _PRESET = ""
if _PRESET:
    os.environ["NUMBA_CACHE_DIR"] = _PRESET
elif _ROOT is not None:
    os.environ["NUMBA_CACHE_DIR"] = str(_ROOT / "numba")
else:
    import atexit
    import shutil
    import tempfile

    os.environ["NUMBA_CACHE_DIR"] = _OWN = tempfile.mkdtemp(prefix="tuner-numba-")
    atexit.register(shutil.rmtree, _OWN, ignore_errors=True)

import numba as nb  # noqa: E402 - after NUMBA_CACHE_DIR is set
import numpy as np  # noqa: E402

_JIT = {"cache": True, "nogil": True, "error_model": "numpy"}


@nb.njit(**_JIT)
def c_and_l(num, den, x, G):
    """C(x) by Horner (num, den (B, m+1); x the grid's s or z values) and L = C G, both (B, W)."""
    B, M = num.shape
    W = x.shape[0]
    C = np.empty((B, W), np.complex128)
    L = np.empty((B, W), np.complex128)
    for b in range(B):
        for j in range(W):
            cn = 0j
            cd = 0j
            xj = x[j]
            for k in range(M):
                cn = cn * xj + num[b, k]
                cd = cd * xj + den[b, k]
            c = cn / cd
            C[b, j] = c
            L[b, j] = c * G[j]
    return C, L


@nb.njit(**_JIT)
def _mod(a, b):
    # numpy's float remainder (the sign of the divisor)
    r = np.fmod(a, b)
    if r != 0.0 and ((b < 0.0) != (r < 0.0)):
        r += b
    return r


@nb.njit(**_JIT)
def _crossing(L, b, c, lm, ph, shift):
    """The gain crossing of row ``b`` between grid points ``c`` and ``c + 1`` (linear in L): its fraction along the
    interval and its phase margin, signed by the unwrapped phase ``ph`` (less ``shift``) within +-180 deg, else the
    distance from -1 (as ``tuner.optimize.batch._frequency_metrics``)."""
    f = lm[c] / (lm[c] - lm[c + 1])
    Lc = L[b, c] + f * (L[b, c + 1] - L[b, c])
    pmv = 180.0 - abs(math.degrees(math.atan2(Lc.imag, Lc.real)))
    p0c = ph[c] - shift
    pc = p0c + f * ((ph[c + 1] - shift) - p0c)
    signed = 180.0 + math.degrees(pc)
    if math.isfinite(signed) and -180.0 <= signed <= 180.0 and \
            abs(abs(_mod(signed + 180.0, 360.0) - 180.0) - pmv) < 1e-3:
        pmv = signed
    return f, pmv


@nb.njit(**_JIT)
def margins(L, lw, ends):
    """Per row of ``L`` (B, W) on the log grid ``lw``: the phase margin (signed as the verifier's: 180 + the phase
    unwrapped along the grid, within +-180, else the distance), its crossover, the upper and lower gain margins (dB)
    and the phase crossover; ``ends`` (B, e): the real parts of L at DC and Nyquist where finite (gain factors, no
    frequency). The same rules as ``tuner.optimize.batch._frequency_metrics``."""
    B, W = L.shape
    pm = np.full(B, np.inf)
    wc = np.full(B, np.nan)
    gm = np.empty(B)
    gml = np.empty(B)
    wp = np.full(B, np.nan)
    lm = np.empty(W)
    ph = np.empty(W)
    pi = math.pi
    for b in range(B):
        for j in range(W):
            lm[j] = math.log(abs(L[b, j]))
        # gain crossings
        have = False
        for c in range(W - 1):
            if lm[c] * lm[c + 1] < 0 and math.isfinite(lm[c]) and math.isfinite(lm[c + 1]):
                have = True
                break
        if have:  # the phase unwrapped along the row (np.unwrap), from the principal angle at the lowest frequency
            p0 = math.atan2(L[b, 0].imag, L[b, 0].real)
            ph[0] = p0
            acc = 0.0
            prev = p0
            for j in range(1, W):
                pj = math.atan2(L[b, j].imag, L[b, j].real)
                d = pj - prev
                dd = _mod(d + pi, 2 * pi) - pi
                if dd == -pi and d > 0:
                    dd = pi
                corr = dd - d
                if abs(d) < pi:
                    corr = 0.0
                acc += corr
                ph[j] = pj + acc
                prev = pj
            shift = 2 * pi if ph[0] > pi / 2 + 1e-9 else 0.0
            for c in range(W - 1):
                if not (lm[c] * lm[c + 1] < 0 and math.isfinite(lm[c]) and math.isfinite(lm[c + 1])):
                    continue
                f, pmv = _crossing(L, b, c, lm, ph, shift)
                if not math.isnan(pm[b]) and (math.isnan(pmv) or pmv < pm[b]):  # np.minimum: nan sticks
                    pm[b] = pmv
            # the crossover: the last crossing whose margin is the row's
            for c in range(W - 1):
                if not (lm[c] * lm[c + 1] < 0 and math.isfinite(lm[c]) and math.isfinite(lm[c + 1])):
                    continue
                f, pmv = _crossing(L, b, c, lm, ph, shift)
                if pmv == pm[b]:
                    wc[b] = math.exp(lw[c] + f * (lw[c + 1] - lw[c]))
        # real-axis crossings (finite, |L| < 1e9), then the ends
        up = np.inf
        lo = 0.0
        for c in range(W - 1):
            l0 = L[b, c]
            l1 = L[b, c + 1]
            if not (l0.imag * l1.imag < 0):
                continue
            if not (math.isfinite(l0.real) and math.isfinite(l0.imag) and abs(l0) < 1e9
                    and math.isfinite(l1.real) and math.isfinite(l1.imag) and abs(l1) < 1e9):
                continue
            g = l0.imag / (l0.imag - l1.imag)
            re = l0.real + g * (l1.real - l0.real)
            if re < 0:
                k = -1.0 / re
                if k > 1.0:
                    if k <= up:
                        up = k
                        wp[b] = math.exp(lw[c] + g * (lw[c + 1] - lw[c]))
                elif k > lo:
                    lo = k
        for e in range(ends.shape[1]):
            re = ends[b, e]
            if re < 0:
                k = -1.0 / re
                if k > 1.0:
                    if k <= up:
                        up = k
                        wp[b] = np.nan
                elif k > lo:
                    lo = k
        gm[b] = 20 * math.log10(up)
        gml[b] = 20 * math.log10(lo) if lo > 0 else -np.inf
    return pm, wc, gm, gml, wp


@nb.njit(**_JIT)
def step_sampled(A, Bv, Cy, dy, Cu, du, Ca, da, Cf, Df, n, K, dt, offsets, yf, band, need_itae, need_iae,
                 need_recovery, share):
    """The unit step responses of sampled-data closed loops ``z+ = A z + Bv`` (B, nz) from rest over K samples,
    each row's output between samples by its lifted rows (``Cf`` (nf, n), ``Df``; nf = 0: the samples alone,
    ``offsets`` the rows' instants within a sample), normalised by ``yf``: per row the settling time (the last time
    |y/yf - 1| > band, interpolated; inf if outside at the end or not finite), overshoot %, max |u|, and where asked
    the ITAE of 1 - y, the IAE of y (a load step: yf is not used) and the load recovery (the last time |y| is above
    ``share`` of its peak, interpolated; inf if not back at the end, 0 if never above)."""
    Bn, nz = Bv.shape
    nf = Cf.shape[0]
    P = K * nf if nf else K
    ts = np.empty(Bn)
    ov = np.empty(Bn)
    cpk = np.empty(Bn)
    itae = np.full(Bn, np.nan)
    iae = np.full(Bn, np.nan)
    rec = np.full(Bn, np.nan)
    z = np.empty(nz)
    zn = np.empty(nz)
    y = np.empty(P)
    t = np.empty(P)
    for b in range(Bn):
        for i in range(nz):
            z[i] = 0.0
        umax = 0.0
        for k in range(K):
            u = du[b]
            for i in range(nz):
                u += Cu[b, i] * z[i]
            if not math.isnan(umax) and not (abs(u) <= umax):  # np.max: nan sticks
                umax = abs(u)
            if nf:
                ua = da[b]
                for i in range(nz):
                    ua += Ca[b, i] * z[i]
                for j in range(nf):
                    v = 0.0
                    for i in range(n):
                        v += z[i] * Cf[j, i]
                    y[k * nf + j] = v + ua * Df[j]
                    t[k * nf + j] = k * dt + offsets[j]
            else:
                v = dy[b]
                for i in range(nz):
                    v += Cy[b, i] * z[i]
                y[k] = v
                t[k] = k * dt
            for i in range(nz):
                s = Bv[b, i]
                for j in range(nz):
                    s += A[b, i, j] * z[j]
                zn[i] = s
            for i in range(nz):
                z[i] = zn[i]
        cpk[b] = umax
        # step metrics on y / yf
        fin = True
        for p in range(P):
            if not math.isfinite(y[p]):
                fin = False
                break
        mx = -np.inf
        last = -1
        for p in range(P):
            yn = y[p] / yf[b]
            if not math.isnan(mx) and not (yn <= mx):
                mx = yn
            if abs(yn - 1.0) > band:
                last = p
        ov[b] = np.nan if math.isnan(mx) else max(0.0, (mx - 1.0) * 100.0)
        if last == P - 1 or not fin or not (math.isfinite(yf[b]) and yf[b] != 0):
            ts[b] = np.inf
        elif last < 0:
            ts[b] = 0.0
        else:
            y0 = y[last] / yf[b]
            y1 = y[last + 1] / yf[b]
            level = 1.0 + band if y0 > 1.0 else 1.0 - band
            frac = (level - y0) / (y1 - y0) if y1 != y0 else 1.0
            ts[b] = t[last] + frac * (t[last + 1] - t[last])
        if need_itae:
            s = 0.0
            for p in range(P - 1):
                s += (t[p + 1] - t[p]) * (t[p + 1] * abs(1.0 - y[p + 1]) + t[p] * abs(1.0 - y[p])) / 2.0
            itae[b] = s
        if need_iae or need_recovery:
            s = 0.0
            for p in range(P - 1):
                s += (t[p + 1] - t[p]) * (abs(y[p + 1]) + abs(y[p])) / 2.0
            iae[b] = s
            if need_recovery:
                peak = -np.inf
                for p in range(P):
                    a = abs(y[p])
                    if not math.isnan(peak) and not (a <= peak):
                        peak = a
                thr = share * peak
                lastu = -1
                for p in range(P):
                    if abs(y[p]) > thr:
                        lastu = p
                if lastu == P - 1:
                    rec[b] = np.inf
                elif lastu < 0:
                    rec[b] = 0.0
                else:
                    e0 = abs(y[lastu])
                    e1 = abs(y[lastu + 1])
                    t0 = t[lastu]
                    t1 = t[lastu + 1]
                    rec[b] = t0 + (e0 - thr) / (e0 - e1) * (t1 - t0) if e0 > e1 else t1
    return ts, ov, cpk, itae, iae, rec


def warm() -> float:
    """Compile (or load from the cache) every kernel on small inputs and write the ready mark
    (:func:`tuner.optimize.cachedir.kernels_ready_mark`); the seconds it took."""
    import time

    t0 = time.perf_counter()
    num = np.array([[1.0, 2.0, 1.0]])
    den = np.array([[1.0, -1.0, 0.0]])
    x = np.exp(1j * np.linspace(0.1, 3.0, 5))
    G = 0.5 / (x - 0.5)
    _, L = c_and_l(num, den, x, G)
    margins(L, np.log(np.linspace(0.1, 3.0, 5)), np.zeros((1, 1)))
    A = np.array([[[0.5]]])
    e1, e0 = np.ones((1, 1)), np.zeros(1)
    for nf in (0, 2):
        step_sampled(A, e1, e1, e0, e1, e0, e1, e0, np.ones((nf, 1)), np.ones(nf), 1, 4, 0.1, np.zeros(nf),
                     np.ones(1), 0.02, True, True, True, 0.02)
    if _ROOT is None:  # (compiled into this process's own folder: no other process can use them)
        return time.perf_counter() - t0
    mark = kernels_ready_mark()
    mark.parent.mkdir(parents=True, exist_ok=True)
    tmp = mark.with_name(mark.name + f".{os.getpid()}.tmp")
    tmp.write_text(f"{numba_version()}\n")
    os.replace(tmp, mark)
    return time.perf_counter() - t0


def numba_version() -> str:
    """The numba the kernels are compiled with."""
    return nb.__version__


if __name__ == "__main__":  # python -m tuner.optimize.kernels: compile the kernels into the cache
    print(f"tuner kernels compiled in {warm():.1f} s into {os.environ['NUMBA_CACHE_DIR']}")
