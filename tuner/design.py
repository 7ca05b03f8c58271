"""Controller *design* helpers: the plant's scale, plant-based starts, search bounds.

A bottom-layer module (plants and structures only): :class:`~tuner.problem.TuningProblem` computes the
scale and checks that a loop can be formed with it, and :mod:`tuner.optimize` searches from its starts
(``tuner.optimize.design`` re-exports it, the name it had).

These are about the plant (its ultimate frequency and gain, its slow poles, the sign of
feedback it needs), not about a structure's parameters <-> transfer function (that is
:mod:`tuner.controllers`). :func:`plant_scale` is computed once per tune (the
:class:`~tuner.problem.TuningProblem` holds it) and passed to the others as ``scale``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .controllers import GAIN_SPAN, Structure
from .errors import InvalidControllerError
from .plant import Plant
from .tolerances import EXACT_ROOT_TOL, REAL_ROOT_TOL, ROOT_AT_DC_TOL, ROOT_MAG_FLOOR, STABILITY_MARGIN

__all__ = ["PlantScale", "plant_scale", "plant_sign", "slow_poles", "bounds", "initial_guess", "zero_variants",
           "dt_note",
           "tf_min", "dc_gain",
           "TF_MIN_W0", "TF_MIN_DT"]

PlantScale = tuple[float, float]  # (K0, w0): characteristic gain and frequency of the loop to design

TF_MIN_W0 = 1e-3  # continuous loops: Tf >= 1e-3 / w0 (the derivative filter's corner at most 1000 w0)
TF_MIN_DT = 1e-3  # sampled loops: Tf >= 1e-3 dt (the filter pole Tf/(Tf+dt) <= 0.001: the one-sample
                  # derivative of pid_z, which pid therefore contains up to that)


def tf_min(dt: float | None, w0: float, *, nyquist: bool = False) -> float:
    """The documented lower bound on a derivative or measurement filter's time constant ``Tf``: with the
    default ``Spec.filter_nyquist`` at a sample time, ``dt/pi`` (the filter's corner at most the Nyquist
    frequency); without it ``1e-3 dt``; continuous loops ``1e-3 / w0``."""
    if dt and nyquist:
        return dt / math.pi
    return TF_MIN_DT * dt if dt else TF_MIN_W0 / w0


def bounds(st: Structure, plant: Plant, dt: float | None, *, scale: PlantScale | None = None,
           nyquist: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Search box from the plant's scale: gains +-GAIN_SPAN times their unit (K0 * w0**unit); ``nyquist``:
    filter time constants from ``dt/pi`` (:func:`tf_min`)."""
    k0, w0 = scale or plant_scale(plant, dt)
    wmax = (math.pi / dt) if dt else 1e3 * w0
    lo, hi = [], []
    for kind, unit in zip(st.kinds, st.gain_scale(k0, w0)):
        if kind == "gain":
            lo.append(-GAIN_SPAN * unit), hi.append(GAIN_SPAN * unit)
        elif kind == "freq":
            lo.append(1e-3 * w0), hi.append(min(wmax, 1e2 * w0))
        elif kind == "time":
            t0 = tf_min(dt, w0, nyquist=nyquist)
            lo.append(t0), hi.append(max(10.0 / w0, 10 * t0))
        else:  # polynomial coefficient of a monic quadratic with zeros in |z| <= 1.5
            lo.append(-3.0), hi.append(3.0)
    for i, (p, kind) in enumerate(zip(st.params, st.kinds)):  # 2-DOF setpoint weights: the structure's range
        if kind == "weight":
            lo[i], hi[i] = st.weight_range(p)
        elif st.nonneg:  # a firmware law's gains are >= 0 (its parameters' ranges)
            lo[i] = 0.0
    return np.array(lo), np.array(hi)


