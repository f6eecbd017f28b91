from __future__ import annotations

import itertools

import numpy as np

from cellplan.adaptive.abstract import abstract
from cellplan.adaptive.graph import BLOCKED, FREE, UNKNOWN, ExperienceGraph
from cellplan.adaptive.reach import reach
from cellplan.adaptive.solve import solve_rrtconnect, solve_two_segment
from cellplan.adaptive.space import PlanSpace


def _line_graph(n: int) -> ExperienceGraph:
    g = ExperienceGraph()
    for i in range(n):
        g.add_vertex(np.array([float(i), 0.0]))
    for i in range(n - 1):
        g.set_edge(i, i + 1, FREE, 0)
    return g


def test_shortest_path_components_and_blocked_edges() -> None:
    g = _line_graph(5)
    assert g.shortest_path(0, 4) == [0, 1, 2, 3, 4]
    g.set_edge(0, 4, FREE, 0)
    assert g.shortest_path(0, 4) == [0, 4]
    g.set_edge(0, 4, BLOCKED, 0)
    assert g.shortest_path(0, 4) == [0, 1, 2, 3, 4]
    g.remove_edge(1, 2)
    assert g.shortest_path(0, 4) is None
    assert g.component(4) == {2, 3, 4}
    g.remove_component(4)
    assert set(g.vertices) == {0, 1}
    assert all(2 not in k and 4 not in k for k in g.edges)


def test_moving_a_vertex_makes_its_edges_unknown() -> None:
    g = _line_graph(3)
    g.set_q(1, np.array([1.0, 0.5]))
    assert g.edge(0, 1).status == UNKNOWN and g.edge(1, 2).status == UNKNOWN
    assert g.by_heuristic(np.array([1.0, 0.6]))[0] == 1


def test_abstract_keeps_ends_and_every_segment_reaches(wall_space: PlanSpace) -> None:
    path = solve_rrtconnect(wall_space, np.array([1.0, 1.0]), np.array([9.0, 1.0]), seed=3)
    assert path is not None
    chain = abstract(path, lambda a, b: reach(wall_space, a, b))
    assert chain is not None and chain[0] == 0 and chain[-1] == len(path) - 1
    assert len(chain) <= len(path)
    for i, j in itertools.pairwise(chain):
        assert reach(wall_space, path[i], path[j])
    # a path Reach can follow directly compresses to one segment
    straight = np.array([[1.0, 9.0], [2.0, 9.0], [3.0, 9.5], [9.0, 9.0]])
    assert abstract(straight, lambda a, b: reach(wall_space, a, b)) == [0, 3]
    assert abstract(path, lambda a, b: reach(wall_space, a, b), max_chain=1) is None


def test_rrtconnect_repeats_with_a_seed_and_counts(wall_space: PlanSpace) -> None:
    a, b = np.array([1.0, 1.0]), np.array([9.0, 1.0])
    p1 = solve_rrtconnect(wall_space, a, b, seed=7)
    n1 = wall_space.counter.total
    p2 = solve_rrtconnect(wall_space, a, b, seed=7)
    assert p1 is not None and p2 is not None and np.array_equal(p1, p2)
    assert wall_space.counter.total == 2 * n1 > 0
    assert all(reach(wall_space, p1[i], p1[i + 1]) for i in range(len(p1) - 1))
    assert solve_rrtconnect(wall_space, a, np.array([5.0, 1.0]), seed=1) is None  # goal in the wall


def test_two_segment_solve(wall_space: PlanSpace) -> None:
    a, b = np.array([1.0, 9.0]), np.array([9.0, 1.0])
    p = solve_two_segment(wall_space, a, b)
    assert p is not None and len(p) <= 3
    assert all(reach(wall_space, p[i], p[i + 1]) for i in range(len(p) - 1))
    # around the wall needs a bend above y = 8 that both ends can see: impossible from y = 1
    assert solve_two_segment(wall_space, np.array([1.0, 1.0]), np.array([9.0, 1.0])) is None
