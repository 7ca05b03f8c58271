"""The identified model's uncertainty in the design: a plant set from the Cramér–Rao bounds, a Monte Carlo check.

An :class:`~tuner.identify.IdentifyResult` carries its parameters (gain, pole and zero frequencies, damping
ratios, the delay) and their covariance (``covariance``, the Cramér–Rao matrix, in the order of
``uncertainty``). ``tune(result, robust=K)`` designs one controller for the set

* the nominal model, plus
* every corner of the ``K``-sigma box of the ``CORNERS`` (4) **dominant** parameters (``2^4 = 16`` plants), the
  others at their nominal values, plus
* the two ``K``-sigma points (``-K``, ``+K``) of each remaining parameter, one at a time;

at most ``1 + 16 + 2 (p - 4)`` plants (17 for a second-order model with a delay; ``MAX_PLANTS`` is 50). A
parameter's *dominance* is how much its ``K``-sigma change moves the model's frequency response where the loop
will cross over: ``|log G(jw; theta + K sigma_i) - log G(jw; theta)|`` (the complex log: dB and phase together)
at the nominal model's ultimate frequency ``w0`` (phase -180 deg with the ZOH at the loop's ``dt``) and at
``w0 / 2``. The corners of the per-parameter box contain the covariance ellipsoid's ``K``-sigma extent in
every parameter direction, so for a quantity that varies about linearly with the parameters (a margin,
over a small uncertainty) the worst corner is at least its ``K``-sigma value.

Gains, frequencies and damping ratios vary in log space (``value * exp(±K sigma_rel)``: they stay positive,
as in the fit), the delay linearly (clipped at 0). The same model is used to **draw** parameters for the
Monte Carlo check (:func:`monte_carlo`): ``N`` draws (default 200, seeded) from the normal distribution
with the reported covariance (mapped to log space for the log-parameters), each draw's loop judged by the
verifier (:func:`tuner.analysis.verify.analyze_loop`, on a 1000-point grid refined by root finding) against
the spec (a loop the verifier cannot decide counts as failing): the fraction of draws meeting each constraint and the
whole spec, and the worst (and 5th-percentile) margins and step metrics.

**Bounds too wide for a set** (:func:`check_spread`): a parameter whose ``K``-sigma change, either way, moves the
model's response at ``w0 / 2`` or ``w0`` by more than a decade, ``|log G(jw; theta +- K sigma_i) - log G(jw; theta)|
> ln 10`` (a factor of 10, 20 dB, in gain; or 132 deg of phase; or a combination), is not identified near the
crossover: the corners of such a box are not plants of one airframe, and a controller for all of them is no design
for the one flown (a 2-sigma box spanning two decades of gain asks for a loop whose gain may drop or rise 100-fold).
The robust set (at ``K``) and the Monte Carlo draws (at ``MC_SIGMA``: one standard deviation already spanning a
decade makes the draws meaningless) are then refused before any work, naming each such parameter, its value and
bound, and what to fly. (A delay's change is a pure phase ``w * K sigma``, taken exactly; the log-parameters'
changes are evaluated in double precision, and a value beyond it, ``exp(K sigma)`` overflowing, counts as too wide.)
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._lazy import is_identification
from .errors import TunerError

__all__ = ["CORNERS", "MONTE_CARLO_DRAWS", "MAX_SPREAD", "MC_SIGMA", "MonteCarlo", "RobustDesign",
           "is_identification", "check_spread", "plant_set", "parameter_draws", "plant_of", "monte_carlo"]

CORNERS = 4  # parameters whose K-sigma corners are all in the set
MONTE_CARLO_DRAWS = 200
MAX_ROBUST_K = 10.0
MAX_DRAWS = 10_000
# the verifier's frequency grid for the draws: its crossings and peaks are refined by root finding either way
# (the margins of a 1000-point grid agree with the default 3000 to 1e-10 deg on the loops tried), 3x cheaper
MC_GRID_POINTS = 1000
#: the most a parameter's K-sigma change may move the model's response near the crossover (|d log G|): a decade
MAX_SPREAD = math.log(10.0)
#: the reach of the Monte Carlo draws checked against MAX_SPREAD, in standard deviations
MC_SIGMA = 1.0
_EXP_MAX = 709.0  # exp() of more overflows a double


def check_robust(k: Any) -> float:
    """``k`` (standard deviations of the robust set) validated, as a float; TunerError(field="robust") otherwise."""
    if isinstance(k, bool) or not isinstance(k, (int, float, np.integer, np.floating)) or not math.isfinite(k) \
            or not 0 < float(k) <= MAX_ROBUST_K:
        raise TunerError(f"robust must be a number of standard deviations in (0, {MAX_ROBUST_K:g}], got {k!r}",
                         field="robust")
    return float(k)


def check_draws(n: Any) -> int:
    """``n`` (Monte Carlo draws) validated, as an int; TunerError(field="monte_carlo") otherwise."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 0 <= int(n) <= MAX_DRAWS:
        raise TunerError(f"monte_carlo must be a whole number of draws from 0 to {MAX_DRAWS}, got {n!r}",
                         field="monte_carlo")
    return int(n)


