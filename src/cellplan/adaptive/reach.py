"""Reach, the fast local planner (Section 2; the go-straight planner of Section 3).

``reach(space, a, b)`` succeeds iff every configuration of the straight segment
``ab`` discretised at ``space.resolution`` is free: the segment is cut into
``n = ceil(|b - a| / resolution)`` equal steps and its ``n + 1`` points are
checked. On a periodic coordinate the segment takes the short way round
(:meth:`~.space.PlanSpace.difference`). The points are tested in bisection order
(both ends, the middle, the quarter points, ...), one batch per level, so a
blocked segment usually fails after a few checks. The predicate depends only on
the unordered pair, so Reach is symmetric as the paper requires.

``reach_potential`` is the potential-field hill-climbing variant: greedy steps
down the attractive potential ``|q - goal|`` among the free neighbours on a
lattice of the resolution, started from the lexicographically smaller end so
that it too is symmetric.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import NDArray

from cellplan.adaptive.space import FloatArray, PlanSpace


@functools.lru_cache(maxsize=4096)
def bisection_levels(n: int) -> tuple[NDArray[np.intp], ...]:
    """Indices ``0..n`` grouped by bisection level: ``[0, n]``, then midpoints, level by level.

    Every index appears exactly once; level ``k`` holds the points first reached
    by halving the intervals of level ``k - 1``.
    """
    if n < 1:
        return (np.array([0], dtype=np.intp),)
    levels = [np.array([0, n], dtype=np.intp)]
    seen = {0, n}
    intervals = [(0, n)]
    while intervals:
        level: list[int] = []
        nxt: list[tuple[int, int]] = []
        for lo, hi in intervals:
            if hi - lo < 2:
                continue
            mid = (lo + hi) // 2
            if mid not in seen:
                seen.add(mid)
                level.append(mid)
            nxt.append((lo, mid))
            nxt.append((mid, hi))
        if level:
            levels.append(np.array(level, dtype=np.intp))
        intervals = nxt
    return tuple(levels)


def segment_steps(
    a: FloatArray, b: FloatArray, resolution: float, space: PlanSpace | None = None
) -> int:
    """Number of steps ``n`` of the discretised segment ``ab`` (at least 1 unless a == b);
    with ``space``, periodic coordinates take the short way round."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    gap = b - a if space is None else space.difference(a, b)
    length = float(np.linalg.norm(gap))
    return int(math.ceil(length / resolution - 1e-9)) if length > 0 else 0


def segment_points(
    a: FloatArray, b: FloatArray, resolution: float, space: PlanSpace | None = None
) -> FloatArray:
    """The ``n + 1`` configurations of the discretised segment ``ab``, in order from ``a``
    (with ``space``: the short way round on periodic coordinates, not wrapped)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    n = segment_steps(a, b, resolution, space)
    if n == 0:
        return a[None, :].copy()
    t = np.arange(n + 1, dtype=float) / n
    return a + t[:, None] * (b - a if space is None else space.difference(a, b))


def reach(space: PlanSpace, a: FloatArray, b: FloatArray) -> bool:
    """Reach(a, b): is the straight segment free at ``space.resolution``? (counted)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    n = segment_steps(a, b, space.resolution, space)
    direction = space.difference(a, b)
    for idx in bisection_levels(n):
        t = idx / n if n else np.zeros(1)
        if not np.all(space.free(a + t[:, None] * direction)):
            return False
    return True


def path_is_free(space: PlanSpace, path: FloatArray, refine: int = 4) -> bool:
    """Uncounted re-check of a polyline at ``resolution / refine`` (for executed paths;
    each segment the short way round on periodic coordinates, as Reach went)."""
    path = np.atleast_2d(np.asarray(path, dtype=float))
    if path.shape[0] == 1:
        return bool(space.free_uncounted(path)[0])
    res = space.resolution / refine
    pts = [segment_points(path[i], path[i + 1], res, space) for i in range(path.shape[0] - 1)]
    return bool(np.all(space.free_uncounted(np.concatenate(pts))))


def reach_potential(
    space: PlanSpace, a: FloatArray, b: FloatArray, max_steps: int = 400
) -> FloatArray | None:
    """Potential-field hill climbing between ``a`` and ``b``; the path, or ``None`` if stuck.

    From the lexicographically smaller end, repeatedly move to the free lattice
    neighbour (step ``resolution`` along each axis, plus the straight step
    towards the goal) with the lowest potential ``|q - goal|``; succeed when
    the goal is within one step and that last step is free. A local minimum
    (no neighbour lowers the potential) is failure, as for any greedy
    hill-climber. The path is returned from ``a`` to ``b`` whichever end it
    was grown from.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    flip = tuple(b) < tuple(a)
    start, goal = (b, a) if flip else (a, b)
    step = space.resolution
    dim = space.dim
    axes = np.concatenate([np.eye(dim), -np.eye(dim)]) * step
    if not space.free(start[None, :])[0]:
        return None
    q = start.copy()
    path = [q.copy()]
    for _ in range(max_steps):
        gap = space.difference(q, goal)
        dist = float(np.linalg.norm(gap))
        if dist <= step:
            if not space.free(goal[None, :])[0]:
                return None
            path.append(goal.copy())
            out = space.wrap(np.array(path))
            return out[::-1] if flip else out
        cands = np.concatenate([(q + gap / dist * step)[None, :], q + axes])
        pot = space.distance(goal, cands)
        order = np.argsort(pot, kind="stable")
        cands, pot = cands[order], pot[order]
        better = pot < dist - 1e-12
        cands = cands[better]
        if cands.shape[0] == 0:
            return None
        ok = space.free(cands)
        if not ok.any():
            return None
        q = cands[int(np.argmax(ok))]
        path.append(q.copy())
    return None
