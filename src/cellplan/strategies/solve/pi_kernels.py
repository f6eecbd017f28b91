"""The numba kernels of policy iteration (:mod:`.policy_iteration`): a policy's rows,
hop distances to the targets of a first policy, and back-substitution of transient
components.

A policy's transition matrix is the transition law of :mod:`cellplan.strategies.solve.law`
written as successors (:func:`action_successors`).
"""

from typing import NamedTuple

import numpy as np
from numba import njit

from cellplan.strategies.model.stencils import EPS_W, cell_of_order, decode, fmp_code, fmp_option
from cellplan.strategies.solve.law import (
    OUTSIDE,
    STAY,
    borrowed,
    keep,
    landing_row,
    lend,
    move_stencil,
    move_supported,
    scratch,
    site_at,
)


class PolicyRows(NamedTuple):
    """A policy over the live states and the room its transition matrix is written in.

    ``states`` are the flat ``m * N + c`` of the live states, ``actions`` their actions,
    ``state_index`` the state number of each ``(m, c)`` (-1 outside). Row ``k``'s successors and
    probabilities are written to ``cols`` and ``vals`` from ``starts[k]`` on (room for the
    most its mode can have), their number to ``counts[k]``, its loss to ``cost[k]``.
    """

    states: np.ndarray
    actions: np.ndarray
    state_index: np.ndarray
    starts: np.ndarray
    cols: np.ndarray
    vals: np.ndarray
    counts: np.ndarray
    cost: np.ndarray


@njit(cache=True, nogil=True)
def action_successors(m, c, a, index, model, s, out):  # pragma: no cover - numba
    """Successor states of action ``a`` at live state ``(m, c)`` and their probabilities.

    ``a`` is an FMP code (``-2``, or ``-3 - j`` for option ``j``), ``-1`` (stay) or a
    move. Fills ``out = (out_s, out_p)`` (state indices from ``index``, probabilities);
    returns ``(n, cost)``, ``n = -1`` where the action is not available (FMP not allowed or
    an outcome not live; a move not collision-free, or a branch with no live corner). The
    law is that of :mod:`cellplan.strategies.solve.law` as the Bellman operator reads it
    (:func:`cellplan.strategies.solve.bellman.bellman_rows`: the same weights and
    renormalisation), written as successors; a successor may appear twice (the caller's
    sparse matrix sums them). ``s`` is a :class:`.law.Scratch`, ``s.mi`` the multi-index
    of ``c``.
    """
    lay = model.layers
    moves = model.moves
    live = lay.live
    out_s, out_p = out
    n = 0
    j = fmp_option(a)
    if j >= 0:
        opt = lay.opt_ptr[m] + j
        if lay.fmp_next[m] < 0 or opt >= lay.opt_ptr[m + 1] or not lay.tf[opt, c] < np.inf:
            return -1, 0.0
        cost = lay.tf[opt, c]
        for o in range(lay.out_ptr[opt], lay.out_ptr[opt + 1]):
            p = lay.out_prob[o]
            if p <= 0.0:
                continue
            L = lay.out_layer[o]
            if not live[L, c]:
                return -1, 0.0
            cost += p * lay.out_cost[o]
            out_s[n] = index[L, c]
            out_p[n] = p
            n += 1
        return n, cost
    cost = lay.cost[m]
    b0 = lay.branch_ptr[m]
    b1 = lay.branch_ptr[m + 1]
    if a == STAY:
        for b in range(b0, b1):
            L = lay.branch_layer[b]
            if not live[L, c]:
                return -1, 0.0
            p = lay.branch_prob[b]
            if p > 0.0:
                out_s[n] = index[L, c]
                out_p[n] = p
                n += 1
        return n, cost
    k = lay.vcls[m]
    na = moves.nact[k]
    if a >= na or ((moves.valid[k, c] >> a) & 1) == 0:
        return -1, 0.0
    # With noisy motion (Section VI-4) the move lands at each of J displacements with
    # probability noise_prob[j] (table rows na + a J + j, :func:`.law.landing_row`).
    J = moves.noise_prob.shape[0]
    site = site_at(model, m, c, False, s.mi)
    for jn in range(J):
        pj = moves.noise_prob[jn] if J > 1 else 1.0
        if pj <= 0.0:
            continue
        nc = move_stencil(model, site, landing_row(na, a, jn, J) if J > 1 else a, s)
        for b in range(b0, b1):
            L = lay.branch_layer[b]
            ssum = 0.0
            for j in range(nc):
                if s.w[j] > EPS_W and live[L, s.idx[j]]:
                    ssum += s.w[j]
            if ssum <= EPS_W:
                return -1, 0.0
            p = lay.branch_prob[b] * pj
            if p <= 0.0:
                continue
            for j in range(nc):
                if s.w[j] > EPS_W and live[L, s.idx[j]]:
                    out_s[n] = index[L, s.idx[j]]
                    out_p[n] = p * s.w[j] / ssum
                    n += 1
    return n, cost


