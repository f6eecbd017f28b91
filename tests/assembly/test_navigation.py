"""The navigation function in log space: gradient vs finite differences, agreement with
the plain linear-space formulas where those do not underflow, and no underflow where they do."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cellplan.assembly.navigation import (
    evaluate,
    grad_linear,
    grad_log_phi,
    phi_linear,
)
from cellplan.assembly.problems import (
    BoxWorkspace,
    CircleWorkspace,
    DiscProblem,
    default_workspace,
    generate_problem,
    legality_problems,
)
from cellplan.assembly.section import GeneratorSpec


def _problem(seed: int, n: int, box: bool = False) -> DiscProblem:
    ws = (
        BoxWorkspace(np.array([-8.0, -8.0]), np.array([8.0, 8.0]))
        if box
        else CircleWorkspace(np.zeros(2), 8.0)
    )
    return generate_problem(GeneratorSpec(n=n, seed=seed, gap=0.3, min_start_gap=0.3), ws)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(2, 5),
    k=st.sampled_from([1.0, 2.0, 5.0, 12.0]),
    box=st.booleans(),
)
def test_gradient_matches_finite_differences(seed: int, n: int, k: float, box: bool) -> None:
    p = _problem(seed, n, box)
    b = p.start
    g = grad_log_phi(b, p, k)
    h = 1e-6
    fd = np.zeros_like(b)
    for i in range(n):
        for c in range(2):
            e = np.zeros_like(b)
            e[i, c] = h
            fd[i, c] = (evaluate(b + e, p, k).log_phi - evaluate(b - e, p, k).log_phi) / (2 * h)
    assert np.allclose(g, fd, rtol=1e-4, atol=1e-6 * max(1.0, float(np.abs(fd).max())))


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(2, 4),
    k=st.sampled_from([1.0, 2.0, 4.0]),
    box=st.booleans(),
)
def test_log_space_agrees_with_linear_space(seed: int, n: int, k: float, box: bool) -> None:
    p = _problem(seed, n, box)
    b = p.start
    ev = evaluate(b, p, k)
    lin_phi = phi_linear(b, p, k)
    lin_grad = grad_linear(b, p, k)
    assert lin_phi > 0 and np.all(np.isfinite(lin_grad)) and np.any(lin_grad != 0)
    assert np.isclose(np.exp(ev.log_phi), lin_phi, rtol=1e-10)
    assert np.allclose(
        np.exp(ev.log_scale) * ev.v, lin_grad, rtol=1e-8, atol=1e-12 * np.abs(lin_grad).max()
    )


def test_phi_is_zero_at_goal_and_tends_to_one_at_contact() -> None:
    p = _problem(3, 3)
    assert evaluate(p.goal, p, 4.0).log_phi == -np.inf
    direction = (p.goal[1] - p.goal[0]) / np.linalg.norm(p.goal[1] - p.goal[0])

    def log_phi(gap: float) -> float:
        b = p.goal.copy()
        b[1] = b[0] + direction * (2.0 + gap)
        return evaluate(b, p, 4.0).log_phi

    values = [log_phi(g) for g in (1e-2, 1e-6, 1e-12)]
    assert values[0] < values[1] < values[2] < 0
    assert values[2] > -1e-3


def test_log_space_survives_where_linear_space_underflows() -> None:
    # fifty packed discs: beta leaves the floating-point range (here it overflows), so the
    # plain formula breaks down; the log-space one is fine
    n = 50
    p = generate_problem(GeneratorSpec(n=n, seed=0, gap=0.01), default_workspace(n))
    b = p.goal + 1e-3 * np.random.default_rng(0).standard_normal((n, 2))
    assert not legality_problems(b, p.radii, p.workspace)
    assert np.all(grad_linear(b, p, 50.0) == 0) or not np.all(np.isfinite(grad_linear(b, p, 50.0)))
    ev = evaluate(b, p, 50.0)
    info = np.finfo(float)
    assert np.isfinite(ev.log_beta)
    assert ev.log_beta < np.log(info.tiny) or ev.log_beta > np.log(info.max)
    assert np.isfinite(ev.log_phi) and np.all(np.isfinite(ev.v))
    assert np.isfinite(ev.log_grad_norm)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 12),
    k=st.sampled_from([1.0, 8.0, 200.0]),
    box=st.booleans(),
)
def test_numba_kernel_matches_numpy_reference(seed: int, n: int, k: float, box: bool) -> None:
    from cellplan.assembly.navigation import evaluate_numpy

    p = (
        _problem(seed, n, box)
        if n <= 5
        else generate_problem(GeneratorSpec(n=n, seed=seed), default_workspace(n))
    )
    a, b = evaluate(p.start, p, k), evaluate_numpy(p.start, p, k)
    for name in ("log_gamma", "log_beta", "log_scale", "log_phi"):
        assert np.isclose(getattr(a, name), getattr(b, name), rtol=1e-11, atol=1e-11)
    for name in ("v", "rep", "rep_bnd", "gaps", "bgap"):
        assert np.allclose(getattr(a, name), getattr(b, name), rtol=1e-9, atol=1e-12)


@settings(max_examples=20, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(2, 5),
    k=st.sampled_from([2.0, 12.0, 64.0]),
    box=st.booleans(),
)
def test_hessian_matches_finite_differences(seed: int, n: int, k: float, box: bool) -> None:
    from cellplan.assembly.navigation import hessian_log_w

    p = _problem(seed, n, box)
    b = p.start

    def grad_l(x: np.ndarray) -> np.ndarray:  # grad L = v / gamma
        ev = evaluate(x.reshape(n, 2), p, k)
        return ev.v.reshape(-1) / np.exp(ev.log_gamma)

    h = 1e-6
    x = b.reshape(-1)
    fd = np.array([(grad_l(x + h * e) - grad_l(x - h * e)) / (2 * h) for e in np.eye(2 * n)])
    hess = hessian_log_w(b, p, k)
    assert np.allclose(hess, hess.T)
    assert np.allclose(hess, fd, rtol=1e-4, atol=1e-6 * max(1.0, float(np.abs(fd).max())))
