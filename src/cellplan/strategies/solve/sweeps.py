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
* the same for NR, with its stay self-loop solved exactly, is in :mod:`.nr`.

Every value of an action is the transition law of :mod:`cellplan.strategies.solve.law`.

Cells are visited in alternating axis orders (``flips``) so that values propagate in
every direction. The model arrives as one :class:`~cellplan.strategies.model.bundles.Model`.
"""

from typing import NamedTuple

import numpy as np
from numba import njit

from cellplan.strategies.model.bundles import Model
from cellplan.strategies.model.stencils import (
    EPS_W,
    decode,
    first_of_order,
    next_of_order,
)
from cellplan.strategies.solve.coldstart import dijkstra_layer
from cellplan.strategies.solve.evaluation import evaluate, layer_system, live_cells
from cellplan.strategies.solve.improvement import improvable, improve_layer
from cellplan.strategies.solve.law import (
    FMP,
    OUTSIDE,
    STAY,
    UNRECORDED,
    borrow,
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

# A recorded policy is evaluated exactly once a full sweep changes the minimiser (by more
# than the inner accuracy) in at most this fraction of the live cells.
SETTLED_FRACTION = 0.01
# After an exact evaluation, a residual check that would change the action of at most this
# fraction of the live cells is followed by an evaluation of the changed policy (a policy-
# iteration step, 2x cheaper than a sweep and an evaluation) instead of a sweep. Fitted on
# problems 2, 4, 5 and P1 at 141 x 141, one thread, CPU time (P2 1.76-2.00 s with none,
# 1.68-1.70 at 0.01, 1.65-1.66 at 0.03; benchmarks/fit_solver_rules.py --cpu).
PI_FRACTION = 0.03


class Sweep(NamedTuple):
    """What one Gauss-Seidel sweep does besides updating the values.

    ``flips``: the axes swept in reverse (:func:`~cellplan.strategies.model.stencils.
    first_of_order`). ``exact_stay``: the stay action's self-loop is solved exactly.
    ``track``: ``D = dh/dg`` is updated along the minimising action. ``mode`` 0: ``pol`` is
    not touched; 1: the minimiser is recorded in ``pol``, ``nchg[0]`` counting the cells
    whose minimiser changed by more than ``tie`` in value (ties between equally good
    actions are not counted).
    """

    flips: int
    exact_stay: bool
    track: bool
    pol: np.ndarray
    mode: int
    nchg: np.ndarray
    tie: float


def sweep_spec(
    flips: int, pol: np.ndarray, nchg: np.ndarray, tie: float, exact_stay: bool = False
) -> Sweep:
    """A :class:`Sweep` that tracks ``D`` and records the minimiser (``mode`` 1)."""
    return Sweep(int(flips), bool(exact_stay), True, pol, 1, nchg, float(tie))


@njit(cache=True, inline="never")
def _dense_moves(hm, cwk, cok, site, vb, step_cost, pold, acc):  # pragma: no cover - numba
    """The moves of a dense cell (:func:`dense_cells`) in :func:`sweep_policy`: the law of
    :func:`.law.table_sums` where every corner is live and finite, read without tests.
    ``acc`` is ``(best, barg, oldv)``; returns it updated. A function of its own: written
    into the sweep, it slows the sweep's general path down by half (multi-branch layers)."""
    best, barg, oldv = acc
    ncorner = cwk.shape[2]
    c = site.c
    t = site.t
    a = 0
    while (vb >> a) != 0:
        if (vb >> a) & 1:
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
        a += 1
    return best, barg, oldv


@njit(cache=True, inline="always")
def _self_probability(lay, m):  # pragma: no cover - numba
    """The probability of the branches of mode ``m`` into itself."""
    pself = 0.0
    for b in range(lay.branch_ptr[m], lay.branch_ptr[m + 1]):
        if lay.branch_layer[b] == m:
            pself += lay.branch_prob[b]
    return pself


@njit(cache=True)
def _all_finite(livem, hm):  # pragma: no cover - numba
    """Whether every live value of a layer is finite."""
    for c in range(hm.shape[0]):
        if livem[c] and hm[c] == np.inf:
            return False
    return True


@njit(cache=True, inline="always")
def _fmp_and_stay(model, law, site, g, own, pself):  # pragma: no cover - numba
    """FMP and stay at ``site`` in the average-cost form of a sweep: ``(fmp, fmp_D, stay,
    stay_D)`` (``inf`` where not available), stay solved exactly for the self-loop of
    probability ``pself`` when ``own`` is the layer itself."""
    lay = model.layers
    m = site.m
    c = site.c
    fv = np.inf
    fd = 0.0
    opt = lay.opt_ptr[m]
    if lay.fmp_next[m] >= 0 and lay.tf[opt, c] < np.inf:
        # FMP: the next mode at the same configuration, loss t_f (equation (7)).
        fv, fd = fmp_value(model, law, opt, c, (lay.tf[opt, c] - g, -1.0))
    sv, sd = stay_value(model, law, site, (lay.cost[m] - g, -1.0), own)
    if sv < np.inf and own == m:
        if pself < 1.0 - 1e-12:
            sv /= 1.0 - pself
            sd /= 1.0 - pself
        else:
            sv = np.inf
    return fv, fd, sv, sd


