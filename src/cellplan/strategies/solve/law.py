"""The transition law of the discretised MDP, written once: the value of an action at a cell.

Every kernel of the solver (Gauss-Seidel sweeps, the Jacobi Bellman operator, the exact
evaluation, the improvement step, the cold start, policy iteration, the live states)
evaluates the right-hand side of equation (9) of the strategies paper at a cell centre
``x`` of mode ``m``:

    FMP option o:  t_f(o, x) + sum_k P_k (c_k + h(L_k, x))             (outcomes k of o)
    stay:          l(m) + sum_b P_b h(L_b, x)                          (branches b of m)
    move a:        l(m) + sum_b P_b sum_j p_j H_{L_b}(x + dx_{a,j})   (landings j of a)

with the branches ``(L_b, P_b)`` of Section III-B, the FMP outcomes of Section V (one,
``next(m)`` with probability one) or VI-3 (failure modes), the landings of a noisy move
of Section VI-4 (one, ``p = 1``, without noise) and ``H_L`` the interpolation of
Section IV-B over the corners of the landing point that are states of layer ``L``
(:mod:`cellplan.strategies.model.interpolation`). The functions here are that law; the
kernels call them and differ only in what they do with the value (keep the minimum,
record the action, write a row of a linear system). They are compiled with
``inline="always"``: numba inlines them into each kernel, where the flags of the
:class:`Law` bundle are constants, so the specialised loops cost what the loops written
out in each kernel cost before.

A kernel describes how it reads the values in a :class:`Law`, the cell it is at in a
:class:`Site` and hands its scratch space over as a :class:`Scratch`.

numba inlines a function compiled with ``inline="always"`` at the level of its own IR:
every array the inlined call takes becomes a new reference, counted up and down with two
atomic operations per array and call. Passed the model bundle (28 arrays) per move, that
made a sweep six times slower (P1 200 x 200 C layer, 6.6 -> 39 ms). The hot kernels
therefore hand the law *borrowed* arrays (:func:`borrow`, :func:`borrowed`,
:func:`lend`): the same data without a reference count, for which counting is a test of
a null pointer. The owners are the kernel's arguments (the caller holds them for the
whole call) or scratch kept alive by :func:`keep` at the kernel's end.

The action codes of a policy are named here (:data:`STAY`, :data:`FMP`,
:data:`OUTSIDE`, :data:`UNRECORDED`; FMP option ``j`` is
:func:`~cellplan.strategies.model.stencils.fmp_code`).
"""

from typing import NamedTuple

import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from cellplan.strategies.model.bundles import Grid, Layers, Model, Moves
from cellplan.strategies.model.interpolation import supported
from cellplan.strategies.model.stencils import (
    EPS_W,
    FMP_CODE,
    OUTSIDE_CODE,
    STAY_CODE,
    table_stencil,
)

# Action codes (a move is its index ``a >= 0``).
STAY = STAY_CODE
FMP = FMP_CODE
OUTSIDE = OUTSIDE_CODE  # a state outside the MDP, or no action found
UNRECORDED = -9  # a sweep that records no policy compares with no old action


@intrinsic
def borrow(typingctx, arr):  # pragma: no cover - numba
    """``arr`` without its reference count (a null meminfo): passing it to an inlined
    function counts nothing. Valid while the owner of ``arr``'s data lives."""
    if not isinstance(arr, types.Array):
        return None

    def codegen(context, builder, signature, args):
        ary = context.make_array(arr)(context, builder, value=args[0])
        out = context.make_array(arr)(context, builder)
        for field in ("nitems", "itemsize", "data", "shape", "strides"):
            setattr(out, field, getattr(ary, field))
        out.meminfo = cgutils.get_null_value(out.meminfo.type)
        out.parent = cgutils.get_null_value(out.parent.type)
        return out._getvalue()

    return arr(arr), codegen


