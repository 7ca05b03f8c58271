"""Study files: many loops tuned at once (every axis of a vehicle, every operating point).

A study is a TOML file::

    name = "quadrotor"          # also the prefix of the study's records in the storage
    seed = 0                    # optional, default 0
    time_budget_s = 10          # optional, per loop
    effort = "default"          # optional: fast / default / thorough (tune()'s effort; a loop may set its own)

    [[loop]]
    name = "pitch"
    plant = "0.377568*3.5184^2/(s^2+2*0.5006*3.5184*s+3.5184^2)"   # or {num = [...], den = [...]}
    # plants = ["...", "..."]   # instead of plant: a plant set, tuned robustly (nominal first)
    # plant_dt = 0.04           # sample time of a plant given in z
    # delay = 0.0               # plant input delay, s (any; whole samples of plant_dt for a plant in z)
    dt = 0.04                   # controller sample time (omit for a continuous controller)
    structure = "pid_z"
    thesis_controller = "37.79*(z^2-1.85*z+0.8686)/(z*(z-1))"    # optional, compared as printed
    thesis_settling_s = 0.5     # optional, what the thesis claimed
    [loop.spec]                 # Spec fields; defaults = Spec() (the thesis spec + the default design limits)
    phase_margin_min_deg = 60

    [[loop]]
    name = "x"
    inner = "pitch"             # a cascade: tuned around pitch's tuned closed loop
    plant = "9.81/s^2"          # from the inner loop's output to this loop's output
    ...

    [[loop]]
    name = "roll"               # a plant given as flight data: identified, then tuned
    data = {file = "data/roll_sweep.csv", time = "t", input = "roll_cmd", output = "roll",
            poles = 2, zeros = 0, delay = "auto"}
    dt = 0.04                   # the delay as fitted (exact in the loop); data.delay_step restricts it
    # robust = 2                # design for the identified parameters' 2-sigma set, Monte Carlo check
    # true_plant = {expr = "...", delay = 0.04}   # a synthetic log's truth: the report judges the loop on it
    structure = "pid_z"

``data.file`` is relative to the study file (when loaded with :func:`load_study`); a data
loop's key includes a hash of the file's contents, so a new log means a new tune.

Loops are tuned in dependency order (inner before outer). Every error names the loop
and the field (:class:`InvalidStudyError`, a :class:`~tuner.errors.TunerError`).
"""

from __future__ import annotations

import hashlib
import json
import math
import tomllib
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, field_validator, model_validator

from ..controllers import ControllerTF, controller_from_expr, controller_tf, get_structure
from ..errors import TunerError
from ..limits import EFFORT_NAMES
from ..plant import MAX_DT_S, MIN_DT_S, Plant, make_plant, plant_from_expr
from ..spec import Spec
from ..tolerances import SAME_DT_RTOL

__all__ = ["InvalidStudyError", "PlantCoeffs", "PlantData", "LoopDef", "StudyDef", "load_study", "parse_study",
           "base_plants", "loop_key", "controller_of", "thesis_controller_of", "identified", "data_path",
           "true_plant_of", "params_path", "vehicle_of"]

_NAME = r"^[A-Za-z0-9_.-]+$"


class InvalidStudyError(TunerError, ValueError):
    """A study file is malformed; the message names the loop and the field."""


class PlantCoeffs(BaseModel):
    """A plant given by coefficients in a study file (``num``, ``den``, highest power first)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    num: list[float] = Field(min_length=1)
    den: list[float] = Field(min_length=1)


PlantText = str | PlantCoeffs


class TruePlant(BaseModel):
    """The plant a synthetic log was made from: an expression in s and its delay."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    expr: str = Field(min_length=1, max_length=2000, description="transfer function in s")
    delay: float = Field(0.0, ge=0, allow_inf_nan=False, description="input delay, s")


class ActuatorDef(BaseModel):
    """The actuator's limits and a reference step's amplitude (the saturated step, as the law runs it)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    u_max: float | None = Field(None, allow_inf_nan=False, description="upper output limit (alone: symmetric)")
    u_min: float | None = Field(None, allow_inf_nan=False, description="lower output limit")
    step_size: float = Field(1.0, allow_inf_nan=False, description="amplitude of the reference step")

    def to_actuator(self) -> Any:
        """The library's :class:`~tuner.analysis.saturation.Actuator` (validated there)."""
        from ..analysis.saturation import Actuator

        try:
            return Actuator.of(u_min=self.u_min, u_max=self.u_max, step_size=self.step_size)
        except TunerError as e:
            raise InvalidStudyError(f"actuator: {e}") from None


