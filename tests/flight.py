"""Synthetic flight logs for the identification tests: piloted frequency sweeps through known models.

Independent of ``tuner.identify`` (numpy/scipy only, no ``tuner`` import): the truth the
identification is judged against. What a flight-test engineer would log for one axis
(Tischler & Remple, *Aircraft and Rotorcraft System Identification*, ch. 5):

* a **pilot-like sweep**: a long first period at the lowest frequency, then a frequency
  that rises roughly exponentially (the book's automated-sweep law
  ``w = w_min + C2 (exp(C1 t/T) - 1)(w_max - w_min)``, ``C1 = 4``, ``C2 = 0.0187``) with a slow
  random wobble, a slowly modulated amplitude, some pilot remnant, trim at both ends;
* **doublets** at the end (for the time-domain check on data the fit has not seen);
* the plant (the thesis's roll, pitch and yaw models, or any ``num/den``) with a **transport
  delay**, **gusts** (white noise through a first-order filter, added at the plant input, so
  they are an unmeasured input that lowers the coherence), **sensor noise** and a **bias drift**
  (a constant offset, a linear drift and a random walk) on the logged output;
* simulated at ``sim_hz`` (1 kHz) exactly for a piecewise-linear input (``scipy.signal.lsim``
  with first-order hold) and logged at ``log_hz`` (50 Hz) by sampling.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

__all__ = ["AXES", "THIRD_ORDER", "FlightLog", "fly", "pilot_sweep", "true_response"]

# the thesis's identified attitude models (quadrotor.md), command -> angle
AXES: dict[str, tuple[list[float], list[float]]] = {
    "roll": ([0.2655 * 14.8528**2], [1.0, 14.195, 14.8528**2]),
    "pitch": ([0.377568 * 3.5184**2], [1.0, 2 * 0.5006 * 3.5184, 3.5184**2]),
    "yaw": ([0.2843 * 18.611], [1.0, 18.611]),
}
# a third-order plant: a real pole at 2 rad/s and a lightly damped pair (12 rad/s, zeta 0.2), both
# inside the band; one quadratic section (and a delay) cannot explain the lag and the resonance
THIRD_ORDER: tuple[list[float], list[float]] = (
    [0.3 * 144.0 * 2.0], [float(c) for c in np.polymul([1.0, 2.0], [1.0, 2 * 0.2 * 12.0, 144.0])])


@dataclass(frozen=True)
class FlightLog:
    """One logged axis: ``t`` (s), command ``u``, measured angle ``y``, at ``dt``; and the truth."""

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    dt: float
    num: list[float]
    den: list[float]
    delay_s: float
    sweep_end_s: float  # the doublets start here

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.dt


def _smooth_noise(rng: np.random.Generator, n: int, fs: float, corner_rad_s: float) -> np.ndarray:
    """Unit-rms white noise through a first-order low-pass (corner in rad/s)."""
    b, a = signal.butter(1, corner_rad_s / (np.pi * fs))
    x = signal.lfilter(b, a, rng.standard_normal(n + int(5 * fs / corner_rad_s)))[-n:]
    return x / np.std(x)


def pilot_sweep(rng: np.random.Generator, t: np.ndarray, *, sweep_s: float, w_min: float = 0.3,
                w_max: float = 25.0, amplitude: float = 1.0) -> np.ndarray:
    """The stick: trim, a sweep ``w_min -> w_max`` within ``sweep_s``, then doublets to the end of ``t``."""
    fs = 1.0 / (t[1] - t[0])
    n = t.size
    trim_s = 2.0
    long_s = 2 * np.pi / w_min  # a long first period at the lowest frequency
    ts = np.clip(t - trim_s, 0.0, None)
    rise_s = sweep_s - 2 * trim_s - long_s
    k = 0.0187 * (np.exp(4.0 * np.clip(ts - long_s, 0.0, rise_s) / rise_s) - 1.0)
    w = w_min + np.clip(k, 0.0, 1.0) * (w_max - w_min)
    w = w * (1.0 + 0.08 * _smooth_noise(rng, n, fs, 0.5))  # a pilot does not hold an exact law
    theta = np.cumsum(w) / fs
    env = 1.0 + 0.2 * _smooth_noise(rng, n, fs, 0.3)  # amplitude modulation
    on = (t >= trim_s) & (t <= sweep_s - trim_s)
    fade = np.clip(np.minimum(t - trim_s, sweep_s - trim_s - t) / 0.5, 0.0, 1.0)  # no steps at the ends
    u = amplitude * np.where(on, env * fade * np.sin(theta), 0.0)
    u += 0.05 * amplitude * _smooth_noise(rng, n, fs, 6.0)  # remnant
    # doublets: +A for w, -A for w, with quiet gaps; widths span the band
    widths = (0.15, 0.3, 0.6, 1.0)
    gap = max(0.5, (t[-1] - sweep_s - 1.5 - 2 * sum(widths)) / len(widths))
    start = sweep_s + 1.0
    for width in widths:
        for sign, t0 in ((1.0, start), (-1.0, start + width)):
            u[(t >= t0) & (t < t0 + width)] += sign * 0.8 * amplitude
        start += 2 * width + gap
    return u


def fly(num: list[float], den: list[float], *, delay_s: float = 0.04, seed: int = 0, duration_s: float = 90.0,
        log_hz: float = 50.0, sim_hz: float = 1000.0, sweep_fraction: float = 0.8, gust_frac: float = 0.15,
        noise_frac: float = 0.02, bias: float = 0.05, drift_per_s: float = 0.001,
        random_walk: float = 0.002) -> FlightLog:
    """Fly one axis of ``num/den`` (continuous, highest power first) and return the log.

    ``gust_frac``: rms of the input gust relative to the rms of the stick; ``noise_frac``: rms of
    the sensor noise relative to the rms of the clean output; ``bias``, ``drift_per_s`` and
    ``random_walk`` (per sqrt(s)) in output units.
    """
    rng = np.random.default_rng(seed)
    n = round(duration_s * sim_hz) + 1
    t = np.arange(n) / sim_hz
    sweep_s = sweep_fraction * duration_s
    u = pilot_sweep(rng, t, sweep_s=sweep_s)
    gust = gust_frac * np.std(u) * _smooth_noise(rng, n, sim_hz, 1.5)
    d = round(delay_s * sim_hz)
    u_plant = np.concatenate([np.zeros(d), u[: n - d]]) + gust
    _, y, _ = signal.lsim((num, den), u_plant, t, interp=True)
    step = round(sim_hz / log_hz)
    tl, ul, yl = t[::step], u[::step], y[::step]
    noise = noise_frac * np.std(yl) * rng.standard_normal(tl.size)
    walk = random_walk * np.cumsum(rng.standard_normal(tl.size)) * np.sqrt(1.0 / log_hz)
    ym = yl + noise + bias + drift_per_s * tl + walk
    return FlightLog(t=tl, u=ul, y=ym, dt=1.0 / log_hz, num=list(num), den=list(den), delay_s=delay_s,
                     sweep_end_s=sweep_s)


def true_response(log: FlightLog, w: np.ndarray) -> np.ndarray:
    """The true frequency response at ``w`` rad/s, delay included."""
    _, h = signal.freqs(log.num, log.den, worN=np.asarray(w, dtype=float))
    return h * np.exp(-1j * np.asarray(w) * log.delay_s)