@njit(cache=True)
def borrowed(model):  # pragma: no cover - numba
    """The model bundle with every array borrowed (:func:`borrow`)."""
    g = model.grid
    mv = model.moves
    ly = model.layers
    grid = Grid(borrow(g.shape), borrow(g.lower), borrow(g.upper), borrow(g.spacing),
                borrow(g.periodic))  # fmt: skip
    moves = Moves(
        borrow(mv.free), borrow(mv.disp), borrow(mv.nact), mv.heading_axis, borrow(mv.valid),
        borrow(mv.offs), borrow(mv.fr), borrow(mv.coff), borrow(mv.cw), borrow(mv.interior),
        borrow(mv.noise_prob),
    )  # fmt: skip
    layers = Layers(
        borrow(ly.live), borrow(ly.vcls), borrow(ly.cost), borrow(ly.fmp_next),
        borrow(ly.opt_ptr), borrow(ly.tf), borrow(ly.branch_ptr), borrow(ly.branch_layer),
        borrow(ly.branch_prob), borrow(ly.out_ptr), borrow(ly.out_layer), borrow(ly.out_prob),
        borrow(ly.out_cost), borrow(ly.dense),
    )  # fmt: skip
    return Model(grid, moves, layers)


class Law(NamedTuple):
    """How a kernel reads the values the law is evaluated against.

    ``finite``: corners (and states) still at ``+inf`` are left out, as by a solve started
    from ``+inf`` (the weights are renormalised over the others); else they are read.
    ``skip_zero``: branches of probability zero are left out; else they must be supported
    like the others. ``track``: the derivative ``D = dh/dg`` is carried along with the
    same weights (the structured solver's Newton step).
    """

    h: np.ndarray  # (M, N) values
    D: np.ndarray  # (M, N) their derivative in g (read only with ``track``)
    live: np.ndarray  # (M, N) bool, the states of each layer
    finite: bool
    skip_zero: bool
    track: bool


class Site(NamedTuple):
    """The cell ``c`` of mode ``m`` an action is taken at.

    ``k`` is the mode's move class, ``inner`` whether every move stencil from ``c`` stays
    inside the grid (``Moves.interior``), ``t`` the heading slice of the stencil tables
    (0 but for robot-frame moves), ``single`` whether the mode has one branch, into
    itself with probability one (a C or W layer without mode changes: its moves then
    read the tables directly).
    """

    m: int
    k: int
    c: int
    inner: bool
    t: int
    single: bool


class Scratch(NamedTuple):
    """Scratch space of a kernel: the multi-index of the cell and a stencil's corners."""

    mi: np.ndarray  # (d,) int64, the multi-index of ``Site.c`` (read at the border)
    idx: np.ndarray  # (2^d,) int64 corners
    w: np.ndarray  # (2^d,) their weights


@njit(cache=True, inline="always")
def scratch(d):  # pragma: no cover - numba
    """A :class:`Scratch` for a ``d``-dimensional grid."""
    return Scratch(np.empty(d, np.int64), np.empty(1 << d, np.int64), np.empty(1 << d))


@njit(cache=True, inline="always")
def lend(own):  # pragma: no cover - numba
    """The :class:`Scratch` ``own`` borrowed (:func:`borrow`); ``own`` must be kept alive
    (:func:`keep`) for as long as this is used."""
    return Scratch(borrow(own.mi), borrow(own.idx), borrow(own.w))


@njit(cache=True)
def keep(own):  # pragma: no cover - numba
    """Use the :class:`Scratch` ``own``: called at a kernel's end, it keeps the arrays its
    borrowed views (:func:`lend`) read alive until then."""
    return own.mi.shape[0] + own.idx.shape[0] + own.w.shape[0]


@njit(cache=True, inline="always")
def reader(h, D, live, finite, skip_zero, track):  # pragma: no cover - numba
    """A :class:`Law` over borrowed ``h``, ``D`` and ``live`` (arrays the caller holds)."""
    return Law(borrow(h), borrow(D), borrow(live), finite, skip_zero, track)


@njit(cache=True, inline="always")
def is_single(lay, m):  # pragma: no cover - numba
    """Mode ``m`` has one branch, into itself with probability one."""
    b0 = lay.branch_ptr[m]
    return (
        lay.branch_ptr[m + 1] - b0 == 1 and lay.branch_layer[b0] == m and lay.branch_prob[b0] == 1.0
    )


