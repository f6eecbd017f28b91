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
    """``(log_gamma, log_beta, v, rep, rep_bnd, gaps, bgap)`` at ``b`` (n, dim).

    ``circle``: the workspace is the disc (ball) of centre ``w0`` and radius ``w1[0]``;
    otherwise the box ``[w0, w1]``. ``gaps`` has ``inf`` on its diagonal. Discs (dim 2)
    or spheres (dim 3): sums over the axes run in axis order, so that in 2-D each sum is
    the planar code's ``x + y`` to the last bit.
    """
    n = b.shape[0]
    dim = b.shape[1]
    gamma = 0.0
    for i in range(n):
        sq = 0.0
        for a in range(dim):
            e = b[i, a] - d[i, a]
            sq += e * e
        gamma += 0.5 * sq
    g = np.zeros((n, dim))
    dist = np.zeros((n, n))
    inv = np.zeros((n, n))
    gaps = np.full((n, n), np.inf)
    log_beta = 0.0
    three = dim == 3
    for i in range(n):
        for j in range(i + 1, n):
            # scalars, not a loop over the axes: the hot loop of every flow (d = 2 or 3)
            d0 = b[i, 0] - b[j, 0]
            d1 = b[i, 1] - b[j, 1]
            d2 = b[i, 2] - b[j, 2] if three else 0.0
            sq = d0 * d0 + d1 * d1
            if three:
                sq += d2 * d2
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
            g[i, 0] += d0 * iv
            g[i, 1] += d1 * iv
            g[j, 0] -= d0 * iv
            g[j, 1] -= d1 * iv
            if three:
                g[i, 2] += d2 * iv
                g[j, 2] -= d2 * iv
    gb = np.zeros((n, dim))
    bgap = np.zeros(n)
    for i in range(n):
        if circle:
            rsq = 0.0
            for a in range(dim):
                rel = b[i, a] - w0[a]
                rsq += rel * rel
            rr = w1[0] - radii[i]
            w = 0.5 * (rr * rr - rsq)
            log_beta += math.log(w) if w > 0.0 else (-np.inf if w == 0.0 else np.nan)
            for a in range(dim):
                gb[i, a] = -(b[i, a] - w0[a]) / w
            bgap[i] = rr - math.sqrt(rsq)
        else:
            m = np.inf
            for a in range(dim):
                m = min(m, b[i, a] - w0[a] - radii[i], w1[a] - radii[i] - b[i, a])
            if m > 0.0:
                s = 0.0
                for a in range(dim):
                    s += math.log(b[i, a] - w0[a] - radii[i])
                    s += math.log(w1[a] - radii[i] - b[i, a])
                log_beta += s
            else:
                log_beta = -np.inf if m == 0.0 else np.nan
            for a in range(dim):
                gb[i, a] = 1.0 / (b[i, a] - w0[a] - radii[i]) - 1.0 / (w1[a] - radii[i] - b[i, a])
            bgap[i] = m
    log_gamma = math.log(gamma) if gamma > 0.0 else -np.inf
    c = gamma / k
    v = np.empty((n, dim))
    rep = np.empty((n, n))
    rep_bnd = np.empty(n)
    for i in range(n):
        sq = 0.0
        for a in range(dim):
            v[i, a] = (b[i, a] - d[i, a]) - c * (g[i, a] + gb[i, a])
            sq += gb[i, a] ** 2
        rep_bnd[i] = c * math.sqrt(sq)
        for j in range(n):
            rep[i, j] = c * dist[i, j] * abs(inv[i, j])
    return log_gamma, log_beta, v, rep, rep_bnd, gaps, bgap


