"""Controller structures: named parameters <-> transfer function.

Every structure is written once, with plain arithmetic on its parameters, so the
same coefficient formulas serve numbers (numpy) and symbols (CasADi ``SX``): the
optimiser and the verifier build the controller the same way.

Continuous forms and the discretisation used at sample time ``dt``:

==========  ==========================================  ===============================================
structure   continuous C(s)                             discrete C(z) at dt
==========  ==========================================  ===============================================
p           Kp                                          Kp
pi          Kp + Ki/s                                   Kp + Ki*dt*z/(z-1)            (backward Euler)
pd          Kp + Kd*s/(Tf*s+1)                          Kp + Kd*(z-1)/((Tf+dt)*z-Tf)  (backward Euler)
pid         Kp + Ki/s + Kd*s/(Tf*s+1)                   sum of the two rows above
pid_z       --                                          K*(z^2+a1*z+a2)/(z*(z-1))     (the thesis form)
lead, lag   K*(s/wz+1)/(s/wp+1)                         K*(1-pd)/(1-zd)*(z-zd)/(z-pd), zd=exp(-wz*dt),
                                                        pd=exp(-wp*dt)                (matched, DC gain K)
leadlag     lead(K, wz1, wp1) * lag(1, wz2, wp2)        product of the matched forms
==========  ==========================================  ===============================================

A lead has ``wp > wz``; a lag has ``wp < wz``; these orderings are part of the
structure (``orderings``) and are enforced by the search and the NLP.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .errors import InvalidControllerError
from .plant import Plant, check_dt, tf_freqresp

GAIN_SPAN = 100.0

__all__ = [
    "GAIN_SPAN",
    "ControllerTF",
    "Structure",
    "STRUCTURES",
    "get_structure",
    "controller_tf",
    "controller_from_expr",
    "plant_scale",
]


@dataclass(frozen=True, eq=False)
class ControllerTF:
    """A controller transfer function ``num/den`` (highest power first), continuous or at ``dt``."""

    num: np.ndarray
    den: np.ndarray
    dt: float | None = None

    def freqresp(self, w: np.ndarray) -> np.ndarray:
        return tf_freqresp(self.num, self.den, w, dt=self.dt)

    def to_dict(self) -> dict[str, Any]:
        return {"num": [float(c) for c in self.num], "den": [float(c) for c in self.den], "dt": self.dt}


# -- polynomial helpers that work on numbers and on CasADi symbols -------------------------

def _pmul(a: Sequence[Any], b: Sequence[Any]) -> list[Any]:
    out: list[Any] = [0] * (len(a) + len(b) - 1)
    for i, x in enumerate(a):
        for j, y in enumerate(b):
            out[i + j] = out[i + j] + x * y
    return out


def _padd(a: Sequence[Any], b: Sequence[Any]) -> list[Any]:
    n = max(len(a), len(b))
    a = [0] * (n - len(a)) + list(a)
    b = [0] * (n - len(b)) + list(b)
    return [x + y for x, y in zip(a, b)]


def _sum_fractions(terms: Sequence[tuple[list[Any], list[Any]]]) -> tuple[list[Any], list[Any]]:
    num, den = terms[0]
    for n2, d2 in terms[1:]:
        num, den = _padd(_pmul(num, d2), _pmul(n2, den)), _pmul(den, d2)
    return num, den


# -- the structures ----------------------------------------------------------------------

Coeffs = tuple[list[Any], list[Any]]


def _p(x, dt, exp):
    return [x[0]], [1]


def _pi_terms(kp, ki, dt):
    if dt is None:
        return [([kp], [1]), ([ki], [1, 0])]
    return [([kp], [1]), ([ki * dt, 0], [1, -1])]


def _d_term(kd, tf, dt):
    if dt is None:
        return ([kd, 0], [tf, 1])
    return ([kd, -kd], [tf + dt, -tf])


def _pi(x, dt, exp):
    return _sum_fractions(_pi_terms(x[0], x[1], dt))


def _pd(x, dt, exp):
    return _sum_fractions([([x[0]], [1]), _d_term(x[1], x[2], dt)])


def _pid(x, dt, exp):
    return _sum_fractions(_pi_terms(x[0], x[1], dt) + [_d_term(x[2], x[3], dt)])


def _pid_z(x, dt, exp):
    k, a1, a2 = x
    return [k, k * a1, k * a2], [1, -1, 0]


def _first_order(k, wz, wp, dt, exp):
    if dt is None:
        # K (s/wz + 1)/(s/wp + 1) = K*wp/wz * (s + wz)/(s + wp)
        return [k * wp, k * wp * wz], [wz, wz * wp]
    zd, pd = exp(-wz * dt), exp(-wp * dt)
    g = k * (1 - pd) / (1 - zd)
    return [g, -g * zd], [1, -pd]


def _leadlag1(x, dt, exp):
    return _first_order(x[0], x[1], x[2], dt, exp)


def _leadlag(x, dt, exp):
    n1, d1 = _first_order(x[0], x[1], x[2], dt, exp)
    n2, d2 = _first_order(1, x[3], x[4], dt, exp)
    return _pmul(n1, n2), _pmul(d1, d2)


@dataclass(frozen=True)
class Structure:
    """A controller structure.

    ``kinds`` gives each parameter's role: ``"gain"`` (any sign, scaled by the
    plant's gain), ``"freq"`` (rad/s, > 0), ``"time"`` (s, >= 0) or ``"coef"``
    (dimensionless polynomial coefficient).
    """

    name: str
    params: tuple[str, ...]
    kinds: tuple[str, ...]
    coeffs: Callable[[Sequence[Any], float | None, Callable[[Any], Any]], Coeffs] = field(repr=False)
    discrete_only: bool = False
    orderings: tuple[tuple[str, str], ...] = ()  # (a, b): a < b
    integrating: bool = False
    gain_units: tuple[int, ...] = ()  # per parameter: the gain scales as K0 * w0**unit (Ki: +1, Kd: -1)

    def gain_scale(self, k0: float, w0: float) -> np.ndarray:
        units = self.gain_units or (0,) * len(self.params)
        return np.array([k0 * w0 ** u for u in units])

    def tf(self, values: Mapping[str, float] | Sequence[float], dt: float | None) -> ControllerTF:
        x = self.vector(values)
        dt = check_dt(dt)
        if self.discrete_only and dt is None:
            raise InvalidControllerError(f"structure {self.name!r} is discrete: give dt")
        if dt is None:
            zero_t = [p for k, p, v in zip(self.kinds, self.params, x) if k == "time" and v == 0]
            if zero_t:
                raise InvalidControllerError(
                    f"{self.name}: {zero_t[0]} must be > 0 in continuous time (a pure derivative is improper)"
                )
        num, den = self.coeffs(x, dt, np.exp)
        num = np.asarray(num, dtype=float)
        den = np.asarray(den, dtype=float)
        if not (np.all(np.isfinite(num)) and np.all(np.isfinite(den))) or den[0] == 0:
            raise InvalidControllerError(f"{self.name} parameters {self.named(x)} give an invalid transfer function")
        return ControllerTF(num=num / den[0], den=den / den[0], dt=dt)

    def vector(self, values: Mapping[str, float] | Sequence[float]) -> np.ndarray:
        if isinstance(values, Mapping):
            unknown = set(values) - set(self.params)
            missing = [p for p in self.params if p not in values]
            if unknown or missing:
                raise InvalidControllerError(
                    f"{self.name} takes parameters {list(self.params)}; "
                    + (f"missing {missing}" if missing else f"unknown {sorted(unknown)}")
                )
            vals = [values[p] for p in self.params]
        else:
            vals = list(values)
            if len(vals) != len(self.params):
                raise InvalidControllerError(f"{self.name} takes {len(self.params)} parameters {list(self.params)}")
        try:
            x = np.asarray(vals, dtype=float)
        except (TypeError, ValueError) as e:
            raise InvalidControllerError(f"{self.name} parameters must be numbers") from e
        if not np.all(np.isfinite(x)):
            raise InvalidControllerError(f"{self.name} parameters must be finite, got {self.named(x)}")
        for kind, p, v in zip(self.kinds, self.params, x):
            if kind == "freq" and v <= 0:
                raise InvalidControllerError(f"{self.name}: {p} is a frequency and must be > 0, got {v}")
            if kind == "time" and v < 0:
                raise InvalidControllerError(f"{self.name}: {p} is a time constant and must be >= 0, got {v}")
        return x

    def named(self, x: Sequence[float]) -> dict[str, float]:
        return {p: float(v) for p, v in zip(self.params, x)}

    def bounds(self, plant: Plant, dt: float | None) -> tuple[np.ndarray, np.ndarray]:
        """Search box from the plant's scale: gains +-GAIN_SPAN times their unit (K0 * w0**unit)."""
        k0, w0 = plant_scale(plant, dt)
        wmax = (math.pi / dt) if dt else 1e3 * w0
        lo, hi = [], []
        for kind, scale in zip(self.kinds, self.gain_scale(k0, w0)):
            if kind == "gain":
                lo.append(-GAIN_SPAN * scale), hi.append(GAIN_SPAN * scale)
            elif kind == "freq":
                lo.append(1e-3 * w0), hi.append(min(wmax, 1e2 * w0))
            elif kind == "time":
                lo.append(0.0), hi.append(10.0 / w0)
            else:  # polynomial coefficient of a monic quadratic with zeros in |z| <= 1.5
                lo.append(-3.0), hi.append(3.0)
        return np.array(lo), np.array(hi)

    def initial_guess(self, plant: Plant, dt: float | None) -> dict[str, float]:
        """A pole-cancellation start (IMC / lambda-tuning style), sign from the plant.

        The controller's zeros go on the plant's slowest stable poles (two for
        PID/pid_z/lead-lag, one for PI/PD/lead); the gain puts the loop's
        crossover at a third of the plant's ultimate frequency ``w0``.
        """
        k0, w0 = plant_scale(plant, dt)
        sgn = plant_sign(plant)
        poles = _slow_poles(plant, w0)
        z1 = float(abs(poles[0]))  # one-zero structures: the slowest pole's frequency
        _, c1, c2 = np.real(np.poly(poles))  # two-zero structures: s^2 + c1 s + c2
        g = {"Kp": 1.0, "Ki": z1, "Kd": 0.0, "Tf": 0.0, "K": 1.0, "wz": z1, "wp": min(10 * z1, 3 * w0),
             "wz1": z1, "wp1": min(10 * z1, 3 * w0), "wz2": 0.1 * z1, "wp2": 0.01 * z1}
        if self.name in ("pid", "pd"):
            # Kd s^2 + Kp s + Ki = Kd (s^2 + c1 s + c2)   (pd: Kd s + Kp = Kd (s + z1))
            g.update(Kd=1.0, Kp=c1 if self.name == "pid" else z1, Ki=c2,
                     Tf=(0.1 / w0) if dt is None else 0.0)
        if dt is not None and self.name in ("pid", "pi"):
            # in discrete time put the zeros exactly on the ZOH plant's poles: with Tf = 0 the
            # backward-Euler PID numerator is (Kp + Ki dt + Kd/dt) z^2 - (Kp + 2 Kd/dt) z + Kd/dt
            zp = np.exp(poles * dt)
            if self.name == "pid":
                _, a1, a2 = np.real(np.poly(zp))
                g.update(Kd=a2 * dt, Kp=-a1 - 2 * a2, Ki=(1 + a1 + a2) / dt, Tf=0.0)
            else:  # (Kp + Ki dt) z - Kp = z - e^{-z1 dt}
                e1 = float(np.exp(-z1 * dt))
                g.update(Kp=e1, Ki=(1 - e1) / dt)
        if self.name == "lag":
            g.update(wz=0.1 * z1, wp=0.01 * z1)
        if self.name == "pid_z":
            if dt is None:
                raise InvalidControllerError("pid_z is discrete: give dt")
            _, a1, a2 = np.real(np.poly(np.exp(poles * dt)))
            g.update(a1=float(a1), a2=float(a2))
        # overall gain: crossover of the loop at w0/3
        wc = w0 / 3.0
        x = np.array([g[p] for p in self.params], dtype=float)
        c1 = self.tf(x, dt)
        p_eff = plant if (dt is None or plant.is_discrete) else plant.zoh(dt)
        mag = abs(c1.freqresp(np.array([wc]))[0] * p_eff.freqresp(np.array([wc]))[0])
        k = sgn / mag if np.isfinite(mag) and mag > 0 else sgn * k0 * 0.1
        for i, kind in enumerate(self.kinds):
            if kind == "gain":
                x[i] *= k
        g = dict(zip(self.params, x))
        # keep the start inside the search box: in discrete time a lead pole at 3*w0 can lie
        # above the Nyquist frequency pi/dt (roll, yaw at dt = 0.04), the box's upper bound
        lo, hi = self.bounds(plant, dt)
        out = {}
        for p, l, h in zip(self.params, lo, hi):
            v = float(g[p])
            if not l <= v <= h:
                v = float(np.clip(v, l + 0.01 * (h - l), h - 0.01 * (h - l)))
            out[p] = v
        for a, b in self.orderings:  # clipping may have collapsed an ordered pair: reopen it
            if out[a] >= out[b]:
                out[a] = max(out[b] / 3.0, float(lo[self.params.index(a)]))
        return out


