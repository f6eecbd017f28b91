"""Memory of the strategies model in a 3-D cell (strategies_ur5).

``Workcell3D.in_region`` poses the carried part's sphere cover at every configuration;
on the model's grid (110,592 cells) that was 550 MB at once. It now takes the
configurations in chunks: the answer is that of the configurations one by one, and its
peak stays within :meth:`Workcell3D.batch_bytes`, which the strategies memory estimate
counts.
"""

from __future__ import annotations

import functools
import tracemalloc

import numpy as np
import pytest

import cellplan
from cellplan.workcell3d import _CHUNK


@functools.cache
def ur5():
    return cellplan.load("strategies_ur5").workcell


@pytest.mark.parametrize(
    ("region", "kind", "carrying"),
    [("D2", "contact", "P1"), ("S2", "contact", None), ("S1", "enclosure", None)],
)
def test_chunked_region_test_is_the_test_of_each_configuration(region, kind, carrying):
    cell = ur5()
    rng = np.random.default_rng(5)
    # Around the configurations that reach the region, so both answers occur.
    centre = next(q for q in cell.reach_region(region) if q is not None)
    q = centre + rng.normal(0.0, 0.15, size=(_CHUNK + 300, 3))
    q = np.clip(q, cell.robot.lower, cell.robot.upper)
    whole = cell.in_region(q, region, kind, None, carrying)
    # The oracle: pieces far below a chunk, concatenated.
    pieces = np.concatenate(
        [cell.in_region(q[i : i + 97], region, kind, None, carrying) for i in range(0, len(q), 97)]
    )
    np.testing.assert_array_equal(whole, pieces)
    assert whole.any() and not whole.all()


def test_region_test_peak_memory_is_bounded_by_batch_bytes():
    cell = ur5()
    q = cell.sample(6 * _CHUNK, np.random.default_rng(1))
    cell.in_region(q[:10], "D1", "contact", None, "P1")  # warm the caches (prepared solids)
    tracemalloc.start()
    try:
        cell.in_region(q, "D1", "contact", None, "P1")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # Unchunked, the posed cover alone was 65 spheres x 3 x 8 bytes per configuration
    # (74 MB here, twice with its copies); chunked it is bounded by one chunk's rows.
    assert peak <= cell.batch_bytes(len(q), "P1")
    assert peak < len(q) * 65 * 24
