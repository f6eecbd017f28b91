"""The ``adaptive`` planners through cellplan.api: result contract, trajectory, failures."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from adaptive_scenarios import POINT_SCENARIO  # type: ignore[import-not-found]

import cellplan.api as api
from cellplan.adaptive import ExperiencePlanner
from cellplan.core import Status, check_stats
from cellplan.errors import ArgumentError
from cellplan.trajectory import Trajectory

TASKS = ["g1", "home", "g1", "g2", "home", "g1", "home"]

# g3 sits in a pocket closed by two fences and the workcell's corner: a valid goal
# (free, within the bounds) that no path reaches.
POCKET_SCENARIO = (
    POINT_SCENARIO.replace(
        "    A: {type: box, min: [4.0, 0.0], max: [6.0, 7.0]}\n",
        "    A: {type: box, min: [4.0, 0.0], max: [6.0, 7.0]}\n"
        "    F1: {type: box, min: [7.0, 7.0], max: [10.0, 7.3]}\n"
        "    F2: {type: box, min: [7.0, 7.0], max: [7.3, 10.0]}\n",
    )
    .replace(
        "  tasks: [g1, home, g1, g2, home, g1, home]",
        "  max_solve_checks: 2000\n  tasks: [g1, g3, home]",
    )
    .replace(
        "    g2: {at: [6.5, 3.0], object: A}\n",
        "    g2: {at: [6.5, 3.0], object: A}\n    g3: {at: [8.5, 8.5]}\n",
    )
)


def _cellplan(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cellplan.cli", *args], capture_output=True, text=True, timeout=300
    )


def test_adaptive_planner_returns_the_executed_paths(tmp_path: Path) -> None:
    setup = api.loads(POINT_SCENARIO)
    seen: list[tuple[float, float | None, str]] = []
    res = api.plan(setup, "adaptive", progress=lambda d, t, s: seen.append((d, t, s)))
    assert res.status is Status.SOLVED and res.planner == "adaptive"
    assert res.message.startswith("7 of 7 tasks solved") and not check_stats(res.stats)
    assert res.stats["tasks"] == 7 and res.stats["solved"] == 7 and res.stats["ratio"] > 0
    assert [d for d, _, _ in seen] == list(range(1, 8)) and seen[-1][1] == 7
    ep = res.solution
    assert isinstance(ep, ExperiencePlanner) and len(ep.tasks) == 7
    traj = res.trajectory
    assert traj is not None and traj.time_unit == "path" and traj.columns == ("x", "y")
    starts = traj.events_of("task")
    arrivals = traj.events_of("arrive")
    assert [e.detail for e in starts] == TASKS == [e.detail for e in arrivals]
    assert not traj.events_of("fail")
    # the change after task 4 is marked at the start of task 5
    (change,) = traj.events_of("change")
    assert change.detail == "add_object C" and change.index == starts[4].index
    names = traj.mode_names
    for start, arrive in zip(starts, arrivals, strict=True):
        assert set(names[start.index : arrive.index + 1]) == {start.detail}
        assert np.allclose(traj.q[arrive.index], ep.goals[start.detail])
    # each task starts where the previous one arrived, and t is the path length so far
    for prev, nxt in zip(arrivals[:-1], starts[1:], strict=True):
        assert np.array_equal(traj.q[prev.index], traj.q[nxt.index])
    assert np.isclose(traj.duration, traj.length()) and res.stats["path_length"] == traj.duration
    for suffix in ("csv", "json"):
        assert Trajectory.load(traj.save(tmp_path / f"paths.{suffix}")) == traj


def test_peers_return_paths_over_the_same_tasks() -> None:
    setup = api.loads(POINT_SCENARIO)
    res = api.plan(setup, "adaptive.rrtconnect", tasks=3, seed=1)
    assert res.success and res.stats["tasks"] == 3 and res.stats["checks"] > 0
    assert [e.detail for e in res.trajectory.events_of("arrive")] == TASKS[:3]  # type: ignore[union-attr]


def test_options_are_validated_by_name() -> None:
    setup = api.loads(POINT_SCENARIO)
    with pytest.raises(ArgumentError, match="repair"):
        api.plan(setup, "adaptive", repair="A9")
    with pytest.raises(ArgumentError, match="did you mean 'tasks'"):
        api.plan(setup, "adaptive", task=3)
    with pytest.raises(ArgumentError, match="tasks"):
        api.plan(setup, "adaptive", tasks=99)


def test_an_unreachable_goal_fails_the_run_and_names_the_task(tmp_path: Path) -> None:
    setup = api.loads(POCKET_SCENARIO)
    res = api.plan(setup, "adaptive", baseline=False)
    assert res.status is Status.FAILED
    assert "tasks failed: 2 (g3)" in res.message
    fails = res.trajectory.events_of("fail")  # type: ignore[union-attr]
    assert [e.detail for e in fails] == ["g3"]
    # the robot stayed where it was and the next task went on from there
    assert res.stats["solved"] == 2
    scenario = tmp_path / "pocket.yaml"
    scenario.write_text(POCKET_SCENARIO, encoding="utf-8")
    run = _cellplan("adapt", str(scenario), "--no-baseline", "-o", str(tmp_path / "o"))
    assert run.returncode == 1, run.stderr
    assert run.stdout.startswith("failed: 1 of 3 tasks failed: 2 (g3)")
    as_json = _cellplan("adapt", str(scenario), "--json", "-o", str(tmp_path / "o"))
    assert as_json.returncode == 1, as_json.stderr
    payload = json.loads(as_json.stdout)
    assert payload["status"] == "failed" and "2 (g3)" in payload["message"]
    assert Path(payload["outputs"]["paths"]).is_file()


def test_the_python_examples_of_the_docs_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import re

    doc = Path(__file__).resolve().parents[2] / "docs" / "adaptive.md"
    blocks = re.findall(r"```python\n(.*?)```", doc.read_text(encoding="utf-8"), re.S)
    assert len(blocks) >= 2
    monkeypatch.chdir(tmp_path)
    for block in blocks:
        namespace: dict[str, object] = {}
        exec(compile(block, str(doc), "exec"), namespace)
    assert Trajectory.load(tmp_path / "paths.csv").events_of("arrive")
    assert (tmp_path / "exp.sqlite").is_file()


def test_showcase_draws_figure_3_through_the_api_without_printing(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    from cellplan.adaptive.plugin import PACKAGE

    assert PACKAGE.showcase is not None
    item = PACKAGE.showcase(tmp_path)[0]  # Figure 3 first; the UR5 item follows
    assert capfd.readouterr() == ("", "")
    (figure,) = item.figures
    assert Path(figure).stat().st_size > 10_000 and "cellplan.plan" in item.code
    assert "11 of 11 tasks solved" in item.caption


def _fig3_with_box_on_parked_robot(more: str = "") -> str:
    """adaptive_fig3 with box D dropped after task 2 on the robot, parked at w2 = (3.5,
    9.5), followed by the changes ``more`` (YAML list items)."""
    from cellplan.registry import resolve_scenario_path

    text = resolve_scenario_path("adaptive_fig3").read_text(encoding="utf-8")
    return text.replace(
        "  changes:\n",
        "  changes:\n"
        "    - after_task: 2\n"
        "      type: add_object\n"
        "      object: D\n"
        "      shape: {type: box, min: [3.3, 9.3], max: [3.7, 9.7]}\n" + more,
    )


def test_validate_refuses_a_change_that_lands_on_the_parked_robot(cellplan, tmp_path: Path) -> None:
    text = _fig3_with_box_on_parked_robot()
    path = tmp_path / "parked.yaml"
    path.write_text(text, encoding="utf-8")
    lines = [line for line in cellplan("validate", str(path)).stderr.splitlines() if line]
    expected = (
        "error: adaptive.changes[0]: puts an obstacle on the robot, parked at goal 'w2' "
        "after task 2"
    )
    assert expected in lines, lines
    adapt = cellplan("adapt", str(path), "-o", str(tmp_path / "out"))
    assert adapt.returncode == 2 and not (tmp_path / "out").exists()
    assert [line for line in adapt.stderr.splitlines() if line] == lines


def test_a_stage_of_changes_acts_together_and_is_checked_once(
    cellplan, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A box dropped on the parked robot and removed again at the same task never meets
    the robot: the preflight and the run both check a stage after its last change, and
    the goals are solved once a stage however many changes it holds (a fuzzed file with
    5,001 moves at one task took over a minute to validate)."""
    from cellplan.adaptive import world as world_module
    from cellplan.scenario import loads_scenario

    moves = "".join(
        "    - {after_task: 2, type: move_object, object: D, by: [0.01, 0.0]}\n"
        "    - {after_task: 2, type: move_object, object: D, by: [-0.01, 0.0]}\n"
        for _ in range(100)
    )
    text = _fig3_with_box_on_parked_robot(
        moves + "    - {after_task: 2, type: remove_object, object: D}\n"
    )
    calls: list[str] = []
    real = world_module.World.goal_problems

    def counted(self: world_module.World, where: str, when: str = "", skip=()) -> list:
        calls.append(when)
        return real(self, where, when, skip)

    monkeypatch.setattr(world_module.World, "goal_problems", counted)
    world_module.preflight(loads_scenario(text), None, 0)
    # once before the changes, then once for each of the file's four stages (tasks 2, 5, 6, 8)
    assert len(calls) == 5, calls
    assert calls[1] == " after the 202 changes adaptive.changes[0, 1, 2, 3, ...] (after task 2)"

    path = tmp_path / "together.yaml"
    path.write_text(text, encoding="utf-8")
    adapt = cellplan("adapt", str(path), "-o", str(tmp_path / "out"))
    assert adapt.returncode == 0, adapt.stderr
