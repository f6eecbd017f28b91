"""Shared fixtures: a fake box world for the planners, and small scenarios."""

from __future__ import annotations

import gc
from collections.abc import Iterator

import numpy as np
import pytest

from cellplan.adaptive.space import PlanSpace


def wall_is_free(Q: np.ndarray) -> np.ndarray:
    """A 10 x 10 square with a wall x in (4, 6), y < 8."""
    Q = np.atleast_2d(Q)
    return ~((Q[:, 0] > 4) & (Q[:, 0] < 6) & (Q[:, 1] < 8))


@pytest.fixture
def wall_space() -> PlanSpace:
    return PlanSpace(wall_is_free, np.zeros(2), np.full(2, 10.0), 0.05)


@pytest.fixture(autouse=True)
def _collect_ompl() -> Iterator[None]:
    yield
    gc.collect()
