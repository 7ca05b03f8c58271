"""Controller export (issue 14): the generated C99 compiled with gcc and the generated Python class, run on a
test sequence and compared with ``scipy.signal.lfilter`` of the same controller; output limits with
anti-windup against a simulation written here from the gains (textbook PI/PID with clamping); the CLI's exit
codes.

References are computed apart from :mod:`tuner.export`: ``b``/``a`` from the controller's own coefficients
(padded to the denominator's length), Tustin by ``scipy.signal.cont2discrete`` (the export uses
``scipy.signal.bilinear``), the structure's discretisation by :mod:`tuner.controllers`.
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
from quadrotor import DT, ROLL_C
from scipy import signal

from tuner.cli import EXIT_BAD_INPUT, EXIT_OK, main
from tuner.controllers import ControllerTF, controller_from_expr, controller_tf
from tuner.errors import InvalidControllerError, TunerError
from tuner.export import check_name, difference_equation, export_controller

GCC = shutil.which("gcc")
needs_gcc = pytest.mark.skipif(GCC is None, reason="gcc not installed")

RNG = np.random.default_rng(14)
# steps, a ramp and noise: exercises every coefficient
E = np.concatenate([np.ones(40), -0.5 * np.ones(40), np.linspace(-1, 1, 60), RNG.normal(size=120)])

CONTROLLERS = {
    "roll pid_z (thesis)": (controller_from_expr(ROLL_C, dt=DT), None),
    "pid at dt (backward Euler)": (controller_tf("pid", {"Kp": 1.2, "Ki": 3.0, "Kd": 0.08, "Tf": 0.02}, dt=0.01),
                                   None),
    "leadlag at dt (matched)": (controller_tf("leadlag", {"K": 2.0, "wz1": 3.0, "wp1": 30.0, "wz2": 0.5, "wp2": 0.05},
                                              dt=0.02), None),
    "p": (controller_tf("p", {"Kp": 0.7}, dt=0.1), None),
    "continuous pid by Tustin": (controller_tf("pid", {"Kp": 2.0, "Ki": 5.0, "Kd": 0.3, "Tf": 0.05}, dt=None), 0.01),
}


def reference_ba(c: ControllerTF, dt: float | None) -> tuple[np.ndarray, np.ndarray]:
    """``b``, ``a`` of the controller in powers of z^-1, computed here."""
    if c.dt is None:
        num, den, _ = signal.cont2discrete((c.num, c.den), dt, method="bilinear")
        num, den = np.atleast_1d(np.squeeze(num)), np.asarray(den, float)
    else:
        num, den = np.asarray(c.num, float), np.asarray(c.den, float)
    num, den = num / den[0], den / den[0]
    return np.concatenate([np.zeros(den.size - num.size), num]), den


def compile_and_run(tmp_path: Path, source: str, name: str, e: np.ndarray) -> np.ndarray:
    """Compile ``source`` (strict C99) with a driver reading e from stdin, one number a line; u printed with 17
    digits."""
    (tmp_path / f"{name}.c").write_text(source)
    (tmp_path / "main.c").write_text(
        f'#include <stdio.h>\n#include "{name}.c"\n'
        f"int main(void) {{\n    {name}_state s;\n    double e;\n    {name}_init(&s);\n"
        f'    while (scanf("%lf", &e) == 1) printf("%.17g\\n", {name}_update(&s, e));\n    return 0;\n}}\n')
    exe = tmp_path / "run"
    cc = subprocess.run([GCC, "-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-O2", "-o", str(exe),
                         str(tmp_path / "main.c")], capture_output=True, text=True, timeout=60)
    assert cc.returncode == 0, cc.stderr
    out = subprocess.run([str(exe)], input="\n".join(repr(float(x)) for x in e) + "\n", capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return np.array([float(x) for x in out.stdout.split()])


def load_python(tmp_path: Path, source: str, name: str):
    path = tmp_path / f"{name}_mod.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location(f"{name}_mod", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return getattr(mod, name)


def run_python(cls, e: np.ndarray) -> np.ndarray:
    c = cls()
    return np.array([c.update(x) for x in e])


def tight(u: np.ndarray, ref: np.ndarray) -> None:
    assert u.shape == ref.shape
    assert_allclose(u, ref, rtol=1e-12, atol=1e-12 * float(np.max(np.abs(ref))))


# -- without limits: the controller exactly ----------------------------------------------------------------------

@needs_gcc
@pytest.mark.parametrize("case", list(CONTROLLERS))
def test_c_matches_lfilter(tmp_path, case):
    c, dt = CONTROLLERS[case]
    src = export_controller(c, format="c", name="ctl", dt=dt)
    b, a = reference_ba(c, dt)
    tight(compile_and_run(tmp_path, src, "ctl", E), signal.lfilter(b, a, E))


@pytest.mark.parametrize("case", list(CONTROLLERS))
def test_python_class_matches_lfilter(tmp_path, case):
    c, dt = CONTROLLERS[case]
    cls = load_python(tmp_path, export_controller(c, format="python", name="Ctl", dt=dt), "Ctl")
    b, a = reference_ba(c, dt)
    tight(run_python(cls, E), signal.lfilter(b, a, E))
    assert cls.dt == (dt or c.dt)


def test_structure_method_is_the_structures_own_discretisation():
    gains = {"Kp": 2.0, "Ki": 5.0, "Kd": 0.3, "Tf": 0.05}
    result = {"structure": "pid", "gains": gains, "controller": controller_tf("pid", gains, dt=None).to_dict()}
    de = difference_equation(controller_tf("pid", gains, dt=None), dt=0.01, method="structure", structure="pid",
                             gains=gains)
    ref = controller_tf("pid", gains, dt=0.01)  # backward Euler, tuner.controllers
    b, a = reference_ba(ref, None)
    assert_allclose(signal.lfilter(de.b, de.a, E), signal.lfilter(b, a, E), rtol=1e-12, atol=1e-12)
    text = export_controller(result, format="text", dt=0.01, method="structure")
    assert "backward Euler" in text and "dt = 0.01 s" in text


def test_text_is_the_difference_equation():
    # C(z) = 2 (z - 0.5)/(z - 1) = (2 - z^-1)/(1 - z^-1): u[k] = 2 e[k] - e[k-1] + u[k-1]
    text = export_controller(controller_from_expr("2*(z - 0.5)/(z - 1)", dt=0.1), format="text", name="pi")
    assert "u[k] = 2.0 * e[k] - 1.0 * e[k-1] + 1.0 * u[k-1]" in text
    assert "direct form II transposed" in text and "double precision" in text


# -- limits and anti-windup -------------------------------------------------------------------------------------

KP, KI, KD, TF, H = 2.0, 4.0, 0.1, 0.02, 0.01
LO, HI = -1.0, 1.5


def textbook_pid(e: np.ndarray, kd: float = 0.0) -> np.ndarray:
    """Backward-Euler PID with filtered derivative (tuner.controllers' form), output clamped to [LO, HI],
    conditional integration: the integrator does not take this sample's increment Ki*h*e when the output
    is saturated and the increment points further into the limit (written from the gains, not from the
    export's partial fractions)."""
    integ, d, e_prev, out = 0.0, 0.0, 0.0, []
    for x in e:
        d = (TF * d + kd * (x - e_prev)) / (TF + H) if kd else 0.0
        inc = KI * H * x
        v = KP * x + integ + inc + d  # the unsaturated output, with this sample integrated
        u = min(max(v, LO), HI)
        if not ((v > HI and inc > 0) or (v < LO and inc < 0)):
            integ += inc
        out.append(u)
        e_prev = x
    return np.array(out)


E_SAT = np.concatenate([np.ones(80), -np.ones(80), 0.2 * np.ones(40), RNG.normal(scale=0.8, size=100)])


@pytest.mark.parametrize("kd", [0.0, KD], ids=["pi", "pid"])
def test_limits_with_anti_windup_match_the_textbook_scheme_python(tmp_path, kd):
    gains = {"Kp": KP, "Ki": KI} if not kd else {"Kp": KP, "Ki": KI, "Kd": kd, "Tf": TF}
    c = controller_tf("pi" if not kd else "pid", gains, dt=H)
    cls = load_python(tmp_path, export_controller(c, format="python", name="Pi", u_min=LO, u_max=HI), "Pi")
    u = run_python(cls, E_SAT)
    ref = textbook_pid(E_SAT, kd)
    assert np.any(ref == HI) and np.any(ref == LO)  # the sequence saturates both ways
    assert_allclose(u, ref, rtol=1e-11, atol=1e-12)


@needs_gcc
def test_limits_with_anti_windup_match_the_textbook_scheme_c(tmp_path):
    c = controller_tf("pid", {"Kp": KP, "Ki": KI, "Kd": KD, "Tf": TF}, dt=H)
    src = export_controller(c, format="c", name="pid", u_min=LO, u_max=HI)
    assert "conditional integration" in src
    assert_allclose(compile_and_run(tmp_path, src, "pid", E_SAT), textbook_pid(E_SAT, KD), rtol=1e-11, atol=1e-12)


def test_inside_the_limits_the_limited_controller_is_the_controller(tmp_path):
    c = controller_from_expr(ROLL_C, dt=DT)
    e = 0.01 * np.sin(np.arange(200) * 0.3)
    cls = load_python(tmp_path, export_controller(c, format="python", name="R", u_min=-10, u_max=10), "R")
    b, a = reference_ba(c, None)
    ref = signal.lfilter(b, a, e)
    assert np.max(np.abs(ref)) < 10
    assert_allclose(run_python(cls, e), ref, rtol=1e-10, atol=1e-13)


def test_anti_windup_shortens_the_overshoot_after_saturation(tmp_path):
    """Closed loop: y[k+1] = p y[k] + (1 - p) u[k] (a first-order lag, exact ZOH) under the PI with |u| <= 1.2
    for a unit step: plain clamping winds up (large overshoot), conditional integration does not."""
    c = controller_tf("pi", {"Kp": KP, "Ki": KI}, dt=H)
    cls = load_python(tmp_path, export_controller(c, format="python", name="Aw", u_min=-1.2, u_max=1.2), "Aw")
    p = math.exp(-H / 0.5)
    b, a = reference_ba(c, None)

    def loop(step):
        y, ys = 0.0, []
        for _ in range(1500):
            u = step(1.0 - y)
            ys.append(y)
            y = p * y + (1 - p) * u
        return np.array(ys)

    aw = cls()
    y_aw = loop(aw.update)
    zi = np.zeros(a.size - 1)

    def naive(e):  # the linear controller with its output clamped
        nonlocal zi
        v, zi = signal.lfilter(b, a, [e], zi=zi)
        return min(max(float(v[0]), -1.2), 1.2)

    y_naive = loop(naive)
    os_aw, os_naive = y_aw.max() - 1.0, y_naive.max() - 1.0
    assert abs(y_aw[-1] - 1.0) < 1e-3 and abs(y_naive[-1] - 1.0) < 1e-2
    assert os_naive > 0.05 and os_aw < 0.5 * os_naive, (os_aw, os_naive)


def test_limits_refused_where_the_state_would_wind_up():
    with pytest.raises(InvalidControllerError) as ei:
        difference_equation(controller_from_expr("1/(z - 1.2)", dt=0.1), u_max=1.0)
    assert ei.value.field == ("controller",)
    with pytest.raises(InvalidControllerError, match="two or more poles at z = 1"):
        difference_equation(controller_from_expr("1/(z - 1)^2", dt=0.1), u_max=1.0)
    with pytest.raises(TunerError) as ei:
        difference_equation(controller_from_expr("1/(z - 0.5)", dt=0.1), u_min=2.0, u_max=1.0)
    assert ei.value.field == ("u_min",)


@pytest.mark.parametrize("bad", ["1x", "a-b", "", "int", "class", "__x", "_X", "x" * 60, "é"])
def test_name_must_be_a_c_identifier(bad):
    with pytest.raises(TunerError) as ei:
        check_name(bad)
    assert ei.value.field == ("name",)


def test_a_continuous_controller_needs_dt_and_a_discrete_one_keeps_its_own():
    with pytest.raises(TunerError) as ei:
        difference_equation(controller_tf("pi", {"Kp": 1, "Ki": 1}, dt=None))
    assert ei.value.field == ("dt",)
    with pytest.raises(TunerError) as ei:
        difference_equation(controller_from_expr(ROLL_C, dt=DT), dt=0.01)
    assert ei.value.field == ("dt",)


# -- the command line -------------------------------------------------------------------------------------------

def run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_exports_an_expression(capsys):
    code, out, err = run(capsys, "export", "--controller", ROLL_C, "--dt", str(DT), "--format", "c", "--name", "roll")
    assert code == EXIT_OK and not err
    assert "roll_state" in out and "void roll_init(roll_state *s)" in out
    assert "double roll_update(roll_state *s, double e)" in out


def test_cli_exports_a_result_file(tmp_path, capsys):
    gains = {"Kp": 1.2, "Ki": 3.0, "Kd": 0.08, "Tf": 0.02}
    c = controller_tf("pid", gains, dt=0.01)
    # the shape of `tuner tune --json` (and of GET /tunes/{id})
    f = tmp_path / "res.json"
    f.write_text(json.dumps({"structure": "pid", "gains": gains, "controller": c.to_dict(), "meets_spec": True}))
    out_file = tmp_path / "pid.py"
    code, out, err = run(capsys, "export", "--result", str(f), "--format", "python", "--name", "Pid", "--out",
                         str(out_file))
    assert code == EXIT_OK and not err and not out
    cls = load_python(tmp_path, out_file.read_text(), "Pid")
    b, a = reference_ba(c, None)
    tight(run_python(cls, E), signal.lfilter(b, a, E))


@pytest.mark.parametrize("args, word", [
    (["--controller", "1+2/s", "--format", "c"], "--dt"),  # continuous: needs --dt
    (["--controller", ROLL_C, "--dt", "0.04", "--format", "c", "--name", "9lives"], "--name"),
    (["--controller", ROLL_C, "--dt", "0.04", "--format", "c", "--u-min", "2", "--u-max", "1"], "--u-min"),
    (["--controller", "1/(z-2)", "--dt", "0.1", "--format", "text", "--u-max", "1"], "--controller"),
    (["--controller", "1+2/(s+", "--dt", "0.1", "--format", "c"], "--controller"),
    (["--controller", "1+2/s", "--dt", "0.1", "--format", "c", "--method", "structure"], "--method"),
    (["--result", "/nonexistent/r.json", "--format", "c"], "--result"),
    (["--controller", ROLL_C, "--dt", "0.04", "--format", "fortran"], "--format"),
])
def test_cli_bad_input_is_exit_2_naming_the_argument(capsys, args, word):
    code, out, err = run(capsys, "export", *args) if "fortran" not in args else _argparse(capsys, args)
    assert code == EXIT_BAD_INPUT, (code, err)
    assert word in err and "Traceback" not in err


def _argparse(capsys, args):
    with pytest.raises(SystemExit) as ei:
        main(["export", *args])
    return ei.value.code, *capsys.readouterr()


def test_cli_result_file_that_is_not_a_result(tmp_path, capsys):
    f = tmp_path / "x.json"
    f.write_text(json.dumps({"metrics": {}}))
    code, _, err = run(capsys, "export", "--result", str(f), "--format", "c")
    assert code == EXIT_BAD_INPUT and "--result" in err and "controller" in err
    f.write_text("{not json")
    code, _, err = run(capsys, "export", "--result", str(f), "--format", "c")
    assert code == EXIT_BAD_INPUT and "not valid JSON" in err
