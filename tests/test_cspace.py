"""C-space grids and conservative bitmaps."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from cellplan.cspace import Grid, free_bitmap, region_bitmap
from cellplan.workcell import load_workcell
from workcells import rotating_cell

P1 = load_workcell("strategies_p1")[1]
P6 = load_workcell("strategies_p6")[1]
ROT = rotating_cell()

CASES = {
    "translating-fft": (P1, (100, 100), "fft", "P1"),
    "translating-exact": (P1, (50, 50), "exact", "P2"),
    "rotating-fft": (ROT, (40, 30, 24), "fft", "bar"),
    "arm-exact": (P6, (24, 24, 24), "exact", "P1"),
}
_BITMAPS: dict = {}


def bitmap(key: str, carrying: bool):
    if (key, carrying) not in _BITMAPS:
        cell, shape, method, part = CASES[key]
        grid = Grid.for_robot(cell.robot, shape)
        _BITMAPS[key, carrying] = (
            grid,
            free_bitmap(cell, grid, part if carrying else None, "none", method),
        )
    return _BITMAPS[key, carrying]


@pytest.mark.parametrize("key", list(CASES))
@given(seed=st.integers(0, 2**32 - 1), carrying=st.booleans())
def test_free_cells_are_free_everywhere_in_their_box(key, seed, carrying):
    cell, _, _, part = CASES[key]
    grid, free = bitmap(key, carrying)
    rng = np.random.default_rng(seed)
    idx = np.argwhere(free)
    pick = idx[rng.integers(0, len(idx), 64)]
    q = grid.config_of(pick) + rng.uniform(-0.5, 0.5, pick.shape) * grid.spacing
    assert not cell.collides(q, part if carrying else None, "none").any()


@pytest.mark.parametrize("key", list(CASES))
@pytest.mark.parametrize("carrying", [False, True])
def test_bitmap_agrees_with_exact_checks_except_near_c_obstacle_boundaries(key, carrying):
    cell, _, _, part = CASES[key]
    grid, free = bitmap(key, carrying)
    centres = grid.points()
    exact_free = cell.free(centres, part if carrying else None, "none").reshape(grid.shape)
    assert not (free & ~exact_free).any()
    # A blocked cell whose centre is free lies within one cell of a C-obstacle:
    # moving one cell in every axis brings the robot into contact.
    disagree = (~free & exact_free).ravel()
    reach = cell.part(part).reach() if carrying else 0.0
    one_cell = cell.robot.workspace_step(grid.spacing, reach)[0]
    gaps = cell.clearance(centres[disagree], part if carrying else None, "none")
    assert np.all(gaps <= one_cell + 1e-9)
    assert free.any()


def test_fft_and_exact_methods_agree_on_most_cells():
    grid = Grid.for_robot(P1.robot, (50, 50))
    a = free_bitmap(P1, grid, method="fft")
    b = free_bitmap(P1, grid, method="exact")
    assert (a == b).mean() > 0.95


def test_grid_indexing_round_trip_and_wrapping():
    grid = Grid(np.array([0.0, -np.pi]), np.array([10.0, np.pi]), (5, 8), (False, True))
    idx = np.array([[0, 0], [4, 7], [2, 3]])
    np.testing.assert_array_equal(grid.index_of(grid.config_of(idx)), idx)
    np.testing.assert_array_equal(grid.index_of(np.array([[10.0, np.pi + 0.1]])), [[4, 0]])
    np.testing.assert_array_equal(grid.index_of(np.array([[-1.0, -np.pi - 0.1]])), [[0, 7]])
    assert grid.points().shape == (40, 2)
    np.testing.assert_allclose(grid.coordinates(grid.config_of(idx)), idx)
    with pytest.raises(ValueError):
        Grid(np.array([0.0]), np.array([0.0]), (3,), (False,))


def test_region_bitmaps_mark_source_components():
    grid = Grid.for_robot(P6.robot, (24, 24, 24))
    both = region_bitmap(P6, grid, "S1")
    parts = [region_bitmap(P6, grid, "S1", component=i) for i in range(2)]
    assert parts[0].any() and parts[1].any()
    np.testing.assert_array_equal(both, parts[0] | parts[1])
    assert not (parts[0] & parts[1]).any()
