"""Frequency response and coherence from a record, several windows composited (CIFER's COMPOSITE).

For each window length ``T_k`` the input and output auto-spectra and the cross-spectrum are
estimated by Welch's method (the numbers of :func:`scipy.signal.welch` and :func:`scipy.signal.csd`: Hann window,
80 % overlap, a straight line removed from each segment, FFT zero-padded to four times the
segment for a fine frequency grid). Long windows resolve low frequencies, short ones average
more at high frequencies. At each frequency the window spectra are merged by a weighted
average, each window weighted by the inverse of its random error of the frequency response,
``1/eps_r^2 = 2 n_d gamma^2 / (1 - gamma^2)`` (Bendat & Piersol; ``n_d`` = how many windows the
record holds, ``gamma^2`` the window's coherence there); a window only counts at frequencies with
at least two of its periods (``w >= 4*pi/T_k``). The composite response is
``H = G_uy / G_uu`` (the H1 estimate) and its coherence ``|G_uy|^2 / (G_uu G_yy)``, both from the
merged spectra, as COMPOSITE does.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InvalidDataError
from .data import Record

__all__ = [
    "MIN_BAND_DECADES",
    "N_WINDOWS",
    "OVERLAP",
    "POINTS_PER_DECADE",
    "FrequencyResponse",
    "WindowSpectra",
    "coherent_band",
    "composite",
    "frequency_response",
    "joint_composite",
    "pooled",
    "unexplained_rms",
    "window_lengths",
    "window_spectra",
]

OVERLAP = 0.8
N_WINDOWS = 5
POINTS_PER_DECADE = 40
MIN_BAND_DECADES = 0.25  # a narrower automatic band is refused
_PAD = 4  # FFT length / segment length
_COH_CLIP = 0.999  # coherence used in the weights is clipped here (a perfect window would take all weight)
STFT_BYTES_PER_SAMPLE = 32  # the short-time transforms held at once, per sample of the record


@dataclass(frozen=True, eq=False)
class FrequencyResponse:
    """Composite estimate: ``w`` (rad/s), complex ``h``, ``coherence`` (0..1), the windows used (s)."""

    w: np.ndarray
    h: np.ndarray
    coherence: np.ndarray
    windows_s: tuple[float, ...] = ()
    #: the joint input-output estimate (a reference r): the coherence of y with r and of u with r (``coherence`` is
    #: then the two combined, :func:`joint_composite`); None for the direct estimate
    coherence_ry: np.ndarray | None = None
    coherence_ru: np.ndarray | None = None

    @property
    def joint(self) -> bool:
        """Whether this is the joint input-output estimate ``S_ry / S_ru`` (from a reference), not ``S_uy / S_uu``."""
        return self.coherence_ry is not None

    @property
    def mag_db(self) -> np.ndarray:
        """Magnitude, dB (``-inf`` where the estimate is zero)."""
        with np.errstate(divide="ignore"):
            return 20.0 * np.log10(np.abs(self.h))

    @property
    def phase_deg(self) -> np.ndarray:
        """Phase unwrapped along ``w`` (meaningless where the coherence is low)."""
        return np.degrees(np.unwrap(np.angle(self.h)))

    def to_dict(self) -> dict[str, Any]:
        """The response as lists (``w``, ``mag_db``, ``phase_deg``, ``coherence``, ``windows_s``; a joint estimate
        also ``coherence_ry``, ``coherence_ru``)."""
        out = {"w": self.w.tolist(), "mag_db": self.mag_db.tolist(), "phase_deg": self.phase_deg.tolist(),
               "coherence": self.coherence.tolist(), "windows_s": list(self.windows_s)}
        if self.joint:
            out.update(coherence_ry=self.coherence_ry.tolist(), coherence_ru=self.coherence_ru.tolist())
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FrequencyResponse:
        """The inverse of :meth:`to_dict`."""
        w = np.asarray(d["w"], dtype=float)
        h = 10.0 ** (np.asarray(d["mag_db"], dtype=float) / 20.0) * np.exp(1j * np.radians(d["phase_deg"]))
        extra = {k: np.asarray(d[k], dtype=float) for k in ("coherence_ry", "coherence_ru") if d.get(k) is not None}
        return cls(w=w, h=h, coherence=np.asarray(d["coherence"], dtype=float),
                   windows_s=tuple(float(x) for x in d.get("windows_s", ())), **extra)


@dataclass(frozen=True, eq=False)
class WindowSpectra:
    """Welch spectra of one window length on its FFT grid (``w`` in rad/s)."""

    window_s: float
    n_avg: float
    w: np.ndarray
    guu: np.ndarray
    gyy: np.ndarray
    guy: np.ndarray

    def at(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The three spectra interpolated (linearly) at ``w``."""
        guy = np.interp(w, self.w, self.guy.real) + 1j * np.interp(w, self.w, self.guy.imag)
        return np.interp(w, self.w, self.guu), np.interp(w, self.w, self.gyy), guy


