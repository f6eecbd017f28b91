"""The short summary printed by ``cellplan validate``."""

from __future__ import annotations

from cellplan.scenario import Scenario, robot_dimension
from cellplan.workcell import Workcell


def assembly_modes(sc: Scenario) -> int:
    """2PSD + 1 assembly modes (strategies paper, Section III-A), all requests allowed."""
    return 2 * len(sc.parts) * len(sc.sources) * len(sc.destinations) + 1


def summarize(sc: Scenario, cell: Workcell | None) -> dict[str, str]:
    """Key facts of a validated scenario (and its workcell model, when it has a robot)."""
    from cellplan.cspace import Grid, free_bitmap

    b = sc.workcell.bounds
    out = {
        "scenario": sc.name or "(unnamed)",
        "workcell": f"[{b.xmin:g}, {b.xmax:g}] x [{b.ymin:g}, {b.ymax:g}], "
        f"{len(sc.workcell.obstacles)} obstacles",
        "sections": ", ".join(sc.section_names()) or "none",
    }
    if sc.discs is not None:
        d = sc.discs
        if d.discs is not None:
            out["discs"] = f"{len(d.discs)} listed, boundary {d.boundary.type}, k = {d.k:g}"
        elif d.generate is not None:
            g = d.generate
            out["discs"] = (
                f"{g.n} generated (seed {g.seed}, {g.pattern} goals, {g.starts} starts), "
                f"boundary {d.boundary.type}, k = {d.k:g}"
            )
    if sc.robot is None or cell is None:
        return out
    regions = lambda rs: ", ".join(f"{n} ({len(r.components)})" for n, r in rs.items()) or "none"  # noqa: E731
    out |= {
        "robot": sc.robot.type,
        "C-space dimension": str(robot_dimension(sc.robot)),
        "parts": ", ".join(sc.parts) or "none",
        "sources (components)": regions(sc.sources),
        "destinations (components)": regions(sc.destinations),
        "assembly modes": str(assembly_modes(sc)),
    }
    grid = Grid.for_robot(cell.robot, cell.default_cells)
    free = free_bitmap(cell, grid)
    shape = " x ".join(str(n) for n in grid.shape)
    out["free fraction"] = f"{free.mean():.3f} (empty robot, NR mode, {shape} cells, conservative)"
    return out
