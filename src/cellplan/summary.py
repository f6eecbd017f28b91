"""The short summary printed by ``cellplan validate``.

The core facts describe the workcell; each registered package whose section the scenario
has adds its own through :attr:`cellplan.core.Package.describe`. Each is a
:class:`~cellplan.core.Fact`: a machine key and a typed value for ``validate --json``,
a label and a text for a person.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from cellplan.core import Fact, Progress
from cellplan.registry import packages
from cellplan.scenario import robot_dimension
from cellplan.scenario3d import Bounds3, UrdfRobotSpec
from cellplan.setup import Setup

__all__ = ["Fact", "facts", "slug", "summarize"]


def summarize(setup: Setup, progress: Progress | None = None) -> dict[str, str]:
    """The facts of :func:`facts` as ``{label: text}``, the lines ``validate`` prints."""
    return {f.label: f.text for f in facts(setup, progress)}


def facts(setup: Setup, progress: Progress | None = None) -> list[Fact]:
    """Key facts of a validated scenario: its workcell model, when it has a robot, and the
    facts of every package whose section it has (which may run that package's checks).

    ``progress(done, total, text)``, if given, hears which check is running: a package's
    checks can take minutes (the strategies model of a large scenario is built in full).
    """
    sc = setup.scenario
    sections = [
        pkg
        for pkg in packages().values()
        if pkg.section in sc.section_names() and pkg.describe is not None
    ]
    steps = 1 + len(sections)

    b = sc.workcell.bounds
    extent = f"[{b.xmin:g}, {b.xmax:g}] x [{b.ymin:g}, {b.ymax:g}]"
    bounds = {"xmin": b.xmin, "xmax": b.xmax, "ymin": b.ymin, "ymax": b.ymax}
    if isinstance(b, Bounds3):
        extent += f" x [{b.zmin:g}, {b.zmax:g}] m"
        bounds |= {"zmin": b.zmin, "zmax": b.zmax}
    n_obstacles = len(sc.workcell.obstacles)
    names = list(sc.section_names())
    out = [
        Fact("scenario", "scenario", sc.name, sc.name or "(unnamed)"),
        Fact(
            "workcell",
            "workcell",
            {"bounds": {k: float(v) for k, v in bounds.items()}, "obstacles": n_obstacles},
            f"{extent}, {n_obstacles} obstacle{'' if n_obstacles == 1 else 's'}",
        ),
        Fact("sections", "sections", names, ", ".join(names) or "none"),
    ]
    if sc.robot is not None:
        if progress is not None:
            progress(0, steps, "the workcell's free space")
        out += _workcell_facts(setup)
    for i, pkg in enumerate(sections):
        if progress is not None:
            progress(1 + i, steps, f"the {pkg.section} section's checks")
        assert pkg.describe is not None
        out += package_facts(pkg.describe(setup))
    return out


def package_facts(given: Sequence[Fact] | Mapping[str, str]) -> list[Fact]:
    """A package's ``describe`` answer as facts; the legacy ``{label: text}`` form becomes
    facts keyed by the label slugged, with the text as value."""
    if isinstance(given, Mapping):
        return [Fact(slug(label), label, text, text) for label, text in given.items()]
    return list(given)


def slug(label: str) -> str:
    """A label as a machine key: ``"repair / Solve / Reach"`` -> ``"repair_solve_reach"``."""
    return "_".join(re.findall(r"[a-z0-9]+", label.lower())) or "value"


def _workcell_facts(setup: Setup) -> list[Fact]:
    """Robot, C-space and free fraction; parts, sources and destinations only where the
    scenario has them (an adaptive scenario has none, and "none" lines say nothing)."""
    from cellplan.cspace import Grid, check_memory, free_bitmap

    sc, cell = setup.scenario, setup.workcell
    assert sc.robot is not None  # a workcell exists only with a robot

    def regions(key: str, label: str, found: Mapping[str, Any]) -> Fact:
        counts = {n: len(r.components) for n, r in found.items()}
        return Fact(key, label, counts, ", ".join(f"{n} ({c})" for n, c in counts.items()))

    dim = robot_dimension(sc.robot)
    # The robot as {"type", "joints"} (and "urdf" for a URDF arm): one shape for every kind.
    axes = list(cell.robot.axis_names)
    robot = Fact("robot", "robot", {"type": sc.robot.type, "joints": axes}, sc.robot.type)
    if isinstance(sc.robot, UrdfRobotSpec):
        text = f"{sc.robot.type} ({sc.robot.urdf}), joints {', '.join(axes)}"
        robot = Fact("robot", "robot", robot.value | {"urdf": str(sc.robot.urdf)}, text)
    out = [robot, Fact("dimension", "C-space dimension", int(dim), str(dim))]
    if isinstance(sc.robot, UrdfRobotSpec):
        out.append(Fact("collision_geometry", "collision geometry", cell.geometry, cell.geometry))
    if sc.parts:
        out.append(Fact("parts", "parts", list(sc.parts), ", ".join(sc.parts)))
    if sc.sources:
        out.append(regions("sources", "sources (components)", cell.sources))
    if sc.destinations:
        out.append(regions("destinations", "destinations (components)", cell.destinations))
    if cell.robot.dim > 3:
        # No bitmap beyond three joints (48^6 cells): a sampled fraction instead.
        rng = np.random.default_rng(0)
        fraction = float(cell.free(cell.sample(_SAMPLES, rng)).mean())
        how = f"empty robot, {_SAMPLES} random configurations, conservative"
        out.append(Fact("free_fraction", "free fraction", fraction, f"{fraction:.3f} ({how})"))
        return out + _reachability(cell)
    grid = Grid.for_robot(cell.robot, cell.default_cells)
    check_memory(cell, grid, field="cspace.cells" if sc.cspace.cells else "default cells")
    fraction = float(free_bitmap(cell, grid).mean())
    shape = " x ".join(str(n) for n in grid.shape)
    sources = ", sources as obstacles" if sc.sources else ""
    how = f"empty robot{sources}, {shape} cells, conservative"
    out.append(Fact("free_fraction", "free fraction", fraction, f"{fraction:.3f} ({how})"))
    if cell.dimension == 3:
        out += _reachability(cell)
    return out


_SAMPLES = 4000
"""Random configurations behind the free fraction of an arm with more than three joints."""


def _reachability(cell: Any) -> list[Fact]:
    """Whether inverse kinematics puts the tool in each region's components collision-free
    (:meth:`cellplan.workcell3d.Workcell3D.reach_region`): per region, ``{"reached": ok,
    "components": total}``."""
    names = [*cell.sources, *cell.destinations]
    if not names:
        return []
    value = {}
    for name in names:
        found = cell.reach_region(name)
        value[name] = {"reached": sum(q is not None for q in found), "components": len(found)}
    text = ", ".join(f"{n} {v['reached']}/{v['components']}" for n, v in value.items())
    return [Fact("reachable", "reachable (components)", value, text)]
