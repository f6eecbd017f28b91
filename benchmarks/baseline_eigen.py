"""Benchmark baseline only: the BLAS-free symmetric eigensolver the implicit step used before
issue 13 (Householder + implicit QR/QL, no BLAS), kept to time LAPACK against it
(benchmarks/bench_assembly.py section 4). Not used by the library.

Original description: symmetric eigen-decomposition without BLAS, for the implicit step.

The implicit step of the flows needs, per step, the eigen-decomposition of the 2n x 2n
Hessian of L (docs/assembly.md, "The step"). LAPACK (numpy's or numba's ``eigh``) calls
the OpenBLAS that scipy ships, whose threads cost ~20 ms per 100 x 100 call on a busy
2-core machine (a 50-disc run: 83 s instead of 5.5 s with OPENBLAS_NUM_THREADS=1). The
kernels below use no BLAS: Householder reduction to tridiagonal form T = Q^T H Q, then
the implicit symmetric QR (or QL) algorithm with Wilkinson shifts on T (Golub & Van
Loan, Matrix Computations, Secs. 8.3.1 and 8.3.5). The step only needs the coordinates
of g in the eigenbasis and one vector back, so it applies the rotations to that vector
instead of accumulating the eigenvector matrix: O(n^2) after the O(n^3) reduction.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from cellplan.assembly.eigen import shift_for_length  # the same shift as the library step

Array = NDArray[np.float64]

_EPS = 2.220446049250313e-16  # float64 machine epsilon
_TINY = 2.2250738585072014e-308  # smallest normal float64
_SQ_LO, _SQ_HI = 1e-290, 1e290  # x^2 + z^2 safely representable: no scaling needed
_SWEEPS_PER_ROW = 30  # budget of QR/QL sweeps, 30 m in all (LAPACK's); about 2 m are used


@numba.njit(cache=True)
def tridiagonalize(h: Array) -> tuple[Array, Array, Array, Array]:
    """Householder reduction of a symmetric matrix: ``Q^T h Q = T`` tridiagonal.

    Parameters
    ----------
    h
        ``(m, m)`` symmetric; only its lower triangle is read.

    Returns
    -------
    d, e
        Diagonal ``(m,)`` and sub-diagonal ``(m - 1,)`` of ``T``.
    vs, tau
        ``Q = P_0 P_1 ... P_(m-3)`` with ``P_k = I - tau[k] v v^T``, ``v = vs[k]`` (zero
        in its first ``k + 1`` entries); ``tau[k] = 0`` where no reflection was needed.

    Notes
    -----
    Step k reflects column k below the sub-diagonal onto its first entry and updates
    the trailing block, ``P A P = A - v w^T - w v^T`` with ``p = tau A v``,
    ``w = p - (tau p.v / 2) v`` (Golub & Van Loan, Sec. 8.3.1); only the lower triangle
    is updated (4/3 m^3 flops in all), the inner loops are row operations. Each
    reflector is formed from its column divided by its largest entry, so entries of
    any size neither overflow nor underflow when squared.
    """
    m = h.shape[0]
    if h.ndim != 2 or h.shape[1] != m:
        raise ValueError("tridiagonalize needs a square matrix")
    for i in range(m):
        for j in range(m):
            if not np.isfinite(h[i, j]):
                raise ValueError("tridiagonalize needs a finite matrix")
    a = np.empty((m, m))
    a[:, :] = h
    d = np.empty(m)
    e = np.zeros(max(m - 1, 0))
    vs = np.zeros((m, m))
    tau = np.zeros(m)
    p = np.empty(m)
    for k in range(m - 2):
        lo = k + 1
        scale = 0.0
        for i in range(lo, m):
            scale = max(scale, abs(a[i, k]))
        if scale == 0.0:
            continue  # column already zero below the diagonal: e[k] = 0, no reflection
        tail = 0.0
        for i in range(lo + 1, m):
            x = a[i, k] / scale
            vs[k, i] = x
            tail += x * x
        if tail == 0.0:
            for i in range(lo + 1, m):
                vs[k, i] = 0.0
            e[k] = a[lo, k]  # already tridiagonal in this column
            continue
        x0 = a[lo, k] / scale
        alpha = -math.copysign(math.sqrt(x0 * x0 + tail), x0)
        v0 = x0 - alpha  # no cancellation: alpha has the sign opposite to x0
        vs[k, lo] = v0
        t = 2.0 / (v0 * v0 + tail)
        tau[k] = t
        e[k] = alpha * scale
        v = vs[k]
        # p = A22 v from the lower triangle: row i gives a[i, j] v[j] (j < i) to p[i]
        # and, by symmetry, a[i, j] v[i] to p[j]
        for i in range(lo, m):
            p[i] = 0.0
        for i in range(lo, m):
            vi = v[i]
            acc = 0.0
            for j in range(lo, i):
                aij = a[i, j]
                p[j] += vi * aij
                acc += aij * v[j]
            p[i] += acc + a[i, i] * vi
        pv = 0.0
        for i in range(lo, m):
            p[i] *= t
            pv += p[i] * v[i]
        half = 0.5 * t * pv
        for i in range(lo, m):
            p[i] -= half * v[i]  # p is now w
        for i in range(lo, m):
            vi = v[i]
            wi = p[i]
            for j in range(lo, i + 1):
                a[i, j] -= vi * p[j] + wi * v[j]
    for i in range(m):
        d[i] = a[i, i]
    if m >= 2:
        e[m - 2] = a[m - 1, m - 2]
    return d, e, vs, tau


@numba.njit(cache=True)
def apply_qt(vs: Array, tau: Array, y: Array) -> None:
    """``y <- Q^T y`` in place for the ``Q`` of :func:`tridiagonalize` (``y``: (m,) or (m, c))."""
    m = vs.shape[0]
    y2 = y.reshape(m, -1)
    for k in range(m - 2):
        if tau[k] != 0.0:
            _reflect_rows(vs[k], tau[k], k + 1, y2)


@numba.njit(cache=True)
def apply_q(vs: Array, tau: Array, y: Array) -> None:
    """``y <- Q y`` in place for the ``Q`` of :func:`tridiagonalize` (``y``: (m,) or (m, c))."""
    m = vs.shape[0]
    y2 = y.reshape(m, -1)
    for k in range(m - 3, -1, -1):
        if tau[k] != 0.0:
            _reflect_rows(vs[k], tau[k], k + 1, y2)


@numba.njit(cache=True)
def _reflect_rows(v: Array, t: float, lo: int, y: Array) -> None:
    """``y <- (I - t v v^T) y`` where ``v`` is zero before row ``lo``."""
    c = y.shape[1]
    r = np.zeros(c)
    for i in range(lo, y.shape[0]):
        vi = v[i]
        for j in range(c):
            r[j] += vi * y[i, j]
    for j in range(c):
        r[j] *= t
    for i in range(lo, y.shape[0]):
        vi = v[i]
        for j in range(c):
            y[i, j] -= vi * r[j]


@numba.njit(cache=True)
def _negligible(d: Array, e: Array, i: int) -> bool:
    """Whether ``e[i]`` is at rounding level of its two diagonal neighbours."""
    f = abs(e[i])
    return f <= _EPS * (abs(d[i]) + abs(d[i + 1])) or f < _TINY


@numba.njit(cache=True)
def _givens(x: float, z: float) -> tuple[float, float, float]:
    """``(c, s, r)`` with ``c x + s z = r`` and ``-s x + c z = 0``, ``c^2 + s^2 = 1``."""
    q2 = x * x + z * z
    if _SQ_LO < q2 < _SQ_HI:
        # math.hypot is slower; this chain of rotations is the serial part of the step
        r = math.sqrt(q2)
        inv = 1.0 / r
        return x * inv, z * inv, r
    if z == 0.0:
        return 1.0, 0.0, x
    if abs(z) > abs(x):
        t = x / z
        u = math.sqrt(1.0 + t * t)
        s = 1.0 / u
        return t * s, s, z * u
    t = z / x
    u = math.sqrt(1.0 + t * t)
    c = 1.0 / u
    return c, t * c, x * u


@numba.njit(cache=True)
def _wilkinson(a: float, b: float, f: float) -> float:
    """Eigenvalue of ``[[a, f], [f, b]]`` nearer to ``b`` (overflow-safe form)."""
    delta = 0.5 * (a - b)
    return b - f * (f / (delta + math.copysign(math.hypot(delta, f), delta)))


@numba.njit(cache=True)
def _rotate(d: Array, e: Array, k: int, j: int, c: float, s: float) -> None:
    """``T <- G^T T G`` on the 2 x 2 block of the coupled indices ``k, j = k +- 1``
    (``G`` maps ``e_k -> c e_k + s e_j``, ``e_j -> c e_j - s e_k``)."""
    ie = min(k, j)
    a0, b0, c0 = d[k], e[ie], d[j]
    cs = c * s
    d[k] = c * c * a0 + 2.0 * cs * b0 + s * s * c0
    d[j] = s * s * a0 - 2.0 * cs * b0 + c * c * c0
    e[ie] = (c * c - s * s) * b0 + cs * (c0 - a0)


@numba.njit(cache=True)
def _rotate_rows(rows: Array, k: int, j: int, c: float, s: float) -> None:
    """``rows <- G^T rows`` on rows ``k, j`` (``G`` as in :func:`_rotate`)."""
    for col in range(rows.shape[1]):
        u0 = rows[k, col]
        u1 = rows[j, col]
        rows[k, col] = c * u0 + s * u1
        rows[j, col] = c * u1 - s * u0


@numba.njit(cache=True)
def _reserve(rc: Array, rs: Array, rk: Array, count: int, need: int) -> tuple[Array, Array, Array]:
    """The rotation store with room for ``need`` more (doubling)."""
    if count + need <= rc.shape[0]:
        return rc, rs, rk
    cap = 2 * rc.shape[0] + need
    rc2 = np.empty(cap)
    rs2 = np.empty(cap)
    rk2 = np.empty(cap, dtype=np.int64)
    rc2[:count] = rc[:count]
    rs2[:count] = rs[:count]
    rk2[:count] = rk[:count]
    return rc2, rs2, rk2


@numba.njit(cache=True)
def tridiagonal_qr(
    d: Array, e: Array, rows: Array, record: bool
) -> tuple[Array, Array, Array, int]:
    """Eigenvalues of a symmetric tridiagonal ``T`` by implicit QR/QL with Wilkinson shifts.

    ``T = Z diag(d_out) Z^T`` with ``Z = G_1 G_2 ... G_r`` a product of Givens rotations.

    Parameters
    ----------
    d, e
        Diagonal ``(m,)`` and sub-diagonal ``(m - 1,)``; overwritten: ``d`` by the
        eigenvalues (unsorted), ``e`` by zeros.
    rows
        ``(m, c)``: overwritten by ``Z^T rows`` (``c = 0`` for eigenvalues alone). With
        ``rows = Q^T`` it ends as the transposed eigenvector matrix of ``Q T Q^T``; with
        one column ``Q^T g``, as the coordinates of ``g`` in the eigenbasis.
    record
        Also return the rotations, so that ``Z x`` can be formed later
        (:func:`apply_rotations`) without storing ``Z``.

    Returns
    -------
    rc, rs, rk, count
        Rotation ``i < count`` acts on coordinates ``rk[i], rk[i] + 1`` with cosine
        ``rc[i]`` and sine ``rs[i]`` (empty unless ``record``).

    Notes
    -----
    The matrix splits where a sub-diagonal entry is negligible (``|e_i| <= eps (|d_i| +
    |d_(i+1)|)``, then set to 0). Each unreduced block is iterated on until it has
    split into 1 x 1 blocks. A sweep shifts by the eigenvalue of the 2 x 2 at the
    deflating end that is nearer to its corner entry (Wilkinson's shift: cubically and
    globally convergent for symmetric tridiagonal matrices), starts with the rotation
    of the shifted column at the other end (implicit Q theorem) and chases the bulge
    back (Golub & Van Loan, Sec. 8.3.5). As in LAPACK's ``dsteqr``, the direction is
    chosen per block so that the chase starts at the end with the larger diagonal
    entry: QR (deflating at the bottom) when the top is larger, QL otherwise. Started
    at the small end, rotations of a strongly graded matrix (1e-150 .. 1e150) underflow
    to the identity and the iteration stalls.
    """
    m = d.shape[0]
    cap = 2 * m * m + 16 if record else 1  # about 1.2 m^2 rotations are used
    rc = np.empty(cap)
    rs = np.empty(cap)
    rk = np.empty(cap, dtype=np.int64)
    count = 0
    sweeps = 0
    start = 0
    while start < m - 1:
        if _negligible(d, e, start):
            e[start] = 0.0
            start += 1
            continue
        end = start + 1
        while end < m - 1 and not _negligible(d, e, end):
            end += 1
        if end < m - 1:
            e[end] = 0.0
        # unreduced block start..end
        if abs(d[end]) < abs(d[start]):
            # QR: shift from the bottom 2 x 2, chase from the top, deflate at the bottom
            hi = end
            while hi > start:
                lo = hi
                while lo > start and not _negligible(d, e, lo - 1):
                    lo -= 1
                if lo == hi:
                    e[hi - 1] = 0.0
                    hi -= 1
                    continue
                if lo > start:
                    e[lo - 1] = 0.0
                sweeps += 1
                if sweeps > _SWEEPS_PER_ROW * m:
                    raise ValueError("tridiagonal QR did not converge")
                if record:
                    rc, rs, rk = _reserve(rc, rs, rk, count, hi - lo)
                x = d[lo] - _wilkinson(d[hi - 1], d[hi], e[hi - 1])
                z = e[lo]
                for k in range(lo, hi):
                    c, s, r = _givens(x, z)
                    if k > lo:
                        e[k - 1] = r  # the bulge at (k-1, k+1) rotated into (k-1, k)
                    _rotate(d, e, k, k + 1, c, s)
                    if k < hi - 1:
                        x = e[k]
                        z = s * e[k + 1]  # the new bulge at (k, k+2)
                        e[k + 1] *= c
                    _rotate_rows(rows, k, k + 1, c, s)
                    if record:
                        rc[count] = c
                        rs[count] = s
                        rk[count] = k
                        count += 1
        else:
            # QL: the mirror image (shift from the top, chase from the bottom)
            lo = start
            while lo < end:
                hi = lo
                while hi < end and not _negligible(d, e, hi):
                    hi += 1
                if hi == lo:
                    e[lo] = 0.0
                    lo += 1
                    continue
                if hi < end:
                    e[hi] = 0.0
                sweeps += 1
                if sweeps > _SWEEPS_PER_ROW * m:
                    raise ValueError("tridiagonal QL did not converge")
                if record:
                    rc, rs, rk = _reserve(rc, rs, rk, count, hi - lo)
                x = d[hi] - _wilkinson(d[lo + 1], d[lo], e[lo])
                z = e[hi - 1]
                for k in range(hi, lo, -1):
                    c, s, r = _givens(x, z)
                    if k < hi:
                        e[k] = r  # the bulge at (k+1, k-1) rotated into (k+1, k)
                    _rotate(d, e, k, k - 1, c, s)
                    if k > lo + 1:
                        x = e[k - 1]
                        z = s * e[k - 2]  # the new bulge at (k, k-2)
                        e[k - 2] *= c
                    _rotate_rows(rows, k, k - 1, c, s)
                    if record:
                        # as a rotation of (k-1, k) in the QR convention: (c, -s)
                        rc[count] = c
                        rs[count] = -s
                        rk[count] = k - 1
                        count += 1
        start = end + 1
    return rc, rs, rk, count


@numba.njit(cache=True)
def apply_rotations(rc: Array, rs: Array, rk: Array, count: int, x: Array) -> None:
    """``x <- Z x`` in place for the rotations recorded by :func:`tridiagonal_qr`."""
    for i in range(count - 1, -1, -1):
        k = rk[i]
        c = rc[i]
        s = rs[i]
        u0 = x[k]
        u1 = x[k + 1]
        x[k] = c * u0 - s * u1
        x[k + 1] = s * u0 + c * u1


@numba.njit(cache=True)
def sym_eigh(h: Array) -> tuple[Array, Array]:
    """Eigenvalues (ascending) and orthonormal eigenvectors of a symmetric matrix, no BLAS.

    Same contract as ``np.linalg.eigh``: ``h @ q[:, i] = lam[i] q[:, i]``. Written out
    (:func:`tridiagonalize`, :func:`tridiagonal_qr`) because the LAPACK routine behind
    ``eigh`` runs on OpenBLAS threads, whose cost on a loaded machine is unpredictable
    (20 ms instead of 1 ms for 100 x 100); this kernel runs on the calling thread.
    """
    m = h.shape[0]
    d, e, vs, tau = tridiagonalize(h)
    w = np.eye(m)
    apply_qt(vs, tau, w)  # w = Q^T; its rows become the eigenvectors
    tridiagonal_qr(d, e, w, False)
    order = np.argsort(d)
    q = np.empty((m, m))
    for jj in range(m):
        src = order[jj]
        for i in range(m):
            q[i, jj] = w[src, i]
    return d[order], q


@numba.njit(cache=True)
def sym_eigvalsh(h: Array) -> Array:
    """Eigenvalues (ascending) of a symmetric matrix, no BLAS (see :func:`sym_eigh`)."""
    d, e, _, _ = tridiagonalize(h)
    tridiagonal_qr(d, e, np.empty((d.shape[0], 0)), False)
    return np.sort(d)


@numba.njit(cache=True)
def sym_eigh_lapack(h: Array) -> tuple[Array, Array]:
    """numba's LAPACK ``eigh`` (the previous implementation; benchmark and test baseline)."""
    return np.linalg.eigh(h)


