"""Issue 13: periodic joints, capsule links, S's fallback starts, the check budget,
no database file for a scenario that fails its checks, reasons in failure messages."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import cellplan
from cellplan import units
from cellplan.adaptive.experience import ExperiencePlanner
from cellplan.adaptive.reach import path_is_free, reach
from cellplan.adaptive.solve import SolveInfo, solve_rrtconnect
from cellplan.adaptive.space import PlanSpace
from cellplan.errors import ScenarioError
from cellplan.scenario import load_scenario

ARM_WRAP = Path(__file__).parent / "data" / "arm_wrap.yaml"


def blocked_at_zero(Q: np.ndarray) -> np.ndarray:
    """Joint 1 may not pass through 0 (|q1| < 0.5 is blocked); joint 2 is free."""
    return np.abs(np.atleast_2d(Q)[:, 0]) >= 0.5


def circle_space(periodic: bool) -> PlanSpace:
    lo, hi = np.full(2, -np.pi), np.full(2, np.pi)
    return PlanSpace(blocked_at_zero, lo, hi, 0.02, periodic=(periodic, periodic))


def test_reach_takes_the_short_way_round_a_periodic_joint():
    a, b = np.array([3.0, 0.2]), np.array([-3.0, -0.2])
    space = circle_space(True)
    assert reach(space, a, b)
    # the short way is 0.49 rad long: 25 steps of 0.02 (the long way would be 300)
    assert space.counter.total == 26
    np.testing.assert_allclose(space.distance(a, b[None])[0], np.hypot(2 * np.pi - 6, 0.4))
    assert not reach(circle_space(False), a, b)


def test_solve_crosses_pi_on_a_periodic_space_and_not_on_an_interval():
    a, b = np.array([2.0, 1.0]), np.array([-2.0, -1.0])
    space = circle_space(True)
    path = solve_rrtconnect(space, a, b, seed=3, max_checks=20_000)
    assert path is not None
    steps = space.unwrap(path)
    assert np.all(np.abs(np.diff(steps[:, 0])) <= np.pi)
    # it went through +-pi (joint 1 ends a turn up, at -2 + 2 pi), never through 0
    assert steps[-1, 0] == pytest.approx(2 * np.pi - 2.0)
    assert steps[:, 0].min() >= 0.5
    assert path_is_free(space, path, refine=4)
    info = SolveInfo()
    assert solve_rrtconnect(circle_space(False), a, b, 3, max_checks=3_000, info=info) is None
    assert info.outcome == "budget" and 3_000 <= info.checks <= 3_100


def test_the_wall_time_guard_is_reported(wall_space):
    info = SolveInfo()
    a, b = np.array([1.0, 1.0]), np.array([9.0, 1.0])
    path = solve_rrtconnect(wall_space, a, b, 0, 10**6, 0.0, info=info)
    assert path is None and info.outcome == "time"


def test_arm_wrap_reaches_goals_only_through_the_wrap():
    setup = cellplan.load(ARM_WRAP)
    result = cellplan.plan(setup, "adaptive", tasks=10, seed=0)
    assert result.status == "solved", result.message
    assert result.stats["paths_ok"] == 10
    planner = result.solution
    lower = {g for g, q in planner.goals.items() if q[0] < 0}
    assert lower & {r["goal"] for r in planner.tasks}  # some task went below the wall
    q = result.trajectory.q
    # executed paths are continuous on the circle: no step longer than half a turn, and
    # joint 1 goes past +-180 degrees rather than through 0 (the wall)
    steps = np.diff(q, axis=0)
    same_task = np.abs(steps).max(axis=1) < np.pi
    assert same_task.sum() >= len(steps) - 10
    assert np.any(np.abs(q[:, 0]) > np.pi - 0.1)


def _interval_arm_wrap(budget: int):
    """arm_wrap with limits of 359.9 degrees: joints become intervals (the issue's bug)."""
    sc = load_scenario(ARM_WRAP)
    robot = sc.robot.model_copy(update={"joint_limits": [(-180.0, 179.9), (-180.0, 179.9)]})
    sec = sc.adaptive.model_copy(update={"max_solve_checks": budget, "tasks": ["g5"]})
    return sc.model_copy(update={"robot": robot, "adaptive": sec})


def test_interval_joints_cannot_reach_below_the_wall_and_say_why():
    result = cellplan.plan(_interval_arm_wrap(4_000), "adaptive", tasks=1)
    assert result.status == "failed"
    assert "task 1: Solve found no path from 1 start vertex of G in 4 calls within its " in (
        result.message
    )
    assert "check budget (" in result.message and "budget 4000)" in result.message
    # the same goal with periodic joints
    ep = ExperiencePlanner(ARM_WRAP)
    assert ep.plan(None, "g5").status == "solved"


def test_a_periodic_start_is_wrapped():
    ep = ExperiencePlanner(ARM_WRAP)
    q = ep.goals["g2"] - np.array([2 * np.pi, 0.0])  # the same arm, a turn further
    res = ep.plan(q, "g3")
    assert res.status == "solved"
    np.testing.assert_allclose(res.trajectory.q[0], ep.goals["g2"], atol=1e-12)


POCKET = """
cellplan: 1
name: pocket
workcell:
  bounds: {xmin: 0, ymin: 0, xmax: 10, ymax: 10}
  obstacles:
    wall: {type: box, min: [4.5, 0.0], max: [5.5, 8.0]}
robot: {type: point, start: [1.0, 1.0]}
adaptive:
  resolution: 0.1
  max_solve_checks: 8000
  goals:
    home: {at: [1.0, 1.0]}
  tasks: [home]
"""

RING = {
    "ring_s": {"type": "box", "min": [7.5, 4.0], "max": [9.5, 4.2]},
    "ring_n": {"type": "box", "min": [7.5, 5.8], "max": [9.5, 6.0]},
    "ring_w": {"type": "box", "min": [7.5, 4.0], "max": [7.7, 6.0]},
    "ring_e": {"type": "box", "min": [9.3, 4.0], "max": [9.5, 6.0]},
}


def test_s_tries_the_next_start_when_the_best_vertex_is_sealed_in(tmp_path):
    path = tmp_path / "pocket.yaml"
    path.write_text(POCKET)
    ep = ExperiencePlanner(cellplan.load(path))
    ep.adapter.new_vertex(np.array([8.5, 5.0]))  # a subgoal G holds from earlier work
    for name, shape in RING.items():  # ... which a change now seals in
        ep.add(name, shape)
    res = ep.plan(None, [9.0, 3.0])
    assert res.status == "solved", res.message
    assert res.stats["s_fallbacks"] >= 1
    # the sealed start only ever got bounded shares of the budget
    assert res.stats["solve_checks"] < 8000 / 2
    assert res.trajectory.q[0].tolist() == [1.0, 1.0]


POINT_POCKET = Path(__file__).parent / "data" / "point_pocket.yaml"


def test_seeded_run_recovers_from_the_sealed_pocket_and_records_it():
    # seed 3: task 13 is the first to gB after the ring sealed gA's vertex; with one
    # start and the whole budget S burnt 200,000 checks there and skipped the task
    result = cellplan.plan(cellplan.load(POINT_POCKET), "adaptive", tasks=13, seed=3)
    assert result.status == "solved", result.message
    row = result.solution.tasks[12]
    assert row["goal"] == "gB" and row["success"] == 1 and row["s_fallbacks"] >= 1
    assert row["solve"] < 200_000 / 16
    assert result.stats["s_fallbacks"] == row["s_fallbacks"]


def test_a_scenario_that_fails_its_checks_creates_no_database(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(POCKET.replace("home: {at: [1.0, 1.0]}", "home: {at: [5.0, 1.0]}"))
    db = tmp_path / "exp.sqlite"
    with pytest.raises(ScenarioError, match=r"collides with .* obstacle 'wall'"):
        cellplan.plan(cellplan.load(bad), "adaptive", db=str(db))
    assert not db.exists()
    good = tmp_path / "good.yaml"
    good.write_text(POCKET)
    result = cellplan.plan(cellplan.load(good), "adaptive", db=str(db))
    assert result.status == "solved" and db.exists()


def test_degrees_come_from_the_units_module():
    # the scenario writes 1 degree; the planner works in radians
    ep = ExperiencePlanner(ARM_WRAP)
    assert ep.settings.resolution == units.radians(1.0)