@njit(cache=True)
def sweep_policy(m, h, D, g, sw, model):  # pragma: no cover - numba
    """One Gauss-Seidel sweep of layer ``m`` in place, as :class:`Sweep` ``sw`` says.

    ``h[m, c] = min_u [ l(u) - g + sum_b P_b h[L_b](x'_u) ]`` (the average-cost form of
    equation (9), the law of :mod:`.law`); corners still at ``+inf`` (not yet reached by a
    solve started from ``+inf``) are left out and the weights renormalised. With
    ``exact_stay`` the stay action's self-loop is solved exactly, ``h = (l - g + sum_{b !=
    m} P_b h[L_b](x)) / (1 - P_mm)``. With ``track`` the derivative ``D = dh/dg`` along the
    minimising action is updated as well. Returns the largest change of ``h[m]``.
    """
    model = borrowed(model)
    moves = model.moves
    lay = model.layers
    live = lay.live
    shape = model.grid.shape
    ncell = h.shape[1]
    held = scratch(shape.shape[0])
    s = lend(held)
    mi = s.mi
    pol, nchg, flips, track = borrow(sw.pol), borrow(sw.nchg), sw.flips, sw.track
    hm = h[m]
    livem = live[m]
    kcls = lay.vcls[m]
    na = moves.nact[kcls]
    step_cost = lay.cost[m] - g
    pself = _self_probability(lay, m)
    own = m if sw.exact_stay else -1
    # A C or W layer without mode changes has one branch, into itself with probability 1:
    # its moves and the winner's D read the stencil tables directly (the same sums in the
    # same order; a sweep of a P1 200 x 200 C layer 5.1 -> 2.8 ms).
    single = is_single(lay, m)
    law = reader(h, D, live, True, True, False)  # the moves: values only
    dlaw = reader(h, D, live, True, True, True)  # and with D (the winner, FMP, stay)
    slaw = dlaw if track else law
    # Where every corner a move can land on is live and no value is +inf, the corner
    # tests are skipped (the same sums in the same order; P1 200 x 200 C layer sweep
    # 2.8-3.0 -> 2.65 ms, W layer 3.5-3.9 -> 3.2 ms).
    dense = lay.dense
    fast = single and dense.shape[0] > 0 and _all_finite(livem, hm)
    cwk = moves.cw[kcls]
    cok = moves.coff[kcls]
    maxchange = 0.0
    c = -1
    for kk in range(ncell):
        # Walk the cells in sweep order by odometer steps (no division per cell).
        c = first_of_order(shape, flips, mi) if kk == 0 else next_of_order(shape, flips, mi)
        if not livem[c]:
            continue
        site = site_at(model, m, c, single, mi)
        pold = pol[m, c] if sw.mode == 1 else UNRECORDED
        fv, fd, sv, sd = _fmp_and_stay(model, slaw, site, g, own, pself)
        best = np.inf
        bestd = 0.0
        barg = OUTSIDE
        oldv = np.inf
        if fv < np.inf:
            best = fv
            bestd = fd
            barg = FMP
            if pold == FMP:
                oldv = fv
        if sv < np.inf:
            if pold == STAY:
                oldv = sv
            if sv < best:
                best = sv
                barg = STAY
                bestd = sd
        vb = moves.valid[kcls, c]
        if fast and dense[m, c] == vb:
            best, barg, oldv = _dense_moves(
                hm, cwk, cok, site, vb, step_cost, pold, (best, barg, oldv)
            )
            vb = 0  # the moves are done
        for a in range(na):
            if ((vb >> a) & 1) == 0:
                continue
            val, _ = move_value(model, law, site, a, (step_cost, 0.0), -1, s)
            if a == pold:
                oldv = val
            if val < best:
                best = val
                barg = a
        if track and barg >= 0:
            # The derivative of the winning move only (cheaper than one per action).
            _, bestd = move_value(model, dlaw, site, barg, (step_cost, -1.0), -1, s)
        if sw.mode == 1 and pol[m, c] != barg:
            pol[m, c] = barg
            if not oldv - best <= sw.tie:
                nchg[0] += 1
        old = hm[c]
        if best < np.inf:
            ch = abs(best - old) if old < np.inf else np.inf
            if ch > maxchange:
                maxchange = ch
            hm[c] = best
            if track:
                D[m, c] = bestd
    keep(held)
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
    sw = Sweep(flips, exact_stay, track, np.empty((1, 1), np.int16), 0, np.zeros(1, np.int64), 0.0)
    return sweep_policy(m, h, D, g, sw, model)