STRUCTURES: dict[str, Structure] = {
    s.name: s
    for s in (
        Structure("p", ("Kp",), ("gain",), _p),
        Structure("pi", ("Kp", "Ki"), ("gain", "gain"), _pi, integrating=True, gain_units=(0, 1)),
        Structure("pd", ("Kp", "Kd", "Tf"), ("gain", "gain", "time"), _pd, gain_units=(0, -1, 0)),
        Structure("pid", ("Kp", "Ki", "Kd", "Tf"), ("gain", "gain", "gain", "time"), _pid, integrating=True,
                  gain_units=(0, 1, -1, 0)),
        Structure("pid_z", ("K", "a1", "a2"), ("gain", "coef", "coef"), _pid_z, discrete_only=True, integrating=True),
        Structure("lead", ("K", "wz", "wp"), ("gain", "freq", "freq"), _leadlag1, orderings=(("wz", "wp"),)),
        Structure("lag", ("K", "wz", "wp"), ("gain", "freq", "freq"), _leadlag1, orderings=(("wp", "wz"),)),
        Structure(
            "leadlag",
            ("K", "wz1", "wp1", "wz2", "wp2"),
            ("gain", "freq", "freq", "freq", "freq"),
            _leadlag,
            orderings=(("wz1", "wp1"), ("wp2", "wz2")),
        ),
    )
}