@njit(cache=True, inline="always")
def site_at(model, m, c, single, mi):  # pragma: no cover - numba
    """The :class:`Site` of cell ``c`` of mode ``m`` (``mi`` its multi-index where the
    moves are in the robot frame)."""
    moves = model.moves
    k = model.layers.vcls[m]
    t = mi[moves.heading_axis] if moves.heading_axis >= 0 else 0
    return Site(m, k, c, moves.interior[k, c], t, single)


@njit(cache=True, inline="always")
def move_stencil(model, site, row, s):  # pragma: no cover - numba
    """Corners and weights of the landing point of table row ``row`` (a move, or one landing
    of a noisy move) from the centre of ``site``'s cell into ``s.idx``, ``s.w``; returns
    their number.

    Away from the border the flat offsets are precomputed (``Moves.coff``, ``Moves.cw``,
    corners by decreasing weight, so the list stops at the first zero weight); at the
    border :func:`~cellplan.strategies.model.stencils.table_stencil` clamps or wraps
    (``s.mi`` must hold the multi-index of the cell there).
    """
    moves = model.moves
    if site.inner:
        nc = 0
        for jj in range(s.idx.shape[0]):
            wj = moves.cw[site.k, row, site.t, jj]
            if wj <= EPS_W:
                break
            s.idx[jj] = site.c + moves.coff[site.k, row, site.t, jj]
            s.w[jj] = wj
            nc += 1
        return nc
    return table_stencil(moves, model.grid, site.k, row, s.mi, s.idx, s.w)


@njit(cache=True, inline="always")
def live_sums(law, L, nc, s):  # pragma: no cover - numba
    """``(sum w, sum w h, sum w D)`` over the corners of ``s`` (``nc`` of them) that are
    states of layer ``L`` (``law.live``; with ``law.finite``, at a finite value): ``H_L``
    is the second over the first (Section IV-B), ``dH_L/dg`` the third over the first.

    The arrays are indexed in two dimensions, never sliced: a slice per call is an array
    view made and released per move, which costs more than the sums in the hot loops."""
    ssum = 0.0
    vsum = 0.0
    dsum = 0.0
    for j in range(nc):
        wj = s.w[j]
        if wj > EPS_W:
            i = s.idx[j]
            if law.live[L, i]:
                hv = law.h[L, i]
                if hv < np.inf or not law.finite:
                    ssum += wj
                    vsum += wj * hv
                    if law.track:
                        dsum += wj * law.D[L, i]
    return ssum, vsum, dsum


@njit(cache=True, inline="always")
def table_sums(model, law, site, row):  # pragma: no cover - numba
    """:func:`live_sums` of the layer's own values for an interior cell, straight from the
    stencil tables (no copy of the corners: the hot loop of a single-branch layer)."""
    moves = model.moves
    m = site.m
    ssum = 0.0
    vsum = 0.0
    dsum = 0.0
    for jj in range(moves.cw.shape[3]):
        wj = moves.cw[site.k, row, site.t, jj]
        if wj <= EPS_W:
            break
        i = site.c + moves.coff[site.k, row, site.t, jj]
        if law.live[m, i]:
            hv = law.h[m, i]
            if hv < np.inf or not law.finite:
                ssum += wj
                vsum += wj * hv
                if law.track:
                    dsum += wj * law.D[m, i]
    return ssum, vsum, dsum


@njit(cache=True, inline="always")
def landing_row(na, a, j, J):  # pragma: no cover - numba
    """The table row of landing ``j`` of move ``a`` (``na`` commanded moves, ``J`` landings
    each; Section VI-4: the landings follow the commanded moves)."""
    return na + a * J + j