class PlantData(BaseModel):
    """A plant given as a flight log: the options of :func:`tuner.identify` and where the columns are."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    file: str = Field(min_length=1, description="CSV or PX4 ULog (.ulg) log, relative to the study file")
    input: str = Field(min_length=1, description="column of the plant input (ULog: TOPIC[:N].FIELD)")
    output: str = Field(min_length=1, description="column of the plant output (ULog: TOPIC[:N].FIELD)")
    reference: str | None = Field(None, min_length=1, description="data flown under feedback: column of the "
                                  "exogenous signal (an injected excitation or the setpoint; ULog: TOPIC.FIELD)")
    hold: Literal["auto", "zoh", "none"] = Field("auto", description="how the plant saw the input: zoh (held, a "
                                                 "controller's output), none (sampled); auto: zoh for a ULog")
    time: str | None = Field(None, min_length=1, description="time column, s (or rate_hz); not for ULog")
    time_unit: Literal["auto", "s", "ms", "us"] = Field("auto", description="the time column's unit; auto: seconds, "
                                                        "refused where its steps look like another unit")
    rate_hz: float | None = Field(None, gt=0, description="sample rate, Hz (or time); ULog: the resampling grid "
                                  "(default: the slower topic's rate)")
    verify: str | None = Field(None, min_length=1, description="a separate verification log (same columns or "
                               "signals), relative to the study file: the time-domain check runs on it")
    poles: int = Field(ge=1, le=8)
    zeros: int = Field(0, ge=0, le=8)
    delay: Literal["auto", "none"] | float = Field("auto", description='"auto" (fitted), "none", or seconds')
    delay_step: float | None = Field(None, gt=0, le=MAX_DT_S, allow_inf_nan=False,
                                     description="restrict the fitted delay to whole multiples of this, s (default: "
                                                 "the delay as fitted; it is exact in the sampled-data loop)")
    band: list[float] | None = Field(None, min_length=2, max_length=2, description="fit band [w_min, w_max], rad/s")
    holdout: Literal["auto"] | Annotated[float, Field(ge=0, le=0.5)] = Field(
        "auto", description='time-domain check data: "auto", a fraction held out at the end, or 0 (none)')
    coherence_min: float = Field(0.6, gt=0, lt=1)
    n_points: int = Field(25, ge=8, le=200)
    _path: Path | None = PrivateAttr(None)  # the file resolved against the study's directory
    _verify_path: Path | None = PrivateAttr(None)

    @model_validator(mode="after")
    def _consistent(self) -> PlantData:
        if self.file.lower().endswith(".ulg"):
            if self.time is not None:
                raise ValueError("data: a ULog log has no time column (its topics are resampled at rate_hz)")
        elif (self.time is None) == (self.rate_hz is None):
            raise ValueError("data: give exactly one of time (a column) or rate_hz")
        if self.zeros > self.poles:
            raise ValueError(f"data: zeros={self.zeros} is more than poles={self.poles}")
        if isinstance(self.delay, float) and self.delay < 0:
            raise ValueError("data: delay must be >= 0 s")
        if self.band is not None and not 0 < self.band[0] < self.band[1]:
            raise ValueError(f"data: band must be [w_min, w_max] with 0 < w_min < w_max, got {self.band}")
        return self


class LoopDef(BaseModel):
    """One loop of a study."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(pattern=_NAME, max_length=64)
    plant: PlantText | None = None
    plants: list[PlantText] | None = Field(None, min_length=1, max_length=50)
    data: PlantData | None = Field(None, description="the plant as a flight log, identified before tuning")
    plant_dt: float | None = Field(None, ge=MIN_DT_S, le=MAX_DT_S, allow_inf_nan=False,
                                   description="sample time of a plant given in z, s")
    delay: float = Field(0.0, ge=0, allow_inf_nan=False, description="plant input delay, s")
    dt: float | None = Field(None, ge=MIN_DT_S, le=MAX_DT_S, allow_inf_nan=False,
                             description="controller sample time, s (None = continuous)")
    structure: str
    spec: Spec = Spec()
    inner: str | None = Field(None, description="name of the loop this one wraps (a cascade)")
    thesis_controller: str | None = Field(None, description="a published controller, compared as printed")
    thesis_settling_s: float | None = Field(None, gt=0, description="the settling time the publication claims, s")
    seed: int | None = Field(None, ge=0, lt=2**32)
    time_budget_s: float | None = Field(None, gt=0, le=3600)
    n_trials: int | None = Field(None, ge=1, le=100_000)
    n_starts: int | None = Field(None, ge=1, le=20)
    effort: Literal[EFFORT_NAMES] | None = Field(  # type: ignore[valid-type]
        None, description="tune()'s effort (None: the study's)")
    note: str | None = Field(None, description="shown in the report (e.g. why a spec is relaxed)")
    robust: float | None = Field(None, gt=0, le=10, allow_inf_nan=False,
                                 description="data loops: design for the plant set spanned by the identified "
                                             "parameters' robust-sigma Cramér–Rao bounds (tuner.robust)")
    monte_carlo: int | None = Field(None, ge=0, le=10_000,
                                    description="data loops: draws of the Monte Carlo check from the identified "
                                                "covariance (default 200 with robust, else 0)")
    true_plant: TruePlant | None = Field(None, description="data loops: the plant the log was made from (a "
                                         "synthetic log's truth), on which the report also judges the loop")
    variant_of: str | None = Field(None, description="name of the loop this one varies (another spec on the same "
                                   "plant): the report says what the change costs")
    params: str | None = Field(None, min_length=1, description="px4_rate / ardupilot_rate: the vehicle's parameters "
                               "(a QGroundControl .params or a ULog .ulg for PX4, a .parm for ArduPilot), relative "
                               "to the study file: loop rate, filters, K, integrator limit and the current gains")
    axis: Literal["roll", "pitch", "yaw"] = Field("roll", description="with params: the axis whose rate law")
    actuator: ActuatorDef | None = Field(None, description="the actuator's limits: a step of step_size simulated with "
                                         "the output clamped, as the law runs it (needs dt)")
    _params_path: Path | None = PrivateAttr(None)

    @field_validator("structure")
    @classmethod
    def _known_structure(cls, v: str) -> str:
        get_structure(v)  # raises with the list of structures
        return v

    @model_validator(mode="after")
    def _one_plant_field(self) -> LoopDef:
        if sum(x is not None for x in (self.plant, self.plants, self.data)) != 1:
            raise ValueError("give exactly one of plant (one model), plants (a set, tuned robustly) or data (a "
                             "flight log to identify the plant from)")
        if self.data is not None and (self.delay or self.plant_dt is not None):
            raise ValueError("data: the delay is identified (data.delay) and the plant is continuous; "
                             "leave delay and plant_dt out")
        if self.data is None:
            for name in ("robust", "monte_carlo", "true_plant"):
                if getattr(self, name) is not None:
                    raise ValueError(f"{name}: only for a plant given as data (a flight log to identify)")
        if get_structure(self.structure).discrete_only and self.dt is None:
            raise ValueError(f"structure {self.structure} is discrete: give dt")
        if self.actuator is not None:
            if self.dt is None:
                raise ValueError("actuator: the saturated step runs the law at its sample time: give dt")
            self.actuator.to_actuator()
        if self.params is not None and get_structure(self.structure).firmware is None:
            from ..firmware.bind import law_choices

            raise ValueError(f"params: the vehicle's parameters set a firmware rate law; give structure "
                             f"{law_choices()} (got {self.structure!r})")
        if self.plant_dt is not None and self.delay:  # a plant in s takes any delay, exactly (also sampled)
            n = self.delay / self.plant_dt
            if abs(n - round(n)) > 1e-6 * max(1.0, n):
                raise ValueError(f"delay: {self.delay} s is not a whole number of samples of the plant's "
                                 f"dt={self.plant_dt} s: a plant given in z needs a multiple of its dt")
        return self

    @property
    def plant_list(self) -> list[PlantText]:
        """The loop's plants as given (one, or the robust set; nominal first)."""
        return [self.plant] if self.plant is not None else list(self.plants or [])


