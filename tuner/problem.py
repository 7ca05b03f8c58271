"""The tuning problem, stated once: plants, structure, sample time and spec, validated together.

:func:`tuner.tune` and the service both build a :class:`TuningProblem`; every check of the
combination happens here, once (a discrete structure needs ``dt``, discrete plants agree on
their sample time, a discrete plant's delay is whole samples of its ``dt``, each plant can form a loop
with the structure). Errors carry ``field`` paths relative to the problem: ``("dt",)``,
``("structure",)``, ``("plants", i, "delay")``; the plant's scale (ultimate gain and frequency,
:func:`tuner.design.plant_scale`) is computed here once per tune.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from .controllers import Structure, get_structure
from .design import PlantScale, dc_gain, initial_guess, plant_scale
from .errors import InvalidPlantError, InvalidSpecError, TunerError
from .loop import build_loop
from .plant import Plant, check_dt
from .rules import has_filter_rule
from .spec import FILTER_N_MAX, NOISE_GAIN_MAX, Spec
from .tolerances import SAME_DT_RTOL

__all__ = ["TuningProblem", "MAX_PLANTS", "gain_variation", "member_spec"]

MAX_PLANTS = 50
#: the plant's ultimate gain K0 a tune accepts: a controller's gains scale as K0, and the loop's products of gains
#: (K0 times the plant's gain, squared in the sensitivities) must stay far inside double precision
GAIN_SCALE_RANGE = (1e-100, 1e100)


@dataclass(frozen=True, eq=False)
class TuningProblem:
    """What to tune: a validated plant set (nominal first), a structure, the loop's ``dt``, a spec.

    Build it with :meth:`build`; ``scale`` is the nominal plant's ``(K0, w0)`` at ``dt``. :func:`tuner.tune`
    accepts one in place of the plants (it then holds the structure, spec and dt).

    Examples
    --------
    >>> import control
    >>> from tuner import TuningProblem, plant_from_control
    >>> prob = TuningProblem.build([plant_from_control(control.tf([1], [1, 1]))], structure="pi", dt=0.05)
    >>> prob.structure.name, prob.dt, len(prob.plants)
    ('pi', 0.05, 1)
    >>> prob.nominal is prob.plants[0]
    True
    """

    plants: tuple[Plant, ...]
    structure: Structure
    dt: float | None
    spec: Spec  # the spec in force: the asked one with the default limits resolved (the noise budget as mks_max)
    scale: PlantScale
    asked: Spec | None = None  # the spec as given (None: the same as ``spec``)
    limits: tuple[dict, ...] = ()  # the default limits in force: {"field", "value", "rule"} (see resolve_limits)
    #: the plant-gain factors of the members added to the set (``spec.gain_variation``): the last
    #: ``len(variation)`` plants are the nominal's gain times each
    variation: tuple[float, ...] = ()

    @property
    def given_plants(self) -> tuple[Plant, ...]:
        """The plants as given (the set without the gain-variation members, :attr:`variation`)."""
        return self.plants[:len(self.plants) - len(self.variation)]

    def plant_spec(self, i: int) -> Spec:
        """The spec plant ``i`` is judged by: :attr:`spec`, except on a gain-variation member (its gain ``k`` times
        the nominal's): its phase margin at least ``spec.gain_variation_pm_min_deg`` (at most the spec's own), its
        gain margin the spec's less ``|20 log10 k|`` (what the gain change itself takes, which the nominal's margin
        implies)."""
        n = len(self.plants) - len(self.variation)
        if i < n:
            return self.spec
        return member_spec(self.spec, self.variation[i - n])

    @property
    def specs(self) -> tuple[Spec, ...]:
        """:meth:`plant_spec` of every plant of the set."""
        return tuple(self.plant_spec(i) for i in range(len(self.plants)))

    @property
    def labels(self) -> tuple[str, ...]:
        """A name for each plant of the set: ``nominal``, ``plant #2``, ..., ``nominal x0.8`` (a gain-variation
        member)."""
        given = ["nominal" if i == 0 else f"plant #{i + 1}" for i in range(len(self.given_plants))]
        return (*given, *(f"nominal x{k:g}" for k in self.variation))

    @property
    def asked_spec(self) -> Spec:
        """The spec as the user gave it (``spec`` is it with the default limits resolved)."""
        return self.asked if self.asked is not None else self.spec

    @property
    def nominal(self) -> Plant:
        """The nominal plant (the first of the set)."""
        return self.plants[0]

    @classmethod
    def build(cls, plant_or_plants: Plant | Sequence[Plant], *, structure: str | Structure,
              spec: Spec | None = None, dt: float | None = None) -> TuningProblem:
        """Validate the inputs together; raises :class:`~tuner.errors.TunerError` with ``field`` set."""
        st = structure if isinstance(structure, Structure) else get_structure(structure)
        plants = _as_plants(plant_or_plants)
        dt = _loop_dt(plants, check_dt(dt))
        if st.discrete_only and dt is None:
            raise TunerError(f"structure {st.name!r} is discrete: give the controller sample time dt", field="dt")
        if spec is None:
            spec = Spec()
        elif not isinstance(spec, Spec):
            raise InvalidSpecError(f"spec must be a tuner.Spec, got {type(spec).__name__}", field="spec")
        if spec.mt_max is not None and spec.mt_max < 1 and spec.zero_steady_state_error:
            raise InvalidSpecError(f"mt_max = {spec.mt_max:g} < 1 is impossible with zero steady-state error "
                                   "(T(0) = 1, so Mt >= 1): give mt_max >= 1 or set zero_steady_state_error = false",
                                   field=("spec", "mt_max"))
        if spec.ki_min is not None and not st.integrating:
            raise InvalidSpecError(f"ki_min = {spec.ki_min:g} demands integral action, and {st.name} has none: give a "
                                   "structure with an integrator (pi, pid, pid2, pid_z, pid_mf2, px4_rate, "
                                   "ardupilot_rate) or leave ki_min out", field=("spec", "ki_min"))
        try:
            scale = plant_scale(plants[0], dt)
        except TunerError as e:
            raise _at_plant(e, 0) from None
        if not all(math.isfinite(v) and v > 0 for v in scale):
            raise InvalidPlantError("the plant's gain or frequency scale is not finite: rescale the model "
                                    "(coefficients spanning hundreds of decades)", field=("plants", 0))
        if not GAIN_SCALE_RANGE[0] <= scale[0] <= GAIN_SCALE_RANGE[1]:  # the controller's gains would be its inverse
            raise InvalidPlantError(f"the plant's gain scale (its ultimate gain K0 = {scale[0]:.3g}) is beyond what "
                                    "the loop's products of gains hold in double precision: rescale the plant (other "
                                    "units for its input or output)", field=("plants", 0))
        asked = spec
        spec, limits = resolve_limits(spec, st, plants, dt, scale)
        variation = gain_variation(spec, st)  # the nominal's gain varied: members of the set (judged by plant_spec)
        plants = [*plants, *(plants[0].scaled(k) for k in variation)]
        guess = st.tf(list(initial_guess(st, plants[0], dt, scale=scale, spec=spec).values()), dt)
        for i, p in enumerate(plants):  # a plant that cannot form a loop fails here, with its own message
            try:
                build_loop(p, guess)
            except TunerError as e:
                raise _at_plant(e, i) from None
        return cls(plants=tuple(plants), structure=st, dt=dt, spec=spec, scale=scale, asked=asked, limits=limits,
                   variation=variation)


def gain_variation(spec: Spec, structure: Structure) -> tuple[float, ...]:
    """The plant-gain factors of ``spec``'s gain-variation members for ``structure`` (``"auto"``: the firmware laws'
    default, none for the others; 1 left out): what :meth:`TuningProblem.build` adds to the plant set, and what a
    study's verification checks too.

    Examples
    --------
    >>> from tuner import Spec, get_structure
    >>> from tuner.problem import gain_variation
    >>> gain_variation(Spec(), get_structure("px4_rate")), gain_variation(Spec(), get_structure("pid"))
    ((0.8, 1.25), ())
    """
    from .spec import AUTO, FIRMWARE_GAIN_VARIATION

    gv = spec.gain_variation
    if gv == AUTO:
        gv = FIRMWARE_GAIN_VARIATION if structure.firmware else None
    return () if gv is None else tuple(float(k) for k in gv if k != 1.0)


def member_spec(spec: Spec, k: float) -> Spec:
    """The spec a gain-variation member (the nominal plant's gain times ``k``) is judged by: ``spec`` with its phase
    margin at least ``gain_variation_pm_min_deg`` (at most the spec's own) and its gain margin less ``|20 log10 k|``
    (what the gain change itself takes, which the nominal's margin implies)."""
    return spec.model_copy(update={
        "phase_margin_min_deg": min(spec.phase_margin_min_deg, spec.gain_variation_pm_min_deg),
        "gain_margin_min_db": max(0.0, spec.gain_margin_min_db - abs(20.0 * math.log10(k)))})


def noise_scale(plants: Sequence[Plant], scale: PlantScale) -> float:
    """The gain the noise budget is relative to: the larger of the nominal plant's ultimate gain ``K0`` and
    the largest inverse DC gain ``1/|G(0)|`` of the set (a resonant plant's K0 can fall below 1/|G(0)|, the
    noise gain every controller with integral action has, Mks >= |C S|(0) = 1/|G(0)|)."""
    inv = [1.0 / g for g in (dc_gain(p) for p in plants) if 0 < g < math.inf]
    return max([scale[0], *inv])


def resolve_limits(spec: Spec, st: Structure, plants: Sequence[Plant], dt: float | None, scale: PlantScale
                   ) -> tuple[Spec, tuple[dict, ...]]:
    """The spec in force and the default limits that apply: the noise budget becomes ``mks_max`` (the tighter of
    the two), the filter rules are described (they act on the structure's parameters: :mod:`tuner.optimize`)."""
    limits: list[dict] = []
    from .spec import AUTO, FIRMWARE_GAIN_VARIATION, resolved_objective

    updates: dict = {}
    if spec.objective == AUTO:
        updates["objective"] = resolved_objective(AUTO, st)
    if spec.gain_variation == AUTO:
        updates["gain_variation"] = FIRMWARE_GAIN_VARIATION if st.firmware else None
    if updates:
        spec = spec.model_copy(update=updates)
    if spec.gain_variation is not None:
        lo, hi = spec.gain_variation
        limits.append({"field": "gain_variation", "value": [lo, hi], "default": spec.gain_variation ==
                       FIRMWARE_GAIN_VARIATION, "rule": f"gain variation: the nominal plant's gain x{lo:g} and "
                       f"x{hi:g} too (a rate loop's control effectiveness moves with battery voltage and payload): "
                       "every constraint on each (the phase margin "
                       f"{spec.gain_variation_pm_min_deg:g} deg), the objective their worst case"})
    if spec.noise_gain_max is not None:
        k = noise_scale(plants, scale)
        budget = spec.noise_gain_max * k
        if spec.mks_max is None or budget < spec.mks_max:
            limits.append({"field": "mks_max", "value": budget, "default": spec.noise_gain_max == NOISE_GAIN_MAX,
                           "rule": f"noise budget: Mks <= noise_gain_max x K0 = {spec.noise_gain_max:g} x {k:.4g}"})
            spec = spec.model_copy(update={"mks_max": budget})
    if spec.filter_n_max is not None and has_filter_rule(st):
        dflt = spec.filter_n_max == FILTER_N_MAX
        limits.append({"field": "filter_n_max", "value": spec.filter_n_max, "default": dflt,
                       "rule": f"derivative filter: N = Td/Tf <= {spec.filter_n_max:g}"
                       + (" (Astrom-Hagglund)" if dflt else "")})
    if spec.filter_nyquist and dt is not None and "Tf" in st.params:
        limits.append({"field": "filter_nyquist", "value": dt / math.pi, "default": True,
                       "rule": f"filter corner at most the Nyquist frequency: Tf >= dt/pi = {dt / math.pi:.4g} s"})
    return spec, tuple(limits)


def _at_plant(e: TunerError, i: int) -> TunerError:
    """An error about plant ``i`` (or its loop: ``("plant", ...)``) located in the plant set; the loop's
    ``dt`` stays ``("dt",)``."""
    if e.field[:1] == ("plant",):
        e.field = ("plants", i) + e.field[1:]
    elif e.field != ("dt",):
        e.field = ("plants", i) + e.field
    return e


def _as_plants(plant_or_plants: Plant | Sequence[Plant]) -> list[Plant]:
    plants = [plant_or_plants] if isinstance(plant_or_plants, Plant) else list(plant_or_plants)
    if not plants:
        raise InvalidPlantError("no plant given", field="plants")
    if len(plants) > MAX_PLANTS:
        raise InvalidPlantError(f"{len(plants)} plants given; at most {MAX_PLANTS} per robust tune", field="plants")
    for i, p in enumerate(plants):
        if not isinstance(p, Plant):
            raise InvalidPlantError(f"expected Plant objects, got {type(p).__name__}", field=("plants", i))
    return plants


def _loop_dt(plants: list[Plant], dt: float | None) -> float | None:
    """The loop's sample time: ``dt``, else the discrete plants' (which must agree with it)."""
    pdt = None
    for i, p in enumerate(plants):
        if not p.is_discrete:
            continue
        if pdt is not None and abs(p.dt - pdt) > SAME_DT_RTOL * pdt:
            raise InvalidPlantError(f"plants are discrete at different sample times {pdt} and {p.dt}",
                                    field=("plants", i, "dt"))
        if dt is not None and abs(p.dt - dt) > SAME_DT_RTOL * dt:
            raise InvalidPlantError(f"plant is discrete at dt={p.dt} but dt={dt} was given; a discrete plant is "
                                    "not resampled", field="dt")
        pdt = p.dt
    return dt if dt is not None else pdt
