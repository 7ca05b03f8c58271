"""The outcome of an identification: model, cost, band, response, uncertainty, check, verdict."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .model import Model
from .spectral import FrequencyResponse
from .uncertainty import ParameterUncertainty
from .validate import Validation

__all__ = ["CLOSED_LOOP", "J_ACCEPTABLE", "J_GOOD", "J_POINT_MAX", "FitPoints", "IdentifyResult", "quality_of"]

J_GOOD = 50.0  # CIFER guidelines: J <= 50 good, J <= 100 acceptable, single frequencies up to ~200
J_ACCEPTABLE = 100.0
J_POINT_MAX = 200.0


#: the verdict of a fit of data flown under feedback without a reference: never good or acceptable, whatever J
CLOSED_LOOP = "closed-loop"


def quality_of(cost: float) -> str:
    """``"good"`` (J <= 50), ``"acceptable"`` (J <= 100) or ``"poor"``."""
    return "good" if cost <= J_GOOD else ("acceptable" if cost <= J_ACCEPTABLE else "poor")


@dataclass(frozen=True, eq=False)
class FitPoints:
    """The data at the fit frequencies, and each frequency's share of the cost."""

    w: np.ndarray
    mag_db: np.ndarray
    phase_deg: np.ndarray
    coherence: np.ndarray
    cost: np.ndarray  # 20 W_gamma (dmag^2 + W_p dphase^2): J is their mean

    def to_dict(self) -> dict[str, Any]:
        """The fit points as lists (``w``, ``mag_db``, ``phase_deg``, ``coherence``, ``cost``)."""
        return {k: getattr(self, k).tolist() for k in ("w", "mag_db", "phase_deg", "coherence", "cost")}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FitPoints:
        """The inverse of :meth:`to_dict`."""
        return cls(**{k: np.asarray(d[k], dtype=float) for k in ("w", "mag_db", "phase_deg", "coherence", "cost")})


