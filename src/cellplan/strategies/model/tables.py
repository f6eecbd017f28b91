"""The move tables of the layered MDP: each move's stencil on the grid (Section IV).

A move from a cell centre lands between grid points; its value is the multilinear
interpolation of the values at the corners of the cell it lands in (the stencil).
"""

from __future__ import annotations

import numpy as np


def stencil_tables(
    disp: np.ndarray, heading_axis: int, shape: np.ndarray, lower: np.ndarray, spacing: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each move from a cell centre in cell units, split into integer and fractional parts.

    Robot-frame moves (``heading_axis >= 0``) get one entry per orientation slice.
    """
    K, A, dim = disp.shape
    if heading_axis >= 0:
        n_t = int(shape[heading_axis])
        theta = lower[heading_axis] + (np.arange(n_t) + 0.5) * spacing[heading_axis]
        ct, st = np.cos(theta), np.sin(theta)
        steps = np.broadcast_to(disp[:, :, None, :], (K, A, n_t, dim)).copy()
        steps[..., 0] = disp[:, :, None, 0] * ct - disp[:, :, None, 1] * st
        steps[..., 1] = disp[:, :, None, 0] * st + disp[:, :, None, 1] * ct
    else:
        steps = disp[:, :, None, :].copy()
    cells = steps / spacing
    offs = np.floor(cells)
    fr = cells - offs
    # Moves of a whole number of cells land on a centre; keep them exact.
    up = fr > 1.0 - 1e-9
    offs[up] += 1.0
    fr[up | (fr < 1e-9)] = 0.0
    return offs.astype(np.int64), np.ascontiguousarray(fr)


def table_rows(nact: np.ndarray, outcomes: int) -> np.ndarray:
    """Rows of the move tables each class uses: its ``A`` commanded moves, and with noise
    (``outcomes = J > 1``, Section VI-4) the ``A J`` noisy landings after them."""
    return nact if outcomes == 1 else nact * (1 + outcomes)


def corner_tables(
    offs: np.ndarray, fr: np.ndarray, rows: np.ndarray, shape: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat corner offsets and weights of every move stencil, and the cells where they apply.

    A cell is *interior* for a move class when every move's stencil, taken without
    clamping or wrapping, stays inside the grid; the kernels then skip the per-axis
    stencil arithmetic (the fast path of the sweeps).
    """
    K, A, T, dim = offs.shape
    strides = np.array([int(np.prod(shape[j + 1 :])) for j in range(dim)], np.int64)
    ncorner = 1 << dim
    coff = np.zeros((K, A, T, ncorner), np.int64)
    cw = np.ones((K, A, T, ncorner))
    for kk in range(ncorner):
        for j in range(dim):
            bit = (kk >> (dim - 1 - j)) & 1
            coff[..., kk] += (offs[..., j] + bit) * strides[j]
            cw[..., kk] *= fr[..., j] if bit else 1.0 - fr[..., j]
    # Largest weights first: the kernels stop at the first zero weight (a move along one
    # joint axis, for example, has 2 corners of 8 with weight).
    order = np.argsort(-cw, axis=-1, kind="stable")
    coff = np.ascontiguousarray(np.take_along_axis(coff, order, axis=-1))
    cw = np.ascontiguousarray(np.take_along_axis(cw, order, axis=-1))
    ncell = int(np.prod(shape))
    idx = np.indices(tuple(int(n) for n in shape)).reshape(dim, ncell)
    interior = np.zeros((K, ncell), np.bool_)
    for k in range(K):
        used = offs[k, : rows[k]]
        lo = used.min(axis=(0, 1))
        hi = used.max(axis=(0, 1)) + 1
        ok = np.ones(ncell, bool)
        for j in range(dim):
            ok &= (idx[j] + lo[j] >= 0) & (idx[j] + hi[j] <= shape[j] - 1)
        interior[k] = ok
    return coff, cw, interior