@numba.njit(cache=True)
def implicit_step_kernel(g: Array, hess: Array, length: float) -> Array:
    """``-(mu I + H_+)^-1 g`` with ``mu`` from :func:`shift_for_length` (see
    :func:`cellplan.assembly.flows.implicit_step`).

    ``H = Q Z diag(lam) Z^T Q^T`` (:func:`tridiagonalize`, :func:`tridiagonal_qr`);
    ``H_+`` keeps the eigenvectors and replaces ``lam`` by ``max(lam, 0)``. Only the
    coordinates ``Z^T Q^T g`` are formed, by applying the reflections and rotations to
    ``g``, and the step is carried back by the same rotations in reverse: no ``n x n``
    eigenvector matrix and no BLAS call.
    """
    m = g.shape[0]
    if hess.shape[0] != m:
        raise ValueError("implicit_step_kernel: g and hess sizes differ")
    d, e, vs, tau = tridiagonalize(hess)
    y = np.empty((m, 1))
    y[:, 0] = g
    apply_qt(vs, tau, y)
    rc, rs, rk, count = tridiagonal_qr(d, e, y, True)
    lam = np.maximum(d, 0.0)
    gq = y[:, 0].copy()
    mu = shift_for_length(gq, lam, length)
    x = np.empty(m)
    for i in range(m):
        x[i] = -gq[i] / (mu + lam[i])
    apply_rotations(rc, rs, rk, count, x)
    apply_q(vs, tau, x)
    return x
