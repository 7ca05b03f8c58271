"""A reference step with the actuator's limits: the law run sample by sample with its output clamped and its
integrator handled as the law does, the plant's output between the samples.

The linear verifier's step is that of a unit reference with an unbounded actuator. A vehicle's actuator is bounded
(normalised torque in [-1, 1], less the share the other axes and the thrust use), and a large step saturates it;
what the integrator does then is the law's own. Here the law runs as it runs on the target, for a step of
amplitude ``A`` (:class:`Actuator`):

* ``px4_rate``: PX4's ``RateControl``: the integrator's update after the output, clamped to ``+-int_lim``, no
  growth in the direction the output saturates (the allocator's saturation flags, as they arrive: see
  :func:`px4_flag_period`), and the fade ``max(0, 1 - (e/400 deg/s)^2)`` (``rate_control.cpp``,
  ``updateIntegral``); the D path as the firmware computes it at the raw gyro rate
  (:func:`tuner.firmware.laws.dgyro_filter`);
* ``ardupilot_rate``: ArduPilot's ``AC_PID``: the integrator updated before the output, clamped to ``+-IMAX``, and
  while the mixer reports a limit it only shrinks (``AC_PID::update_i`` with ``limit`` set);
* ``pid2``: the law ``tuner export`` writes for it (conditional integration: the integral held while the unclamped
  output is beyond a limit and would integrate further; :mod:`tuner.export.twodof`);
* any other discrete controller: the difference equation ``tuner export`` writes with ``--u-min/--u-max``
  (the integrator split off by partial fractions, held under the same condition; :mod:`tuner.export.codegen`).

The plant is the loop's: its zero-order-hold model at ``dt`` with the delay (a fraction of a sample exact), the
output at ``samples_per_dt`` instants of every sample (:func:`tuner.analysis.response.lifted_with_switch`). The
metrics are the verifier's (:func:`tuner.analysis.response.step_metrics`) on ``y/A``; ``saturated_fraction`` is the
share of samples whose output the limits clamped. A loop without a sample time is refused (the law runs at one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import TunerError
from ..firmware.px4 import PX4_STATUS_INTERVAL_S, px4_flag_period  # noqa: F401  (PX4's, re-exported here)
from .response import SAMPLES_PER_DT, StepMetrics, StepResponse, default_horizon, lifted_with_switch, step_metrics

__all__ = ["Actuator", "SaturatedStep", "saturated_step", "MAX_SAT_SAMPLES", "px4_flag_period"]

MAX_SAT_SAMPLES = 200_000  # samples of one simulated step (the horizon is cut there, and said)


@dataclass(frozen=True)
class Actuator:
    """The actuator's limits and the step's amplitude: ``u_min <= u <= u_max``, a reference step of ``step_size``.

    Examples
    --------
    >>> from tuner.analysis.saturation import Actuator
    >>> Actuator.of(u_max=0.4, step_size=8.0)
    Actuator(u_min=-0.4, u_max=0.4, step_size=8.0)
    """

    u_min: float
    u_max: float
    step_size: float = 1.0

    @classmethod
    def of(cls, *, u_min: float | None = None, u_max: float | None = None, step_size: float | None = None
           ) -> Actuator:
        """Validated; one limit alone is symmetric (``u_max`` alone means ``-u_max <= u <= u_max``)."""
        vals = {}
        for name, v in (("u_min", u_min), ("u_max", u_max), ("step_size", step_size)):
            if v is None:
                continue
            try:
                f = float(v)
            except (TypeError, ValueError):
                raise TunerError(f"{name} must be a number, got {v!r}", field=name) from None
            if not math.isfinite(f):
                raise TunerError(f"{name} must be finite, got {v!r}", field=name)
            vals[name] = f
        if "u_min" not in vals and "u_max" not in vals:
            raise TunerError("give the actuator's limit: u_max (and u_min; u_max alone is symmetric)", field="u_max")
        hi = vals.get("u_max", -vals.get("u_min", 0.0))
        lo = vals.get("u_min", -hi)
        if not lo < hi:
            raise TunerError(f"u_min ({lo:g}) must be below u_max ({hi:g})", field="u_min")
        a = vals.get("step_size", 1.0)
        if a == 0:
            raise TunerError("step_size must be non-zero (the reference step's amplitude)", field="step_size")
        return cls(u_min=lo, u_max=hi, step_size=a)


@dataclass(frozen=True, eq=False)
class SaturatedStep:
    """The step of amplitude ``actuator.step_size`` with the output clamped: ``response`` (``y`` in the plant's
    units, ``u`` the clamped output), ``metrics`` (on ``y/A``), ``saturated_fraction`` (the share of the samples up
    to the settling time, the whole run if it never settles, whose output the limits clamped),
    ``saturated_time_s`` (their total time), ``law`` (what ran), ``iae`` (of ``A - y``), ``notes``."""

    actuator: Actuator
    response: StepResponse
    metrics: StepMetrics
    saturated_fraction: float
    law: str
    iae: float
    saturated_time_s: float = 0.0
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """The step's figures (``u_min``, ``u_max``, ``step_size``, the metrics, ``saturated_fraction``, ...)."""
        m = self.metrics
        return {"u_min": self.actuator.u_min, "u_max": self.actuator.u_max, "step_size": self.actuator.step_size,
                "law": self.law, "overshoot_pct": m.overshoot_pct, "settling_time_s": m.settling_time_s,
                "rise_time_s": m.rise_time_s, "steady_state_error": m.steady_state_error,
                "control_peak": m.control_peak, "saturated_fraction": self.saturated_fraction,
                "saturated_time_s": self.saturated_time_s, "iae": self.iae,
                "horizon_s": float(self.response.t[-1]) if self.response.t.size else 0.0, "notes": list(self.notes)}


