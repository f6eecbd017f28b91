"""Exact evaluation of a fixed policy on one layer, in dependency order (numba).

The structured solver (:mod:`cellplan.strategies.solve.solver`) runs a modified policy
iteration on each layer: full Bellman sweeps choose the actions, and between them the
values of the chosen actions are brought up to date. For a fixed policy the values of a
layer solve a sparse linear system

    h = c + W h,        D = c_D + W D,

where row ``x`` of ``W`` holds the interpolation weights (Section IV-B of the strategies
paper) of the landing point of the action chosen at ``x`` (times the probability of
staying in the layer), ``c`` the stage loss minus ``g`` plus everything read from other,
fixed layers (the FMP's next mode, request branches), and ``D = dh/dg`` the quantity the
solver's Newton step on ``g`` needs.

Repeated Gauss-Seidel sweeps solve this slowly when the policy's paths run against the
sweep directions (the arms of problems 5 and 6 needed 30-70 sweeps per layer and outer
pass). Here the system is solved in one pass: the dependency graph of the policy (``x``
depends on the corners it lands between) is split into strongly connected components by
Tarjan's algorithm, which emits them successors first, and each component is solved once
its successors are final - a single cell directly (a self-loop divided out), a cycle of
cells (interpolation can point back) by Gauss-Seidel on that component alone.
"""

from typing import NamedTuple

import numpy as np
from numba import njit

from cellplan.strategies.model.stencils import EPS_W, decode
from cellplan.strategies.solve.law import (
    FMP,
    STAY,
    borrow,
    borrowed,
    fmp_value,
    is_single,
    keep,
    lend,
    live_sums,
    move_stencil,
    reader,
    scratch,
    site_at,
)

# A component's Gauss-Seidel stops when its values change by less than this (relative).
COMPONENT_TOL = 1e-13
# A component that has not converged after this many sweeps is left as it is (a policy
# that never leaves it has unbounded cost; the next full sweep replaces that policy).
COMPONENT_SWEEPS = 10000


@njit(cache=True)
def live_cells(livem):  # pragma: no cover - numba
    """``(cells, local)``: the live cells of a layer and each cell's position among them."""
    cells = np.flatnonzero(livem)
    local = np.full(livem.shape[0], -1, np.int64)
    for v in range(cells.shape[0]):
        local[cells[v]] = v
    return cells, local


class Rows(NamedTuple):
    """A linear system ``h = const + W h`` (and ``D = dconst + W D``) being written.

    Row ``v`` of ``W`` is ``succ[ptr[v]:ptr[v + 1]]`` (local indices) with weights ``wt``;
    ``fixed`` rows keep their value (no usable action).
    """

    ptr: np.ndarray
    succ: np.ndarray
    wt: np.ndarray
    const: np.ndarray
    dconst: np.ndarray
    fixed: np.ndarray


@njit(cache=True, inline="always")
def _rows(n, cap):  # pragma: no cover - numba
    """Empty :class:`Rows` for ``n`` unknowns and at most ``cap`` weights."""
    return Rows(
        np.zeros(n + 1, np.int64), np.empty(cap, np.int64), np.empty(cap), np.zeros(n),
        np.zeros(n), np.zeros(n, np.bool_),
    )  # fmt: skip


@njit(cache=True, inline="always")
def _lend(rows):  # pragma: no cover - numba
    """:class:`Rows` borrowed (:func:`.law.borrow`): the owner ``rows`` stays alive, it is
    what the kernel returns."""
    return Rows(
        borrow(rows.ptr), borrow(rows.succ), borrow(rows.wt), borrow(rows.const),
        borrow(rows.dconst), borrow(rows.fixed),
    )  # fmt: skip


