"""Named scenarios and planners, shared by the CLI, benchmarks and tests.

Bundled scenarios are the ``*.yaml`` files of the repository's ``scenarios/``
folder (shipped inside the package as ``cellplan/bundled_scenarios``); a
scenario name is its file stem. Planners are listed by each paper package in
its ``planners.py`` as ``PLANNERS``; the registry imports those modules only
when asked, so ``import cellplan`` stays light.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from cellplan.core import PlannerEntry
from cellplan.errors import Problem, ScenarioError

BUNDLED_DIR = Path(__file__).resolve().parent / "bundled_scenarios"

_PLANNER_MODULES = (
    "cellplan.strategies.planners",
    "cellplan.adaptive.planners",
    "cellplan.assembly.planners",
)


def scenario_names() -> list[str]:
    """Names of the bundled scenarios, sorted."""
    return sorted(p.stem for p in BUNDLED_DIR.glob("*.yaml"))


def scenario_path(name: str) -> Path:
    """Path of a bundled scenario by name."""
    path = BUNDLED_DIR / f"{name}.yaml"
    if not path.is_file():
        known = ", ".join(scenario_names())
        raise ScenarioError([Problem(name, f"no such bundled scenario (known: {known})")])
    return path


def resolve_scenario_path(path_or_name: str | Path) -> Path:
    """A file path as given, or a bundled scenario's path when only a name is given."""
    path = Path(path_or_name)
    if path.is_file():
        return path
    if path.suffix == "" and path.parent == Path("."):
        return scenario_path(str(path))
    raise ScenarioError([Problem(str(path_or_name), "no such file")])


def planners() -> dict[str, PlannerEntry]:
    """All registered planners by name."""
    out: dict[str, PlannerEntry] = {}
    for module_name in _PLANNER_MODULES:
        module = importlib.import_module(module_name)
        for entry in module.PLANNERS:
            if entry.name in out:
                raise RuntimeError(f"planner {entry.name!r} registered twice")
            out[entry.name] = entry
    return out