# -- the laws, one sample per call: u = law(r, y) --------------------------------------------------------------

class _TwoDof:
    """tuner export's pid2 law (tuner.export.twodof._lines), conditional integration or back-calculation."""

    def __init__(self, law: Any) -> None:
        self.law = law
        self.i = self.d = self.v1 = self.e1 = 0.0

    def __call__(self, r: float, y: float) -> tuple[float, bool]:
        L = self.law
        e = r - y
        p = L.kp * (L.b * r - y)
        v = L.c * r - y
        dd = L.ad * self.d + L.bd * (v - self.v1)
        di = L.gi0 * e + L.gi1 * self.e1
        i = self.i + di
        w = p + i + dd
        u = min(max(w, L.u_min if L.u_min is not None else -math.inf), L.u_max if L.u_max is not None else math.inf)
        if L.anti_windup == "conditional":
            if (L.u_max is not None and w > L.u_max and di > 0) or (L.u_min is not None and w < L.u_min and di < 0):
                i = self.i
                w = p + i + dd
                u = min(max(w, L.u_min if L.u_min is not None else -math.inf),
                        L.u_max if L.u_max is not None else math.inf)
        elif L.tt is not None:
            i += L.dt / L.tt * (u - w)
        self.i, self.d, self.v1, self.e1 = i, dd, v, e
        return u, u != w


class _Difference:
    """tuner export's difference equation with output limits (tuner.export.codegen._body): a controller with one
    integrator is split as r/(z - 1) + Q/A', the integrator held while saturated and integrating further."""

    def __init__(self, de: Any) -> None:
        self.de = de
        it = de.integrator
        b, a = (it.q, it.a) if it is not None else (de.b, de.a)
        n = max(len(a), len(b)) - 1
        self.b = np.concatenate([b, np.zeros(n + 1 - len(b))])
        self.a = np.concatenate([a, np.zeros(n + 1 - len(a))])
        self.z = np.zeros(max(n, 1))
        self.xi = 0.0

    def _df2t(self, e: float) -> float:
        b, a, z = self.b, self.a, self.z
        y = b[0] * e + (z[0] if b.size > 1 else 0.0)
        for i in range(b.size - 1):
            z[i] = b[i + 1] * e - a[i + 1] * y + (z[i + 1] if i + 1 < b.size - 1 else 0.0)
        return y

    def __call__(self, r: float, y: float) -> tuple[float, bool]:
        de = self.de
        e = r - y
        lo = de.u_min if de.u_min is not None else -math.inf
        hi = de.u_max if de.u_max is not None else math.inf
        w = self._df2t(e)
        if de.integrator is None:
            u = min(max(w, lo), hi)
            return u, u != w
        v = w + self.xi
        d = de.integrator.r * e
        u = min(max(v, lo), hi)
        if not ((v > hi and d > 0) or (v < lo and d < 0)):
            self.xi += d
        return u, u != v


