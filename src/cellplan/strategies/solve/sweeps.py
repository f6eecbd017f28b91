"""Gauss-Seidel sweeps and policy iteration on one layer of the layered MDP (numba).

For a fixed gain ``g`` every C and W layer is a deterministic shortest path with terminal
costs, and NR (its request branches into the fixed W layers summed in advance) a single
stochastic layer. The structured solver (:mod:`cellplan.strategies.solve.solver`) solves each
by policy iteration built from the kernels here:

* :func:`sweep_policy` - one Gauss-Seidel sweep of the average-cost form of equation (9),

      h(m, x) = min_u [ l(m, u) - g + sum_b P_b H_{L_b}(x'_u) ],

  recording the minimiser and, alongside, ``D = dh/dg`` along it (the derivative the
  Newton step on ``g`` needs);
* :func:`layer_iteration` - policy iteration on one layer: full sweeps choose the
  actions, :mod:`cellplan.strategies.solve.evaluation` evaluates the chosen policy exactly once
  it has nearly settled (the solver runs independent layers in parallel threads; the
  kernels release the GIL);
* :func:`other_branches`, :func:`sweep_self` - the same for NR with its stay self-loop
  solved exactly, ``h = (l - g + E_stay) / (1 - P_self)``; NR is one layer, so its sweep
  runs in slabs of rows on parallel threads (the policy-iteration loop around it is
  :meth:`cellplan.strategies.solve.solver._Layers.nr_layer`).

Cells are visited in alternating axis orders (``flips``) so that values propagate in
every direction. The model arrives as one :class:`~cellplan.strategies.model.bundles.Model`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cellplan.strategies.model.bundles import Model
from cellplan.strategies.model.stencils import (
    EPS_W,
    decode,
    first_of_order,
    first_of_rows,
    move_corners,
    next_of_order,
    table_stencil,
)
from cellplan.strategies.solve.coldstart import dijkstra_layer
from cellplan.strategies.solve.evaluation import evaluate, layer_system, live_cells
from cellplan.strategies.solve.improvement import improvable, improve_layer

# A recorded policy is evaluated exactly once a full sweep changes the minimiser (by more
# than the inner accuracy) in at most this fraction of the live cells.
SETTLED_FRACTION = 0.01
# After an exact evaluation, a residual check that would change the action of at most this
# fraction of the live cells is followed by an evaluation of the changed policy (a policy-
# iteration step, 2x cheaper than a sweep and an evaluation) instead of a sweep. Fitted on
# problems 2, 4, 5 and P1 at 141 x 141, one thread, CPU time (P2 1.76-2.00 s with none,
# 1.68-1.70 at 0.01, 1.65-1.66 at 0.03; benchmarks/fit_solver_rules.py --cpu).
PI_FRACTION = 0.03


@njit(cache=True, inline="never")
def _dense_moves(hm, cwk, cok, c, t, vb, na, step_cost, pold, best, barg, oldv):  # pragma: no cover
    """The moves of a dense cell (:func:`dense_cells`) in :func:`sweep_policy`: corners read
    without tests. Returns the updated ``(best, barg, oldv)``. A function of its own: written
    into the sweep, it slows the sweep's general path down by half (multi-branch layers)."""
    ncorner = cwk.shape[2]
    for a in range(na):
        if ((vb >> a) & 1) == 0:
            continue
        ssum = 0.0
        vsum = 0.0
        for jj in range(ncorner):
            wj = cwk[a, t, jj]
            if wj <= EPS_W:
                break
            ssum += wj
            vsum += wj * hm[c + cok[a, t, jj]]
        val = step_cost + vsum / ssum
        if a == pold:
            oldv = val
        if val < best:
            best = val
            barg = a
    return best, barg, oldv


