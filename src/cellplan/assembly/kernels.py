"""Numba kernel of the flows: the log-space navigation function.

:func:`nav_kernel` (same formulas as :mod:`navigation`): one pass over the disc pairs
accumulates ``log beta`` (equations (4)-(5)), ``grad log beta``, the repulsion magnitudes
used for step control, and the gaps, without the temporary ``(n, n, 2)`` arrays of the
numpy version; it is what the flows call. The numpy version,
:func:`navigation.evaluate_numpy`, stays as the reference it is tested against.

The implicit step's eigensolver is in :mod:`cellplan.assembly.eigen`.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@numba.njit(cache=True)
def nav_kernel(
    b: Array, d: Array, radii: Array, circle: bool, w0: Array, w1: Array, k: float
) -> tuple[float, float, Array, Array, Array, Array, Array]:
    """``(log_gamma, log_beta, v, rep, rep_bnd, gaps, bgap)`` at ``b``.

    ``circle``: the workspace is the disc of centre ``w0`` and radius ``w1[0]``;
    otherwise the box ``[w0, w1]``. ``gaps`` has ``inf`` on its diagonal.
    """
    n = b.shape[0]
    gamma = 0.0
    for i in range(n):
        ex = b[i, 0] - d[i, 0]
        ey = b[i, 1] - d[i, 1]
        gamma += 0.5 * (ex * ex + ey * ey)
    g = np.zeros((n, 2))
    dist = np.zeros((n, n))
    inv = np.zeros((n, n))
    gaps = np.full((n, n), np.inf)
    log_beta = 0.0
    for i in range(n):
        for j in range(i + 1, n):
            dx = b[i, 0] - b[j, 0]
            dy = b[i, 1] - b[j, 1]
            sq = dx * dx + dy * dy
            rs = radii[i] + radii[j]
            beta_ij = 0.5 * (sq - rs * rs)
            r = math.sqrt(sq)
            dist[i, j] = r
            dist[j, i] = r
            gaps[i, j] = r - rs
            gaps[j, i] = r - rs
            if beta_ij > 0.0:
                log_beta += math.log(beta_ij)
            else:
                log_beta = -np.inf if beta_ij == 0.0 else np.nan
            iv = 1.0 / beta_ij
            inv[i, j] = iv
            inv[j, i] = iv
            g[i, 0] += dx * iv
            g[i, 1] += dy * iv
            g[j, 0] -= dx * iv
            g[j, 1] -= dy * iv
    gb = np.zeros((n, 2))
    bgap = np.zeros(n)
    for i in range(n):
        if circle:
            rx = b[i, 0] - w0[0]
            ry = b[i, 1] - w0[1]
            rr = w1[0] - radii[i]
            w = 0.5 * (rr * rr - (rx * rx + ry * ry))
            log_beta += math.log(w) if w > 0.0 else (-np.inf if w == 0.0 else np.nan)
            gb[i, 0] = -rx / w
            gb[i, 1] = -ry / w
            bgap[i] = rr - math.sqrt(rx * rx + ry * ry)
        else:
            t0 = b[i, 0] - w0[0] - radii[i]
            t1 = w1[0] - radii[i] - b[i, 0]
            t2 = b[i, 1] - w0[1] - radii[i]
            t3 = w1[1] - radii[i] - b[i, 1]
            m = min(t0, t1, t2, t3)
            if m > 0.0:
                log_beta += math.log(t0) + math.log(t1) + math.log(t2) + math.log(t3)
            else:
                log_beta = -np.inf if m == 0.0 else np.nan
            gb[i, 0] = 1.0 / t0 - 1.0 / t1
            gb[i, 1] = 1.0 / t2 - 1.0 / t3
            bgap[i] = m
    log_gamma = math.log(gamma) if gamma > 0.0 else -np.inf
    c = gamma / k
    v = np.empty((n, 2))
    rep = np.empty((n, n))
    rep_bnd = np.empty(n)
    for i in range(n):
        v[i, 0] = (b[i, 0] - d[i, 0]) - c * (g[i, 0] + gb[i, 0])
        v[i, 1] = (b[i, 1] - d[i, 1]) - c * (g[i, 1] + gb[i, 1])
        rep_bnd[i] = c * math.sqrt(gb[i, 0] ** 2 + gb[i, 1] ** 2)
        for j in range(n):
            rep[i, j] = c * dist[i, j] * abs(inv[i, j])
    return log_gamma, log_beta, v, rep, rep_bnd, gaps, bgap
