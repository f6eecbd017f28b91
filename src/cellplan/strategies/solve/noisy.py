"""Noisy motion (the first step of Section VI-4 of the strategies paper): moves that land
at one of several displacements around the commanded one (numba).

With noise, move ``a`` lands at ``x + dx_{a,j}`` with probability ``p_j``
(:func:`cellplan.strategies.model.actions.with_noise`: the model's move tables hold these
landings in rows ``A + a J + j`` after the ``A`` commanded moves), so its value in (9) is

    l(m) + sum_b P_b sum_j p_j H_{L_b}(x + dx_{a,j}),

and the move is allowed only where every landing's swept motion is free (the model's
``valid`` bitmask says so per commanded move) and, in every branch, every landing has a
live corner. At cell centres that is the transition law of
:mod:`cellplan.strategies.solve.law` (:func:`~cellplan.strategies.solve.law.move_value`,
:func:`~cellplan.strategies.solve.law.move_supported`); here is its value at a real
configuration (an online query).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cellplan.strategies.model.interpolation import interp
from cellplan.strategies.model.motion import motion_ok
from cellplan.strategies.model.stencils import displacement, stencil, wrap
from cellplan.strategies.solve.law import landing_row


@njit(cache=True)
def noisy_value_at(q, m, a, h, live, model, pr):  # pragma: no cover - numba
    """``sum_b P_b sum_j p_j H_{L_b}(q_j)`` at a real configuration (without the loss),
    ``q_j = q + dq_{a,j}``, or ``q`` itself where landing ``j``'s swept motion is blocked;
    NaN where every landing is blocked or a value has no live corner.

    A real configuration is not a cell centre: near a wall a landing that is free from the
    centre can be blocked from ``q``. Execution guards the motion (the robot stops where it
    is, :meth:`~cellplan.strategies.policy.strategy.Strategy.next_configuration`), and the value
    here counts that outcome, so the robot is never left without a move. ``bufs`` is the
    scratch :class:`~cellplan.strategies.model.bundles.Probe` of a point query.
    """
    moves = model.moves
    lay = model.layers
    grid = model.grid
    k = lay.vcls[m]
    na = moves.nact[k]
    J = moves.noise_prob.shape[0]
    d = q.shape[0]
    dq = np.empty(d)
    qn = np.empty(d)
    total = 0.0
    moved = False
    for j in range(J):
        p = moves.noise_prob[j]
        if p <= 0.0:
            continue
        displacement(q, moves.disp[k, landing_row(na, a, j, J)], moves.heading_axis, dq)
        if motion_ok(q, dq, moves.free[k], grid, pr.mbuf):
            moved = True
            for i in range(d):
                qn[i] = q[i] + dq[i]
            wrap(qn, grid.lower, grid.upper, grid.periodic)
        else:
            for i in range(d):
                qn[i] = q[i]
        n = stencil(qn, grid, pr.idx, pr.w, pr.ibuf, pr.frac)
        for b in range(lay.branch_ptr[m], lay.branch_ptr[m + 1]):
            L = lay.branch_layer[b]
            v = interp(h[L], live[L], pr.idx, pr.w, n)
            if np.isnan(v):
                return np.nan
            total += lay.branch_prob[b] * p * v
    return total if moved else np.nan
