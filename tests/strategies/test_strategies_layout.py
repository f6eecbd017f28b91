"""The strategies package's layout (issue 33): no import cycle, deferred imports included;
no file, function or parameter list over its limit; the Section VI branches in ``variants/``.

Every ``import``/``from ... import`` of a ``cellplan.strategies`` module, at any depth of
any function, is an edge; a cycle among the package's modules fails the test, naming them.
"""

from __future__ import annotations

import ast
import importlib
import re
import typing
from pathlib import Path

import networkx as nx

import cellplan.strategies

ROOT = Path(cellplan.strategies.__file__).parent
PACKAGE = "cellplan.strategies"


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent.parent).with_suffix("").parts
    name = ".".join(parts)
    return name.removesuffix(".__init__")


def imported(path: Path, name: str) -> set[str]:
    """Every module of the package that ``path`` imports, the names of a ``from`` included."""
    found: set[str] = set()
    is_package = path.name == "__init__.py"
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = name.split(".")
                anchor = anchor[: len(anchor) - node.level + (1 if is_package else 0)]
                base = ".".join([*anchor, *([node.module] if node.module else [])])
            found.add(base)
            found.update(f"{base}.{a.name}" for a in node.names)
    return {m for m in found if m.startswith(PACKAGE)}


def import_graph() -> nx.DiGraph:
    files = {module_name(p): p for p in ROOT.rglob("*.py") if "__pycache__" not in p.parts}
    graph = nx.DiGraph()
    graph.add_nodes_from(files)
    for name, path in files.items():
        for target in imported(path, name):
            # ``from pkg import name``: the module ``pkg.name`` if it is one, else ``pkg``
            while target and target not in files:
                target = target.rpartition(".")[0]
            if target and target != name:
                graph.add_edge(name, target)
    return graph


def test_the_strategies_package_has_no_import_cycle():
    graph = import_graph()
    assert graph.number_of_nodes() > 40
    cycles = [sorted(c) for c in nx.strongly_connected_components(graph) if len(c) > 1]
    assert cycles == []


def test_the_cycle_check_sees_a_deferred_import(tmp_path):
    """The check is not blind to function-local imports: a planted one is an edge."""
    planted = tmp_path / "planted.py"
    planted.write_text("def f():\n    from cellplan.strategies.sim import simulate\n")
    assert "cellplan.strategies.sim.simulate" in imported(planted, "cellplan.strategies.x")


# --- issue 33's size limits and its one seam ----------------------------------------------------

MAX_FILE_LINES = 600
MAX_FUNCTION_LINES = 100
MAX_PARAMETERS = 8
VARIANT_TESTS = re.compile(r"period > 1|simultaneous\(\)")


def sources() -> list[Path]:
    return sorted(p for p in ROOT.rglob("*.py") if "__pycache__" not in p.parts)


def limit_violations(path: Path, root: Path = ROOT) -> list[str]:
    """Where ``path`` breaks a size limit: its length, a function's length or parameters.

    ``self``/``cls`` are not counted; ``*args``/``**kwargs`` are, one each."""
    text = path.read_text()
    rel = path.relative_to(root)
    found = []
    if text.count("\n") > MAX_FILE_LINES:
        found.append(f"{rel}: {text.count(chr(10))} lines")
    for node in ast.walk(ast.parse(text)):
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        a = node.args
        params = [*a.posonlyargs, *a.args, *a.kwonlyargs, *filter(None, (a.vararg, a.kwarg))]
        count = len(params) - (1 if params and params[0].arg in ("self", "cls") else 0)
        length = (node.end_lineno or node.lineno) - node.lineno + 1
        if length > MAX_FUNCTION_LINES:
            found.append(f"{rel}:{node.lineno} {node.name}: {length} lines")
        if count > MAX_PARAMETERS:
            found.append(f"{rel}:{node.lineno} {node.name}: {count} parameters")
    return found


def test_no_file_function_or_parameter_list_is_over_its_limit():
    assert len(sources()) > 40
    assert [v for path in sources() for v in limit_violations(path)] == []


def test_the_limit_check_sees_a_long_function_and_a_long_parameter_list(tmp_path):
    planted = tmp_path / "planted.py"
    body = "".join(f"    x{i} = {i}\n" for i in range(100))
    planted.write_text(f"class C:\n  def f(self, a, b, c, d, e, f, g, h, *i):\n{body}")
    assert limit_violations(planted, tmp_path) == [
        "planted.py:2 f: 101 lines",
        "planted.py:2 f: 9 parameters",
    ]


def test_only_variants_test_which_variant_a_model_has():
    """Issue 33's grep: the Section VI branches live in ``variants/`` alone."""
    hits = [
        f"{p.relative_to(ROOT)}:{n}"
        for p in sources()
        if "variants" not in p.relative_to(ROOT).parts
        for n, line in enumerate(p.read_text().splitlines(), 1)
        if VARIANT_TESTS.search(line)
    ]
    assert hits == []


def test_every_named_tuple_has_annotations_the_api_reference_can_read():
    """pdoc reads a NamedTuple's ``__new__`` annotations, which live outside the module: under
    ``from __future__ import annotations`` they are strings naming ``np`` that cannot resolve
    there (the slow API reference build failed on seven bundles of ``solve/``)."""
    bundles = [
        obj
        for path in sources()
        for obj in vars(importlib.import_module(module_name(path))).values()
        if isinstance(obj, type)
        and issubclass(obj, tuple)
        and hasattr(obj, "_fields")
        and obj.__module__ == module_name(path)
        and not obj.__name__.startswith("_")
    ]  # fmt: skip  (pdoc renders the public ones)
    assert len(bundles) > 10
    unreadable = []
    for cls in bundles:
        try:
            typing.get_type_hints(cls.__new__)
        except NameError:
            unreadable.append(cls.__qualname__)
    assert unreadable == []
