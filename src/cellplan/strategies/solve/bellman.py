"""The Jacobi Bellman operator over every state (numba, parallel): certificate and policy.

For relative values ``h`` the operator of the average-cost problem is (the right-hand
side of equation (9), Section III-C of the strategies paper, without ``g``)

    (T h)(m, x) = min( min_j t_f(j, x) + sum_o P_o (c_o + h(L_o, x)),       FMP options j
                       l(m) + sum_b P_b h(L_b, x),                          stay
                       min_a  l(m) + sum_b P_b H_{L_b}(x + dx_a) )          moves a

(with noisy motion, Section VI-4, the move's term is ``sum_j p_j H_{L_b}(x + dx_{a,j})``:
:mod:`cellplan.strategies.solve.noisy`)

with ``H`` the interpolation of :mod:`cellplan.strategies.model.interpolation` and the branches
``(L_b, P_b)`` of Section III-B. FMP's outcomes ``(L_o, P_o, c_o)`` are the single
``(next(m), 1, 0)`` of Section III-B, or success and failure (Section VI-3). A mode has
one FMP option except with simultaneous requests (Section VI-2), where a pick may serve
any open request whose source allows it.
``min (T h - h) <= g <= max (T h - h)`` over the live states brackets the optimal gain
(the span test of relative value iteration), which is how every reported gain is
certified (:func:`cellplan.strategies.solve.solver.certify`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cellplan.strategies.model.stencils import decode, fmp_code
from cellplan.strategies.solve.improvement import RUN, move_sums, move_tables
from cellplan.strategies.solve.law import (
    OUTSIDE,
    STAY,
    Site,
    borrowed,
    fmp_value,
    is_single,
    keep,
    lend,
    move_value,
    reader,
    scratch,
    site_at,
    stay_value,
)


@njit(cache=True, inline="always")
def _take(val, a, acc):  # pragma: no cover - numba
    """Action ``a`` of value ``val`` offered to ``acc = (best, second, arg)``: it wins only
    if better by more than 1e-12 relative (ties go to the action offered first)."""
    best, second, arg = acc
    if val < best and (best == np.inf or val < best - 1e-12 * abs(best)):
        return val, best, a
    if val < second:
        return best, val, arg
    return acc


@njit(cache=True, inline="always")
def _fmp_options(model, law, m, c, acc):  # pragma: no cover - numba
    """The FMP options of mode ``m`` at cell ``c`` offered to ``acc`` (:func:`_take`)."""
    lay = model.layers
    if lay.fmp_next[m] >= 0:
        opt0 = lay.opt_ptr[m]
        for opt in range(opt0, lay.opt_ptr[m + 1]):
            if lay.tf[opt, c] < np.inf:
                fval, _ = fmp_value(model, law, opt, c, (lay.tf[opt, c], 0.0))
                acc = _take(fval, fmp_code(opt - opt0), acc)
    return acc


@njit(cache=True, nogil=True)
def bellman_rows(h, out, policy, gap, subset, start, stop, model):  # pragma: no cover - numba
    """One Jacobi sweep over the states ``start <= m * N + c < stop``: ``out = T h`` there.

    No ``g`` is subtracted; every action's value is the law of :mod:`.law` (every corner
    and branch read, none at ``+inf`` left out). ``policy[m, c]`` receives the minimising
    action: ``-1`` stay, ``-2`` FMP (``-3 - j`` its option ``j >= 1``,
    :func:`.stencils.fmp_code`), ``a >= 0`` move ``a``; ``-3`` for states outside the MDP.
    Ties (within 1e-12 relative) go to the first action in the order FMP options, stay,
    moves. ``gap[m, c]`` receives the second-best action value minus the best (``inf``
    with a single action): adding to ``h`` anything whose span (max - min) is below it
    cannot change the action there. A non-empty ``subset`` (boolean, like ``h``) limits the
    sweep to the live states it marks (the outputs elsewhere are left as they were). Every
    state is independent, so disjoint ranges may run in parallel threads (the GIL is
    released).
    """
    model = borrowed(model)
    moves = model.moves
    lay = model.layers
    live = lay.live
    shape = model.grid.shape
    ncell = h.shape[1]
    some = subset.shape[0] > 0
    held = scratch(shape.shape[0])
    s = lend(held)
    law = reader(h, h, live, False, False, False)
    for m in range(start // ncell, (stop + ncell - 1) // ncell):
        kcls = lay.vcls[m]
        na = moves.nact[kcls]
        cost = lay.cost[m]
        # One branch into the layer itself (C and W without mode changes): the moves read
        # the stencil tables directly (the same sums as the general loop).
        single = is_single(lay, m)
        for c in range(max(start - m * ncell, 0), min(stop - m * ncell, ncell)):
            if not live[m, c]:
                out[m, c] = np.nan
                policy[m, c] = OUTSIDE
                gap[m, c] = np.nan
                continue
            if some and not subset[m, c]:
                continue
            decode(c, shape, s.mi)
            site = site_at(model, m, c, single, s.mi)
            acc = _fmp_options(model, law, m, c, (np.inf, np.inf, OUTSIDE))
            sval, _ = stay_value(model, law, site, (cost, 0.0), -1)
            acc = _take(sval, STAY, acc)
            vb = moves.valid[kcls, c]
            for a in range(na):
                if (vb >> a) & 1:
                    val, _ = move_value(model, law, site, a, (cost, 0.0), -1, s)
                    acc = _take(val, a, acc)
            best, second, arg = acc
            out[m, c] = best
            policy[m, c] = arg
            gap[m, c] = second - best
    keep(held)


@njit(cache=True, nogil=True)
def bellman_all(h, out, policy, gap, subset, model):  # pragma: no cover - numba
    """:func:`bellman_rows` over every state, in the calling thread."""
    bellman_rows(h, out, policy, gap, subset, 0, h.shape[0] * h.shape[1], model)


@njit(cache=True, nogil=True)
def bellman_dense(m, h, out, policy, gap, subset, model):  # pragma: no cover - numba
    """:func:`bellman_rows` over layer ``m``, the moves of its dense cells vectorised.

    For a layer :func:`cellplan.strategies.solve.improvement.improvable` accepts (one branch
    into itself, world-frame moves, ``Layers.dense`` filled) and without noisy motion.
    Cells are taken in runs; FMP and stay first, then the moves in their order, each move
    over the whole run at once for the cells whose corners are all live (the loop
    :mod:`cellplan.strategies.solve.improvement` uses) and one cell at a time for the others, so
    every state sees its actions in the order of :func:`bellman_rows`, with the same sums
    and the same tie rule: the same values, actions and gaps bit for bit.
    """
    model = borrowed(model)
    moves = model.moves
    lay = model.layers
    live = lay.live
    livem = live[m]
    hm = h[m]
    N = hm.shape[0]
    d = model.grid.shape.shape[0]
    kcls = lay.vcls[m]
    na = moves.nact[kcls]
    valid = moves.valid[kcls]
    interior = moves.interior[kcls]
    dense = lay.dense[m]
    cost = lay.cost[m]
    some = subset.shape[0] > 0
    nk, wts, offs, lo, hi, wsum = move_tables(model, kcls, N)
    best = np.empty(RUN)
    second = np.empty(RUN)
    arg = np.empty(RUN, np.int64)
    acc = np.empty(RUN)
    other = np.empty(RUN, np.int64)  # live cells of the run with moves off the dense path
    held = scratch(d)
    sc = lend(held)
    law = reader(h, h, live, False, False, False)
    for c0 in range(0, N, RUN):
        c1 = min(N, c0 + RUN)
        n_other = 0
        for c in range(c0, c1):
            i = c - c0
            b = np.inf
            s2 = np.inf
            ar = OUTSIDE
            if livem[c]:
                tk = _fmp_options(model, law, m, c, (b, s2, ar))
                site = Site(m, kcls, c, interior[c], 0, True)
                sval, _ = stay_value(model, law, site, (cost, 0.0), -1)
                b, s2, ar = _take(sval, STAY, tk)
                if (valid[c] & ~dense[c]) != 0:
                    other[n_other] = c
                    n_other += 1
            best[i] = b
            second[i] = s2
            arg[i] = ar
        for a in range(na):
            bit = np.int64(1) << a
            s0 = max(c0, lo[a])
            s1 = min(c1, hi[a])
            n = s1 - s0
            if n > 0 and nk[a] > 0:
                move_sums(hm, a, s0, n, nk, wts, offs, acc)
                ws = wsum[a]
                bl = best[s0 - c0 : s1 - c0]
                sl = second[s0 - c0 : s1 - c0]
                al = arg[s0 - c0 : s1 - c0]
                dl = dense[s0:s1]
                for i in range(n):
                    v = cost + acc[i] / ws
                    use = (dl[i] & bit) != 0
                    bb = bl[i]
                    better = use & (v < bb) & ((bb == np.inf) | (v < bb - 1e-12 * abs(bb)))
                    lower = use & (v < sl[i])
                    sl[i] = bb if better else (v if lower else sl[i])
                    bl[i] = v if better else bb
                    al[i] = a if better else al[i]
            for k in range(n_other):
                c = other[k]
                if (valid[c] & bit) == 0 or (dense[c] & bit) != 0:
                    continue
                if not interior[c]:
                    decode(c, model.grid.shape, sc.mi)
                site = Site(m, kcls, c, interior[c], 0, True)
                v, _ = move_value(model, law, site, a, (cost, 0.0), -1, sc)
                i = c - c0
                best[i], second[i], arg[i] = _take(v, a, (best[i], second[i], arg[i]))
        for c in range(c0, c1):
            if not livem[c]:
                out[m, c] = np.nan
                policy[m, c] = OUTSIDE
                gap[m, c] = np.nan
                continue
            if some and not subset[m, c]:
                continue
            i = c - c0
            out[m, c] = best[i]
            policy[m, c] = arg[i]
            gap[m, c] = second[i] - best[i]
    keep(held)


@njit(cache=True, nogil=True)
def residual_range(th, h, live):  # pragma: no cover - numba
    """``(min, max)`` of ``T h - h`` over the live states: the bracket of the span test.

    A loop rather than ``(th - h)[live]``: on problem 6 those two temporaries are 58 MB of
    memory touched for the first time, which costs more than the Bellman sweep's own
    arithmetic on a virtual machine. NaN if some live residual is NaN (as numpy's min).
    """
    lo = np.inf
    hi = -np.inf
    M, N = th.shape
    for m in range(M):
        for c in range(N):
            if live[m, c]:
                r = th[m, c] - h[m, c]
                if r != r:
                    return np.nan, np.nan
                lo = min(lo, r)
                hi = max(hi, r)
    return lo, hi


@njit(cache=True, nogil=True)
def near_ties(th, gap, live, span):  # pragma: no cover - numba
    """Live states whose best action leads the second by at most ``span`` plus float slack
    (``1e-9 max(1, |T h|)``: values are sums of tens of terms of size up to ``|T h|``):
    the only states whose action one more Bellman sweep can change."""
    M, N = th.shape
    near = np.zeros((M, N), np.bool_)
    for m in range(M):
        for c in range(N):
            if live[m, c]:
                near[m, c] = gap[m, c] <= span + 1e-9 * max(1.0, abs(th[m, c]))
    return near
