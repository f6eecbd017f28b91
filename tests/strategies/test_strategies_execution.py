"""Executing a strategy at real states: (9), the lookahead, the LRTA* correction, progress."""

from __future__ import annotations

import numpy as np
import pytest
from strategies_helpers import tiny

from cellplan.errors import ArgumentError
from cellplan.strategies.policy.execution import Executor, default_depth
from cellplan.strategies.policy.strategy import FMP, STAY, Strategy, solve_scenario
from cellplan.strategies.sim.options import SimulationOptions
from cellplan.strategies.sim.simulate import Request, Simulation, simulate
from cellplan.workcell import load_workcell


@pytest.fixture(scope="module")
def solved():
    sc, cell = tiny(cells=16)
    strategy, _ = solve_scenario(sc, cell)
    return cell, strategy


def _centre(strategy: Strategy, c: int) -> np.ndarray:
    mdp = strategy.mdp
    return mdp.lower + (np.array(np.unravel_index(c, tuple(mdp.shape))) + 0.5) * mdp.spacing


def _task_states(strategy: Strategy, n: int, seed: int) -> np.ndarray:
    """Random live (mode, cell) pairs of the W and C layers."""
    live = np.argwhere(strategy.mdp.live)
    live = live[live[:, 0] > 0]
    rng = np.random.default_rng(seed)
    return live[rng.choice(len(live), n, replace=False)]


def test_plain_executor_is_equation_9_at_cell_centres(solved):
    _, strategy = solved
    ex = Executor(strategy, depth=1)
    for m, c in _task_states(strategy, 150, 0):
        q = _centre(strategy, int(c))
        vals = ex.action_values(q, int(m)).copy()
        u = ex.action(q, int(m))
        np.testing.assert_allclose(vals, strategy.action_values(q, int(m)), equal_nan=True)
        assert vals[{FMP: 0, STAY: 1}.get(u, u + 2)] == pytest.approx(np.nanmin(vals))
    # At the grid states the solved values satisfy (9): nothing to correct.
    assert ex.corrections == 0
    np.testing.assert_array_equal(ex.h[strategy.mdp.live], strategy.values[strategy.mdp.live])


def test_lookahead_of_depth_one_is_the_minimum_of_equation_9_inside_the_domain(solved):
    """One stage of lookahead: FMP here, or one motion that stays in the domain (then
    the cost-to-go where it lands, or FMP there)."""
    _, strategy = solved
    mdp = strategy.mdp
    ex = Executor(strategy, depth=1, learn=False)
    rng = np.random.default_rng(1)
    checked = 0
    for m, c in _task_states(strategy, 120, 1):
        m = int(m)
        q = _centre(strategy, int(c)) + rng.uniform(-0.5, 0.5, 2) * mdp.spacing
        if not mdp.live[m, strategy.cell_of(q)]:
            continue
        g = strategy.gain
        vals = strategy.action_values(q, m).copy()
        expect = vals[0] - g if np.isfinite(vals[0]) else np.inf
        for a in range(mdp.nact[mdp.vcls[m]]):
            q1 = strategy.next_configuration(q, m, a)
            if np.isfinite(vals[2 + a]) and mdp.live[m, strategy.cell_of(q1)]:
                expect = min(expect, vals[2 + a] - g)
                # ... or the move and then FMP where it lands (a two-stage sequence).
                fmp = strategy.action_values(q1, m)[0]
                if np.isfinite(fmp):
                    expect = min(expect, mdp.cost[m] - g + fmp - g)
        best, plan = ex._lookahead(q, m, True)
        if np.isfinite(expect):
            assert best == pytest.approx(expect)
            checked += 1
        else:
            assert plan == []
    assert checked > 50


def test_the_correction_raises_inconsistent_values_of_this_run_only(solved):
    _, strategy = solved
    mdp = strategy.mdp
    before = strategy.values.copy()
    ex = Executor(strategy)
    # A W state whose values are made far too low: (9) there cannot deliver what they promise.
    m, c = next((m, c) for m, c in _task_states(strategy, 50, 2) if mdp.modes[m].kind == "W")
    q = _centre(strategy, int(c))
    ex.h[m, c] -= 5.0
    h0 = ex.h.copy()
    ex.action(q, int(m))
    assert ex.corrections == 1 and ex.raised > 2.5
    assert np.all(ex.h >= h0) and ex.h[m, c] > h0[m, c]
    np.testing.assert_array_equal(strategy.values, before)


def test_default_depth_keeps_the_number_of_sequences_small(solved):
    _, strategy = solved
    na = int(strategy.mdp.nact.max())
    depth = default_depth(strategy.mdp)
    assert depth >= 1 and na * (na - 1) ** (depth - 1) <= 400


