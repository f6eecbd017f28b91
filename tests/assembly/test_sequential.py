"""Sequential assembly (Section 4.2): a stuck T map continued at a lower k; place-rule routes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from cellplan.assembly.navigation import evaluate, hessian_log_w, log_w
from cellplan.assembly.problems import CircleWorkspace, DiscProblem, generate_problem
from cellplan.assembly.routes import (
    placement_route,
    route_margin,
    route_nodes,
    segment_clearance,
    shortest_route,
    shortest_route_full,
)
from cellplan.assembly.section import GeneratorSpec
from cellplan.assembly.sequential import Rule, SequentialResult, sequential_assembly
from cellplan.core import Status

# Seven unit discs, hexagonal goals with pairwise beta(d) = 1e-16 (Fig. 5(c)). The starts
# are random legal ones (generator seeds 1 and 4), written out so that the tests do not
# depend on the generator or the default workspace.
HEX = np.array(
    [
        [0.0, 0.0],
        [-1.0036711316621478, -1.738409394128992],
        [1.0036711316621478, -1.738409394128992],
        [2.0073422633242957, 0.0],
        [1.0036711316621478, 1.738409394128992],
        [-1.0036711316621478, 1.738409394128992],
        [-2.0073422633242957, 0.0],
    ]
)
# k = 48: the T map at k alone runs out of its 20 n switches with two discs pressed
# together handing the turn back and forth (it solves only after 181 switches)
PING_PONG = DiscProblem(
    np.ones(7),
    np.array(
        [
            [-1.5869574702043012, -7.548733073037667],
            [-8.750518505339972, 3.293009396759315],
            [5.781808107370352, 3.8062636853552334],
            [-3.2764170041026963, 3.236272247279302],
            [-0.817040215745796, 8.891677773140197],
            [-4.5921874139775145, 0.22416827260256159],
            [-7.527354726059178, -3.9485190004263058],
        ]
    ),
    HEX,
    CircleWorkspace(np.zeros(2), math.sqrt(7 / 0.05)),
)
# k = 128: given 2,000 switches the T map at k alone ends at a spurious minimum of phi
MINIMUM = DiscProblem(
    np.ones(7),
    np.array(
        [
            [8.502503951561781, 0.5014044186974838],
            [-7.639906054552546, -2.9541896416794606],
            [-4.974085509499576, 0.5109299830604094],
            [-0.8264038376106735, -6.677296312716237],
            [5.079880098463133, -0.13413278725061303],
            [7.205586012419186, 2.518009889781232],
            [-0.42874986801157106, -1.962137963183225],
        ]
    ),
    HEX,
    CircleWorkspace(np.zeros(2), 4.0 + 2.2 * math.sqrt(7)),
)


def _replay(p: DiscProblem, res: SequentialResult) -> np.ndarray:
    """Execute the grasps one disc at a time; every straight piece keeps a gap > 0."""
    x = p.start.copy()
    assert len(res.actions()) == 3 * res.switches
    for g in res.grasps:
        assert np.allclose(g.path[0], x[g.disc])
        for b in g.path[1:]:
            assert segment_clearance(p, x, g.disc, b) > 0
            x[g.disc] = b
    return x


def _grasp_ends(res: SequentialResult) -> np.ndarray:
    return np.concatenate([[0], np.cumsum([len(g.path) - 1 for g in res.grasps])])


def test_ping_pong_exhausts_the_budget_at_k_and_lowering_k_solves() -> None:
    k = 48.0
    plain = sequential_assembly(PING_PONG, k, "paper")
    assert plain.status is Status.BUDGET_EXHAUSTED and plain.switches == 20 * 7
    assert "no progress" in plain.reason
    assert plain.escapes == 0 and not plain.solved_at_k and plain.k_final == k
    # not a critical point of phi: the full gradient is far from zero ...
    end = plain.path[-1]
    assert np.linalg.norm(evaluate(end, PING_PONG, k).v) > 0.05 * np.linalg.norm(end - HEX)
    # ... but L = log alpha^(1/k) hardly falls any more, while the grasps alternate
    lw = [log_w(evaluate(plain.path[e], PING_PONG, k), k) for e in _grasp_ends(plain)[-15:]]
    assert lw[0] - lw[-1] < 1e-2
    assert len({g.disc for g in plain.grasps[-14:]}) <= 4

    res = sequential_assembly(PING_PONG, k, "paper", escapes=6)
    assert res.status is Status.SOLVED and res.escapes >= 1 and not res.solved_at_k
    assert res.stages[0].status is Status.STUCK and "no progress" in res.stages[0].reason
    assert [s.k for s in res.stages] == [k * 0.5**j for j in range(len(res.stages))]
    assert res.k_final == res.stages[-1].k and res.stages[-1].status is Status.SOLVED
    assert res.switches == sum(s.steps for s in res.stages)
    # the first stage is the plain run, grasp for grasp
    for a, b in zip(res.grasps[: res.stages[0].steps], plain.grasps, strict=False):
        assert a.disc == b.disc and np.array_equal(a.path, b.path)
    assert res.min_clearance > 0
    assert np.linalg.norm(_replay(PING_PONG, res) - HEX) < 1e-2


def test_t_map_ends_at_a_spurious_minimum_and_a_lower_k_leaves_it() -> None:
    k, budget = 128.0, 2000
    plain = sequential_assembly(MINIMUM, k, "paper", max_switches=budget)
    assert plain.status is Status.STUCK and plain.reason == "spurious minimum"
    # every disc is blocked: all blocks of grad phi vanish, and phi has a minimum there
    end = plain.path[-1]
    v = evaluate(end, MINIMUM, k).v
    block = 1e-2 / (4.0 * math.sqrt(7))
    assert np.max(np.linalg.norm(v, axis=1)) < block
    assert np.linalg.norm(end - HEX) > 1.0
    assert np.linalg.eigvalsh(hessian_log_w(end, MINIMUM, k))[0] > 0
    # only the critical-point test (min_progress=0): the first stage is the plain run
    res = sequential_assembly(MINIMUM, k, "paper", max_switches=budget, escapes=3, min_progress=0.0)
    assert res.stages[0] == plain.stages[0]
    assert res.status is Status.SOLVED and res.escapes >= 1
    assert res.min_clearance > 0
    assert np.linalg.norm(_replay(MINIMUM, res) - HEX) < 1e-2


def test_escapes_do_not_change_solved_runs_or_the_place_rule() -> None:
    p = generate_problem(GeneratorSpec(n=5, seed=2, gap=0.1), CircleWorkspace(np.zeros(2), 8.0))
    rules: tuple[Rule, ...] = ("paper", "place")
    for rule in rules:
        a = sequential_assembly(p, 32.0, rule)
        b = sequential_assembly(p, 32.0, rule, escapes=6)
        assert a.status is Status.SOLVED and b.status is Status.SOLVED
        assert a.solved_at_k and b.escapes == 0 and b.k_final == 32.0
        assert [g.disc for g in a.grasps] == [g.disc for g in b.grasps]
        assert np.array_equal(a.path, b.path)


def test_bad_escape_arguments_are_rejected() -> None:
    with pytest.raises(ValueError, match="escape_factor"):
        sequential_assembly(PING_PONG, 48.0, escape_factor=1.0)
    with pytest.raises(ValueError, match="escapes"):
        sequential_assembly(PING_PONG, 48.0, escapes=-1)


# --- route search ------------------------------------------------------------------------


def _route_state(seed: int, n: int, at_goals: bool) -> tuple[DiscProblem, np.ndarray, int]:
    p = generate_problem(
        GeneratorSpec(n=n, seed=seed, gap=0.1), CircleWorkspace(np.zeros(2), 2.5 * n)
    )
    i = seed % n
    x = p.start.copy()
    if at_goals:  # the others stand on their goals: disc i must go round the cluster
        x = p.goal.copy()
        x[i] = p.start[i]
    return p, x, i


def _clear_of_discs(p: DiscProblem, x: np.ndarray, i: int, pts: np.ndarray) -> float:
    """Smallest gap along the polyline ``pts`` (shapely distances, independent of ours)."""
    line = shapely.LineString(pts)
    others = np.delete(np.arange(p.n), i)
    dist = shapely.distance(shapely.points(x[others]), line)
    return float(np.min(dist - p.radii[others] - p.radii[i]))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(3, 8), at_goals=st.booleans())
def test_lazy_route_is_as_short_as_the_full_graph_and_collision_free(
    seed: int, n: int, at_goals: bool
) -> None:
    p, x, i = _route_state(seed, n, at_goals)
    nodes = route_nodes(p, x, i)
    full = shortest_route_full(p, x, i, nodes)
    lazy = shortest_route(p, x, i, nodes)
    assert (full is None) == (lazy is None)
    if lazy is None or full is None:
        return
    assert lazy[1] == pytest.approx(full[1], rel=1e-9, abs=1e-12)
    pts = np.array([x[i], *lazy[0]])
    assert np.array_equal(pts[-1], nodes[1])
    assert float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1))) == pytest.approx(lazy[1])
    assert _clear_of_discs(p, x, i, pts) >= route_margin(p) - 1e-12
    ws = p.workspace
    assert isinstance(ws, CircleWorkspace)
    assert np.all(np.linalg.norm(pts - ws.center, axis=1) + p.radii[i] < ws.radius)


def test_route_to_an_occupied_goal_is_none_in_both_searches() -> None:
    p, x, i = _route_state(3, 5, at_goals=False)
    x[(i + 1) % p.n] = p.goal[i]  # another disc stands on disc i's goal
    nodes = route_nodes(p, x, i)
    assert shortest_route(p, x, i, nodes) is None
    assert shortest_route_full(p, x, i, nodes) is None
    assert placement_route(p, x, i) is None
