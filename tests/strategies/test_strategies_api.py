"""The strategies planner through ``cellplan.plan`` and the simulation as a Result."""

from __future__ import annotations

import json

import numpy as np
import pytest
from strategies_helpers import TINY

import cellplan
from cellplan.core import Status, check_stats
from cellplan.errors import ArgumentError
from cellplan.strategies.policy.strategy import FMP, STAY
from cellplan.strategies.sim.options import SimulationOptions
from cellplan.strategies.sim.simulate import simulate_result, wait_bound
from cellplan.trajectory import Trajectory


@pytest.fixture(scope="module")
def setup():
    return cellplan.load("strategies_tiny")


@pytest.fixture(scope="module")
def result(setup):
    return cellplan.plan(setup, "strategies")


def test_plan_solves_the_smoke_problem(result):
    assert result.status is Status.SOLVED and result.success
    assert result.planner == "strategies"
    assert result.options["method"] is None and result.options["sample_stages"] == 200
    assert check_stats(result.stats) == []
    assert result.stats["gain"] == pytest.approx(result.solution.gain)
    assert result.stats["span"] < 1e-6
    assert result.stats["sim_stages"] == 200
    assert result.message.startswith(f"gain {result.solution.gain:.4f} per stage")
    assert "\n" not in result.message


def test_solution_answers_queries_at_real_states(result, setup):
    strategy = result.solution
    start = setup.workcell.robot.start
    waiting = strategy.mode_index("1,1,1,W")
    for mode in (0, waiting):
        u = strategy.action(start, mode)
        assert u.kind in ("pick", "drop", "stay", "move")
        assert u.code in (FMP, STAY) or 0 <= u.move == u.code < strategy.mdp.disp.shape[1]
    # The axis names travel with the strategy (and its file).
    assert strategy.meta["axes"] == ["x", "y"]


def test_trajectory_is_the_sample_run_with_its_events(result, setup):
    traj = result.trajectory
    assert len(traj) == 201 and traj.time_unit == "stage"
    np.testing.assert_array_equal(traj.t, np.arange(201.0))
    np.testing.assert_array_equal(traj.q[0], setup.workcell.robot.start)
    assert traj.columns == ("x", "y") and traj.units == ("workcell", "workcell")
    assert traj.modes == tuple(m.label for m in result.solution.modes)
    kinds = {e.kind for e in traj.events}
    assert {"request", "pick", "place"} <= kinds
    names = traj.mode_names
    for e in traj.events_of("request"):
        assert names[e.index].endswith(",W>") and names[e.index - 1] == "NR"
    for e in traj.events_of("pick"):
        assert names[e.index].endswith(",C>") and names[e.index - 1].endswith(",W>")
    for e in traj.events_of("place"):
        assert names[e.index] == "NR" and names[e.index - 1].endswith(",C>")
    assert len(traj.events_of("place")) == result.stats["sim_served"]


@pytest.mark.parametrize("suffix", [".csv", ".json", ".npz"])
def test_trajectory_round_trips(result, tmp_path, suffix):
    path = result.trajectory.save(tmp_path / f"run{suffix}")
    back = Trajectory.load(path)
    assert back == result.trajectory
    assert back.events == result.trajectory.events


def test_same_seed_same_run_other_seed_other_run(setup, result):
    again = cellplan.plan(setup, "strategies", seed=0)
    assert again.trajectory == result.trajectory
    other = cellplan.plan(setup, "strategies", seed=5, sample_stages=50)
    assert len(other.trajectory) == 51
    assert not np.array_equal(other.trajectory.q, result.trajectory.q[:51])


def test_general_method_agrees_with_structured(setup, result):
    general = cellplan.plan(setup, "strategies", method="general", sample_stages=5)
    assert general.success and general.solution.meta["method"] == "general"
    assert general.stats["gain"] == pytest.approx(result.stats["gain"], abs=1e-5)