@njit(cache=True)
def unreached(hm, cells):  # pragma: no cover - numba
    """How many of the live ``cells`` of one layer's values ``hm`` are still at ``+inf``."""
    n = 0
    for c in cells:
        if hm[c] == np.inf:
            n += 1
    return n


class LayerSolve(NamedTuple):
    """How far :func:`layer_iteration` solves a layer.

    ``accuracy``: a full sweep that changes the values by less ends the solve. ``cap``:
    sweeps and evaluations after which an inexact solve stops (once every live state has
    a finite value); ``limit``: after which any solve stops. ``warm``: start by evaluating
    the policy recorded last pass. ``check``: the residual check after an evaluation.
    ``dijkstra``: a cold start takes the policy of
    :func:`cellplan.strategies.solve.coldstart.dijkstra_layer` first.
    """

    accuracy: float
    cap: int
    limit: int
    warm: bool
    check: bool
    dijkstra: bool


def layer_solve(
    accuracy: float, cap: int, limit: int, warm: bool, check: bool, dijkstra: bool
) -> LayerSolve:
    """A :class:`LayerSolve` with the types the compiled kernel expects."""
    return LayerSolve(
        float(accuracy), int(cap), int(limit), bool(warm), bool(check), bool(dijkstra)
    )


@njit(cache=True, inline="always")
def _evaluate_policy(m, h, D, g, pol, cells, local, model):  # pragma: no cover - numba
    """Exact evaluation of ``pol[m]`` into ``h[m]``, ``D[m]`` (:mod:`.evaluation`)."""
    evaluate(h[m], D[m], cells, layer_system(m, h, D, g, pol, cells, local, model))


@njit(cache=True, nogil=True)
def layer_iteration(m, h, D, g, pol, opts, model):  # pragma: no cover - numba
    """Policy iteration on one C or W layer; returns (full sweeps, exact evaluations).

    Alternates full Gauss-Seidel sweeps (every action, minimiser recorded in ``pol``) with
    an exact evaluation of the recorded policy once a full sweep changes the minimiser in
    at most :data:`SETTLED_FRACTION` of the cells; stops when a *full* sweep changes the
    values by less than ``opts.accuracy``, or after ``opts.cap`` sweeps and evaluations (an
    inexact solve) once every live state has a finite value, or after ``opts.limit``. After
    each exact evaluation of a single-branch layer, a Jacobi residual check
    (:func:`cellplan.strategies.solve.improvement.improve_layer`, vectorised) ends the solve when
    no state can improve by ``accuracy``, without the confirming sweep (with ``opts.check``:
    the solver asks for it on uncapped passes, where layers converge; on capped ones they
    stop at the cap, and a failed check costs half a sweep in 3-D). A solve started
    from ``+inf`` is never stopped by ``cap`` with live states unreached: a later pass
    would start from them, and an infinite value has no place in the outer iteration's
    arithmetic; it goes on until every live state is reached or ``2^d`` sweeps in a row
    reach none.
    With ``opts.warm`` (later passes) it starts by evaluating the policy recorded in the last
    pass; otherwise (values at ``+inf``), with ``opts.dijkstra``, from the policy of
    :func:`cellplan.strategies.solve.coldstart.dijkstra_layer`.
    """
    d = model.grid.shape.shape[0]
    accuracy = opts.accuracy
    cells, local = live_cells(model.layers.live[m])
    nlive = cells.shape[0]
    nchg = np.zeros(1, np.int64)
    full = 0
    ev = 0
    flip = 0
    left = nlive  # live states still at +inf (counted only past the cap)
    stuck = 0  # sweeps past the cap in a row that reached no new state
    check = opts.check and improvable(m, model)
    evaluated = False  # h[m] is the exact value of pol[m]
    # Warm start: the recorded policy is last pass's and nearly right, so evaluate it first
    # and let the residual check (or one full sweep) confirm it.
    evaluate_first = opts.warm
    if not opts.warm and opts.dijkstra:
        evaluate_first = dijkstra_layer(m, h, g, pol, model) > 0
    while full + ev < max(1, opts.limit):
        if full + ev >= max(1, opts.cap):
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
                _evaluate_policy(m, h, D, g, pol, cells, local, model)
                ev += 1
                evaluated = True
            continue
        else:
            nchg[0] = 0
            sw = Sweep(flip % (1 << d), False, True, pol, 1, nchg, accuracy)
            change = sweep_policy(m, h, D, g, sw, model)
            full += 1
            flip += 1
            evaluated = False
            if change < accuracy:
                break
        if nchg[0] <= SETTLED_FRACTION * nlive:
            _evaluate_policy(m, h, D, g, pol, cells, local, model)
            ev += 1
            evaluated = True
    return full, ev
