"""ExperiencePlanner: plan(start, goal) against G, environment changes, persistence, bad input."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from adaptive_scenarios import POINT_SCENARIO  # type: ignore[import-not-found]
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import cellplan.api as api
from cellplan.adaptive import ExperiencePlanner
from cellplan.adaptive.graph import BLOCKED
from cellplan.adaptive.reach import segment_points
from cellplan.adaptive.world import Tag
from cellplan.core import Status
from cellplan.errors import ArgumentError, PersistenceError
from cellplan.trajectory import Trajectory
from cellplan.workcell import Workcell

LID = {"type": "box", "min": [3.0, 7.05], "max": [7.0, 9.0]}


def _dense(q: np.ndarray, step: float) -> np.ndarray:
    """The polyline through ``q`` sampled every ``step`` (what the robot sweeps)."""
    return np.concatenate([segment_points(a, b, step) for a, b in itertools.pairwise(q)])


def _assert_free(cell: Workcell, traj: Trajectory, step: float) -> None:
    dense = _dense(traj.q, step)
    assert len(dense) > len(traj.q)
    assert not np.any(cell.collides(dense, avoid_sources="none"))


def _graph(ep: ExperiencePlanner) -> tuple[object, object]:
    g = ep.graph
    return (
        sorted((v.id, v.obj, v.branch, tuple(v.q.tolist()), v.rel) for v in g.vertices.values()),
        sorted((k, e.status, e.gen) for k, e in g.edges.items()),
    )


@pytest.fixture(scope="module")
def fig4() -> api.Setup:
    return api.load("adaptive_fig4")


def test_arm_query_is_solved_and_the_path_is_collision_free(fig4: api.Setup) -> None:
    ep = ExperiencePlanner(fig4)
    a, b = ep.goals["g1"], ep.goals["g5"]
    res = ep.plan(a, b)
    assert res.status is Status.SOLVED and res.solution is ep
    traj = res.trajectory
    assert traj is not None and traj.time_unit == "path" and traj.units == ("rad", "rad")
    assert np.array_equal(traj.q[0], a) and np.array_equal(traj.q[-1], b)
    assert [e.kind for e in traj.events] == ["task", "arrive"]
    assert traj.events[-1].index == len(traj) - 1
    # the joints sweep nothing at a 20th of a degree between the returned waypoints
    _assert_free(fig4.workcell, traj, np.radians(0.05))
    assert res.stats["solve_calls"] == 1 and res.stats["checks"] > 0


def test_a_second_query_between_known_configurations_is_cheaper(fig4: api.Setup) -> None:
    ep = ExperiencePlanner(fig4)
    a, b = ep.goals["g1"], ep.goals["g5"]
    first = ep.plan(a, b)
    back = ep.plan(b, a)
    again = ep.plan(a, b)
    assert first.success and back.success and again.success
    assert back.stats["solve_calls"] == 0 and again.stats["solve_calls"] == 0
    assert again.stats["checks"] < first.stats["checks"] / 10
    assert np.array_equal(again.trajectory.q[-1], b)  # type: ignore[union-attr]


def test_added_obstacle_is_repaired_on_demand_and_the_new_path_avoids_it() -> None:
    setup = api.loads(POINT_SCENARIO)
    ep = ExperiencePlanner(setup)
    home, g1 = ep.goals["home"], ep.goals["g1"]
    first = ep.plan(home, g1)
    assert first.success
    over = first.trajectory.q  # type: ignore[union-attr]
    assert over[:, 1].max() > 7.0  # over the wall A
    ep.add("lid", LID)
    assert ep.world.gen == 1
    res = ep.plan(home, g1)
    assert res.success and res.stats["generation"] == 1
    # T met the blocked edge over the wall (A3 repairs on demand) and Solve went round
    assert any(e.status == BLOCKED and e.gen == 1 for e in ep.graph.edges.values())
    assert res.stats["solve_calls"] >= 1
    _assert_free(ep.world.workcell(), res.trajectory, 0.005)  # type: ignore[arg-type]
    assert "lid" in ep.world.workcell().obstacles
    with pytest.raises(ArgumentError, match="collides with obstacle 'lid'"):
        ep.plan([5.0, 8.0], g1)


def test_moved_object_carries_its_goal_and_subgoals() -> None:
    ep = ExperiencePlanner(api.loads(POINT_SCENARIO))
    assert ep.plan(None, "g2").success
    ep.move("A", (0.5, 0.25, 0.0))
    with pytest.raises(ArgumentError, match=r"start: .* collides with obstacle 'A'"):
        ep.plan(None, "home")  # A moved onto the robot standing at g2's old place
    ep.move("A", (0.0, 0.0, 0.0))
    assert ep.plan(None, "home").success
    ep.move("A", (0.5, 0.25, 0.0))
    assert ep.pose("A") == (0.5, 0.25, 0.0)
    assert np.allclose(ep.goals["g2"], [7.0, 3.25])
    res = ep.plan(None, "g2")
    assert res.success and np.allclose(res.trajectory.q[-1], [7.0, 3.25])  # type: ignore[union-attr]
    _assert_free(ep.world.workcell(), res.trajectory, 0.005)  # type: ignore[arg-type]
    ep.add("crate", {"type": "box", "min": [0.0, 9.0], "max": [1.0, 10.0]})
    ep.remove("crate")
    assert ep.world.gen == 5 and "crate" not in ep.world.objects
    with pytest.raises(ArgumentError, match="attached to 'A'"):
        ep.remove("A")


def test_persistence_round_trip_continues_with_the_same_graph(tmp_path: Path) -> None:
    setup = api.loads(POINT_SCENARIO)
    db = tmp_path / "exp.sqlite"
    memory = ExperiencePlanner(setup, repair="A1")
    saved = ExperiencePlanner(setup, repair="A1", db=db)
    for ep in (memory, saved):
        assert ep.plan(None, "g1").success
        ep.add("lid", LID)
        assert ep.plan(None, "home").success
    before = _graph(saved)
    saved.close()
    reopened = ExperiencePlanner(setup, repair="A1", db=db)
    assert _graph(reopened) == before == _graph(memory)
    assert reopened.world.gen == 1 and "lid" in reopened.world.objects
    assert np.array_equal(reopened.position, memory.position)
    # continuing after the reopen does exactly what the uninterrupted session does
    reopened.move("lid", (0.0, 0.5, 0.0))
    memory.move("lid", (0.0, 0.5, 0.0))
    a, b = reopened.plan([2.0, 9.5], "g1"), memory.plan([2.0, 9.5], "g1")
    assert a.success and b.success
    assert a.trajectory == b.trajectory and a.stats["checks"] == b.stats["checks"]
    assert _graph(reopened) == _graph(memory)
    reopened.close()
    with pytest.raises(ArgumentError, match="resolution"):
        ExperiencePlanner(setup, db=db, resolution=0.2)
    other = api.loads(POINT_SCENARIO.replace("max: [6.0, 7.0]", "max: [6.0, 7.5]"))
    with pytest.raises(PersistenceError, match="another workcell"):
        ExperiencePlanner(other, db=db)


def test_a_planner_continues_from_a_scenario_runs_database(tmp_path: Path) -> None:
    setup = api.loads(POINT_SCENARIO)
    db = tmp_path / "run.sqlite"
    run = api.plan(setup, "adaptive", db=str(db))
    assert run.success
    ep = ExperiencePlanner(setup, db=db)
    assert _graph(ep) == _graph(run.solution)
    assert ep.world.gen == 1 and "C" in ep.world.objects  # the change after task 4
    assert ep.plan(None, "g2").success
    ep.close()
    with pytest.raises(PersistenceError, match="ExperiencePlanner"):
        api.plan(setup, "adaptive", db=str(db), tasks=7)


def test_bad_start_and_goal_are_refused_with_one_line(fig4: api.Setup) -> None:
    ep = ExperiencePlanner(fig4)
    g1 = ep.goals["g1"]
    with pytest.raises(ArgumentError, match=r"start: angle q1=90 .* radians"):
        ep.plan([90.0, -90.0], g1)
    with pytest.raises(ArgumentError, match=r"goal: expected shape \(N, 2\)"):
        ep.plan(None, [0.1, 0.2, 0.3])
    with pytest.raises(ArgumentError, match=r"start: configuration .* outside the joint limits"):
        ep.plan([3.1, 0.0], g1)
    with pytest.raises(ArgumentError, match="goal: unknown goal 'g99'"):
        ep.plan(None, "g99")
    # the tool point inside O1: the second link collides with it
    inside = ep.world.config_of(Tag(None, (1.5, 0.55, 0.0), 1))
    assert inside is not None
    with pytest.raises(ArgumentError, match="collides with obstacle 'O1'") as err:
        ep.plan(inside, g1)
    assert len(err.value.problems) == 1
    assert ep.queries == 0 and len(ep.graph) == 1  # nothing was planned


def test_a_bare_workcell_is_enough(tmp_path: Path) -> None:
    setup = api.loads(POINT_SCENARIO)
    cell = setup.workcell
    db = tmp_path / "cell.sqlite"
    ep = ExperiencePlanner(cell, resolution=0.1, db=db)
    res = ep.plan([1.0, 1.0], [9.0, 1.0])
    assert res.success and ep.goals == {}
    _assert_free(cell, res.trajectory, 0.005)  # type: ignore[arg-type]
    ep.add("post", {"type": "disc", "center": [8.0, 5.0], "radius": 0.5}, (0.5, 0.0, 0.0))
    with pytest.raises(ArgumentError, match="collides with obstacle 'post'"):
        ep.plan(None, [8.5, 5.0])
    with pytest.raises(ArgumentError, match="shape"):
        ep.add("bad", {"type": "box", "min": [1.0]})
    ep.close()
    again = ExperiencePlanner(cell, resolution=0.1, db=db)
    assert _graph(again) == _graph(ep) and again.pose("post") == (0.5, 0.0, 0.0)
    again.close()
    # keyed on the workcell's own numbers: the scenario's signature is another key
    with pytest.raises(PersistenceError, match="another"):
        ExperiencePlanner(setup, db=db)


def test_a_rotating_robot_plans_and_its_attached_subgoals_turn_with_objects() -> None:
    setup = api.load("strategies_p3")
    robot = setup.workcell.robot
    ep = ExperiencePlanner(setup, resolution=0.2)
    rng = np.random.default_rng(3)
    q = rng.uniform(robot.lower, robot.upper, size=(200, robot.dim))
    q = q[ep.world.is_free(q)]
    first = ep.plan(q[0], q[1])
    assert first.success and first.trajectory.units == ("workcell", "workcell", "rad")  # type: ignore[union-attr]
    _assert_free(setup.workcell, first.trajectory, 0.01)  # type: ignore[arg-type]
    attached = {v.id: v.q.copy() for v in ep.graph.vertices.values() if v.obj is not None}
    assert attached
    obj = ep.graph.vertices[next(iter(attached))].obj
    assert obj is not None
    turned = [vid for vid in attached if ep.graph.vertices[vid].obj == obj]
    ep.move(obj, (0.0, 0.0, 0.1))
    # subgoals on the object turn with it; one the turn makes collide is dropped (2.3)
    kept = [vid for vid in turned if vid in ep.graph.vertices]
    assert kept
    for vid in kept:
        after, before = ep.graph.vertices[vid].q, attached[vid]
        assert np.isclose(after[2], robot.wrap(before + np.array([0.0, 0.0, 0.1]))[2])
        assert not np.allclose(after[:2], before[:2])
    assert ep.plan(None, q[2]).success


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.floats(0.2, 9.8), st.floats(0.2, 9.8)), min_size=2, max_size=5))
def test_every_answer_is_a_free_path_between_the_asked_configurations(
    points: list[tuple[float, float]],
) -> None:
    setup = api.loads(POINT_SCENARIO)
    ep = ExperiencePlanner(setup, seed=1)
    free = [np.array(p) for p in dict.fromkeys(points) if ep.world.is_free(np.array([p]))[0]]
    assume(len(free) >= 2)
    for a, b in itertools.pairwise(free):
        res = ep.plan(a, b)
        traj = res.trajectory
        assert traj is not None
        assert res.success, res.message  # the wall leaves every free pair connected
        assert np.array_equal(traj.q[0], a) and np.array_equal(traj.q[-1], b)
        _assert_free(setup.workcell, traj, 0.01)
        assert res.stats["checks"] == sum(v for k, v in res.stats.items() if k.endswith("_checks"))
