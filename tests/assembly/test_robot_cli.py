"""``cellplan assemble FILE --algorithm robot``: planner ``assembly.robot`` from the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cellplan.trajectory import Trajectory


def test_assemble_robot_writes_the_arm_trajectory_the_viewer_and_metrics(cellplan, tmp_path):
    out = tmp_path / "o"
    res = cellplan("assemble", "ur5_assembly", "--algorithm", "robot", "-o", str(out))
    assert res.returncode == 0, res.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["status"] == "solved" and metrics["algorithm"] == "robot"
    assert metrics["grasps"] >= 3 and metrics["lift"] == 0.15
    traj = Trajectory.load(out / "trajectory.csv")
    assert len(traj.columns) == 6  # the UR5's joints
    picks, places = traj.events_of("pick"), traj.events_of("place")
    assert len(picks) == len(places) == metrics["grasps"]
    assert "<html" in (out / "viewer.html").read_text()[:2000].lower()
    assert not (out / "assembly.gif").exists()


@pytest.mark.parametrize(
    ("args", "field"),
    [
        (["ur5_assembly", "--lift", "-1"], "--lift"),
        (["ur5_assembly", "--epsilon", "0.1"], "--epsilon"),
        (["--random", "3"], "--random"),
        (["discs_swap"], "robot"),
        (["ur5_assembly", "--repair", "A9"], "--repair"),
    ],
)
def test_bad_robot_input_is_one_line_and_exit_2(cellplan, tmp_path: Path, args, field):
    out = tmp_path / "o"
    res = cellplan("assemble", *args, "--algorithm", "robot", "-o", str(out))
    assert res.returncode == 2
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and field in lines[0], res.stderr
    assert "Traceback" not in res.stderr
    assert not out.exists()
