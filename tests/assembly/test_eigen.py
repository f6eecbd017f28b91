"""The BLAS-free symmetric eigensolver of the implicit step, against LAPACK.

``eigen.sym_eigh`` (Householder tridiagonalisation + implicit QR with Wilkinson shifts)
replaces LAPACK's ``eigh`` in the implicit step, whose OpenBLAS threads made its cost
depend on the machine's load. Accuracy is that of a backward-stable solver: errors
relative to ``||H||`` (a graded matrix's small eigenvalues are not relatively accurate in
either solver).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellplan.assembly import eigen
from cellplan.assembly.flows import critical_point_kind, implicit_step
from cellplan.assembly.navigation import evaluate, hessian_log_w
from cellplan.assembly.problems import DiscProblem, default_workspace, generate_problem
from cellplan.assembly.section import GeneratorSpec

KINDS = ("general", "repeated", "diagonal", "rank_deficient", "scaled", "graded", "zero")


def _orthogonal(rng: np.random.Generator, m: int) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((m, m)))
    return q * np.sign(np.diag(r))


def _matrix(kind: str, m: int, seed: int, exponent: float) -> np.ndarray:
    """A symmetric test matrix of the given kind; ``exponent`` in [-12, 12] sets scales."""
    rng = np.random.default_rng(seed)
    if kind == "repeated":
        # eigenvalues drawn from 3 values: clusters of exactly repeated eigenvalues
        lam = rng.choice(rng.standard_normal(3), size=m)
        q = _orthogonal(rng, m)
        h = (q * lam) @ q.T
    elif kind == "diagonal":
        h = np.diag(rng.standard_normal(m) * 10.0 ** rng.uniform(-3, 3, m))
    elif kind == "rank_deficient":
        b = rng.standard_normal((m, rng.integers(0, m)))
        h = b @ b.T - 0.5 * (b[:, :1] @ b[:, :1].T if b.shape[1] else 0.0)
    elif kind == "scaled":
        h = rng.standard_normal((m, m)) * 10.0**exponent
    elif kind == "graded":
        # entries from about 1e-12 to 1e12
        s = 10.0 ** rng.uniform(-6, 6, m)
        h = s[:, None] * rng.standard_normal((m, m)) * s[None, :]
    elif kind == "zero":
        h = np.zeros((m, m))
    else:
        h = rng.standard_normal((m, m))
    return np.ascontiguousarray(0.5 * (h + h.T))


matrices = st.builds(
    _matrix,
    st.sampled_from(KINDS),
    st.integers(1, 40),
    st.integers(0, 2**32 - 1),
    st.floats(-12.0, 12.0),
)


@settings(max_examples=250, deadline=None)
@given(matrices)
def test_sym_eigh_matches_lapack(h: np.ndarray) -> None:
    m = h.shape[0]
    lam, q = eigen.sym_eigh(h)
    ref = np.linalg.eigh(h)[0]
    scale = max(float(np.linalg.norm(h, 2)), np.finfo(float).tiny)
    assert np.all(np.diff(lam) >= 0.0)
    assert np.max(np.abs(lam - ref)) <= 1e-12 * scale
    assert np.linalg.norm(h @ q - q * lam) <= 1e-12 * scale
    assert np.linalg.norm(q.T @ q - np.eye(m)) <= 1e-12
    # eigenvalues alone (the stall classification) are the same numbers
    np.testing.assert_array_equal(eigen.sym_eigvalsh(h), lam)


@settings(max_examples=60, deadline=None)
@given(matrices)
def test_tridiagonal_factors_reconstruct_the_matrix(h: np.ndarray) -> None:
    """``Q T Q^T = H`` from the reflections, ``Z diag(lam) Z^T = T`` from the rotations."""
    m = h.shape[0]
    d, e, vs, tau = eigen.tridiagonalize(h)
    q = np.eye(m)
    eigen.apply_q(vs, tau, q)
    t = np.diag(d) + np.diag(e, 1) + np.diag(e, -1)
    scale = max(float(np.linalg.norm(h, 2)), np.finfo(float).tiny)
    assert np.linalg.norm(q @ t @ q.T - h) <= 1e-12 * scale
    lam = d.copy()
    rc, rs, rk, count = eigen.tridiagonal_qr(lam, e.copy(), np.empty((m, 0)), True)
    z = np.eye(m)
    for j in range(m):
        col = z[:, j].copy()
        eigen.apply_rotations(rc, rs, rk, count, col)
        z[:, j] = col
    assert np.linalg.norm((z * lam) @ z.T - t) <= 1e-12 * scale
    assert np.linalg.norm(z.T @ z - np.eye(m)) <= 1e-12


def test_non_finite_matrix_is_refused() -> None:
    h = np.eye(3)
    h[1, 2] = h[2, 1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        eigen.sym_eigh(h)


def test_critical_point_kind_reads_the_smallest_eigenvalue() -> None:
    q = _orthogonal(np.random.default_rng(3), 6)
    assert critical_point_kind((q * np.array([0.02, 1, 2, 3, 4, 5.0])) @ q.T) == "spurious minimum"
    assert critical_point_kind((q * np.array([-0.02, 1, 2, 3, 4, 5.0])) @ q.T) == "saddle"


def _states(n: int, seed: int) -> list[tuple[DiscProblem, np.ndarray]]:
    """A random legal start and a near-contact state (the packed goal, perturbed)."""
    p = generate_problem(GeneratorSpec(n=n, seed=seed, gap=0.1), default_workspace(n))
    rng = np.random.default_rng(seed)
    near = p.goal + rng.uniform(-0.02, 0.02, p.goal.shape)
    return [(p, p.start), (p, near)]


@pytest.mark.parametrize("n", [7, 15])
def test_implicit_step_equals_the_lapack_step_on_real_hessians(n: int) -> None:
    checked = 0
    for seed in range(4):
        for p, b in _states(n, seed):
            for k in (32.0, 256.0):
                ev = evaluate(b, p, k)
                g = ev.v.reshape(-1) / np.exp(ev.log_gamma)
                hess = hessian_log_w(b, p, k)
                for length in (1e-4, 3e-3, 0.05, 1.0):
                    new = implicit_step(g, hess, length)
                    old = implicit_step(g, hess, length, lapack=True)
                    assert np.linalg.norm(new - old) <= 1e-9 * np.linalg.norm(old)
                    assert np.linalg.norm(new) <= length * (1 + 1e-12)
                    checked += 1
                # one disc alone (the low-level flow's 2 x 2 block)
                sel = np.array([0, 1])
                sub = hess[np.ix_(sel, sel)]
                np.testing.assert_allclose(
                    implicit_step(g[sel], sub, 0.01),
                    implicit_step(g[sel], sub, 0.01, lapack=True),
                    rtol=1e-9,
                    atol=0.0,
                )
    assert checked == 4 * 2 * 2 * 4


def test_implicit_step_is_the_documented_shifted_newton_step() -> None:
    """``delta = -(mu I + H_+)^-1 g`` for the ``mu`` of the step-length rule."""
    rng = np.random.default_rng(5)
    q = _orthogonal(rng, 10)
    lam = np.array([-3.0, -0.1, 0.0, 1e-3, 0.5, 1, 2, 10, 1e3, 1e4])
    h = (q * lam) @ q.T
    g = rng.standard_normal(10)
    gq = q.T @ g
    lam_plus = np.maximum(lam, 0.0)
    for length in (1e-6, 1e-2, 0.3, 3.0):
        delta = implicit_step(g, h, length)
        mu = eigen.shift_for_length(np.ascontiguousarray(gq), lam_plus, length)
        np.testing.assert_allclose(delta, -q @ (gq / (mu + lam_plus)), rtol=1e-9, atol=0.0)
        assert np.linalg.norm(delta) <= length * (1 + 1e-12)
        if mu > 1e-12:  # the grid step below mu would have been too long
            assert np.linalg.norm(gq / (mu / 10 ** (0.5 / 16) + lam_plus)) > length


@pytest.mark.parametrize("m", [21, 100])
@pytest.mark.parametrize("reverse", [False, True])
def test_strongly_graded_tridiagonal_converges(m: int, reverse: bool) -> None:
    """Diagonal 1e-150 .. 1e150: the sweep must start at the large end (QR or QL), and
    such a block needs more sweeps than a per-eigenvalue cap of 60 allowed."""
    d = 10.0 ** np.linspace(-150, 150, m)
    e = 10.0 ** np.linspace(-150, 149, m - 1)
    h = np.diag(d) + np.diag(e, 1) + np.diag(e, -1)
    if reverse:
        h = np.ascontiguousarray(h[::-1, ::-1])
    lam, q = eigen.sym_eigh(h)
    scale = float(np.linalg.norm(h, 2))
    assert np.max(np.abs(lam - np.linalg.eigvalsh(h))) <= 1e-12 * scale
    assert np.linalg.norm(h @ q - q * lam) <= 1e-12 * scale
    assert np.linalg.norm(q.T @ q - np.eye(m)) <= 1e-12