def zero_variants(plant: Plant, dt: float | None, w0: float) -> list[np.ndarray]:
    """Where a start may put the controller's two zeros (s-plane; a one-zero structure uses the first): on the
    plant's two slowest stable poles (the classic pole-cancelling design), and the corners: one on the slowest
    pole and the other far away (at z = 0 in discrete time, cancelling the derivative filter's own pole: a
    PI-like design; at 10 w0 in continuous time), both on the slowest pole; a damped pair at half the slowest
    pole's frequency and at half ``w0``; one zero at twice the slowest pole's frequency and at 1.5 ``w0``."""
    base = slow_poles(plant, w0)
    p1 = base[0] if abs(base[0].imag) <= REAL_ROOT_TOL else complex(-abs(base[0]))
    far = -np.inf if dt is not None else -10.0 * w0
    r1 = abs(p1)
    out = [base, np.array([p1, far], dtype=complex), np.array([p1, p1], dtype=complex)]
    # zeros slower than the slowest pole (a lag plant's settling-optimal PID: a damped pair at about half
    # its frequency), and placements from the loop's own scale (integrating plants have no slow pole)
    for r in (0.5 * r1, 0.5 * w0):
        out.append(r * np.array([complex(-0.7, 0.71), complex(-0.7, -0.71)]))
    for r in (2.0 * r1, 1.5 * w0):
        out.append(np.array([-r, far], dtype=complex))
    if dt is not None:  # zeros beyond Nyquist fold: keep them below it
        wn = 0.9 * math.pi / dt
        with np.errstate(invalid="ignore"):
            out = [np.where(np.isfinite(z) & (np.abs(z) > wn), z * wn / np.maximum(np.abs(z), 1e-300), z) for z in out]
    return out


