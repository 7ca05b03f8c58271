"""Stop 46's check of the default designs against a control-effectiveness error: each loop tuned at default effort
(seed 0) on its nominal model, then analyzed (the verifier) on the model with its gain at 0.8x and 1.25x.

    .venv/bin/python bench/effectiveness_check.py

Prints, per loop: the nominal settling time and overshoot, then for each gain factor the settling time, overshoot,
phase margin and whether the spec is met. Nothing here asserts anything.
"""

from __future__ import annotations

from tuner import analyze, plant_from_expr, tune

LOOPS = {  # name: (plant expression, structure, dt) -- bench/warm_speed.py's
    "roll": ("0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)", "pid_z", 0.04),
    "pitch": ("0.377568*3.5184^2/(s^2+2*0.5006*3.5184*s+3.5184^2)", "pid_z", 0.04),
    "yaw": ("0.2843*18.611/(s+18.611)", "pid_z", 0.04),
    "px4_rate": ("200/((s+2)*(0.03*s+1))", "px4_rate", 0.0025),
}
FACTORS = (0.8, 1.25)


def main() -> None:
    for name, (expr, structure, dt) in LOOPS.items():
        r = tune(plant_from_expr(expr), structure=structure, dt=dt, seed=0)
        out = [name, "nominal", f"{r.metrics.settling_time_s:.4f} s", f"{r.metrics.overshoot_pct:.2f} %"]
        for k in FACTORS:
            a = analyze(plant_from_expr(f"{k}*{expr}"), r.controller, r.spec)
            m = a.metrics
            out += [f"x{k}", f"{m.settling_time_s:.4f} s", f"{m.overshoot_pct:.2f} %", f"PM {m.phase_margin_deg:.1f}",
                    "meets" if a.meets_spec else "FAILS"]
        print(*out, flush=True)


if __name__ == "__main__":
    main()