@njit(cache=True, inline="always")
def _landing_row(rows, ne, law, site, row, local, s, model):  # pragma: no cover
    """Row entries of a move's landing (table row ``row``) from ``site``, from ``ne`` on:
    in every branch, the live (finite) corners with their renormalised weights (the law
    of :func:`.law.move_value`) times the branch probability; the branch into the layer
    itself becomes weights of ``W``, the others are added to the row's constants (which
    hold the stage loss). Returns the new ``ne``, -1 where a branch has no live corner."""
    lay = model.layers
    m = site.m
    v = local[site.c]
    cv = rows.const[v]
    dv = rows.dconst[v]
    nc = move_stencil(model, site, row, s)
    for b in range(lay.branch_ptr[m], lay.branch_ptr[m + 1]):
        L = lay.branch_layer[b]
        p = lay.branch_prob[b]
        if p == 0.0:
            continue
        ssum, _, _ = live_sums(law, L, nc, s)
        if ssum <= EPS_W:
            return -1
        for j in range(nc):
            i = s.idx[j]
            if s.w[j] > EPS_W and law.live[L, i] and law.h[L, i] < np.inf:
                q = p * s.w[j] / ssum
                if L == m:
                    rows.succ[ne] = local[i]
                    rows.wt[ne] = q
                    ne += 1
                else:
                    cv += q * law.h[L, i]
                    dv += q * law.D[L, i]
    rows.const[v] = cv
    rows.dconst[v] = dv
    return ne


@njit(cache=True)
def layer_system(m, h, D, g, pol, cells, local, model):  # pragma: no cover - numba
    """The linear system of the policy ``pol[m]`` on layer ``m`` (other layers fixed).

    The same update as :func:`cellplan.strategies.solve.sweeps.sweep_policy` restricted to the
    recorded action (the law of :mod:`.law`), written as :class:`Rows` over the local
    indices of ``cells`` (cells without a usable action are ``fixed``: they keep their
    value).
    """
    model = borrowed(model)
    lay = model.layers
    shape = model.grid.shape
    d = shape.shape[0]
    n = cells.shape[0]
    ncorner = 1 << d
    b0 = lay.branch_ptr[m]
    b1 = lay.branch_ptr[m + 1]
    nself = 0
    for b in range(b0, b1):
        if lay.branch_layer[b] == m and lay.branch_prob[b] > 0.0:
            nself += 1
    owner = _rows(n, n * max(1, nself * ncorner))
    rows = _lend(owner)
    held = scratch(d)
    s = lend(held)
    law = reader(h, D, lay.live, True, True, True)
    single = is_single(lay, m)
    step_cost = lay.cost[m] - g
    ne = 0
    for v in range(n):
        c = cells[v]
        pa = pol[m, c]
        start = ne
        ok = True
        if pa == FMP:
            opt = lay.opt_ptr[m]
            cv = np.inf
            dv = 0.0
            if lay.fmp_next[m] >= 0 and lay.tf[opt, c] < np.inf:
                cv, dv = fmp_value(model, law, opt, c, (lay.tf[opt, c] - g, -1.0))
            ok = cv < np.inf
            rows.const[v] = cv
            rows.dconst[v] = dv
        elif pa == STAY:
            cv = step_cost
            dv = -1.0
            for b in range(b0, b1):
                L = lay.branch_layer[b]
                p = lay.branch_prob[b]
                if p == 0.0:
                    continue
                if not lay.live[L, c] or h[L, c] == np.inf:
                    ok = False
                    break
                if L == m:
                    rows.succ[ne] = v
                    rows.wt[ne] = p
                    ne += 1
                else:
                    cv += p * h[L, c]
                    dv += p * D[L, c]
            rows.const[v] = cv
            rows.dconst[v] = dv
        elif pa >= 0:
            # The multi-index is read only at the border or for a robot-frame heading.
            if not model.moves.interior[lay.vcls[m], c] or model.moves.heading_axis >= 0:
                decode(c, shape, s.mi)
            site = site_at(model, m, c, single, s.mi)
            rows.const[v] = step_cost
            rows.dconst[v] = -1.0
            ne = _landing_row(rows, ne, law, site, pa, local, s, model)
            ok = ne >= 0
        else:
            ok = False
        if not ok:
            ne = start
            rows.fixed[v] = True
        rows.ptr[v + 1] = ne
    keep(held)
    return Rows(owner.ptr, owner.succ[:ne], owner.wt[:ne], owner.const, owner.dconst, owner.fixed)


