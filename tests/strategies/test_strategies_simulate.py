"""The simulator: the assembly process, per-request statistics, baselines."""

from __future__ import annotations

import numpy as np
import pytest
from strategies_helpers import tiny

from cellplan.strategies.policy.strategy import solve_scenario
from cellplan.strategies.sim.options import SimulationOptions
from cellplan.strategies.sim.simulate import compare_policies, simulate


@pytest.fixture(scope="module")
def solved():
    sc, cell = tiny(cells=16)
    strategy, _ = solve_scenario(sc, cell)
    return cell, strategy


def test_long_run_loss_per_stage_matches_the_gain(solved):
    cell, strategy = solved
    sim = simulate(strategy, 30000, 4, SimulationOptions(start=cell.robot.start), cell=cell)
    batches = sim.losses.reshape(30, -1).mean(axis=1)
    se = batches.std(ddof=1) / np.sqrt(len(batches))
    # The gain is the long-run expected loss per stage (average-cost optimality).
    assert abs(batches.mean() - strategy.gain) < 4 * se + 0.02


def test_request_bookkeeping(solved):
    cell, strategy = solved
    sim = simulate(strategy, 3000, 1, SimulationOptions(start=cell.robot.start), cell=cell)
    done = [r for r in sim.requests if r.delivery >= 0]
    assert done
    for r in done:
        assert r.arrival < r.pickup <= r.delivery
        # Waiting time = loss (7) summed from arrival to delivery.
        assert r.waiting == pytest.approx(sim.losses[r.arrival : r.delivery].sum())
    # Only the last request may still be open.
    assert all(r.delivery >= 0 for r in sim.requests[:-1])
    m = sim.metrics()
    assert m["served"] == len(done)
    assert m["idle_fraction"] == pytest.approx(np.mean(sim.modes[:-1] == 0))


def test_same_seed_same_run(solved):
    cell, strategy = solved
    a = simulate(strategy, 500, 7, SimulationOptions(start=cell.robot.start))
    b = simulate(strategy, 500, 7, SimulationOptions(start=cell.robot.start))
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.modes, b.modes)


def test_reactive_stays_still_while_idle(solved):
    cell, strategy = solved
    sim = simulate(strategy, 400, 2, SimulationOptions(policy="reactive", start=cell.robot.start))
    idle = np.flatnonzero(sim.modes[:-1] == 0)
    for k in idle:
        if sim.modes[k + 1] == 0:
            np.testing.assert_array_equal(sim.q[k], sim.q[k + 1])


def test_home_policy_returns_home(solved):
    _, strategy = solved
    home = np.array([15.0, 22.0])
    sim = simulate(
        strategy,
        60,
        0,
        SimulationOptions(policy="home", start=np.array([4.0, 10.0]), home=home, start_mode=0),
    )
    # Before any request arrives the robot walks to the home cell.
    first_request = next(
        (k for k in range(len(sim.modes)) if sim.modes[k] != 0), len(sim.modes) - 1
    )
    if first_request > 15:
        assert np.linalg.norm(sim.q[first_request] - home) < 2.0


def test_anticipation_does_not_lose_to_baselines(solved):
    cell, strategy = solved
    out = compare_policies(strategy, 4000, [0, 1, 2], SimulationOptions(start=cell.robot.start))
    mean = {p: np.mean([r["loss_per_stage"] for r in rows]) for p, rows in out.items()}
    assert mean["optimal"] <= mean["reactive"] + 0.02
    assert mean["optimal"] <= mean["home"] + 0.02
