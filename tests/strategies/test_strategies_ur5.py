"""The strategies paper on the first three joints of a UR5 (``strategies_ur5``, issue 31).

The model is built through the validity interface from a 3-D workcell; what the section
refuses in 3-D is refused in one line; the behaviours are measured on a cut-down copy of
the bundled scenario (one request, which crosses the gate) so that the file runs in well
under a minute; the whole scenario's claims are decided by ``cellplan reproduce
strategies --only strategies.ur5`` (and the slow test at the end).
"""

from __future__ import annotations

import copy
import functools

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

import cellplan
from cellplan.errors import ScenarioError
from cellplan.registry import scenario_path
from cellplan.scenario import scenario_from_data
from cellplan.strategies.experiments import arm_behaviours, ur5_experiment
from cellplan.strategies.policy.strategy import FMP


def _data(name: str = "strategies_ur5") -> dict:
    return yaml.safe_load(scenario_path(name).read_text())


def _refusal(data: dict) -> list[str]:
    with pytest.raises(ScenarioError) as err:
        scenario_from_data(data)
    return str(err.value).splitlines()


# --- what a 3-D cell can take ------------------------------------------------------------


def test_the_six_joint_ur5_of_ur5_cell_is_refused_in_one_line_naming_robot_joints():
    data = _data("ur5_cell")
    data["strategy"] = _data("strategies_tiny")["strategy"]
    lines = _refusal(data)
    assert len(lines) == 1
    assert lines[0].startswith("robot.joints: lists none; the strategies grid holds 1 to 3")


def test_four_active_joints_are_refused_in_one_line():
    data = _data()
    data["robot"]["joints"] = [*data["robot"]["joints"], "wrist_1_joint"]
    del data["robot"]["locked"]["wrist_1_joint"]
    data["robot"]["start"] = [*data["robot"]["start"], -90]
    lines = _refusal(data)
    assert lines == [
        "robot.joints: lists 4; the strategies grid holds 1 to 3 active joints of a 3-D arm: "
        "list them and lock the others (robot.locked)"
    ]


@pytest.mark.parametrize(
    ("key", "value", "field"),
    [
        ("noise", {"outcomes": [{"offset": [0, 0, 0], "probability": 1.0}]}, "strategy.noise"),
        ("period", 4, "strategy.period"),
        ("max_pending", 2, "strategy.max_pending"),
        (
            "fine_motion",
            {"time": 2.0, "point": [0.3, 0.4], "rate": 1.0},
            "strategy.fine_motion.point",
        ),
    ],
)
def test_section_vi_extensions_are_refused_in_a_3d_cell_in_one_line(key, value, field):
    data = _data()
    data["strategy"][key] = value
    lines = _refusal(data)
    assert lines == [f"{field}: is not available in a 3-D workcell yet (the Section V model is)"]


def test_the_bundled_scenario_loads_with_a_three_joint_grid():
    setup = cellplan.load("strategies_ur5")
    assert setup.scenario.strategy.cells == [48, 48, 48]
    assert setup.workcell.robot.dim == 3
    assert setup.workcell.geometry == "spheres"


def test_plot_refuses_a_3d_cell_in_one_line_before_reading_the_strategy(cellplan, tmp_path):
    unread = tmp_path / "unread.npz"
    unread.write_bytes(b"not read")
    r = cellplan(
        "plot",
        "strategies_ur5",
        "--strategy",
        str(unread),
        "--mode",
        "NR",
        "-o",
        str(tmp_path / "x.png"),
    )
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        "error: workcell: this needs a 2-D workcell; this one is 3-D"
    ]
    assert not (tmp_path / "x.png").exists()


# --- the workspace bound the simulator's exact collision test samples with ----------------


@functools.cache
def _cell():
    return cellplan.load("strategies_ur5").workcell


