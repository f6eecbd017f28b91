"""The configuration space the adaptive planners work in: a counted validity test.

Every planner of this package sees the workcell only through :class:`PlanSpace`:
box joint bounds, a straight-line resolution, and ``free(Q)``, a batched
validity test whose every call is counted (:mod:`.counters`). Joints are treated
as intervals (no wrap-around), so OMPL's ``RealVectorStateSpace`` and the
straight-line Reach agree exactly on distances and interpolation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from cellplan.adaptive.counters import CheckCounter

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IsFree = Callable[[FloatArray], BoolArray]


@dataclass
class PlanSpace:
    """A bounded configuration space with a counted validity test.

    Parameters
    ----------
    is_free
        ``is_free(Q)`` for ``Q`` of shape ``(N, dim)`` returns ``bool[N]``.
    lower, upper
        Bounds of each coordinate.
    resolution
        Largest step (Euclidean, in configuration units) between two checked
        configurations of a straight segment; the "stated resolution" of Reach.
    counter
        Where checks are counted.
    """

    is_free: IsFree
    lower: FloatArray
    upper: FloatArray
    resolution: float
    counter: CheckCounter = field(default_factory=CheckCounter)

    def __post_init__(self) -> None:
        self.lower = np.asarray(self.lower, dtype=float)
        self.upper = np.asarray(self.upper, dtype=float)
        if self.lower.shape != self.upper.shape or np.any(self.upper <= self.lower):
            raise ValueError("PlanSpace needs lower < upper of equal shape")
        if not self.resolution > 0:
            raise ValueError("resolution must be positive")

    @property
    def dim(self) -> int:
        return int(self.lower.shape[0])

    def free(self, Q: FloatArray) -> BoolArray:
        """Counted validity of configurations ``Q`` (``(N, dim)``); out of bounds is not free."""
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        self.counter.add(Q.shape[0])
        inside = np.all((Q >= self.lower) & (Q <= self.upper), axis=1)
        out = np.zeros(Q.shape[0], dtype=bool)
        if inside.any():
            out[inside] = np.asarray(self.is_free(Q[inside]), dtype=bool)
        return out

    def free_uncounted(self, Q: FloatArray) -> BoolArray:
        """Validity without counting (re-checks of executed paths, tests)."""
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        inside = np.all((Q >= self.lower) & (Q <= self.upper), axis=1)
        out = np.zeros(Q.shape[0], dtype=bool)
        if inside.any():
            out[inside] = np.asarray(self.is_free(Q[inside]), dtype=bool)
        return out

    def distance(self, a: FloatArray, B: FloatArray) -> FloatArray:
        """Euclidean distances from ``a`` (``(dim,)``) to each row of ``B`` (``(N, dim)``)."""
        return np.asarray(np.linalg.norm(np.atleast_2d(B) - a, axis=1), dtype=float)

    def with_is_free(self, is_free: IsFree) -> PlanSpace:
        """The same space and counter over another validity test (after a workcell change)."""
        return PlanSpace(is_free, self.lower, self.upper, self.resolution, self.counter)