def _law(loop: Any, structure: str | None, gains: dict[str, float] | None, act: Actuator) -> tuple[Any, str]:
    dt = loop.dt
    from ..firmware.registry import by_structure

    fw = by_structure(structure)
    if fw is not None:  # a firmware's law, as the firmware runs it (its module's simulator)
        from ..controllers import get_structure

        st = get_structure(structure)
        g = {**st.fixed_values, **{k: float(v) for k, v in (gains or {}).items()}}  # (a later fixed value: its default)
        missing = [k for k in (*st.params, *st.fixed_values) if k not in g]
        if missing:
            raise TunerError(f"{structure}: the gains lack {', '.join(missing)}", field="gains")
        return fw.simulator(g, dt, act.u_min, act.u_max), fw.simulator_words
    if structure == "pid2":
        from ..export.twodof import two_dof_law

        law = two_dof_law(dict(gains or {}), dt, dt=None, method="structure", u_min=act.u_min, u_max=act.u_max)
        return _TwoDof(law), "pid2 as exported (conditional integration)"
    if loop.controller.two_dof:
        raise TunerError("a 2-DOF controller given by its coefficients: the saturated step needs its structure "
                         "(pid2, px4_rate, ardupilot_rate) and gains", field="controller")
    from ..export.discrete import difference_equation

    de = difference_equation(loop.controller, u_min=act.u_min, u_max=act.u_max)
    what = ("the exported difference equation, integrator held while saturated (conditional integration)"
            if de.integrator is not None else "the exported difference equation, output clamped")
    return _Difference(de), what