class StudyDef(BaseModel):
    """A study: a name and its loops."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(pattern=_NAME, max_length=64)
    description: str | None = None
    seed: int = Field(0, ge=0, lt=2**32)
    time_budget_s: float = Field(10.0, gt=0, le=3600)
    effort: Literal[EFFORT_NAMES] = "default"  # type: ignore[valid-type]
    loop: list[LoopDef] = Field(min_length=1, max_length=1000)  # (the quality suite as a study: 210 loops)

    @model_validator(mode="after")
    def _graph(self) -> StudyDef:
        names = [lp.name for lp in self.loop]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"loop names must be unique; repeated: {dup}")
        by = {lp.name: lp for lp in self.loop}
        for lp in self.loop:
            if lp.variant_of is not None:
                if lp.variant_of not in by or lp.variant_of == lp.name:
                    raise ValueError(f"loop {lp.name!r}: variant_of: no other loop named {lp.variant_of!r}")
                base = by[lp.variant_of]
                same = ("plant", "plants", "data", "plant_dt", "delay", "dt", "structure", "inner")
                differ = [k for k in same if getattr(lp, k) != getattr(base, k)]
                if differ:
                    raise ValueError(f"loop {lp.name!r}: variant_of {base.name!r}: a variant changes the spec only; "
                                     f"it differs in {', '.join(differ)}")
            if lp.inner is None:
                continue
            if lp.inner not in by:
                raise ValueError(f"loop {lp.name!r}: inner: no loop named {lp.inner!r}")
            inner = by[lp.inner]
            if lp.dt is None or inner.dt is None or abs(lp.dt - inner.dt) > SAME_DT_RTOL * lp.dt:
                raise ValueError(f"loop {lp.name!r}: dt: a cascade runs at its inner loop's dt "
                                 f"({inner.dt}), got {lp.dt}")
        self.order()  # raises on a cycle
        return self

    def get(self, name: str) -> LoopDef:
        """The loop called ``name``."""
        for lp in self.loop:
            if lp.name == name:
                return lp
        raise InvalidStudyError(f"study {self.name!r} has no loop named {name!r}")

    def order(self) -> list[LoopDef]:
        """Loops with every inner loop before the loops that wrap it (file order otherwise)."""
        by = {lp.name: lp for lp in self.loop}
        out: list[LoopDef] = []
        state: dict[str, int] = {}

        def visit(lp: LoopDef, path: tuple[str, ...]) -> None:
            if state.get(lp.name) == 2:
                return
            if state.get(lp.name) == 1:
                raise ValueError(f"loop {lp.name!r}: inner: cascade cycle {' -> '.join(path + (lp.name,))}")
            state[lp.name] = 1
            if lp.inner is not None and lp.inner in by:
                visit(by[lp.inner], path + (lp.name,))
            state[lp.name] = 2
            out.append(lp)

        for lp in self.loop:
            visit(lp, ())
        return out

    def chain(self, name: str) -> list[LoopDef]:
        """``name``'s loop and the loops it wraps, innermost first."""
        out = [self.get(name)]
        while out[0].inner is not None:
            out.insert(0, self.get(out[0].inner))
        return out