@dataclass(frozen=True, eq=False)
class IdentifyResult:
    """What :func:`tuner.identify` found. ``model`` is continuous (in ``s``), with its delay.

    ``cost`` is CIFER's J over ``band_rad_s``; ``quality`` is J's verdict, ``good``/``acceptable``/
    ``poor`` by the guidelines; ``check`` is the time-domain check's, beside it (``good``, ``fair``,
    ``noise-limited``, ``poor`` or ``none``): neither overrules the other. ``warnings`` say what to
    change when something is off (a poor J, poorly determined parameters, a failed time-domain
    check, ...).

    Examples
    --------
    A first-order plant ``5/(s + 5)`` driven by white noise at 100 Hz, 30 s:

    >>> import control
    >>> import numpy as np
    >>> from tuner import identify
    >>> u = np.random.default_rng(0).standard_normal(3000)
    >>> y = control.forced_response(control.c2d(control.tf([5], [1, 5]), 0.01), U=u).outputs
    >>> res = identify(u, y, rate_hz=100, poles=1, delay=None, band=[1.1, 30], n_starts=2)
    >>> res.quality, round(float(res.plant().poles[0].real))
    ('good', -5)
    >>> plant = res.plant()  # for tune(); res.to_control() and res.delay_s for python-control
    >>> plant.order, res.delay_s
    (1, 0.0)
    """

    model: Model
    cost: float
    band_rad_s: tuple[float, float]
    frequency_response: FrequencyResponse
    fit_points: FitPoints
    uncertainty: dict[str, ParameterUncertainty]
    validation: Validation | None
    warnings: tuple[str, ...]
    rate_hz: float
    n_samples: int
    fit_duration_s: float
    options: dict[str, Any] = field(default_factory=dict)
    # the parameters' covariance (Cramér–Rao matrix) in the order of ``uncertainty``, in their own units:
    # its diagonal is the square of each cr_bound (tuner.identify.uncertainty.covariance)
    covariance: np.ndarray | None = None
    #: what tells that the data were flown under feedback: ``detected``, ``signs``, ``estimate`` (``direct`` or
    #: ``joint``), ``message``, ``inverse_match`` (the direct estimate against -1/C of a known controller)
    closed_loop: dict[str, Any] = field(default_factory=dict)

    @property
    def unreliable_feedback(self) -> bool:
        """Flown under feedback and fitted from the direct estimate (no reference): what was fitted may be -1/C."""
        return bool(self.closed_loop.get("detected")) and self.closed_loop.get("estimate") != "joint"

    @property
    def quality(self) -> str:
        """J's verdict by CIFER's guideline: ``good`` (J <= 50), ``acceptable`` (<= 100), ``poor``; ``closed-loop``
        for data flown under feedback fitted without a reference (whatever J: the direct estimate may be the
        controller's inverse). The time-domain check is :attr:`check`, reported beside it."""
        if self.unreliable_feedback:
            return CLOSED_LOOP
        return quality_of(self.cost)

    @property
    def check(self) -> str:
        """The time-domain check's verdict (:attr:`Validation.verdict`): ``good`` (Theil <= 0.3, the rms
        error within 1.5 times the noise floor the data show), ``fair`` (Theil <= 0.3, error above),
        ``noise-limited`` (Theil above, error within), ``poor`` (both above), or ``none``."""
        return "none" if self.validation is None else self.validation.verdict

    @property
    def verdict(self) -> str:
        """One line: the quality, CIFER's J over the band, and the held-out check."""
        lo, hi = self.band_rad_s
        s = (f"J = {self.cost:.3g} over {lo:.3g}-{hi:.3g} rad/s ({self.fit_points.w.size} frequencies): "
             f"{self.quality} (CIFER: <= {J_GOOD:.0f} good, <= {J_ACCEPTABLE:.0f} acceptable)")
        if self.unreliable_feedback:
            s += ("; flown under feedback without a reference: the fit may be of the controller's inverse, "
                  "not the plant (give the reference)")
        if self.validation is not None:
            s += f"; time-domain check {self.validation.describe()}"
        else:
            s += "; no time-domain check"
        return s

    def __repr__(self) -> str:
        lo, hi = self.band_rad_s
        pars = ", ".join(f"{k} {u.value:.4g} ± {u.cr_bound_pct:.2g} %" for k, u in self.uncertainty.items())
        lines = [f"IdentifyResult: {self.describe()}",
                 f"  {pars}" if pars else "  (no parameters)",
                 f"  J {self.cost:.3g} over {lo:.3g}-{hi:.3g} rad/s: {self.quality}; time-domain check: {self.check}"
                 + (f" (Theil {self.validation.theil_u:.2f}, rms error {self.validation.noise_ratio:.2f} x noise, "
                    f"on the {_SHORT.get(self.validation.source, self.validation.source)})"
                    if self.validation is not None else ""),
                 f"  {self.n_samples} samples at {self.rate_hz:.4g} Hz"
                 + (f", {len(self.warnings)} warning(s)" if self.warnings else "")]
        return "\n".join(lines)

    def plant(self):
        """The model as a :class:`tuner.plant.Plant` (continuous, with its delay) for tuning."""
        from ..plant import make_plant

        num, den = self.model.tf()
        return make_plant(num, den, delay=self.model.delay_s)

    @property
    def delay_s(self) -> float:
        """The fitted equivalent delay, s (0 without one)."""
        return float(self.model.delay_s or 0.0)

    def to_control(self):
        """The fitted model's rational part as a continuous ``control.TransferFunction``; python-control has no
        input delay, so the delay is :attr:`delay_s`: ``tune(res.to_control(), delay=res.delay_s, ...)``."""
        import control

        num, den = self.model.tf()
        return control.tf(np.asarray(num, dtype=float), np.asarray(den, dtype=float))

    def describe(self) -> str:
        """The model as text (:meth:`tuner.plant.Plant.describe` of :meth:`plant`)."""
        return self.plant().describe()

    def _rational_text(self) -> str:
        """The rational part as a plant expression (6 significant digits), without the delay."""
        from ..plant import make_plant

        num, den = self.model.tf()
        return make_plant(num, den).describe()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready after :func:`tuner.jsonio.jsonable` (non-finite bounds become strings)."""
        return {
            "model": self.model.to_dict(),
            "plant": self._rational_text(),  # for `tuner tune --plant`, with --delay model.delay
            "cost": self.cost,
            "quality": self.quality,
            "check": self.check,
            "verdict": self.verdict,
            "warnings": list(self.warnings),
            "band_rad_s": list(self.band_rad_s),
            "frequency_response": self.frequency_response.to_dict(),
            "fit_points": self.fit_points.to_dict(),
            "uncertainty": {k: v.to_dict() for k, v in self.uncertainty.items()},
            "validation": None if self.validation is None else self.validation.to_dict(),
            "rate_hz": self.rate_hz,
            "n_samples": self.n_samples,
            "fit_duration_s": self.fit_duration_s,
            "options": dict(self.options),
            "covariance": None if self.covariance is None else {
                "parameters": list(self.uncertainty), "matrix": np.asarray(self.covariance, float).tolist()},
            "closed_loop": dict(self.closed_loop),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> IdentifyResult:
        """Rebuild from :meth:`to_dict` (e.g. a stored result, to redraw its plot); a file that does not hold what it
        needs is refused naming the field (:func:`tuner.identify.resultfile.check_identification`)."""
        from .resultfile import check_identification

        check_identification(d)
        m = d["model"]
        model = Model.from_values(int(m["poles"]), int(m["zeros"]), {k: _num(v) for k, v in m["parameters"].items()})
        unc = {k: ParameterUncertainty(**{f: _num(x) for f, x in v.items()}) for k, v in d["uncertainty"].items()}
        val = d.get("validation")
        return cls(model=model, cost=_num(d["cost"]), band_rad_s=(_num(d["band_rad_s"][0]), _num(d["band_rad_s"][1])),
                   frequency_response=FrequencyResponse.from_dict(_nums(d["frequency_response"])),
                   fit_points=FitPoints.from_dict(_nums(d["fit_points"])), uncertainty=unc,
                   validation=None if val is None else Validation.from_dict(_nums(val)),
                   warnings=tuple(d.get("warnings", ())), rate_hz=_num(d["rate_hz"]), n_samples=int(d["n_samples"]),
                   fit_duration_s=_num(d["fit_duration_s"]), options=dict(d.get("options", {})),
                   covariance=_covariance(d.get("covariance"), list(unc)),
                   closed_loop=dict(d.get("closed_loop") or {}))

    def plot(self, *, title: str | None = None, time_domain: bool = True):
        """Bode plot of the data and the fit with a coherence panel (and the held-out check).

        Returns a :class:`matplotlib.figure.Figure` (no pyplot state; save it with ``savefig``).
        """
        from .plot import fit_figure

        return fit_figure(self, title=title, time_domain=time_domain)


_SHORT = {"holdout": "held-out end", "verify": "verification record", "fit": "fitted record"}
_SPECIAL = {"Infinity": math.inf, "-Infinity": -math.inf, "NaN": math.nan}


def _covariance(d: Any, names: list[str]) -> np.ndarray | None:
    """The stored covariance, checked against the parameters' order (``None`` when absent)."""
    if d is None:
        return None
    from ..errors import InvalidDataError

    if not isinstance(d, dict) or list(d.get("parameters", ())) != names:
        raise InvalidDataError(f"covariance: expected {{'parameters': {names}, 'matrix': ...}}", field="covariance")
    try:
        m = np.asarray(_nums(d["matrix"]), dtype=float)
    except (TypeError, ValueError, KeyError):
        raise InvalidDataError("covariance: matrix must be a square list of numbers", field="covariance") from None
    if m.shape != (len(names), len(names)):
        raise InvalidDataError(f"covariance: matrix must be {len(names)} x {len(names)}, got shape {m.shape}",
                               field="covariance")
    return m


def _num(v: Any) -> float:
    return _SPECIAL[v] if isinstance(v, str) else float(v)


def _nums(d: Any) -> Any:
    """Undo :func:`jsonable`'s strings for non-finite numbers, recursively."""
    if isinstance(d, dict):
        return {k: _nums(v) for k, v in d.items()}
    if isinstance(d, list):
        return [_nums(v) for v in d]
    if isinstance(d, str) and d in _SPECIAL:
        return _SPECIAL[d]
    return d
