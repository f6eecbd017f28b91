"""Interpolated cost-to-go: weighted means over the live corners of a stencil (numba).

Section IV-B of the strategies paper represents the cost-to-go at cell centres and
interpolates between them. With the ``2^d`` corners ``i_k`` of a point's multilinear
stencil and their weights ``w_k`` (:func:`cellplan.strategies.model.stencils.stencil`,
:func:`~cellplan.strategies.solve.law.move_stencil`), the value of layer ``L`` there is

    H_L(x) = sum_k w_k [live_L(i_k)] h_L(i_k) / sum_k w_k [live_L(i_k)],

the weights renormalised over the corners that are states of the layer. The same
renormalised weights are the transition probabilities of the discretised MDP, so this is
also the expectation of ``h_L`` after a move. It is undefined (NaN) where no live corner
has weight.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cellplan.strategies.model.stencils import EPS_W


@njit(cache=True, inline="always")
def interp(values, live, idx, w, n):  # pragma: no cover - numba
    """``H(x)`` of one layer (``values``, ``live`` 1-D) over ``n`` corners; NaN: unsupported."""
    s = 0.0
    v = 0.0
    for k in range(n):
        if w[k] > EPS_W and live[idx[k]]:
            s += w[k]
            v += w[k] * values[idx[k]]
    if s <= EPS_W:
        return np.nan
    return v / s


@njit(cache=True, inline="always")
def supported(live, idx, w, n):  # pragma: no cover - numba
    """Whether some live corner of the stencil has positive weight."""
    for k in range(n):
        if w[k] > EPS_W and live[idx[k]]:
            return True
    return False