def window_lengths(duration_s: float, dt: float, *, w_max_rad_s: float, n: int = N_WINDOWS) -> tuple[float, ...]:
    """Up to ``n`` window lengths, log-spaced from half the record down to the longest of: an eighth
    of that, 20 periods of ``w_max_rad_s``, 64 samples; neighbours at least 1.5 times apart."""
    t_max = duration_s / 2.0
    t_min = max(t_max / 8.0, 20.0 * 2.0 * np.pi / w_max_rad_s, 64 * dt)
    k = min(n, 1 + int(np.floor(np.log(t_max / t_min) / np.log(1.5)))) if t_min < t_max else 1
    if k <= 1:
        return (t_max,)
    return tuple(float(x) for x in np.geomspace(t_max, t_min, k))


def _linear_detrend(n: int):
    """Subtract each segment's least-squares straight line (vectorised over the leading axes)."""
    tc = np.arange(n) - (n - 1) / 2.0
    tss = float(tc @ tc)

    def detr(x: np.ndarray) -> np.ndarray:
        return x - x.mean(axis=-1, keepdims=True) - (x @ tc / tss)[..., None] * tc

    return detr


def window_spectra(rec: Record, window_s: float) -> WindowSpectra:
    """Auto- and cross-spectra of ``rec`` with windows of ``window_s`` seconds.

    Exactly what :func:`scipy.signal.welch` and :func:`scipy.signal.csd` return (same
    :class:`scipy.signal.ShortTimeFFT` set-up, segments, scaling and averaging), computed from one
    short-time transform of input and output together instead of three calls of two transforms
    each (a 200,000-sample log would otherwise take seconds).
    """
    from scipy.fft import next_fast_len
    from scipy.signal import ShortTimeFFT, get_window

    nper = int(min(rec.n, round(window_s / rec.dt)))
    nover = int(OVERLAP * nper)
    sft = ShortTimeFFT(get_window("hann", nper), nper - nover, 1.0 / rec.dt, fft_mode="onesided",
                       mfft=next_fast_len(_PAD * nper), scale_to="psd", phase_shift=None)
    n_seg = (rec.n - nover) // sft.hop
    x = np.stack([rec.u, rec.y])
    detr = _linear_detrend(nper)
    nf = sft.mfft // 2 + 1
    # the segments' transforms in batches, their products summed: memory bounded by about 4 doubles per sample of
    # the record (all segments at once hold 2 x (5 n / nper) x 2 nper complex values: 320 bytes per sample)
    batch = max(1, int(STFT_BYTES_PER_SAMPLE * rec.n / (2 * nf * 16)))
    guu, gyy = np.zeros(nf), np.zeros(nf)
    guy = np.zeros(nf, dtype=complex)
    for p0 in range(0, n_seg, batch):
        S = sft.stft_detrend(x, detr, p0=p0, p1=min(n_seg, p0 + batch), k_offset=nper // 2)
        su, sy = S[0], S[1]
        guu += np.sum(su.real ** 2 + su.imag ** 2, axis=-1)
        gyy += np.sum(sy.real ** 2 + sy.imag ** 2, axis=-1)
        guy += np.sum(np.conj(su) * sy, axis=-1)  # csd(u, y): conj(U) Y; H1 = Guy / Guu
        del S, su, sy
    guu, gyy, guy = guu / n_seg, gyy / n_seg, guy / n_seg
    one_sided = slice(1, -1 if sft.mfft % 2 == 0 else None)  # as csd: double all but DC (and Nyquist)
    for g in (guu, gyy, guy):
        g[one_sided] *= 2.0
    return WindowSpectra(window_s=nper * rec.dt, n_avg=max(1.0, rec.n / nper), w=2 * np.pi * sft.f,
                         guu=guu, gyy=gyy, guy=guy)


def _merge(spectra: Sequence[WindowSpectra], w: np.ndarray, *, noise: bool = False
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The windows' spectra at ``w`` merged: ``guu, gyy, guy`` and where any window counts.

    Weights: the inverse random error of the response, ``2 n_d gamma^2 / (1 - gamma^2)`` (the
    composite); with ``noise``, ``n_d (1 + gamma^2) / (1 - gamma^2)``, which is the same where the
    coherence is high and a plain average over all segments where it is low (for the residual
    spectrum, where a coherence-only weight would leave nothing)."""
    acc = [np.zeros(w.size), np.zeros(w.size), np.zeros(w.size, dtype=complex)]
    wsum = np.zeros(w.size)
    for sp in spectra:
        guu, gyy, guy = sp.at(w)
        with np.errstate(divide="ignore", invalid="ignore"):
            coh = np.nan_to_num(np.abs(guy) ** 2 / (guu * gyy), nan=0.0)
        coh = np.clip(coh, 0.0, _COH_CLIP)
        weight = sp.n_avg * ((1.0 + coh) if noise else 2.0 * coh) / (1.0 - coh)
        weight[(w < 4.0 * np.pi / sp.window_s) | (w > sp.w[-1])] = 0.0
        for a, g in zip(acc, (guu, gyy, guy)):
            a += weight * g
        wsum += weight
    ok = wsum > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        guu, gyy, guy = (np.where(ok, a / np.where(ok, wsum, 1.0), 0.0) for a in acc)
    return guu, gyy, guy, ok


def composite(spectra: Sequence[WindowSpectra], w: np.ndarray) -> FrequencyResponse:
    """Merge the windows' spectra at ``w`` (rad/s), weighted by their random error."""
    w = np.asarray(w, dtype=float)
    guu, gyy, guy, ok = _merge(spectra, w)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(ok & (guu > 0), guy / np.where(guu > 0, guu, 1.0), np.nan + 0j)
        coh = np.where(ok & (guu > 0) & (gyy > 0), np.abs(guy) ** 2 / np.where(ok, guu * gyy, 1.0), 0.0)
    return FrequencyResponse(w=w, h=h, coherence=np.clip(np.nan_to_num(coh), 0.0, 1.0),
                             windows_s=tuple(sp.window_s for sp in spectra))


def joint_composite(spectra_ry: Sequence[WindowSpectra], spectra_ru: Sequence[WindowSpectra], w: np.ndarray
                    ) -> FrequencyResponse:
    """The joint input-output estimate at ``w``: ``G = S_ry / S_ru`` from the windows' spectra of the reference
    ``r`` with the output ``y`` (``spectra_ry``: ``guu`` is ``S_rr``, ``guy`` is ``S_ry``) and with the plant input
    ``u`` (``spectra_ru``), each merged as :func:`composite` merges (Forssell & Ljung 1999: unbiased under feedback,
    where ``S_uy / S_uu`` tends to ``-1/C`` wherever the disturbance dominates).

    ``coherence_ry`` and ``coherence_ru`` say where ``r`` explains ``y`` and ``u``; ``coherence`` is the two
    combined so that the random error of the ratio is that of one estimate with it:
    ``(1 - g2)/g2 = (1 - g2_ry)/g2_ry + (1 - g2_ru)/g2_ru`` (the relative errors of the two estimates add,
    Bendat & Piersol's ``eps^2 = (1 - g2)/(2 n_d g2)`` each).
    """
    w = np.asarray(w, dtype=float)
    ty, tu = composite(spectra_ry, w), composite(spectra_ru, w)
    g_ry, g_ru = ty.coherence, tu.coherence
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(np.isfinite(ty.h) & np.isfinite(tu.h) & (np.abs(tu.h) > 0), ty.h / tu.h, np.nan + 0j)
        q = (1.0 - g_ry) / np.maximum(g_ry, 1e-300) + (1.0 - g_ru) / np.maximum(g_ru, 1e-300)
        coh = np.where((g_ry > 0) & (g_ru > 0), 1.0 / (1.0 + q), 0.0)
    return FrequencyResponse(w=w, h=h, coherence=np.clip(np.nan_to_num(coh), 0.0, 1.0), windows_s=ty.windows_s,
                             coherence_ry=g_ry, coherence_ru=g_ru)


def unexplained_rms(spectra: Sequence[WindowSpectra]) -> float:
    """The rms of the output that no linear model of the input explains: ``sqrt(int G_nn dw / 2 pi)``
    with the residual spectrum ``G_nn = G_yy - |G_uy|^2 / G_uu = G_yy (1 - gamma^2)`` (Bendat &
    Piersol), merged over the windows and integrated from the lowest resolved frequency to Nyquist.

    This is the noise floor of a time-domain check: sensor noise, the response to unmeasured
    inputs (gusts) and nonlinearity, as the record shows them; a perfect model's residual has
    about this rms. Slower wander (below two periods of the longest window) is not counted; the
    check removes a bias and a linear drift. Spectral leakage and the per-segment detrending bias
    the coherence of even noise-free data slightly below 1, which adds a few per cent of the
    output's rms (in quadrature) to the floor."""
    longest = max(spectra, key=lambda sp: sp.window_s)
    top = float(min(sp.w[-1] for sp in spectra))
    lo = 4.0 * np.pi / longest.window_s
    if not lo < top:
        return float("nan")
    w = np.geomspace(lo, top, max(16, int(np.ceil(POINTS_PER_DECADE * np.log10(top / lo))) + 1))
    guu, gyy, guy, ok = _merge(spectra, w, noise=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        gnn = np.where(ok & (guu > 0), gyy - np.abs(guy) ** 2 / np.where(guu > 0, guu, 1.0), gyy)
    gnn = np.clip(gnn, 0.0, None)
    return float(np.sqrt(np.trapezoid(gnn, w) / (2.0 * np.pi)))


def pooled(group: Sequence[WindowSpectra]) -> WindowSpectra:
    """One window length's spectra of several records combined: the auto- and cross-spectra
    averaged over all their segments (Welch's average over the union of the records' windows, as
    CIFER concatenates repeated sweeps). The records share the sample time and the window."""
    if len(group) == 1:
        return group[0]
    n = np.array([sp.n_avg for sp in group])
    g = [sum(k * getattr(sp, a) for k, sp in zip(n, group)) / n.sum() for a in ("guu", "gyy", "guy")]
    return WindowSpectra(window_s=group[0].window_s, n_avg=float(n.sum()), w=group[0].w, guu=g[0], gyy=g[1], guy=g[2])


def frequency_response(rec: Record | Sequence[Record], *, w_min_rad_s: float | None = None,
                       w_max_rad_s: float | None = None,
                       windows_s: Sequence[float] | None = None) -> tuple[FrequencyResponse, list[WindowSpectra]]:
    """The composite response of a (detrended) record on a log grid, and the window spectra.

    The grid runs from the lowest frequency the longest window resolves (``w_min_rad_s`` if
    higher) to 90 % of the Nyquist frequency (``w_max_rad_s`` if lower), 40 points per decade.
    Several records (same sample time): the windows are chosen for the longest, and each window's
    spectra are :func:`pooled` over the records that hold it.
    """
    recs = [rec] if isinstance(rec, Record) else list(rec)
    rec = max(recs, key=lambda r: r.n)
    top = 0.9 * rec.nyquist_rad_s if w_max_rad_s is None else min(w_max_rad_s, 0.9 * rec.nyquist_rad_s)
    if windows_s is None:
        windows_s = window_lengths(rec.duration_s, rec.dt, w_max_rad_s=top)
    for t in windows_s:
        if not (np.isfinite(t) and 64 * rec.dt <= t <= rec.duration_s):
            raise InvalidDataError(f"window of {t} s: windows must hold at least 64 samples and at most the "
                                   f"whole record ({rec.duration_s:g} s)", field="windows_s")
    spectra = [pooled([window_spectra(r, t) for r in recs if r.n >= round(t / rec.dt)] or [window_spectra(rec, t)])
               for t in sorted(windows_s, reverse=True)]
    lo = 4.0 * np.pi / spectra[0].window_s
    if w_min_rad_s is not None:
        lo = max(lo, w_min_rad_s)
    if not lo < top:
        raise InvalidDataError(f"no frequencies to analyse between {lo:.4g} and {top:.4g} rad/s: the record "
                               f"({rec.duration_s:g} s at {1 / rec.dt:g} Hz) is too short", field="input")
    n = max(8, int(np.ceil(POINTS_PER_DECADE * np.log10(top / lo))) + 1)
    return composite(spectra, np.geomspace(lo, top, n)), spectra


def coherent_band(fr: FrequencyResponse, *, coherence_min: float = 0.6) -> tuple[float, float]:
    """The widest stretch (in decades) where the coherence is at least ``coherence_min``.

    Dips below the threshold narrower than a tenth of a decade inside the stretch are bridged
    (their points are left out of the fit, not the band). A stretch narrower than
    :data:`MIN_BAND_DECADES` is refused: with few spectral averages, unrelated signals reach a
    coherence of 0.6 at a few neighbouring frequencies by chance.
    """
    ok = fr.coherence >= coherence_min
    idx = np.flatnonzero(ok)
    if idx.size < 2:
        best = float(np.max(fr.coherence)) if fr.coherence.size else 0.0
        raise InvalidDataError(
            f"no coherent band: the coherence reaches {coherence_min:g} at {idx.size} of {fr.w.size} frequencies "
            f"(best {best:.2f}); the output is not explained by the input (more excitation, less noise, or a "
            "longer record)", field="output")
    logw = np.log10(fr.w)
    runs: list[list[int]] = [[int(idx[0]), int(idx[0])]]
    for i in idx[1:]:
        if logw[i] - logw[runs[-1][1]] <= 0.1 + 1e-12:
            runs[-1][1] = int(i)
        else:
            runs.append([int(i), int(i)])
    a, b = max(runs, key=lambda r: logw[r[1]] - logw[r[0]])
    if logw[b] - logw[a] < MIN_BAND_DECADES:
        raise InvalidDataError(
            f"no coherent band: the coherence reaches {coherence_min:g} only over {fr.w[a]:.3g}-{fr.w[b]:.3g} rad/s "
            f"({logw[b] - logw[a]:.2f} decades; at least {MIN_BAND_DECADES:g} are needed, and with few averages "
            "independent signals reach such coherence by chance); excite the plant over a wider band, or give "
            "the band explicitly", field="output")
    return float(fr.w[a]), float(fr.w[b])
