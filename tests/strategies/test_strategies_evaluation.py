"""Exact policy evaluation (Tarjan order) and the Dijkstra cold start, against references."""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from strategies_helpers import tiny

from cellplan.strategies.model.mdp import build_model
from cellplan.strategies.solve import coldstart, evaluation


def _csr(n: int, edges: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    ptr = np.zeros(n + 1, np.int64)
    succ = []
    for v in range(n):
        out = sorted({b for a, b in edges if a == v})
        succ.extend(out)
        ptr[v + 1] = len(succ)
    return ptr, np.array(succ, np.int64)


graphs = st.integers(1, 25).flatmap(
    lambda n: st.tuples(
        st.just(n), st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)), max_size=60)
    )
)


@settings(max_examples=150, deadline=None)
@given(graphs)
def test_components_are_the_strongly_connected_components_successors_first(graph):
    n, edges = graph
    ptr, succ = _csr(n, edges)
    members, comp_ptr = evaluation.components(ptr, succ)
    comps = [set(members[comp_ptr[k] : comp_ptr[k + 1]].tolist()) for k in range(len(comp_ptr) - 1)]
    g = nx.DiGraph()
    g.add_nodes_from(range(n))
    g.add_edges_from(edges)
    assert sorted(map(sorted, comps)) == sorted(map(sorted, nx.strongly_connected_components(g)))
    where = {v: k for k, comp in enumerate(comps) for v in comp}
    # Every edge leaves a component for an earlier one: successors are solved first.
    assert all(where[b] <= where[a] for a, b in edges)


@settings(max_examples=100, deadline=None)
@given(graphs, st.integers(0, 2**31 - 1))
def test_solve_system_is_the_exact_solution_of_the_linear_system(graph, seed):
    n, edges = graph
    ptr, succ = _csr(n, edges)
    rng = np.random.default_rng(seed)
    # Rows of W sum to at most 0.9 (a discounted or leaving chain: the system is regular).
    wt = np.empty(len(succ))
    for v in range(n):
        k = ptr[v + 1] - ptr[v]
        if k:
            w = rng.random(k)
            wt[ptr[v] : ptr[v + 1]] = 0.9 * rng.random() * w / w.sum()
    const = rng.normal(size=n)
    dconst = rng.normal(size=n)
    fixed = np.zeros(n, bool)
    hl = np.full(n, np.inf)
    Dl = np.zeros(n)
    evaluation.solve_system(ptr, succ, wt, const, dconst, fixed, hl, Dl)
    W = np.zeros((n, n))
    for v in range(n):
        for e in range(ptr[v], ptr[v + 1]):
            W[v, succ[e]] += wt[e]
    np.testing.assert_allclose(hl, np.linalg.solve(np.eye(n) - W, const), atol=1e-9)
    np.testing.assert_allclose(Dl, np.linalg.solve(np.eye(n) - W, dconst), atol=1e-9)


def test_dijkstra_values_are_shortest_paths_on_the_main_corner_graph():
    sc, cell = tiny(16)
    mdp = build_model(sc, cell)
    m = mdp.c_layer(0)
    g = 0.4
    h = np.zeros(mdp.live.shape)
    nxt = int(mdp.fmp_next[m])
    h[nxt] = np.linspace(0.0, 1.0, h.shape[1])  # some terminal values
    h[m] = np.inf
    pol = np.full(h.shape, -3, np.int16)
    reached = coldstart.dijkstra_layer(m, h, g, pol, mdp.kernel_args())
    assert reached > 0
    # The reference: networkx Dijkstra from a super source, every move a stage.
    step = float(mdp.cost[m]) - g
    k = int(mdp.vcls[m])
    graph = nx.DiGraph()
    offset = 100.0  # keeps the super-source edges positive
    for c in np.flatnonzero(mdp.live[m]):
        if np.isfinite(mdp.tf[m, c]) and mdp.live[nxt, c]:
            graph.add_edge(c, "target", weight=mdp.tf[m, c] - g + h[nxt, c] + offset)
        if not mdp.interior[k, c]:
            continue
        for a in range(int(mdp.nact[k])):
            if (int(mdp.valid[k, c]) >> a) & 1:
                graph.add_edge(c, int(c + mdp.coff[k, a, 0, 0]), weight=step)
    dist = nx.single_source_dijkstra_path_length(graph.reverse(), "target")
    cells = [c for c in np.flatnonzero(mdp.live[m]) if np.isfinite(h[m, c])]
    assert len(cells) == reached
    for c in cells:
        assert abs(h[m, c] - (dist[c] - offset)) < 1e-9
        assert pol[m, c] == -2 or pol[m, c] >= 0


