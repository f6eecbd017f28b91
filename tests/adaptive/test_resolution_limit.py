"""A Reach resolution that would make every segment check pointlessly long is refused
before any work, in the library and on the command line."""

from __future__ import annotations

import math

import pytest

from cellplan.adaptive.world import MAX_SEGMENT_STEPS, World, check_resolution
from cellplan.api import load
from cellplan.errors import ScenarioError
from cellplan.registry import scenario_path


def test_a_resolution_of_1e_9_is_refused_by_the_library():
    scenario = load("adaptive_fig4").scenario
    # An arm: radians here, degrees in the message (as in the file).
    with pytest.raises(ScenarioError, match=r"adaptive.resolution 5.7\d*e-08: .* collision checks"):
        World(scenario, 1e-9)


def test_the_limit_is_the_number_of_steps_of_the_longest_segment():
    robot = load("adaptive_fig4").workcell.robot
    check_resolution(robot, 1.0)  # the bundled value
    widths = [
        math.pi if periodic else u - lo
        for lo, u, periodic in zip(robot.lower, robot.upper, robot.periodic, strict=True)
    ]
    coarse_enough = math.hypot(*widths) / MAX_SEGMENT_STEPS * 1.01
    check_resolution(robot, coarse_enough)
    with pytest.raises(ScenarioError):
        check_resolution(robot, coarse_enough / 1.1)


def test_adapt_refuses_it_in_one_line(cellplan, tmp_path):
    text = scenario_path("adaptive_fig4").read_text()
    assert "resolution: 1.0" in text
    path = tmp_path / "fine.yaml"
    path.write_text(text.replace("resolution: 1.0", "resolution: 1.0e-9"))
    r = cellplan("adapt", str(path), "-o", str(tmp_path / "out"))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "adaptive.resolution 1e-09" in lines[0], r.stderr
    assert not (tmp_path / "out").exists()
