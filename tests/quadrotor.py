"""The quadrotor thesis case, as decoded in shared/reference/quadrotor.md."""

from __future__ import annotations

DT = 0.04  # thesis sample time, s (ZOH)

# identified continuous attitude models (command -> angle)
YAW = "0.2843*18.611/(s+18.611)"
ROLL = "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)"
PITCH = "0.377568*3.5184^2/(s^2+2*0.5006*3.5184*s+3.5184^2)"

# digital PIDs as printed, C(z) = K (z^2 + a1 z + a2)/(z (z-1))
ROLL_C = "3.868*(z^2-1.305*z+0.5668)/(z*(z-1))"
PITCH_C = "37.79*(z^2-1.85*z+0.8686)/(z*(z-1))"
YAW_C = "(z-0.475)/(z*(z-1))"  # K is illegible in the thesis; K = 1 here

# altitude loop: H(z)/Tn(z) = 0.04/(z-1), PI printed as 5 + 2/(z-1)
ALT_PLANT = "0.04/(z-1)"
ALT_C = "5+2/(z-1)"


def scaled(expr: str, k: float) -> str:
    """``k`` times a controller expression."""
    return f"{k!r}*({expr})"