@settings(max_examples=25, deadline=None)
@given(
    st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3),
    st.lists(st.floats(-0.2, 0.2), min_size=3, max_size=3),
    st.floats(0.0, 0.3),
)
def test_workspace_step_bounds_how_far_the_arm_and_tool_points_move(u, dq, reach):
    """Oracle: the sphere centres (FK) and points ``reach`` from the tool origin, sampled
    densely along the segment, never move farther than the bound."""
    from cellplan import arm as arms

    cell = _cell()
    robot = cell.robot
    q0 = robot.lower + (np.asarray(u) + 1.0) / 2.0 * (robot.upper - robot.lower)
    d = np.asarray(dq)
    bound = float(robot.workspace_step(d[None], reach)[0])
    t = np.linspace(0.0, 1.0, 41)[:, None]
    qs = q0 + t * d
    centres = arms.sphere_centers(robot.arm, qs)
    moved = np.linalg.norm(centres - centres[:1], axis=-1).max()
    tool = robot.tool_pose(qs)
    offsets = reach * np.vstack([np.eye(3), -np.eye(3)])
    points = tool[:, None, :3, 3] + np.einsum("tij,kj->tki", tool[:, :3, :3], offsets)
    moved_tool = np.linalg.norm(points - points[:1], axis=-1).max()
    assert max(moved, moved_tool) <= bound + 1e-9


# --- behaviours on a cut-down copy: one request across the gate ----------------------------


@functools.cache
def _one_request():
    data = copy.deepcopy(_data())
    data["strategy"]["requests"] = [{"part": "P1", "source": "S1", "destination": "D2"}]
    data["sources"] = {"S1": data["sources"]["S1"]}
    scenario = scenario_from_data(data, folder=scenario_path("strategies_ur5").parent)
    setup = cellplan.Setup(scenario, "strategies_ur5 (one request)")
    result = cellplan.plan(setup, "strategies", sample_stages=60, seed=1)
    return setup, result


def test_a_destination_out_of_reach_is_refused_before_solving_naming_it():
    data = copy.deepcopy(_data())
    data["strategy"]["requests"] = [{"part": "P1", "source": "S1", "destination": "D2"}]
    data["sources"] = {"S1": data["sources"]["S1"]}
    data["destinations"]["D2"]["components"][0]["pose"]["xyz"] = [0.9, 0.9, 1.7]
    setup = cellplan.Setup(scenario_from_data(data), "strategies_ur5 (D2 out of reach)")
    with pytest.raises(ScenarioError) as err:
        cellplan.plan(setup, "strategies")
    lines = str(err.value).splitlines()
    assert "strategy.requests <P1,S1,D2>: part 'P1' cannot be delivered anywhere in " in lines[-1]
    assert "destination 'D2'" in lines[-1]


def test_the_planner_solves_a_3d_cell_and_its_sample_run_is_collision_free():
    setup, result = _one_request()
    assert result.status == cellplan.Status.SOLVED, result.message
    assert result.trajectory is not None and result.trajectory.q.shape[1] == 3
    # The simulator's own exact check (first_collision) ran on the 3-D cell; confirm it
    # independently: every stage's motion, with the part of its mode, sampled finely.
    from cellplan.strategies.sim.records import carried_part

    strategy = result.solution
    q = result.trajectory.q
    modes = [strategy.mdp.modes[strategy.mode_index(m)] for m in result.trajectory.mode_names]
    cell = setup.workcell
    for k in range(len(q) - 1):
        part = carried_part(modes[k])
        assert not cell.motion_collides(q[k : k + 1], q[k + 1 : k + 2], 0.005, part, "none")[0]


def test_empty_the_arm_passes_under_the_gate_and_carrying_it_detours():
    setup, result = _one_request()
    strategy, cell = result.solution, setup.workcell
    seen = arm_behaviours.detour_where_empty_fits(
        strategy, cell, np.random.default_rng(0), 8, ("P1", "S1", "D2"), ur5_experiment.GATE
    )
    assert len(seen) == 8
    assert np.mean([s.shown for s in seen]) > 0.5
    assert np.mean([s.loaded_stages for s in seen]) > np.mean([s.empty_stages for s in seen])


def test_execute_ends_in_an_fmp_that_the_exact_region_test_allows():
    setup, result = _one_request()
    strategy, cell = result.solution, setup.workcell
    waiting = strategy.mode_index("P1,S1,D2,W")
    rng = np.random.default_rng(3)
    for q in arm_behaviours.live_starts(strategy, [waiting], 4, rng):
        path, u = arm_behaviours.execute(strategy, cell, q, waiting)
        assert u == FMP
        assert cell.in_region(path[-1][None], "S1", "contact", None, None)[0]


