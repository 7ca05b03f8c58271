"""What the solver processes run. Plain dicts in, plain (JSON-ready) data out.

Tune and analysis jobs receive the library objects the route validated (pickled once);
plot jobs rebuild the stored plants (``{"num", "den", "dt", "delay"}``, the numbers the library
accepted) with :func:`tuner.plant.make_plant`.
"""

from __future__ import annotations

from typing import Any

__all__ = ["tune_job", "tradeoff_job", "analyze_job", "plot_job", "build_plant", "identify_job", "identify_plot_job",
           "ulog_signals_job", "PLOT_MODULES"]

# what a plot process imports before its first job (this list replaces api.worker.PLOT_MODULES, which
# still names the removed api.plots)
PLOT_MODULES = ("tuner.analysis.verify", "tuner.analysis.plots", "tuner.identify.plot", "matplotlib.figure",
                "matplotlib.backends.backend_agg", "matplotlib.backends.backend_svg")


def build_plant(d: dict[str, Any]):
    from tuner.plant import make_plant

    return make_plant(d["num"], d["den"], dt=d.get("dt"), delay=d.get("delay") or 0.0)


def _controller(d: dict[str, Any]):
    import numpy as np

    from tuner.controllers import ControllerTF

    num_r = d.get("num_r")  # a 2-DOF result (pid2, the firmware laws): the loop that was tuned, reference path too
    return ControllerTF(num=np.asarray(d["num"], dtype=float), den=np.asarray(d["den"], dtype=float), dt=d.get("dt"),
                        num_r=None if num_r is None else np.asarray(num_r, dtype=float))


def tune_job(payload: dict[str, Any]) -> dict[str, Any]:
    """``payload``: ``problem`` (a validated :class:`tuner.problem.TuningProblem`), ``seed``, ``time_budget_s``,
    ``effort``; with ``identification`` (an IdentifyResult), ``robust`` and ``monte_carlo`` too (the problem's plants
    are its set); ``vehicle`` (a VehicleParams, the problem's structure bound to it): its current tune analysed."""
    from tuner.tuning import tune

    effort = payload.get("effort", "default")
    vehicle = {k: payload[k] for k in ("vehicle", "actuator") if payload.get(k) is not None}
    if payload.get("identification") is not None:
        p = payload["problem"]
        return tune(payload["identification"], structure=p.structure, spec=p.spec, dt=p.dt, seed=payload["seed"],
                    time_budget_s=payload["time_budget_s"], robust=payload.get("robust"),
                    monte_carlo=payload.get("monte_carlo"), effort=effort, **vehicle).to_json()
    return tune(payload["problem"], seed=payload["seed"], time_budget_s=payload["time_budget_s"],
                effort=effort, **vehicle).to_json()


def tradeoff_job(payload: dict[str, Any]) -> dict[str, Any]:
    """``payload``: ``problem`` (validated), ``y``, ``points``, ``seed``, ``time_budget_s``."""
    from tuner.tradeoff import tradeoff

    return tradeoff(payload["problem"], y=payload["y"], points=payload["points"], seed=payload["seed"],
                    time_budget_s=payload["time_budget_s"]).to_json()


def analyze_job(payload: dict[str, Any]) -> dict[str, Any]:
    """``payload``: ``plant``, ``controller`` (library objects, validated as one loop), ``spec``; ``actuator`` (with
    the law's ``structure`` and ``gains``): the saturated step too."""
    from tuner.analysis import analyze
    from tuner.jsonio import jsonable
    from tuner.text import verdict, verdict_basis

    a = analyze(payload["plant"], payload["controller"], payload["spec"], actuator=payload.get("actuator"),
                structure=payload.get("structure"), gains=payload.get("gains"))
    out = {**a.to_dict(), "verdict": verdict([a]), "basis": verdict_basis([a])}
    if a.measured is not None:  # an identification: what the verdict rests on
        from tuner.tuning import identification_summary

        out["identification"] = identification_summary(payload["plant"])
    return jsonable(out)