@pytest.mark.parametrize(
    ("options", "named"),
    [
        ({"sample_stage": 10}, "did you mean 'sample_stages'"),
        ({"method": "fast"}, "method"),
        ({"cells": [2, 2]}, "cells"),
        ({"cells": [12, 12, 12]}, "cells: needs 2 values"),
        ({"sample_stages": 0}, "sample_stages"),
        ({"seed": -1}, "seed"),
        ({"tolerance": 0}, "tolerance"),
        ({"tolerance": float("nan")}, "tolerance"),
        ({"max_sweeps": 0}, "max_sweeps"),
        ({"damping": 1.5}, "damping"),
    ],
)
def test_bad_options_are_one_line_naming_them(setup, options, named):
    with pytest.raises(ArgumentError) as info:
        cellplan.plan(setup, "strategies", **options)
    assert named in str(info.value)
    assert all("\n" not in str(p) for p in info.value.problems)


def test_unconverged_solve_is_reported_not_raised():
    setup = cellplan.loads(
        TINY.replace("CELLS", "12") + "  solver: {method: general, max_sweeps: 2}\n"
    )
    result = cellplan.plan(setup, "strategies", sample_stages=10)
    assert result.status is Status.NOT_CONVERGED and not result.success
    assert result.message.startswith("did not converge within 2 sweeps")
    assert len(result.trajectory) == 11 and check_stats(result.stats) == []


def test_solver_settings_are_options_defaulting_to_the_scenario(setup, result):
    # Each solver setting is an option of the planner; None reads strategy.solver.
    tight = cellplan.plan(setup, "strategies", tolerance=1e-8, sample_stages=5)
    assert tight.success
    assert tight.stats["gain_upper"] - tight.stats["gain_lower"] < 1e-8
    assert abs(tight.stats["gain"] - result.stats["gain"]) < 1e-6
    setup_2 = cellplan.loads(TINY.replace("CELLS", "12") + "  solver: {method: general}\n")
    stopped = cellplan.plan(setup_2, "strategies", max_sweeps=2, sample_stages=10)
    assert stopped.status is Status.NOT_CONVERGED
    assert stopped.message.startswith("did not converge within 2 sweeps")
    # The option wins over the scenario's value, which stays the default.
    setup_3 = cellplan.loads(
        TINY.replace("CELLS", "12") + "  solver: {method: general, max_sweeps: 2}\n"
    )
    assert cellplan.plan(setup_3, "strategies", max_sweeps=100_000, sample_stages=10).success


# --- simulate_result ---------------------------------------------------------------------------


def test_cellplan_simulate_is_simulate_result():
    assert cellplan.simulate is simulate_result


def test_simulation_result_matches_its_simulation(result, setup):
    run = cellplan.simulate(result.solution, 400, 3, cell=setup.workcell)
    sim = run.solution
    assert run.success and check_stats(run.stats) == []
    np.testing.assert_array_equal(run.trajectory.q, sim.q)
    np.testing.assert_array_equal(run.trajectory.mode, sim.modes)
    events = {(e.kind, e.index) for e in run.trajectory.events}
    for r in sim.requests:
        assert ("request", r.arrival) in events
        if r.pickup >= 0:
            assert ("pick", r.pickup) in events
        if r.delivery >= 0:
            assert ("place", r.delivery) in events
    assert run.stats["served"] == sum(r.delivery >= 0 for r in sim.requests) > 0
    assert run.stats["wait_bound"] == pytest.approx(wait_bound(result.solution))
    assert f"served {int(run.stats['served'])} of {len(sim.requests)} requests" in run.message
    # Without the workcell the columns come from the strategy's record of its axes.
    bare = cellplan.simulate(result.solution, 400, 3)
    assert bare.trajectory.columns == ("x", "y")


def test_a_request_waiting_past_the_bound_fails_the_run(result):
    run = simulate_result(result.solution, 400, 3, SimulationOptions(max_wait=2.0))
    assert run.status is Status.FAILED
    assert "waited" in run.message and "> 2" in run.message
    assert run.trajectory is not None and len(run.trajectory) == 401


