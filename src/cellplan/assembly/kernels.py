"""Numba kernels of the flows and the place rule's routes: one pass over the disc pairs.

:func:`nav_kernel` (same formulas as :mod:`navigation`): one pass over the disc pairs
accumulates ``log beta`` (equations (4)-(5)), ``grad log beta``, the repulsion magnitudes
used for step control, and the gaps, without the temporary ``(n, n, 2)`` arrays of the
numpy version; it is what the flows call. The numpy version,
:func:`navigation.evaluate_numpy`, stays as the reference it is tested against.

The others (issue 13, each with its numpy reference kept and tested,
``tests/assembly/test_kernels.py``): :func:`hessian_kernel` (the Hessian of
``L = log alpha^(1/k)``, equations (2)-(5), for the implicit step), :func:`segment_kernel`
(the implicit step's exact segment test), :func:`triangle_safe_kernel`,
:func:`max_dt_kernel` and :func:`rk4_stages_kernel` (the RK4 step's bounds and stages,
the same operations as the numpy code, so bit-identical steps) and
:func:`segments_gap_kernel` (the place rule's segment clearances). No kernel allocates
``(n, n, 2)`` or ``(S, n)`` temporaries.

The implicit step's eigen-decomposition is in :mod:`cellplan.assembly.eigen`.
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


@numba.njit(cache=True)
def hessian_kernel(
    b: Array, d: Array, radii: Array, circle: bool, w0: Array, w1: Array, k: float
) -> Array:
    """Hessian ``(2n, 2n)`` of ``L = log gamma - log(beta) / k`` in one pass over the pairs.

    The formulas of :func:`navigation.hessian_log_w_numpy` (equations (3)-(5) and the
    boundary term differentiated twice): per pair ``x = b_i - b_j``,
    ``M = D_x^2 log beta_ij = I / beta_ij - x x^T / beta_ij^2`` enters ``+M`` on the
    ``ii`` and ``jj`` blocks and ``-M`` on the ``ij`` and ``ji`` blocks of
    ``D^2 log beta``; ``D^2 log gamma = I / gamma - e e^T / gamma^2``. Workspace as in
    :func:`nav_kernel`.
    """
    n = b.shape[0]
    m = 2 * n
    hb = np.zeros((m, m))  # D^2 log beta
    for i in range(n):
        for j in range(i + 1, n):
            x0 = b[i, 0] - b[j, 0]
            x1 = b[i, 1] - b[j, 1]
            rs = radii[i] + radii[j]
            iv = 1.0 / (0.5 * (x0 * x0 + x1 * x1 - rs * rs))
            iv2 = iv * iv
            m00 = iv - iv2 * x0 * x0
            m01 = -iv2 * x0 * x1
            m11 = iv - iv2 * x1 * x1
            a, c = 2 * i, 2 * j
            hb[a, a] += m00
            hb[a, a + 1] += m01
            hb[a + 1, a] += m01
            hb[a + 1, a + 1] += m11
            hb[c, c] += m00
            hb[c, c + 1] += m01
            hb[c + 1, c] += m01
            hb[c + 1, c + 1] += m11
            hb[a, c] = -m00
            hb[a, c + 1] = -m01
            hb[a + 1, c] = -m01
            hb[a + 1, c + 1] = -m11
            hb[c, a] = -m00
            hb[c, a + 1] = -m01
            hb[c + 1, a] = -m01
            hb[c + 1, a + 1] = -m11
    for i in range(n):
        a = 2 * i
        if circle:
            y0 = b[i, 0] - w0[0]
            y1 = b[i, 1] - w0[1]
            rr = w1[0] - radii[i]
            iw = 1.0 / (0.5 * (rr * rr - (y0 * y0 + y1 * y1)))
            iw2 = iw * iw
            hb[a, a] += -iw - iw2 * y0 * y0
            hb[a, a + 1] += -iw2 * y0 * y1
            hb[a + 1, a] += -iw2 * y0 * y1
            hb[a + 1, a + 1] += -iw - iw2 * y1 * y1
        else:
            for axis in range(2):
                t_lo = b[i, axis] - w0[axis] - radii[i]
                t_hi = w1[axis] - radii[i] - b[i, axis]
                hb[a + axis, a + axis] -= 1.0 / (t_lo * t_lo) + 1.0 / (t_hi * t_hi)
    e = np.empty(m)
    gamma = 0.0
    for i in range(n):
        e[2 * i] = b[i, 0] - d[i, 0]
        e[2 * i + 1] = b[i, 1] - d[i, 1]
        gamma += 0.5 * (e[2 * i] * e[2 * i] + e[2 * i + 1] * e[2 * i + 1])
    ig = 1.0 / gamma
    g2 = gamma * gamma
    out = np.empty((m, m))
    for r in range(m):
        for c in range(m):
            # e[r] * e[c] == e[c] * e[r]: exactly symmetric, as LAPACK's eigh assumes
            out[r, c] = -((e[r] * e[c]) / g2) - hb[r, c] / k
        out[r, r] = (ig - (e[r] * e[r]) / g2) - hb[r, r] / k
    return out


@numba.njit(cache=True)
def segment_kernel(b: Array, delta: Array, radii: Array, gaps: Array, fraction: float) -> bool:
    """True when along ``b -> b + delta`` no pair gap falls below ``fraction`` of ``gaps``.

    Per pair, the smallest centre distance along the segment: ``x(t) = x0 + t dx`` is
    closest to the origin at ``t = clip(-x0.dx / dx.dx, 0, 1)`` (exact; the boundary is
    checked by the caller at the end points).
    """
    n = b.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            x0 = b[i, 0] - b[j, 0]
            x1 = b[i, 1] - b[j, 1]
            d0 = delta[i, 0] - delta[j, 0]
            d1 = delta[i, 1] - delta[j, 1]
            dd = d0 * d0 + d1 * d1
            t = 0.0
            if dd > 0.0:
                t = min(max(-(x0 * d0 + x1 * d1) / dd, 0.0), 1.0)
            c0 = x0 + t * d0
            c1 = x1 + t * d1
            gap = math.sqrt(c0 * c0 + c1 * c1) - (radii[i] + radii[j])
            if not gap >= fraction * gaps[i, j]:
                return False
    return True


@numba.njit(cache=True)
def segments_gap_kernel(P: Array, Q: Array, x: Array, radii: Array, i: int) -> Array:
    """Smallest gap to the standing discs while disc i moves straight ``P[s] -> Q[s]`` (S,).

    Per segment and standing disc j: the distance from ``x[j]`` to the segment (the
    closest point at ``t = clip((x_j - P).(Q - P) / |Q - P|^2, 0, 1)``, ``t = 0`` for a
    point segment) minus ``radii[j] + radii[i]``; ``inf`` with no other disc. The same
    operations, in the same order, as the numpy reference
    :func:`routes.segments_clearance_numpy`, without its ``(S, n)`` temporaries.
    """
    S = P.shape[0]
    n = x.shape[0]
    out = np.full(S, np.inf)
    for s in range(S):
        sx = Q[s, 0] - P[s, 0]
        sy = Q[s, 1] - P[s, 1]
        length2 = sx * sx + sy * sy
        best = np.inf
        for j in range(n):
            if j == i:
                continue
            rx = x[j, 0] - P[s, 0]
            ry = x[j, 1] - P[s, 1]
            t = 0.0
            if length2 > 0.0:
                t = min(max((rx * sx + ry * sy) / length2, 0.0), 1.0)
            dx = rx - t * sx
            dy = ry - t * sy
            gap = math.sqrt(dx * dx + dy * dy) - radii[j] - radii[i]
            if gap < best:
                best = gap
        out[s] = best
    return out


@numba.njit(cache=True)
def triangle_safe_kernel(delta: Array, gaps: Array, bgap: Array, fraction: float) -> bool:
    """True when ``|delta_i| + |delta_j| <= fraction gap_ij`` for every pair and
    ``|delta_i| <= fraction bgap_i`` for every disc (the RK4 step's bound, see
    :func:`flows.step_is_safe`); the same comparisons as its numpy reference."""
    n = delta.shape[0]
    m = np.empty(n)
    for i in range(n):
        m[i] = math.sqrt(delta[i, 0] * delta[i, 0] + delta[i, 1] * delta[i, 1])
    for i in range(n):
        if not m[i] <= fraction * bgap[i]:
            return False
        for j in range(n):
            if not m[i] + m[j] <= fraction * gaps[i, j]:
                return False
    return True


@numba.njit(cache=True, error_model="numpy")
def max_dt_kernel(
    w: Array, rep: Array, rep_bnd: Array, moving: Array, gaps: Array, bgap: Array, stiff: bool
) -> float:
    """The step bound of :func:`flows.max_dt` in one pass over the pairs (its reference
    is :func:`flows.max_dt_numpy`); a ``nan`` term makes the result ``nan``, as there."""
    n = w.shape[0]
    s = 1.0 if stiff else 0.0
    speed = np.empty(n)
    for i in range(n):
        speed[i] = math.sqrt(w[i, 0] * w[i, 0] + w[i, 1] * w[i, 1])
    best = np.inf
    for i in range(n):
        for j in range(n):
            x = gaps[i, j] / (
                speed[i] + speed[j] + 2.0 * rep[i, j] * (max(moving[i], moving[j]) * s)
            )
            if x != x:
                return np.nan
            best = min(best, x)
    for i in range(n):
        x = bgap[i] / (speed[i] + rep_bnd[i] * moving[i] * s)
        if x != x:
            return np.nan
        best = min(best, x)
    return best


@numba.njit(cache=True)
def rk4_stages_kernel(
    b: Array,
    w1: Array,
    dt: float,
    gaps: Array,
    bgap: Array,
    d: Array,
    radii: Array,
    circle: bool,
    ws0: Array,
    ws1: Array,
    k: float,
    mask: Array,
    fraction: float,
) -> tuple[bool, Array, int]:
    """The stages of one classical RK4 step of ``b' = w = -(v * mask)`` (the flows' RK4).

    ``v`` is ``grad phi`` rescaled (equation (8) factored, :func:`nav_kernel`): with every
    disc moving this is the gradient flow (9), with one disc the low-level flow
    (10)-(12). Workspace arguments as in :func:`nav_kernel` (``ws0``, ``ws1``).

    Returns ``(ok, delta, evaluations)``: ``ok`` is False when a stage point or the
    combined step fails the triangle bound (:func:`triangle_safe_kernel`) or a stage
    field is not finite; ``delta = dt/6 (w1 + 2 w2 + 2 w3 + w4)``. Each stage point is
    a straight step from ``b``. The same operations, in the same order, as
    :func:`flows._rk4` with the field of :func:`flows.integrate` (no ``direction``, no
    ``normalize``), so both give the same steps to the last bit.
    """
    n = b.shape[0]
    stages = np.empty((4, n, 2))
    stages[0] = w1
    evals = 0
    for s in range(3):
        c = 1.0 if s == 2 else 0.5
        delta = (c * dt) * stages[s]
        if not triangle_safe_kernel(delta, gaps, bgap, fraction):
            return False, delta, evals
        out = nav_kernel(b + delta, d, radii, circle, ws0, ws1, k)
        evals += 1
        v = out[2]
        for i in range(n):
            for j in range(2):
                x = -(v[i, j] * mask[i, 0]) * 1.0
                if not np.isfinite(x):
                    return False, delta, evals
                stages[s + 1, i, j] = x
    delta = (dt / 6.0) * (stages[0] + 2.0 * stages[1] + 2.0 * stages[2] + stages[3])
    return triangle_safe_kernel(delta, gaps, bgap, fraction), delta, evals
