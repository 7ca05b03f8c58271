"""The package's layering, enforced: every module of ``tuner/`` and ``api/`` has a layer, and no module imports
a higher layer than its own, at module level or inside a function (a function-level import is a dependency
too, only a later one). The layers, bottom first (also in the README, "Layout"):

0. **core** — the model of a loop and what every layer shares: ``errors``, ``tolerances``, ``_lazy``,
   ``_process``, ``jsonio``, ``fileio``, ``objectives``, ``spec``, ``expr``, ``lti``, ``plant``, ``controllers``,
   ``loop``, ``interop`` (python-control in and out), ``design`` (the plant's scale, plant-based starts and
   bounds), ``rules`` (the default limits on a structure's parameters), ``problem`` (the validated tuning
   problem), and the identification library ``identify.*`` (records -> a fitted ``Plant``; not its CLI).
1. **analysis** — the verifier ``analysis.*`` (metrics, margins, responses, cascades, plots) and the code
   generator ``export.*`` (a controller -> C/Python; not its CLI): both consume a controller and a loop.
2. **optimize** — how gains are chosen: ``optimize.*`` (search, NLP, batch scoring).
3. **tuning** — the facade and what works on its results: ``tuning``, ``diagnose``, ``tradeoff``, ``robust``,
   ``bounds``, ``display`` (the text and HTML of the results).
4. **front-ends** — ``studies.*``, ``export.cli``, ``identify.cli``.
5. **interfaces** — ``tuner`` (the package's lazy public API), ``cli``, and the service ``api.*``.

A lower layer that needs a higher-layer *object* at run time without depending on its module (``export``
takes a ``TuneResult``, ``make_plant`` an ``IdentifyResult``) recognises it with
:func:`tuner._lazy.is_instance_of`, which imports nothing. The only upward imports allowed are display
conveniences, recognised by where they stand: an import of a presentation module (``CONVENIENCE_MODULES``:
``display``, the plotting modules) inside a result's ``__repr__``/``__str__``/``_repr_html_`` or ``plot``
method (``CONVENIENCE_METHODS``): the text or figure of a result, never core logic. ``ALLOWED`` lists any
other upward import with its reason (none today). Beyond layers, the module graph without those convenience
edges has no import cycle except those in ``ALLOWED_CYCLES``.
"""

from __future__ import annotations

import ast
import pathlib
from collections import defaultdict

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
PACKAGES = ("tuner", "api")

LAYER_NAMES = ("core", "analysis", "optimize", "tuning", "front-ends", "interfaces")

# module (or package: it and everything under it) -> layer; the longest matching name wins
LAYER_OF = {
    **dict.fromkeys(("tuner.errors", "tuner.tolerances", "tuner.limits", "tuner.text", "tuner._lazy", "tuner._process",
                     "tuner.jsonio",
                     "tuner.fileio", "tuner.objectives", "tuner.spec", "tuner.expr", "tuner.lti", "tuner.plant",
                     "tuner.controllers", "tuner.loop", "tuner.interop", "tuner.design", "tuner.rules",
                     "tuner.problem", "tuner.identify", "tuner.firmware"), "core"),
    **dict.fromkeys(("tuner.analysis", "tuner.export"), "analysis"),
    "tuner.optimize": "optimize",
    **dict.fromkeys(("tuner.tuning", "tuner.diagnose", "tuner.tradeoff", "tuner.robust", "tuner.bounds",
                     "tuner.display"), "tuning"),
    **dict.fromkeys(("tuner.studies", "tuner.export.cli", "tuner.identify.cli"), "front-ends"),
    **dict.fromkeys(("tuner", "tuner.cli", "api"), "interfaces"),
}

# a result's text and figures: these modules, imported inside these methods, may sit in a higher layer
CONVENIENCE_MODULES = frozenset({"tuner.analysis.plots", "tuner.identify.plot"})
CONVENIENCE_METHODS = frozenset({"__repr__", "__str__", "_repr_html_", "_repr_pretty_", "plot"})

# (importer, imported): why this other upward import is a display/plots convenience, not core logic
ALLOWED: dict[tuple[str, str], str] = {}

# import cycles (as the set of their modules) that remain, each with its reason
ALLOWED_CYCLES: dict[frozenset[str], str] = {}  # none: issue 29 broke the last two (display, interop)


