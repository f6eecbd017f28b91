"""The configuration space the adaptive planners work in: a counted validity test.

Every planner of this package sees the workcell only through :class:`PlanSpace`:
box joint bounds, a straight-line resolution, and ``free(Q)``, a batched
validity test whose every call is counted (:mod:`.counters`). A coordinate the
robot marks periodic (a revolute joint without limits, or with limits spanning the
full turn; a rotating body's heading) is a circle: differences take the short way
round (:meth:`PlanSpace.difference`), straight segments follow them, and
configurations are wrapped to (-pi, pi] before they are tested, so a path may cross
+-pi. Other coordinates are intervals. OMPL's state space (:mod:`.solve`) is built to
match: ``SO2`` for a periodic coordinate, a real interval otherwise.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from cellplan.adaptive.counters import CheckCounter
from cellplan.errors import ArgumentError
from cellplan.geometry import wrap_angle

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IsFree = Callable[[FloatArray], BoolArray]


def and_validity(base: IsFree, user: IsFree) -> IsFree:
    """``base(Q) & user(Q)``: a user's validity test AND-ed with the workcell's (as OMPL's
    ``SimpleSetup`` takes one). ``user`` sees only the rows ``base`` accepts; it must
    return ``bool[N]`` for ``Q`` of shape ``(N, dim)``."""

    def free(Q: FloatArray) -> BoolArray:
        out = np.array(base(Q), dtype=bool)
        if out.any():
            rows = Q[out]
            answer = np.asarray(user(rows))
            if answer.shape != (rows.shape[0],) or answer.dtype != np.bool_:
                raise ArgumentError(
                    f"must return bool[N] for Q of shape (N, dim); for shape {rows.shape} "
                    f"it returned {answer.dtype} of shape {answer.shape}",
                    "validity",
                )
            out[out] = answer
        return out

    return free


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
    periodic
        Which coordinates are angles on a circle (their bounds are then ignored:
        values are wrapped to (-pi, pi]); empty means none.
    """

    is_free: IsFree
    lower: FloatArray
    upper: FloatArray
    resolution: float
    counter: CheckCounter = field(default_factory=CheckCounter)
    periodic: tuple[bool, ...] = ()

    def __post_init__(self) -> None:
        self.lower = np.asarray(self.lower, dtype=float)
        self.upper = np.asarray(self.upper, dtype=float)
        if self.lower.shape != self.upper.shape or np.any(self.upper <= self.lower):
            raise ValueError("PlanSpace needs lower < upper of equal shape")
        if not self.resolution > 0:
            raise ValueError("resolution must be positive")
        if not self.periodic:
            self.periodic = (False,) * self.dim
        if len(self.periodic) != self.dim:
            raise ValueError("periodic needs one flag per coordinate")
        self._mask = np.array(self.periodic, dtype=bool)

    @property
    def dim(self) -> int:
        return int(self.lower.shape[0])

    @property
    def any_periodic(self) -> bool:
        """Whether some coordinate wraps round."""
        return bool(self._mask.any())

    def wrap(self, Q: FloatArray) -> FloatArray:
        """``Q`` with periodic coordinates wrapped to (-pi, pi] (a copy)."""
        Q = np.array(Q, dtype=float)
        if self.any_periodic:
            Q[..., self._mask] = wrap_angle(Q[..., self._mask])
        return Q

    def difference(self, a: FloatArray, B: FloatArray) -> FloatArray:
        """``B - a`` with periodic coordinates taking the short way round (in [-pi, pi])."""
        D = np.asarray(B, dtype=float) - np.asarray(a, dtype=float)
        if self.any_periodic:
            D[..., self._mask] = wrap_angle(D[..., self._mask])
        return D

    def _inside(self, Q: FloatArray) -> BoolArray:
        inside = (Q >= self.lower) & (Q <= self.upper)
        return np.all(inside | self._mask, axis=1)

    def free(self, Q: FloatArray) -> BoolArray:
        """Counted validity of configurations ``Q`` (``(N, dim)``); out of bounds is not free."""
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        self.counter.add(Q.shape[0])
        return self.free_uncounted(Q)

    def free_uncounted(self, Q: FloatArray) -> BoolArray:
        """Validity without counting (re-checks of executed paths, tests)."""
        Q = self.wrap(np.atleast_2d(np.asarray(Q, dtype=float)))
        inside = self._inside(Q)
        out = np.zeros(Q.shape[0], dtype=bool)
        if inside.any():
            out[inside] = np.asarray(self.is_free(Q[inside]), dtype=bool)
        return out

    def distance(self, a: FloatArray, B: FloatArray) -> FloatArray:
        """Euclidean distances from ``a`` (``(dim,)``) to each row of ``B`` (``(N, dim)``),
        the short way round on periodic coordinates."""
        return np.asarray(np.linalg.norm(self.difference(a, np.atleast_2d(B)), axis=1), dtype=float)

    def unwrap(self, path: FloatArray) -> FloatArray:
        """A polyline whose consecutive points differ by the short way round (continuous
        angles, which may leave (-pi, pi]); it starts at ``path[0]``."""
        path = np.atleast_2d(np.asarray(path, dtype=float))
        if not self.any_periodic or len(path) < 2:
            return path.copy()
        steps = self.difference(path[:-1], path[1:])
        return np.asarray(np.concatenate([path[:1], path[:1] + np.cumsum(steps, axis=0)]))

    def with_is_free(self, is_free: IsFree) -> PlanSpace:
        """The same space and counter over another validity test (after a workcell change)."""
        return PlanSpace(
            is_free, self.lower, self.upper, self.resolution, self.counter, self.periodic
        )