def test_cells_of_and_crossings_agree_with_a_direct_count():
    _, result = _one_request()
    strategy = result.solution
    mdp = strategy.mdp
    rng = np.random.default_rng(5)
    q = mdp.lower + rng.random((50, 3)) * (mdp.upper - mdp.lower)
    flat = arm_behaviours._cells_of(strategy, q)
    idx = np.array(np.unravel_index(flat, tuple(mdp.shape))).T
    centres = mdp.lower + (idx + 0.5) * mdp.spacing
    assert np.all(np.abs(centres - q) <= mdp.spacing / 2 + 1e-12)
    path = np.array([[-0.2, 0, 0], [-0.1, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [-0.3, 0, 0]])
    assert arm_behaviours._crossings(path, 0, 0.0) == [1, 3]


def test_the_simulated_motion_plays_in_a_viewer_page(tmp_path):
    from cellplan.strategies.commands import write_motion_viewer
    from cellplan.strategies.sim.simulate import simulate_result

    setup, result = _one_request()
    run = simulate_result(result.solution, 40, 2, cell=setup.workcell)
    page = write_motion_viewer(result.solution, setup, run.solution, tmp_path / "viewer.html")
    text = page.read_text()
    assert "<html" in text.lower()
    assert page.stat().st_size > 10_000  # meshcat's viewer inlined, and the motion


def test_the_ur5_showcase_draws_a_run_and_writes_its_viewer_page(tmp_path, monkeypatch, capsys):
    from cellplan.strategies.experiments import showcase

    data = copy.deepcopy(_data())
    data["strategy"]["requests"] = [{"part": "P1", "source": "S1", "destination": "D2"}]
    data["sources"] = {"S1": data["sources"]["S1"]}
    path = tmp_path / "ur5_one.yaml"
    path.write_text(yaml.safe_dump(data))
    monkeypatch.setattr(showcase, "UR5_SCENARIO", str(path))
    monkeypatch.setattr(showcase, "UR5_STAGES", 60)
    item = showcase.ur5_showcase(tmp_path / "show")
    assert len(item.figures) == 3
    assert all(p.is_file() and p.stat().st_size > 0 for p in item.figures)
    assert (tmp_path / "show" / "ur5_simulation.html").is_file()
    assert item.caption.startswith("solved: ") and "cellplan.plan" in item.code
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""


# --- the experiment's claims ---------------------------------------------------------------


def _rows(values: list[float], starts: int = 40) -> list[dict]:
    return [
        {"seed": i, "starts": starts, "idle": v, "component": v, "detour": v}
        for i, v in enumerate(values)
    ]


def test_claims_are_decided_on_the_95_percent_interval_with_five_seeds():
    high = ur5_experiment.claims(_rows([0.9, 0.85, 0.95, 0.9, 0.88]))
    low = ur5_experiment.claims(_rows([0.1, 0.2, 0.15, 0.1, 0.12]))
    few = ur5_experiment.claims(_rows([0.9, 0.95]))
    assert [c.reproduced for c in high] == [True] * 3
    assert [c.reproduced for c in low] == [False] * 3
    assert [c.reproduced for c in few] == [None] * 3
    assert all(c.n == 5 and "at least 5 seeds" in c.rule for c in high)


def test_the_quick_version_runs_the_seeds_asked_with_fewer_starts():
    quick = ur5_experiment.make_runs(10, quick=True)
    full = ur5_experiment.make_runs(10, quick=False)
    assert [r.seed for r in quick] == [r.seed for r in full] == list(range(10))
    assert quick[0].params["starts"] <= full[0].params["starts"]


@pytest.mark.slow
def test_the_bundled_scenario_shows_the_three_behaviours():
    """The whole scenario (about a minute): what the report's experiment measures, for one
    seed; the fast tests above cover the same code on one request."""
    row = ur5_experiment.run(
        cellplan.core.RunSpec("strategies.ur5", {"cells": "48,48,48", "starts": 20}, 0)
    )
    assert row["idle"] > 0.5 and row["component"] > 0.5 and row["detour"] > 0.5
