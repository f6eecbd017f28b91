"""The dense-cell bits, the vectorised improvement and Bellman steps, the capped cold start.

References from the definitions (plain loops over cells and corners in Python), on the
small random models of ``test_strategies_kernels`` and on grids large enough to span
several of the improvement step's runs of cells.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from test_strategies_kernels import landing, models, random_actions, ref_transition

from cellplan.strategies.model.actions import ActionSet
from cellplan.strategies.model.mdp import Geometry, LayeredMDP, assemble, grid_box
from cellplan.strategies.model.spec import Motions, Process
from cellplan.strategies.solve.bellman import bellman_dense, bellman_rows
from cellplan.strategies.solve.improvement import RUN, improvable, improve_layer
from cellplan.strategies.solve.sweeps import (
    dense_cells,
    layer_iteration,
    layer_solve,
    sweep_policy,
    sweep_spec,
    with_dense,
)


def ref_dense(mdp: LayeredMDP) -> np.ndarray:
    """Bit ``a`` of ``[m, c]``: ``c`` live and interior, ``a`` collision-free from it, and
    every corner of its landing stencil (weight above 1e-12) live in layer ``m``."""
    out = np.zeros(mdp.live.shape, np.int64)
    for m, c in zip(*np.nonzero(mdp.live), strict=True):
        k = mdp.vcls[m]
        if not mdp.interior[k, c]:
            continue
        for a in range(int(mdp.nact[k])):
            if not (int(mdp.valid[k, c]) >> a) & 1:
                continue
            corners = [i for i, w in landing(mdp, m, c, a).items() if w > 1e-12]
            if all(mdp.live[m, i] for i in corners):
                out[m, c] |= 1 << a
    return out


def ref_improvement(mdp: LayeredMDP, h: np.ndarray, m: int, g: float) -> tuple[np.ndarray, dict]:
    """``min_u [l(u) - g + H_m(x'_u)]`` per live cell of layer ``m`` and each action's value."""
    best = np.full(h.shape[1], np.inf)
    values: dict[int, dict[int, float]] = {}
    for c in np.flatnonzero(mdp.live[m]):
        values[int(c)] = {}
        for a in range(-2, int(mdp.nact[mdp.vcls[m]])):
            tr = ref_transition(mdp, h, m, c, a)
            if tr is None:
                continue
            cost, succ = tr
            values[int(c)][a] = cost - g + sum(p * h[L, i] for L, i, p in succ)
        if values[int(c)]:
            best[c] = min(values[int(c)].values())
    return best, values


def big_model(seed: int, nx: int = 70, ny: int = 60) -> LayeredMDP:
    """A one-request model on a grid of more than two runs of cells (``RUN``)."""
    rng = np.random.default_rng(seed)
    n = nx * ny
    free = rng.random(n) < 0.9
    geometry = Geometry(
        free_nr=free,
        free_w={"S": free},
        free_c={("P", "S"): free & (rng.random(n) < 0.95)},
        pick={("P", "S"): rng.random(n) < 0.05},
        drop={("P", "D"): rng.random(n) < 0.05},
        tf_pick={("P", "S"): 1.0 + rng.random(n)},
        tf_drop={("P", "D"): 1.0 + rng.random(n)},
    )
    acts = random_actions(rng, 8)
    return assemble(
        grid_box((nx, ny), (0.0, 0.0), (float(nx), float(ny)), (False, False)),
        [("P", "S", "D", 1.0)],
        geometry,
        Motions(acts, {"P": acts}),
        Process(1.0, 0.2),
    )


@settings(max_examples=60, deadline=None)
@given(models())
def test_dense_bits_mark_the_moves_whose_corners_are_all_live(mdp):
    np.testing.assert_array_equal(dense_cells(mdp.kernel_args()), ref_dense(mdp))


def test_dense_bits_on_a_grid_of_several_runs():
    mdp = big_model(3)
    assert mdp.live.shape[1] > 2 * RUN
    bits = dense_cells(mdp.kernel_args())
    np.testing.assert_array_equal(bits, ref_dense(mdp))
    assert np.count_nonzero(bits) > 0.5 * np.count_nonzero(mdp.live)


def check_improvement(mdp: LayeredMDP, h: np.ndarray, g: float, rng: np.random.Generator) -> None:
    model = with_dense(mdp.kernel_args())
    for m in (mdp.c_layer(0), mdp.w_layer(0)):
        assert improvable(m, model)
        best, values = ref_improvement(mdp, h, m, g)
        live = mdp.live[m] & np.isfinite(best)
        # Each cell's recorded action: a random available one.
        pol = np.full(h.shape, -3, np.int16)
        for c, vals in values.items():
            if vals:
                pol[m, c] = list(vals)[rng.integers(len(vals))]
        # A recorded stay (the stage loss is positive: g < 1) has no finite value, so h is
        # not that action's value: the cell leaves for its best other action, whatever the
        # gain, and the residual is unbounded.
        leave = {
            c: min(v for a, v in values[c].items() if a != -1)
            for c in np.flatnonzero(live)
            if pol[m, c] == -1 and any(a != -1 for a in values[c])
        }
        for tie in (0.0, 0.5):
            got = pol.copy()
            residual, changed = improve_layer(m, h, g, got, tie, model)
            drop = h[m] - best
            if leave:
                assert residual == np.inf
            else:
                assert residual == np.max(drop[live], initial=0.0) or np.isclose(
                    residual, np.max(drop[live], initial=0.0), rtol=1e-12, atol=1e-12
                )
            assert changed == np.count_nonzero(got[m] != pol[m])
            for c in np.flatnonzero(live):
                old, new = int(pol[m, c]), int(got[m, c])
                if c in leave:
                    assert new != -1
                    assert abs(values[c][new] - leave[c]) <= 1e-12 * max(1.0, abs(leave[c]))
                elif new != old:
                    # A change goes to an action attaining the minimum, only for more than tie.
                    assert abs(values[c][new] - best[c]) <= 1e-12 * max(1.0, abs(best[c]))
                    assert h[m, c] - best[c] > tie
                else:
                    # A kept action is the best one, or the switch would gain at most tie.
                    assert (
                        abs(values[c][old] - best[c]) <= 1e-12 * max(1.0, abs(best[c]))
                        or h[m, c] - best[c] <= tie
                    )
            np.testing.assert_array_equal(got[~mdp.live], pol[~mdp.live])


@settings(max_examples=60, deadline=None)
@given(models(), st.integers(0, 2**31 - 1), st.floats(0.0, 0.9))
def test_one_improvement_step_matches_the_reference(mdp, seed, g):
    rng = np.random.default_rng(seed)
    h = np.where(mdp.live, rng.normal(size=mdp.live.shape), 0.0)
    check_improvement(mdp, h, g, rng)


def test_one_improvement_step_across_runs_of_cells():
    mdp = big_model(5)
    rng = np.random.default_rng(7)
    h = np.where(mdp.live, rng.normal(size=mdp.live.shape) + 10.0, 0.0)
    check_improvement(mdp, h, 0.4, rng)


def test_a_state_left_below_its_value_by_staying_is_not_taken_for_solved():
    # Staying for ever has no finite value, so the exact evaluation leaves a state whose
    # action is stay as it was. Found by starting the solver from a converged problem 6:
    # a C state left 0.35 below every action it has, its action stay, passed the residual
    # check pass after pass and the certificate failed (span 0.3).
    mdp = big_model(11)
    model = with_dense(mdp.kernel_args())
    rng = np.random.default_rng(2)
    g = 0.4
    m = mdp.c_layer(0)
    h = np.where(mdp.live, 5.0 * rng.random(mdp.live.shape), 0.0)
    D = np.zeros_like(h)
    pol = np.full(h.shape, -3, np.int16)
    h[m][mdp.live[m]] = np.inf
    layer_iteration(m, h, D, g, pol, layer_solve(1e-11, 10**6, 10**6, False, True, False), model)
    solved = h[m].copy()
    # A state on a move, upstream of others, set below its value and to stay.
    moving = np.flatnonzero(mdp.live[m] & (pol[m] >= 0))
    c = int(moving[len(moving) // 2])
    h[m, c] -= 0.5
    pol[m, c] = -1
    layer_iteration(m, h, D, g, pol, layer_solve(1e-11, 10**6, 10**6, True, True, False), model)
    assert pol[m, c] != -1
    np.testing.assert_allclose(h[m][mdp.live[m]], solved[mdp.live[m]], rtol=0, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(models(), st.integers(0, 2**31 - 1), st.floats(0.0, 0.9), st.integers(0, 3))
def test_sweeps_reading_dense_cells_untested_equal_the_tested_loop(mdp, seed, g, flips):
    # With every value finite, a sweep that skips the corner tests of dense cells gives
    # bit for bit what the tested loop gives.
    rng = np.random.default_rng(seed)
    h = np.where(mdp.live, rng.normal(size=mdp.live.shape), 0.0)
    D = np.where(mdp.live, rng.normal(size=mdp.live.shape), 0.0)
    plain = mdp.kernel_args()
    for m in (mdp.c_layer(0), mdp.w_layer(0)):
        runs = []
        for model in (plain, with_dense(plain)):
            hh, DD = h.copy(), D.copy()
            pol = np.full(h.shape, -3, np.int16)
            nchg = np.zeros(1, np.int64)
            change = sweep_policy(m, hh, DD, g, sweep_spec(flips, pol, nchg, 1e-9), model)
            runs.append((change, hh, DD, pol, nchg))
        for a, b in zip(*runs, strict=True):
            np.testing.assert_array_equal(a, b)


@settings(max_examples=60, deadline=None)
@given(models(), st.floats(0.0, 0.9), st.booleans())
def test_a_capped_cold_solve_leaves_no_live_state_unreached(mdp, g, dense):
    # The first outer pass caps the sweeps of each layer (an inexact solve); it must still
    # give every live state a finite value, whatever the cap, or the next pass's warm
    # start computes with infinities.
    model = with_dense(mdp.kernel_args()) if dense else mdp.kernel_args()
    h = np.where(mdp.live, 0.0, 0.0)
    D = np.zeros_like(h)
    pol = np.full(h.shape, -3, np.int16)
    for m in (mdp.c_layer(0), mdp.w_layer(0)):
        h[m][mdp.live[m]] = np.inf
        layer_iteration(m, h, D, g, pol, layer_solve(1e-2, 1, 100_000, False, True, False), model)
        assert np.all(np.isfinite(h[m][mdp.live[m]]))


def test_a_capped_cold_solve_of_a_long_corridor_goes_past_the_cap():
    # A serpentine corridor: one sweep reaches only part of it, so the cap of one sweep
    # is overridden until the far end is reached.
    nx, ny = 15, 15
    free = np.zeros((nx, ny), bool)
    free[:, ::2] = True
    for j in range(1, ny, 2):
        free[nx - 1 if j % 4 == 1 else 0, j] = True
    free = free.ravel()
    drop = np.zeros(nx * ny, bool)
    drop[0] = True
    pick = np.zeros(nx * ny, bool)
    pick[-1] = True
    acts = ActionSet(
        np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]]), -1, ("e", "w", "n", "s")
    )
    mdp = assemble(
        grid_box((nx, ny), (0.0, 0.0), (float(nx), float(ny)), (False, False)),
        [("P", "S", "D", 1.0)],
        Geometry(
            free_nr=free,
            free_w={"S": free},
            free_c={("P", "S"): free},
            pick={("P", "S"): pick},
            drop={("P", "D"): drop},
            tf_pick={("P", "S"): np.ones(nx * ny)},
            tf_drop={("P", "D"): np.ones(nx * ny)},
        ),
        Motions(acts, {"P": acts}),
        Process(1.0, 0.2),
    )
    model = with_dense(mdp.kernel_args())
    m = mdp.c_layer(0)
    h = np.zeros(mdp.live.shape)
    h[m][mdp.live[m]] = np.inf
    D = np.zeros_like(h)
    pol = np.full(h.shape, -3, np.int16)
    opts = layer_solve(1e-2, 1, 100_000, False, True, False)
    full, _ = layer_iteration(m, h, D, 0.5, pol, opts, model)
    assert full > 1  # one sweep did not reach the far end
    # Every cell of the corridor: (steps to the drop cell + 1) x (1 - g), the FMP there
    # costing t_f - g = 1 - g with NR at zero; steps by breadth-first search.
    steps = np.full(nx * ny, -1)
    steps[0] = 0
    frontier = [0]
    while frontier:
        nxt = []
        for c in frontier:
            i, j = divmod(c, ny)
            for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                if 0 <= i + di < nx and 0 <= j + dj < ny:
                    e = (i + di) * ny + j + dj
                    if free[e] and steps[e] < 0:
                        steps[e] = steps[c] + 1
                        nxt.append(e)
        frontier = nxt
    live = mdp.live[m]
    np.testing.assert_array_equal(live, steps >= 0)
    np.testing.assert_allclose(h[m][live], (steps[live] + 1) * 0.5, rtol=1e-12)


def check_dense_bellman(mdp: LayeredMDP, h: np.ndarray, subset: np.ndarray) -> None:
    model = with_dense(mdp.kernel_args())
    for m in (mdp.c_layer(0), mdp.w_layer(0)):
        assert improvable(m, model)
        outs = []
        for dense in (False, True):
            out = np.full_like(h, -7.0)
            policy = np.full(h.shape, -9, np.int64)
            gap = np.full_like(h, -7.0)
            N = h.shape[1]
            if dense:
                bellman_dense(m, h, out, policy, gap, subset, model)
            else:
                bellman_rows(h, out, policy, gap, subset, m * N, (m + 1) * N, model)
            outs.append((out, policy, gap))
        for a, b in zip(*outs, strict=True):
            np.testing.assert_array_equal(a, b)


@settings(max_examples=60, deadline=None)
@given(models(), st.integers(0, 2**31 - 1), st.booleans())
def test_the_vectorised_bellman_sweep_equals_the_state_by_state_one(mdp, seed, with_subset):
    # Values, actions and gaps bit for bit (the certificate's), with or without a subset.
    rng = np.random.default_rng(seed)
    h = np.where(mdp.live, rng.normal(size=mdp.live.shape), 0.0)
    subset = rng.random(h.shape) < 0.5 if with_subset else np.zeros((0, 0), np.bool_)
    check_dense_bellman(mdp, h, subset)


def test_the_vectorised_bellman_sweep_across_runs_with_ties():
    # Values on a coarse lattice: many actions tie exactly, so the tie rule is exercised.
    mdp = big_model(11)
    rng = np.random.default_rng(2)
    h = np.where(mdp.live, np.round(rng.normal(size=mdp.live.shape), 1), 0.0)
    check_dense_bellman(mdp, h, np.zeros((0, 0), np.bool_))