def _loop_label(raw: Any, loc: tuple[Any, ...]) -> tuple[str, tuple[Any, ...]]:
    """('loop', 2, 'spec', 'x') -> ("loop 'pitch'", ('spec', 'x'))."""
    if len(loc) >= 2 and loc[0] == "loop" and isinstance(loc[1], int):
        name = None
        try:
            name = raw["loop"][loc[1]].get("name")
        except (KeyError, IndexError, TypeError, AttributeError):
            pass
        label = f"loop {name!r}" if isinstance(name, str) else f"loop #{loc[1] + 1}"
        return label, tuple(loc[2:])
    return "", tuple(loc)


def parse_study(raw: dict[str, Any], *, source: str = "study") -> StudyDef:
    """Validate a study given as a dict (a parsed TOML file)."""
    try:
        return StudyDef.model_validate(raw)
    except ValidationError as e:
        err = e.errors()[0]
        label, rest = _loop_label(raw, tuple(err["loc"]))
        # drop pydantic's union-branch names (e.g. 'str', 'PlantCoeffs') from the location
        fields = ".".join(str(x) for x in rest if not (isinstance(x, str) and x[:1].isupper()) and x != "str")
        msg = err["msg"].removeprefix("Value error, ")
        where = ": ".join(x for x in (label, fields) if x)
        raise InvalidStudyError(f"{source}: {where + ': ' if where else ''}{msg}") from None
    except TunerError as e:  # raised inside a validator (unknown structure)
        raise InvalidStudyError(f"{source}: {e}") from None


