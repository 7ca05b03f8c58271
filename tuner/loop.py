"""The feedback loop under analysis: plant + controller, continuous or sampled-data.

Unity negative feedback, controller in the forward path::

    r --> (+) --> C --> [ZOH] --> G (with delay) --+--> y
           ^-------------------------------------- |

* continuous loop: ``C(s)`` and ``G(s)``, any delay (exact ``exp(-s*tau)``);
* sampled-data loop: ``C(z)`` at ``dt`` driving the continuous ``G(s)`` through a
  zero-order hold; the delay must be whole samples. The loop seen at the samples
  is ``C(z) * ZOH[G](z) * z^-d``; the output between samples comes from ``G(s)``;
* discrete plant ``G(z)`` at the same ``dt``: between-sample output uses the
  continuous plant whose ZOH equivalent is ``G(z)``, when one exists.

The characteristic polynomial is formed without cancelling controller zeros
against plant poles, so hidden unstable modes are not lost.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .controllers import ControllerTF
from .errors import InvalidControllerError, InvalidPlantError, TunerError
from .plant import Plant, delay_in_samples, tf_freqresp

__all__ = ["Loop", "build_loop", "MIN_CONTINUOUS_DELAY_S"]

MIN_CONTINUOUS_DELAY_S = 1e-6


@dataclass(frozen=True, eq=False)
class Loop:
    """Open-loop polynomials and what is needed to simulate the closed loop."""

    plant: Plant
    controller: ControllerTF
    dt: float | None
    ln: np.ndarray  # open-loop numerator  nC*nG
    ld: np.ndarray  # open-loop denominator dC*dG (times z^d in discrete time)
    delay_s: float  # continuous delay; 0 in discrete time (folded into ld)
    delay_samples: int
    plant_ct: Plant | None  # continuous plant for between-sample output (no delay), or None
    plant_d: Plant | None  # discrete plant at dt (no delay folded), or None for continuous loops

    @property
    def is_discrete(self) -> bool:
        return self.dt is not None

    @property
    def charpoly(self) -> np.ndarray:
        return np.polyadd(self.ld, self.ln)

    def freqresp(self, w: np.ndarray) -> np.ndarray:
        """Open-loop ``L`` at ``w`` rad/s (delay exact)."""
        return tf_freqresp(self.ln, self.ld, w, dt=self.dt, delay_s=self.delay_s)

    def nyquist_w(self) -> float | None:
        return np.pi / self.dt if self.dt else None


def build_loop(plant: Plant, controller: ControllerTF) -> Loop:
    """Combine a plant and a controller into a :class:`Loop`, with clear errors."""
    nc, dc = np.asarray(controller.num, float), np.asarray(controller.den, float)
    if controller.dt is None:
        if plant.is_discrete:
            raise InvalidControllerError(
                f"plant is discrete (dt={plant.dt}) but the controller is continuous: give a controller in z",
                field="dt",
            )
        if 0 < plant.delay_s < MIN_CONTINUOUS_DELAY_S:
            raise InvalidPlantError(
                f"delay {plant.delay_s:g} s is below {MIN_CONTINUOUS_DELAY_S:g} s, too short to simulate exactly "
                "in a continuous loop (the simulation step divides the delay); give 0 or a longer delay",
                field=("plant", "delay"))
        return Loop(
            plant=plant, controller=controller, dt=None,
            ln=np.polymul(nc, plant.num), ld=np.polymul(dc, plant.den),
            delay_s=plant.delay_s, delay_samples=0, plant_ct=plant, plant_d=None,
        )
    dt = controller.dt
    try:
        pd = plant.zoh(dt)  # validates dt match for discrete plants and whole-sample delay
    except TunerError as e:
        raise (e if e.field == ("dt",) else e.at("plant")) from None
    d = delay_in_samples(pd.delay_s, dt)
    ld = np.polymul(dc, np.concatenate([pd.den, np.zeros(d)]))
    return Loop(
        plant=plant, controller=controller, dt=dt,
        ln=np.polymul(nc, pd.num), ld=ld, delay_s=0.0, delay_samples=d,
        plant_ct=_cached(plant, "ct_nodelay", lambda: _without_delay(
            plant.continuous_equivalent() if plant.is_discrete else plant)),
        plant_d=_cached(pd, "nodelay", lambda: _without_delay(pd)),
    )


def _without_delay(p: Plant | None) -> Plant | None:
    return None if p is None else Plant(num=p.num, den=p.den, dt=p.dt, delay_s=0.0)


def _cached(p: Plant, key: str, make):  # derived plants are built once per plant object
    if key not in p._cache:
        p._cache[key] = make()
    return p._cache[key]
