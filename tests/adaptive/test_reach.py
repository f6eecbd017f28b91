from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cellplan.adaptive.counters import CheckCounter
from cellplan.adaptive.reach import (
    bisection_levels,
    path_is_free,
    reach,
    reach_potential,
    segment_points,
)
from cellplan.adaptive.space import PlanSpace


def wall_is_free(Q: np.ndarray) -> np.ndarray:
    Q = np.atleast_2d(Q)
    return ~((Q[:, 0] > 4) & (Q[:, 0] < 6) & (Q[:, 1] < 8))


@given(st.integers(min_value=0, max_value=300))
def test_bisection_levels_cover_every_index_once(n: int) -> None:
    idx = np.concatenate(bisection_levels(n))
    assert sorted(idx.tolist()) == list(range(n + 1))
    if n >= 1:
        assert set(bisection_levels(n)[0].tolist()) == {0, n}


coord = st.floats(min_value=0.0, max_value=10.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(coord, coord, coord, coord)
def test_reach_is_symmetric_and_matches_dense_check(
    x0: float, y0: float, x1: float, y1: float
) -> None:
    space = PlanSpace(wall_is_free, np.zeros(2), np.full(2, 10.0), 0.05)
    a, b = np.array([x0, y0]), np.array([x1, y1])
    forward = reach(space, a, b)
    assert forward == reach(space, b, a)
    assert forward == bool(np.all(wall_is_free(segment_points(a, b, 0.05))))


def test_reach_counts_checks_and_fails_early(wall_space: PlanSpace) -> None:
    assert not reach(wall_space, np.array([1.0, 1.0]), np.array([9.0, 1.0]))
    failed = wall_space.counter.total
    assert failed < 10  # the midpoint is inside the wall: found at the second level
    assert reach(wall_space, np.array([1.0, 9.0]), np.array([9.0, 9.0]))
    assert wall_space.counter.total - failed == 161  # 8 / 0.05 steps + 1 points


def test_path_recheck_finds_a_thin_obstacle_between_samples() -> None:
    def thin(Q: np.ndarray) -> np.ndarray:
        return ~((Q[:, 0] > 5.01) & (Q[:, 0] < 5.02))

    space = PlanSpace(thin, np.zeros(2), np.full(2, 10.0), 0.5)
    path = np.array([[0.0, 1.0], [10.0, 1.0]])
    assert reach(space, path[0], path[1])  # samples at 5.0 and 5.5 miss the sliver
    assert not path_is_free(space, path, refine=64)


def test_potential_reach_goes_around_nothing_and_is_symmetric(wall_space: PlanSpace) -> None:
    a, b = np.array([1.0, 9.0]), np.array([3.0, 8.5])
    p = reach_potential(wall_space, a, b)
    assert p is not None and np.allclose(p[0], a) and np.allclose(p[-1], b)
    q = reach_potential(wall_space, b, a)
    assert q is not None
    # blocked by the wall: greedy descent gets stuck at the wall's face
    assert reach_potential(wall_space, np.array([1.0, 1.0]), np.array([9.0, 1.0])) is None
    assert reach_potential(wall_space, np.array([9.0, 1.0]), np.array([1.0, 1.0])) is None


def test_counter_categories_are_separate() -> None:
    counter = CheckCounter()
    space = PlanSpace(wall_is_free, np.zeros(2), np.full(2, 10.0), 0.05, counter)
    with counter.charge("trace"):
        space.free(np.zeros((3, 2)))
        with counter.charge("solve"):
            space.free(np.zeros((2, 2)))
    with counter.charge("repair"), counter.charge("solve"):
        space.free(np.zeros((5, 2)))  # repair is sticky
    assert (
        counter.counts["trace"] == 3
        and counter.counts["solve"] == 2
        and counter.counts["repair"] == 5
    )
