"""What the solver processes run. Plain dicts in, plain (JSON-ready) data out.

Tune and analysis jobs receive the library objects the route validated (pickled once);
plot jobs rebuild the stored plants (``{"num", "den", "dt", "delay"}``, the numbers the library
accepted) with :func:`tuner.plant.make_plant`.
"""

from __future__ import annotations

from typing import Any

__all__ = ["tune_job", "analyze_job", "plot_job", "build_plant", "identify_job", "identify_plot_job", "PLOT_MODULES"]

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

    return ControllerTF(num=np.asarray(d["num"], dtype=float), den=np.asarray(d["den"], dtype=float), dt=d.get("dt"))


def tune_job(payload: dict[str, Any]) -> dict[str, Any]:
    """``payload``: ``problem`` (a validated :class:`tuner.problem.TuningProblem`), ``seed``, ``time_budget_s``,
    ``effort``."""
    from tuner.tuning import tune

    return tune(payload["problem"], seed=payload["seed"], time_budget_s=payload["time_budget_s"],
                effort=payload.get("effort", "default")).to_json()


def analyze_job(payload: dict[str, Any]) -> dict[str, Any]:
    """``payload``: ``plant``, ``controller`` (library objects, validated as one loop), ``spec``."""
    from tuner.analysis import analyze
    from tuner.jsonio import jsonable

    return jsonable(analyze(payload["plant"], payload["controller"], payload["spec"]).to_dict())


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

    opts = {k: v for k, v in payload.items() if k not in ("input", "output")}
    return jsonable(identify(payload["input"], payload["output"], **opts).to_dict())


def identify_plot_job(payload: dict[str, Any]) -> bytes:
    """``payload``: ``result`` (a stored identification), ``fmt``. Returns the image."""
    from tuner.analysis.plots import figure_bytes
    from tuner.identify.result import IdentifyResult

    return figure_bytes(IdentifyResult.from_dict(payload["result"]).plot(), fmt=payload["fmt"])