@njit(cache=True, nogil=True)
def policy_rows(rows, start, stop, model):  # pragma: no cover - numba
    """Rows ``start:stop`` of the policy's transition matrix and its cost vector, into the
    :class:`PolicyRows` ``rows``.

    Returns the number of rows whose action is not available (0 for a policy chosen by
    the Bellman operator; such a row is left empty).
    """
    model = borrowed(model)  # the law is inlined per move: no reference counting
    ncell = model.layers.live.shape[1]
    shape = model.grid.shape
    held = scratch(shape.shape[0])
    s = lend(held)
    bad = 0
    for k in range(start, stop):
        m = rows.states[k] // ncell
        c = rows.states[k] % ncell
        decode(c, shape, s.mi)
        at = rows.starts[k]
        room = rows.starts[k + 1] - at
        out = (rows.cols[at : at + room], rows.vals[at : at + room])
        n, cst = action_successors(m, c, rows.actions[k], rows.state_index, model, s, out)
        if n < 0:
            bad += 1
            n = 0
        rows.counts[k] = n
        rows.cost[k] = cst
    keep(held)
    return bad


@njit(cache=True, nogil=True)
def _first_available(m, c, index, model, s, out):  # pragma: no cover - numba
    """The first available action at ``(m, c)``: stay, the moves, then the FMP options."""
    lay = model.layers
    na = model.moves.nact[lay.vcls[m]]
    nopt = lay.opt_ptr[m + 1] - lay.opt_ptr[m]
    for a in range(-1, na + nopt):
        aa = a if a < na else fmp_code(a - na)
        n, _ = action_successors(m, c, aa, index, model, s, out)
        if n >= 0:
            return aa
    return OUTSIDE


@njit(cache=True, inline="always")
def _cell_hops(m, c, dist, index, model, acc):  # pragma: no cover - numba
    """FMP and stay offered to ``acc = (best, arg)``: their successors keep the cell, so
    their distance is one more than the nearest of the outcomes' (branches') states."""
    lay = model.layers
    live = lay.live
    best, arg = acc
    for j in range(lay.opt_ptr[m + 1] - lay.opt_ptr[m] if lay.fmp_next[m] >= 0 else 0):
        opt = lay.opt_ptr[m] + j
        if not lay.tf[opt, c] < np.inf:
            continue
        near = np.inf
        for o in range(lay.out_ptr[opt], lay.out_ptr[opt + 1]):
            if lay.out_prob[o] > 0.0:
                L = lay.out_layer[o]
                near = min(near, dist[index[L, c]]) if live[L, c] else -np.inf
        if near > -np.inf and near + 1 < best:
            best = near + 1
            arg = fmp_code(j)
    near = np.inf
    for b in range(lay.branch_ptr[m], lay.branch_ptr[m + 1]):
        L = lay.branch_layer[b]
        if not live[L, c]:
            near = np.inf
            break
        if lay.branch_prob[b] > 0.0:
            near = min(near, dist[index[L, c]])
    if near + 1 < best:
        best = near + 1
        arg = STAY
    return best, arg


@njit(cache=True, inline="always")
def _usable_moves(model, site, s):  # pragma: no cover - numba
    """The moves at ``site`` every landing of which has a live corner in every branch
    (:func:`.law.move_supported`), as a bitmask."""
    vb = model.moves.valid[site.k, site.c]
    live = model.layers.live
    bits = 0
    for a in range(model.moves.nact[site.k]):
        if (vb >> a) & 1 and move_supported(model, live, live[site.m], site, a, s, False):
            bits |= 1 << a
    return bits


