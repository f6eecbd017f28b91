"""NR, the one layer without FMP, swept with its stay self-loop solved exactly (numba).

NR's request branches lead to the W layers, which are fixed while NR is solved; they are
summed once per pass (:func:`other_branches`), so a Gauss-Seidel sweep of NR
(:func:`sweep_self`) interpolates NR alone,

    h = min( (l - g + E_stay) / (1 - P_self),  min_a  l - g + E_a + P_self H_NR(x'_a) ).

NR is one layer, so its sweep runs in slabs of rows on parallel threads (the
policy-iteration loop around it is :meth:`cellplan.strategies.solve.layers.Layers.nr_layer`).
Every value of an action is the transition law of :mod:`cellplan.strategies.solve.law`.
"""

from typing import NamedTuple

import numpy as np
from numba import njit

from cellplan.strategies.model.stencils import EPS_W, decode, first_of_rows, next_of_order
from cellplan.strategies.solve.law import (
    OUTSIDE,
    STAY,
    UNRECORDED,
    borrow,
    borrowed,
    is_single,
    keep,
    lend,
    live_sums,
    move_stencil,
    move_value,
    reader,
    scratch,
    site_at,
    stay_value,
)


@njit(cache=True, nogil=True)
def other_branches(m, h, D, E, ED, start, stop, model):  # pragma: no cover - numba
    """Expected next value over the branches that leave layer ``m``, per cell and action.

    ``E[c, 0] = sum_{b: L_b != m} P_b h[L_b](c)`` for stay and ``E[c, 1 + a]`` the same at
    the landing point of move ``a`` (the law of :mod:`.law`, as in :func:`.sweeps.sweep_policy`);
    ``ED`` is the same for ``D``. ``inf`` marks an action that is not available (move not
    collision-free, or some branch without a live corner). In NR these branches lead to
    the W layers, which are fixed while NR is solved, so a Gauss-Seidel sweep of NR then
    touches only its own values (the request branches cost 16 interpolations per move in
    problem 1; done once here instead of once per sweep). Only cells ``start <= c < stop``
    are written, so that disjoint ranges can run in parallel threads.
    """
    model = borrowed(model)
    moves = model.moves
    lay = model.layers
    live = lay.live
    held = scratch(model.grid.shape.shape[0])
    s = lend(held)
    kcls = lay.vcls[m]
    na = moves.nact[kcls]
    single = is_single(lay, m)
    law = reader(h, D, live, True, True, True)
    for c in range(start, stop):
        for a in range(E.shape[1]):
            E[c, a] = np.inf
            ED[c, a] = 0.0
        if not live[m, c]:
            continue
        decode(c, model.grid.shape, s.mi)
        site = site_at(model, m, c, single, s.mi)
        E[c, 0], ED[c, 0] = stay_value(model, law, site, (0.0, 0.0), m)
        vb = moves.valid[kcls, c]
        for a in range(na):
            if ((vb >> a) & 1) == 0:
                continue
            val, der = move_value(model, law, site, a, (0.0, 0.0), m, s)
            if val < np.inf:
                E[c, 1 + a] = val
                ED[c, 1 + a] = der
    keep(held)


class NRBranches(NamedTuple):
    """NR's branches for :func:`sweep_self`: the others summed (:func:`other_branches`)
    and the probability ``pself`` of its self-loop."""

    E: np.ndarray  # (N, 1 + A): stay, then each move
    ED: np.ndarray  # the same for D
    pself: float


class Slab(NamedTuple):
    """A slab of rows of NR swept by one thread (:func:`sweep_self`).

    ``work_h`` and ``work_D`` hold the layer's values from before the sweep; the slab
    reads and writes them only, and copies its own rows back into the layer at the end.
    """

    rows: tuple[int, int]  # (start, stop) of the first index
    work_h: np.ndarray  # (N,)
    work_D: np.ndarray  # (N,)


