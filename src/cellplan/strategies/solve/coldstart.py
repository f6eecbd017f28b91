"""A first policy for a carrying or waiting layer by Dijkstra's algorithm (numba).

On the first pass of the structured solver every C and W layer is a deterministic
shortest path to its FMP cells (terminal cost ``t_f - g + h[next]``) with a positive
cost ``dt - g`` per stage. Gauss-Seidel sweeps started from ``+inf`` need one sweep per
direction before the wavefront has crossed the layer and several more to converge
(12-19 full sweeps per layer in 3-D). Here a label-setting pass gives every reachable
cell a value and an action first: Dijkstra's algorithm on the graph whose edge from a
cell follows each collision-free move to the corner of its landing point with the
largest interpolation weight (the corner tables store that corner first). This is an
approximation of the interpolated MDP (Section IV-B), good enough as the initial
policy of the policy iteration that follows: the solver evaluates this policy exactly
and improves it with full sweeps, so the answer does not depend on it.

Predecessors of a cell are found from the same translation-invariant corner offsets,
so only *interior* cells (whose moves need no clamping or wrapping) take part; the
others are left at ``+inf`` and filled in by the sweeps.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cellplan.strategies.model.stencils import decode
from cellplan.strategies.solve.law import FMP, Law, fmp_value


@njit(cache=True, inline="always")
def _push(keys, vals, n, key, val):  # pragma: no cover - numba
    """Insert into the binary min-heap of size ``n``; returns the new size."""
    i = n
    keys[i] = key
    vals[i] = val
    while i > 0:
        parent = (i - 1) >> 1
        if keys[parent] <= keys[i]:
            break
        keys[parent], keys[i] = keys[i], keys[parent]
        vals[parent], vals[i] = vals[i], vals[parent]
        i = parent
    return n + 1


@njit(cache=True, inline="always")
def _pop(keys, vals, n):  # pragma: no cover - numba
    """Remove the smallest entry of the heap of size ``n`` (it must be non-empty)."""
    n -= 1
    keys[0] = keys[n]
    vals[0] = vals[n]
    i = 0
    while True:
        left = 2 * i + 1
        if left >= n:
            break
        child = left
        if left + 1 < n and keys[left + 1] < keys[left]:
            child = left + 1
        if keys[i] <= keys[child]:
            break
        keys[child], keys[i] = keys[i], keys[child]
        vals[child], vals[i] = vals[i], vals[child]
        i = child
    return n


@njit(cache=True)
def dijkstra_layer(m, h, g, pol, model):  # pragma: no cover - numba
    """Values ``h[m]`` and actions ``pol[m]`` of layer ``m`` by Dijkstra (see module doc).

    Only cells the label-setting pass reaches are written; returns their number (0 when
    the stage cost ``cost[m] - g`` is not positive, where Dijkstra does not apply).
    """
    moves = model.moves
    lay = model.layers
    live = lay.live
    tf = lay.tf
    valid = moves.valid
    coff = moves.coff
    interior = moves.interior
    heading_axis = moves.heading_axis
    shape = model.grid.shape
    step = lay.cost[m] - g
    nxt = lay.fmp_next[m]
    if step <= 0.0 or nxt < 0:
        return 0
    ncell = live.shape[1]
    d = shape.shape[0]
    kcls = lay.vcls[m]
    na = moves.nact[kcls]
    n_t = coff.shape[2]
    dist = np.full(ncell, np.inf)
    done = np.zeros(ncell, np.bool_)
    cap = ncell * (na + 1) + 1
    keys = np.empty(cap)
    vals = np.empty(cap, np.int64)
    size = 0
    law = Law(h, h, live, True, True, False)
    opt = lay.opt_ptr[m]
    for c in range(ncell):
        if live[m, c] and tf[opt, c] < np.inf:
            # The terminal cost of the layer: FMP (the law of :mod:`.law`).
            v, _ = fmp_value(model, law, opt, c, (tf[opt, c] - g, 0.0))
            if v < np.inf:
                dist[c] = v
                pol[m, c] = FMP
                size = _push(keys, vals, size, v, c)
    mi = np.empty(d, np.int64)
    reached = 0
    while size > 0:
        v = keys[0]
        i = vals[0]
        size = _pop(keys, vals, size)
        if done[i] or v > dist[i]:
            continue
        done[i] = True
        h[m, i] = v
        reached += 1
        nd = v + step
        for a in range(na):
            for t in range(n_t):
                c = i - coff[kcls, a, t, 0]
                if c < 0 or c >= ncell or done[c] or nd >= dist[c]:
                    continue
                if not live[m, c] or not interior[kcls, c] or ((valid[kcls, c] >> a) & 1) == 0:
                    continue
                if heading_axis >= 0:
                    decode(c, shape, mi)
                    if mi[heading_axis] != t:
                        continue
                dist[c] = nd
                pol[m, c] = a
                size = _push(keys, vals, size, nd, c)
    return reached
