"""Swept-motion checks on the conservative free bitmaps (numba).

A move is allowed only if its straight C-space segment is free: the segment is cut into
pieces of at most one cell per axis and every cell in the box of each piece must be free
in the bitmap. Free cells of the conservative bitmaps (:func:`cellplan.cspace.free_bitmap`)
are free throughout their box, so a permitted motion is collision-free everywhere along
it, not only at its end point (docs/strategies.md, "Collision checks").
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cellplan.strategies.model.stencils import MAX_DIM, centre, displacement


@njit(cache=True)
def motion_ok(q, dq, free, grid, ibuf):  # pragma: no cover - numba
    """Swept check of the segment ``q -> q + dq`` against the bitmap ``free`` (1-D, flat).

    ``grid`` is the :class:`~.bundles.Grid` bundle (a plain, non-inlined call: its five
    arrays travel as five arguments, no reference is counted); ``ibuf`` is int scratch of
    length ``3 * MAX_DIM``.
    """
    shape = grid.shape
    lower = grid.lower
    upper = grid.upper
    spacing = grid.spacing
    periodic = grid.periodic
    d = shape.shape[0]
    nsub = 1
    for j in range(d):
        m = math.ceil(abs(dq[j]) / spacing[j] - 1e-9)
        if m > nsub:
            nsub = m
    lo_c = ibuf[:MAX_DIM]
    cnt = ibuf[MAX_DIM : 2 * MAX_DIM]
    cur = ibuf[2 * MAX_DIM :]
    for s in range(nsub):
        t0 = s / nsub
        t1 = (s + 1) / nsub
        total = 1
        for j in range(d):
            a = q[j] + t0 * dq[j]
            b = q[j] + t1 * dq[j]
            lo = min(a, b)
            hi = max(a, b)
            if not periodic[j]:
                if lo < lower[j] - 1e-9 or hi > upper[j] + 1e-9:
                    return False
            c0 = math.floor((lo - lower[j]) / spacing[j])
            c1 = math.floor((hi - lower[j]) / spacing[j])
            if not periodic[j]:
                c0 = min(max(c0, 0), shape[j] - 1)
                c1 = min(max(c1, 0), shape[j] - 1)
            lo_c[j] = c0
            cnt[j] = c1 - c0 + 1
            total *= cnt[j]
        for k in range(total):
            rem = k
            for j in range(d - 1, -1, -1):
                off = rem % cnt[j]
                rem //= cnt[j]
                ij = lo_c[j] + off
                if periodic[j]:
                    ij = ij % shape[j]
                cur[j] = ij
            flat = 0
            for j in range(d):
                flat = flat * shape[j] + cur[j]
            if not free[flat]:
                return False
    return True


@njit(cache=True)
def valid_moves(free, disp, heading_axis, grid):  # pragma: no cover - numba
    """Bitmask per cell of the actions whose swept motion from the cell centre is free.

    ``free`` is one class's bitmap (1-D), ``disp`` its ``(A, d)`` displacements.
    """
    shape = grid.shape
    d = shape.shape[0]
    ncell = free.shape[0]
    nact = disp.shape[0]
    out = np.zeros(ncell, np.int64)
    q = np.empty(d)
    dq = np.empty(d)
    mbuf = np.empty(3 * MAX_DIM, np.int64)
    for c in range(ncell):
        if not free[c]:
            continue
        centre(c, shape, grid.lower, grid.spacing, q)
        bits = 0
        for a in range(nact):
            displacement(q, disp[a], heading_axis, dq)
            if motion_ok(q, dq, free, grid, mbuf):
                bits |= 1 << a
        out[c] = bits
    return out
