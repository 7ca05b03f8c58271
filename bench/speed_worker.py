"""A warm tuning process for ``bench/tune_speed.py``: one JSON request per line on stdin, one JSON answer
per line on stdout. Imports ``tuner`` from whatever tree is first on ``PYTHONPATH`` (the working tree, or
an older commit extracted with ``git archive``), so it imports nothing of the benchmark and works with the
older layouts (``tuner.tuning`` or ``tuner.tune``; ``tuner.studies.*`` or ``tuner.study``/``tuner.study_eval``).

Requests:
  {"cmd": "loops", "studies": [[toml, gains json or null], ...], "attitude_pid": [names]}
      -> {"tuner_file": ..., "loops": [{"id", "study", "name", "structure", "dt", "order", "plants",
          "spec", "response", "tune_kw"}]}
  {"cmd": "tune", "id": i, "seed": s, "time_budget_s": b}
      -> {"wall_s", "cpu_s", "settling_s", "meets_spec", "failing"}  (the verifier's numbers)
  {"cmd": "hello"} -> {"tuner_file", "efforts"}
  {"cmd": "tune_expr", "plant": expr, "structure", "dt", "seed", "time_budget_s", "effort"} -> as "tune"
  {"cmd": "tune_tf", "num", "den", "delay_s", "structure", "dt", "seed", "time_budget_s"} -> as "tune", on the
      thesis spec (bench/convergence_ab.py: the convergence suite's cases; time_budget_s null: the default budget)
  {"cmd": "quit"}

Each tune gets freshly built plants (built outside the timed call), so what stays warm is the process:
imports, compiled NLPs and whatever the library keeps per process, not the plant objects' own caches.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
import traceback

os.environ.setdefault("TUNER_NLP_COMPILE", "load")  # (no background compile beside timed runs: README, compiled code)


def _api():
    try:
        from tuner.tuning import tune
    except ImportError:
        from tuner.tune import tune
    try:
        from tuner.studies.evaluate import check_gains_file, loop_plants
        from tuner.studies.schema import load_study
    except ImportError:
        from tuner.study import load_study
        from tuner.study_eval import check_gains_file, loop_plants
    return tune, load_study, check_gains_file, loop_plants


def _response(p) -> list[list[float]]:
    """The plant's frequency response at 0.3, 3 and 30 rad/s (delay included), as [re, im] pairs: two trees
    may print one plant differently (a common factor cancelled or not)."""
    import numpy as np

    w = np.array([0.3, 3.0, 30.0])
    x = np.exp(1j * w * p.dt) if p.dt is not None else 1j * w
    h = np.polyval(p.num, x) / np.polyval(p.den, x) * np.exp(-1j * w * p.delay_s)
    return [[float(v.real), float(v.imag)] for v in h]


class Worker:
    def __init__(self) -> None:
        self.tune, self.load_study, self.check_gains_file, self.loop_plants = _api()
        self.loops: list[tuple] = []  # (study, loop def, controllers)

    def cmd_loops(self, studies: list[list], attitude_pid: list[str]) -> dict:
        import tuner

        out = []
        for toml, gains in studies:
            study = self.load_study(toml)
            ctrls = {}
            if gains:
                with open(gains, encoding="utf-8") as f:
                    ctrls = self.check_gains_file(study, json.load(f))
            defs = [(lp, lp.name) for lp in study.order()]
            defs += [(lp.model_copy(update={"structure": "pid"}), f"{lp.name} (pid)")
                     for lp in study.order() if lp.name in attitude_pid and lp.structure != "pid"]
            for lp, name in defs:
                plants = self.loop_plants(study, lp, ctrls)
                self.loops.append((study, lp, ctrls))
                out.append({"id": len(self.loops) - 1, "study": study.name, "name": name, "structure": lp.structure,
                            "dt": lp.dt, "order": max(p.order for p in plants),
                            "plants": [p.describe() for p in plants], "response": [_response(p) for p in plants],
                            "spec": json.loads(json.dumps(lp.spec.model_dump(), default=str)),
                            "tune_kw": self._kw(lp)})
        return {"tuner_file": tuner.__file__, "loops": out}

    @staticmethod
    def _kw(lp) -> dict:
        return {k: getattr(lp, k) for k in ("n_trials", "n_starts") if getattr(lp, k, None) is not None}

    def cmd_tune(self, id: int, seed: int, time_budget_s: float) -> dict:
        study, lp, ctrls = self.loops[id]
        plants = self.loop_plants(study, lp, ctrls)
        return self._timed(plants, structure=lp.structure, spec=lp.spec, dt=lp.dt, seed=seed,
                           time_budget_s=time_budget_s, **self._kw(lp))

    def cmd_hello(self) -> dict:
        """Where ``tuner`` was imported from, and whether its ``tune`` takes an ``effort``."""
        import inspect

        import tuner

        return {"tuner_file": tuner.__file__, "efforts": "effort" in inspect.signature(self.tune).parameters}

    def cmd_tune_expr(self, plant: str, structure: str, dt: float | None, seed: int, time_budget_s: float | None,
                      effort: str | None = None, delay: float | None = None) -> dict:
        """A tune of a plant expression (built fresh, outside the timed call), at ``effort`` where the tree has
        efforts (``delay``: the plant's input delay, s, where given)."""
        from tuner import plant_from_expr

        kw = {"effort": effort} if effort and self.cmd_hello()["efforts"] else {}
        built = plant_from_expr(plant) if delay is None else plant_from_expr(plant, delay=delay)
        return self._timed(built, structure=structure, dt=dt, seed=seed,
                           time_budget_s=time_budget_s, **kw)

    def cmd_tune_tf(self, num: list[float], den: list[float], delay_s: float, structure: str, dt: float | None,
                    seed: int, time_budget_s: float | None) -> dict:
        """A tune of ``num / den`` (delay ``delay_s``) on the thesis spec, diagnosis off, as the quality and
        convergence suites tune their cases."""
        import numpy as np

        from tuner import Spec
        from tuner.plant import Plant

        plant = Plant(np.array(num, float), np.array(den, float), delay_s=float(delay_s))
        return self._timed(plant, structure=structure, dt=dt, spec=Spec.thesis(), seed=seed,
                           time_budget_s=time_budget_s, diagnose=False)

    def _timed(self, plants, **kw) -> dict:
        c0, t0 = time.process_time(), time.perf_counter()
        r = self.tune(plants, **kw)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        ts = max(a.metrics.settling_time_s for a in r.analyses)
        failing = sorted({c.name for a in r.analyses for c in a.failing})
        opt = r.solver.get("optimality") or {}
        return {"wall_s": wall, "cpu_s": cpu, "settling_s": ts if math.isfinite(ts) else str(ts),
                "meets_spec": bool(r.meets_spec), "failing": failing, "stop": r.solver.get("stop"),
                "claim": opt.get("claim"), "objective": float(r.objective) if r.meets_spec else None,
                # load-independent figures: the NLP solves the search ran, and the gains themselves (to compare trees)
                "nlp_solves": opt.get("nlp_solves"), "gains": {k: float(v) for k, v in dict(r.gains).items()}}


def main() -> int:
    out = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # anything the library or its dependencies print goes to stderr, not into the protocol
    sys.stdout = sys.stderr
    w = Worker()
    for line in sys.stdin:
        req = json.loads(line)
        cmd = req.pop("cmd")
        if cmd == "quit":
            break
        try:
            ans = getattr(w, f"cmd_{cmd}")(**req)
        except Exception as e:  # report to the parent, keep serving
            ans = {"error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc()}
        out.write(json.dumps(ans) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