def initial_guess(st: Structure, plant: Plant, dt: float | None, *, scale: PlantScale | None = None,
                  zeros: np.ndarray | None = None, spec: Any = None) -> dict[str, float]:
    """A pole-cancellation start (IMC / lambda-tuning style), sign from the plant.

    The controller's zeros go on the plant's slowest stable poles (two for
    PID/pid_z/lead-lag, one for PI/PD/lead), or where ``zeros`` says (s-plane; ``-inf`` is z = 0 in
    discrete time, see :func:`zero_variants`); the gain puts the loop's crossover at a third of the
    plant's ultimate frequency ``w0``. ``spec``: its default filter rules shape the start (the filter at
    ``Td/N`` and no faster than ``dt/pi``).
    """
    if st.name == "pid2":  # the feedback part is pid's; the default start puts D on the measurement (c = 0)
        from .controllers import STRUCTURES

        g2 = initial_guess(STRUCTURES["pid"], plant, dt, scale=scale, zeros=zeros, spec=spec)
        return {**g2, "b": PID2_START_B, "c": PID2_START_C}
    k0, w0 = scale or plant_scale(plant, dt)
    fw = None
    if st.firmware is not None:  # a firmware law: pid's start, its gains in the law's units, no feed-forward
        from .controllers import STRUCTURES

        g2 = initial_guess(STRUCTURES["pid"], plant, dt, scale=scale, zeros=zeros, spec=spec)
        k = st.fixed_values.get("K", 1.0)
        fw = {"P": g2["Kp"] / k, "I": g2["Ki"] / k, "D": g2["Kd"] / k, "FF": 0.0}
    nyq = bool(getattr(spec, "filter_nyquist", False))
    n_max = getattr(spec, "filter_n_max", None)
    sgn = plant_sign(plant)
    poles = slow_poles(plant, w0) if zeros is None else np.asarray(zeros, dtype=complex)
    z1 = float(abs(poles[0]))  # one-zero structures: the slowest pole's frequency
    with np.errstate(invalid="ignore"):
        _, c1, c2 = np.real(np.poly(poles))  # two-zero structures: s^2 + c1 s + c2
    g = {"Kp": 1.0, "Ki": z1, "Kd": 0.0, "Tf": 0.0, "K": 1.0, "wz": z1, "wp": min(10 * z1, 3 * w0),
         "wz1": z1, "wp1": min(10 * z1, 3 * w0), "wz2": 0.1 * z1, "wp2": 0.01 * z1}
    if st.name in ("pid", "pd", "pid_mf2"):
        # Kd s^2 + Kp s + Ki = Kd (s^2 + c1 s + c2)   (pd: Kd s + Kp = Kd (s + z1))
        g.update(Kd=1.0, Kp=z1 if st.name == "pd" else c1, Ki=c2,
                 Tf=(0.1 / w0) if dt is None else tf_min(dt, w0, nyquist=nyq))
    if dt is not None and st.name in ("pid", "pi", "pid_mf2"):
        # in discrete time put the zeros exactly on the ZOH plant's poles: with Tf = 0 the
        # backward-Euler PID numerator is (Kp + Ki dt + Kd/dt) z^2 - (Kp + 2 Kd/dt) z + Kd/dt
        zp = np.exp(poles * dt)
        if st.name in ("pid", "pid_mf2"):
            _, a1, a2 = np.real(np.poly(zp))
            g.update(Kd=a2 * dt, Kp=-a1 - 2 * a2, Ki=(1 + a1 + a2) / dt, Tf=tf_min(dt, w0, nyquist=nyq))
        else:  # (Kp + Ki dt) z - Kp = z - e^{-z1 dt}
            e1 = float(np.exp(-z1 * dt))
            g.update(Kp=e1, Ki=(1 - e1) / dt)
    if st.name == "lag":
        g.update(wz=0.1 * z1, wp=0.01 * z1)
    if st.name == "pid_z":
        if dt is None:
            raise InvalidControllerError("pid_z is discrete: give dt")
        _, a1, a2 = np.real(np.poly(np.exp(poles * dt)))
        g.update(a1=float(a1), a2=float(a2))
    if n_max and st.name in ("pd", "pid", "pid2", "pid_mf2", "pidf2") and g["Kp"] != 0:
        g["Tf"] = max(g["Tf"], 1.001 * abs(g["Kd"] / g["Kp"]) / n_max)  # the filter rule: N = Td/Tf <= n_max
    if fw is not None:
        g.update({p: abs(v) for p, v in fw.items()})
    x = np.array([g[p] for p in st.params], dtype=float)
    c1 = st.tf(x, dt)
    p_eff = plant if (dt is None or plant.is_discrete) else plant.zoh(dt)
    k = sgn * _margin_gain(c1, p_eff, sgn, w0, dt, k0)
    with np.errstate(over="ignore", invalid="ignore"):  # an extreme plant's gain may overflow: clipped below
        for i, kind in enumerate(st.kinds):
            if kind == "gain":
                x[i] *= k
    g = dict(zip(st.params, x))
    # keep the start inside the search box: in discrete time a lead pole at 3*w0 can lie
    # above the Nyquist frequency pi/dt (roll, yaw at dt = 0.04), the box's upper bound
    lo, hi = bounds(st, plant, dt, scale=(k0, w0), nyquist=nyq)
    out = {}
    for p, a, b in zip(st.params, lo, hi):
        v = float(g[p])
        if not math.isfinite(v):  # overflowed (an extreme plant): the middle of the box, in its own scale
            v = float(math.sqrt(a * b)) if a > 0 and math.isfinite(a * b) else 0.5 * a + 0.5 * b
        if not a <= v <= b:
            v = float(np.clip(v, a + 0.01 * (b - a), b - 0.01 * (b - a)))
        out[p] = v
    for a, b in st.orderings:  # clipping may have collapsed an ordered pair: reopen it
        if out[a] >= out[b]:
            out[a] = max(out[b] / 3.0, float(lo[st.params.index(a)]))
    return out


PID2_START_B, PID2_START_C = 1.0, 0.0  # pid2's own starts: full proportional setpoint weight, D on the measurement
START_PM_DEG = 65.0  # the designed starts' phase margin (a little above the default spec's 60)
START_GM_DB = 8.0


