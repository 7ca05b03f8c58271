"""The tuner's designs for the firmware laws: ``ours(airframe, law, **tune_kw)``.

The plant given to the tuner is what the law sees: the airframe's continuous plant from the law's output to the
rate at the IMU, times the firmware's gyro low-pass (a continuous second-order Butterworth at ``IMU_GYRO_CUTOFF``
/ ``INS_GYRO_FILTER``), with the delay ``tau`` (``delay=``), at the loop's ``dt``; the vehicle's fixed values
(PX4: ``K`` 1, ``IMU_DGYRO_CUTOFF``, ``MC_RR_INT_LIM``; ArduPilot: FLTT, FLTE, FLTD, IMAX) travel as
``vehicle=`` so that the tuner designs the law the vehicle runs. Default spec and effort unless ``tune_kw`` says
otherwise (``objective="iae"`` builds ``Spec(objective="iae")``). Pluggable: ``--designer`` names in
``bench/autotune_h2h.py`` map to keyword sets here, and the whole result of the tune is kept.
"""

from __future__ import annotations

import time
from typing import Any

from .airframes import Airframe
from .laws import AP_DEFAULTS, PX4_DEFAULTS

__all__ = ["ours", "tuner_view", "FIRMWARE_OF_LAW"]

FIRMWARE_OF_LAW = {"px4_rate": "px4", "ardupilot_rate": "ardupilot"}


def _vehicle(af: Airframe, law: str):
    from tuner.firmware import VehicleParams

    if law == "px4_rate":
        d = PX4_DEFAULTS
        return VehicleParams(firmware="px4", axis="roll", loop_hz=af.loop_hz,
                             gains={k: d[k] for k in ("P", "I", "D", "FF")},
                             fixed={"K": d["K"], "dgyro_hz": d["dgyro_hz"], "int_lim": d["int_lim"],
                                    "dgyro_order": 1.0, "raw_hz": af.raw_hz},  # the D path at the raw rate (issue 40)
                             gyro_cutoff_hz=af.px4_gyro_hz, source=f"bench airframe {af.name}")
    d = AP_DEFAULTS
    return VehicleParams(firmware="ardupilot", axis="roll", loop_hz=af.loop_hz,
                         gains={k: d[k] for k in ("P", "I", "D", "FF")},
                         fixed={k: d[k] for k in ("fltt_hz", "flte_hz", "fltd_hz", "imax")},
                         gyro_cutoff_hz=af.ap_gyro_hz, source=f"bench airframe {af.name}")


def _describe(e: Any) -> str:
    """An ``at_bounds`` entry in words (the result's own wording, as its JSON gives it)."""
    try:
        from tuner.bounds import describe

        return str(describe(e))
    except Exception:  # the tuner's wording is a convenience here
        return str(e)


def ours(af: Airframe, law: str, **tune_kw: Any) -> dict:
    """Tune ``law`` (``"px4_rate"`` or ``"ardupilot_rate"``) for ``af`` with ``tuner.tune``; returns
    ``{"gains": the law's parameters incl. the fixed ones, "wall_s", "meets_spec", "claimed": the tuner's own
    figures, "solver": its stop reason}``. ``objective=...`` in ``tune_kw`` sets the spec's objective."""
    from tuner import Spec, tune

    kw = dict(tune_kw)
    if isinstance(kw.get("spec"), dict):  # (--tune-kw '{"spec": {...}}': the Spec's fields)
        kw["spec"] = Spec(**kw["spec"])
    objective = kw.pop("objective", None)
    if objective is not None and "spec" not in kw:
        kw["spec"] = Spec(objective=objective)
    fw = FIRMWARE_OF_LAW[law]
    t0 = time.perf_counter()
    res = tune(af.plant_tf(fw), structure=law, dt=af.dt, delay=af.delay_s, vehicle=_vehicle(af, law), **kw)
    wall = time.perf_counter() - t0
    m = res.metrics
    spec = getattr(res, "spec", None)
    solver = res.solver if isinstance(res.solver, dict) else {}
    return {"gains": {k: float(v) for k, v in res.gains.items()}, "wall_s": wall, "meets_spec": bool(res.meets_spec),
            "objective": getattr(spec, "objective", None), "failing": [str(c) for c in res.failing],
            "at_bounds": [_describe(e) for e in res.at_bounds],
            "limits": [str(e.get("rule", e)) if isinstance(e, dict) else str(e) for e in (res.limits or ())],
            "claimed": {"pm_deg": float(m.phase_margin_deg), "gm_db": float(m.gain_margin_db),
                        "overshoot_pct": float(m.overshoot_pct), "settling_s": float(m.settling_time_s),
                        "load_recovery_s_2pct": float(getattr(m, "load_recovery_s", float("nan")))},
            "solver": {k: solver.get(k) for k in ("stop", "converged", "wall_time_s", "build_s")}}


def tuner_view(af: Airframe, law: str, gains: dict) -> dict:
    """The tuner's verifier on ``gains`` (its model of the law: the D path at the raw rate where the gains carry it,
    ``raw_hz``; the gyro low-pass continuous): PM, GM, overshoot, settling, as it would claim them for this design."""
    from tuner import analyze, get_structure

    fw = FIRMWARE_OF_LAW[law]
    keys = ("P", "I", "D", "FF", "K", "dgyro_hz", "int_lim", "dgyro_order", "raw_hz") if fw == "px4" else (
        "P", "I", "D", "FF", "fltt_hz", "flte_hz", "fltd_hz", "imax")
    c = get_structure(law).tf({k: gains[k] for k in keys if k in gains}, af.dt)
    a = analyze(af.plant_tf(fw), c, dt=af.dt, delay=af.delay_s)
    m = a.metrics
    return {"stable": bool(all(abs(p) < 1 for p in a.poles)) if getattr(a, "poles", None) is not None else None,
            "pm_deg": float(m.phase_margin_deg), "gm_db": float(m.gain_margin_db),
            "overshoot_pct": float(m.overshoot_pct), "settling_s": float(m.settling_time_s)}
