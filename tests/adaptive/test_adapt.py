from __future__ import annotations

import numpy as np
import pytest
from adaptive_scenarios import POINT_SCENARIO  # type: ignore[import-not-found]

from cellplan import units
from cellplan.adaptive.adapt import Adapter
from cellplan.adaptive.graph import BLOCKED
from cellplan.adaptive.repair import repair
from cellplan.adaptive.runner import cumulative_ratio, run_adaptive, settings_for
from cellplan.adaptive.section import AddObject, MoveObject, RotateObject
from cellplan.adaptive.world import World
from cellplan.errors import ArgumentError, ScenarioError
from cellplan.scenario import load_scenario, loads_scenario


def _adapter(text: str = POINT_SCENARIO, strategy: str = "A3") -> Adapter:
    sc = loads_scenario(text)
    st = settings_for(sc, strategy, 0)
    return Adapter(World(sc, st.resolution), st)


def test_first_task_solves_then_reuses_experience() -> None:
    ad = _adapter()
    g1 = ad.world.goal_config("g1")
    first = ad.task("g1", g1)
    assert first.success and first.solve_calls == 1 and first.path_ok
    assert first.costs["solve"] > 0 and first.costs["abstract"] > 0
    home = ad.world.goal_config("home")
    back = ad.task("home", home)
    assert back.success and back.solve_calls == 0 and back.costs["solve"] == 0
    # no change since: T verifies nothing again
    again = ad.task("g1", g1)
    assert again.success and again.costs["trace"] == 0 and again.solve_calls == 0
    assert np.allclose(again.path[0], home) and np.allclose(again.path[-1], g1)


def test_trace_removes_a_blocked_edge_and_reconnects_with_solve() -> None:
    ad = _adapter()
    ad.settings.corner_cutting = (
        False  # G stays a tree (Section 2.6), so a blocked edge disconnects it
    )
    ad.task("g1", ad.world.goal_config("g1"))
    ad.task("home", ad.world.goal_config("home"))
    over_wall = ad.graph.vertices[ad.graph.by_heuristic(np.array([5.0, 8.0]))[0]].q
    assert over_wall[1] > 7.0  # the chain goes over the obstacle A
    # a lid over A blocks the chain: T must find the blocked edge and call Solve (step 2)
    ad.world.apply(
        AddObject(
            after_task=2,
            type="add_object",
            object="lid",
            shape={"type": "box", "min": [3.0, 7.05], "max": [7.0, 9.0]},
        )
    )
    res = ad.task("g1", ad.world.goal_config("g1"))
    assert any(e.status == BLOCKED and e.gen == 1 for e in ad.graph.edges.values())
    assert res.success and res.path_ok and res.solve_calls == 1 and res.costs["trace"] > 0


def test_trace_step_3_drops_an_unreachable_component() -> None:
    ad = _adapter()
    ad.task("g1", ad.world.goal_config("g1"))
    ad.task("home", ad.world.goal_config("home"))
    n_before = len(ad.graph)
    # wall off the right half completely: the far side of G cannot be reconnected
    ad.world.apply(
        AddObject(
            after_task=2,
            type="add_object",
            object="fence",
            shape={"type": "box", "min": [6.2, 0.0], "max": [6.4, 10.0]},
        )
    )
    ad.settings.max_solve_checks = 3000
    far = [v for v, x in ad.graph.vertices.items() if x.q[0] > 6.4]
    assert far
    gamma = ad.trace(far[0])
    assert gamma is None
    assert all(v not in ad.graph.vertices for v in far) and len(ad.graph) < n_before
    assert ad.u_hat in ad.graph.vertices


@pytest.mark.parametrize("strategy", ["A0", "A1", "A2", "A3"])
def test_repair_strategies_after_a_change(strategy: str) -> None:
    ad = _adapter(strategy=strategy)
    ad.task("g1", ad.world.goal_config("g1"))
    ad.task("home", ad.world.goal_config("home"))
    edges_before = len(ad.graph.usable_edges())
    ad.world.apply(
        AddObject(
            after_task=2,
            type="add_object",
            object="far",
            shape={"type": "box", "min": [0.2, 9.5], "max": [0.4, 9.7]},
        )
    )
    repair(ad, strategy)
    g = ad.graph
    if strategy == "A0":
        assert len(g) == 1 and not g.edges
    elif strategy == "A1":
        assert all(g.edge(a, b).gen == 1 for a, b in g.usable_edges())  # every edge verified
        assert len(g.usable_edges()) == edges_before and ad.counter.counts["repair"] > 0
    elif strategy == "A2":
        assert ad.counter.counts["repair"] > 0 and g.component(ad.u_hat) == set(g.vertices)
    else:
        assert ad.counter.counts["repair"] == 0
    res = ad.task("g1", ad.world.goal_config("g1"))
    assert res.success and res.path_ok