def _margin_gain(c1, p_eff: Plant, sgn: float, w0: float, dt: float | None, k0: float) -> float:
    """The gain magnitude that gives the loop ``k c1 G`` a phase margin of ``START_PM_DEG`` at the first
    frequency where its phase has fallen that far (and at most ``START_GM_DB`` of gain margin used up at its
    phase crossover); the classic crossover at ``w0 / 3`` where the phase never falls that far."""
    key = ("start_grid", w0, dt)
    if key not in p_eff._cache:  # the plant's response once per tune, not once per start
        wmax = math.pi / dt * 0.999 if dt else 30.0 * w0
        w = np.geomspace(1e-3 * w0, wmax, 400)
        with np.errstate(all="ignore"):
            p_eff._cache[key] = (w, p_eff.freqresp(w))
    w, G = p_eff._cache[key]
    with np.errstate(all="ignore"):
        L1 = sgn * c1.freqresp(w) * G
    mag, ph = np.abs(L1), np.unwrap(np.angle(L1))
    ok = np.isfinite(mag) & (mag > 0) & np.isfinite(ph)
    if not ok.all():
        w, mag, ph = w[ok], mag[ok], ph[ok]
    if w.size < 2:
        return k0 * 0.1
    ph = ph - 2 * np.pi * np.round((ph[0] + 0.5 * np.pi) / (2 * np.pi))  # low frequencies near (-180, 0]
    gains = []
    for target, margin in ((-np.pi + math.radians(START_PM_DEG), 1.0), (-np.pi, 10 ** (-START_GM_DB / 20))):
        idx = np.flatnonzero((ph[:-1] > target) & (ph[1:] <= target))
        if idx.size:
            i = int(idx[0])
            f = (ph[i] - target) / (ph[i] - ph[i + 1])
            m = math.exp((1 - f) * math.log(mag[i]) + f * math.log(mag[i + 1]))
            gains.append(margin / m)
    if gains:
        return float(min(gains))
    m = float(np.interp(math.log(w0 / 3), np.log(w), mag))
    return 1.0 / m if m > 0 and math.isfinite(m) else k0 * 0.1


def slow_poles(plant: Plant, w0: float) -> np.ndarray:
    """The plant's two slowest stable, non-integrating poles in the s-plane (a complex pair counts
    as two); made-up real poles at fractions of ``w0`` when the plant has fewer."""
    poles = np.asarray(plant.poles, dtype=complex)
    if plant.dt is not None:
        poles = poles[np.abs(poles) > ROOT_MAG_FLOOR]
        poles = np.log(poles) / plant.dt
    cand = sorted((p for p in poles if p.real < -STABILITY_MARGIN * max(1.0, abs(p))), key=abs)
    if cand and abs(cand[0].imag) > REAL_ROOT_TOL:
        return np.array([cand[0], np.conj(cand[0])])
    fill = [-0.3 * w0, -0.9 * w0]
    out = [p for p in cand[:2] if abs(p.imag) <= REAL_ROOT_TOL]
    return np.array((out + fill)[:2], dtype=complex)


DT_MAX_SHARE = 0.2  # a sample time above this share of the plant's fastest time constant is implausible
DT_MIN_SHARE = 1e-3  # and one below this share of it
DT_FAR = 1e-2  # said only beyond those by this factor (20 time constants, 1e-5 of one)


def dt_note(plant: Any, dt: float | None) -> str | None:
    """A warning when ``dt`` is implausible for a continuous ``plant``: a hundred times beyond the usual range (more
    than 20 times its fastest time constant, 1/|p| of its fastest nonzero pole, or below 1e-5 of it), with the likely
    unit slip (``--dt 4`` meant as milliseconds, ``--dt 250`` meant as a rate in Hz) where one lands in the usual
    range (a fifth to a thousandth of that time constant); None otherwise. Only that far out: a fast actuator or
    filter pole makes an ordinary sample time look coarse (a 250 Hz loop with a 2 ms motor), and a slow plant
    oversampled is no mistake."""
    if dt is None or getattr(plant, "dt", None) is not None:
        return None
    poles = np.asarray(plant.zpk.poles)
    mags = np.abs(poles[np.abs(poles) > 1e-12])
    if mags.size == 0:
        return None
    tau = float(1.0 / mags.max())
    lo, hi = DT_MIN_SHARE * tau, DT_MAX_SHARE * tau
    if DT_FAR * lo <= dt <= hi / DT_FAR:
        return None
    slips = [(f"{dt:g} ms", dt * 1e-3), (f"a rate of {dt:g} Hz", 1.0 / dt)] if dt > hi else \
        [(f"{dt:g} ks", dt * 1e3), (f"{dt:g} min", dt * 60.0)]
    fits = [f"if {what} was meant, give dt = {v:g} s" for what, v in slips if lo <= v <= hi]
    return (f"dt = {dt:g} s is {dt / tau:.3g} times the plant's fastest time constant ({tau:.3g} s): "
            + ("; ".join(fits) if fits else f"a sample time between {lo:.3g} and {hi:.3g} s suits this plant")
            + " (the sample time is in seconds)")


