"""A fourth planner family in a few lines: the example of docs/architecture.md.

A package declares a scenario section, its options and a run function, and registers
itself (here by the test, through :data:`cellplan.registry.BUILTIN_PACKAGES`; an installed
distribution would use the ``cellplan.packages`` entry point). Nothing in the core changes.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import Field

from cellplan.core import Options, Package, PlannerSpec, Progress, Result, Status
from cellplan.schema import StrictModel, Vec2
from cellplan.setup import Setup
from cellplan.trajectory import Trajectory
from cellplan.units import axis_units


class ToySection(StrictModel):
    """The ``toy:`` section: where a point robot should go."""

    goal: Vec2 = Field(description="goal position (workcell units)")


class StraightOptions(Options):
    """Options of ``toy.straight``."""

    samples: Annotated[int, Field(ge=2, le=10_000)] = Field(
        default=11, description="samples along the segment"
    )


def run_straight(setup: Setup, options: StraightOptions, progress: Progress | None) -> Result:
    """Move the robot along the straight line from its start to the goal, if it is free."""
    cell = setup.workcell
    start = cell.robot.start
    goal = np.array(setup.section("toy").goal, float)
    blocked = bool(cell.motion_collides(start, goal, step=0.05)[0])
    s = np.linspace(0.0, 1.0, options.samples)
    q = start + s[:, None] * (goal - start)
    traj = Trajectory(
        s,
        q,
        np.zeros(len(s), np.int64),
        ("moving",),
        cell.robot.axis_names,
        axis_units(cell.robot.axis_names),
        "path",
    )
    status = Status.INFEASIBLE if blocked else Status.SOLVED
    message = "the straight line is blocked" if blocked else "straight line to the goal"
    return Result(
        status,
        message,
        stats={"length": float(np.linalg.norm(goal - start))},
        solution=q,
        trajectory=traj,
    )


PACKAGE = Package(
    name="toy",
    title="A toy planner family",
    citation="",
    summary="Straight lines for point robots.",
    section="toy",
    section_model=ToySection,
    planners=(
        PlannerSpec(
            "toy.straight",
            "toy",
            "straight line to the goal",
            StraightOptions,
            run_straight,
            section="toy",
        ),
    ),
)