def get_structure(name: str) -> Structure:
    try:
        return STRUCTURES[name]
    except KeyError:
        raise InvalidControllerError(
            f"unknown structure {name!r}; choose one of {sorted(STRUCTURES)}"
        ) from None


def controller_tf(structure: str, gains: Mapping[str, float], *, dt: float | None) -> ControllerTF:
    """Transfer function of ``structure`` with named ``gains`` (continuous, or at ``dt``)."""
    return get_structure(structure).tf(gains, dt)


def controller_from_expr(text: str, *, dt: float | None) -> ControllerTF:
    """A controller from an expression in ``s`` (continuous) or ``z`` (needs ``dt``)."""
    from .expr import parse_tf_expr

    p = parse_tf_expr(text)
    dt = check_dt(dt)
    if p.var == "z" and dt is None:
        raise InvalidControllerError("controller is in z: give its sample time dt")
    if p.var == "s" and dt is not None:
        raise InvalidControllerError(
            "controller is in s but a sample time dt was given: write the digital controller in z"
        )
    if p.num.size > p.den.size:
        raise InvalidControllerError("controller is improper (more zeros than poles): add a filter pole")
    return ControllerTF(num=p.num, den=p.den, dt=dt)


# -- plant scale ---------------------------------------------------------------------------

def _low_freq_coeffs(plant: Plant) -> tuple[np.ndarray, np.ndarray]:
    """num/den as polynomials in a variable that is 0 at DC (s, or z-1)."""
    if plant.dt is None:
        return plant.num, plant.den
    shift = np.poly1d([1.0, 1.0])
    return np.poly1d(plant.num)(shift).coeffs, np.poly1d(plant.den)(shift).coeffs


