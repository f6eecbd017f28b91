"""Numba kernels of the strategies solver: interpolation, swept-motion checks, Bellman sweeps.

All kernels work on a uniform grid of cell centres over the C-space (flat C-order
indices) and on the layered MDP of :mod:`cellplan.strategies.model`:

* a layer ``m`` (one assembly mode) has a per-stage cost ``cost[m]`` (0 in NR, the stage
  time otherwise, equation (7)), a move class ``vcls[m]`` (its free bitmap, the action
  displacements and the bitmask of collision-free actions per cell), an FMP successor
  ``fmp_next[m]`` with fine-motion time ``tf[m, c]`` (``inf`` where FMP is not allowed),
  and branches ``(branch_layer[b], branch_prob[b])`` for ``b`` in
  ``branch_ptr[m]:branch_ptr[m+1]``: after a move or a stay the next mode is
  ``branch_layer[b]`` with probability ``branch_prob[b]`` (Section III-B);
* ``live[m, c]`` marks the states that belong to the MDP (free and able to finish the
  request); interpolation (Section IV-B) uses the multilinear weights of the ``2^d``
  surrounding cell centres, renormalised over the live ones, so it is also the
  transition distribution of the discretised MDP.

The model arrays travel as one tuple ``model``, in the order of
:meth:`~cellplan.strategies.model.LayeredMDP.kernel_args` (``live, valid, offs, fr, coff,
cw, interior, nact, heading_axis, vcls, cost, fmp_next, tf, branch_ptr, branch_layer,
branch_prob, shape, periodic``); each kernel unpacks the ones it reads.

Action ``a`` of move class ``k`` displaces a configuration by ``disp[k, a]``; with
``heading_axis >= 0`` the first two components are in the robot frame (rotated by the
angle on that axis), which gives the rotating robot of problem 3 its "move along the
axis" action.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from cellplan.strategies.coldstart import dijkstra_layer
from cellplan.strategies.evaluation import evaluate, layer_system, live_cells, self_system
from cellplan.strategies.stencils import (
    EPS_W,
    MAX_DIM,
    cell_containing,
    cell_of_order,
    centre,
    decode,
    displacement,
    first_of_order,
    move_corners,
    next_of_order,
    stencil,
    table_stencil,
    wrap,
)

_EPS_W = EPS_W


@njit(cache=True, inline="always")
def interp(values, live, idx, w, n):  # pragma: no cover - numba
    """Weighted mean over the live corners; NaN when no live corner has weight."""
    s = 0.0
    v = 0.0
    for k in range(n):
        if w[k] > _EPS_W and live[idx[k]]:
            s += w[k]
            v += w[k] * values[idx[k]]
    if s <= _EPS_W:
        return np.nan
    return v / s


@njit(cache=True, inline="always")
def interp2(values, live, L, idx, w, n):  # pragma: no cover - numba
    """:func:`interp` on layer ``L`` of 2-D arrays, also skipping corners not yet reached.

    During a Gauss-Seidel solve started from ``+inf`` the corners still at ``inf`` are
    left out (and the weights renormalised), so the wavefront can cross thin target sets;
    at convergence every live value is finite and this is the MDP's transition.
    """
    s = 0.0
    v = 0.0
    for k in range(n):
        i = idx[k]
        if w[k] > _EPS_W and live[L, i] and values[L, i] < np.inf:
            s += w[k]
            v += w[k] * values[L, i]
    if s <= _EPS_W:
        return np.nan
    return v / s


@njit(cache=True, inline="always")
def interp2_der(D, h, live, L, idx, w, n):  # pragma: no cover - numba
    """The derivative field interpolated with the weights :func:`interp2` used for ``h``."""
    s = 0.0
    v = 0.0
    for k in range(n):
        i = idx[k]
        if w[k] > _EPS_W and live[L, i] and h[L, i] < np.inf:
            s += w[k]
            v += w[k] * D[L, i]
    if s <= _EPS_W:
        return 0.0
    return v / s


@njit(cache=True, inline="always")
def supported(live, idx, w, n):  # pragma: no cover - numba
    """Whether some live corner of the stencil has positive weight."""
    for k in range(n):
        if w[k] > _EPS_W and live[idx[k]]:
            return True
    return False


@njit(cache=True)
def motion_ok(q, dq, free, shape, lower, upper, spacing, periodic, ibuf):  # pragma: no cover
    """Swept check of the straight C-space segment ``q -> q + dq`` against a free bitmap.

    The segment is cut into pieces no longer than one cell per axis; each piece lies in
    the box of cells spanned by its end points, and every one of those cells must be
    free. Free cells of the conservative bitmaps are free throughout their box, so a
    motion passing this test is collision-free (not only its end point).
    """
    d = shape.shape[0]
    nsub = 1
    for j in range(d):
        m = math.ceil(abs(dq[j]) / spacing[j] - 1e-9)
        if m > nsub:
            nsub = m
    lo_c = ibuf[:MAX_DIM]
    cnt = ibuf[MAX_DIM : 2 * MAX_DIM]
    cur = ibuf[2 * MAX_DIM :]
    for s in range(nsub):
        t0 = s / nsub
        t1 = (s + 1) / nsub
        total = 1
        for j in range(d):
            a = q[j] + t0 * dq[j]
            b = q[j] + t1 * dq[j]
            lo = min(a, b)
            hi = max(a, b)
            if not periodic[j]:
                if lo < lower[j] - 1e-9 or hi > upper[j] + 1e-9:
                    return False
            c0 = math.floor((lo - lower[j]) / spacing[j])
            c1 = math.floor((hi - lower[j]) / spacing[j])
            if not periodic[j]:
                c0 = min(max(c0, 0), shape[j] - 1)
                c1 = min(max(c1, 0), shape[j] - 1)
            lo_c[j] = c0
            cnt[j] = c1 - c0 + 1
            total *= cnt[j]
        for k in range(total):
            rem = k
            for j in range(d - 1, -1, -1):
                off = rem % cnt[j]
                rem //= cnt[j]
                ij = lo_c[j] + off
                if periodic[j]:
                    ij = ij % shape[j]
                cur[j] = ij
            flat = 0
            for j in range(d):
                flat = flat * shape[j] + cur[j]
            if not free[flat]:
                return False
    return True


@njit(cache=True)
def valid_moves(
    free, disp, heading_axis, shape, lower, upper, spacing, periodic
):  # pragma: no cover
    """Bitmask per cell of the actions whose swept motion from the cell centre is free."""
    d = shape.shape[0]
    ncell = free.shape[0]
    nact = disp.shape[0]
    out = np.zeros(ncell, np.int64)
    q = np.empty(d)
    dq = np.empty(d)
    mbuf = np.empty(3 * MAX_DIM, np.int64)
    for c in range(ncell):
        if not free[c]:
            continue
        centre(c, shape, lower, spacing, q)
        bits = 0
        for a in range(nact):
            displacement(q, disp[a], heading_axis, dq)
            if motion_ok(q, dq, free, shape, lower, upper, spacing, periodic, mbuf):
                bits |= 1 << a
        out[c] = bits
    return out


@njit(cache=True)
def sweep_policy(
    m, flips, h, D, g, exact_stay, track, pol, mode, nchg, tie, model
):  # pragma: no cover - numba
    """One Gauss-Seidel sweep of layer ``m`` in place (axis order reversed where ``flips``).

    ``mode`` 0: ``pol`` is not touched; 1: the minimiser is recorded in ``pol[m]``,
    ``nchg[0]`` counting the cells whose minimiser changed by more than ``tie`` in value
    (ties between equally good actions are not counted). Between such sweeps the solver
    evaluates the recorded policy exactly (:mod:`cellplan.strategies.evaluation`).

    ``h[m, c] = min_u [ l(u) - g + sum_b P_b h[L_b](x'_u) ]`` (the average-cost form of
    equation (9)); with ``exact_stay`` the stay action's self-loop is solved exactly,
    ``h = (l - g + sum_{b != m} P_b h[L_b](x)) / (1 - P_mm)``. With ``track`` the
    derivative ``D = dh/dg`` along the minimising action is updated as well (used by the
    g update of the structured solver). Returns the largest change of ``h[m]``.

    The move loop is written out here rather than calling a helper: a call that passes
    a dozen arrays costs more than the arithmetic it does.
    """
    (
        live, valid, offs, fr, coff, cw, interior, nact, heading_axis, vcls, cost, fmp_next, tf,
        branch_ptr, branch_layer, branch_prob, shape, periodic,
    ) = model  # fmt: skip
    d = shape.shape[0]
    ncell = h.shape[1]
    mi = np.empty(d, np.int64)
    ncorner = 1 << d
    idx = np.empty(ncorner, np.int64)
    w = np.empty(ncorner)
    hm = h[m]
    livem = live[m]
    nxt = fmp_next[m]
    kcls = vcls[m]
    na = nact[kcls]
    b0 = branch_ptr[m]
    b1 = branch_ptr[m + 1]
    step_cost = cost[m] - g
    pself = 0.0
    for b in range(b0, b1):
        if branch_layer[b] == m:
            pself += branch_prob[b]
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
        if nxt >= 0 and tf[m, c] < np.inf and live[nxt, c] and h[nxt, c] < np.inf:
            best = tf[m, c] - g + h[nxt, c]
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
        for a in range(na):
            if ((vb >> a) & 1) == 0:
                continue
            # Written out: numba compiles the inlined move_corners into a loop about twice
            # as slow here, the hottest loop of the solver.
            if inner:
                nc = 0
                for jj in range(ncorner):
                    wj = cw[kcls, a, t, jj]
                    if wj <= _EPS_W:
                        break
                    idx[jj] = c + coff[kcls, a, t, jj]
                    w[jj] = wj
                    nc += 1
            else:
                table_stencil(kcls, a, mi, offs, fr, heading_axis, shape, periodic, idx, w)
                nc = ncorner
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
                    if wj > _EPS_W:
                        i = idx[j]
                        if live[L, i]:
                            hv = h[L, i]
                            if hv < np.inf:
                                ssum += wj
                                vsum += wj * hv
                if ssum <= _EPS_W:
                    ok = False
                    break
                val += branch_prob[b] * vsum / ssum
            if ok and a == pold:
                oldv = val
            if ok and val < best:
                best = val
                barg = a
        if track and barg >= 0:
            # The derivative of the winning move only (cheaper than one per action).
            nc = move_corners(
                kcls, barg, c, mi, inner, offs, fr, coff, cw, heading_axis, shape, periodic, idx, w
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
                    if wj > _EPS_W:
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
            if old < np.inf:
                ch = abs(best - old)
            else:
                ch = np.inf
            if ch > maxchange:
                maxchange = ch
            hm[c] = best
            if track:
                D[m, c] = bestd
    return maxchange


@njit(cache=True)
def sweep_layer(
    m,
    flips,
    h,
    D,
    g,
    exact_stay,
    track,
    model,
):  # pragma: no cover - numba
    """One Gauss-Seidel sweep of layer ``m`` over every action (:func:`sweep_policy`, mode 0).

    ``h[m, c] = min_u [ l(u) - g + sum_b P_b h[L_b](x'_u) ]`` (the average-cost form of
    equation (9)); with ``exact_stay`` the stay action's self-loop is solved exactly,
    ``h = (l - g + sum_{b != m} P_b h[L_b](x)) / (1 - P_mm)``. With ``track`` the
    derivative ``D = dh/dg`` along the minimising action is updated as well. Returns the
    largest change of ``h[m]``.
    """
    pol = np.empty((1, 1), np.int16)
    nchg = np.zeros(1, np.int64)
    return sweep_policy(m, flips, h, D, g, exact_stay, track, pol, 0, nchg, 0.0, model)


@njit(cache=True, parallel=True)
def bellman_all(
    h,
    out,
    policy,
    gap,
    subset,
    model,
):  # pragma: no cover - numba
    """One Jacobi Bellman sweep over every state: ``out = T h`` (no g subtracted).

    ``policy[m, c]`` receives the minimising action: ``-1`` stay, ``-2`` FMP, ``a >= 0``
    move ``a``; ``-3`` for states outside the MDP. Ties (within 1e-12 relative) go to the
    first action in the order FMP, stay, moves. ``gap[m, c]`` receives the second-best
    action value minus the best (``inf`` with a single action): adding to ``h`` anything
    whose span (max - min) is below it cannot change the action there. A non-empty
    ``subset`` (boolean, like ``h``) limits the sweep to the live states it marks (the
    outputs elsewhere are left as they were).
    """
    (
        live, valid, offs, fr, coff, cw, interior, nact, heading_axis, vcls, cost, fmp_next, tf,
        branch_ptr, branch_layer, branch_prob, shape, periodic,
    ) = model  # fmt: skip
    M = h.shape[0]
    ncell = h.shape[1]
    some = subset.shape[0] > 0
    d = shape.shape[0]
    ncorner = 1 << d
    # A Jacobi sweep: every state is independent, so chunks of states run in parallel.
    nchunk = 64
    for chunk in prange(M * nchunk):
        m = chunk // nchunk
        part = chunk % nchunk
        mi = np.empty(d, np.int64)
        idx = np.empty(ncorner, np.int64)
        w = np.empty(ncorner)
        nxt = fmp_next[m]
        kcls = vcls[m]
        na = nact[kcls]
        b0 = branch_ptr[m]
        b1 = branch_ptr[m + 1]
        for c in range(part * ncell // nchunk, (part + 1) * ncell // nchunk):
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
            if nxt >= 0 and tf[m, c] < np.inf and live[nxt, c]:
                best = tf[m, c] + h[nxt, c]
                arg = -2
            sval = cost[m]
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
            for a in range(na):
                if ((vb >> a) & 1) == 0:
                    continue
                nc = move_corners(
                    kcls, a, c, mi, inner, offs, fr, coff, cw, heading_axis, shape, periodic, idx, w
                )
                val = cost[m]
                ok = True
                for b in range(b0, b1):
                    L = branch_layer[b]
                    ssum = 0.0
                    vsum = 0.0
                    for j in range(nc):
                        wj = w[j]
                        if wj > _EPS_W and live[L, idx[j]]:
                            ssum += wj
                            vsum += wj * h[L, idx[j]]
                    if ssum <= _EPS_W:
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


@njit(cache=True)
def action_values_at(
    q,
    m,
    h,
    live,
    free,
    disp,
    nact,
    heading_axis,
    vcls,
    cost,
    fmp_next,
    tf_here,
    fmp_allowed,
    branch_ptr,
    branch_layer,
    branch_prob,
    shape,
    lower,
    upper,
    spacing,
    periodic,
    out,
):  # pragma: no cover - numba
    """Right-hand side of equation (9) at a real configuration ``q`` in mode ``m``.

    ``out[0]`` is FMP, ``out[1]`` stay, ``out[2 + a]`` move ``a``; NaN marks an action that is
    not available (collision along the swept motion, outside the MDP, FMP outside the
    region). ``free[vcls[m]]`` is the bitmap of the swept-motion check.
    """
    d = shape.shape[0]
    qn = np.empty(d)
    dq = np.empty(d)
    idx = np.empty(1 << d, np.int64)
    w = np.empty(1 << d)
    ibuf = np.empty(3 * MAX_DIM, np.int64)
    fbuf = np.empty(MAX_DIM)
    mbuf = np.empty(3 * MAX_DIM, np.int64)
    k = vcls[m]
    na = nact[k]
    for i in range(out.shape[0]):
        out[i] = np.nan
    nxt = fmp_next[m]
    if nxt >= 0 and fmp_allowed:
        n = stencil(q, shape, lower, spacing, periodic, idx, w, ibuf, fbuf)
        v = interp(h[nxt], live[nxt], idx, w, n)
        if not np.isnan(v):
            out[0] = tf_here + v
    for a in range(-1, na):
        if a >= 0:
            displacement(q, disp[k, a], heading_axis, dq)
            if not motion_ok(q, dq, free[k], shape, lower, upper, spacing, periodic, mbuf):
                continue
            for j in range(d):
                qn[j] = q[j] + dq[j]
            wrap(qn, lower, upper, periodic)
        else:
            for j in range(d):
                qn[j] = q[j]
        n = stencil(qn, shape, lower, spacing, periodic, idx, w, ibuf, fbuf)
        val = cost[m]
        ok = True
        for b in range(branch_ptr[m], branch_ptr[m + 1]):
            L = branch_layer[b]
            v = interp(h[L], live[L], idx, w, n)
            if np.isnan(v):
                ok = False
                break
            val += branch_prob[b] * v
        if ok:
            out[2 + a] = val
    # While a request waits, stay is dominated in the MDP (it costs a stage and changes
    # nothing), but at an off-grid state the interpolated cost-to-go can make it look best
    # and the robot would wait for ever; offer it only when no motion is possible.
    if nxt >= 0:
        for i in range(2, out.shape[0]):
            if not np.isnan(out[i]):
                out[1] = np.nan
                break


@njit(cache=True)
def live_pass(
    live,
    fmp_ok,
    valid,
    offs,
    fr,
    coff,
    cw,
    interior,
    nact,
    heading_axis,
    vcls,
    fmp_next,
    branch_ptr,
    branch_layer,
    branch_prob,
    shape,
    periodic,
):  # pragma: no cover - numba
    """Shrink ``live`` once: a state stays live when it can finish its request.

    Layers with an FMP successor keep the states from which an FMP-capable state is
    reachable through actions whose every branch lands on live states (a backward
    closure); a layer without FMP (NR) keeps the states that have some such action.
    Returns whether anything changed; the caller repeats until nothing does.
    """
    M = live.shape[0]
    ncell = live.shape[1]
    d = shape.shape[0]
    mi = np.empty(d, np.int64)
    idx = np.empty(1 << d, np.int64)
    w = np.empty(1 << d)
    changed = False
    reach = np.zeros(ncell, np.bool_)
    for m in range(M):
        nxt = fmp_next[m]
        k = vcls[m]
        na = nact[k]
        if nxt >= 0:
            for c in range(ncell):
                reach[c] = live[m, c] and fmp_ok[m, c] and live[nxt, c]
            target = reach
        else:
            target = live[m].copy()
        sweep = 0
        while True:
            grew = False
            for kk in range(ncell):
                c = cell_of_order(kk, shape, sweep % (1 << d), mi)
                if not live[m, c]:
                    continue
                if nxt >= 0 and target[c]:
                    continue
                good = False
                for a in range(-1, na):
                    if a >= 0:
                        if ((valid[k, c] >> a) & 1) == 0:
                            continue
                        inner = interior[k, c]
                        n = move_corners(
                            k,
                            a,
                            c,
                            mi,
                            inner,
                            offs,
                            fr,
                            coff,
                            cw,
                            heading_axis,
                            shape,
                            periodic,
                            idx,
                            w,
                        )
                    else:
                        if nxt >= 0:
                            continue  # staying never finishes a request
                        n = 1
                        idx[0] = c
                        w[0] = 1.0
                    allsup = True
                    for b in range(branch_ptr[m], branch_ptr[m + 1]):
                        L = branch_layer[b]
                        if branch_prob[b] <= 0.0:
                            continue
                        src = target if L == m else live[L]
                        if not supported(src, idx, w, n):
                            allsup = False
                            break
                    if allsup:
                        good = True
                        break
                if nxt >= 0:
                    if good:
                        target[c] = True
                        grew = True
                elif not good and target[c]:
                    target[c] = False
                    grew = True
            sweep += 1
            if not grew:
                break
        for c in range(ncell):
            if live[m, c] != target[c]:
                changed = True
            live[m, c] = target[c]
    return changed


@njit(cache=True)
def query(
    q,
    m,
    h,
    live,
    free,
    disp,
    nact,
    heading_axis,
    vcls,
    cost,
    fmp_next,
    tf,
    forbid_fmp,
    branch_ptr,
    branch_layer,
    branch_prob,
    shape,
    lower,
    upper,
    spacing,
    periodic,
    out,
):  # pragma: no cover - numba
    """The optimal action at a real state in one call (the online step of Section IV-B).

    FMP is offered where the grid cell containing ``q`` allows it (unless ``forbid_fmp``).
    Returns -2 (FMP), -1 (stay), a move index, or -9 when no action is available; ``out``
    receives the right-hand side of (9) per action as in :func:`action_values_at`.
    """
    c = cell_containing(q, shape, lower, spacing, periodic)
    tf_here = tf[m, c]
    allowed = (not forbid_fmp) and tf_here < np.inf
    action_values_at(
        q,
        m,
        h,
        live,
        free,
        disp,
        nact,
        heading_axis,
        vcls,
        cost,
        fmp_next,
        tf_here if allowed else 0.0,
        allowed,
        branch_ptr,
        branch_layer,
        branch_prob,
        shape,
        lower,
        upper,
        spacing,
        periodic,
        out,
    )
    best = np.inf
    arg = -9
    for i in range(out.shape[0]):
        v = out[i]
        if not np.isnan(v) and v < best:
            best = v
            arg = i
    if arg < 0:
        return -9
    return -2 if arg == 0 else -1 if arg == 1 else arg - 2


@njit(cache=True, parallel=True)
def solve_layers(
    ms,
    h,
    D,
    g,
    accuracy,
    max_sweeps,
    pol,
    warm,
    dijkstra,
    counts,
    model,
):  # pragma: no cover - numba
    """Solve independent layers ``ms`` by policy iteration, in parallel.

    Each layer alternates full Gauss-Seidel sweeps (every action, minimiser recorded in
    ``pol``) with an exact evaluation of the recorded policy
    (:mod:`cellplan.strategies.evaluation`) once a full sweep changes the minimiser in
    fewer than 1% of the cells; it stops when a *full* sweep changes the values by less
    than ``accuracy``. ``counts[i]`` receives (full sweeps, evaluations) of ``ms[i]``.
    With ``warm`` (later passes) each layer starts by evaluating the policy recorded in the
    last pass; otherwise (values at ``+inf``), with ``dijkstra``, from the policy of
    :func:`cellplan.strategies.coldstart.dijkstra_layer`. The layers must not read each
    other (C layers read only NR, W layers only C layers), so the threads never race.
    """
    for i in prange(ms.shape[0]):
        full, ev = _mpi(ms[i], h, D, g, False, accuracy, max_sweeps, pol, warm, dijkstra, model)
        counts[i, 0] = full
        counts[i, 1] = ev


@njit(cache=True)
def _mpi(
    m, h, D, g, exact_stay, accuracy, max_sweeps, pol, warm, dijkstra, model
):  # pragma: no cover - numba
    """Policy iteration on one layer (see :func:`solve_layers`)."""
    (
        live, valid, _offs, _fr, coff, _cw, interior, nact, heading_axis, vcls, cost, fmp_next, tf,
        _branch_ptr, _branch_layer, _branch_prob, shape, _periodic,
    ) = model  # fmt: skip
    d = shape.shape[0]
    cells, local = live_cells(live[m])
    nlive = cells.shape[0]
    nchg = np.zeros(1, np.int64)
    full = 0
    ev = 0
    flip = 0
    # Warm start: the recorded policy is last pass's and nearly right, so evaluate it first
    # and let one full sweep confirm (saves a full sweep per layer and pass).
    evaluate_first = warm
    if not warm and dijkstra:
        # Cold start: a first policy by Dijkstra, then exact evaluation and full sweeps.
        evaluate_first = (
            dijkstra_layer(
                m,
                h,
                g,
                pol,
                live,
                valid,
                coff,
                interior,
                nact,
                heading_axis,
                vcls,
                cost,
                fmp_next,
                tf,
                shape,
            )
            > 0
        )
    while full + ev < max(1, max_sweeps):
        if evaluate_first:
            evaluate_first = False
        else:
            nchg[0] = 0
            change = sweep_policy(
                m, flip % (1 << d), h, D, g, exact_stay, True, pol, 1, nchg, accuracy, model
            )
            full += 1
            flip += 1
            if change < accuracy:
                break
        if nchg[0] * 100 <= nlive:
            # The policy has nearly settled: evaluate it exactly (one pass in dependency
            # order, :mod:`cellplan.strategies.evaluation`) rather than by many sweeps.
            ptr, succ, wt, const, dconst, fixed = layer_system(m, h, D, g, pol, cells, local, model)
            evaluate(h[m], D[m], cells, ptr, succ, wt, const, dconst, fixed)
            ev += 1
    return full, ev


@njit(cache=True, parallel=True)
def other_branches(
    m,
    h,
    D,
    E,
    ED,
    model,
):  # pragma: no cover - numba
    """Expected next value over the branches that leave layer ``m``, per cell and action.

    ``E[c, 0]`` is ``sum_{b: L_b != m} P_b h[L_b](c)`` for stay and ``E[c, 1 + a]`` the
    same at the landing point of move ``a`` (interpolated as in :func:`sweep_layer`);
    ``ED`` is the same for ``D``. ``inf`` marks an action that is not available (move not
    collision-free, or some branch without a live corner). In NR these branches lead to
    the W layers, which are fixed while NR is solved, so a Gauss-Seidel sweep of NR then
    touches only its own values (the request branches cost 16 interpolations per move in
    problem 1; done once here instead of once per sweep).
    """
    (
        live, valid, offs, fr, coff, cw, interior, nact, heading_axis, vcls, _cost, _fmp_next, _tf,
        branch_ptr, branch_layer, branch_prob, shape, periodic,
    ) = model  # fmt: skip
    d = shape.shape[0]
    ncell = h.shape[1]
    ncorner = 1 << d
    kcls = vcls[m]
    na = nact[kcls]
    b0 = branch_ptr[m]
    b1 = branch_ptr[m + 1]
    nchunk = 64
    for chunk in prange(nchunk):
        mi = np.empty(d, np.int64)
        idx = np.empty(ncorner, np.int64)
        w = np.empty(ncorner)
        for c in range(chunk * ncell // nchunk, (chunk + 1) * ncell // nchunk):
            for a in range(E.shape[1]):
                E[c, a] = np.inf
                ED[c, a] = 0.0
            if not live[m, c]:
                continue
            decode(c, shape, mi)
            sval = 0.0
            sder = 0.0
            sok = True
            for b in range(b0, b1):
                L = branch_layer[b]
                if L == m or branch_prob[b] == 0.0:
                    continue
                if not live[L, c] or h[L, c] == np.inf:
                    sok = False
                    break
                sval += branch_prob[b] * h[L, c]
                sder += branch_prob[b] * D[L, c]
            if sok:
                E[c, 0] = sval
                ED[c, 0] = sder
            vb = valid[kcls, c]
            inner = interior[kcls, c]
            for a in range(na):
                if ((vb >> a) & 1) == 0:
                    continue
                nc = move_corners(
                    kcls, a, c, mi, inner, offs, fr, coff, cw, heading_axis, shape, periodic, idx, w
                )
                val = 0.0
                der = 0.0
                ok = True
                for b in range(b0, b1):
                    L = branch_layer[b]
                    if L == m or branch_prob[b] == 0.0:
                        continue
                    ssum = 0.0
                    vsum = 0.0
                    dsum = 0.0
                    for j in range(nc):
                        wj = w[j]
                        if wj > _EPS_W:
                            i = idx[j]
                            if live[L, i]:
                                hv = h[L, i]
                                if hv < np.inf:
                                    ssum += wj
                                    vsum += wj * hv
                                    dsum += wj * D[L, i]
                    if ssum <= _EPS_W:
                        ok = False
                        break
                    val += branch_prob[b] * vsum / ssum
                    der += branch_prob[b] * dsum / ssum
                if ok:
                    E[c, 1 + a] = val
                    ED[c, 1 + a] = der


@njit(cache=True)
def sweep_self(
    m, flips, h, D, g, E, ED, pself, pol, mode, nchg, tie, model
):  # pragma: no cover - numba
    """One Gauss-Seidel sweep of a layer without FMP whose other branches are in ``E``.

    The same update as :func:`sweep_layer` with ``exact_stay`` for NR (``pself`` is the
    probability of staying in the layer): stay is solved exactly,
    ``h = (l - g + E[c, 0]) / (1 - pself)``, and a move costs
    ``l - g + E[c, 1 + a] + pself * h[m](x')``. ``pol``, ``mode`` and ``nchg`` as in
    :func:`sweep_policy`. Returns the largest change.
    """
    (
        live, valid, offs, fr, coff, cw, interior, nact, heading_axis, vcls, cost, _fmp_next, _tf,
        _branch_ptr, _branch_layer, _branch_prob, shape, periodic,
    ) = model  # fmt: skip
    d = shape.shape[0]
    ncell = h.shape[1]
    mi = np.empty(d, np.int64)
    ncorner = 1 << d
    idx = np.empty(ncorner, np.int64)
    w = np.empty(ncorner)
    hm = h[m]
    Dm = D[m]
    livem = live[m]
    kcls = vcls[m]
    na = nact[kcls]
    step_cost = cost[m] - g
    maxchange = 0.0
    c = -1
    for kk in range(ncell):
        c = first_of_order(shape, flips, mi) if kk == 0 else next_of_order(shape, flips, mi)
        if not livem[c]:
            continue
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
        vb = valid[kcls, c]
        inner = interior[kcls, c]
        t = mi[heading_axis] if heading_axis >= 0 else 0
        for a in range(na):
            if ((vb >> a) & 1) == 0 or E[c, 1 + a] == np.inf:
                continue
            # Written out, as in sweep_policy (move_corners here is twice as slow).
            if inner:
                nc = 0
                for jj in range(ncorner):
                    wj = cw[kcls, a, t, jj]
                    if wj <= _EPS_W:
                        break
                    idx[jj] = c + coff[kcls, a, t, jj]
                    w[jj] = wj
                    nc += 1
            else:
                table_stencil(kcls, a, mi, offs, fr, heading_axis, shape, periodic, idx, w)
                nc = ncorner
            val = step_cost + E[c, 1 + a]
            der = -1.0 + ED[c, 1 + a]
            if pself > 0.0:
                ssum = 0.0
                vsum = 0.0
                dsum = 0.0
                for j in range(nc):
                    wj = w[j]
                    if wj > _EPS_W:
                        i = idx[j]
                        if livem[i]:
                            hv = hm[i]
                            if hv < np.inf:
                                ssum += wj
                                vsum += wj * hv
                                dsum += wj * Dm[i]
                if ssum <= _EPS_W:
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


@njit(cache=True)
def solve_self(
    m,
    h,
    D,
    g,
    E,
    ED,
    pself,
    accuracy,
    max_sweeps,
    pol,
    warm,
    counts,
    model,
):  # pragma: no cover - numba
    """Modified policy iteration with :func:`sweep_self` (as in :func:`solve_layers`).

    Stops when a full sweep changes less than ``accuracy``; ``counts`` receives
    (full sweeps, evaluation sweeps).
    """
    live = model[0]
    shape = model[16]  # the order of LayeredMDP.kernel_args
    d = shape.shape[0]
    cells, local = live_cells(live[m])
    nlive = cells.shape[0]
    nchg = np.zeros(1, np.int64)
    full = 0
    ev = 0
    flip = 0
    evaluate_first = warm
    while full + ev < max(1, max_sweeps):
        if evaluate_first:
            # Last pass's policy, evaluated exactly, then confirmed by a full sweep.
            evaluate_first = False
            change = np.inf
        else:
            nchg[0] = 0
            change = sweep_self(
                m, flip % (1 << d), h, D, g, E, ED, pself, pol, 1, nchg, accuracy, model
            )
            full += 1
            flip += 1
            if change < accuracy:
                break
        if nchg[0] * 100 <= nlive:
            ptr, succ, wt, const, dconst, fixed = self_system(
                m, h, D, g, E, ED, pself, pol, cells, local, model
            )
            evaluate(h[m], D[m], cells, ptr, succ, wt, const, dconst, fixed)
            ev += 1
    counts[0] = full
    counts[1] = ev