@njit(cache=True, nogil=True)
def hop_sweep(dist, act, fixed, index, order, flips, usable, model):  # pragma: no cover
    """One Gauss-Seidel sweep of the hop distances ``d(s) = 1 + min_a min_{s'} d(s')``.

    ``dist`` (per state: 0 on the targets, a large number where unknown) and ``act`` are
    updated in place, except at the ``fixed`` states (the targets), which keep their
    action (or take the first available one, stay first, where it is ``-3``). The layers
    are visited in ``order``, the cells of each in the sweep order ``flips``
    (:func:`~cellplan.strategies.model.stencils.cell_of_order`). A state takes the action with
    the successor nearest to the targets, among the moves whose every successor is a live
    state (``usable``, a bitmask per state, found on the first visit: -1 before); a noisy
    move's successors for the distance are those of its first landing (Section VI-4).
    Returns whether any distance fell.
    """
    model = borrowed(model)  # the law is inlined per move: no reference counting
    lay = model.layers
    moves = model.moves
    live = lay.live
    shape = model.grid.shape
    ncell = live.shape[1]
    held = scratch(shape.shape[0])
    s = lend(held)
    width = (
        s.idx.shape[0]
        * moves.noise_prob.shape[0]
        * (lay.branch_prob.shape[0] + lay.out_prob.shape[0] + 1)
    )
    out = (np.empty(width, np.int64), np.empty(width))
    changed = False
    J = moves.noise_prob.shape[0]
    j0 = 0
    while J > 1 and moves.noise_prob[j0] <= 0.0:
        j0 += 1
    for m in order:
        k = lay.vcls[m]
        na = moves.nact[k]
        for kk in range(ncell):
            c = cell_of_order(kk, shape, flips, s.mi)
            if not live[m, c]:
                continue
            st = index[m, c]
            if fixed[st]:
                if act[st] == OUTSIDE:
                    act[st] = _first_available(m, c, index, model, s, out)
                continue
            best, arg = _cell_hops(m, c, dist, index, model, (dist[st], act[st]))
            site = site_at(model, m, c, False, s.mi)
            # The moves every landing of which has a live corner in every branch do not
            # change from sweep to sweep: found once per state (usable[st] < 0 until then).
            if usable[st] < 0:
                usable[st] = _usable_moves(model, site, s)
            bits = usable[st]
            # A hop goes through the first landing of positive probability: progress there
            # has positive probability, which is all a proper policy needs.
            for a in range(na):
                if ((bits >> a) & 1) == 0:
                    continue
                nc = move_stencil(model, site, landing_row(na, a, j0, J) if J > 1 else a, s)
                near = np.inf
                for b in range(lay.branch_ptr[m], lay.branch_ptr[m + 1]):
                    if lay.branch_prob[b] <= 0.0:
                        continue
                    L = lay.branch_layer[b]
                    for j in range(nc):
                        if s.w[j] > EPS_W and live[L, s.idx[j]]:
                            near = min(near, dist[index[L, s.idx[j]]])
                if near + 1 < best:
                    best = near + 1
                    arg = a
            act[st] = arg
            if best < dist[st]:
                dist[st] = best
                changed = True
    keep(held)
    return changed


@njit(cache=True, nogil=True)
def back_substitute(P, cost, g, h, comps, first, last):  # pragma: no cover - numba
    """``h = c - g + P h`` on the strongly connected components ``first:last`` of the chain.

    ``P`` is the CSR triple ``(indptr, indices, data)``. The components ``comps = (order,
    starts)`` are numbered sinks first (every edge leaves a component for one with a
    smaller number), their states are ``order[starts[k]:starts[k + 1]]``, and ``h`` is
    known on every state they lead to. A single state is solved directly (its self-loop
    divided out); a small component (interpolation cycles) by Gauss-Seidel on itself
    alone, which converges since it is transient. Returns the largest number of
    Gauss-Seidel passes one component needed.
    """
    indptr, indices, data = P
    order, starts = comps
    most = 0
    for k in range(first, last):
        a = starts[k]
        b = starts[k + 1]
        passes = 0
        while True:
            change = 0.0
            for q in range(a, b):
                s = order[q]
                acc = cost[s] - g
                diag = 1.0
                for e in range(indptr[s], indptr[s + 1]):
                    j = indices[e]
                    if j == s:
                        diag -= data[e]
                    else:
                        acc += data[e] * h[j]
                new = acc / diag
                change = max(change, abs(new - h[s]) / (1.0 + abs(new)))
                h[s] = new
            passes += 1
            if b - a == 1 or change <= 1e-15 or passes >= 100_000:
                break
        most = max(most, passes)
    return most