def _slow_poles(plant: Plant, w0: float) -> np.ndarray:
    """The plant's two slowest stable, non-integrating poles in the s-plane (a complex pair counts
    as two); made-up real poles at fractions of ``w0`` when the plant has fewer."""
    poles = np.roots(plant.den).astype(complex)
    if plant.dt is not None:
        poles = poles[np.abs(poles) > 1e-9]
        poles = np.log(poles) / plant.dt
    cand = sorted((p for p in poles if p.real < -1e-9 * max(1.0, abs(p))), key=abs)
    if cand and abs(cand[0].imag) > 1e-9:
        return np.array([cand[0], np.conj(cand[0])])
    fill = [-0.3 * w0, -0.9 * w0]
    out = [p for p in cand[:2] if abs(p.imag) <= 1e-9]
    return np.array((out + fill)[:2], dtype=complex)


def plant_sign(plant: Plant) -> float:
    """Feedback sign for the plant: the sign of its low-frequency gain (ratio of lowest-order
    coefficients), flipped once per unstable real pole (1/(s-1) has gain -1 at DC yet needs a
    positive controller gain to be stabilised)."""
    n, d = _low_freq_coeffs(plant)
    nl = n[np.flatnonzero(np.abs(n) > 1e-14 * np.max(np.abs(n)))[-1]]
    dl = d[np.flatnonzero(np.abs(d) > 1e-14 * np.max(np.abs(d)))[-1]]
    poles = np.roots(plant.den)
    unstable_real = poles[(np.abs(poles.imag) < 1e-9) & ((poles.real > 1e-9) if plant.dt is None
                                                          else (np.abs(poles) > 1 + 1e-9))]
    return (float(np.sign(nl * dl)) or 1.0) * (-1.0) ** unstable_real.size


def plant_scale(plant: Plant, dt: float | None) -> tuple[float, float]:
    """Characteristic gain ``K0`` and frequency ``w0`` of the loop to design.

    ``w0`` is the plant's ultimate frequency (phase -180 deg, ZOH and delay
    included) when it exists below the Nyquist frequency, else the frequency of
    -135 deg, else the largest pole/zero magnitude; ``K0 = 1/|G(j w0)|``.
    """
    p = plant if (dt is None or plant.is_discrete) else plant.zoh(dt)
    wnyq = math.pi / p.dt if p.dt else None
    roots = np.concatenate([np.roots(plant.den), np.roots(plant.num)])
    if plant.dt is not None:
        roots = np.log(roots[np.abs(roots) > 1e-9].astype(complex)) / plant.dt
    mags = np.abs(roots[np.abs(roots) > 1e-9])
    wref = float(np.max(mags)) if mags.size else 1.0
    whi = wnyq if wnyq else 1e3 * wref
    w = np.logspace(np.log10(min(wref, whi) * 1e-4), np.log10(whi), 800)
    if wnyq:
        w = w[w < wnyq * 0.999]
    g = p.freqresp(w)
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