def dc_gain(plant: Any) -> float:
    """|G(0)| of the plant (continuous) or |G(1)| (discrete); inf with an integrator, 0 with a zero there."""
    zk = plant.zpk
    at = 1.0 if plant.is_discrete else 0.0
    if np.any(np.isclose(zk.poles, at, atol=EXACT_ROOT_TOL)):
        return math.inf
    return float(abs(complex(zk(np.array([at]))[0])))


def plant_sign(plant: Plant) -> float:
    """Feedback sign for the plant: the sign of its low-frequency gain (from the factored form, the
    integrators divided out), flipped once per unstable real pole (1/(s-1) has gain -1 at DC yet needs
    a positive controller gain to be stabilised)."""
    zk = plant.zpk
    x = 0.0 if plant.dt is None else 1.0
    scale = max(1.0, *(abs(r) for r in np.concatenate([zk.zeros, zk.poles]))) if zk.poles.size else 1.0
    at_dc = lambda r: np.abs(r - x) <= ROOT_AT_DC_TOL * scale
    g = zk.gain * np.prod(x - zk.zeros[~at_dc(zk.zeros)]) / np.prod(x - zk.poles[~at_dc(zk.poles)])
    poles = zk.poles
    unstable_real = poles[(np.abs(poles.imag) < REAL_ROOT_TOL) & ((poles.real > STABILITY_MARGIN) if plant.dt is None
                                                          else (np.abs(poles) > 1 + STABILITY_MARGIN))]
    return (float(np.sign(np.real(g))) or 1.0) * (-1.0) ** unstable_real.size


def plant_scale(plant: Plant, dt: float | None) -> PlantScale:
    """Characteristic gain ``K0`` and frequency ``w0`` of the loop to design.

    ``w0`` is the plant's ultimate frequency (phase -180 deg, ZOH and delay
    included) when it exists below the Nyquist frequency, else the frequency of
    -135 deg, else the largest pole/zero magnitude; ``K0 = 1/|G(j w0)|``.
    """
    p = plant if (dt is None or plant.is_discrete) else plant.zoh(dt)
    wnyq = math.pi / p.dt if p.dt else None
    roots = np.concatenate([np.roots(plant.den), np.roots(plant.num)])
    if plant.dt is not None:
        roots = np.log(roots[np.abs(roots) > ROOT_MAG_FLOOR].astype(complex)) / plant.dt
    mags = np.abs(roots[np.abs(roots) > ROOT_MAG_FLOOR])
    wref = float(np.max(mags)) if mags.size else 1.0
    whi = wnyq if wnyq else 1e3 * wref
    w = np.logspace(np.log10(min(wref, whi) * 1e-4), np.log10(whi), 800)
    if wnyq:
        w = w[w < wnyq * 0.999]
    g = p.freqresp(w)
    with np.errstate(invalid="ignore", over="ignore"):  # a non-finite response finds no crossing: the fallback
        ph = np.unwrap(np.angle(g * plant_sign(plant)))
    ph -= 2 * np.pi * np.round(ph[0] / (2 * np.pi))
    w0 = None
    for target in (-np.pi, -0.75 * np.pi):  # first frequency where the phase falls through target
        idx = np.flatnonzero((ph[:-1] > target) & (ph[1:] <= target))
        if idx.size:
            w0 = float(w[idx[0] + 1])
            break
    if w0 is None:  # no such crossing (e.g. 1/s^2): the plant's unity-gain frequency, else its poles
        mag = np.abs(g)
        idx = np.flatnonzero((mag[:-1] >= 1.0) & (mag[1:] < 1.0))
        w0 = float(w[idx[0] + 1]) if idx.size else (min(wref, 0.3 * wnyq) if wnyq else wref)
        if wnyq:
            w0 = min(w0, 0.3 * wnyq)
    k0 = 1.0 / max(float(np.abs(p.freqresp(np.array([w0]))[0])), 1e-300)
    return k0, w0
