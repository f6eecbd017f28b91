"""Point queries: equation (9) at a real-valued configuration, and the executor's lookahead.

Section IV-B of the strategies paper: "the optimal action can be obtained from any
real-valued location x through the use of (9), linear interpolation, and the approximate
representation of L*". At ``(q, m)`` the value of an action is

    FMP:   t_f(m, q) + sum_o P_o (c_o + H_{L_o}(q))   (outcomes: Section V, VI-3)
    stay:  l(m) + sum_b P_b H_{L_b}(q)
    move:  l(m) + sum_b P_b H_{L_b}(q + dq_a)     (only if the swept motion is free)

with ``H`` the interpolation of :mod:`cellplan.strategies.model.interpolation` over the layer's
live corners. :func:`query` picks the minimiser (the online step, a few us);
:func:`lookahead` searches motion sequences for the :class:`~cellplan.strategies.policy.execution.
Executor`. The values ``h`` and their ``live`` mask are arguments (the executor passes
its corrected copy, the baselines their own layers); the rest of the model comes in one
:class:`~cellplan.strategies.model.bundles.Model`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numba
import numpy as np
from numba import njit

from cellplan.strategies.model.bundles import Probe
from cellplan.strategies.model.interpolation import interp
from cellplan.strategies.model.motion import motion_ok
from cellplan.strategies.model.stencils import (
    FMP_CODE,
    MAX_DIM,
    NO_ACTION_CODE,
    NOT_FINITE_CODE,
    STAY_CODE,
    cell_containing,
    displacement,
    stencil,
    wrap,
)
from cellplan.strategies.solve.noisy import noisy_value_at


@njit(cache=True)
def outcomes_at(opt, h, live, lay, idx, w, n):  # pragma: no cover - numba
    """``sum_o P_o (c_o + H_{L_o})`` over the outcomes of FMP option ``opt`` at the stencil
    ``idx, w`` (NaN when an outcome has no live corner)."""
    val = 0.0
    for o in range(lay.out_ptr[opt], lay.out_ptr[opt + 1]):
        p = lay.out_prob[o]
        if p <= 0.0:
            continue
        L = lay.out_layer[o]
        val += p * (lay.out_cost[o] + interp(h[L], live[L], idx, w, n))
    return val


@njit(cache=True)
def probe(d):  # pragma: no cover - numba
    """A :class:`~.bundles.Probe` (scratch of a point query) for a ``d``-dimensional grid."""
    return Probe(
        np.empty(1 << d, np.int64),
        np.empty(1 << d),
        np.empty(2 * MAX_DIM, np.int64),
        np.empty(MAX_DIM),
        np.empty(3 * MAX_DIM, np.int64),
    )


@njit(cache=True)
def fmp_outcomes(q, m, h, live, model, pr):  # pragma: no cover - numba
    """:func:`outcomes_at` of mode ``m``'s (first) FMP option at ``q`` (the caller adds
    ``t_f`` and checks that the cell allows FMP); ``pr`` is the
    :class:`~.bundles.Probe` scratch."""
    n = stencil(q, model.grid, pr.idx, pr.w, pr.ibuf, pr.frac)
    lay = model.layers
    return outcomes_at(lay.opt_ptr[m], h, live, lay, pr.idx, pr.w, n)


@njit(cache=True)
def branches_at(start, m, h, live, lay, idx, w, n):  # pragma: no cover - numba
    """``start + sum_b P_b H_{L_b}`` over mode ``m``'s branches at the stencil ``idx, w``
    (``n`` corners); NaN where a branch has no live corner."""
    val = start
    for b in range(lay.branch_ptr[m], lay.branch_ptr[m + 1]):
        L = lay.branch_layer[b]
        v = interp(h[L], live[L], idx, w, n)
        if np.isnan(v):
            return np.nan
        val += lay.branch_prob[b] * v
    return val


@njit(cache=True)
def moved_to(q, dq, k, a, model, pr, qn):  # pragma: no cover - numba
    """``qn = q + dq`` (wrapped) for move ``a`` of class ``k``, its displacement written to
    ``dq``; False (``qn`` untouched) where the swept motion is not free."""
    moves = model.moves
    grid = model.grid
    displacement(q, moves.disp[k, a], moves.heading_axis, dq)
    if not motion_ok(q, dq, moves.free[k], grid, pr.mbuf):
        return False
    for j in range(q.shape[0]):
        qn[j] = q[j] + dq[j]
    wrap(qn, grid.lower, grid.upper, grid.periodic)
    return True


@njit(cache=True)
def action_values_at(q, m, h, live, tf_here, fmp_allowed, model, out):  # pragma: no cover
    """Right-hand side of equation (9) at a real configuration ``q`` in mode ``m``.

    ``out[0]`` is FMP (loss ``tf_here``, offered only if ``fmp_allowed``), ``out[1]`` stay,
    ``out[2 + a]`` move ``a``; NaN marks an action that is not available (collision along
    the swept motion, outside the MDP, FMP outside the region).
    """
    moves = model.moves
    lay = model.layers
    d = model.grid.shape.shape[0]
    qn = np.empty(d)
    dq = np.empty(d)
    pr = probe(d)
    k = lay.vcls[m]
    na = moves.nact[k]
    for i in range(out.shape[0]):
        out[i] = np.nan
    nxt = lay.fmp_next[m]
    if nxt >= 0 and fmp_allowed:
        n = stencil(q, model.grid, pr.idx, pr.w, pr.ibuf, pr.frac)
        v = outcomes_at(lay.opt_ptr[m], h, live, lay, pr.idx, pr.w, n)
        if not np.isnan(v):
            out[0] = tf_here + v
    noisy = moves.noise_prob.shape[0] > 1
    for a in range(-1, na):
        if a >= 0 and noisy:  # Section VI-4: the expectation over the landings
            v = noisy_value_at(q, m, a, h, live, model, pr)
            if not np.isnan(v):
                out[2 + a] = lay.cost[m] + v
            continue
        if a >= 0:
            if not moved_to(q, dq, k, a, model, pr, qn):
                continue
        else:
            for j in range(d):
                qn[j] = q[j]
        n = stencil(qn, model.grid, pr.idx, pr.w, pr.ibuf, pr.frac)
        out[2 + a] = branches_at(lay.cost[m], m, h, live, lay, pr.idx, pr.w, n)
    # While a request waits, stay is dominated in the MDP (it costs a stage and changes
    # nothing), but at an off-grid state the interpolated cost-to-go can make it look best
    # and the robot would wait for ever; offer it only when no motion is possible.
    if nxt >= 0:
        for i in range(2, out.shape[0]):
            if not np.isnan(out[i]):
                out[1] = np.nan
                break


@njit(cache=True)
def query(q, m, h, live, forbid_fmp, model, out):  # pragma: no cover - numba
    """The optimal action at a real state in one call (the online step of Section IV-B).

    FMP is offered where the grid cell containing ``q`` allows it (unless ``forbid_fmp``).
    Returns -2 (FMP), -1 (stay), a move index, -9 when no action is available (the cell of
    ``q`` is not live in layer ``m``, or no action has a value), or -10 when
    ``q`` is not finite (nothing is read then); ``out`` receives the right-hand side of (9)
    per action as in :func:`action_values_at`. ``q`` must have the grid's dimension and
    ``m`` be a layer index: the caller checks both.
    """
    for j in range(q.shape[0]):
        if not np.isfinite(q[j]):
            return NOT_FINITE_CODE
    grid = model.grid
    c = cell_containing(q, grid.shape, grid.lower, grid.spacing, grid.periodic)
    if not live[m, c]:
        # Outside the strategy's domain (issue 35: one rule, Strategy.in_domain, for the
        # strategy and the simulator's start), even where live corners nearby give values.
        for i in range(out.shape[0]):
            out[i] = np.nan
        return NO_ACTION_CODE
    tf_here = model.layers.tf[model.layers.opt_ptr[m], c]
    allowed = (not forbid_fmp) and tf_here < np.inf
    action_values_at(q, m, h, live, tf_here if allowed else 0.0, allowed, model, out)
    best = np.inf
    arg = -1
    for i in range(out.shape[0]):
        v = out[i]
        if not np.isnan(v) and v < best:
            best = v
            arg = i
    if arg < 0:
        return NO_ACTION_CODE
    return FMP_CODE if arg == 0 else STAY_CODE if arg == 1 else arg - 2


@njit(cache=True)
def queries(qs, m, h, live, forbid_fmp, model, codes, steps):  # pragma: no cover - numba
    """:func:`query` at each row of ``qs`` (``(n, d)``, finite: the caller checks), all in
    layer ``m``: ``codes[i]`` the action code, ``steps[i]`` a move's C-space displacement
    from ``qs[i]`` (zero for any other code)."""
    out = np.empty(2 + model.moves.disp.shape[1])
    moves = model.moves
    k = model.layers.vcls[m]
    for i in range(qs.shape[0]):
        u = query(qs[i], m, h, live, forbid_fmp, model, out)
        codes[i] = u
        if u >= 0:
            displacement(qs[i], moves.disp[k, u], moves.heading_axis, steps[i])
        else:
            steps[i, :] = 0.0


@njit(cache=True)
def after_motion(q, m, h, live, model, pr):  # pragma: no cover - numba
    """Expected interpolated cost-to-go ``sum_b P_b H_{L_b}(q)`` after a motion (NaN: none);
    leaves ``q``'s stencil in the :class:`~.bundles.Probe` ``pr``."""
    n = stencil(q, model.grid, pr.idx, pr.w, pr.ibuf, pr.frac)
    return branches_at(0.0, m, h, live, model.layers, pr.idx, pr.w, n)


