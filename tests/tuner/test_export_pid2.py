"""Export of the 2-DOF PID (pid2): ``N_update(s, r, y)`` in C (compiled with gcc), Python and text.

References are written here from the law u = Kp(b r - y) + Ki/s (r - y) + Kd s/(Tf s+1) (c r - y), discretised
term by term (backward Euler, as tuner.controllers; Tustin for a continuous result), with the anti-windup
schemes of Astrom & Hagglund written from their definitions; and, without limits, scipy.signal.lfilter of the
library's own transfer functions C_r (on r) and C (on -y).
"""

from __future__ import annotations

import importlib.util
import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import signal

from tuner.cli import EXIT_OK, main
from tuner.controllers import controller_tf
from tuner.errors import TunerError
from tuner.export import export_controller

GCC = shutil.which("gcc")
needs_gcc = pytest.mark.skipif(GCC is None, reason="gcc not installed")

RNG = np.random.default_rng(18)
N = 300
R = np.concatenate([np.zeros(10), np.ones(90), -0.5 * np.ones(60), RNG.normal(scale=0.7, size=N - 160)])
Y = 0.3 * RNG.normal(size=N) + np.convolve(R, np.ones(5) / 5, mode="same")
H = 0.04
G = {"Kp": 2.0, "Ki": 3.0, "Kd": 0.2, "Tf": 0.02, "b": 0.6, "c": 0.0}
LO, HI = -1.0, 1.2


def result(gains: dict, dt: float | None) -> dict:
    return {"structure": "pid2", "gains": gains, "controller": controller_tf("pid2", gains, dt=dt).to_dict()}


def reference(r, y, g, dt, *, method="structure", lo=None, hi=None, aw="conditional", tt=None):
    """The 2-DOF law sample by sample, written from the formula (zero initial state)."""
    kp, ki, kd, tf, b, c = (g[k] for k in ("Kp", "Ki", "Kd", "Tf", "b", "c"))
    if method == "structure":  # backward Euler: s -> (z - 1)/(z dt)
        def i_inc(e, e1):
            return ki * dt * e
        ad, bd = tf / (tf + dt), kd / (tf + dt)
    else:  # Tustin: s -> 2/dt (z - 1)/(z + 1)
        def i_inc(e, e1):
            return ki * dt / 2 * (e + e1)
        ad, bd = (2 * tf - dt) / (2 * tf + dt), 2 * kd / (2 * tf + dt)
    integ, d, v1, e1, out = 0.0, 0.0, 0.0, 0.0, []
    for rk, yk in zip(r, y):
        e, v = rk - yk, c * rk - yk
        d = ad * d + bd * (v - v1)
        p = kp * (b * rk - yk)
        inc = i_inc(e, e1)
        w = p + integ + inc + d
        u = w if lo is None else max(w, lo)
        u = u if hi is None else min(u, hi)
        if lo is None and hi is None:
            integ += inc
        elif aw == "conditional":
            if (hi is not None and w > hi and inc > 0) or (lo is not None and w < lo and inc < 0):
                w = p + integ + d  # held: this sample's increment is not integrated
                u = min(max(w, lo if lo is not None else -math.inf), hi if hi is not None else math.inf)
            else:
                integ += inc
        else:  # back-calculation: dI = Ki e dt + (dt/Tt)(u - w)
            integ += inc + dt / tt * (u - w)
        v1, e1 = v, e
        out.append(u)
    return np.array(out)


