"""The documentation runs: every docstring example in every module of ``tuner/`` is executed (``doctest``).

This is ``pytest --doctest-modules tuner`` inside the README's test command (``testpaths = ["tests"]``): one test
per module, with the options the examples are written for (``ELLIPSIS``, ``NORMALIZE_WHITESPACE``). An example
that needs a tune uses a tiny budget and prints only what does not depend on timing or the search's path.
"""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import tuner

OPTIONS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE

# modules whose examples take more than a few seconds go to the slow lane (none today: the tunes in
# tuner.tuning's examples have a 1 s budget; what they print holds for any budget, a first round included)
SLOW: set[str] = set()


def _modules() -> list[str]:
    names = ["tuner"]
    for m in pkgutil.walk_packages(tuner.__path__, "tuner."):
        names.append(m.name)
    return sorted(names)


MODULES = _modules()


def _module(name: str):
    mod = importlib.import_module(name)
    if name == "tuner.identify":  # ``tuner.identify`` the attribute is the function; the package is in sys.modules
        import sys

        mod = sys.modules[name]
    return mod


def test_every_module_is_collected():
    assert {"tuner", "tuner.tuning", "tuner.analysis.verify", "tuner.export", "tuner.identify"} <= set(MODULES)
    assert len(MODULES) > 40


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in MODULES])
def test_module_doctests(name):
    mod = _module(name)
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=OPTIONS)
    tests = finder.find(mod, name)  # each with the module's globals, as pytest --doctest-modules
    report: list[str] = []
    for t in tests:
        if t.lineno is None and not t.examples:
            continue
        runner.run(t, out=report.append)
    res = runner.summarize(verbose=False)
    assert res.failed == 0, "".join(report)


def test_the_doctest_runner_fails_on_a_wrong_example():
    """The check above can fail: a docstring whose example is wrong is reported."""

    def f():
        """
        >>> 1 + 1
        3
        """

    t = doctest.DocTestFinder().find(f, "f", globs={})[0]
    runner = doctest.DocTestRunner(optionflags=OPTIONS)
    runner.run(t, out=lambda s: None)
    assert runner.summarize(verbose=False).failed == 1