@njit(cache=True)
def undoes(disp_k, a, prev):  # pragma: no cover - numba
    """Whether move ``a`` is the inverse of move ``prev`` (``disp_k``: the class's
    displacements): the pair returns to the same configuration."""
    for j in range(disp_k.shape[1]):
        if abs(disp_k[a, j] + disp_k[prev, j]) > 1e-12:
            return False
    return True


@njit(cache=True)
def lookahead(q, m, h, live, model, search):  # pragma: no cover - numba
    """The best motion sequence of up to ``search.depth`` stages from ``q`` (a lookahead on
    (9)); ``search`` is the :class:`~.bundles.Search` bundle.

    The value of a sequence is its stage losses less ``search.offset`` per stage (the gain,
    as in the average-cost form of (9)) plus the interpolated cost-to-go where it ends:
    after ``depth`` motions, or by FMP at a configuration whose cell allows it (at ``q``
    itself only if ``search.fmp_root``). Every motion must pass the swept check and end in
    a cell that is a live state of layer ``m`` (inside the strategy's domain). A motion
    followed by its inverse is skipped (it returns to the same configuration). Returns
    ``(value, length, count)``: the best sequence is ``search.seq[:length]`` (move
    indices, -2 for FMP, which ends it; length 0 when no sequence qualifies) and ``count``
    the configurations after the root whose cell allows FMP.

    The exact region test is not available in compiled code, so FMP away from the root
    takes two calls: with ``search.collect`` the count configurations are written to
    ``search.nodes`` (and FMP is not offered there); without it ``search.fmp_ok[i]`` says
    whether FMP is possible at the i-th of them, in the same order.
    """
    grid = model.grid
    lay = model.layers
    depth = search.depth
    offset = search.offset
    seq = search.seq
    d = grid.shape.shape[0]
    k = lay.vcls[m]
    na = model.moves.nact[k]
    step = lay.cost[m] - offset
    qd = np.empty((depth + 1, d))
    dq = np.empty(d)
    acc = np.zeros(depth + 1)
    choice = np.full(depth + 1, -1, np.int64)
    pr = probe(d)
    best = np.inf
    count = 0
    length = 0
    for j in range(d):
        qd[0, j] = q[j]
    can_fmp = lay.fmp_next[m] >= 0
    if can_fmp and search.fmp_root:
        c = cell_containing(q, grid.shape, grid.lower, grid.spacing, grid.periodic)
        tf = lay.tf[lay.opt_ptr[m], c]
        v = tf - offset + fmp_outcomes(q, m, h, live, model, pr) if tf < np.inf else np.nan
        if not np.isnan(v):
            best = v
            seq[0] = FMP_CODE
            length = 1
    level = 0
    while level >= 0:
        choice[level] += 1
        a = choice[level]
        if a >= na:
            choice[level] = -1
            level -= 1
            continue
        if level > 0 and undoes(model.moves.disp[k], a, choice[level - 1]):
            continue
        if not moved_to(qd[level], dq, k, a, model, pr, qd[level + 1]):
            continue
        c = cell_containing(qd[level + 1], grid.shape, grid.lower, grid.spacing, grid.periodic)
        if not live[m, c]:
            continue
        acc[level + 1] = acc[level] + step
        fmp_here = False
        if can_fmp and lay.tf[lay.opt_ptr[m], c] < np.inf:
            if search.collect:
                if count < search.nodes.shape[0]:
                    for j in range(d):
                        search.nodes[count, j] = qd[level + 1, j]
            else:
                fmp_here = count < search.fmp_ok.shape[0] and search.fmp_ok[count]
            count += 1
        if fmp_here:
            tf = lay.tf[lay.opt_ptr[m], c]
            v = acc[level + 1] + tf - offset + fmp_outcomes(qd[level + 1], m, h, live, model, pr)
            if not np.isnan(v) and v < best:
                best = v
                for i in range(level + 1):
                    seq[i] = choice[i]
                seq[level + 1] = FMP_CODE
                length = level + 2
        if level + 1 == depth:
            v = acc[level + 1] + after_motion(qd[level + 1], m, h, live, model, pr)
            if not np.isnan(v) and v < best:
                best = v
                for i in range(level + 1):
                    seq[i] = choice[i]
                length = level + 1
        else:
            level += 1
    return best, length, count