def test_mean_wait_with_and_without_open_requests():
    reqs = [Request("P1", "S1", "D1", 0, 3, 10, 10.0), Request("P1", "S1", "D1", 12, waiting=30.0)]
    losses = np.r_[np.ones(10), 0.0, 0.0, np.ones(30)]
    sim = Simulation(
        np.zeros((43, 2)), np.zeros(43, np.int64), np.zeros(42, np.int64), losses, reqs
    )
    m = sim.metrics()
    assert m["mean_wait"] == 10.0  # delivered requests only
    assert m["mean_wait_all"] == 20.0  # the open one at its age so far
    assert m["open_requests"] == 1.0 and m["open_wait"] == 30.0
    assert m["mean_wait_all"] * m["requests"] == pytest.approx(losses.sum())


def test_every_stage_of_waiting_is_charged_to_a_request(solved):
    cell, strategy = solved
    sim = simulate(strategy, 2000, 3, SimulationOptions(start=cell.robot.start), cell=cell)
    m = sim.metrics()
    assert m["mean_wait_all"] * m["requests"] == pytest.approx(sim.losses.sum())


@pytest.fixture(scope="module")
def p3():
    sc, cell = load_workcell("strategies_p3")
    strategy, _ = solve_scenario(sc, cell)
    return cell, strategy


def test_rotating_robot_makes_progress_with_its_own_motions_only(p3):
    """Regression: on problem 3 the plain rule (9) cycles for ever beside the openings.

    The old safeguard stepped the robot to its cell centre, a sideways jump this robot
    cannot make; the executor must finish every request with the robot's own motions
    and lose per stage what the solve predicts.
    """
    cell, strategy = p3
    sim = simulate(
        strategy, 6000, 0, SimulationOptions(start=np.array(strategy.meta["start"])), cell=cell
    )
    for k in range(len(sim.actions)):
        u, m = int(sim.actions[k]), int(sim.modes[k])
        expect = sim.q[k] if u < 0 else strategy.next_configuration(sim.q[k], m, u)
        np.testing.assert_allclose(sim.q[k + 1], expect, atol=1e-9, err_msg=f"stage {k}")
    ages = [(r.delivery if r.delivery >= 0 else len(sim.actions)) - r.arrival for r in sim.requests]
    assert len(ages) > 50 and max(ages) < 400
    batches = sim.losses.reshape(20, -1).mean(axis=1)
    se = batches.std(ddof=1) / np.sqrt(len(batches))
    assert abs(batches.mean() - strategy.gain) < 4 * se + 0.02


def test_no_snap_model_keeps_only_moves_that_land_among_free_cells(solved):
    from cellplan.strategies.model.stencils import stencil

    _, strategy = solved
    sc, cell = tiny(cells=16)
    strict, _ = solve_scenario(sc, cell, snap=False)
    mdp, old = strict.mdp, strategy.mdp
    assert strict.meta["transitions"] == "no-snap" and np.isfinite(strict.gain)
    assert np.all(mdp.valid & ~old.valid == 0)  # only removals
    assert np.all(mdp.live <= old.live)
    idx = np.empty(4, np.int64)
    w = np.empty(4)
    removed = 0
    for k in range(len(mdp.nact)):
        for c in np.flatnonzero(old.valid[k]):
            q = _centre(strategy, int(c))
            for a in range(mdp.nact[k]):
                if not (old.valid[k, c] >> a) & 1:
                    continue
                landing = strategy.next_configuration(q, int(np.flatnonzero(mdp.vcls == k)[0]), a)
                n = stencil(landing, mdp.grid(), idx, w, np.empty(12, np.int64), np.empty(6))
                touches = bool(np.any((w[:n] > 1e-12) & ~mdp.free[k, idx[:n]]))
                assert bool((mdp.valid[k, c] >> a) & 1) == (not touches)
                removed += touches
    assert removed > 0  # the tiny cell's block makes some moves snap


def test_the_executor_refuses_bad_states_with_one_line(solved):
    # The executor's kernels index the values with the mode unchecked, like the query's.
    _, strategy = solved
    ex = Executor(strategy)
    n = strategy.mdp.n_modes
    q = np.array([15.0, 8.0])
    cases = [
        (lambda: ex.action(q, n), "mode"),
        (lambda: ex.action(np.array([np.nan, 8.0]), 1), "q"),
        (lambda: ex.action_values(q[:1], 1), "q"),
        (lambda: ex.value(q, -2), "mode"),
        (lambda: ex.correct(q, n + 1, 0.0), "mode"),
    ]
    for call, field in cases:
        with pytest.raises(ArgumentError) as info:
            call()
        assert [p.field for p in info.value.problems] == [field]
