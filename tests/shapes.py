"""Hypothesis strategies for planar shapes used by several test modules."""

from __future__ import annotations

import numpy as np
import shapely
from hypothesis import assume
from hypothesis import strategies as st


@st.composite
def star_polygon(
    draw: st.DrawFn, cx: float = 0.0, cy: float = 0.0, rmax: float = 5.0
) -> np.ndarray:
    """A simple (possibly non-convex) star-shaped polygon around (cx, cy)."""
    n = draw(st.integers(3, 9))
    angles = np.sort(
        np.array(
            draw(
                st.lists(
                    st.floats(0, 2 * np.pi, exclude_max=True), min_size=n, max_size=n, unique=True
                )
            )
        )
    )
    if np.min(np.diff(np.r_[angles, angles[0] + 2 * np.pi])) < 0.05:
        angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    radii = np.array(draw(st.lists(st.floats(0.3 * rmax, rmax), min_size=n, max_size=n)))
    pts = np.c_[cx + radii * np.cos(angles), cy + radii * np.sin(angles)]
    assume(shapely.Polygon(pts).is_valid)
    return pts


poses = st.tuples(st.floats(-10, 10), st.floats(-10, 10), st.floats(-np.pi, np.pi))
