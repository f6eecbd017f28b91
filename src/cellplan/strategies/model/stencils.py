"""Numba helpers for a uniform grid of cell centres: indices, stencils, sweep orders.

Shared by every kernel module of the strategies solver (sweeps, Bellman, evaluation,
point queries). Cells are flat C-order indices;
the multilinear stencil of a point is the ``2^d`` surrounding cell centres with their
weights (Section IV-B of the strategies paper).
"""

from __future__ import annotations

import math

from numba import njit

MAX_DIM = 6
# Corner weights at or below this are treated as zero.
EPS_W = 1e-12


@njit(cache=True, inline="always")
def decode(c, shape, out):  # pragma: no cover - numba
    """Multi-index of flat C-order index ``c``."""
    d = shape.shape[0]
    for j in range(d - 1, -1, -1):
        out[j] = c % shape[j]
        c //= shape[j]


@njit(cache=True, inline="always")
def centre(c, shape, lower, spacing, out):  # pragma: no cover - numba
    """Configuration at the centre of cell ``c``."""
    d = shape.shape[0]
    for j in range(d - 1, -1, -1):
        i = c % shape[j]
        c //= shape[j]
        out[j] = lower[j] + (i + 0.5) * spacing[j]


@njit(cache=True, inline="always")
def displacement(q, disp_a, heading_axis, out):  # pragma: no cover - numba
    """The C-space displacement of an action from ``q`` (robot-frame for a heading axis)."""
    d = q.shape[0]
    for j in range(d):
        out[j] = disp_a[j]
    if heading_axis >= 0:
        ct = math.cos(q[heading_axis])
        st = math.sin(q[heading_axis])
        out[0] = disp_a[0] * ct - disp_a[1] * st
        out[1] = disp_a[0] * st + disp_a[1] * ct


@njit(cache=True, inline="always")
def wrap(q, lower, upper, periodic):  # pragma: no cover - numba
    """Bring periodic coordinates back into ``[lower, upper)``, in place."""
    for j in range(q.shape[0]):
        if periodic[j]:
            span = upper[j] - lower[j]
            q[j] = lower[j] + (q[j] - lower[j]) % span


@njit(cache=True)
def stencil(q, grid, idx, w, ibuf, frac):  # pragma: no cover - numba
    """Multilinear stencil of ``q``: ``2^d`` flat indices and weights (some may be 0).

    ``grid`` is the :class:`~.bundles.Grid` bundle; ``ibuf`` (int, ``2 * MAX_DIM``) and
    ``frac`` (float, ``MAX_DIM``) are scratch space.
    """
    shape = grid.shape
    lower = grid.lower
    spacing = grid.spacing
    periodic = grid.periodic
    d = shape.shape[0]
    base = ibuf[:MAX_DIM]
    nxt = ibuf[MAX_DIM:]
    for j in range(d):
        f = (q[j] - lower[j]) / spacing[j] - 0.5
        i0 = math.floor(f)
        t = f - i0
        n = shape[j]
        if periodic[j]:
            i0 = i0 % n
            base[j] = i0
            nxt[j] = (i0 + 1) % n
            frac[j] = t
        else:
            if i0 < 0:
                i0 = 0
                t = 0.0
            elif i0 >= n - 1:
                i0 = n - 1
                t = 0.0
            base[j] = i0
            nxt[j] = min(i0 + 1, n - 1)
            frac[j] = t
    ncorner = 1 << d
    for k in range(ncorner):
        flat = 0
        wk = 1.0
        for j in range(d):
            if (k >> (d - 1 - j)) & 1:
                ij = nxt[j]
                wk *= frac[j]
            else:
                ij = base[j]
                wk *= 1.0 - frac[j]
            flat = flat * shape[j] + ij
        idx[k] = flat
        w[k] = wk
    return ncorner


@njit(cache=True, inline="always")
def cell_of_order(k, shape, flips, mi):  # pragma: no cover - numba
    """Flat index (and multi-index ``mi``) of the k-th cell in a sweep with flipped axes."""
    d = shape.shape[0]
    rem = k
    for j in range(d - 1, -1, -1):
        ij = rem % shape[j]
        rem //= shape[j]
        if (flips >> j) & 1:
            ij = shape[j] - 1 - ij
        mi[j] = ij
    flat = 0
    for j in range(d):
        flat = flat * shape[j] + mi[j]
    return flat


