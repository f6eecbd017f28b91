"""Named scenarios, packages and planners, shared by the API, CLI, benchmarks and tests.

Bundled scenarios are the ``*.yaml`` files of the repository's ``scenarios/`` folder
(shipped inside the package as ``cellplan/bundled_scenarios``); a scenario name is its
file stem.

Packages (one per planner family) declare themselves once, as a
:class:`~cellplan.core.Package` named ``PACKAGE`` in a module listed in
:data:`BUILTIN_PACKAGES` or exposed by a Python entry point in the group
``cellplan.packages``. Everything else (scenario sections, planners, experiments, CLI
commands, report metadata) is read from those declarations: this module holds the only
registration list in the core.
"""

from __future__ import annotations

import difflib
import functools
import importlib
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from cellplan.core import Options, Package, PlannerSpec
from cellplan.errors import ArgumentError, Problem, ScenarioError
from cellplan.fileio import kind_of

BUNDLED_DIR = Path(__file__).resolve().parent / "bundled_scenarios"

BUILTIN_PACKAGES: tuple[str, ...] = (
    "cellplan.strategies.plugin",
    "cellplan.adaptive.plugin",
    "cellplan.assembly.plugin",
)
"""The registration list: modules that each define ``PACKAGE``, in report order."""

ENTRY_POINT_GROUP = "cellplan.packages"
"""Entry-point group through which an installed distribution adds a package."""


# --- scenarios -------------------------------------------------------------------------------


def scenario_names() -> list[str]:
    """Names of the bundled scenarios, sorted."""
    return sorted(p.stem for p in BUNDLED_DIR.glob("*.yaml"))


def scenario_path(name: str) -> Path:
    """Path of a bundled scenario by name."""
    path = BUNDLED_DIR / f"{name}.yaml"
    if not path.is_file():
        known = ", ".join(scenario_names())
        hint = _did_you_mean(name, scenario_names())
        raise ScenarioError([Problem(name, f"no such bundled scenario{hint} (known: {known})")])
    return path


def resolve_scenario_path(path_or_name: str | Path) -> Path:
    """A file path as given, or a bundled scenario's path when only a name is given."""
    if not str(path_or_name).strip():
        raise ScenarioError(
            [Problem("SCENARIO", "is empty; give a scenario file or a bundled scenario's name")]
        )
    path = Path(path_or_name)
    if path.is_file():
        return path
    if path.is_dir():
        raise ScenarioError([Problem(str(path_or_name), "is a folder, not a scenario file")])
    if path.exists():  # a device, a FIFO or a socket, or a link to one: never read
        what = kind_of(path.stat().st_mode)
        raise ScenarioError([Problem(str(path_or_name), f"is {what}, not a scenario file")])
    if path.suffix == "" and path.parent == Path("."):
        return scenario_path(str(path))
    raise ScenarioError([Problem(str(path_or_name), "no such file")])


# --- packages and planners -------------------------------------------------------------------


@functools.cache
def packages() -> dict[str, Package]:
    """Every registered package by name: the built-in ones, then entry points."""
    found: list[Package] = []
    for module_name in BUILTIN_PACKAGES:
        found.append(importlib.import_module(module_name).PACKAGE)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        pkg = ep.load()
        if not isinstance(pkg, Package):
            raise TypeError(f"entry point {ep.name!r} of {ENTRY_POINT_GROUP} is not a Package")
        found.append(pkg)
    out: dict[str, Package] = {}
    sections: dict[str, str] = {}
    for pkg in found:
        if pkg.name in out:
            raise RuntimeError(f"package {pkg.name!r} registered twice")
        if pkg.section is not None:
            if pkg.section in sections:
                raise RuntimeError(
                    f"section {pkg.section!r} claimed by {sections[pkg.section]} and {pkg.name}"
                )
            sections[pkg.section] = pkg.name
        out[pkg.name] = pkg
    return out


def sections() -> dict[str, Any]:
    """Scenario section key -> its pydantic model, for every package that has one."""
    return {
        p.section: p.section_model
        for p in packages().values()
        if p.section is not None and p.section_model is not None
    }


@functools.cache
def planners() -> dict[str, PlannerSpec]:
    """All registered planners by name, in package order."""
    out: dict[str, PlannerSpec] = {}
    for pkg in packages().values():
        for spec in pkg.planners:
            if spec.name in out:
                raise RuntimeError(f"planner {spec.name!r} registered twice")
            if spec.package != pkg.name:
                raise RuntimeError(f"planner {spec.name!r} names package {spec.package!r}")
            out[spec.name] = spec
    return out


def planner(name: str) -> PlannerSpec:
    """The planner registered as ``name``; an :class:`ArgumentError` (with a suggestion) if none."""
    known = planners()
    if name not in known:
        hint = _did_you_mean(name, list(known))
        raise ArgumentError(
            [Problem("planner", f"unknown planner {name!r}{hint} (known: {', '.join(known)})")]
        )
    return known[name]


def parse_options(spec: PlannerSpec, given: dict[str, Any], flag: bool = False) -> Options:
    """Validate options for ``spec``: one problem per unknown or bad option.

    ``flag=True`` names options as command-line flags (``--max-sweeps``) in the problems.
    """

    def label(key: str) -> str:
        return "--" + key.replace("_", "-") if flag else key

    known = list(spec.options.model_fields)
    problems = []
    for key in given:
        if key not in known:
            hint = _did_you_mean(key, known)
            problems.append(
                Problem(
                    label(key),
                    f"unknown option for {spec.name}{hint} (options: {', '.join(known) or 'none'})",
                )
            )
    if problems:
        raise ArgumentError(problems)
    try:
        return spec.options.model_validate(given)
    except ValidationError as exc:
        problems = []
        for err in exc.errors(include_url=False):
            key = str(err["loc"][0]) if err["loc"] else ""
            msg = err["msg"]
            for prefix in ("Value error, ", "Assertion failed, "):
                msg = msg.removeprefix(prefix)
            value = given.get(key, None)
            problems.append(Problem(label(key), f"{msg} (got {value!r})"))
        raise ArgumentError(problems) from None


def _did_you_mean(name: str, choices: list[str]) -> str:
    close = difflib.get_close_matches(name, choices, n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""