@njit(cache=True)
def self_system(m, h, g, nr, pol, cells, local, model):  # pragma: no cover - numba
    """The linear system of ``pol[m]`` for the NR update of :func:`.nr.sweep_self`
    (``nr``: :class:`.nr.NRBranches`), as :class:`Rows`.

    Stay is solved exactly, ``h = (l - g + E[c, 0]) / (1 - pself)`` (a constant here); a
    move costs ``l - g + E[c, 1 + a] + pself * h[m](x')`` (the law of :mod:`.law`; the
    derivatives ``D`` enter through ``nr.ED`` only).
    """
    model = borrowed(model)
    lay = model.layers
    shape = model.grid.shape
    d = shape.shape[0]
    n = cells.shape[0]
    owner = _rows(n, n * (1 << d))
    rows = _lend(owner)
    held = scratch(d)
    s = lend(held)
    law = reader(h, h, lay.live, True, True, False)
    E = nr.E
    ED = nr.ED
    pself = nr.pself
    step_cost = lay.cost[m] - g
    ne = 0
    for v in range(n):
        c = cells[v]
        pa = pol[m, c]
        start = ne
        ok = True
        if pa == STAY:
            if E[c, 0] < np.inf and pself < 1.0 - 1e-12:
                rows.const[v] = (step_cost + E[c, 0]) / (1.0 - pself)
                rows.dconst[v] = (-1.0 + ED[c, 0]) / (1.0 - pself)
            else:
                ok = False
        elif pa >= 0 and E[c, 1 + pa] < np.inf:
            rows.const[v] = step_cost + E[c, 1 + pa]
            rows.dconst[v] = -1.0 + ED[c, 1 + pa]
            if pself > 0.0:
                # The multi-index is read only at the border or for a robot-frame heading.
                if not model.moves.interior[lay.vcls[m], c] or model.moves.heading_axis >= 0:
                    decode(c, shape, s.mi)
                site = site_at(model, m, c, False, s.mi)
                nc = move_stencil(model, site, pa, s)
                ssum, _, _ = live_sums(law, m, nc, s)
                if ssum <= EPS_W:
                    ok = False
                else:
                    # Not the transition law (the stencil and its live sum are law.py's):
                    # the policy's matrix row, one successor and weight per live corner,
                    # written and closed (fixed, ptr) as layer_system writes its rows.
                    for j in range(nc):
                        i = s.idx[j]
                        if s.w[j] > EPS_W and lay.live[m, i] and h[m, i] < np.inf:
                            rows.succ[ne] = local[i]
                            rows.wt[ne] = pself * s.w[j] / ssum
                            ne += 1
        else:
            ok = False
        if not ok:
            ne = start
            rows.fixed[v] = True
        rows.ptr[v + 1] = ne
    keep(held)
    return Rows(owner.ptr, owner.succ[:ne], owner.wt[:ne], owner.const, owner.dconst, owner.fixed)


