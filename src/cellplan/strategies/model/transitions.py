"""An optional, stricter transition law: no sideways snaps into narrow corridors.

The model's interpolation (Section IV-B) renormalises a landing point's weights over the
live corners of its stencil. Beside a passage one cell wide this moves the robot sideways
by up to a cell, which the rotating robot of problem 3 (it moves only along its axis)
cannot do; at 48 x 48 x 30 the solved route to D1 exists only through such snaps (see
"Executing P3 off the grid" in docs/strategies.md). :func:`forbid_snapping` removes from
the MDP every move whose landing stencil, taken from the cell centre, puts positive weight
on a cell that is not free in the move class's bitmap, then recomputes the live states.
The remaining transitions only spread the landing point over free cells around it.

Not used by default: it makes the model pessimistic on coarse grids (it also forbids
moves that are possible from off-centre states). ``solve_scenario(..., snap=False)``
applies it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numba import njit

from cellplan.errors import ScenarioError
from cellplan.strategies.model import stencils
from cellplan.strategies.model.mdp import LayeredMDP, compute_live, live_problems


@njit(cache=True)
def snap_free_moves(moves, grid):  # pragma: no cover - numba
    """``moves.valid`` without the moves whose landing stencil touches a blocked cell
    (``moves``, ``grid``: the bundles of :mod:`.bundles`)."""
    free = moves.free
    valid = moves.valid
    disp = moves.disp
    nact = moves.nact
    heading_axis = moves.heading_axis
    shape = grid.shape
    lower = grid.lower
    upper = grid.upper
    spacing = grid.spacing
    periodic = grid.periodic
    K, N = free.shape
    d = shape.shape[0]
    q = np.empty(d)
    dq = np.empty(d)
    idx = np.empty(1 << d, np.int64)
    w = np.empty(1 << d)
    ibuf = np.empty(2 * stencils.MAX_DIM, np.int64)
    frac = np.empty(stencils.MAX_DIM)
    out = valid.copy()
    for k in range(K):
        for c in range(N):
            if valid[k, c] == 0:
                continue
            stencils.centre(c, shape, lower, spacing, q)
            for a in range(nact[k]):
                if (valid[k, c] >> a) & 1 == 0:
                    continue
                stencils.displacement(q, disp[k, a], heading_axis, dq)
                for j in range(d):
                    dq[j] += q[j]
                stencils.wrap(dq, lower, upper, periodic)
                n = stencils.stencil(dq, grid, idx, w, ibuf, frac)
                for kk in range(n):
                    if w[kk] > stencils.EPS_W and not free[k, idx[kk]]:
                        out[k, c] &= ~(1 << a)
                        break
    return out


def forbid_snapping(mdp: LayeredMDP) -> LayeredMDP:
    """A copy of ``mdp`` without snapping moves, its live states recomputed.

    Raises
    ------
    ScenarioError
        When a request can no longer be served (as :func:`~.mdp.build_model`).
    """
    model = mdp.kernel_args()
    valid = snap_free_moves(model.moves, model.grid)
    live = np.stack([mdp.free[mdp.vcls[m]] for m in range(mdp.n_modes)])
    out = replace(mdp, valid=valid, live=live)
    compute_live(out)
    problems = live_problems(out)
    if problems:
        raise ScenarioError(problems)
    return out