@njit(cache=True)
def fmp_options_at(q, m, h, live, allowed, model):  # pragma: no cover - numba
    """The best FMP option of mode ``m`` at a real configuration ``q`` and its value.

    Option ``j`` is offered where ``allowed[j]`` (its fine motion is possible at ``q``); its
    value is ``t_f(j, q's cell) + sum_o P_o (c_o + H_{L_o}(q))``. Returns ``(j, value)``,
    ``(-1, inf)`` when no option is offered or none has live outcomes. With simultaneous
    requests (Section VI-2) this is the choice of which open request a pick serves.
    """
    grid = model.grid
    lay = model.layers
    d = grid.shape.shape[0]
    idx = np.empty(1 << d, np.int64)
    w = np.empty(1 << d)
    c = cell_containing(q, grid.shape, grid.lower, grid.spacing, grid.periodic)
    n = stencil(q, grid, idx, w, np.empty(2 * MAX_DIM, np.int64), np.empty(MAX_DIM))
    best = np.inf
    arg = -1
    o0 = lay.opt_ptr[m]
    for j in range(lay.opt_ptr[m + 1] - o0):
        if not allowed[j] or not lay.tf[o0 + j, c] < np.inf:
            continue
        v = outcomes_at(o0 + j, h, live, lay, idx, w, n)
        if not np.isnan(v) and lay.tf[o0 + j, c] + v < best:
            best = lay.tf[o0 + j, c] + v
            arg = j
    return arg, best


def compiled_for(kernel: Any, args: Sequence[Any]) -> Callable[..., Any]:
    """``kernel``'s compiled code for the numba types of ``args``, callable without numba's
    dispatcher.

    A call through the dispatcher first works out the type of every argument to choose
    the compiled version; for the model bundle, named tuples of about thirty arrays, that
    took 8 of a 12 us query on problem 1 (docs/benchmarks.md). The returned function skips
    that step, so it must only be called with arguments of exactly these types: the same
    arrays, or arrays of the same dtype, dimension and layout, and scalars of the same
    kind (``int``, ``bool``). Compiles the kernel, or loads it from numba's cache, on the
    way.
    """
    fn: Callable[..., Any] = kernel.compile(tuple(numba.typeof(a) for a in args))
    return fn
