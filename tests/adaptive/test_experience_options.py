"""ExperiencePlanner's SimpleSetup-like options (issue 34): a per-query time limit and a
user validity checker AND-ed with the workcell's."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from adaptive_scenarios import POINT_SCENARIO

import cellplan.api as api
from cellplan.adaptive import ExperiencePlanner
from cellplan.adaptive.reach import segment_points
from cellplan.core import Result, Status
from cellplan.errors import ArgumentError


def _below_ceiling(Q: np.ndarray) -> np.ndarray:
    """The user's rule: stay below y = 8.5 (the workcell allows up to 10)."""
    return np.asarray(Q[:, 1] <= 8.5)


def _all_free(Q: np.ndarray) -> np.ndarray:
    return np.ones(len(Q), dtype=bool)


def _dense(q: np.ndarray) -> np.ndarray:
    return np.concatenate([segment_points(a, b, 0.005) for a, b in itertools.pairwise(q)])


def _same(a: Result, b: Result) -> None:
    assert a.status is b.status and a.message == b.message
    assert a.trajectory is not None and b.trajectory is not None
    assert np.array_equal(a.trajectory.q, b.trajectory.q)
    assert {k: v for k, v in a.stats.items() if k != "seconds"} == {
        k: v for k, v in b.stats.items() if k != "seconds"
    }


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf"), "1", True])
def test_a_bad_time_limit_is_refused_in_one_line(bad: object) -> None:
    ep = ExperiencePlanner(api.loads(POINT_SCENARIO))
    with pytest.raises(ArgumentError) as err:
        ep.plan(None, "g1", time_limit=bad)  # type: ignore[arg-type]
    assert [p.field for p in err.value.problems] == ["time_limit"]
    assert ep.queries == 0


def test_a_bad_validity_checker_is_refused_before_any_work() -> None:
    setup = api.loads(POINT_SCENARIO)
    with pytest.raises(ArgumentError, match="callable") as err:
        ExperiencePlanner(setup, validity=3)  # type: ignore[arg-type]
    assert [p.field for p in err.value.problems] == ["validity"]
    with pytest.raises(ArgumentError, match=r"bool\[N\]"):
        ExperiencePlanner(setup, validity=lambda Q: np.ones((len(Q), 2), bool))
    with pytest.raises(ArgumentError, match=r"bool\[N\]"):
        ExperiencePlanner(setup, validity=lambda Q: Q[:, 0])  # type: ignore[arg-type, return-value]


def test_an_always_true_checker_changes_nothing() -> None:
    """AND with True is the identity: same paths, same counted checks, query by query."""
    setup = api.loads(POINT_SCENARIO)
    plain = ExperiencePlanner(setup)
    user = ExperiencePlanner(setup, validity=_all_free)
    for goal in ["g1", "home", "g2", "g1"]:
        _same(plain.plan(None, goal), user.plan(None, goal))


def test_the_checker_is_anded_with_the_workcell_and_paths_obey_both() -> None:
    setup = api.loads(POINT_SCENARIO)
    seen: list[int] = []

    def ceiling(Q: np.ndarray) -> np.ndarray:
        seen.append(len(Q))
        return _below_ceiling(Q)

    ep = ExperiencePlanner(setup, validity=ceiling)
    for goal in ["g1", "home", "g1"]:
        res = ep.plan(None, goal)
        assert res.status is Status.SOLVED, res.message
        dense = _dense(res.trajectory.q)  # type: ignore[union-attr]
        assert np.all(_below_ceiling(dense))
        assert not np.any(setup.workcell.collides(dense, avoid_sources="none"))
    # every configuration the checker saw was counted (it sees only the workcell's free ones)
    assert 0 < sum(seen)
    # start and goal are refused in one line when the checker refuses them
    with pytest.raises(ArgumentError, match="refused by the validity checker") as err:
        ep.plan(None, [5.0, 9.0])
    assert [p.field for p in err.value.problems] == ["goal"]


def test_a_time_limit_stops_the_query_and_keeps_the_graph(tmp_path: Path) -> None:
    ep = ExperiencePlanner(api.loads(POINT_SCENARIO))
    before = (len(ep.graph), len(ep.graph.edges))
    res = ep.plan(None, "g1", time_limit=1e-9)  # past before R looks at one vertex
    assert res.status is Status.TIMEOUT and not res.success
    assert "time limit" in res.message
    assert res.trajectory is not None and len(res.trajectory) == 1
    assert (len(ep.graph), len(ep.graph.edges)) == before
    # the next query, without a limit, is not affected
    again = ep.plan(None, "g1")
    assert again.status is Status.SOLVED, again.message


def test_a_generous_time_limit_changes_nothing() -> None:
    setup = api.loads(POINT_SCENARIO)
    plain, limited = ExperiencePlanner(setup), ExperiencePlanner(setup)
    for goal in ["g1", "home", "g2"]:
        _same(plain.plan(None, goal), limited.plan(None, goal, time_limit=1e6))


def test_a_database_reopened_with_a_checker_starts_a_new_generation(tmp_path: Path) -> None:
    setup = api.loads(POINT_SCENARIO)
    db = tmp_path / "exp.sqlite"
    with ExperiencePlanner(setup, db=db) as ep:
        assert ep.plan(None, "g1").success
        gen = ep.world.gen
    with ExperiencePlanner(setup, db=db, validity=_below_ceiling) as again:
        assert again.world.gen == gen + 1
        res = again.plan(None, "home")
        assert res.success and np.all(_below_ceiling(_dense(res.trajectory.q)))  # type: ignore[union-attr]


S_BEND = """
cellplan: 1
name: s-bend
workcell:
  bounds: {xmin: 0, ymin: 0, xmax: 10, ymax: 10}
  obstacles:
    A: {type: box, min: [3.0, 0.0], max: [4.0, 8.0]}
    B: {type: box, min: [6.0, 2.0], max: [7.0, 10.0]}
robot: {type: point, start: [1.0, 1.0]}
adaptive:
  SOLVE
  resolution: 0.1
  goals:
    far: {at: [9.0, 1.0]}
  tasks: [far]
"""


def test_the_toy_solve_says_what_it_is_and_names_the_real_planner() -> None:
    """Issue 34: the S-bend needs three bends, beyond the toy Solve of Fig. 3."""
    toy = ExperiencePlanner(api.loads(S_BEND.replace("SOLVE", "solve: two_segment")))
    res = toy.plan(None, "far")
    assert res.status is Status.FAILED
    assert "toy Solve of the paper's Fig. 3" in res.message
    assert "ompl.RRTConnect" in res.message
    real = ExperiencePlanner(api.loads(S_BEND.replace("SOLVE", "solve: ompl.RRTConnect")))
    solved = real.plan(None, "far")
    assert solved.status is Status.SOLVED, solved.message
    assert "toy" not in solved.message
