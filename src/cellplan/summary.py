"""The short summary printed by ``cellplan validate``.

The core lines describe the workcell; each registered package whose section the scenario
has adds its own lines through :attr:`cellplan.core.Package.describe`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cellplan.core import Progress
from cellplan.registry import packages
from cellplan.scenario import robot_dimension
from cellplan.scenario3d import Bounds3, UrdfRobotSpec
from cellplan.setup import Setup


def summarize(setup: Setup, progress: Progress | None = None) -> dict[str, str]:
    """Key facts of a validated scenario: its workcell model, when it has a robot, and the
    lines of every package whose section it has (which may run that package's checks).

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
    if isinstance(b, Bounds3):
        extent += f" x [{b.zmin:g}, {b.zmax:g}] m"
    out = {
        "scenario": sc.name or "(unnamed)",
        "workcell": f"{extent}, "
        f"{len(sc.workcell.obstacles)} obstacle{'' if len(sc.workcell.obstacles) == 1 else 's'}",
        "sections": ", ".join(sc.section_names()) or "none",
    }
    if sc.robot is not None:
        if progress is not None:
            progress(0, steps, "the workcell's free space")
        out |= _workcell_lines(setup)
    for i, pkg in enumerate(sections):
        if progress is not None:
            progress(1 + i, steps, f"the {pkg.section} section's checks")
        assert pkg.describe is not None
        out |= dict(pkg.describe(setup))
    return out


def _workcell_lines(setup: Setup) -> dict[str, str]:
    """Robot, C-space and free fraction; parts, sources and destinations only where the
    scenario has them (an adaptive scenario has none, and "none" lines say nothing)."""
    from cellplan.cspace import Grid, check_memory, free_bitmap

    sc, cell = setup.scenario, setup.workcell
    assert sc.robot is not None  # a workcell exists only with a robot
    regions = lambda rs: ", ".join(f"{n} ({len(r.components)})" for n, r in rs.items())  # noqa: E731
    out = {"robot": sc.robot.type, "C-space dimension": str(robot_dimension(sc.robot))}
    if isinstance(sc.robot, UrdfRobotSpec):
        out["robot"] = f"{sc.robot.type} ({sc.robot.urdf}), joints " + ", ".join(
            cell.robot.axis_names
        )
        out["collision geometry"] = cell.geometry
    if sc.parts:
        out["parts"] = ", ".join(sc.parts)
    if sc.sources:
        out["sources (components)"] = regions(cell.sources)
    if sc.destinations:
        out["destinations (components)"] = regions(cell.destinations)
    if cell.robot.dim > 3:
        # No bitmap beyond three joints (48^6 cells): a sampled fraction instead.
        rng = np.random.default_rng(0)
        free = cell.free(cell.sample(_SAMPLES, rng))
        out["free fraction"] = (
            f"{free.mean():.3f} (empty robot, {_SAMPLES} random configurations, conservative)"
        )
        return out | _reachability(cell)
    grid = Grid.for_robot(cell.robot, cell.default_cells)
    check_memory(cell, grid, field="cspace.cells" if sc.cspace.cells else "default cells")
    free = free_bitmap(cell, grid)
    shape = " x ".join(str(n) for n in grid.shape)
    sources = ", sources as obstacles" if sc.sources else ""
    out["free fraction"] = f"{free.mean():.3f} (empty robot{sources}, {shape} cells, conservative)"
    if cell.dimension == 3:
        out |= _reachability(cell)
    return out


_SAMPLES = 4000
"""Random configurations behind the free fraction of an arm with more than three joints."""


def _reachability(cell: Any) -> dict[str, str]:
    """Whether inverse kinematics puts the tool in each region's components collision-free
    (:meth:`cellplan.workcell3d.Workcell3D.reach_region`)."""
    names = [*cell.sources, *cell.destinations]
    if not names:
        return {}
    parts = []
    for name in names:
        found = cell.reach_region(name)
        ok = sum(q is not None for q in found)
        parts.append(f"{name} {ok}/{len(found)}")
    return {"reachable (components)": ", ".join(parts)}