@njit(cache=True, inline="always")
def move_value(model, law, site, a, start, own, s):  # pragma: no cover - numba
    """``(value, derivative)`` of move ``a`` at ``site``: ``start[0] + sum_b P_b sum_j p_j
    H_{L_b}(x + dx_{a,j})`` and the same with ``D`` from ``start[1]``; ``inf`` where some
    landing has no live corner in some branch (the move is not available).

    The branches into layer ``own`` are left out (-1: none; NR's sweep adds its self-loop
    itself). The caller checks that the move is collision-free (``Moves.valid``).
    """
    moves = model.moves
    lay = model.layers
    m = site.m
    val = start[0]
    der = start[1]
    J = moves.noise_prob.shape[0]
    noisy = J > 1
    na = moves.nact[site.k]
    for j in range(J if noisy else 1):
        p = moves.noise_prob[j] if noisy else 1.0
        if p <= 0.0:
            continue
        row = landing_row(na, a, j, J) if noisy else a
        if site.single and site.inner and own != m:
            ssum, vsum, dsum = table_sums(model, law, site, row)
            if ssum <= EPS_W:
                return np.inf, 0.0
            val += p * vsum / ssum
            if law.track:
                der += p * dsum / ssum
            continue
        nc = move_stencil(model, site, row, s)
        for b in range(lay.branch_ptr[m], lay.branch_ptr[m + 1]):
            L = lay.branch_layer[b]
            q = lay.branch_prob[b]
            if L == own or (law.skip_zero and q == 0.0):
                continue
            ssum, vsum, dsum = live_sums(law, L, nc, s)
            if ssum <= EPS_W:
                return np.inf, 0.0
            q = q * p
            val += q * vsum / ssum
            if law.track:
                der += q * dsum / ssum
    return val, der


@njit(cache=True, inline="always")
def stay_value(model, law, site, start, own):  # pragma: no cover - numba
    """``(value, derivative)`` of staying at ``site``: ``start[0] + sum_b P_b h(L_b, x)``
    (and ``D`` from ``start[1]``), the branches into ``own`` left out (-1: none); ``inf``
    where a branch's state is not live (or, with ``law.finite``, not finite)."""
    lay = model.layers
    c = site.c
    val = start[0]
    der = start[1]
    for b in range(lay.branch_ptr[site.m], lay.branch_ptr[site.m + 1]):
        L = lay.branch_layer[b]
        q = lay.branch_prob[b]
        if L == own or (law.skip_zero and q == 0.0):
            continue
        if not law.live[L, c] or (law.finite and law.h[L, c] == np.inf):
            return np.inf, 0.0
        val += q * law.h[L, c]
        if law.track:
            der += q * law.D[L, c]
    return val, der


@njit(cache=True, inline="always")
def fmp_value(model, law, opt, c, start):  # pragma: no cover - numba
    """``(value, derivative)`` of FMP option ``opt`` at cell ``c``: ``start[0] +
    sum_k P_k (c_k + h(L_k, c))`` over its outcomes (``start[0]`` is ``t_f``, less ``g``
    in the structured solver's average-cost form) and ``start[1] + sum_k P_k D(L_k, c)``;
    ``inf`` where an outcome of positive probability is not a live (finite) state."""
    lay = model.layers
    val = start[0]
    der = start[1]
    for o in range(lay.out_ptr[opt], lay.out_ptr[opt + 1]):
        p = lay.out_prob[o]
        if p <= 0.0:
            continue
        L = lay.out_layer[o]
        if not law.live[L, c] or (law.finite and law.h[L, c] == np.inf):
            return np.inf, 0.0
        val += p * (lay.out_cost[o] + law.h[L, c])
        if law.track:
            der += p * law.D[L, c]
    return val, der


@njit(cache=True, inline="always")
def move_supported(model, live, target, site, a, s, skip_zero):  # pragma: no cover - numba
    """Whether move ``a`` is available at ``site`` under the law of :func:`move_value`:
    every landing (one without noise) has a live corner in every branch (with
    ``skip_zero``: of positive probability). ``live`` are the states of each layer,
    ``target`` stands for the layer ``site.m`` itself. The caller checks that the move is
    collision-free."""
    moves = model.moves
    lay = model.layers
    m = site.m
    J = moves.noise_prob.shape[0]
    noisy = J > 1
    na = moves.nact[site.k]
    for j in range(J if noisy else 1):
        if noisy and moves.noise_prob[j] <= 0.0:
            continue
        nc = move_stencil(model, site, landing_row(na, a, j, J) if noisy else a, s)
        for b in range(lay.branch_ptr[m], lay.branch_ptr[m + 1]):
            if skip_zero and lay.branch_prob[b] <= 0.0:
                continue
            L = lay.branch_layer[b]
            if not supported(target if L == m else live[L], s.idx, s.w, nc):
                return False
    return True