@numba.njit(cache=True)
def hessian_kernel(
    b: Array, d: Array, radii: Array, circle: bool, w0: Array, w1: Array, k: float
) -> Array:
    """Hessian ``(dim n, dim n)`` of ``L = log gamma - log(beta) / k`` in one pass over the pairs.

    The formulas of :func:`navigation.hessian_log_w_numpy` (equations (3)-(5) and the
    boundary term differentiated twice): per pair ``x = b_i - b_j``,
    ``M = D_x^2 log beta_ij = I / beta_ij - x x^T / beta_ij^2`` enters ``+M`` on the
    ``ii`` and ``jj`` blocks and ``-M`` on the ``ij`` and ``ji`` blocks of
    ``D^2 log beta``; ``D^2 log gamma = I / gamma - e e^T / gamma^2``. Workspace as in
    :func:`nav_kernel`; any dimension.
    """
    n = b.shape[0]
    dim = b.shape[1]
    m = dim * n
    hb = np.zeros((m, m))  # D^2 log beta
    x = np.empty(dim)
    for i in range(n):
        for j in range(i + 1, n):
            sq = 0.0
            for a in range(dim):
                x[a] = b[i, a] - b[j, a]
                sq += x[a] * x[a]
            rs = radii[i] + radii[j]
            iv = 1.0 / (0.5 * (sq - rs * rs))
            iv2 = iv * iv
            p, q = dim * i, dim * j
            for a in range(dim):
                for c in range(dim):
                    # x[lo] x[hi]: the (a, c) and (c, a) entries are the same number
                    mac = -iv2 * x[min(a, c)] * x[max(a, c)]
                    if a == c:
                        mac = iv - iv2 * x[a] * x[a]
                    hb[p + a, p + c] += mac
                    hb[q + a, q + c] += mac
                    hb[p + a, q + c] = -mac
                    hb[q + a, p + c] = -mac
    for i in range(n):
        p = dim * i
        if circle:
            ysq = 0.0
            for a in range(dim):
                x[a] = b[i, a] - w0[a]
                ysq += x[a] * x[a]
            rr = w1[0] - radii[i]
            iw = 1.0 / (0.5 * (rr * rr - ysq))
            iw2 = iw * iw
            for a in range(dim):
                for c in range(dim):
                    if a == c:
                        hb[p + a, p + a] += -iw - iw2 * x[a] * x[a]
                    else:
                        hb[p + a, p + c] += -iw2 * x[min(a, c)] * x[max(a, c)]
        else:
            for axis in range(dim):
                t_lo = b[i, axis] - w0[axis] - radii[i]
                t_hi = w1[axis] - radii[i] - b[i, axis]
                hb[p + axis, p + axis] -= 1.0 / (t_lo * t_lo) + 1.0 / (t_hi * t_hi)
    e = np.empty(m)
    gamma = 0.0
    for i in range(n):
        sq = 0.0
        for a in range(dim):
            e[dim * i + a] = b[i, a] - d[i, a]
            sq += e[dim * i + a] * e[dim * i + a]
        gamma += 0.5 * sq
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
    checked by the caller at the end points). Any dimension.
    """
    n = b.shape[0]
    dim = b.shape[1]
    for i in range(n):
        for j in range(i + 1, n):
            gap = _pair_segment_gap(b, delta, radii, i, j, dim)
            if not gap >= fraction * gaps[i, j]:
                return False
    return True


@numba.njit(cache=True)
def _pair_segment_gap(b: Array, delta: Array, radii: Array, i: int, j: int, dim: int) -> float:
    """Smallest gap of discs i, j along ``b -> b + delta`` (both moving straight)."""
    dd = 0.0
    xd = 0.0
    for a in range(dim):
        da = delta[i, a] - delta[j, a]
        dd += da * da
        xd += (b[i, a] - b[j, a]) * da
    t = 0.0
    if dd > 0.0:
        t = min(max(-xd / dd, 0.0), 1.0)
    sq = 0.0
    for a in range(dim):
        ca = (b[i, a] - b[j, a]) + t * (delta[i, a] - delta[j, a])
        sq += ca * ca
    return math.sqrt(sq) - (radii[i] + radii[j])


@numba.njit(cache=True)
def path_pair_gap_kernel(path: Array, radii: Array) -> float:
    """Smallest pair gap along a path of configurations ``(m, n, dim)``, exactly.

    Between rows the configuration moves straight (every disc at once, linearly), so
    per segment and pair the closest approach is :func:`_pair_segment_gap`'s; ``inf``
    with fewer than two discs. (The boundary gap is concave along a segment in a convex
    workspace, so the rows bound it; the caller takes it there.)
    """
    m = path.shape[0]
    n = path.shape[1]
    dim = path.shape[2]
    best = np.inf
    delta = np.empty((n, dim))
    for s in range(max(m - 1, 1)):
        b = path[s]
        if m > 1:
            for i in range(n):
                for a in range(dim):
                    delta[i, a] = path[s + 1, i, a] - b[i, a]
        else:
            delta[:] = 0.0
        for i in range(n):
            for j in range(i + 1, n):
                gap = _pair_segment_gap(b, delta, radii, i, j, dim)
                if gap < best:
                    best = gap
    return best


@numba.njit(cache=True)
def segments_gap_kernel(P: Array, Q: Array, x: Array, radii: Array, i: int) -> Array:
    """Smallest gap to the standing discs while disc i moves straight ``P[s] -> Q[s]`` (S,).

    Per segment and standing disc j: the distance from ``x[j]`` to the segment (the
    closest point at ``t = clip((x_j - P).(Q - P) / |Q - P|^2, 0, 1)``, ``t = 0`` for a
    point segment) minus ``radii[j] + radii[i]``; ``inf`` with no other disc. The same
    operations, in the same order, as the numpy reference
    :func:`routes.segments_clearance_numpy`, without its ``(S, n)`` temporaries. Any
    dimension.
    """
    S = P.shape[0]
    n = x.shape[0]
    dim = x.shape[1]
    out = np.full(S, np.inf)
    sv = np.empty(dim)
    for s in range(S):
        length2 = 0.0
        for a in range(dim):
            sv[a] = Q[s, a] - P[s, a]
            length2 += sv[a] * sv[a]
        best = np.inf
        for j in range(n):
            if j == i:
                continue
            rs = 0.0
            for a in range(dim):
                rs += (x[j, a] - P[s, a]) * sv[a]
            t = 0.0
            if length2 > 0.0:
                t = min(max(rs / length2, 0.0), 1.0)
            sq = 0.0
            for a in range(dim):
                da = (x[j, a] - P[s, a]) - t * sv[a]
                sq += da * da
            gap = math.sqrt(sq) - radii[j] - radii[i]
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
    dim = delta.shape[1]
    m = np.empty(n)
    for i in range(n):
        sq = 0.0
        for a in range(dim):
            sq += delta[i, a] * delta[i, a]
        m[i] = math.sqrt(sq)
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
    dim = w.shape[1]
    s = 1.0 if stiff else 0.0
    speed = np.empty(n)
    for i in range(n):
        sq = 0.0
        for a in range(dim):
            sq += w[i, a] * w[i, a]
        speed[i] = math.sqrt(sq)
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
    dim = b.shape[1]
    stages = np.empty((4, n, dim))
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
            for j in range(dim):
                x = -(v[i, j] * mask[i, 0]) * 1.0
                if not np.isfinite(x):
                    return False, delta, evals
                stages[s + 1, i, j] = x
    delta = (dt / 6.0) * (stages[0] + 2.0 * stages[1] + 2.0 * stages[2] + stages[3])
    return triangle_safe_kernel(delta, gaps, bgap, fraction), delta, evals
