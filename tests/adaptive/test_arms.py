"""Adapt on URDF arms in 3-D cells (issue 31): the UR5 of ``adaptive_ur5``, the Panda of
``panda_shelf``. Oracles: forward kinematics for goals and attached subgoals, the exact
(no clearance) check at a 16x finer resolution for certified Reach segments."""

from __future__ import annotations

import functools

import numpy as np
import pytest

import cellplan
from cellplan.adaptive.experiments3d import scenario as ur5_scenario
from cellplan.adaptive.peers import run_peer
from cellplan.adaptive.reach import reach, segment_points
from cellplan.adaptive.space import PlanSpace
from cellplan.adaptive.world import make_world
from cellplan.adaptive.world3d import World3D
from cellplan.errors import ArgumentError, ScenarioError
from cellplan.registry import scenario_path
from cellplan.scenario import load_scenario, parse_yaml, scenario_from_data
from cellplan.setup import Setup


@functools.cache
def ur5_world() -> World3D:
    world = make_world(cellplan.load("adaptive_ur5"), np.radians(1.0))
    assert isinstance(world, World3D)
    return world


def test_goal_configurations_put_the_tool_on_the_goal_pose():
    """Each named goal's IK configuration reaches its tool position, pointing down (FK)."""
    world = ur5_world()
    sec = world.section
    assert sec is not None and len(sec.goals) == 9
    for name, goal in sec.goals.items():
        q = world.goal_config(name)
        assert q is not None, name
        tool = world.robot.tool_pose(q[None, :])[0]
        np.testing.assert_allclose(tool[:3, 3], goal.at, atol=1e-3)
        np.testing.assert_allclose(tool[:3, 2], [0.0, 0.0, -1.0], atol=1e-2)
        assert world.is_free(q[None, :])[0]


def test_reach_on_the_ur5_is_certified_between_its_samples():
    """Every segment Reach accepts is free (exact check) at 1/16 of its resolution."""
    world = ur5_world()
    res = np.radians(1.0)
    space = PlanSpace(world.is_free, world.robot.lower, world.robot.upper, res)
    rng = np.random.default_rng(3)
    goals = [world.goal_config(n) for n in sorted(world.goals)]
    accepted = 0
    for _ in range(12):
        i, j = rng.choice(len(goals), 2, replace=False)
        a, b = goals[i], goals[j]
        # A random bend keeps the pairs varied (some segments blocked, some free).
        b = b + rng.normal(0.0, 0.2, size=b.shape)
        if not reach(space, a, b):
            continue
        accepted += 1
        fine = segment_points(a, b, res / 16, space)
        assert not world.workcell().collides(fine, avoid_sources="none").any()
    assert accepted >= 3


def test_subgoals_follow_a_moved_fixture_by_inverse_kinematics():
    """Section 2.3: after the fixture moves, its goals and the vertices attached to it
    come back by IK seeded from their old configuration (FK oracle), and plans go on."""
    planner = cellplan.ExperiencePlanner(cellplan.load("adaptive_ur5"), seed=0)
    first = planner.plan(None, "f1")
    assert first.success
    attached = [v.id for v in planner.graph.vertices.values() if v.obj == "fixture"]
    before = {vid: planner.world.tool(planner.graph.vertices[vid].q) for vid in attached}
    goal_before = planner.world.tool(planner.goals["f1"])
    planner.move("fixture", (-0.1, 0.0, 0.0))
    goal_after = planner.world.tool(planner.goals["f1"])
    np.testing.assert_allclose(np.subtract(goal_after, goal_before), [-0.1, 0.0, 0.0], atol=1e-3)
    for vid in attached:
        if vid in planner.graph.vertices:  # dropped when no free IK solution remains
            moved = planner.world.tool(planner.graph.vertices[vid].q)
            np.testing.assert_allclose(np.subtract(moved, before[vid]), [-0.1, 0, 0], atol=1e-3)
    again = planner.plan(None, "f1")
    assert again.success and again.stats["generation"] == 1.0


@pytest.mark.parametrize("repair", ["A2", pytest.param("A0", marks=pytest.mark.slow), "A1", "A3"])
def test_repair_strategies_run_on_the_ur5_through_a_change(repair):
    """A0-A3 (Section 2.5) across the crate and the fixture move: every task solved, every
    executed path free at the 4x finer exact re-check."""
    setup = Setup(ur5_scenario(5, 2, 1), "adaptive_ur5")
    result = cellplan.plan(setup, "adaptive", repair=repair, seed=1, baseline=False)
    assert result.success, result.message
    rows = result.solution.tasks
    assert len(rows) == 5
    assert all(r["path_ok"] == 1 for r in rows)
    assert rows[2]["generation"] == 2  # two changes after task 2


def test_a_repeated_task_costs_no_collision_check():
    """R's memory and T's generation stamps: a repeated query is answered through G."""
    planner = cellplan.ExperiencePlanner(cellplan.load("adaptive_ur5"), seed=0)
    planner.plan(None, "a1")
    planner.plan(None, "b2")
    planner.plan(None, "a1")
    again = planner.plan(None, "b2")
    assert again.success
    assert again.stats["checks"] <= 2
    assert again.stats["solve_calls"] == 0