def compile_and_run(tmp_path: Path, source: str, name: str, r: np.ndarray, y: np.ndarray) -> np.ndarray:
    (tmp_path / f"{name}.c").write_text(source)
    (tmp_path / "main.c").write_text(
        f'#include <stdio.h>\n#include "{name}.c"\n'
        f"int main(void) {{\n    {name}_state s;\n    double r, y;\n    {name}_init(&s);\n"
        f'    while (scanf("%lf %lf", &r, &y) == 2) printf("%.17g\\n", {name}_update(&s, r, y));\n'
        "    return 0;\n}\n")
    exe = tmp_path / "run"
    cc = subprocess.run([GCC, "-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-O2", "-o", str(exe),
                         str(tmp_path / "main.c")], capture_output=True, text=True, timeout=60)
    assert cc.returncode == 0, cc.stderr
    inp = "\n".join(f"{float(a)!r} {float(b)!r}" for a, b in zip(r, y)) + "\n"
    out = subprocess.run([str(exe)], input=inp, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return np.array([float(x) for x in out.stdout.split()])


def load_python(tmp_path: Path, source: str, name: str):
    path = tmp_path / f"{name}_mod.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location(f"{name}_mod", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return getattr(mod, name)


def run_python(cls, r, y) -> np.ndarray:
    c = cls()
    return np.array([c.update(a, b) for a, b in zip(r, y)])


def test_reference_is_the_library_transfer_functions():
    """Without limits the law written here is u = C_r(z) r - C(z) y of the tuned controller (lfilter)."""
    c = controller_tf("pid2", G, dt=H)
    u_lib = signal.lfilter(c.num_r, c.den, R) - signal.lfilter(c.num, c.den, Y)
    assert_allclose(reference(R, Y, G, H), u_lib, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("gains", [G, dict(G, b=1.0, c=1.0), dict(G, b=1.7, c=0.4)], ids=["c0", "pid", "ff"])
def test_python_export_matches_the_law(tmp_path, gains):
    cls = load_python(tmp_path, export_controller(result(gains, H), format="python", name="P2"), "P2")
    assert_allclose(run_python(cls, R, Y), reference(R, Y, gains, H), rtol=1e-12, atol=1e-12)


@needs_gcc
@pytest.mark.parametrize("method", ["structure", "tustin"])
def test_c_export_matches_the_law(tmp_path, method):
    """A pid2 tuned at dt (the structure's discretisation), and a continuous one exported by Tustin."""
    if method == "structure":
        src, ref = export_controller(result(G, H), format="c", name="p2"), reference(R, Y, G, H)
    else:
        src = export_controller(result(G, None), format="c", name="p2", dt=H, method="tustin")
        ref = reference(R, Y, G, H, method="tustin")
    assert "p2_update(p2_state *s, double r, double y)" in src
    assert_allclose(compile_and_run(tmp_path, src, "p2", R, Y), ref, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("aw", ["conditional", "back_calculation"])
def test_anti_windup_python_matches_the_reference(tmp_path, aw):
    tt = math.sqrt((G["Kp"] / G["Ki"]) * (G["Kd"] / G["Kp"]))  # Astrom-Hagglund's default, written here
    src = export_controller(result(G, H), format="python", name="A", u_min=LO, u_max=HI, anti_windup=aw)
    u = run_python(load_python(tmp_path, src, "A"), R, Y)
    ref = reference(R, Y, G, H, lo=LO, hi=HI, aw=aw, tt=tt)
    assert np.any(ref == HI) and np.any(ref == LO)  # saturates both ways
    assert_allclose(u, ref, rtol=1e-11, atol=1e-12)


@needs_gcc
@pytest.mark.parametrize("aw", ["conditional", "back_calculation"])
def test_anti_windup_c_matches_the_reference(tmp_path, aw):
    tt = 0.5
    src = export_controller(result(G, H), format="c", name="aw", u_min=LO, u_max=HI, anti_windup=aw,
                            tt=tt if aw == "back_calculation" else None)
    ref = reference(R, Y, G, H, lo=LO, hi=HI, aw=aw, tt=tt)
    assert_allclose(compile_and_run(tmp_path, src, "aw", R, Y), ref, rtol=1e-11, atol=1e-12)


@pytest.mark.parametrize("aw", ["conditional", "back_calculation"])
def test_integrator_does_not_wind_up_in_saturation(tmp_path, aw):
    """A long saturation (the measurement stuck at 0, r = 1): without anti-windup the integral term grows
    without bound; with it, it stays where the output is at its limit, and u leaves the limit as soon as the
    measurement reaches the reference."""
    src = export_controller(result(G, H), format="python", name="W", u_min=LO, u_max=HI, anti_windup=aw)
    c = load_python(tmp_path, src, "W")()
    for _ in range(500):  # 20 s saturated: the plain integral would be Ki * 20 = 60
        u = c.update(1.0, 0.0)
    assert u == HI
    if aw == "conditional":  # I no larger than what holds the output at its limit
        assert c._i <= HI - G["Kp"] * G["b"] + 1e-9
    else:  # tracking: I settles where Ki e dt = (dt/Tt)(w - u), i.e. I = u - P + Ki e (Tt - dt)
        tt = math.sqrt((G["Kp"] / G["Ki"]) * (G["Kd"] / G["Kp"]))
        assert c._i == pytest.approx(HI - G["Kp"] * G["b"] + G["Ki"] * 1.0 * (tt - H), rel=1e-6)
    u_plain = reference(np.ones(500), np.zeros(500), G, H)  # the law without limits, for contrast
    assert u_plain[-1] > 50
    u_next = [c.update(1.0, 1.0) for _ in range(3)]  # y reaches r: the output leaves the limit at once
    assert u_next[-1] < HI


def test_text_states_the_law_and_the_scheme():
    txt = export_controller(result(G, H), format="text", name="t", u_min=LO, u_max=HI,
                            anti_windup="back_calculation")
    assert "P[k] = 2.0 * (0.6 * r[k] - y[k])" in txt
    assert "D on the measurement" in txt
    assert "back-calculation" in txt and "Tt = " in txt
    assert "Kp (b - 1) = " in txt


def test_default_tracking_time_is_astrom_hagglund():
    from tuner.export.twodof import default_tt

    assert default_tt(2.0, 3.0, 0.2, 0.01) == pytest.approx(math.sqrt((2 / 3) * (0.2 / 2)))
    assert default_tt(2.0, 3.0, 0.0, 0.01) == pytest.approx(2 / 3)  # a PI: Ti
    assert default_tt(2.0, 3000.0, 0.0, 0.01) == 0.01  # never below dt


def test_bad_options_name_the_field():
    with pytest.raises(TunerError) as ei:
        export_controller(result(G, H), format="c", anti_windup="reset")
    assert ei.value.field == ("anti_windup",)
    with pytest.raises(TunerError) as ei:
        export_controller(result(G, H), format="c", u_max=1.0, anti_windup="back_calculation", tt=0.001)
    assert ei.value.field == ("tt",)
    with pytest.raises(TunerError) as ei:  # a 1-DOF controller: conditional integration only
        export_controller(controller_tf("pi", {"Kp": 1.0, "Ki": 1.0}, dt=H), format="c", u_max=1.0,
                          anti_windup="back_calculation")
    assert ei.value.field == ("anti_windup",)
    with pytest.raises(TunerError) as ei:  # a 2-DOF controller without its gains
        export_controller(controller_tf("pid2", G, dt=H), format="c")
    assert ei.value.field == ("controller",)


def test_cli_exports_a_pid2_result(tmp_path, capsys):
    f = tmp_path / "r.json"
    f.write_text(json.dumps(result(G, H)))
    code = main(["export", "--result", str(f), "--format", "c", "--u-min", "-1", "--u-max", "1",
                 "--anti-windup", "back-calculation"])
    out = capsys.readouterr().out
    assert code == EXIT_OK
    assert "double r, double y" in out and "back-calculation" in out