def load_study(path: str | Path) -> StudyDef:
    """Read and validate a study TOML file (data files are found relative to it)."""
    p = Path(path)
    from ..fileio import MAX_STUDY_BYTES, read_text

    try:
        text = read_text(p, limit=MAX_STUDY_BYTES, hint="save the study file as UTF-8 TOML")
    except TunerError as e:
        raise InvalidStudyError(str(e)) from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise InvalidStudyError(f"{p}: not valid TOML: {e}") from None
    except RecursionError:
        raise InvalidStudyError(f"{p}: TOML nested too deeply to read") from None
    from ..fileio import MAX_NESTING, nesting_depth

    if nesting_depth(raw) > MAX_NESTING:
        raise InvalidStudyError(f"{p}: TOML nested more than {MAX_NESTING} levels deep; a study is a few levels deep")
    study = parse_study(raw, source=str(p))
    for lp in study.loop:
        if lp.data is not None:
            f = Path(lp.data.file)
            lp.data._path = f if f.is_absolute() else p.resolve().parent / f
            if lp.data.verify is not None:
                v = Path(lp.data.verify)
                lp.data._verify_path = v if v.is_absolute() else p.resolve().parent / v
        if lp.params is not None:
            f = Path(lp.params)
            lp._params_path = f if f.is_absolute() else p.resolve().parent / f
    for lp in study.loop:  # build every plant and printed controller once, so errors surface early
        try:
            vehicle_of(lp)
            base_plants(lp)
            thesis_controller_of(lp)
            true_plant_of(lp)
        except TunerError as e:
            raise InvalidStudyError(f"{p}: loop {lp.name!r}: {e}") from None
    return study


def _plant(text: PlantText, lp: LoopDef) -> Plant:
    if isinstance(text, PlantCoeffs):
        return make_plant(text.num, text.den, dt=lp.plant_dt, delay=lp.delay)
    return plant_from_expr(text, dt=lp.plant_dt, delay=lp.delay)


def data_path(d: PlantData) -> Path:
    """Where a data loop's log is (relative to the study file, or to the working directory)."""
    return d._path if d._path is not None else Path(d.file)


def verify_path(d: PlantData) -> Path | None:
    """Where a data loop's verification log is (``None``: none)."""
    if d.verify is None:
        return None
    return d._verify_path if d._verify_path is not None else Path(d.verify)


def _digest(path: Path) -> str:
    import errno
    import stat

    st = path.stat()
    if not stat.S_ISREG(st.st_mode):  # a regular file only: hashing a FIFO or a device would never end
        raise OSError(errno.EINVAL, "not a regular file (a FIFO, a device or a directory): give a file", str(path))
    return _digest_cached(str(path.resolve()), st.st_mtime_ns, st.st_size)


@lru_cache(maxsize=64)
def _digest_cached(path: str, mtime_ns: int, size: int) -> str:
    """The log's SHA-256, streamed in chunks (a log is at most the larger of the CSV and ULog limits), the cache key
    of its identification: a cache hit reads nothing more."""
    from ..fileio import MAX_CSV_BYTES, open_input
    from ..identify.ulog import MAX_ULOG_BYTES

    with open_input(path, limit=max(MAX_CSV_BYTES, MAX_ULOG_BYTES), field="data") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def _read_log(path: str, o: dict[str, Any]) -> dict[str, Any]:
    """A data loop's log as :func:`tuner.identify` arguments (a ULog log split at gaps: several records)."""
    from ..identify.csvlog import read_columns
    from ..identify.feedback import hints
    from ..identify.ulog import open_log, read_ulog

    ref = o.get("reference")
    with open_log(path) as (kind, fh):  # opened once: told CSV or ULog, and read, from one handle
        if kind == "ulog":
            r = read_ulog(fh, {"input": o["input"], "output": o["output"], **({"reference": ref} if ref else {})},
                          rate_hz=o["rate_hz"])
            one = len(r.inputs) == 1
            refs = r.references
            return {"input": r.inputs[0] if one else r.inputs, "output": r.outputs[0] if one else r.outputs,
                    "time": None, "rate_hz": r.rate_hz, "ulog": True,
                    "reference": None if refs is None else (refs[0] if one else refs),
                    **hints(o["input"], r.parameters, r.rate_hz)}
        cols = {"input": o["input"], "output": o["output"], **({"time": o["time"]} if o["time"] else {}),
                **({"reference": ref} if ref else {})}
        data = read_columns(path, cols, handle=fh)
    return {"input": data["input"], "output": data["output"], "time": data.get("time"), "rate_hz": o["rate_hz"],
            "ulog": False, "reference": data.get("reference"), **hints(o["input"], None, None)}