def _modules() -> dict[str, pathlib.Path]:
    out = {}
    for pkg in PACKAGES:
        for p in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(p.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = p
    return out


MODULES = _modules()


def _rel(p: pathlib.Path) -> pathlib.Path:
    return p.relative_to(ROOT) if p.is_relative_to(ROOT) else p


def layer(mod: str) -> str:
    parts = mod.split(".")
    for n in range(len(parts), 0, -1):
        if ".".join(parts[:n]) in LAYER_OF:
            return LAYER_OF[".".join(parts[:n])]
    raise KeyError(mod)


def _enclosing_functions(tree: ast.Module) -> dict[int, str]:
    """``id(import node)`` -> the name of the innermost function it stands in."""
    out: dict[int, str] = {}

    def visit(node: ast.AST, fn: str | None) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                visit(child, child.name)
            else:
                if isinstance(child, (ast.Import, ast.ImportFrom)) and fn is not None:
                    out[id(child)] = fn
                visit(child, fn)

    visit(tree, None)
    return out


def imports(mod: str, *, conveniences: bool = True) -> list[tuple[str, int, bool]]:
    """``(imported module, line, at module level)`` for every import of a ``tuner``/``api`` module in ``mod``;
    ``conveniences=False`` leaves out the display conveniences (see the module's docstring)."""
    path = MODULES[mod]
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    top = {id(n) for n in tree.body}
    fns = _enclosing_functions(tree)
    pkg = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = ".".join(pkg[: len(pkg) - node.level + 1] + ([node.module] if node.module else [])) \
                if node.level else (node.module or "")
            # ``from pkg import sub``: the submodule when it is one, else the module itself
            names = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
        else:
            continue
        for n in names:
            if n.split(".")[0] not in PACKAGES:
                continue
            if not conveniences and n in CONVENIENCE_MODULES and fns.get(id(node)) in CONVENIENCE_METHODS:
                continue
            out.append((n, node.lineno, id(node) in top))
    return out


def graph(*, conveniences: bool = True) -> dict[str, set[str]]:
    g: dict[str, set[str]] = defaultdict(set)
    for m in MODULES:
        for n, _, _ in imports(m, conveniences=conveniences):
            if n != m:
                g[m].add(n)
    return g


def test_every_module_has_a_layer():
    missing = [m for m in MODULES if not any(m == k or m.startswith(k + ".") for k in LAYER_OF)]
    assert not missing, f"give these modules a layer in LAYER_OF (and the README's Layout): {missing}"
    assert {layer(m) for m in MODULES} <= set(LAYER_NAMES)


def test_no_import_of_a_higher_layer():
    bad = []
    for m in MODULES:
        for n, line, at_top in imports(m, conveniences=False):
            if LAYER_NAMES.index(layer(n)) > LAYER_NAMES.index(layer(m)) and (m, n) not in ALLOWED:
                where = "module level" if at_top else "in a function"
                bad.append(f"{_rel(MODULES[m])}:{line} ({layer(m)}) imports {n} ({layer(n)}), {where}")
    assert not bad, "imports of a higher layer:\n" + "\n".join(bad)


@pytest.mark.slow  # (over about 2 s on this machine: the whole suite runs it)
def test_allow_list_is_current_and_only_conveniences():
    g = graph()
    for (m, n), why in ALLOWED.items():
        assert n in g[m], f"stale ALLOWED entry {m} -> {n}: remove it"
        assert LAYER_NAMES.index(layer(n)) > LAYER_NAMES.index(layer(m)), f"{m} -> {n} is not upward: remove it"
        assert why and ("repr" in why or "plot" in why), "upward imports are allowed for display/plots only"


def _cycles(g: dict[str, set[str]]) -> list[frozenset[str]]:
    """The strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out = []
    for root in sorted(MODULES):
        if root in index:
            continue
        work = [(root, iter(sorted(g.get(root, ()))))]
        index[root] = low[root] = len(index)
        stack.append(root), on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w), on.add(w)
                    work.append((w, iter(sorted(g.get(w, ())))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = set()
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.add(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    out.append(frozenset(comp))
    return out


@pytest.mark.slow  # (over about 1.5 s on this machine: the whole suite runs it)
def test_no_import_cycles_but_the_documented_ones():
    # every import counts, the display and plotting conveniences included (issue 29: the display circle went through
    # them, and the plant/interop/controllers one through a function-level import): neither can come back
    cycles = _cycles(graph(conveniences=True))
    unexpected = [sorted(c) for c in cycles if c not in ALLOWED_CYCLES]
    assert not unexpected, f"import cycles (module or function level): {unexpected}"
    stale = [sorted(c) for c in ALLOWED_CYCLES if c not in cycles]
    assert not stale, f"these cycles are gone: remove them from ALLOWED_CYCLES: {stale}"


def test_the_checks_can_fail(tmp_path, monkeypatch):
    """The import reader sees function-level and relative imports, and the checks flag what they must."""
    src = tmp_path / "tuner" / "lowmod.py"
    src.parent.mkdir()
    src.write_text("from .errors import TunerError\n\ndef f():\n    from .optimize import engine\n"
                   "    import tuner.tuning\n\nclass R:\n    def __repr__(self):\n        from .identify import plot\n"
                   "    def plot(self):\n        from .analysis import plots\n\n"
                   "    def summary(self):\n        from .identify import plot\n")
    monkeypatch.setitem(MODULES, "tuner.lowmod", src)
    monkeypatch.setitem(LAYER_OF, "tuner.lowmod", "core")
    got = {(n, top) for n, _, top in imports("tuner.lowmod")}
    assert ("tuner.errors", True) in got and ("tuner.optimize.engine", False) in got
    assert ("tuner.tuning", False) in got
    lines = {(n, line) for n, line, _ in imports("tuner.lowmod", conveniences=False)}
    assert ("tuner.identify.plot", 14) in lines and ("tuner.identify.plot", 9) not in lines  # summary() is no repr
    assert ("tuner.analysis.plots", 11) not in lines
    with pytest.raises(AssertionError, match="lowmod.py:4 \\(core\\) imports tuner.optimize.engine"):
        test_no_import_of_a_higher_layer()


def test_cycle_finder_on_a_known_graph(monkeypatch):
    monkeypatch.setattr(f"{__name__}.MODULES", dict.fromkeys("abcde"))
    got = set(_cycles({"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": {"e"}, "e": {"d"}}))
    assert got == {frozenset("abc"), frozenset("de")}


def test_problem_does_not_import_optimize():
    """The package cycle of issue 21: ``problem`` -> ``optimize.design`` while ``optimize`` -> ``problem``."""
    assert not [n for n, _, _ in imports("tuner.problem") if n.startswith("tuner.optimize")]
    assert "tuner.problem" in {n for m in MODULES if m.startswith("tuner.optimize") for n, _, _ in imports(m)}
