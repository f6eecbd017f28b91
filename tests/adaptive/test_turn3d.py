"""Objects of a 3-D adaptive cell turn (issue 31): collision, attached subgoals, validation.

A turn (``rotate_object`` with ``rpy``) displaces an object by a rotation about its
centre; its collision geometry turns (checked against points transformed by hand), and a
subgoal attached to it follows through the object's full pose (Chen, Section 2.3: the
attached tool pose turns with the object, then IK brings the arm back).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

import cellplan
from cellplan import solids
from cellplan.adaptive import store
from cellplan.adaptive.section import RotateObject
from cellplan.adaptive.world3d import World3D
from cellplan.errors import ScenarioError
from cellplan.registry import scenario_path
from cellplan.workcell3d import Workcell3D

RESOLUTION = math.radians(1.0)


def rz(degrees: float) -> np.ndarray:
    a = math.radians(degrees)
    return np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0, 0, 1]])


def turn(obj: str, rpy: tuple[float, float, float], about=None) -> RotateObject:
    return RotateObject(type="rotate_object", after_task=0, object=obj, rpy=rpy, about=about)


@pytest.fixture(scope="module")
def setup() -> cellplan.Setup:
    return cellplan.load("adaptive_ur5")


def world_of(setup: cellplan.Setup) -> World3D:
    cell = setup.workcell
    assert isinstance(cell, Workcell3D)
    return World3D(setup.scenario, cell, RESOLUTION)


def test_a_turned_bar_holds_exactly_the_points_turned_by_hand(setup) -> None:
    world = world_of(setup)
    centre, size = np.array([0.3, 0.5, 1.4]), np.array([0.6, 0.06, 0.04])
    world.add_object("bar", solids.box(size, solids.pose_matrix(centre, (0.0, 0.0, 0.0))))
    world.apply(turn("bar", (0.0, 0.0, 90.0)))
    placed = world.workcell().obstacles["bar"]
    rng = np.random.default_rng(3)
    points = centre + rng.uniform(-1.0, 1.0, size=(4000, 3)) * [0.35, 0.35, 0.03]
    # Oracle: a point lies in the turned bar when, turned back by hand about the centre,
    # it lies in the unturned bar.
    local = (points - centre) @ rz(90.0)  # rows: R^T (p - c)
    margin = np.min(size / 2 - np.abs(local), axis=1)
    inside = margin > 1e-9
    clear = np.abs(margin) > 1e-3  # away from the surface, where both must agree
    d = solids.distances(solids.SolidSet.build([placed]), points)[:, 0]
    assert inside.sum() > 50 and (~inside).sum() > 50
    np.testing.assert_array_equal((d <= 0)[clear], inside[clear])
    # the same points against the unturned bar: a different set
    unturned = solids.box(size, solids.pose_matrix(centre, (0.0, 0.0, 0.0)))
    d0 = solids.distances(solids.SolidSet.build([unturned]), points)[:, 0]
    assert ((d0 <= 0) != (d <= 0)).sum() > 50


def test_a_turned_box_meets_the_arm_where_the_unturned_does_not(setup) -> None:
    world = world_of(setup)
    q = world.goal_config("f2")
    assert q is not None
    tool = np.array(world.tool(q))
    # A bar along x whose centre lies 0.2 m beside the tool in y: clear of the arm;
    # turned 90 degrees about its centre it runs along y through the tool point.
    centre = tool + np.array([0.0, 0.2, 0.0])
    world.add_object("bar", solids.box((0.6, 0.03, 0.03), solids.pose_matrix(centre, (0, 0, 0))))
    assert world.hits(q) == []
    world.apply(turn("bar", (0.0, 0.0, 90.0)))
    # by hand: the tool point lies inside the turned bar
    local = rz(90.0).T @ (tool - centre)
    assert np.all(np.abs(local) <= np.array([0.3, 0.015, 0.015]))
    assert world.hits(q) == ["bar"]


def test_a_subgoal_attached_to_a_turning_object_follows_its_full_pose(setup) -> None:
    world = world_of(setup)
    q = world.goal_config("f2")
    assert q is not None
    tag = world.tag_of(q)  # a vertex's tag: attached to the nearest object
    assert tag.obj == "fixture" and tag.rot is None
    before = world.robot.tool_pose(q[None, :])[0]
    centre = np.array([0.45, 0.40, 0.79])  # the fixture's, from the scenario file
    world.apply(turn("fixture", (0.0, 0.0, 90.0)))
    q_new = world.config_of(tag, q)
    assert q_new is not None
    after = world.robot.tool_pose(q_new[None, :])[0]
    # by hand: the tool pose turned 90 degrees about the fixture's centre
    np.testing.assert_allclose(
        after[:3, 3], centre + rz(90.0) @ (before[:3, 3] - centre), atol=1e-4
    )
    np.testing.assert_allclose(after[:3, :3], rz(90.0) @ before[:3, :3], atol=1e-4)
    np.testing.assert_allclose(after[:3, 3], [0.50, 0.35, 1.05], atol=1e-4)  # f2 was (0.40, 0.35)
    # the named goal (its orientation given: tool down) turns with it too
    goal = world.goal_config("f2")
    assert goal is not None
    pose = world.robot.tool_pose(goal[None, :])[0]
    np.testing.assert_allclose(pose[:3, 3], [0.50, 0.35, 1.05], atol=1e-4)
    down = np.diag([1.0, -1.0, -1.0])
    np.testing.assert_allclose(pose[:3, :3], rz(90.0) @ down, atol=1e-4)


def test_a_turn_about_a_point_and_a_shift_compose(setup) -> None:
    world = world_of(setup)
    world.apply(turn("fixture", (0.0, 0.0, 90.0), about=(0.45, 0.30, 0.79)))
    obj = world.objects["fixture"]
    # the centre (0.45, 0.40) turned about (0.45, 0.30) goes to (0.35, 0.30)
    np.testing.assert_allclose(
        world.workcell().obstacles["fixture"].translation, [0.35, 0.30, 0.79]
    )
    world.set_pose("fixture", (obj.pose[0], obj.pose[1], obj.pose[2] + 0.01))
    np.testing.assert_allclose(
        world.workcell().obstacles["fixture"].translation, [0.35, 0.30, 0.80]
    )
    np.testing.assert_allclose(world.workcell().obstacles["fixture"].rotation, rz(90.0), atol=1e-12)


def test_turns_survive_the_store_round_trip(setup) -> None:
    world = world_of(setup)
    world.apply(turn("bin_a", (10.0, 0.0, 30.0)))
    saved = world.objects_json()
    # the database's check of what it reads back: a turn must be a rotation
    assert store._is_objects(saved)
    bad = {n: dict(o) for n, o in saved.items()}
    bad["bin_a"]["turn"] = [2.0, 0, 0, 0, 1, 0, 0, 0, 1]
    assert not store._is_objects(bad)
    other = world_of(setup)
    other.restore_json(saved, world.goals_json(), world.gen)
    for name in world.objects:
        np.testing.assert_allclose(other.objects[name].frame(), world.objects[name].frame())
    assert other.tool_pose_of(other.goals["a1"]) == pytest.approx(
        world.tool_pose_of(world.goals["a1"])
    )


def load_with(changes: list[dict], obstacle_rpy=None) -> ScenarioError:
    data = yaml.safe_load(scenario_path("adaptive_ur5").read_text())
    data["adaptive"]["changes"] = changes
    if obstacle_rpy is not None:
        data["workcell"]["obstacles"]["fixture"]["pose"]["rpy"] = obstacle_rpy
    with pytest.raises(ScenarioError) as info:
        cellplan.loads(yaml.safe_dump(data))
    return info.value


def test_bad_orientations_are_refused_one_line_each() -> None:
    turn_ = {"after_task": 2, "type": "rotate_object", "object": "fixture"}
    err = load_with(
        [turn_, turn_ | {"degrees": 30}, turn_ | {"rpy": [0, 0, 30], "about": [0.1, 0.2]}]
    )
    assert sorted(p.field for p in err.problems) == [
        "adaptive.changes[0].rpy",
        "adaptive.changes[1].degrees",
        "adaptive.changes[1].rpy",
        "adaptive.changes[2].about",
    ]
    assert len(str(err).splitlines()) == len(err.problems)
    # the schema's range (two turns) and finiteness, on a change and on a solid's pose
    err = load_with([turn_ | {"rpy": [0, 0, 400]}])
    assert [p.field for p in err.problems] == ["adaptive.changes[0].rpy[2]"]
    assert "360" in str(err)
    err = load_with([], obstacle_rpy=[0, float("nan"), 0])
    assert [p.field for p in err.problems] == ["workcell.obstacles.fixture.pose.rpy[1]"]


def test_a_planar_turn_still_needs_degrees_and_no_rpy() -> None:
    data = yaml.safe_load(scenario_path("adaptive_fig3").read_text())
    data["adaptive"]["changes"] = [
        {
            "after_task": 1,
            "type": "rotate_object",
            "object": next(iter(data["workcell"]["obstacles"])),
            "rpy": [0, 0, 30],
        }
    ]
    with pytest.raises(ScenarioError) as info:
        cellplan.loads(yaml.safe_dump(data))
    fields = sorted(p.field for p in info.value.problems)
    assert fields == ["adaptive.changes[0].degrees", "adaptive.changes[0].rpy"]


def test_the_viewer_draws_a_turned_object_turned(setup) -> None:
    from cellplan.scene3d import cell_scene

    world = world_of(setup)
    centre, size = np.array([0.3, 0.5, 1.4]), np.array([0.6, 0.06, 0.04])
    world.add_object("bar", solids.box(size, solids.pose_matrix(centre, (0.0, 0.0, 0.0))))
    world.apply(turn("bar", (0.0, 0.0, 90.0)))
    scene = cell_scene(world.workcell())
    (k,) = [i for i, item in enumerate(scene.items) if item.name == "obstacle/bar"]
    pose = scene.poses[0, k]
    drawn = scene.items[k].vertices @ pose[:3, :3].T + pose[:3, 3]
    # by hand: the corners of the bar turned 90 degrees about its centre
    local = (drawn - centre) @ rz(90.0)
    np.testing.assert_allclose(np.abs(local), np.broadcast_to(size / 2, local.shape), atol=1e-9)


def test_a_scheduled_turn_runs_end_to_end_and_the_goal_turns_with_its_object() -> None:
    data = yaml.safe_load(scenario_path("adaptive_ur5").read_text())
    data["adaptive"]["tasks"] = ["f2", "a1", "f2"]
    data["adaptive"]["changes"] = [
        {"after_task": 2, "type": "rotate_object", "object": "fixture", "rpy": [0, 0, 90]}
    ]
    setup = cellplan.loads(yaml.safe_dump(data))
    res = cellplan.plan(setup, "adaptive", repair="A3", seed=0)
    assert res.success
    assert [r["path_ok"] for r in res.solution.tasks] == [1, 1, 1]
    traj = res.trajectory
    assert [e.kind for e in traj.events_of("change")] == ["change"]
    arrivals = traj.events_of("arrive")
    cell = setup.workcell
    assert isinstance(cell, Workcell3D)
    first, last = (cell.robot.tool_pose(traj.q[[e.index]])[0] for e in (arrivals[0], arrivals[-1]))
    np.testing.assert_allclose(first[:3, 3], [0.40, 0.35, 1.05], atol=1e-4)
    # by hand: f2 turned 90 degrees about the fixture's centre (0.45, 0.40), tool still down
    np.testing.assert_allclose(last[:3, 3], [0.50, 0.35, 1.05], atol=1e-4)
    np.testing.assert_allclose(last[:3, :3], rz(90.0) @ first[:3, :3], atol=1e-4)
