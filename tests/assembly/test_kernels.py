"""The numba kernels of the implicit flow and the place rule against their numpy references.

Each kernel (:mod:`cellplan.assembly.kernels`) replaces a vectorised numpy function that
stays as its reference: the Hessian of ``L`` (:func:`navigation.hessian_log_w_numpy`),
the exact segment test of a step (:func:`flows.segment_is_safe_numpy`) and the segment
clearances of the place rule's routes (:func:`routes.segments_clearance_numpy`). The last
two decide accept / reject and route choices, so they must agree exactly, not only to a
tolerance.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellplan.assembly.flows import segment_is_safe, segment_is_safe_numpy
from cellplan.assembly.navigation import clearances, hessian_log_w, hessian_log_w_numpy
from cellplan.assembly.problems import (
    BoxWorkspace,
    DiscProblem,
    default_workspace,
    generate_problem,
)
from cellplan.assembly.routes import segments_clearance, segments_clearance_numpy
from cellplan.assembly.section import GeneratorSpec


def _problem(seed: int, n: int, box: bool) -> DiscProblem:
    if box:
        ws = BoxWorkspace(np.array([-9.0, -9.0]), np.array([9.0, 9.0]))
        return generate_problem(GeneratorSpec(n=n, seed=seed, gap=0.1, min_start_gap=0.05), ws)
    return generate_problem(GeneratorSpec(n=n, seed=seed, gap=0.01), default_workspace(n))


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 14),
    k=st.sampled_from([1.0, 16.0, 500.0]),
    box=st.booleans(),
)
def test_hessian_kernel_matches_numpy_reference(seed: int, n: int, k: float, box: bool) -> None:
    p = _problem(seed, n, box)
    for b in (p.start, 0.5 * (p.start + p.goal)):
        if np.min(np.concatenate([x.ravel() for x in clearances(b, p.radii, p.workspace)])) <= 0:
            continue
        fast, ref = hessian_log_w(b, p, k), hessian_log_w_numpy(b, p, k)
        assert fast.shape == (2 * n, 2 * n)
        np.testing.assert_allclose(fast, ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())
        np.testing.assert_array_equal(fast, fast.T)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 12),
    scale=st.floats(1e-3, 4.0),
    box=st.booleans(),
)
def test_segment_kernel_decides_exactly_as_numpy(
    seed: int, n: int, scale: float, box: bool
) -> None:
    p = _problem(seed, n, box)
    rng = np.random.default_rng(seed)
    b = p.start
    gaps, bgap = clearances(b, p.radii, p.workspace)
    for _ in range(5):
        delta = scale * rng.normal(size=b.shape)
        new_bgap = clearances(b + delta, p.radii, p.workspace)[1]
        args = (b, delta, p.radii, gaps, bgap, new_bgap, 0.5)
        assert segment_is_safe(*args) == segment_is_safe_numpy(*args)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 12),
    segments=st.integers(1, 60),
    box=st.booleans(),
)
def test_segments_clearance_kernel_is_bitwise_the_numpy_reference(
    seed: int, n: int, segments: int, box: bool
) -> None:
    p = _problem(seed, n, box)
    rng = np.random.default_rng(seed)
    i = int(rng.integers(n))
    P = p.start[rng.integers(n, size=segments)] + rng.normal(size=(segments, 2))
    Q = P + 3.0 * rng.normal(size=(segments, 2))
    Q[: segments // 4] = P[: segments // 4]  # point segments
    np.testing.assert_array_equal(
        segments_clearance(p, p.start, i, P, Q), segments_clearance_numpy(p, p.start, i, P, Q)
    )


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 12), box=st.booleans())
def test_rk4_step_bounds_are_the_numpy_references(seed: int, n: int, box: bool) -> None:
    from cellplan.assembly.flows import max_dt, max_dt_numpy, step_is_safe, step_is_safe_numpy
    from cellplan.assembly.navigation import evaluate

    p = _problem(seed, n, box)
    rng = np.random.default_rng(seed)
    ev = evaluate(p.start, p, 50.0)
    moving = (rng.random(n) < 0.5) * rng.random(n)
    for stiff in (True, False):
        assert max_dt(-ev.v, ev, moving, ev.gaps, ev.bgap, stiff) == max_dt_numpy(
            -ev.v, ev, moving, ev.gaps, ev.bgap, stiff
        )
    for scale in (1e-3, 0.05, 0.3, 2.0):
        delta = scale * rng.normal(size=(n, 2))
        assert step_is_safe(delta, ev.gaps, ev.bgap, 0.5) == step_is_safe_numpy(
            delta, ev.gaps, ev.bgap, 0.5
        )


def test_rk4_stages_kernel_gives_the_generic_steps_bit_for_bit(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import cellplan.assembly.flows as flows

    p = generate_problem(GeneratorSpec(n=9, seed=4, min_start_gap=0.05), default_workspace(9))
    settings_rk4 = flows.FlowSettings(method="rk4")
    fast = flows.gradient_flow(p, 128.0, settings=settings_rk4)

    def generic(fld: Any, problem: Any, k: float, mask: Any, *args: Any) -> Any:
        return flows._rk4(fld, *args), 0  # b, w, dt, gaps, bgap

    monkeypatch.setattr(flows, "_rk4_fast", generic)
    slow = flows.gradient_flow(p, 128.0, settings=settings_rk4)
    assert fast.status is slow.status and fast.steps == slow.steps > 50
    assert fast.evaluations == slow.evaluations
    np.testing.assert_array_equal(fast.path, slow.path)
