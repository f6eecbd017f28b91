"""The experience planner's validity holds the carried part (issue 31).

A 3-D query with ``carrying`` is checked with the part attached to the tool in every
step (start and goal, Reach, Solve, the repair, the exact re-check); the oracle here is
independent of the planner: :meth:`Workcell3D.motion_collides` with the part attached at
a 5 mm step (the planner certifies with lever-bound balls at its own resolution).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

import cellplan
from cellplan.assembly.robot import tool_pose
from cellplan.errors import ArgumentError
from cellplan.setup import Setup
from cellplan.workcell3d import Workcell3D

# A block on the table between two hover poses: the bare arm passes over it, a rod held
# 5-25 cm below the tool does not.
CELL = """
cellplan: 2
name: carry_test
workcell:
  units: m
  bounds: {xmin: -0.9, ymin: -0.9, zmin: 0.0, xmax: 1.1, ymax: 0.9, zmax: 1.8}
  obstacles:
    table: {type: box, size: [1.6, 1.4, 0.05], pose: {xyz: [0.25, 0.0, 0.725]}}
    block: {type: box, size: [0.1, 0.3, 0.16], pose: {xyz: [0.65, 0.0, 0.83]}}
robot:
  type: urdf
  urdf: ur5
  base: {xyz: [0.0, 0.0, 0.755]}
  tool: tool0
  start: [0, -90, 90, -90, -90, 0]
parts:
  rod: {shape: {type: cylinder, radius: 0.02, length: 0.2, pose: {xyz: [0, 0, 0.15]}}}
"""
A = tool_pose(np.array([0.65, -0.3]), 0.82, 0.24)
B = tool_pose(np.array([0.65, 0.3]), 0.82, 0.24)
FINE = 0.005  # metres of the cover's travel between the oracle's samples


@functools.cache
def _setup() -> Setup:
    return cellplan.loads(CELL)


def _hits(q: np.ndarray, part: str | None) -> np.ndarray:
    cell = _setup().workcell
    assert isinstance(cell, Workcell3D)
    return cell.motion_collides(q[:-1], q[1:], FINE, carrying=part, avoid_sources="none")


def _to_a_then_b(carrying: str | None) -> cellplan.Result:
    planner = cellplan.ExperiencePlanner(_setup(), seed=0)
    assert planner.plan(None, A).success
    return planner.plan(None, B, carrying=carrying)


def test_a_carried_part_is_kept_off_the_obstacle_the_bare_path_swings_it_into():
    bare = _to_a_then_b(None)
    assert bare.success and bare.trajectory is not None
    assert not np.any(_hits(bare.trajectory.q, None))  # the bare arm is fine ...
    assert np.any(_hits(bare.trajectory.q, "rod"))  # ... the rod it would hold is not
    held = _to_a_then_b("rod")
    assert held.success, held.message
    assert held.trajectory is not None
    assert held.stats["solve_calls"] >= 1  # Reach alone cannot take it across
    assert not np.any(_hits(held.trajectory.q, "rod"))
    cell = _setup().workcell
    assert isinstance(cell, Workcell3D)
    tool = cell.robot.tool_pose(held.trajectory.q[-1:])[0]
    np.testing.assert_allclose(tool[:3, 3], B[:3, 3], atol=1e-3)


def test_holding_another_part_is_a_change_and_the_same_part_is_not():
    planner = cellplan.ExperiencePlanner(_setup(), seed=0)
    gen = planner.world.gen
    planner.plan(None, A, carrying="rod")
    assert planner.world.gen == gen + 1 and planner.world.carrying == "rod"
    planner.plan(None, A, carrying="rod")
    assert planner.world.gen == gen + 1
    planner.plan(None, A)
    assert planner.world.gen == gen + 2 and planner.world.carrying is None


@pytest.mark.parametrize(
    ("carrying", "words"), [("nut", "unknown part 'nut'"), (3, "a part's name or None")]
)
def test_a_bad_part_is_refused_in_one_line(carrying, words):
    planner = cellplan.ExperiencePlanner(_setup(), seed=0)
    with pytest.raises(ArgumentError) as info:
        planner.plan(None, A, carrying=carrying)
    (problem,) = info.value.problems
    assert problem.field == "carrying" and words in problem.message


def test_the_planar_world_refuses_a_carried_part_in_one_line():
    planner = cellplan.ExperiencePlanner(cellplan.load("adaptive_fig3"), seed=0)
    with pytest.raises(ArgumentError) as info:
        planner.plan(None, planner.position, carrying="P1")
    (problem,) = info.value.problems
    assert problem.field == "carrying" and "bare robot" in problem.message
