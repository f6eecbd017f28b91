"""The implicit step's eigen-decomposition: LAPACK ``eigh`` on one BLAS thread.

Until issue 13 a hand-written BLAS-free solver (Householder + implicit QR) served the
step; it is gone (``benchmarks/baseline_eigen.py`` keeps it as the benchmark's
baseline). These tests check the step against its documented formula, that BLAS threads
are limited only inside a run, and that whole runs give the results recorded with the
old solver.
"""

from __future__ import annotations

import numpy as np
import pytest

from cellplan.assembly import eigen
from cellplan.assembly.flows import critical_point_kind, gradient_flow, implicit_step
from cellplan.assembly.navigation import evaluate, hessian_log_w
from cellplan.assembly.problems import default_workspace, generate_problem
from cellplan.assembly.section import GeneratorSpec


def _orthogonal(rng: np.random.Generator, m: int) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((m, m)))
    return q * np.sign(np.diag(r))


def test_critical_point_kind_reads_the_smallest_eigenvalue() -> None:
    q = _orthogonal(np.random.default_rng(3), 6)
    assert critical_point_kind((q * np.array([0.02, 1, 2, 3, 4, 5.0])) @ q.T) == "spurious minimum"
    assert critical_point_kind((q * np.array([-0.02, 1, 2, 3, 4, 5.0])) @ q.T) == "saddle"


def test_implicit_step_is_the_documented_shifted_newton_step() -> None:
    """``delta = -(mu I + H_+)^-1 g``: the shortest grid ``mu`` whose step fits ``length``."""
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
        # independent of the step's own eigen-decomposition: a linear solve
        expected = -np.linalg.solve(mu * np.eye(10) + (q * lam_plus) @ q.T, g)
        np.testing.assert_allclose(delta, expected, rtol=1e-8, atol=1e-14)
        assert np.linalg.norm(delta) <= length * (1 + 1e-12)
        if mu > 1e-12:  # the grid point below mu would have given too long a step
            assert np.linalg.norm(gq / (mu / 10 ** (0.5 / 16) + lam_plus)) > length


def test_step_on_real_hessians_descends_and_respects_the_length() -> None:
    p = generate_problem(GeneratorSpec(n=15, seed=1, gap=0.1), default_workspace(15))
    near = p.goal + np.random.default_rng(1).uniform(-0.02, 0.02, p.goal.shape)
    for b in (p.start, near):
        ev = evaluate(b, p, 256.0)
        g = ev.v.reshape(-1) / np.exp(ev.log_gamma)
        hess = hessian_log_w(b, p, 256.0)
        for length in (1e-4, 0.05):
            delta = implicit_step(g, hess, length)
            assert np.linalg.norm(delta) <= length * (1 + 1e-12)
            assert float(g @ delta) < 0.0  # a descent direction of L


def test_blas_threads_are_limited_inside_a_run_only() -> None:
    from threadpoolctl import threadpool_info

    def blas_threads() -> list[int]:
        # numpy's BLAS, the one np.linalg.eigh calls (scipy's may be loaded too)
        return [
            lib["num_threads"]
            for lib in threadpool_info()
            if lib["user_api"] == "blas" and "numpy" in lib["filepath"]
        ]

    before = blas_threads()
    assert before
    with eigen.one_blas_thread():
        assert set(blas_threads()) == {1}
    assert blas_threads() == before


# Runs recorded with the previous BLAS-free solver (commit ab9b41a): status, steps and the
# path-length ratio. LAPACK's eigenvectors differ from it by rounding only, so the same
# runs must give the same steps and ratios to rounding (measured: 1e-12).
RECORDED = [
    (7, 0, 96.0, 517, 1.1959568331954609, 1),
    (7, 1, 96.0, 436, 1.1058558587321374, 1),
    (7, 2, 96.0, 458, 1.1580460948766584, 1),
    (15, 0, 256.0, 1413, 1.541738527936255, 3),  # stuck twice, solved at k=64
]


@pytest.mark.parametrize(("n", "seed", "k", "steps", "ratio", "stages"), RECORDED)
def test_eigh_gives_the_runs_of_the_old_solver(
    n: int, seed: int, k: float, steps: int, ratio: float, stages: int
) -> None:
    p = generate_problem(GeneratorSpec(n=n, seed=seed, gap=0.1), default_workspace(n))
    res = gradient_flow(p, k, escapes=6, escape="halve-k")
    assert res.status.value == "solved"
    assert (res.steps, len(res.stages)) == (steps, stages)
    got = res.length() / float(np.linalg.norm(p.start - p.goal))
    assert got == pytest.approx(ratio, rel=1e-9)
