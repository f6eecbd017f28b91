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

from cellplan.strategies.model.stencils import EPS_W, decode, fmp_code, table_stencil
from cellplan.strategies.solve.improvement import RUN, move_sums, move_tables
from cellplan.strategies.solve.noisy import noisy_move_value


@njit(cache=True, nogil=True, inline="always")
def fmp_value(opt, c, tf_oc, h, live, lay):  # pragma: no cover - numba
    """FMP option ``opt`` at cell ``c``: ``t_f + sum_o P_o (c_o + h(L_o, c))``; inf if an
    outcome with positive probability is not a live state."""
    val = tf_oc
    for o in range(lay.out_ptr[opt], lay.out_ptr[opt + 1]):
        p = lay.out_prob[o]
        if p <= 0.0:
            continue
        L = lay.out_layer[o]
        if not live[L, c]:
            return np.inf
        val += p * (lay.out_cost[o] + h[L, c])
    return val


@njit(cache=True, nogil=True)
def bellman_rows(h, out, policy, gap, subset, start, stop, model):  # pragma: no cover - numba
    """One Jacobi sweep over the states ``start <= m * N + c < stop``: ``out = T h`` there.

    No ``g`` is subtracted. ``policy[m, c]`` receives the minimising action: ``-1`` stay,
    ``-2`` FMP (``-3 - j`` its option ``j >= 1``, :func:`.stencils.fmp_code`), ``a >= 0``
    move ``a``; ``-3`` for states outside the MDP. Ties (within 1e-12 relative) go to the
    first action in the order FMP options, stay, moves. ``gap[m, c]``
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
    tf = lay.tf
    valid = moves.valid
    interior = moves.interior
    coff = moves.coff
    cw = moves.cw
    heading_axis = moves.heading_axis
    branch_layer = lay.branch_layer
    branch_prob = lay.branch_prob
    shape = grid.shape
    ncell = h.shape[1]
    some = subset.shape[0] > 0
    d = shape.shape[0]
    ncorner = 1 << d
    noise_prob = moves.noise_prob
    nj = noise_prob.shape[0]
    noisy = nj > 1  # Section VI-4: several landings per move
    mi = np.empty(d, np.int64)
    idx = np.empty(ncorner, np.int64)
    w = np.empty(ncorner)
    for m in range(start // ncell, (stop + ncell - 1) // ncell):
        nxt = lay.fmp_next[m]
        opt0 = lay.opt_ptr[m]
        opt1 = lay.opt_ptr[m + 1]
        kcls = lay.vcls[m]
        na = moves.nact[kcls]
        b0 = lay.branch_ptr[m]
        b1 = lay.branch_ptr[m + 1]
        cost = lay.cost[m]
        # One branch into the layer itself (C and W without mode changes): the moves read
        # the stencil tables directly (the same sums as the general loop below).
        single = b1 - b0 == 1 and branch_layer[b0] == m and branch_prob[b0] == 1.0
        livem = live[m]
        hm = h[m]
        for c in range(max(start - m * ncell, 0), min(stop - m * ncell, ncell)):
            if not live[m, c]:
                out[m, c] = np.nan
                policy[m, c] = -3
                gap[m, c] = np.nan
                continue
            if some and not subset[m, c]:
                continue
            decode(c, shape, mi)
            best = np.inf
            second = np.inf
            arg = -3
            if nxt >= 0:
                for opt in range(opt0, opt1):
                    if tf[opt, c] < np.inf:
                        fval = fmp_value(opt, c, tf[opt, c], h, live, lay)
                        if fval < best and (best == np.inf or fval < best - 1e-12 * abs(best)):
                            second = best
                            best = fval
                            arg = fmp_code(opt - opt0)
                        elif fval < second:
                            second = fval
            sval = cost
            sok = True
            for b in range(b0, b1):
                L = branch_layer[b]
                if not live[L, c]:
                    sok = False
                    break
                sval += branch_prob[b] * h[L, c]
            if sok and sval < best and (best == np.inf or sval < best - 1e-12 * abs(best)):
                second = best
                best = sval
                arg = -1
            elif sok and sval < second:
                second = sval
            vb = valid[kcls, c]
            inner = interior[kcls, c]
            t = mi[heading_axis] if heading_axis >= 0 else 0
            for a in range(na):
                if ((vb >> a) & 1) == 0:
                    continue
                if noisy:
                    if single and inner:
                        # The landings' corners straight from the tables, as below.
                        val = cost
                        for j in range(nj):
                            pj = noise_prob[j]
                            if pj <= 0.0:
                                continue
                            row = na + a * nj + j
                            ssum = 0.0
                            vsum = 0.0
                            for jj in range(ncorner):
                                wj = cw[kcls, row, t, jj]
                                if wj <= EPS_W:
                                    break
                                i = c + coff[kcls, row, t, jj]
                                if livem[i]:
                                    ssum += wj
                                    vsum += wj * hm[i]
                            if ssum <= EPS_W:
                                val = np.inf
                                break
                            val += pj * vsum / ssum
                    else:
                        val = cost + noisy_move_value(m, c, a, mi, inner, h, live, model, idx, w)
                    if val < best and (best == np.inf or val < best - 1e-12 * abs(best)):
                        second = best
                        best = val
                        arg = a
                    elif val < second:
                        second = val
                    continue
                if single and inner:
                    ssum = 0.0
                    vsum = 0.0
                    for jj in range(ncorner):
                        wj = cw[kcls, a, t, jj]
                        if wj <= EPS_W:
                            break
                        i = c + coff[kcls, a, t, jj]
                        if livem[i]:
                            ssum += wj
                            vsum += wj * hm[i]
                    if ssum <= EPS_W:
                        continue
                    val = cost + vsum / ssum
                    if val < best and (best == np.inf or val < best - 1e-12 * abs(best)):
                        second = best
                        best = val
                        arg = a
                    elif val < second:
                        second = val
                    continue
                # Written out as in sweeps.sweep_policy (an inlined helper is slower here).
                if inner:
                    nc = 0
                    for jj in range(ncorner):
                        wj = cw[kcls, a, t, jj]
                        if wj <= EPS_W:
                            break
                        idx[jj] = c + coff[kcls, a, t, jj]
                        w[jj] = wj
                        nc += 1
                else:
                    nc = table_stencil(
                        kcls,
                        a,
                        mi,
                        moves.offs,
                        moves.fr,
                        heading_axis,
                        shape,
                        grid.periodic,
                        idx,
                        w,
                    )
                val = cost
                ok = True
                for b in range(b0, b1):
                    L = branch_layer[b]
                    ssum = 0.0
                    vsum = 0.0
                    for j in range(nc):
                        wj = w[j]
                        if wj > EPS_W:
                            i = idx[j]
                            if live[L, i]:
                                ssum += wj
                                vsum += wj * h[L, i]
                    if ssum <= EPS_W:
                        ok = False
                        break
                    val += branch_prob[b] * vsum / ssum
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
    moves = model.moves
    lay = model.layers
    live = lay.live
    livem = live[m]
    hm = h[m]
    N = hm.shape[0]
    d = model.grid.shape.shape[0]
    ncorner = 1 << d
    kcls = lay.vcls[m]
    na = moves.nact[kcls]
    valid = moves.valid[kcls]
    interior = moves.interior[kcls]
    dense = lay.dense[m]
    nxt = lay.fmp_next[m]
    opt0 = lay.opt_ptr[m]
    opt1 = lay.opt_ptr[m + 1]
    cost = lay.cost[m]
    some = subset.shape[0] > 0
    nk, wts, offs, lo, hi, wsum = move_tables(model, kcls, N)
    best = np.empty(RUN)
    second = np.empty(RUN)
    arg = np.empty(RUN, np.int64)
    acc = np.empty(RUN)
    other = np.empty(RUN, np.int64)  # live cells of the run with moves off the dense path
    mi = np.empty(d, np.int64)
    idx = np.empty(ncorner, np.int64)
    w = np.empty(ncorner)
    for c0 in range(0, N, RUN):
        c1 = min(N, c0 + RUN)
        n_other = 0
        for c in range(c0, c1):
            i = c - c0
            b = np.inf
            s = np.inf
            ar = -3
            if livem[c]:
                if nxt >= 0:
                    for opt in range(opt0, opt1):
                        if lay.tf[opt, c] < np.inf:
                            v = fmp_value(opt, c, lay.tf[opt, c], h, live, lay)
                            if v < b and (b == np.inf or v < b - 1e-12 * abs(b)):
                                s = b
                                b = v
                                ar = fmp_code(opt - opt0)
                            elif v < s:
                                s = v
                v = cost + 1.0 * hm[c]
                if v < b and (b == np.inf or v < b - 1e-12 * abs(b)):
                    s = b
                    b = v
                    ar = -1
                elif v < s:
                    s = v
                if (valid[c] & ~dense[c]) != 0:
                    other[n_other] = c
                    n_other += 1
            best[i] = b
            second[i] = s
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
                if interior[c]:
                    nc = nk[a]
                    for j in range(nc):
                        idx[j] = c + offs[a, j]
                        w[j] = wts[a, j]
                else:
                    decode(c, model.grid.shape, mi)
                    nc = table_stencil(
                        kcls, a, mi, moves.offs, moves.fr, -1, model.grid.shape,
                        model.grid.periodic, idx, w,
                    )  # fmt: skip
                ssum = 0.0
                vsum = 0.0
                for j in range(nc):
                    wj = w[j]
                    if wj > EPS_W and livem[idx[j]]:
                        ssum += wj
                        vsum += wj * hm[idx[j]]
                if ssum <= EPS_W:
                    continue
                v = cost + vsum / ssum
                i = c - c0
                bb = best[i]
                if v < bb and (bb == np.inf or v < bb - 1e-12 * abs(bb)):
                    second[i] = bb
                    best[i] = v
                    arg[i] = a
                elif v < second[i]:
                    second[i] = v
        for c in range(c0, c1):
            if not livem[c]:
                out[m, c] = np.nan
                policy[m, c] = -3
                gap[m, c] = np.nan
                continue
            if some and not subset[m, c]:
                continue
            i = c - c0
            out[m, c] = best[i]
            policy[m, c] = arg[i]
            gap[m, c] = second[i] - best[i]


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