def _names(res: Any) -> list[str]:
    return list(res.uncertainty)


def _log_covariance(res: Any, field: str = "robust") -> tuple[list[str], np.ndarray, np.ndarray]:
    """Names, nominal values and the covariance with the log-parameters in log space (the delay linear)."""
    names = _names(res)
    cov = res.covariance
    if cov is None or np.shape(cov) != (len(names), len(names)) or not np.all(np.isfinite(cov)):
        raise TunerError("the identification carries no finite parameter covariance (re-identify with this "
                         "version; a singular fit has none): the uncertainty cannot enter the design",
                         field=field)
    values = res.model.values()
    v0 = np.array([float(values[n]) for n in names])
    d = np.array([1.0 if n == "delay_s" else abs(v) for n, v in zip(names, v0)])
    if np.any(d == 0):
        raise TunerError("a parameter of the identified model is 0: no relative uncertainty", field=field)
    c = np.asarray(cov, float) / np.outer(d, d)
    return names, v0, 0.5 * (c + c.T)


def _apply(names: list[str], v0: np.ndarray, dx: np.ndarray) -> dict[str, float]:
    """Parameter values at the offset ``dx`` (log space for the log-parameters, linear for the delay); a value
    beyond double precision is ``inf`` (such a parameter set is no plant: :func:`plant_of` refuses it)."""
    out = {}
    for n, v, x in zip(names, v0, dx):
        out[n] = max(v + x, 0.0) if n == "delay_s" else (v * math.exp(x) if x <= _EXP_MAX else math.copysign(
            math.inf, v))
    return out


def _w0(res: Any, nominal: Any, dt: float | None) -> float:
    """The frequency the loop will cross over near: the nominal model's ultimate frequency with the hold at ``dt``
    (:func:`tuner.design.plant_scale`), else the middle of the identification's band (log scale)."""
    from .design import plant_scale

    try:
        w0 = float(plant_scale(nominal, dt)[1])
    except TunerError:
        w0 = math.nan
    if not (math.isfinite(w0) and w0 > 0):
        w0 = math.sqrt(res.band_rad_s[0] * res.band_rad_s[1])
    return w0