def plot_job(payload: dict[str, Any]) -> bytes:
    """``payload``: plants, controller, spec, ``kind`` (``all``/``step``/``bode``/``nyquist``), ``fmt``
    (``png``/``svg``), title. Returns the image (:func:`tuner.analysis.plots.render`)."""
    from tuner.analysis.plots import render
    from tuner.analysis.verify import analyze
    from tuner.spec import Spec

    ctrl = _controller(payload["controller"])
    spec = Spec(**payload["spec"])
    analyses = [analyze(build_plant(p), ctrl, spec) for p in payload["plants"]]
    return render(analyses, payload.get("kind", "all"), payload["fmt"], spec=spec, title=payload.get("title", ""))


def identify_job(payload: dict[str, Any]) -> dict[str, Any]:
    """``payload``: ``input``, ``output`` (arrays), ``time`` or ``rate_hz``, and the options of
    :func:`tuner.identify` (``poles``, ``zeros``, ``delay``, ...). Returns the JSON-ready result."""
    from tuner.identify import identify
    from tuner.jsonio import jsonable

    ulog = payload.get("ulog")
    if ulog is None:
        opts = {k: v for k, v in payload.items() if k not in ("input", "output")}
        return jsonable(identify(payload["input"], payload["output"], **opts).to_dict())
    from tuner.errors import TunerError
    from tuner.identify.dataflash import is_dataflash, read_dataflash
    from tuner.identify.ulog import read_ulog

    cols = {"input": ulog["input"], "output": ulog["output"]}
    if ulog.get("reference"):
        cols["reference"] = ulog["reference"]
    try:
        raw = bytes(ulog["data"])
        if is_dataflash(raw[:3]):  # an ArduPilot DataFlash log, uploaded as a ULog is
            recs = read_dataflash(raw, cols, rate_hz=payload.get("rate_hz"))
        else:
            recs = read_ulog(raw, cols, rate_hz=payload.get("rate_hz"))
    except TunerError as e:
        role = e.field[0] if e.field else "data"
        e.field = ("ulog", "data" if role == "file" else role, *e.field[1:])
        raise
    from tuner.identify.feedback import hints

    opts = {k: v for k, v in payload.items() if k not in ("ulog", "rate_hz", "time")}
    one = len(recs.inputs) == 1
    if recs.references is not None:
        opts["reference"] = recs.references[0] if one else recs.references
    try:
        res = identify(recs.inputs[0] if one else recs.inputs, recs.outputs[0] if one else recs.outputs,
                       rate_hz=recs.rate_hz, **hints(ulog["input"], recs.parameters, recs.rate_hz),
                       reference_biased=recs.flight.get("reference_biased", ""),
                       firmware=recs.flight.get("firmware"), **opts)
    except TunerError as e:
        if e.field[:1] == ("reference",):
            e.field = ("ulog", "reference", *e.field[1:])
        raise
    out = jsonable(res.to_dict())
    out["flight"] = jsonable(recs.flight)  # what the log says was flown
    if recs.parameters:
        out["_parameters"] = dict(recs.parameters)
    out["_samples"] = {"inputs": [r.tolist() for r in recs.inputs], "outputs": [r.tolist() for r in recs.outputs],
                       "rate_hz": recs.rate_hz}
    return out


def identify_plot_job(payload: dict[str, Any]) -> bytes:
    """``payload``: ``result`` (a stored identification), ``fmt``. Returns the image."""
    from tuner.analysis.plots import figure_bytes
    from tuner.identify.result import IdentifyResult

    return figure_bytes(IdentifyResult.from_dict(payload["result"]).plot(), fmt=payload["fmt"])


def ulog_signals_job(payload: dict[str, Any]) -> dict[str, Any]:
    """``payload``: ``data`` (a ULog's bytes). Returns the signals a page may choose from (``TOPIC[:N].FIELD`` with
    their rates) and the rate law's parameters the log stores (as a QGroundControl .params text)."""
    from tuner.identify import dataflash
    from tuner.identify.ulog import signals

    raw = bytes(payload["data"])
    return dataflash.signals(raw) if dataflash.is_dataflash(raw[:3]) else {**signals(raw), "kind": "ulog"}