@njit(cache=True)
def sweep_policy(
    m, flips, h, D, g, exact_stay, track, pol, mode, nchg, tie, model
):  # pragma: no cover - numba
    """One Gauss-Seidel sweep of layer ``m`` in place (axis order reversed where ``flips``).

    ``mode`` 0: ``pol`` is not touched; 1: the minimiser is recorded in ``pol[m]``,
    ``nchg[0]`` counting the cells whose minimiser changed by more than ``tie`` in value
    (ties between equally good actions are not counted).

    ``h[m, c] = min_u [ l(u) - g + sum_b P_b h[L_b](x'_u) ]`` (the average-cost form of
    equation (9)); corners still at ``+inf`` (not yet reached by a solve started from
    ``+inf``) are left out and the weights renormalised. With ``exact_stay`` the stay
    action's self-loop is solved exactly, ``h = (l - g + sum_{b != m} P_b h[L_b](x)) /
    (1 - P_mm)``. With ``track`` the derivative ``D = dh/dg`` along the minimising action
    is updated as well. Returns the largest change of ``h[m]``.

    The move loop is written out here rather than calling a helper: numba compiles the
    inlined :func:`~cellplan.strategies.model.stencils.move_corners` into a loop about twice as
    slow in this, the hottest loop of the solver.
    """
    moves = model.moves
    grid = model.grid
    lay = model.layers
    live = lay.live
    cw = moves.cw
    coff = moves.coff
    heading_axis = moves.heading_axis
    branch_layer = lay.branch_layer
    branch_prob = lay.branch_prob
    valid = moves.valid
    interior = moves.interior
    shape = grid.shape
    d = shape.shape[0]
    ncell = h.shape[1]
    mi = np.empty(d, np.int64)
    ncorner = 1 << d
    idx = np.empty(ncorner, np.int64)
    w = np.empty(ncorner)
    hm = h[m]
    livem = live[m]
    nxt = lay.fmp_next[m]
    tfm = lay.tf[m]
    kcls = lay.vcls[m]
    na = moves.nact[kcls]
    b0 = lay.branch_ptr[m]
    b1 = lay.branch_ptr[m + 1]
    step_cost = lay.cost[m] - g
    pself = 0.0
    for b in range(b0, b1):
        if branch_layer[b] == m:
            pself += branch_prob[b]
    # A C or W layer without mode changes has one branch, into itself with probability 1:
    # its moves and the winner's D read the stencil tables directly (the same sums in the
    # same order; a sweep of a P1 200 x 200 C layer 5.1 -> 2.8 ms).
    single = b1 - b0 == 1 and branch_layer[b0] == m and branch_prob[b0] == 1.0
    # Where every corner a move can land on is live and no value is +inf, the corner
    # tests are skipped (the same sums in the same order; P1 200 x 200 C layer sweep
    # 2.8-3.0 -> 2.65 ms, W layer 3.5-3.9 -> 3.2 ms).
    dense = lay.dense
    fast = single and dense.shape[0] > 0
    if fast:
        for c in range(ncell):
            if livem[c] and hm[c] == np.inf:
                fast = False
                break
    cwk = cw[kcls]
    cok = coff[kcls]
    maxchange = 0.0
    c = -1
    for kk in range(ncell):
        # Walk the cells in sweep order by odometer steps (no division per cell).
        c = first_of_order(shape, flips, mi) if kk == 0 else next_of_order(shape, flips, mi)
        if not livem[c]:
            continue
        best = np.inf
        bestd = 0.0
        barg = -3
        pold = pol[m, c] if mode == 1 else -9
        oldv = np.inf
        # FMP: switch to the next mode at the same configuration, loss t_f (equation (7)).
        if nxt >= 0 and tfm[c] < np.inf and live[nxt, c] and h[nxt, c] < np.inf:
            best = tfm[c] - g + h[nxt, c]
            barg = -2
            if pold == -2:
                oldv = best
            if track:
                bestd = -1.0 + D[nxt, c]
        # Stay: the configuration is unchanged; solved exactly for the self-loop if asked.
        sval = step_cost
        sder = -1.0
        sok = True
        for b in range(b0, b1):
            L = branch_layer[b]
            if (exact_stay and L == m) or branch_prob[b] == 0.0:
                continue
            if not live[L, c] or h[L, c] == np.inf:
                sok = False
                break
            sval += branch_prob[b] * h[L, c]
            if track:
                sder += branch_prob[b] * D[L, c]
        if sok:
            if exact_stay:
                if pself < 1.0 - 1e-12:
                    sval /= 1.0 - pself
                    sder /= 1.0 - pself
                else:
                    sok = False
            if sok and pold == -1:
                oldv = sval
            if sok and sval < best:
                best = sval
                barg = -1
                bestd = sder
        # Moves.
        vb = valid[kcls, c]
        inner = interior[kcls, c]
        t = mi[heading_axis] if heading_axis >= 0 else 0
        if fast and dense[m, c] == vb:
            best, barg, oldv = _dense_moves(
                hm, cwk, cok, c, t, vb, na, step_cost, pold, best, barg, oldv
            )
            vb = 0  # the moves are done
        for a in range(na):
            if ((vb >> a) & 1) == 0:
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
                        hv = hm[i]
                        if hv < np.inf:
                            ssum += wj
                            vsum += wj * hv
                if ssum <= EPS_W:
                    continue
                val = step_cost + vsum / ssum
                if a == pold:
                    oldv = val
                if val < best:
                    best = val
                    barg = a
                continue
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
                    kcls, a, mi, moves.offs, moves.fr, heading_axis, shape, grid.periodic, idx, w
                )
            val = step_cost
            ok = True
            for b in range(b0, b1):
                L = branch_layer[b]
                if branch_prob[b] == 0.0:
                    continue
                ssum = 0.0
                vsum = 0.0
                for j in range(nc):
                    wj = w[j]
                    if wj > EPS_W:
                        i = idx[j]
                        if live[L, i]:
                            hv = h[L, i]
                            if hv < np.inf:
                                ssum += wj
                                vsum += wj * hv
                if ssum <= EPS_W:
                    ok = False
                    break
                val += branch_prob[b] * vsum / ssum
            if ok and a == pold:
                oldv = val
            if ok and val < best:
                best = val
                barg = a
        if track and barg >= 0 and single and inner:
            # The derivative of the winning move only (cheaper than one per action).
            ssum = 0.0
            dsum = 0.0
            for jj in range(ncorner):
                wj = cw[kcls, barg, t, jj]
                if wj <= EPS_W:
                    break
                i = c + coff[kcls, barg, t, jj]
                if livem[i] and hm[i] < np.inf:
                    ssum += wj
                    dsum += wj * D[m, i]
            bestd = -1.0 + dsum / ssum
        elif track and barg >= 0:
            nc = move_corners(
                kcls,
                barg,
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
            bestd = -1.0
            for b in range(b0, b1):
                L = branch_layer[b]
                if branch_prob[b] == 0.0:
                    continue
                ssum = 0.0
                dsum = 0.0
                for j in range(nc):
                    wj = w[j]
                    if wj > EPS_W:
                        i = idx[j]
                        if live[L, i] and h[L, i] < np.inf:
                            ssum += wj
                            dsum += wj * D[L, i]
                bestd += branch_prob[b] * dsum / ssum
        if mode == 1 and pol[m, c] != barg:
            pol[m, c] = barg
            if not oldv - best <= tie:
                nchg[0] += 1
        old = hm[c]
        if best < np.inf:
            ch = abs(best - old) if old < np.inf else np.inf
            if ch > maxchange:
                maxchange = ch
            hm[c] = best
            if track:
                D[m, c] = bestd
    return maxchange


def with_dense(model: Model) -> Model:
    """``model`` with ``layers.dense`` filled (:func:`dense_cells`), as the solver sweeps it."""
    return model._replace(layers=model.layers._replace(dense=dense_cells(model)))


@njit(cache=True)
def dense_cells(model):  # pragma: no cover - numba
    """``(M, N)`` int64 bitmasks: bit ``a`` of ``[m, c]`` is set where ``c`` is a live
    interior cell of layer ``m``, move ``a`` is collision-free from it, and every corner
    it can land on (weight above :data:`EPS_W`) is live in that layer.

    There the interpolation of Section IV-B needs no renormalisation: a sweep of a layer
    whose values are all finite reads those corners without testing them
    (:func:`sweep_policy`), and the improvement step computes those moves a move at a time
    over runs of cells (:mod:`cellplan.strategies.solve.improvement`).
    """
    moves = model.moves
    lay = model.layers
    live = lay.live
    M, N = live.shape
    d = model.grid.shape.shape[0]
    ncorner = 1 << d
    nt = moves.cw.shape[2]
    out = np.zeros((M, N), np.int64)
    mi = np.empty(d, np.int64)
    heading = np.zeros(N, np.int64)  # each cell's slice of the stencil tables
    if moves.heading_axis >= 0:
        for c in range(N):
            decode(c, model.grid.shape, mi)
            heading[c] = mi[moves.heading_axis]
    ok = np.empty(N, np.bool_)
    for m in range(M):
        kcls = lay.vcls[m]
        livem = live[m]
        inside = moves.interior[kcls]
        valid = moves.valid[kcls]
        om = out[m]
        for a in range(moves.nact[kcls]):
            bit = np.int64(1) << a
            for t in range(nt):
                # One move and heading at a time over every cell (slices: vectorised).
                lo = 0
                hi = N
                for jj in range(ncorner):
                    if moves.cw[kcls, a, t, jj] <= EPS_W:
                        break
                    o = moves.coff[kcls, a, t, jj]
                    lo = max(lo, -o)
                    hi = min(hi, N - o)
                if hi <= lo:
                    continue
                okv = ok[lo:hi]
                lv = livem[lo:hi]
                iv = inside[lo:hi]
                hv = heading[lo:hi]
                vv = valid[lo:hi]
                for i in range(hi - lo):
                    okv[i] = lv[i] & iv[i] & (hv[i] == t) & ((vv[i] & bit) != 0)
                for jj in range(ncorner):
                    if moves.cw[kcls, a, t, jj] <= EPS_W:
                        break
                    o = moves.coff[kcls, a, t, jj]
                    lv = livem[lo + o : hi + o]
                    for i in range(hi - lo):
                        okv[i] = okv[i] & lv[i]
                ov = om[lo:hi]
                for i in range(hi - lo):
                    ov[i] |= bit * okv[i]
    return out


@njit(cache=True)
def sweep_layer(m, flips, h, D, g, exact_stay, track, model):  # pragma: no cover - numba
    """One Gauss-Seidel sweep of layer ``m`` over every action (:func:`sweep_policy`, mode 0).

    Returns the largest change of ``h[m]``.
    """
    pol = np.empty((1, 1), np.int16)
    nchg = np.zeros(1, np.int64)
    return sweep_policy(m, flips, h, D, g, exact_stay, track, pol, 0, nchg, 0.0, model)


@njit(cache=True)
def unreached(hm, cells):  # pragma: no cover - numba
    """How many of the live ``cells`` of one layer's values ``hm`` are still at ``+inf``."""
    n = 0
    for c in cells:
        if hm[c] == np.inf:
            n += 1
    return n


@njit(cache=True, nogil=True)
def layer_iteration(
    m, h, D, g, accuracy, cap, limit, pol, warm, check, dijkstra, model
):  # pragma: no cover - numba
    """Policy iteration on one C or W layer; returns (full sweeps, exact evaluations).

    Alternates full Gauss-Seidel sweeps (every action, minimiser recorded in ``pol``) with
    an exact evaluation of the recorded policy once a full sweep changes the minimiser in
    at most :data:`SETTLED_FRACTION` of the cells; stops when a *full* sweep changes the
    values by less than ``accuracy``, or after ``cap`` sweeps and evaluations (an inexact
    solve) once every live state has a finite value, or after ``limit``. After each exact
    evaluation of a single-branch layer, a Jacobi residual check
    (:func:`cellplan.strategies.solve.improvement.improve_layer`, vectorised) ends the solve when
    no state can improve by ``accuracy``, without the confirming sweep (with ``check``: the
    solver asks for it on uncapped passes, where layers converge; on capped ones they stop
    at the cap, and a failed check costs half a sweep in 3-D). A solve started
    from ``+inf`` is never stopped by ``cap`` with live states unreached: a later pass
    would start from them, and an infinite value has no place in the outer iteration's
    arithmetic; it goes on until every live state is reached or ``2^d`` sweeps in a row
    reach none.
    With ``warm`` (later passes) it starts by evaluating the policy recorded in the last
    pass; otherwise (values at ``+inf``), with ``dijkstra``, from the policy of
    :func:`cellplan.strategies.solve.coldstart.dijkstra_layer`.
    """
    d = model.grid.shape.shape[0]
    cells, local = live_cells(model.layers.live[m])
    nlive = cells.shape[0]
    nchg = np.zeros(1, np.int64)
    full = 0
    ev = 0
    flip = 0
    left = nlive  # live states still at +inf (counted only past the cap)
    stuck = 0  # sweeps past the cap in a row that reached no new state
    check = check and improvable(m, model)
    evaluated = False  # h[m] is the exact value of pol[m]
    # Warm start: the recorded policy is last pass's and nearly right, so evaluate it first
    # and let the residual check (or one full sweep) confirm it.
    evaluate_first = warm
    if not warm and dijkstra:
        evaluate_first = dijkstra_layer(m, h, g, pol, model) > 0
    while full + ev < max(1, limit):
        if full + ev >= max(1, cap):
            now = unreached(h[m], cells)
            stuck = 0 if now < left else stuck + 1
            left = now
            if now == 0 or stuck > (1 << d):
                break
        if evaluate_first:
            evaluate_first = False
        elif check and evaluated and unreached(h[m], cells) == 0:
            # Just evaluated: the values are exact for the policy, so the Bellman residual
            # of every state (one Jacobi improvement step, vectorised: improvement.py)
            # tells whether the layer is solved, at a quarter of a sweep's cost. If not and
            # few actions change, the improved policy is evaluated (policy iteration);
            # if many, Gauss-Seidel sweeps go on: they carry improvements across the layer
            # in one sweep, where policy iteration moves a change of action by about one
            # cell per step on a fine grid.
            residual, changed = improve_layer(m, h, g, pol, accuracy, model)
            evaluated = False
            if residual < accuracy:
                full += 1
                break
            if 0 < changed <= PI_FRACTION * nlive:
                full += 1
                ptr, succ, wt, const, dconst, fixed = layer_system(
                    m, h, D, g, pol, cells, local, model
                )
                evaluate(h[m], D[m], cells, ptr, succ, wt, const, dconst, fixed)
                ev += 1
                evaluated = True
            continue
        else:
            nchg[0] = 0
            change = sweep_policy(
                m, flip % (1 << d), h, D, g, False, True, pol, 1, nchg, accuracy, model
            )
            full += 1
            flip += 1
            evaluated = False
            if change < accuracy:
                break
        if nchg[0] <= SETTLED_FRACTION * nlive:
            ptr, succ, wt, const, dconst, fixed = layer_system(m, h, D, g, pol, cells, local, model)
            evaluate(h[m], D[m], cells, ptr, succ, wt, const, dconst, fixed)
            ev += 1
            evaluated = True
    return full, ev


@njit(cache=True, nogil=True)
def other_branches(m, h, D, E, ED, start, stop, model):  # pragma: no cover - numba
    """Expected next value over the branches that leave layer ``m``, per cell and action.

    ``E[c, 0] = sum_{b: L_b != m} P_b h[L_b](c)`` for stay and ``E[c, 1 + a]`` the same at
    the landing point of move ``a`` (interpolated as in :func:`sweep_policy`); ``ED`` is
    the same for ``D``. ``inf`` marks an action that is not available (move not
    collision-free, or some branch without a live corner). In NR these branches lead to
    the W layers, which are fixed while NR is solved, so a Gauss-Seidel sweep of NR then
    touches only its own values (the request branches cost 16 interpolations per move in
    problem 1; done once here instead of once per sweep). Only cells ``start <= c < stop``
    are written, so that disjoint ranges can run in parallel threads.
    """
    moves = model.moves
    grid = model.grid
    lay = model.layers
    live = lay.live
    cw = moves.cw
    coff = moves.coff
    heading_axis = moves.heading_axis
    shape = grid.shape
    d = shape.shape[0]
    ncorner = 1 << d
    kcls = lay.vcls[m]
    na = moves.nact[kcls]
    b0 = lay.branch_ptr[m]
    b1 = lay.branch_ptr[m + 1]
    mi = np.empty(d, np.int64)
    idx = np.empty(ncorner, np.int64)
    w = np.empty(ncorner)
    for c in range(start, stop):
        for a in range(E.shape[1]):
            E[c, a] = np.inf
            ED[c, a] = 0.0
        if not live[m, c]:
            continue
        decode(c, grid.shape, mi)
        sval = 0.0
        sder = 0.0
        sok = True
        for b in range(b0, b1):
            L = lay.branch_layer[b]
            if L == m or lay.branch_prob[b] == 0.0:
                continue
            if not live[L, c] or h[L, c] == np.inf:
                sok = False
                break
            sval += lay.branch_prob[b] * h[L, c]
            sder += lay.branch_prob[b] * D[L, c]
        if sok:
            E[c, 0] = sval
            ED[c, 0] = sder
        vb = moves.valid[kcls, c]
        inner = moves.interior[kcls, c]
        t = mi[heading_axis] if heading_axis >= 0 else 0
        for a in range(na):
            if ((vb >> a) & 1) == 0:
                continue
            # Written out, as in sweep_policy (an inlined helper is slower here).
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
                    kcls, a, mi, moves.offs, moves.fr, heading_axis, shape, grid.periodic, idx, w
                )
            val = 0.0
            der = 0.0
            ok = True
            for b in range(b0, b1):
                L = lay.branch_layer[b]
                if L == m or lay.branch_prob[b] == 0.0:
                    continue
                ssum = 0.0
                vsum = 0.0
                dsum = 0.0
                for j in range(nc):
                    wj = w[j]
                    if wj > EPS_W:
                        i = idx[j]
                        if live[L, i]:
                            hv = h[L, i]
                            if hv < np.inf:
                                ssum += wj
                                vsum += wj * hv
                                dsum += wj * D[L, i]
                if ssum <= EPS_W:
                    ok = False
                    break
                val += lay.branch_prob[b] * vsum / ssum
                der += lay.branch_prob[b] * dsum / ssum
            if ok:
                E[c, 1 + a] = val
                ED[c, 1 + a] = der