def saturated_step(loop: Any, actuator: Actuator, *, structure: str | None = None,
                   gains: dict[str, float] | None = None, horizon_s: float | None = None,
                   samples_per_dt: int = SAMPLES_PER_DT) -> SaturatedStep:
    """The reference step of ``actuator.step_size`` on ``loop`` (a sampled-data :class:`~tuner.loop.Loop`) with
    the law's output clamped to the actuator's limits (see the module); ``structure`` and ``gains`` name the law
    (a firmware law or ``pid2``; other controllers run as their exported difference equation). ``horizon_s``
    defaults to three times the linear loop's (saturation slows the response).

    Examples
    --------
    A P controller Kp = 2 on an integrator, 1/s, at 100 Hz: with |u| <= 1 a step of 10 ramps at slope 1 until the
    error is 1/Kp = 0.5 (t = 9.5 s), then decays with the time constant 1/Kp into the 2 % band (an error of 0.2) at
    9.5 + ln(2.5)/2 = 9.96 s: saturated for 9.5 of its 9.96 s:

    >>> from tuner import controller_from_coeffs, make_plant
    >>> from tuner.loop import build_loop
    >>> from tuner.analysis.saturation import Actuator, saturated_step
    >>> loop = build_loop(make_plant([1.0], [1.0, 0.0]), controller_from_coeffs([2.0], [1.0], dt=0.01))
    >>> s = saturated_step(loop, Actuator.of(u_max=1.0, step_size=10.0), horizon_s=15.0)
    >>> round(s.metrics.settling_time_s, 2), round(s.saturated_time_s, 2), round(s.saturated_fraction, 3)
    (9.95, 9.51, 0.954)
    """
    dt = loop.dt
    if dt is None:
        raise TunerError("the saturated step runs the law at its sample time: give dt (the controller's)",
                         field="dt")
    law, what = _law(loop, structure, gains, actuator)
    g = loop.loop_plant.ss()
    A, B, C, D = (np.asarray(m, float) for m in (g.A, g.B, g.C, g.D))
    B, C = B.reshape(-1), C.reshape(-1)
    D = float(np.asarray(D).reshape(-1)[0]) if np.size(D) else 0.0
    m = int(loop.delay_samples)
    if D != 0.0 and m == 0:
        raise TunerError("the plant has a direct feedthrough and no delay: the law's output would act on the "
                         "measurement it reads in the same sample; give the computation delay (one sample)",
                         field="plant")
    T = 3.0 * default_horizon(loop) if horizon_s is None else float(horizon_s)
    K = int(math.ceil(T / dt)) + 1
    notes = []
    if K > MAX_SAT_SAMPLES:
        K = MAX_SAT_SAMPLES
        notes.append(f"the simulation is cut at {K} samples ({K * dt:g} s)")
    fine = loop.plant_ct is not None and samples_per_dt > 1
    if fine:
        Cf, Df, offsets, phi = lifted_with_switch(loop, int(samples_per_dt))
    a = actuator.step_size
    x = np.zeros(A.shape[0])
    buf = [0.0] * (m + 1)  # u[k-m-1] ... u[k-1] before this sample's law runs; u[k-m] ... u[k] after
    ys, us, sat, yf_rows, tf_rows = [], [], [], [], []
    for k in range(K):
        # the measurement at t_k: the state and, through a feedthrough (only with a delay, m >= 1), the input
        # held over this sample, u[k-m], the same one the state update and the fine output below use
        y = float(C @ x) + (D * buf[1] if m else 0.0)
        u, clamped = law(a, y)
        sat.append(bool(clamped))
        buf = buf[1:] + [u] if m else [u]
        ua = buf[0]
        if fine:
            yf_rows.append(Cf @ x + Df * ua)
            tf_rows.append(k * dt + offsets)
        ys.append(y)
        us.append(u)
        x = A @ x + B * ua
    ts = np.arange(K) * dt
    ys_a, us_a = np.asarray(ys), np.asarray(us)
    if fine:
        t = np.concatenate(tf_rows)
        yfine = np.concatenate(yf_rows)
        ufine = np.repeat(us_a, offsets.size)
        corners = None if phi is None else ts + phi
    else:
        t, yfine, ufine, corners = ts, ys_a, us_a, None
    from .response import steady_state

    final = a * steady_state(loop)[0]  # the linear loop's final value (1 with integral action): what it settles to
    resp = StepResponse(t=t, y=yfine, u=ufine, t_samples=ts, y_samples=ys_a, y_final=final, between_samples=fine,
                        corners=corners)
    norm = StepResponse(t=t, y=yfine / a, u=ufine, t_samples=ts, y_samples=ys_a / a, y_final=final / a,
                        between_samples=fine, corners=corners)
    met = step_metrics(norm)
    met = StepMetrics(met.overshoot_pct, met.settling_time_s, met.rise_time_s, float((final - ys_a[-1]) / a),
                      float(np.max(np.abs(us_a))))  # (the error against the final value the metrics use)
    err = np.abs(a - yfine)
    iae = float(np.sum(0.5 * (err[1:] + err[:-1]) * np.diff(t))) if t.size > 1 else 0.0
    # the share of the step's transient (up to its settling; the whole run if it never settles) spent saturated
    n = K if not math.isfinite(met.settling_time_s) else max(1, min(K, int(math.ceil(met.settling_time_s / dt)) + 1))
    return SaturatedStep(actuator=actuator, response=resp, metrics=met, saturated_fraction=float(np.mean(sat[:n])),
                         law=what, iae=iae, saturated_time_s=float(np.sum(sat)) * dt, notes=tuple(notes))