def _spread(res: Any, names: list[str], v0: np.ndarray, sd: np.ndarray, k: float, w: np.ndarray) -> list[float]:
    """Per parameter: the largest ``|log G(jw; theta +- k sigma_i) - log G(jw; theta)|`` over ``w`` (either way; inf
    where the changed model has no finite response)."""
    from .identify.model import Model

    o = res.model.structure
    full = dict(res.model.values())
    g0 = res.model.freqresp(w)
    out = []
    for i, n in enumerate(names):
        x = k * float(sd[i])
        if n == "delay_s":  # a pure phase change, exact: w * dtau (the lower side clipped at a zero delay)
            out.append(float(np.max(w)) * max(x, 0.0))
            continue
        if not math.isfinite(x) or x > _EXP_MAX:
            out.append(math.inf)
            continue
        worst = 0.0
        for s in (-1.0, 1.0):
            dx = np.zeros(len(names))
            dx[i] = s * x
            vals = {**full, **_apply(names, v0, dx)}
            try:
                with np.errstate(all="ignore"):
                    g = Model.from_values(o.poles, o.zeros, vals).freqresp(w)
                    d = np.abs(np.log(g / g0))
            except (ValueError, OverflowError, ZeroDivisionError, FloatingPointError):
                d = np.array([math.inf])
            worst = max(worst, float(np.max(d)) if np.all(np.isfinite(d)) else math.inf)
        out.append(worst)
    return out


def check_spread(res: Any, k: float, *, dt: float | None = None, field: str = "robust") -> None:
    """Refuse (:class:`~tuner.errors.TunerError` at ``field``) an identification whose ``k``-sigma parameter box is
    too wide for a plant set (the module's docstring): each parameter whose ``k``-sigma change moves the model's
    response at ``w0 / 2`` or ``w0`` by more than :data:`MAX_SPREAD` is named, with its value and 1-sigma bound,
    and what to fly instead.

    Examples
    --------
    >>> import numpy as np
    >>> from tuner import identify
    >>> from tuner.robust import check_spread
    >>> u = np.random.default_rng(0).standard_normal(3000)
    >>> y = np.convolve(u, 0.05 * 0.95 ** np.arange(200))[:3000]  # a first-order lag at 100 Hz, no noise
    >>> res = identify(u, y, rate_hz=100, poles=1, delay=None, n_starts=2)
    >>> check_spread(res, 2.0, dt=0.01)  # a well-determined fit: nothing to refuse
    """
    names, v0, c = _log_covariance(res, field=field)
    sd = np.sqrt(np.maximum(np.diag(c), 0.0))
    w0 = _w0(res, res.plant(), dt)
    w = np.array([0.5 * w0, w0])
    effect = _spread(res, names, v0, sd, float(k), w)
    wide = [i for i, e in enumerate(effect) if not e <= MAX_SPREAD]
    if not wide:
        return
    sigma = {n: float(res.uncertainty[n].cr_bound) for n in names}
    parts = []
    for i in wide:
        n = names[i]
        unit = " s" if n == "delay_s" else " rad/s" if n.endswith("_rad_s") else ""
        rel = "" if n == "delay_s" or v0[i] == 0 else f", {100 * sigma[n] / abs(v0[i]):.3g} %"
        parts.append(f"{n} = {v0[i]:.4g}{unit} +- {sigma[n]:.3g}{unit} (1 sigma{rel})")
    lo, hi = w0 / 3.0, 3.0 * w0
    what = (f"the {k:g}-sigma set of the identified parameters is" if field == "robust" else
            "the identified parameters' bounds are")
    use = "a robust set" if field == "robust" else "the Monte Carlo draws"
    raise TunerError(
        f"{what} too wide for one airframe ({use}): {'; '.join(parts)}: at {k:g} sigma each moves the model's response "
        f"near the crossover ({w0:.3g} rad/s) by more than a decade of gain or 132 deg of phase: the log does not "
        f"determine {'it' if len(wide) == 1 else 'them'}. Fly an excitation of the loop over about {lo:.3g}-{hi:.3g} "
        f"rad/s ({lo / (2 * math.pi):.3g}-{hi / (2 * math.pi):.3g} Hz: a frequency sweep or doublets on the rate "
        "setpoint, logged and identified with it as the reference) for long enough to average several windows, or fit "
        "fewer poles and zeros; or tune the nominal model "
        + ("alone (no robust set)" if field == "robust" else "without the Monte Carlo check"), field=field)


