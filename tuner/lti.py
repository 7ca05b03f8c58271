"""Well-conditioned numerics of SISO LTI systems: factored forms, cascade state space, ZOH, responses.

High-degree polynomials are never evaluated or factored here. A system is held as its zeros,
poles and gain (:class:`Zpk`) and realised as a **cascade of first- and second-order sections**
(:func:`realize`): block lower-triangular, each section scaled to unit gain at its own corner
frequency and the whole balanced (exact power-of-two scaling, ``scipy.linalg.matrix_balance``).
In that form a matrix exponential (ZOH), an eigenvalue problem (closed-loop poles) and a frequency
response are as accurate as the data: ``1/(s+1)^8`` is eight bidiagonal first-order sections, not
a companion matrix whose coefficients span five decades.

* :func:`zoh` / :func:`zoh_delayed`: exact ZOH equivalents (the delayed one for a delay that is not a
  whole number of steps: the input held on a shifted grid, still exact for a piecewise-constant input);
  :func:`zoh_fractional`: the same as one discrete realisation with one extra state (the previous input),
  the ZOH of ``G(s) e^{-s phi}`` for ``0 < phi < dt`` (MATLAB's ``c2d`` of a delayed model);
* :func:`freqresp`: ``C (xI - A)^{-1} B + D`` at many ``x`` (``s = jw`` or ``z = e^{jw dt}``) by a
  complex Schur form and vectorised back substitution;
* :func:`invariant_zeros`: the finite zeros of ``(A, B, C, D)`` from the Rosenbrock pencil.

numpy and scipy.linalg only (cheap to import).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg

from .tolerances import REAL_ROOT_TOL, SAMPLE_FRACTION_TOL

__all__ = ["Zpk", "SS", "realize", "series", "zoh", "zoh_delayed", "zoh_fractional", "freqresp", "invariant_zeros",
           "zpk_from_ss", "conjugate_pairs", "poly_from_roots", "lifted_outputs"]

_IMAG_TOL = REAL_ROOT_TOL


@dataclass(frozen=True, eq=False)
class Zpk:
    """Zeros, poles and gain: ``G(x) = k prod(x - z_i) / prod(x - p_j)`` (``x`` = s, or z)."""

    zeros: np.ndarray
    poles: np.ndarray
    gain: float

    def __call__(self, x: np.ndarray | complex) -> np.ndarray:
        """``G(x)`` from the factors, summed in logs: each factor is exact to rounding, and no partial
        product over- or underflows (``1e28 / (s^2 + 1e-8)`` at 1e16 rad/s is 1e-4, where a realisation's
        eigenvector form cancels to 2.5); ``inf`` at a pole, 0 at a zero."""
        x = np.asarray(x, dtype=complex)
        if self.gain == 0:
            return np.zeros_like(x)
        with np.errstate(divide="ignore", invalid="ignore"):
            lg = np.full(x.shape, complex(math.log(abs(self.gain)), 0.0 if self.gain > 0 else math.pi))
            for z in self.zeros:
                lg = lg + np.log(x - z)
            for p in self.poles:
                lg = lg - np.log(x - p)
            # a pole cancelled by a zero at the very point is undefined: nan, not exp(nan)'s arbitrary value
            return np.where(np.isnan(lg), complex(np.nan, np.nan), np.exp(lg))


@dataclass(frozen=True, eq=False)
class SS:
    """A SISO state-space model ``x' = A x + B u, y = C x + D u`` (B a column, C a row, as 1-D arrays)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: float
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def n(self) -> int:
        """The number of states."""
        return self.A.shape[0]

    def schur(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Complex Schur form: ``A = Q T Q^H``; returns ``(T, Q^H B, C Q)``."""
        if "schur" not in self._cache:
            if self.n == 0:
                self._cache["schur"] = (np.zeros((0, 0), complex), np.zeros(0, complex), np.zeros(0, complex))
            else:
                T, Q = linalg.schur(self.A.astype(complex), output="complex")
                self._cache["schur"] = (T, Q.conj().T @ self.B.astype(complex), self.C.astype(complex) @ Q)
        return self._cache["schur"]


def trim_leading(p: np.ndarray) -> np.ndarray:
    """``np.trim_zeros(p, "f")`` of a 1-D array (a view of ``p`` from its first nonzero entry; empty if all are 0),
    without its general machinery: it runs on every controller a search builds, where numpy's costs more than the
    rest of the controller's factoring."""
    nz = np.flatnonzero(p)
    return p[nz[0]:] if nz.size else p[:0]


def polymul(a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray) -> np.ndarray:
    """``np.polymul(a, b)`` of two 1-D real coefficient arrays, bitwise (``poly1d``'s leading zeros trimmed, an all-zero
    operand taken as ``[0.]``, then the same ``np.convolve``), without building ``poly1d`` objects."""
    a, b = (np.atleast_1d(np.asarray(c)) for c in (a, b))
    return np.convolve(trim_or_zero(a), trim_or_zero(b))


def trim_or_zero(p: np.ndarray) -> np.ndarray:
    """:func:`trim_leading`, an all-zero (or empty) ``p`` taken as the zero polynomial ``[0.]``."""
    t = trim_leading(p)
    return t if t.size else np.zeros(1)


def conjugate_pairs(roots: np.ndarray) -> tuple[list[complex], list[float]]:
    """Split roots of a real polynomial into complex pairs (one of each, imag > 0) and real roots."""
    roots = np.asarray(roots, dtype=complex)
    scale = np.maximum(np.abs(roots), 1.0)
    is_real = np.abs(roots.imag) <= _IMAG_TOL * scale
    pos = sorted((r for r, ir in zip(roots, is_real) if not ir and r.imag > 0), key=abs)
    neg = [r for r, ir in zip(roots, is_real) if not ir and r.imag < 0]
    if len(pos) != len(neg):  # not conjugate-symmetric: treat the odd ones as real parts
        return [], sorted(float(r.real) for r in roots)
    return pos, sorted(float(r.real) for r, ir in zip(roots, is_real) if ir)


def poly_from_roots(roots: Sequence[complex]) -> np.ndarray:
    """Monic real polynomial with these roots (conjugates completed), for low degree only."""
    pos, real = conjugate_pairs(np.asarray(roots, dtype=complex))
    p = np.ones(1)
    for r in pos:
        p = polymul(p, [1.0, -2.0 * r.real, abs(r) ** 2])
    for r in real:
        p = polymul(p, [1.0, -r])
    return p


def roots_of(p: np.ndarray) -> np.ndarray | None:
    """The roots of the polynomial ``p`` (highest power first; leading zeros are dropped), or None when they cannot
    be computed in double precision: coefficients so far apart that the companion matrix overflows
    (``1e-300 s + 1e300``, a root at -1e600), or a root that is not finite.

    Roots far below the largest come out with an absolute, not a relative, error (``s^4 + 1e100 s + 1e-100``:
    the root near -1e-200 comes out as 0 beside three of magnitude 2e33). Every analysis treats a root that small
    beside the others as at DC already (:attr:`tuner.loop.Loop.integrating`), and a discrete loop's pole at
    ``z = 1e-300`` (a fast pole at a long ``dt``) is at the origin for every purpose: such roots are kept."""
    p = trim_leading(np.asarray(p, dtype=float))
    if p.size <= 1:
        return np.zeros(0, complex)
    with np.errstate(all="ignore"):
        try:
            r = np.roots(p).astype(complex)
        except (np.linalg.LinAlgError, ValueError):
            return None
    return r if np.all(np.isfinite(r)) else None


# -- cascade realisation ----------------------------------------------------------------------

def _factors(roots: np.ndarray) -> list[tuple[np.ndarray, float]]:
    """Real first/second-order monic factors ``(poly, |root|)`` of a root set."""
    pos, real = conjugate_pairs(roots)
    out = [(np.array([1.0, -2.0 * r.real, abs(r) ** 2]), abs(r)) for r in pos]
    out += [(np.array([1.0, -r]), abs(r)) for r in real]
    return out


def _log_ratio(a: float, b: float) -> float:
    """``|log(a / b)|`` for magnitudes that may be 0 or span more than the float range (a pole at 0 and a
    zero at 1e59: the quotient underflows to 0, and its log was a math domain error)."""
    return abs(math.log(min(max(a, 1e-300), 1e300)) - math.log(min(max(b, 1e-300), 1e300)))


def _sections(zpk: Zpk) -> list[tuple[np.ndarray, np.ndarray]]:
    """Proper sections (num, den), poles sorted slow to fast, zeros paired with the nearest poles."""
    dens = sorted(_factors(zpk.poles), key=lambda f: f[1])
    nums = sorted(_factors(zpk.zeros), key=lambda f: -f[0].size)  # quadratics first
    sec = [[np.ones(1), d, m] for d, m in dens]  # num, den, |pole|
    for zf, zm in nums:
        deg = zf.size - 1
        free = [i for i, s in enumerate(sec) if (s[1].size - 1) - (s[0].size - 1) >= deg]
        if not free and deg == 2:  # merge two first-order pole sections that have no zero yet
            ones = [i for i, s in enumerate(sec) if s[1].size == 2 and s[0].size == 1]
            if len(ones) >= 2:
                ones.sort(key=lambda i: _log_ratio(sec[i][2], zm))
                i, j = sorted(ones[:2])
                merged = [np.ones(1), polymul(sec[i][1], sec[j][1]), math.sqrt(max(sec[i][2] * sec[j][2], 0.0))]
                sec = [s for k, s in enumerate(sec) if k not in (i, j)] + [merged]
                free = [len(sec) - 1]
        if not free:  # improper overall cannot happen for a proper system; a gain section absorbs it
            sec.append([np.ones(1), np.ones(1), 1.0])
            free = [len(sec) - 1]
            if deg > 0:
                raise ValueError("improper system: more zeros than poles")
        i = min(free, key=lambda i: _log_ratio(sec[i][2], zm))
        sec[i][0] = polymul(sec[i][0], zf)
    return [(s[0], s[1]) for s in sec]


def _section_ss(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """A scaled realisation of a proper section of order 0, 1 or 2 (den monic)."""
    nd = den.size - 1
    b = np.concatenate([np.zeros(den.size - num.size), num])
    if nd == 0:
        return np.zeros((0, 0)), np.zeros(0), np.zeros(0), float(b[0])
    d = b[0]
    if nd == 1:
        a0 = den[1]
        return np.array([[-a0]]), np.array([1.0]), np.array([b[1] - d * a0]), float(d)
    a1, a0 = den[1], den[2]
    w = math.sqrt(abs(a0)) if a0 != 0 else 1.0
    # x1' = w x2 ; x2' = -(a0/w) x1 - a1 x2 + u  ->  x1 = w/(s^2+a1 s+a0) u, x2 = s/(s^2+a1 s+a0) u
    A = np.array([[0.0, w], [-a0 / w, -a1]])
    C = np.array([(b[2] - d * a0) / w, b[1] - d * a1])
    return A, np.array([0.0, 1.0]), C, float(d)


def series(first: SS, second: SS) -> SS:
    """``second`` driven by the output of ``first``."""
    n1, n2 = first.n, second.n
    A = np.zeros((n1 + n2, n1 + n2))
    A[:n1, :n1] = first.A
    A[n1:, :n1] = np.outer(second.B, first.C)
    A[n1:, n1:] = second.A
    B = np.concatenate([first.B, second.B * first.D])
    C = np.concatenate([second.D * first.C, second.C])
    return SS(A, B, C, second.D * first.D)


def realize(zpk: Zpk, *, discrete: bool = False) -> SS:
    """A balanced cascade realisation of ``zpk`` (continuous, or discrete: the same algebra in z)."""
    secs = _sections(zpk)
    out = SS(np.zeros((0, 0)), np.zeros(0), np.zeros(0), 1.0)
    gain = float(zpk.gain)
    for num, den in secs:
        # unit gain at the section's corner (|pole| in s; the point on the unit circle at its angle in z)
        r = np.roots(den) if den.size > 1 else np.zeros(0)
        if discrete:
            ang = float(np.max(np.abs(np.angle(r)))) if r.size else 0.0
            x0 = np.exp(1j * max(ang, 1e-3))
        else:
            x0 = 1j * (float(np.max(np.abs(r))) if r.size and np.max(np.abs(r)) > 0 else 1.0)
        v = abs(np.polyval(num, x0) / np.polyval(den, x0))
        s = 1.0 / v if np.isfinite(v) and v > 0 else 1.0
        gain /= s
        A, B, C, D = _section_ss(num * s, den)
        out = series(out, SS(A, B, C, D))
    out = SS(out.A, out.B, out.C * gain, out.D * gain)
    if out.n:
        _, (sc, perm) = linalg.matrix_balance(out.A, permute=False, separate=True)
        A = out.A / sc[:, None] * sc[None, :]
        out = SS(A, out.B / sc, out.C * sc, out.D)
    return out


# -- discretisation ---------------------------------------------------------------------------

def _int_expm(A: np.ndarray, B: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """``(e^{A t}, int_0^t e^{A s} ds B)`` from one augmented matrix exponential."""
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = A * t, B * t
    E = linalg.expm(M)
    return E[:n, :n], E[:n, n]


def zoh(sys: SS, dt: float) -> SS:
    """Exact zero-order-hold equivalent at ``dt``."""
    if sys.n == 0:
        return SS(np.zeros((0, 0)), np.zeros(0), np.zeros(0), sys.D)
    Phi, Gam = _int_expm(sys.A, sys.B, dt)
    return SS(Phi, Gam, sys.C.copy(), sys.D)


def zoh_delayed(sys: SS, h: float, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, float]:
    """Exact ZOH of ``x' = A x + B u(t - tau)`` at step ``h``, ``u`` constant on ``[kh, (k+1)h)``.

    ``tau = m h + f`` (``0 <= f < h``): ``x[k+1] = Phi x[k] + Gam_old u[k-m-1] + Gam_new u[k-m]``.
    Returns ``(Phi, Gam_old, Gam_new, m, f)``.
    """
    m = int(math.floor(tau / h + SAMPLE_FRACTION_TOL))
    f = max(tau - m * h, 0.0)
    if f < SAMPLE_FRACTION_TOL * h:
        f = 0.0
    Phi, Gam = _int_expm(sys.A, sys.B, h)
    if f == 0.0:
        return Phi, np.zeros_like(Gam), Gam, m, 0.0
    E2, G2 = _int_expm(sys.A, sys.B, h - f)  # the new input acts over the last h - f
    E1, G1 = _int_expm(sys.A, sys.B, f)  # the old one over the first f
    return Phi, E2 @ G1, G2, m, f


def zoh_fractional(sys: SS, dt: float, phi: float) -> SS:
    """Exact ZOH at ``dt`` of ``x' = A x + B u(t - phi)``, ``0 < phi < dt``, as one discrete realisation.

    States ``[x, v]`` with ``v[k] = u[k-1]``: ``x[k+1] = Phi x[k] + Gam0 u[k] + Gam1 v[k]``, ``v[k+1] = u[k]``,
    with ``Gam0 = int_0^{dt-phi} e^{A s} ds B`` (the new input, over the last ``dt - phi``) and
    ``Gam1 = e^{A (dt-phi)} int_0^{phi} e^{A s} ds B`` (the previous one, over the first ``phi``). The output
    at ``t_k`` still sees the previous input: ``y[k] = C x[k] + D v[k]`` (no feedthrough).
    """
    n = sys.n
    if n == 0:
        Phi, G0, G1 = np.zeros((0, 0)), np.zeros(0), np.zeros(0)
    else:
        Phi, _ = _int_expm(sys.A, sys.B, dt)
        E2, G0 = _int_expm(sys.A, sys.B, dt - phi)
        _, G1p = _int_expm(sys.A, sys.B, phi)
        G1 = E2 @ G1p
    A = np.zeros((n + 1, n + 1))
    A[:n, :n], A[:n, n] = Phi, G1
    return SS(A, np.concatenate([G0, [1.0]]), np.concatenate([sys.C, [sys.D]]), 0.0)


def lifted_outputs(sys: SS, dt: float, N: int, phi: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """``Cf`` (N, n'), ``Df`` (N): the output of ``x' = A x + B u(t - phi)`` at ``t_k + j dt/N`` from the
    state of its ZOH model at ``t_k`` and the input held over ``[t_k, t_k+1)``: ``y = Cf[j] z_k + Df[j] u_k``.

    ``phi = 0``: ``z = x`` (the coordinates of :func:`zoh`); ``0 < phi < dt``: ``z = [x, u[k-1]]`` (those of
    :func:`zoh_fractional`), the previous input acting until ``t_k + phi``.
    """
    n = sys.n
    if phi == 0.0:
        M = np.zeros((n + 1, n + 1))
        M[:n, :n], M[:n, n] = sys.A, sys.B
        E1 = linalg.expm(M * (dt / N))
        Cf, Df, E = np.zeros((N, n)), np.zeros(N), np.eye(n + 1)
        for j in range(N):
            Cf[j], Df[j] = sys.C @ E[:n, :n], sys.C @ E[:n, n] + sys.D
            E = E @ E1
        return Cf, Df
    Cf, Df = np.zeros((N, n + 1)), np.zeros(N)
    h = dt / N
    j0 = min(int(math.ceil(phi / h - SAMPLE_FRACTION_TOL)), N)  # the first point at or after the switch
    if n == 0:
        Cf[:j0, 0], Df[j0:] = sys.D, sys.D
        return Cf, Df
    _, Gphi = _int_expm(sys.A, sys.B, phi)
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = sys.A, sys.B
    E1 = linalg.expm(M * h)
    E = np.eye(n + 1)  # (e^{A s}, int_0^s e^{A r} dr B) at s = j h
    R = np.eye(n + 1)
    if j0 < N:
        R[:n, :n], R[:n, n] = _int_expm(sys.A, sys.B, j0 * h - phi)  # at s - phi for s = j0 h
    for j in range(N):
        Cf[j, :n] = sys.C @ E[:n, :n]
        if j < j0:  # still the previous input
            Cf[j, n], Df[j] = sys.C @ E[:n, n] + sys.D, 0.0
        else:
            Cf[j, n], Df[j] = sys.C @ (R[:n, :n] @ Gphi), sys.C @ R[:n, n] + sys.D
            R = R @ E1
        E = E @ E1
    return Cf, Df


def switch_output(sys: SS, phi: float) -> np.ndarray:
    """``Cs`` (n + 1): the output of ``x' = A x + B u(t - phi)`` at the instant ``t_k + phi`` where its delayed
    input switches, from the state ``z_k = [x, u[k-1]]`` of :func:`zoh_fractional` (``y = Cs z_k``; the previous
    input still acting, the left limit; for a strictly proper plant the output is continuous there). The output
    has a corner at that instant, which a fixed grid of points between the samples misses: its peak can be there."""
    n = sys.n
    if n == 0:
        return np.r_[np.zeros(0), sys.D]
    Ephi, Gphi = _int_expm(sys.A, sys.B, phi)
    return np.r_[sys.C @ Ephi, sys.C @ Gphi + sys.D]


# -- frequency response and zeros ---------------------------------------------------------------

def freqresp(sys: SS, x: np.ndarray) -> np.ndarray:
    """``C (xI - A)^{-1} B + D`` at every complex ``x`` (Schur form, O(n^2) per point)."""
    x = np.atleast_1d(np.asarray(x, dtype=complex))
    T, b, c = sys.schur()
    n = T.shape[0]
    out = np.full(x.shape, complex(sys.D))
    if n == 0:
        return out
    v = np.zeros((n,) + x.shape, dtype=complex)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # at a pole / huge gains: inf, reported
        for i in range(n - 1, -1, -1):
            acc = b[i] + (T[i, i + 1:] @ v[i + 1:] if i + 1 < n else 0.0)
            v[i] = acc / (x - T[i, i])
        out = out + c @ v
    return out


def invariant_zeros(sys: SS) -> np.ndarray:
    """Finite zeros of ``(A, B, C, D)``: generalised eigenvalues of the Rosenbrock pencil."""
    n = sys.n
    if n == 0:
        return np.zeros(0, complex)
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n], M[n, :n], M[n, n] = sys.A, sys.B, sys.C, sys.D
    N = np.zeros((n + 1, n + 1))
    N[:n, :n] = np.eye(n)
    alpha, beta = linalg.eigvals(M, N, homogeneous_eigvals=True)
    scale = max(1.0, float(np.max(np.abs(sys.A)))) if n else 1.0
    finite = np.abs(beta) * 1e10 * scale > np.abs(alpha)
    return alpha[finite] / beta[finite]


def zpk_from_ss(sys: SS, *, discrete: bool) -> Zpk:
    """Poles (eigenvalues), zeros (pencil) and the gain matched at a point away from both."""
    poles = np.linalg.eigvals(sys.A) if sys.n else np.zeros(0, complex)
    zeros = invariant_zeros(sys)
    rad = max([1.0] + [abs(r) for r in np.concatenate([poles, zeros])])
    x0 = (1.7 + 0.9j) * rad if not discrete else 1.3 * rad * np.exp(0.7j)
    ref = freqresp(sys, np.array([x0]))[0]
    unit = Zpk(zeros, poles, 1.0)(np.array([x0]))[0]
    gain = float((ref / unit).real) if unit != 0 else 0.0
    return Zpk(zeros, poles, gain)