def test_a_tool_pose_goal_is_solved_and_an_unreachable_one_refused_in_one_line():
    planner = cellplan.ExperiencePlanner(cellplan.load("adaptive_ur5"), seed=0)
    target = planner.world.robot.tool_pose(planner.goals["f2"][None, :])[0]
    result = planner.plan(None, target)
    assert result.success
    reached = planner.world.robot.tool_pose(result.trajectory.q[-1][None, :])[0]
    np.testing.assert_allclose(reached[:3, 3], target[:3, 3], atol=1e-3)
    far = target.copy()
    far[:3, 3] = [1.05, 0.85, 1.75]  # inside the bounds, beyond the UR5's reach
    checks = planner.counter.total
    with pytest.raises(ArgumentError) as err:
        planner.plan(None, far)
    assert len(str(err.value).splitlines()) == 1
    assert "no collision-free inverse-kinematics solution" in str(err.value)
    assert planner.counter.total == checks  # refused before any counted work


def _ur5_data() -> dict:
    return parse_yaml(scenario_path("adaptive_ur5").read_text())


def test_an_unreachable_goal_pose_is_refused_before_work():
    data = _ur5_data()
    data["adaptive"]["goals"]["a1"]["at"] = [1.0, 0.8, 1.7]
    setup = Setup(scenario_from_data(data), "adaptive_ur5")
    with pytest.raises(ScenarioError) as err:
        cellplan.plan(setup, "adaptive", tasks=2)
    lines = str(err.value).splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("adaptive.goals.a1: no collision-free inverse-kinematics")


def test_planar_coordinates_in_a_3d_cell_are_one_line_each():
    data = _ur5_data()
    data["adaptive"]["goals"]["a1"]["at"] = [0.4, -0.3]
    data["adaptive"]["changes"][1]["by"] = [0.1, 0.0]
    with pytest.raises(ScenarioError) as err:
        scenario_from_data(data)
    fields = sorted(p.field for p in err.value.problems)
    assert fields == ["adaptive.changes[1].by", "adaptive.goals.a1.at"]


def test_panda_experience_is_kept_in_the_store(tmp_path):
    """A 7-joint Panda: plan(start, goal), then a new session on the same database answers
    the repeated query through the saved graph."""
    setup = cellplan.load("panda_shelf")
    db = tmp_path / "panda.sqlite"
    with cellplan.ExperiencePlanner(setup, db=db, seed=0) as planner:
        start = planner.position
        goal = start + np.array([0.5, 0.3, -0.2, 0.3, 0.2, -0.3, 0.4])
        first = planner.plan(start, goal)
        assert first.success, first.message
        np.testing.assert_allclose(first.trajectory.q[-1], goal)
        size = len(planner.graph)
    with cellplan.ExperiencePlanner(setup, db=db, seed=0) as planner:
        assert len(planner.graph) == size
        again = planner.plan(start, goal)
        assert again.success
        assert again.stats["checks"] <= 2 and again.stats["solve_calls"] == 0
        planner.move("shelf_high", (0.0, 0.0, 0.02))
        moved = planner.plan(start, goal)
        assert moved.success and moved.stats["generation"] == 1.0
    with cellplan.ExperiencePlanner(setup, db=db, seed=0) as planner:
        assert planner.pose("shelf_high") == (0.0, 0.0, 0.02)


def test_peers_run_on_the_ur5_with_wall_times():
    sc = ur5_scenario(3, 40, 0)
    rows = run_peer(sc, "rrtconnect")
    assert [r["task"] for r in rows] == [1, 2, 3]
    assert all(r["success"] == 1.0 and r["checks"] > 0 and r["seconds"] > 0 for r in rows)


def test_bundled_scenario_loads_with_nine_goals_and_the_change_after_task_40():
    sc = load_scenario(scenario_path("adaptive_ur5"))
    assert sc.adaptive is not None
    assert len(sc.adaptive.goals) == 9
    assert {c.after_task for c in sc.adaptive.changes} == {40}


def _with_solve(name: str, solve: str) -> Setup:
    data = parse_yaml(scenario_path(name).read_text())
    data["adaptive"]["solve"] = solve
    return Setup(scenario_from_data(data), name)


def test_solve_is_any_single_threaded_ompl_planner_by_name():
    result = cellplan.plan(_with_solve("adaptive_fig4", "ompl.RRT"), "adaptive", tasks=6, seed=0)
    assert result.success, result.message
    assert result.stats["solve_calls"] >= 1


@pytest.mark.parametrize(
    ("solve", "why"), [("ompl.NoSuchPlanner", "has no planner"), ("ompl.PRM", "second thread")]
)
def test_an_unusable_ompl_planner_is_refused_in_one_line(solve, why):
    with pytest.raises(ScenarioError) as err:
        cellplan.plan(_with_solve("adaptive_fig4", solve), "adaptive", tasks=2)
    lines = str(err.value).splitlines()
    assert len(lines) == 1 and lines[0].startswith("adaptive.solve: ") and why in lines[0]


def test_objects_are_added_and_removed_in_a_3d_cell():
    planner = cellplan.ExperiencePlanner(cellplan.load("adaptive_ur5"), seed=0)
    assert planner.plan(None, "f1").success
    planner.add(
        "post",
        {"type": "cylinder", "radius": 0.04, "length": 0.3, "pose": {"xyz": [-0.5, 0.5, 0.9]}},
    )
    assert "post" in planner.world.objects and planner.world.gen == 1
    with pytest.raises(ArgumentError) as err:
        planner.add("bad", {"type": "box", "min": [0, 0], "max": [1, 1]})
    assert str(err.value).startswith("shape: ")
    with pytest.raises(ArgumentError):
        planner.move("post", (0.1, 0.0))  # 3-D objects take (x, y, z)
    assert planner.plan(None, "a1").success
    planner.remove("post")
    assert planner.world.gen == 2 and planner.plan(None, "f1").success