def plant_of(res: Any, values: dict[str, float]):
    """The continuous :class:`~tuner.plant.Plant` of the identified structure at these parameter values."""
    from .identify.model import Model
    from .plant import make_plant

    o = res.model.structure
    full = dict(res.model.values())
    full.update(values)
    m = Model.from_values(o.poles, o.zeros, full)
    num, den = m.tf()
    return make_plant(num, den, delay=max(float(full.get("delay_s", 0.0)), 0.0))


@dataclass(frozen=True)
class MonteCarlo:
    """The verifier's verdict on ``n`` plants drawn from the identified parameters' covariance."""

    n: int
    seed: int
    fraction_meeting: dict[str, float]  # per constraint of the spec
    fraction_meeting_spec: float
    n_unstable: int
    worst: dict[str, float]
    percentile_95: dict[str, float]  # what 95 % of the draws do at least as well as: the 5th percentile of the
    # margins, the 95th of overshoot and settling

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: draws, seed, fractions meeting each constraint and the spec, unstable count, worst, 95 %."""
        return {"n": self.n, "seed": self.seed, "fraction_meeting": dict(self.fraction_meeting),
                "fraction_meeting_spec": self.fraction_meeting_spec, "n_unstable": self.n_unstable,
                "worst": dict(self.worst), "percentile_95": dict(self.percentile_95)}

    def summary(self) -> str:
        """One line: the share of draws meeting the spec and the worst margins, overshoot and settling."""
        w = self.worst
        return (f"Monte Carlo ({self.n} draws, seed {self.seed}): {100 * self.fraction_meeting_spec:.1f} % meet the "
                f"spec; worst PM {w['phase_margin_deg']:.3g} deg, GM {w['gain_margin_db']:.3g} dB, overshoot "
                f"{w['overshoot_pct']:.3g} %" + (f", {self.n_unstable} unstable" if self.n_unstable else ""))


@dataclass(frozen=True)
class RobustDesign:
    """How the identified model's uncertainty entered the design, and the Monte Carlo check."""

    k: float | None  # sigmas of the plant set (None: the nominal model only)
    method: str
    parameters: dict[str, float]  # nominal values
    sigma: dict[str, float]  # 1-sigma Cramér–Rao bounds
    corners: tuple[str, ...]  # the dominant parameters (all corners)
    axes: tuple[str, ...]  # the others (+- K sigma one at a time)
    n_plants: int
    monte_carlo: MonteCarlo | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the set's K, method, parameters and sigmas, corners, axes, size, and the Monte Carlo check."""
        return {"k": self.k, "method": self.method, "parameters": dict(self.parameters), "sigma": dict(self.sigma),
                "corners": list(self.corners), "axes": list(self.axes), "n_plants": self.n_plants,
                "monte_carlo": None if self.monte_carlo is None else self.monte_carlo.to_dict()}


_METHOD = ("nominal + every corner of the K-sigma box of the dominant parameters (largest change of the "
           "frequency response near the ultimate frequency) + +-K sigma of each other parameter")