@pytest.mark.parametrize(
    ("kwargs", "named"),
    [
        ({"stages": 0}, "stages"),
        ({"seed": -3}, "seed"),
        ({"policy": "greedy"}, "policy"),
        ({"start": [1e3, 1e3]}, "start"),
        ({"start": [1.0, 2.0, 3.0]}, "start"),
    ],
)
def test_bad_simulation_arguments(result, kwargs, named):
    args = {"stages": 10, "seed": 0, **kwargs}
    stages, seed = args.pop("stages"), args.pop("seed")
    with pytest.raises(ArgumentError) as info:
        simulate_result(result.solution, stages, seed, SimulationOptions(**args))
    assert info.value.problems[0].field == named


def test_summary_is_json(result):
    payload = json.loads(json.dumps(result.summary(), allow_nan=False))
    assert payload["status"] == "solved" and payload["options"]["cells"] is None


def test_showcase_makes_its_pictures_through_the_api_silently(tmp_path, monkeypatch, capsys):
    from cellplan.registry import packages
    from cellplan.strategies.experiments import showcase

    # The demo's recipe on the tiny cell (same modes, shorter run), to keep the suite fast.
    monkeypatch.setattr(showcase, "SCENARIO", "strategies_tiny")
    monkeypatch.setattr(showcase, "STAGES", 40)
    monkeypatch.setattr(showcase, "WITH_UR5", False)  # test_strategies_ur5.py shows that one
    items = packages()["strategies"].showcase(tmp_path)
    assert len(items) == 2
    for item in items:
        assert item.figures and all(p.is_file() and p.stat().st_size > 0 for p in item.figures)
        assert item.caption.startswith("solved: ") and "cellplan" in item.code
    assert Trajectory.load(tmp_path / "p1_simulation" / "trajectory.csv").events
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""


def test_mode_numbers_follow_the_file_order():
    """``1,1,1,W`` counts parts, sources and destinations in the order the file lists them."""
    import yaml

    from cellplan.registry import scenario_path

    data = yaml.safe_load(scenario_path("strategies_tiny").read_text())
    data["sources"] = dict(reversed(list(data["sources"].items())))  # S2 first
    setup = cellplan.loads(yaml.safe_dump(data, sort_keys=False))
    strategy = cellplan.plan(setup, "strategies", sample_stages=1).solution
    mode = strategy.modes[strategy.mode_index("1,1,1,W")]
    assert (mode.part, mode.source, mode.destination, mode.kind) == ("P1", "S2", "D1", "W")
    assert strategy.mode_index("<P1,S1,D1,W>") == strategy.mode_index("1,2,1,W")


def test_an_attached_workcell_vetoes_fmp_the_exact_test_refuses():
    """``Strategy.action`` never returns an FMP that the attached region test refuses."""
    from cellplan.strategies.policy.strategy import FMP

    setup = cellplan.load("strategies_tiny")
    strategy = cellplan.plan(setup, "strategies", sample_stages=1).solution
    mode = strategy.mode_index("1,1,1,W")
    # A configuration where the grid offers FMP: inside source S1.
    q = np.array([4.0, 3.5])
    strategy.__dict__.pop("_fmp_test", None)
    assert strategy.action(q, mode).kind == "pick" == strategy.action(q[None], mode).kind[0]
    assert strategy.action_code(q, mode) == FMP
    strategy.attach(setup.workcell)
    assert strategy.action(q, mode).kind == "pick"  # the exact test agrees here
    assert strategy.action(q, mode).region == "S1"
    strategy.__dict__["_fmp_test"] = lambda points, m: np.zeros(len(points), bool)
    assert strategy.action_code(q, mode) != FMP  # refused: the best motion instead
    assert strategy.action(q, mode).kind == "move"
