"""The implicit step's eigen-decomposition: LAPACK ``eigh`` on one BLAS thread.

The implicit step of the flows needs, per step, the eigen-decomposition of the 2n x 2n
Hessian of L (docs/assembly.md, "The step"). LAPACK's ``eigh`` runs on OpenBLAS's
threads, which on a busy 2-core machine made a 100 x 100 call cost 7-20 ms instead of
about 1 ms; the flows therefore run inside :func:`one_blas_thread`
(``threadpoolctl``), which limits the BLAS libraries to one thread for the duration of
a run and restores them afterwards. (Until issue 13 a hand-written BLAS-free solver did
this job; ``benchmarks/bench_assembly.py --only-eigh`` times LAPACK against it in the
same process, docs/benchmarks.md.)
"""

from __future__ import annotations

import functools
import math
from contextlib import AbstractContextManager
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@functools.cache
def _controller() -> Any:
    # scanning the loaded libraries costs ~3 ms: once per process (numpy's OpenBLAS is
    # loaded by then; the flows call no other BLAS)
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def one_blas_thread() -> AbstractContextManager[Any]:
    """Context manager: BLAS/LAPACK on one thread inside, the previous setting after."""
    limiter: AbstractContextManager[Any] = _controller().limit(limits=1, user_api="blas")
    return limiter


def eigvalsh(h: Array) -> Array:
    """Eigenvalues (ascending) of a symmetric matrix (LAPACK, one BLAS thread)."""
    with one_blas_thread():
        lam = np.asarray(np.linalg.eigvalsh(h), dtype=np.float64)
    return lam


@numba.njit(cache=True)
def _step_lengths(gq: Array, lam: Array, mus: Array) -> Array:
    """``||(mu I + diag(lam))^-1 gq||`` for each ``mu`` in ``mus``."""
    out = np.empty(mus.shape[0])
    for j in range(mus.shape[0]):
        acc = 0.0
        for i in range(gq.shape[0]):
            t = gq[i] / (mus[j] + lam[i])
            acc += t * t
        out[j] = math.sqrt(acc)
    return out


@numba.njit(cache=True)
def shift_for_length(gq: Array, lam: Array, length: float) -> float:
    """The ``mu = 1/h`` of the implicit step: the first ``mu`` of a log grid with
    ``||(mu I + diag(lam))^-1 gq|| <= length``, refined once on a finer grid.

    ``lam >= 0``, so the length decreases with ``mu``: ``mu`` on the grid
    ``10^-12 .. 10^12`` (49 points); between the last point that is too long and the
    first that is not, 17 geometric points; ``10^12`` if none is short enough.
    """
    mus = np.empty(49)
    for i in range(49):
        mus[i] = 10.0 ** (-12.0 + 0.5 * i)
    mu = mus[48]
    for _ in range(2):
        lens = _step_lengths(gq, lam, mus)
        first = -1
        for j in range(mus.shape[0]):
            if lens[j] <= length:
                first = j
                break
        if first < 0:
            mu = mus[mus.shape[0] - 1]
            break
        mu = mus[first]
        if first == 0:
            break
        a = math.log10(mus[first - 1])
        b = math.log10(mus[first])
        step = (b - a) / 16.0
        fine = np.empty(17)
        for i in range(17):
            fine[i] = 10.0 ** (i * step + a)
        fine[0] = mus[first - 1]
        fine[16] = mus[first]
        mus = fine
    return mu