def plant_set(res: Any, k: float | None, *, dt: float | None = None) -> tuple[list[Any], RobustDesign]:
    """The plants to tune on (nominal first) and the record of how they were chosen (module docstring)."""
    nominal = res.plant()
    names = _names(res)
    values = res.model.values()
    params = {n: float(values[n]) for n in names}
    sigma = {n: float(res.uncertainty[n].cr_bound) for n in names}
    if k is None:
        return [nominal], RobustDesign(None, "nominal model only", params, sigma, (), (), 1)
    k = check_robust(k)
    check_spread(res, k, dt=dt, field="robust")  # (before any plant: a box too wide overflowed here)
    names, v0, c = _log_covariance(res)
    sd = np.sqrt(np.maximum(np.diag(c), 0.0))
    w0 = _w0(res, nominal, dt)
    w = np.array([0.5 * w0, w0])
    g0 = res.model.freqresp(w)
    effect = []
    for i in range(len(names)):
        dx = np.zeros(len(names))
        dx[i] = k * sd[i]
        m = plant_of(res, _apply(names, v0, dx))
        g = m.freqresp(w)
        effect.append(float(np.max(np.abs(np.log(g / g0)))) if np.all(np.isfinite(g)) else math.inf)
    order = [i for i in np.argsort(effect)[::-1] if sd[i] > 0]
    dom, rest = sorted(order[:CORNERS]), order[CORNERS:]
    plants = [nominal]
    for signs in itertools.product((-1.0, 1.0), repeat=len(dom)):
        dx = np.zeros(len(names))
        dx[dom] = k * sd[dom] * np.array(signs)
        plants.append(plant_of(res, _apply(names, v0, dx)))
    for i in rest:
        for s in (-1.0, 1.0):
            dx = np.zeros(len(names))
            dx[i] = s * k * sd[i]
            plants.append(plant_of(res, _apply(names, v0, dx)))
    info = RobustDesign(k, _METHOD, params, sigma, tuple(names[i] for i in dom), tuple(names[i] for i in rest),
                        len(plants), extra={"effect": dict(zip(names, effect)), "w0_rad_s": float(w0)})
    return plants, info


def parameter_draws(res: Any, n: int, seed: int = 0) -> list[dict[str, float]]:
    """``n`` parameter sets drawn from the reported covariance (log space for the log-parameters), seeded."""
    names, v0, c = _log_covariance(res)
    rng = np.random.default_rng(seed)
    lam, V = np.linalg.eigh(c)
    X = rng.standard_normal((n, len(names))) * np.sqrt(np.maximum(lam, 0.0)) @ V.T
    return [_apply(names, v0, x) for x in X]


def monte_carlo(res: Any, controller: Any, spec: Any = None, *, n: int = MONTE_CARLO_DRAWS,
                seed: int = 0) -> MonteCarlo:
    """Judge ``controller`` on ``n`` plants drawn from ``res``'s covariance with the verifier (module docstring)."""
    from .analysis.verify import analyze_loop
    from .interop import as_controller
    from .loop import build_loop
    from .spec import Spec

    spec = spec or Spec()
    n = check_draws(n)
    controller = as_controller(controller)
    if n:
        check_spread(res, MC_SIGMA, dt=controller.dt, field="monte_carlo")
    ok: dict[str, list[bool]] = {}
    meets, unstable = [], 0
    keys = ("phase_margin_deg", "gain_margin_db", "overshoot_pct", "settling_time_s")
    vals: dict[str, list[float]] = {k: [] for k in keys}
    for values in parameter_draws(res, n, seed):
        try:
            a = analyze_loop(build_loop(plant_of(res, values), controller), spec, grid_points=MC_GRID_POINTS)
        except TunerError:  # a draw that cannot form a loop with the controller: not meeting the spec
            meets.append(False)
            unstable += 1
            for k in keys:
                vals[k].append(math.nan)
            continue
        for c in a.checks:
            ok.setdefault(c.name, []).append(bool(c.ok))
        meets.append(a.meets_spec)
        unstable += not a.metrics.stable
        for k in keys:
            vals[k].append(float(getattr(a.metrics, k)))
    worst, p95 = {}, {}
    for k, v in vals.items():
        x = np.asarray(v, float)
        x = np.where(np.isnan(x), -math.inf if k in ("phase_margin_deg", "gain_margin_db") else math.inf, x)
        low = k in ("phase_margin_deg", "gain_margin_db")
        worst[k] = float(np.min(x) if low else np.max(x)) if x.size else math.nan
        p95[k] = float(np.percentile(x, 5 if low else 95, method="lower" if low else "higher")) if x.size \
            else math.nan
    return MonteCarlo(n=n, seed=int(seed), fraction_meeting={k: float(np.mean(v)) for k, v in ok.items()},
                      fraction_meeting_spec=float(np.mean(meets)) if meets else math.nan, n_unstable=int(unstable),
                      worst=worst, percentile_95=p95)
