"""``ExperiencePlanner.turn``: an object turned through the API (issue 31 follow-up).

The oracle is the scenario's own scheduled ``rotate_object`` change: the same turn made
through the API between the same queries gives the same experience graph (vertex for
vertex, bit for bit), the same goals and the same object pose. The attached subgoals'
new poses are also checked against the turn computed by hand, the database round trip
keeps the turn, and bad arguments are refused one line each before anything changes.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from adaptive_scenarios import POINT_SCENARIO
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import cellplan
from cellplan import solids, units
from cellplan.adaptive import ExperiencePlanner
from cellplan.adaptive.section import RotateObject
from cellplan.adaptive.world3d import Object3D
from cellplan.errors import ArgumentError
from cellplan.registry import scenario_path
from cellplan.workcell3d import Workcell3D


def _graph(ep: ExperiencePlanner) -> tuple[object, object]:
    g = ep.graph
    return (
        sorted((v.id, v.obj, v.branch, tuple(v.q.tolist()), v.rel) for v in g.vertices.values()),
        sorted((k, e.status, e.gen) for k, e in g.edges.items()),
    )


def _state(ep: ExperiencePlanner) -> tuple[object, ...]:
    goals = {n: q.tolist() for n, q in ep.goals.items()}
    return _graph(ep), goals, ep.world.objects_json(), ep.position.tolist(), ep.world.gen


def _frame(ep: ExperiencePlanner, name: str) -> np.ndarray:
    obj = ep.world.objects[name]
    assert isinstance(obj, Object3D)
    return obj.frame()


def _rz(radians: float) -> np.ndarray:
    c, s = math.cos(radians), math.sin(radians)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# --- planar: a point robot, box A turned about a point -------------------------------------

PLANAR_TASKS = ["g1", "g2", "home", "g2", "g1"]
"""The turn comes after task 3 (the robot at home, clear of the turned box)."""


def _planar(with_turn: bool) -> cellplan.Setup:
    data = yaml.safe_load(POINT_SCENARIO)
    data["adaptive"]["tasks"] = PLANAR_TASKS
    data["adaptive"]["changes"] = (
        [
            {
                "after_task": 3,
                "type": "rotate_object",
                "object": "A",
                "degrees": 90,
                "about": [5.0, 3.0],
            }
        ]
        if with_turn
        else []
    )
    return cellplan.loads(yaml.safe_dump(data))


def test_a_planar_turn_through_the_api_equals_the_scheduled_turn() -> None:
    scheduled = cellplan.plan(_planar(True), "adaptive", repair="A3", seed=0, baseline=False)
    assert scheduled.success
    by_schedule = scheduled.solution
    assert isinstance(by_schedule, ExperiencePlanner)

    ep = ExperiencePlanner(_planar(False), repair="A3", seed=0)
    for goal in PLANAR_TASKS[:3]:
        assert ep.plan(None, goal).success
    attached = [v.id for v in ep.graph.vertices.values() if v.obj == "A"]
    assert attached  # g2's vertex at least: the turn has a subgoal to carry
    ep.turn("A", units.radians(90.0), about=(5.0, 3.0))
    # by hand: g2 at (6.5, 3.0) turned 90 degrees counter-clockwise about (5, 3)
    np.testing.assert_allclose(ep.goals["g2"], [5.0, 4.5], atol=1e-12)
    x, y, theta = ep.pose("A")
    np.testing.assert_allclose([x, y, theta], [8.0, -2.0, math.pi / 2], atol=1e-12)
    for goal in PLANAR_TASKS[3:]:
        assert ep.plan(None, goal).success
    assert _state(ep) == _state(by_schedule)


def test_a_planar_turn_defaults_to_the_centroid_and_turns_the_attached_subgoals() -> None:
    ep = ExperiencePlanner(_planar(False), repair="A1", seed=0)
    assert ep.plan(None, "g2").success
    before = {v.id: v.q.copy() for v in ep.graph.vertices.values() if v.obj == "A"}
    assert before
    ep.turn("A", -math.pi / 2)  # about A's centroid (5, 3.5)
    for vid, q in before.items():
        d = q - [5.0, 3.5]
        np.testing.assert_allclose(ep.graph.vertices[vid].q, [5.0 + d[1], 3.5 - d[0]], atol=1e-9)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.floats(-3.0, 3.0),
    st.floats(-3.0, 3.0),
    st.tuples(st.floats(-5.0, 15.0), st.floats(-5.0, 15.0)),
)
def test_planar_turns_about_one_point_add_up(a: float, b: float, about: Any) -> None:
    one = ExperiencePlanner(_planar(False))
    two = ExperiencePlanner(_planar(False))
    one.turn("A", a, about=about)
    one.turn("A", b, about=about)
    two.turn("A", a + b, about=about)
    p, q = one.pose("A"), two.pose("A")
    np.testing.assert_allclose(p[:2], q[:2], atol=1e-9)
    assert math.isclose(math.remainder(p[2] - q[2], math.tau), 0.0, abs_tol=1e-9)


# --- 3-D: the UR5's bin_b turned, its goals and subgoals following by IK ---------------------

UR5_TASKS = ["f2", "b2", "f3", "b2", "b1"]
"""b2 (under hood_b) needs Solve, whose subgoal is attached to bin_b; the turn comes after
task 3 (the robot over the fixture)."""


def _ur5(with_turn: bool) -> cellplan.Setup:
    data = yaml.safe_load(scenario_path("adaptive_ur5").read_text())
    data["adaptive"]["tasks"] = UR5_TASKS
    data["adaptive"]["changes"] = (
        [{"after_task": 3, "type": "rotate_object", "object": "bin_b", "rpy": [0, 0, 20]}]
        if with_turn
        else []
    )
    return cellplan.loads(yaml.safe_dump(data))


def test_a_3d_turn_through_the_api_equals_the_scheduled_turn() -> None:
    scheduled = cellplan.plan(_ur5(True), "adaptive", repair="A3", seed=0, baseline=False)
    assert scheduled.success
    by_schedule = scheduled.solution
    assert isinstance(by_schedule, ExperiencePlanner)

    setup = _ur5(False)
    ep = ExperiencePlanner(setup, repair="A3", seed=0)
    for goal in UR5_TASKS[:3]:
        assert ep.plan(None, goal).success
    robot = ep.world.robot
    attached = {v.id: v.q.copy() for v in ep.graph.vertices.values() if v.obj == "bin_b"}
    assert attached
    b2 = robot.tool_pose(ep.goals["b2"][None, :])[0]
    ep.turn("bin_b", (0.0, 0.0, units.radians(20.0)))
    # by hand: each subgoal's tool pose turned 20 degrees about bin_b's centre
    centre, spin = np.array([-0.05, -0.5, 0.81]), _rz(math.radians(20.0))
    kept = [vid for vid in attached if vid in ep.graph.vertices]
    assert kept
    for vid in kept:
        old = robot.tool_pose(attached[vid][None, :])[0]
        new = robot.tool_pose(ep.graph.vertices[vid].q[None, :])[0]
        np.testing.assert_allclose(new[:3, 3], centre + spin @ (old[:3, 3] - centre), atol=1e-4)
        np.testing.assert_allclose(new[:3, :3], spin @ old[:3, :3], atol=1e-4)
    # the named goal too (its orientation given: the tool down, turned with the bin)
    now = robot.tool_pose(ep.goals["b2"][None, :])[0]
    np.testing.assert_allclose(now[:3, 3], centre + spin @ (b2[:3, 3] - centre), atol=1e-4)
    np.testing.assert_allclose(now[:3, :3], spin @ b2[:3, :3], atol=1e-4)
    for goal in UR5_TASKS[3:]:
        assert ep.plan(None, goal).success
    assert _state(ep) == _state(by_schedule)


@pytest.fixture(scope="module")
def ur5() -> cellplan.Setup:
    return _ur5(False)


def test_a_3d_turn_about_a_point_matches_the_scheduled_one_and_survives_the_store(
    ur5: cellplan.Setup, tmp_path: Path
) -> None:
    db = tmp_path / "turn.sqlite"
    ep = ExperiencePlanner(ur5, db=db)
    rpy, about = (0.1, -0.05, 0.3), (0.45, 0.30, 0.79)
    ep.turn("fixture", rpy, about=about)
    # the scheduled change (degrees in the scenario) through the world's apply
    data = yaml.safe_load(scenario_path("adaptive_ur5").read_text())
    data["adaptive"]["changes"] = []
    other = ExperiencePlanner(cellplan.loads(yaml.safe_dump(data)))
    change = RotateObject(
        type="rotate_object",
        after_task=0,
        object="fixture",
        rpy=tuple(units.degrees(np.array(rpy))),
        about=about,
    )
    other.world.apply(change)
    np.testing.assert_allclose(_frame(ep, "fixture"), _frame(other, "fixture"), atol=1e-12)
    cell = ep.world.workcell()
    assert isinstance(cell, Workcell3D)
    fixture = cell.obstacles["fixture"]
    # by hand: the centre (0.45, 0.40, 0.79) turned about (0.45, 0.30, 0.79)
    spin = solids.pose_matrix(np.zeros(3), rpy)[:3, :3]
    np.testing.assert_allclose(
        fixture.translation, spin @ np.array([0.0, 0.1, 0.0]) + about, atol=1e-12
    )
    goals, gen = {n: q.tolist() for n, q in ep.goals.items()}, ep.world.gen
    ep.close()
    reopened = ExperiencePlanner(ur5, db=db)
    assert reopened.world.gen == gen
    np.testing.assert_array_equal(_frame(reopened, "fixture"), _frame(ep, "fixture"))
    assert {n: q.tolist() for n, q in reopened.goals.items()} == goals
    reopened.close()


# --- refusals ----------------------------------------------------------------------------------


def _refused(ep: ExperiencePlanner, *args: Any, **kw: Any) -> list[str]:
    before = (ep.world.gen, ep.world.objects_json())
    with pytest.raises(ArgumentError) as info:
        ep.turn(*args, **kw)
    assert (ep.world.gen, ep.world.objects_json()) == before  # nothing changed
    assert len(str(info.value).splitlines()) == len(info.value.problems)
    return [p.field for p in info.value.problems]


def test_bad_turns_are_refused_one_line_each_planar() -> None:
    ep = ExperiencePlanner(_planar(False))
    assert _refused(ep, "nope", 0.1) == ["name"]
    assert _refused(ep, "A", (0.0, 0.0, 0.1)) == ["angle"]  # a planar turn is one angle
    assert _refused(ep, "A", float("nan")) == ["angle"]
    assert _refused(ep, "A", True) == ["angle"]
    assert _refused(ep, "A", "ninety") == ["angle"]
    assert _refused(ep, "A", 0.1, about=(1.0, 2.0, 3.0)) == ["about"]
    assert _refused(ep, "A", 0.1, about=(1.0, math.inf)) == ["about"]
    assert _refused(ep, "nope", [1.0, 2.0], about="x") == ["name", "angle", "about"]
    with pytest.raises(ArgumentError, match=r"angle: .*radians here"):
        ep.turn("A", 90.0)  # degrees where radians are expected


def test_bad_turns_are_refused_one_line_each_3d(ur5: cellplan.Setup) -> None:
    ep = ExperiencePlanner(ur5)
    assert _refused(ep, "fixture", 0.5) == ["angle"]  # a 3-D turn is roll, pitch, yaw
    assert _refused(ep, "fixture", (0.0, 0.5)) == ["angle"]
    assert _refused(ep, "fixture", (0.0, 0.0, 180.0)) == ["angle"]
    assert _refused(ep, "fixture", (0.0, 0.0, 0.5), about=(0.4, 0.4)) == ["about"]
    assert _refused(ep, "robot", (0.0, 0.0, 0.5)) == ["name"]
    with pytest.raises(ArgumentError, match=r"angle: expected 3 finite numbers \(roll, pitch"):
        ep.turn("fixture", 0.5)