def test_attached_subgoals_follow_their_object() -> None:
    text = POINT_SCENARIO.replace("attach_radius: 1.0", "attach_radius: 2.0")
    ad = _adapter(text)
    ad.task("g2", ad.world.goal_config("g2"))
    attached = {v: x.q.copy() for v, x in ad.graph.vertices.items() if x.obj == "A"}
    assert attached
    moved = ad.world.apply(MoveObject(after_task=1, type="move_object", object="A", by=(0.5, 0.25)))
    ad.follow_objects(moved)
    for v, q in attached.items():
        if v in ad.graph.vertices:
            assert np.allclose(ad.graph.vertices[v].q, q + np.array([0.5, 0.25]))
    assert np.allclose(ad.world.goal_config("g2"), [7.0, 3.25])
    ad.world.apply(
        RotateObject(
            after_task=1, type="rotate_object", object="A", degrees=90.0, about=(5.5, 3.75)
        )
    )
    assert np.allclose(
        ad.world.goal_config("g2"), [5.5 + 0.5, 3.75 + 1.5]
    )  # (1.5, -0.5) turned by 90 deg


def test_arm_subgoal_ik_keeps_its_elbow_branch() -> None:
    sc = load_scenario("adaptive_fig4")
    world = World(sc, units.radians(1.0))
    for name, tag in world.goals.items():
        q = world.goal_config(name)
        assert q is not None and world.branch(q) == tag.branch
        assert np.allclose(world.tool(q)[:2], world.tool_pose_of(tag)[:2])
    moved = world.apply(MoveObject(after_task=0, type="move_object", object="O1", by=(0.05, 0.05)))
    assert moved == {"O1"} and world.gen == 1
    q = world.goal_config("g1")
    assert q is not None and np.allclose(world.tool(q)[:2], np.array([1.442, 0.152]) + 0.05)
    far = world.apply(MoveObject(after_task=0, type="move_object", object="O1", by=(5.0, 0.0)))
    assert far and world.goal_config("g1") is None  # out of reach: no IK solution


def test_fig4_run_meets_the_paper_shape_and_every_path_is_free() -> None:
    sc = load_scenario("adaptive_fig4")
    out = run_adaptive(sc, "A3", tasks=45, seed=1)
    rows = out.rows
    assert all(r["success"] and r["path_ok"] for r in rows)
    ratio = cumulative_ratio(rows)
    assert ratio[0] > 1.0  # the first task costs Solve plus Abstract
    assert ratio[39] < 0.6  # experience pays off (paper: 0.67 at task 40)
    assert sum(r["solve_calls"] for r in rows) < 10


def test_bad_input_is_refused_before_work() -> None:
    with pytest.raises(ScenarioError, match=r"adaptive.changes\[0\].object"):
        loads_scenario(POINT_SCENARIO.replace("object: C\n", "object: A\n"))
    with pytest.raises(ScenarioError, match="unknown object 'Z'"):
        loads_scenario(POINT_SCENARIO.replace("object: A}", "object: Z}"))
    with pytest.raises(ScenarioError, match=r"adaptive.tasks\[1\]"):
        loads_scenario(POINT_SCENARIO.replace("tasks: [g1, home,", "tasks: [g1, nowhere,"))
    inside = loads_scenario(POINT_SCENARIO.replace("g1: {at: [9.0, 1.0]}", "g1: {at: [5.0, 1.0]}"))
    with pytest.raises(
        ScenarioError,
        match=r"adaptive\.goals\.g1: the goal configuration collides with \(or is within the "
        r"clearance of\) obstacle 'A'$",
    ):
        run_adaptive(inside)
    with pytest.raises(ArgumentError, match=r"^repair: unknown repair strategy"):
        run_adaptive(loads_scenario(POINT_SCENARIO), "A9")
    with pytest.raises(ArgumentError, match=r"^tasks: the scenario lists only 7 tasks"):
        run_adaptive(loads_scenario(POINT_SCENARIO), tasks=99)


def test_potential_field_reach_drives_adapt_too() -> None:
    sc = loads_scenario(
        POINT_SCENARIO.replace("  resolution: 0.1\n", "  resolution: 0.1\n  reach: potential\n")
    )
    out = run_adaptive(sc, "A3", tasks=4)
    assert all(r["success"] and r["path_ok"] for r in out.rows)
    assert out.adapter is not None and out.adapter.settings.reach == "potential"
