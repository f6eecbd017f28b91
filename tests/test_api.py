"""The planning API: load, make, plan, option validation, and adding a package."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import cellplan
from cellplan import registry
from cellplan.errors import ArgumentError, ScenarioError


def test_load_gives_scenario_and_workcell():
    setup = cellplan.load("strategies_tiny")
    assert setup.scenario.strategy is not None
    assert setup.workcell.robot.dim == 2
    assert setup.workcell is setup.workcell  # built once


def test_disc_scenario_has_no_workcell():
    setup = cellplan.load("discs_swap")
    with pytest.raises(ScenarioError, match="no robot"):
        _ = setup.workcell


def test_unknown_planner_suggests_the_close_name():
    with pytest.raises(ArgumentError) as err:
        cellplan.plan("strategies_tiny", "strategy")
    assert "did you mean 'strategies'" in str(err.value)


def test_option_typo_is_named_with_a_suggestion():
    with pytest.raises(ArgumentError) as err:
        cellplan.make("assembly.gradient", "discs_swap", kk=3)
    (problem,) = err.value.problems
    assert problem.field == "kk"
    assert "did you mean 'k'" in problem.message


def test_out_of_range_option_is_one_line():
    with pytest.raises(ArgumentError) as err:
        cellplan.make("assembly.gradient", "discs_swap", k=-1)
    (problem,) = err.value.problems
    assert problem.field == "k"


def test_planner_needs_its_section():
    with pytest.raises(ScenarioError) as err:
        cellplan.make("assembly.gradient", "strategies_tiny")
    assert err.value.problems[0].field == "discs"


def test_options_name_cli_flags():
    spec = registry.planner("assembly.gradient")
    with pytest.raises(ArgumentError) as err:
        registry.parse_options(spec, {"no_such": 1}, flag=True)
    assert err.value.problems[0].field == "--no-such"


def test_arm_configuration_in_degrees_is_refused():
    cell = cellplan.load("strategies_p5").workcell
    with pytest.raises(ArgumentError, match="radians"):
        cell.collides(np.array([[90.0, -90.0, 0.0]]))
    assert cell.collides(np.radians([[90.0, -90.0, 0.0]])).shape == (1,)


def test_a_new_package_needs_no_core_change(monkeypatch):
    monkeypatch.setattr(registry, "BUILTIN_PACKAGES", (*registry.BUILTIN_PACKAGES, "toy_package"))
    registry.packages.cache_clear()
    registry.planners.cache_clear()
    try:
        from cellplan.scenario import build_scenario_model

        model = build_scenario_model()
        assert "toy" in model.model_fields
        text = (
            "cellplan: 1\nworkcell: {bounds: {xmin: 0, ymin: 0, xmax: 10, ymax: 10}}\n"
            "robot: {type: point, start: [1, 1]}\ntoy: {goal: [9, 9]}\n"
        )
        import yaml

        scenario = model.model_validate(yaml.safe_load(text))
        result = cellplan.plan(scenario, "toy.straight", samples=5)
        assert result.success and result.planner == "toy.straight"
        assert result.trajectory.q[-1].tolist() == [9.0, 9.0]
        assert "toy.straight" in cellplan.planners()
    finally:
        registry.packages.cache_clear()
        registry.planners.cache_clear()


def test_import_cellplan_loads_no_planner_code():
    code = (
        "import sys, cellplan; cellplan.load('discs_seven'); cellplan.load('strategies_p1');"
        "heavy = [m for m in sys.modules if m.startswith(('numba', 'ompl', 'matplotlib'))"
        " or m.endswith(('.navigation', '.flows', '.solver', '.kernels'))];"
        "print(heavy)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
