"""The Jacobi Bellman operator over every state (numba, parallel): certificate and policy.

For relative values ``h`` the operator of the average-cost problem is (the right-hand
side of equation (9), Section III-C of the strategies paper, without ``g``)

    (T h)(m, x) = min( t_f(m, x) + h(next(m), x),                          FMP
                       l(m) + sum_b P_b h(L_b, x),                          stay
                       min_a  l(m) + sum_b P_b H_{L_b}(x + dx_a) )          moves a

with ``H`` the interpolation of :mod:`cellplan.strategies.interpolation` and the branches
``(L_b, P_b)`` of Section III-B. ``min (T h - h) <= g <= max (T h - h)`` over the live
states brackets the optimal gain (the span test of relative value iteration), which is
how every reported gain is certified (:func:`cellplan.strategies.solver.certify`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cellplan.strategies.stencils import EPS_W, decode, move_corners


@njit(cache=True, nogil=True)
def bellman_rows(h, out, policy, gap, subset, start, stop, model):  # pragma: no cover - numba
    """One Jacobi sweep over the states ``start <= m * N + c < stop``: ``out = T h`` there.

    No ``g`` is subtracted. ``policy[m, c]`` receives the minimising action: ``-1`` stay,
    ``-2`` FMP, ``a >= 0`` move ``a``; ``-3`` for states outside the MDP. Ties (within
    1e-12 relative) go to the first action in the order FMP, stay, moves. ``gap[m, c]``
    receives the second-best action value minus the best (``inf`` with a single action):
    adding to ``h`` anything whose span (max - min) is below it cannot change the action
    there. A non-empty ``subset`` (boolean, like ``h``) limits the sweep to the live
    states it marks (the outputs elsewhere are left as they were). Every state is
    independent, so disjoint ranges may run in parallel threads (the GIL is released).
    """
    moves = model.moves
    grid = model.grid
    lay = model.layers
    live = lay.live
    ncell = h.shape[1]
    some = subset.shape[0] > 0
    d = grid.shape.shape[0]
    ncorner = 1 << d
    mi = np.empty(d, np.int64)
    idx = np.empty(ncorner, np.int64)
    w = np.empty(ncorner)
    for m in range(start // ncell, (stop + ncell - 1) // ncell):
        nxt = lay.fmp_next[m]
        kcls = lay.vcls[m]
        na = moves.nact[kcls]
        b0 = lay.branch_ptr[m]
        b1 = lay.branch_ptr[m + 1]
        cost = lay.cost[m]
        for c in range(max(start - m * ncell, 0), min(stop - m * ncell, ncell)):
            if not live[m, c]:
                out[m, c] = np.nan
                policy[m, c] = -3
                gap[m, c] = np.nan
                continue
            if some and not subset[m, c]:
                continue
            decode(c, grid.shape, mi)
            best = np.inf
            second = np.inf
            arg = -3
            if nxt >= 0 and lay.tf[m, c] < np.inf and live[nxt, c]:
                best = lay.tf[m, c] + h[nxt, c]
                arg = -2
            sval = cost
            sok = True
            for b in range(b0, b1):
                L = lay.branch_layer[b]
                if not live[L, c]:
                    sok = False
                    break
                sval += lay.branch_prob[b] * h[L, c]
            if sok and sval < best and (best == np.inf or sval < best - 1e-12 * abs(best)):
                second = best
                best = sval
                arg = -1
            elif sok and sval < second:
                second = sval
            vb = moves.valid[kcls, c]
            inner = moves.interior[kcls, c]
            for a in range(na):
                if ((vb >> a) & 1) == 0:
                    continue
                nc = move_corners(
                    kcls,
                    a,
                    c,
                    mi,
                    inner,
                    moves.offs,
                    moves.fr,
                    moves.coff,
                    moves.cw,
                    moves.heading_axis,
                    grid.shape,
                    grid.periodic,
                    idx,
                    w,
                )
                val = cost
                ok = True
                for b in range(b0, b1):
                    L = lay.branch_layer[b]
                    ssum = 0.0
                    vsum = 0.0
                    for j in range(nc):
                        wj = w[j]
                        if wj > EPS_W and live[L, idx[j]]:
                            ssum += wj
                            vsum += wj * h[L, idx[j]]
                    if ssum <= EPS_W:
                        ok = False
                        break
                    val += lay.branch_prob[b] * vsum / ssum
                if ok and val < best and (best == np.inf or val < best - 1e-12 * abs(best)):
                    second = best
                    best = val
                    arg = a
                elif ok and val < second:
                    second = val
            out[m, c] = best
            policy[m, c] = arg
            gap[m, c] = second - best


@njit(cache=True, nogil=True)
def bellman_all(h, out, policy, gap, subset, model):  # pragma: no cover - numba
    """:func:`bellman_rows` over every state, in the calling thread."""
    bellman_rows(h, out, policy, gap, subset, 0, h.shape[0] * h.shape[1], model)
