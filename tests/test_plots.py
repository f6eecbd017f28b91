"""Shared drawing helpers: grid layout for frames, GIF sizes, frame rendering."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cellplan.errors import ArgumentError
from cellplan.plots import GIF_SIZE, GIF_SIZE_RANGE, check_gif_size, figure_to_rgb, grid_shape


@given(st.integers(1, 200), st.floats(0.05, 20.0))
def test_grid_shape_holds_every_panel_without_an_empty_row(count, aspect):
    rows, cols = grid_shape(count, aspect)
    assert rows * cols >= count
    assert (rows - 1) * cols < count  # no empty row
    assert cols <= count


def test_grid_shape_follows_the_cell_aspect():
    # 18 frames (the run): square cells in 6 columns of 3 rows (page about 1.6:1);
    # wide cells stack in fewer columns, tall ones spread over more.
    assert grid_shape(18, 1.0) == (3, 6)
    assert grid_shape(18, 3.0)[1] < grid_shape(18, 1.0)[1] < grid_shape(18, 0.4)[1]
    assert grid_shape(1, 5.0) == (1, 1)
    rows, cols = grid_shape(12, 2.0)
    assert abs(math.log(cols * 2.0 / rows / 1.6)) < math.log(2.0)


@pytest.mark.parametrize("bad", [(0, 1.0), (3, 0.0), (3, float("nan"))])
def test_grid_shape_refuses_nonsense(bad):
    with pytest.raises(ValueError):
        grid_shape(*bad)


def test_gif_size_default_and_range():
    lo, hi = GIF_SIZE_RANGE
    assert lo <= GIF_SIZE <= hi and GIF_SIZE >= 480
    assert check_gif_size(lo) == lo and check_gif_size(str(hi)) == hi
    for bad in (lo - 1, hi + 1, "12.5", "wide", True, ""):
        with pytest.raises(ArgumentError) as err:
            check_gif_size(bad)
        assert err.value.problems[0].field == "--gif-size"


def test_figure_to_rgb_renders_the_requested_width():
    from cellplan.plots import new_figure

    fig, _ = new_figure(size=3.0)
    fig.set_size_inches(4.0, 3.0)
    assert figure_to_rgb(fig, 500).shape == (375, 500, 3)