# The tail of sweep_self's cell loop (the record of the policy and of the largest change)
# repeats sweeps.sweep_policy's in shape: bookkeeping, not the transition law, which both
# take from law.py (live_sums, move_value).
@njit(cache=True, nogil=True)
def sweep_self(m, h, D, g, nr, sw, model, slab):  # pragma: no cover - numba
    """One Gauss-Seidel sweep of a slab of a layer without FMP whose other branches are in
    ``nr.E``.

    The update of :func:`.sweeps.sweep_policy` with ``exact_stay`` for NR (``nr.pself`` is the
    probability of staying in the layer): stay is solved exactly,
    ``h = (l - g + E[c, 0]) / (1 - pself)``, and a move costs
    ``l - g + E[c, 1 + a] + pself * H_m(x')`` (the law of :mod:`.law`,
    :func:`.law.live_sums`). ``sw`` (a :class:`.sweeps.Sweep`) as in
    :func:`.sweeps.sweep_policy` (``mode`` 1 records the policy). Returns the largest
    change.

    Only the cells whose first index lies in ``slab.rows`` are updated, in the sweep
    order, in the slab's working copy of the layer (a landing corner outside the slab
    reads the value from before the sweep); the slab's rows are then copied into ``h`` and
    ``D``. Slabs of one sweep therefore read nothing another writes, so they can run on
    parallel threads in any order and give the same values: Gauss-Seidel inside a slab,
    Jacobi across slabs.
    """
    model = borrowed(model)
    moves = model.moves
    lay = model.layers
    shape = model.grid.shape
    ncell = h.shape[1]
    held = scratch(shape.shape[0])
    s = lend(held)
    mi = s.mi
    pol, nchg = borrow(sw.pol), borrow(sw.nchg)
    hw, Dw = slab.work_h, slab.work_D
    E, ED, pself = nr.E, nr.ED, nr.pself
    livem = lay.live[m]
    kcls = lay.vcls[m]
    na = moves.nact[kcls]
    step_cost = lay.cost[m] - g
    # The law reads the slab's working copy of the layer (as layer 0 of a one-layer view).
    law = reader(
        hw.reshape((1, ncell)), Dw.reshape((1, ncell)), livem.reshape((1, ncell)), True, True, True
    )
    maxchange = 0.0
    # The slab is a run of flat indices (the first axis varies slowest).
    stride = ncell // shape[0]
    lo = slab.rows[0] * stride
    hi = slab.rows[1] * stride
    c = -1
    for kk in range(hi - lo):
        if kk == 0:
            c = first_of_rows(shape, sw.flips, slab.rows, mi)
        else:
            c = next_of_order(shape, sw.flips, mi)
        if not livem[c]:
            continue
        best = np.inf
        bestd = 0.0
        barg = OUTSIDE
        pold = pol[m, c] if sw.mode == 1 else UNRECORDED
        oldv = np.inf
        if E[c, 0] < np.inf and pself < 1.0 - 1e-12:
            best = (step_cost + E[c, 0]) / (1.0 - pself)
            bestd = (-1.0 + ED[c, 0]) / (1.0 - pself)
            barg = STAY
            if pold == STAY:
                oldv = best
        site = site_at(model, m, c, False, mi)
        vb = moves.valid[kcls, c]
        for a in range(na):
            if ((vb >> a) & 1) == 0 or E[c, 1 + a] == np.inf:
                continue
            val = step_cost + E[c, 1 + a]
            der = -1.0 + ED[c, 1 + a]
            if pself > 0.0:
                nc = move_stencil(model, site, a, s)
                ssum, vsum, dsum = live_sums(law, 0, nc, s)
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
        if sw.mode == 1 and pol[m, c] != barg:
            pol[m, c] = barg
            if not oldv - best <= sw.tie:
                nchg[0] += 1
        old = hw[c]
        if best < np.inf:
            ch = abs(best - old) if old < np.inf else np.inf
            if ch > maxchange:
                maxchange = ch
            hw[c] = best
            Dw[c] = bestd
    hm = h[m]
    Dm = D[m]
    for c in range(lo, hi):
        hm[c] = hw[c]
        Dm[c] = Dw[c]
    keep(held)
    return maxchange