@lru_cache(maxsize=32)
def _identify_cached(path: str, digest: str, options: str, dt: float | None, verify: str | None = None,
                     verify_digest: str | None = None) -> Any:
    from ..identify import identify

    o = json.loads(options)
    data = _read_log(path, o)
    ver = None
    if verify is not None:
        try:
            v = _read_log(verify, o)
        except TunerError as e:
            raise type(e)(f"verify {o['verify']}: {e}", field=("verify", *e.field)) from None
        if isinstance(v["input"], list):
            raise InvalidStudyError(f"data.verify ({o['verify']}): the verification log has gaps; give one "
                                    "continuous record")
        ver = {k: v[k] for k in ("input", "output", "time", "rate_hz") if v[k] is not None}
    delay = None if o["delay"] == "none" else o["delay"]
    hold = {"zoh": "zoh", "none": None}.get(o.get("hold", "auto"), "zoh" if data["ulog"] else None)
    return identify(data["input"], data["output"], time=data["time"], rate_hz=data["rate_hz"], poles=o["poles"],
                    zeros=o["zeros"], delay=delay, delay_step=o.get("delay_step"), band=o["band"],
                    holdout=o["holdout"], verify=ver, coherence_min=o["coherence_min"], n_points=o["n_points"],
                    reference=data["reference"], controller=data["controller"],
                    closed_loop_signs=data["closed_loop_signs"], hold=hold, time_unit=o.get("time_unit", "auto"))


def identified(lp: LoopDef) -> Any:
    """The :class:`~tuner.identify.IdentifyResult` of a data loop (the delay as fitted, or in whole multiples of
    ``data.delay_step``); computed once per file content and options."""
    if lp.data is None:
        raise InvalidStudyError(f"loop {lp.name!r} has no data")
    path = data_path(lp.data)
    vpath = verify_path(lp.data)
    try:
        digest = _digest(path)
        vdigest = None if vpath is None else _digest(vpath)
    except OSError as e:
        raise InvalidStudyError(f"data: {e.filename or path}: cannot read: {e.strerror or e}") from None
    try:
        return _identify_cached(str(path), digest, lp.data.model_dump_json(), lp.dt,
                                None if vpath is None else str(vpath), vdigest)
    except TunerError as e:
        where = "data." + ".".join(str(x) for x in e.field) if e.field else "data"
        raise type(e)(f"{where} ({lp.data.file}): {e}", field=("data", *e.field)) from e


def base_plants(lp: LoopDef) -> list[Plant]:
    """The loop's own plants (for a cascade: from the inner loop's output to this loop's output);
    for a data loop, the identified model (with ``robust``, its K-sigma plant set, :func:`tuner.robust.plant_set`)."""
    if lp.data is not None:
        if lp.robust is not None:
            from ..robust import plant_set

            try:
                return plant_set(identified(lp), lp.robust, dt=lp.dt)[0]
            except TunerError as e:
                raise type(e)(f"robust: {e}", field=("robust",)) from e
        return [identified(lp).plant()]
    out = []
    for i, text in enumerate(lp.plant_list):
        field = "plant" if lp.plant is not None else f"plants[{i}]"
        try:
            p = _plant(text, lp)
        except TunerError as e:
            raise type(e)(f"{field}: {e}") from e
        out.append(p)
    return out


