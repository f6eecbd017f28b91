"""The strategies package's import graph has no cycle, deferred imports included (issue 33).

Every ``import``/``from ... import`` of a ``cellplan.strategies`` module, at any depth of
any function, is an edge; a cycle among the package's modules fails the test, naming them.
"""

from __future__ import annotations

import ast
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
