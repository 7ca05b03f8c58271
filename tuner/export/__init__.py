"""Controller export: from a tuned or given controller to code for the target.

* :mod:`~tuner.export.discrete`: the difference equation at ``dt`` (a continuous controller discretised by a
  stated method), output limits and the anti-windup split (:class:`DifferenceEquation`);
* :mod:`~tuner.export.codegen`: C99, a Python class, plain text;
* :mod:`~tuner.export.source`: :func:`export_controller`, the one call (a controller, a
  :class:`~tuner.TuneResult` or a result dict in, the source out);
* :mod:`~tuner.export.cli`: ``tuner export``.

>>> from tuner.controllers import controller_from_expr
>>> from tuner.export import difference_equation, export_controller, to_text
>>> de = difference_equation(controller_from_expr("2*(z - 0.5)/(z - 1)", dt=0.1))
>>> print(to_text(de, "pi").splitlines()[3])
  u[k] = 2.0 * e[k] - 1.0 * e[k-1] + 1.0 * u[k-1]
>>> c_source = export_controller(controller_from_expr("2*(z - 0.5)/(z - 1)", dt=0.1), format="c")
>>> print(c_source)  # doctest: +ELLIPSIS
/*
 * controller: discrete controller at dt = 0.1 s (10 Hz), order 1; the discrete controller as given
...

Importing this package costs nothing (``tuner --help`` registers ``tuner export`` without numpy): its
names load on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_getattr

if TYPE_CHECKING:
    from .codegen import FORMATS, check_name, render, to_c, to_python, to_text
    from .discrete import METHODS, DifferenceEquation, Integrator, difference_equation, discretize
    from .source import equation_of, export_controller, from_result

__all__ = ["export_controller", "equation_of", "from_result", "difference_equation", "discretize",
           "DifferenceEquation", "Integrator", "render", "to_c", "to_python", "to_text", "check_name", "FORMATS",
           "METHODS"]
_WHERE = {
    **dict.fromkeys(("FORMATS", "check_name", "render", "to_c", "to_python", "to_text"), "codegen"),
    **dict.fromkeys(("METHODS", "DifferenceEquation", "Integrator", "difference_equation", "discretize"),
                    "discrete"),
    **dict.fromkeys(("equation_of", "export_controller", "from_result"), "source"),
}


__getattr__ = lazy_getattr(__name__, _WHERE)