def true_plant_of(lp: LoopDef) -> Plant | None:
    """A data loop's ``true_plant`` (the truth of a synthetic log), or None."""
    if lp.true_plant is None:
        return None
    try:
        p = plant_from_expr(lp.true_plant.expr, delay=lp.true_plant.delay)
    except TunerError as e:
        raise type(e)(f"true_plant: {e}") from e
    if p.is_discrete:
        raise InvalidStudyError("true_plant: give the plant in s (the continuous plant the log was made from)")
    return p


def controller_of(lp: LoopDef, gains: dict[str, float]) -> ControllerTF:
    """The loop's controller for ``gains`` (its structure at its ``dt``; a firmware law with ``params``: bound to that
    vehicle, unless the gains carry the law's fixed values themselves)."""
    v = vehicle_of(lp)
    if v is None:
        return controller_tf(lp.structure, gains, dt=lp.dt)
    from ..firmware.bind import bind_law

    st, dt, _ = bind_law(lp.structure, v, lp.dt)
    return st.tf(gains, dt)


def params_path(lp: LoopDef) -> Path | None:
    """Where a loop's vehicle parameters are (relative to the study file, or to the working directory)."""
    if lp.params is None:
        return None
    return lp._params_path if lp._params_path is not None else Path(lp.params)


def vehicle_of(lp: LoopDef) -> Any:
    """The :class:`~tuner.firmware.params.VehicleParams` of a loop with ``params`` (None without), read once per
    file content."""
    path = params_path(lp)
    if path is None:
        return None
    try:
        digest = _digest(path)
    except OSError as e:
        raise InvalidStudyError(f"params: {e.filename or path}: cannot read: {e.strerror or e}") from None
    from ..firmware.bind import FIRMWARE_OF

    return _vehicle_cached(str(path), digest, lp.axis, FIRMWARE_OF[lp.structure])


@lru_cache(maxsize=32)
def _vehicle_cached(path: str, digest: str, axis: str, firmware: str) -> Any:
    from ..firmware.params import read_params

    try:
        return read_params(path, axis=axis, firmware=firmware)
    except TunerError as e:
        raise InvalidStudyError(f"params: {e}") from None


def thesis_controller_of(lp: LoopDef) -> ControllerTF | None:
    """The loop's published (thesis) controller, or None when the study gives none."""
    if lp.thesis_controller is None:
        return None
    try:
        return controller_from_expr(lp.thesis_controller, dt=lp.dt)
    except TunerError as e:
        raise type(e)(f"thesis_controller: {e}") from e


def _canon(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return repr(v)
    return v


def loop_key(study: StudyDef, name: str) -> str:
    """A short hash of everything the loop's result depends on: its definition, the study's
    seed and budget, (for a cascade) the loops it wraps, and the contents of data files. A changed
    file gives a new key, so results are reused only for the study as it is now."""
    parts = []
    for lp in study.chain(name):
        d = lp.model_dump(mode="json", exclude={**dict.fromkeys(("note", "thesis_controller", "thesis_settling_s",
                                                                 "effort", "params", "axis", "actuator"), True),
                                                "data": {"time_unit": True}})
        entry = {k: _canon(v) for k, v in d.items()}
        effort = lp.effort or study.effort
        if effort != "default":  # (only then: the keys of studies that never name an effort stay as they were)
            entry["effort"] = effort
        if lp.actuator is not None:  # (only then: the keys of loops without one stay as they were)
            entry["actuator"] = lp.actuator.model_dump(mode="json")
        if lp.params is not None:  # the vehicle's parameters by contents (only then: other keys stay as they were)
            try:
                entry["params_sha256"] = _digest(params_path(lp))
            except OSError:
                entry["params_sha256"] = None
            entry["axis"] = lp.axis
        if lp.data is not None:  # the log's contents, not where it lies
            if lp.data.time_unit != "auto":  # (only then: the keys of data loops that never name one stay as they were)
                entry["time_unit"] = lp.data.time_unit
            try:
                entry["data_sha256"] = _digest(data_path(lp.data))
            except OSError:
                entry["data_sha256"] = None
            vp = verify_path(lp.data)
            if vp is not None:
                try:
                    entry["verify_sha256"] = _digest(vp)
                except OSError:
                    entry["verify_sha256"] = None
        parts.append(entry)
    blob = json.dumps({"seed": study.seed, "budget": study.time_budget_s, "loops": parts}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:12]