@njit(cache=True, nogil=True)
def sweep_self(
    m, flips, h, D, g, E, ED, pself, pol, mode, nchg, tie, model, rows, frozen_h, frozen_D
):  # pragma: no cover - numba
    """One Gauss-Seidel sweep of a slab of a layer without FMP whose other branches are in
    ``E``.

    The update of :func:`sweep_policy` with ``exact_stay`` for NR (``pself`` is the
    probability of staying in the layer): stay is solved exactly,
    ``h = (l - g + E[c, 0]) / (1 - pself)``, and a move costs
    ``l - g + E[c, 1 + a] + pself * H_m(x')``. ``pol``, ``mode`` and ``nchg`` as in
    :func:`sweep_policy`. Returns the largest change.

    Only the cells whose first index lies in ``rows = (start, stop)`` are updated, in the
    sweep order; a landing corner outside the slab is read from ``frozen_h`` and
    ``frozen_D`` (the layer's values before the sweep) rather than from ``h`` and ``D``.
    Slabs of one sweep therefore read nothing another writes, so they can run on parallel
    threads in any order and give the same values: Gauss-Seidel inside a slab, Jacobi
    across slabs.
    """
    moves = model.moves
    grid = model.grid
    lay = model.layers
    cw = moves.cw
    coff = moves.coff
    heading_axis = moves.heading_axis
    shape = grid.shape
    d = shape.shape[0]
    ncell = h.shape[1]
    mi = np.empty(d, np.int64)
    ncorner = 1 << d
    idx = np.empty(ncorner, np.int64)
    w = np.empty(ncorner)
    hm = h[m]
    Dm = D[m]
    livem = lay.live[m]
    kcls = lay.vcls[m]
    na = moves.nact[kcls]
    step_cost = lay.cost[m] - g
    maxchange = 0.0
    # The slab is a run of flat indices (the first axis varies slowest).
    stride = ncell // shape[0]
    lo = rows[0] * stride
    hi = rows[1] * stride
    # A cell at least `reach` rows inside the slab lands only on corners in the slab.
    reach = 0
    for a in range(na):
        for t in range(moves.offs.shape[2]):
            o = moves.offs[kcls, a, t, 0]
            reach = max(reach, -o if o < 0 else o + 1)
    safe_lo = lo + reach * stride
    safe_hi = hi - reach * stride
    c = -1
    for kk in range(hi - lo):
        c = first_of_rows(shape, flips, rows, mi) if kk == 0 else next_of_order(shape, flips, mi)
        if not livem[c]:
            continue
        inside = safe_lo <= c < safe_hi
        best = np.inf
        bestd = 0.0
        barg = -3
        pold = pol[m, c] if mode == 1 else -9
        oldv = np.inf
        if E[c, 0] < np.inf and pself < 1.0 - 1e-12:
            best = (step_cost + E[c, 0]) / (1.0 - pself)
            bestd = (-1.0 + ED[c, 0]) / (1.0 - pself)
            barg = -1
            if pold == -1:
                oldv = best
        vb = moves.valid[kcls, c]
        inner = moves.interior[kcls, c]
        t = mi[heading_axis] if heading_axis >= 0 else 0
        for a in range(na):
            if ((vb >> a) & 1) == 0 or E[c, 1 + a] == np.inf:
                continue
            # Written out, as in sweep_policy (move_corners here is twice as slow).
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
                    kcls, a, mi, moves.offs, moves.fr, heading_axis, shape, grid.periodic, idx, w
                )
            val = step_cost + E[c, 1 + a]
            der = -1.0 + ED[c, 1 + a]
            if pself > 0.0:
                ssum = 0.0
                vsum = 0.0
                dsum = 0.0
                for j in range(nc):
                    wj = w[j]
                    if wj > EPS_W:
                        i = idx[j]
                        if livem[i]:
                            own = inside or lo <= i < hi
                            hv = hm[i] if own else frozen_h[i]
                            if hv < np.inf:
                                ssum += wj
                                vsum += wj * hv
                                dsum += wj * (Dm[i] if own else frozen_D[i])
                if ssum <= EPS_W:
                    continue
                val += pself * vsum / ssum
                der += pself * dsum / ssum
            if a == pold:
                oldv = val
            if val < best:
                best = val
                bestd = der
                barg = a
        if mode == 1 and pol[m, c] != barg:
            pol[m, c] = barg
            if not oldv - best <= tie:
                nchg[0] += 1
        old = hm[c]
        if best < np.inf:
            ch = abs(best - old) if old < np.inf else np.inf
            if ch > maxchange:
                maxchange = ch
            hm[c] = best
            Dm[c] = bestd
    return maxchange
