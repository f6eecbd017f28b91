"""Policy improvement of one C or W layer, vectorised over cells (numba).

Policy iteration on a layer (:func:`cellplan.strategies.solve.sweeps.layer_iteration`)
alternates an exact evaluation of the recorded policy
(:mod:`cellplan.strategies.solve.evaluation`) with an improvement step: every state takes the
best action of the average-cost form of equation (9),

    pi'(x) = argmin_u [ l(u) - g + H(x'_u) ],

read from the evaluated values (a Jacobi step: no value changes while the actions are
chosen). Since ``h`` is the exact value of the old policy, the old action's value at
``x`` is ``h(x)`` itself, so ``h(x) - min_u [...]`` is the Bellman residual there and the
layer is solved once it is below the inner accuracy everywhere.

Unlike a Gauss-Seidel sweep, the Jacobi step has no order between cells, so the moves of
the cells whose every landing corner is live (``Layers.dense``: no renormalisation of the
interpolation weights of Section IV-B) are computed one move at a time over runs of
consecutive cells: with the model's moves in the world frame, a move's corners sit at the
same flat offsets from every interior cell, and the loop over a run compiles to vector
instructions (P1 200 x 200 W layer: the whole step in 0.65 ms, a Gauss-Seidel sweep
2.9 ms). The other cells (near obstacles and the border) take the scalar
path, with the corner tests and renormalisation of
:func:`cellplan.strategies.solve.sweeps.sweep_policy`. The sums are the same as the sweep's,
in the same order, so both find the same values.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cellplan.strategies.model.stencils import EPS_W, decode
from cellplan.strategies.solve.law import (
    FMP,
    OUTSIDE,
    STAY,
    Site,
    borrowed,
    fmp_value,
    keep,
    lend,
    move_value,
    reader,
    scratch,
    stay_value,
)

# Cells per run of the vectorised loops: its scratch rows stay in the L1 cache.
RUN = 2048


@njit(cache=True)
def improvable(m, model):  # pragma: no cover - numba
    """Layer ``m`` has one branch, into itself with probability one (a C or W layer of a
    model without mode changes), its moves are in the world frame (no heading axis) and
    land where commanded (no noise), and the dense cells are known (``Layers.dense``
    filled)."""
    lay = model.layers
    b0 = lay.branch_ptr[m]
    b1 = lay.branch_ptr[m + 1]
    return (
        b1 - b0 == 1
        and lay.branch_layer[b0] == m
        and lay.branch_prob[b0] == 1.0
        and model.moves.heading_axis < 0
        and model.moves.noise_prob.shape[0] <= 1
        and lay.dense.shape[0] > 0
    )


@njit(cache=True)
def move_tables(model, kcls, N):  # pragma: no cover - numba
    """Each move of class ``kcls`` from an interior cell (heading slice 0: world-frame
    moves): ``(nk, wts, offs, lo, hi, wsum)``, its number of corners with weight, their
    weights and flat offsets (by decreasing weight, as the stencil tables), the cells
    ``lo <= c < hi`` from which all its corners are inside the ``N`` cells, and the sum of
    its weights."""
    moves = model.moves
    na = moves.nact[kcls]
    ncorner = moves.cw.shape[3]
    nk = np.zeros(na, np.int64)
    wts = np.zeros((na, ncorner))
    offs = np.zeros((na, ncorner), np.int64)
    wsum = np.zeros(na)
    lo = np.zeros(na, np.int64)
    hi = np.full(na, N, np.int64)
    for a in range(na):
        for jj in range(ncorner):
            wj = moves.cw[kcls, a, 0, jj]
            if wj <= EPS_W:
                break
            o = moves.coff[kcls, a, 0, jj]
            wts[a, jj] = wj
            offs[a, jj] = o
            wsum[a] += wj
            lo[a] = max(lo[a], -o)
            hi[a] = min(hi[a], N - o)
            nk[a] += 1
    return nk, wts, offs, lo, hi, wsum


@njit(cache=True)
def move_sums(hm, a, s0, n, nk, wts, offs, acc):  # pragma: no cover - numba
    """``acc[i] = sum_j w_j hm[s0 + i + o_j]`` for move ``a`` over ``n`` cells from ``s0``:
    the interpolation sums of a run of cells, corner by corner in the tables' order (the
    sweeps' order, so the same sums). Slices, so that the loops index from zero: numba
    then drops the negative-index checks and vectorises them."""
    o = offs[a, 0]
    hv = hm[s0 + o : s0 + o + n]
    wj = wts[a, 0]
    for i in range(n):
        acc[i] = wj * hv[i]
    for jj in range(1, nk[a]):
        o = offs[a, jj]
        hv = hm[s0 + o : s0 + o + n]
        wj = wts[a, jj]
        for i in range(n):
            acc[i] += wj * hv[i]


@njit(cache=True, inline="always")
def _dense_run(hm, dense, c0, c1, step_cost, tables, run):  # pragma: no cover - numba
    """The moves of the dense cells of the run ``c0:c1`` into ``run = (best, arg, acc)``,
    one move at a time over the run (the law of :func:`.law.table_sums` where every corner
    is live: the same sums in the same order). ``tables``: :func:`move_tables`."""
    nk, wts, offs, lo, hi, wsum = tables
    best, arg, acc = run
    for a in range(nk.shape[0]):
        s0 = max(c0, lo[a])
        s1 = min(c1, hi[a])
        n = s1 - s0
        if n <= 0 or nk[a] == 0:
            continue
        # Slices, so that the loops index from zero: numba then drops the negative-index
        # checks and vectorises them.
        move_sums(hm, a, s0, n, nk, wts, offs, acc)
        bit = np.int64(1) << a
        ws = wsum[a]
        bl = best[s0 - c0 : s1 - c0]
        al = arg[s0 - c0 : s1 - c0]
        dl = dense[s0:s1]
        for i in range(n):
            v = step_cost + acc[i] / ws
            take = ((dl[i] & bit) != 0) & (v < bl[i])
            bl[i] = v if take else bl[i]
            al[i] = a if take else al[i]


@njit(cache=True, nogil=True)
def improve_layer(m, h, g, pol, tie, model):  # pragma: no cover - numba
    """One policy-improvement step on layer ``m`` from the exact values ``h`` of ``pol[m]``.

    Every live cell takes the minimiser of ``l(u) - g + H_m(x'_u)`` over FMP, stay and the
    collision-free moves (ties to the first in that order, as in
    :func:`cellplan.strategies.solve.sweeps.sweep_policy`), unless its recorded action is within
    ``tie`` of the best (an action is kept rather than swapped for an equally good one, so
    that policy iteration cannot cycle between ties). ``h`` is not changed. Returns
    ``(residual, changed)``: the largest ``h(x) - min_u [...]`` over the live cells (the
    Bellman residual of the evaluated policy) and the number of cells whose action changed.
    Needs :func:`improvable` and every live value finite.

    A cell whose recorded action is stay, with a positive stage loss ``l - g``, has no
    finite value under it (staying for ever), and the exact evaluation leaves such a cell
    as it was, possibly below every action it has: there ``h`` is not the policy's value.
    The cell takes its best other action (FMP or a move) and the residual is ``inf``, so
    the layer is not taken for solved.
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
    dense = lay.dense[m]  # moves of each cell whose corners are all live
    nxt = lay.fmp_next[m]
    opt = lay.opt_ptr[m]
    tfm = lay.tf[opt]
    step_cost = lay.cost[m] - g
    tables = move_tables(model, kcls, N)
    best = np.empty(RUN)
    arg = np.empty(RUN, np.int64)
    acc = np.empty(RUN)
    held = scratch(d)
    sc = lend(held)
    law = reader(h, h, live, True, True, False)
    residual = 0.0
    changed = 0
    for c0 in range(0, N, RUN):
        c1 = min(N, c0 + RUN)
        for i in range(c1 - c0):
            best[i] = np.inf
            arg[i] = OUTSIDE
        _dense_run(hm, dense, c0, c1, step_cost, tables, (best, arg, acc))
        # Every live cell: the moves of the cells that are not dense, then FMP and stay
        # ahead of the moves (the tie order of the sweeps).
        for c in range(c0, c1):
            if not livem[c]:
                continue
            i = c - c0
            vb = valid[c] & ~dense[c]  # the moves left to the scalar path
            site = Site(m, kcls, c, moves.interior[kcls, c], 0, True)
            if vb != 0:
                if not site.inner:
                    decode(c, model.grid.shape, sc.mi)
                for a in range(na):
                    if (vb >> a) & 1:
                        v, _ = move_value(model, law, site, a, (step_cost, 0.0), -1, sc)
                        if v < best[i]:
                            best[i] = v
                            arg[i] = a
            fmp = np.inf
            if nxt >= 0 and tfm[c] < np.inf:
                fmp, _ = fmp_value(model, law, opt, c, (tfm[c] - g, 0.0))
            top = fmp
            act = FMP if fmp < np.inf else OUTSIDE
            stay, _ = stay_value(model, law, site, (step_cost, 0.0), -1)
            if stay < top:
                top = stay
                act = STAY
            if best[i] < top:
                top = best[i]
                act = arg[i]
            drop = hm[c] - top
            old = pol[m, c]
            if old == STAY and step_cost > 0.0 and min(fmp, best[i]) < np.inf:
                # Staying for ever has no finite value: the exact evaluation leaves such a
                # state as it was, possibly below every action it has, so ``h`` is not the
                # policy's value there. Leaving is an improvement of unbounded size.
                act = FMP if fmp <= best[i] else arg[i]
                drop = np.inf
            if drop > residual:
                residual = drop
            if act != old and (old == OUTSIDE or not drop <= tie):
                pol[m, c] = act
                changed += 1
    keep(held)
    return residual, changed
