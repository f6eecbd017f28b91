"""The live states of each layer: the states from which its request can be finished (numba).

The MDP is defined on live states only (docs/strategies.md, "Live states"): without this
a cell that can never deliver would have infinite relative cost and break the
average-cost iteration, and the input checks could not name a request that is never
served. :func:`live_layer` shrinks one layer's live set once;
:func:`cellplan.strategies.model.mdp.compute_live` repeats it until nothing changes.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cellplan.strategies.model.stencils import cell_of_order
from cellplan.strategies.solve.law import (
    borrow,
    borrowed,
    keep,
    lend,
    move_supported,
    scratch,
    site_at,
)


@njit(cache=True)
def live_layer(live, fmp_ok, model, m):  # pragma: no cover - numba
    """Shrink layer ``m`` of ``live`` (``(M, N)``, in place) once; returns whether it changed.

    A layer with an FMP successor keeps the states from which an FMP-capable state
    (``fmp_ok``, ``(O, N)`` by FMP option, with every outcome of an allowed option live)
    is reachable through actions whose every branch lands on live states (a backward
    closure); a layer without FMP (NR) keeps the states that have some such action. The
    result depends only on the rows ``live[m]``, the ``fmp_ok`` rows of the layer's FMP
    options, the FMP outcome layers' and the branch layers' ``live`` rows, and the
    layer's motion class, and running it again on its own output changes nothing (the caller,
    :func:`cellplan.strategies.model.mdp.compute_live`, relies on both to skip work).
    ``model.layers.live`` is not read (``live`` replaces it).
    """
    model = borrowed(model)  # the law is inlined per move: no reference counting
    moves = model.moves
    grid = model.grid
    lay = model.layers
    shape = grid.shape
    ncell = live.shape[1]
    d = shape.shape[0]
    held = scratch(d)
    s = lend(held)
    mi = s.mi
    lent = borrow(live)
    changed = False
    reach = np.zeros(ncell, np.bool_)
    nxt = lay.fmp_next[m]
    k = lay.vcls[m]
    na = moves.nact[k]
    if nxt >= 0:
        for c in range(ncell):
            if not live[m, c]:
                continue
            # Some FMP option (one but with simultaneous requests, Section VI-2) every
            # outcome of which (success, and failure with failure modes) lands on a live
            # state; a retry in place lands on this very state.
            for opt in range(lay.opt_ptr[m], lay.opt_ptr[m + 1]):
                ok = fmp_ok[opt, c]
                for o in range(lay.out_ptr[opt], lay.out_ptr[opt + 1]):
                    if ok and lay.out_prob[o] > 0.0:
                        ok = live[lay.out_layer[o], c]
                if ok:
                    reach[c] = True
                    break
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
            # Staying finishes a request only through another layer (a time-varying
            # model's next phase, Section VI-1): in a stationary layer its branch to
            # itself reads ``target``, which does not hold ``c`` here.
            good = True
            for b in range(lay.branch_ptr[m], lay.branch_ptr[m + 1]):
                L = lay.branch_layer[b]
                if lay.branch_prob[b] > 0.0 and not (target[c] if L == m else live[L, c]):
                    good = False
                    break
            if not good:
                # Some move every landing of which is supported in every branch (the law
                # of :func:`cellplan.strategies.solve.law.move_supported`).
                site = site_at(model, m, c, False, s.mi)
                vb = moves.valid[k, c]
                for a in range(na):
                    if (vb >> a) & 1 and move_supported(
                        model, lent, borrow(target), site, a, s, True
                    ):
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
    keep(held)
    return changed