@njit(cache=True, inline="always")
def cell_containing(q, shape, lower, spacing, periodic):  # pragma: no cover - numba
    """Flat index of the grid cell containing configuration ``q`` (clamped at the border)."""
    c = 0
    for j in range(shape.shape[0]):
        i = int(math.floor((q[j] - lower[j]) / spacing[j]))
        if periodic[j]:
            i = i % shape[j]
        else:
            i = min(max(i, 0), shape[j] - 1)
        c = c * shape[j] + i
    return c


@njit(cache=True, inline="always")
def first_of_order(shape, flips, mi):  # pragma: no cover - numba
    """Set ``mi`` to the first cell of a sweep with flipped axes; returns its flat index."""
    flat = 0
    for j in range(shape.shape[0]):
        mi[j] = shape[j] - 1 if (flips >> j) & 1 else 0
        flat = flat * shape[j] + mi[j]
    return flat


@njit(cache=True, inline="always")
def first_of_rows(shape, flips, rows, mi):  # pragma: no cover - numba
    """:func:`first_of_order` of the cells whose first index is in ``rows = (start, stop)``."""
    first_of_order(shape, flips, mi)
    mi[0] = rows[1] - 1 if flips & 1 else rows[0]
    flat = 0
    for j in range(shape.shape[0]):
        flat = flat * shape[j] + mi[j]
    return flat


@njit(cache=True, inline="always")
def next_of_order(shape, flips, mi):  # pragma: no cover - numba
    """Step ``mi`` to the next cell of the sweep (an odometer, no division); its flat index."""
    for j in range(shape.shape[0] - 1, -1, -1):
        if (flips >> j) & 1:
            if mi[j] > 0:
                mi[j] -= 1
                break
            mi[j] = shape[j] - 1
        else:
            if mi[j] < shape[j] - 1:
                mi[j] += 1
                break
            mi[j] = 0
    flat = 0
    for j in range(shape.shape[0]):
        flat = flat * shape[j] + mi[j]
    return flat


@njit(cache=True, inline="always")
def table_stencil(moves, grid, k, a, mi, idx, w):  # pragma: no cover - numba
    """Stencil of move ``a`` of class ``k`` from the centre of cell ``mi`` (precomputed offsets).

    From a cell centre the landing point of a move is ``mi + offs + fr`` in cell
    coordinates (``moves.offs``, ``moves.fr``), the same for every cell (per orientation
    slice for robot-frame moves), so the multilinear stencil needs no floating-point
    division. ``moves`` and ``grid`` are the bundles of :mod:`.bundles`.
    """
    offs = moves.offs
    fr = moves.fr
    heading_axis = moves.heading_axis
    shape = grid.shape
    periodic = grid.periodic
    d = shape.shape[0]
    t = mi[heading_axis] if heading_axis >= 0 else 0
    ncorner = 1 << d
    for kk in range(ncorner):
        idx[kk] = 0
        w[kk] = 1.0
    for j in range(d):
        n = shape[j]
        i0 = mi[j] + offs[k, a, t, j]
        f = fr[k, a, t, j]
        if periodic[j]:
            i0 = i0 % n
            i1 = (i0 + 1) % n
        else:
            if i0 < 0:
                i0 = 0
                f = 0.0
            elif i0 >= n - 1:
                i0 = n - 1
                f = 0.0
            i1 = min(i0 + 1, n - 1)
        for kk in range(ncorner):
            if (kk >> (d - 1 - j)) & 1:
                idx[kk] = idx[kk] * n + i1
                w[kk] *= f
            else:
                idx[kk] = idx[kk] * n + i0
                w[kk] *= 1.0 - f
    return ncorner


# Action codes of a policy: a move ``a >= 0``, stay -1, FMP (its first option) -2, a state
# outside the MDP -3, and FMP option ``j >= 1`` of the mode (simultaneous requests,
# Section VI-2: which open request a pick serves) ``-3 - j``.
STAY_CODE = -1
FMP_CODE = -2
OUTSIDE_CODE = -3
# What an online query (:func:`.points.query`) returns where no action is available, and
# where the configuration is not finite.
NO_ACTION_CODE = -9
NOT_FINITE_CODE = -10


@njit(cache=True, inline="always")
def fmp_code(j):  # pragma: no cover - numba
    """The action code of FMP option ``j`` (0-based within its mode)."""
    return FMP_CODE if j == 0 else OUTSIDE_CODE - j


@njit(cache=True, inline="always")
def fmp_option(code):  # pragma: no cover - numba
    """The option ``j`` of an FMP action code, -1 for any other code."""
    if code == FMP_CODE:
        return 0
    if code < OUTSIDE_CODE:
        return OUTSIDE_CODE - code
    return -1
