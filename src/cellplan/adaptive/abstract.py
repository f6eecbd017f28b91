"""Abstract: compress a Solve path into a short chain of subgoals (Section 2.3).

The paper suggests binary search on the discretised solution path. We search
over the Solve path's own waypoints, longest reachable prefix first: from the
current anchor, try the path's end; if Reach fails, binary-search the last
waypoint that Reach still connects to the anchor (treating reachability as
monotone along the path, which is the assumption behind the paper's binary
search), make it the next subgoal and repeat. Every chain segment is verified
by Reach, so the chain is always traversable. With ``max_chain`` the chain is
bounded: a longer one is reported as a failure (None).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cellplan.adaptive.space import FloatArray

ReachFn = Callable[[FloatArray, FloatArray], bool]


def abstract(path: FloatArray, reach: ReachFn, max_chain: int | None = None) -> list[int] | None:
    """Indices of the waypoints of ``path`` kept as the chain, first and last included.

    Parameters
    ----------
    path
        ``(m, dim)`` waypoints from Solve, every consecutive pair traversable.
    reach
        The (counted) Reach predicate.
    max_chain
        Largest number of segments allowed in the chain, or ``None``.

    Returns
    -------
    list of int or None
        Chain waypoint indices; ``None`` when a segment between consecutive
        waypoints fails Reach (a path Reach cannot follow) or the chain is too long.
    """
    path = np.atleast_2d(path)
    m = path.shape[0] - 1
    chain = [0]
    anchor = 0
    while anchor < m:
        if reach(path[anchor], path[m]):
            best = m
        else:
            lo, hi = anchor + 1, m  # hi is known to fail
            if lo == hi:
                return None
            if not reach(path[anchor], path[lo]):
                return None
            while hi - lo > 1:
                mid = (lo + hi) // 2
                if reach(path[anchor], path[mid]):
                    lo = mid
                else:
                    hi = mid
            best = lo
        chain.append(best)
        anchor = best
        if max_chain is not None and len(chain) - 1 > max_chain:
            return None
    return chain