def test_stability_check_on_near_ties_equals_a_full_second_sweep():
    from cellplan.strategies.solve import solver

    sc, cell = tiny(16)
    mdp = build_model(sc, cell)
    result = solver.solve(mdp, "structured")
    h = np.where(mdp.live, result.values, 0.0)
    noise = np.random.default_rng(0).normal(scale=0.05, size=h.shape)
    # The solved values (span ~1e-7, few near ties) and perturbed ones (many actions change).
    for values in (h, h + noise):
        cert = solver.certify(mdp, values)
        _, _, th, policy, _ = cert
        _, full, _ = solver.bellman(mdp, th - result.gain)
        expected = int(np.count_nonzero((full != policy) & mdp.live))
        assert solver.stability(mdp, cert, result.gain) == expected
    assert expected > 0  # the perturbed case exercises the second sweep


@settings(max_examples=60, deadline=None)
@given(
    st.integers(1, 4),
    st.integers(1, 40),
    st.integers(0, 2**32 - 1),
    st.sampled_from([0.0, 1e-8, 1e-3]),
)
def test_span_and_near_ties_equal_the_array_formulas(M, N, seed, span):
    """The loops that replace the certificate's temporaries give the same numbers."""
    from cellplan.strategies.solve import bellman as bk

    rng = np.random.default_rng(seed)
    live = rng.random((M, N)) < 0.7
    live[0, 0] = True
    h = rng.normal(scale=10.0, size=(M, N))
    th = h + rng.normal(scale=1e-3, size=(M, N))
    # Ties (gap 0), gaps at the slack's edge, and NaN where no second action exists.
    gap = rng.choice([0.0, span, 2e-9, 1.0, np.nan], size=(M, N))
    th[~live] = np.nan
    r = (th - h)[live]
    assert bk.residual_range(th, h, live) == (r.min(), r.max())
    slack = span + 1e-9 * np.maximum(1.0, np.abs(np.where(live, th, 0.0)))
    np.testing.assert_array_equal(bk.near_ties(th, gap, live, span), live & (gap <= slack))


def test_span_of_a_nan_residual_is_nan():
    from cellplan.strategies.solve import bellman as bk

    h = np.zeros((1, 3))
    th = np.array([[0.5, np.nan, 0.2]])
    lo, hi = bk.residual_range(th, h, np.ones((1, 3), np.bool_))
    assert np.isnan(lo) and np.isnan(hi)


def test_bellman_into_a_given_array_equals_a_fresh_one():
    from cellplan.strategies.solve import solver

    sc, cell = tiny(12)
    mdp = build_model(sc, cell)
    h = np.where(mdp.live, solver.solve(mdp, "structured").values, 0.0)
    fresh = solver.bellman(mdp, h)
    buf = np.full_like(h, 123.0)
    given_out = solver.bellman(mdp, h, out=buf)
    assert given_out[0] is buf
    for a, b in zip(fresh, given_out, strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="out must be a separate array"):
        solver.bellman(mdp, h, out=h)
    with pytest.raises(ValueError, match="out must be a separate array"):
        solver.bellman(mdp, h, out=h[:, ::-1])  # a view of h