@njit(cache=True)
def components(ptr, succ):  # pragma: no cover - numba
    """Strongly connected components, successors first (Tarjan, iterative).

    Returns ``(members, comp_ptr)``: component ``k`` is
    ``members[comp_ptr[k]:comp_ptr[k + 1]]``; every edge leaving a component points into
    an earlier one.
    """
    n = ptr.shape[0] - 1
    index = np.full(n, -1, np.int64)
    low = np.zeros(n, np.int64)
    onstack = np.zeros(n, np.bool_)
    stack = np.empty(n, np.int64)
    call_node = np.empty(n, np.int64)
    call_edge = np.empty(n, np.int64)
    members = np.empty(n, np.int64)
    comp_ptr = np.zeros(n + 1, np.int64)
    counter = 0
    sp = 0
    nout = 0
    ncomp = 0
    for s in range(n):
        if index[s] >= 0:
            continue
        index[s] = counter
        low[s] = counter
        counter += 1
        stack[sp] = s
        sp += 1
        onstack[s] = True
        call_node[0] = s
        call_edge[0] = ptr[s]
        csp = 1
        while csp > 0:
            v = call_node[csp - 1]
            e = call_edge[csp - 1]
            if e < ptr[v + 1]:
                call_edge[csp - 1] = e + 1
                u = succ[e]
                if index[u] < 0:
                    index[u] = counter
                    low[u] = counter
                    counter += 1
                    stack[sp] = u
                    sp += 1
                    onstack[u] = True
                    call_node[csp] = u
                    call_edge[csp] = ptr[u]
                    csp += 1
                elif onstack[u] and index[u] < low[v]:
                    low[v] = index[u]
            else:
                if low[v] == index[v]:
                    while True:
                        sp -= 1
                        u = stack[sp]
                        onstack[u] = False
                        members[nout] = u
                        nout += 1
                        if u == v:
                            break
                    ncomp += 1
                    comp_ptr[ncomp] = nout
                csp -= 1
                if csp > 0:
                    parent = call_node[csp - 1]
                    if low[v] < low[parent]:
                        low[parent] = low[v]
    return members, comp_ptr[: ncomp + 1]


@njit(cache=True, inline="always")
def _row(v, ptr, succ, wt, const, dconst, hl, Dl):  # pragma: no cover - numba
    """``(h, D)`` of row ``v`` with its self-loop divided out (``nan`` if it is total)."""
    val = const[v]
    der = dconst[v]
    selfw = 0.0
    for e in range(ptr[v], ptr[v + 1]):
        u = succ[e]
        if u == v:
            selfw += wt[e]
        else:
            val += wt[e] * hl[u]
            der += wt[e] * Dl[u]
    if selfw >= 1.0 - 1e-12:
        return np.nan, np.nan
    return val / (1.0 - selfw), der / (1.0 - selfw)


@njit(cache=True)
def solve_system(ptr, succ, wt, const, dconst, fixed, hl, Dl):  # pragma: no cover - numba
    """Solve ``h = const + W h`` and ``D = dconst + W D`` in place, component by component.

    ``fixed`` rows keep their values.
    """
    members, comp_ptr = components(ptr, succ)
    for k in range(comp_ptr.shape[0] - 1):
        a = comp_ptr[k]
        b = comp_ptr[k + 1]
        if b - a == 1:
            # A single cell (nearly all of them): its successors are final, one solve.
            v = members[a]
            if not fixed[v]:
                val, der = _row(v, ptr, succ, wt, const, dconst, hl, Dl)
                if val == val:  # else a total self-loop: no finite value under this policy
                    hl[v] = val
                    Dl[v] = der
            continue
        # Gauss-Seidel round a cycle needs finite starting values.
        for j in range(a, b):
            v = members[j]
            if not fixed[v] and not hl[v] < np.inf:
                hl[v] = 0.0
        for _ in range(COMPONENT_SWEEPS):
            worst = 0.0
            for j in range(a, b):
                v = members[j]
                if fixed[v]:
                    continue
                val, der = _row(v, ptr, succ, wt, const, dconst, hl, Dl)
                if val != val:
                    continue
                rel = abs(val - hl[v]) / (1.0 + abs(val))
                if rel > worst:
                    worst = rel
                hl[v] = val
                Dl[v] = der
            if worst < COMPONENT_TOL:
                break


@njit(cache=True)
def evaluate(hm, Dm, cells, system):  # pragma: no cover - numba
    """Solve the system (:class:`Rows`) of :func:`layer_system` / :func:`self_system` into a
    layer's ``hm`` and ``Dm`` (indexed by cell)."""
    ptr, succ, wt, const, dconst, fixed = system
    n = cells.shape[0]
    hl = np.empty(n)
    Dl = np.empty(n)
    for v in range(n):
        hl[v] = hm[cells[v]]
        Dl[v] = Dm[cells[v]]
    solve_system(ptr, succ, wt, const, dconst, fixed, hl, Dl)
    for v in range(n):
        hm[cells[v]] = hl[v]
        Dm[cells[v]] = Dl[v]
