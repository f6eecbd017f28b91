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


def test_workcell_reprs_are_short_and_name_what_the_cell_holds():
    cell = cellplan.load("strategies_tiny").workcell
    assert repr(cell) == (
        "Workcell('strategies-tiny', robot=translating, dim 2, bounds=[0, 30] x [0, 30], "
        "obstacles=[middle], parts=[P1], sources=[S1 (1), S2 (1)], destinations=[D1 (1)])"
    )
    assert cell._repr_png_()[:8] == b"\x89PNG\r\n\x1a\n"
    arm = cellplan.load("ur5_cell").workcell
    text = repr(arm)
    assert text.startswith("Workcell3D('ur5_cell', robot=ur5 (urdf), dim 6, bounds=[")
    assert "sources=[bin_a (1), bin_b (1)]" in text and "array" not in text
    assert "\n" not in text


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
        cellplan.make("discs_swap", "assembly.gradient", kk=3)
    (problem,) = err.value.problems
    assert problem.field == "kk"
    assert "did you mean 'k'" in problem.message


def test_out_of_range_option_is_one_line():
    with pytest.raises(ArgumentError) as err:
        cellplan.make("discs_swap", "assembly.gradient", k=-1)
    (problem,) = err.value.problems
    assert problem.field == "k"


def test_planner_needs_its_section():
    with pytest.raises(ScenarioError) as err:
        cellplan.make("strategies_tiny", "assembly.gradient")
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


def test_the_package_lists_what_it_offers():
    # dir() shows the API, not the names the package's own code imports.
    assert dir(cellplan) == sorted([*cellplan.__all__, "__version__"])
    assert "Any" not in dir(cellplan) and "TYPE_CHECKING" not in dir(cellplan)
    assert {"simulate", "ExperiencePlanner", "draw"} <= set(cellplan.__all__)
    for name in cellplan.__all__:
        assert getattr(cellplan, name) is not None


def test_a_planner_repr_is_short():
    planner = cellplan.make("strategies_tiny", "strategies", seed=3)
    text = repr(planner)
    assert text == "Planner('strategies', setup='strategies-tiny', options={'seed': 3})"


def test_draw_returns_a_figure_and_saves_a_png(tmp_path):
    setup = cellplan.load("strategies_tiny")
    fig = cellplan.draw(setup, tmp_path / "cell.png")
    assert fig.axes and fig.axes[0].get_xlabel() == "x (workcell units)"
    assert (tmp_path / "cell.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert setup._repr_png_()[:8] == b"\x89PNG\r\n\x1a\n"  # what a notebook shows


def test_draw_of_a_3d_cell_takes_a_view_and_a_2d_one_refuses_it(tmp_path):
    fig = cellplan.draw(cellplan.load("ur5_cell"), tmp_path / "ur5.png", view="top")
    assert fig.get_size_inches()[0] > 0
    assert (tmp_path / "ur5.png").is_file()
    with pytest.raises(ArgumentError, match=r"^view: views apply to 3-D cells"):
        cellplan.draw(cellplan.load("strategies_tiny"), view="top")


def test_loads_takes_text_or_a_mapping_and_refuses_the_rest():
    import yaml

    text = cellplan.registry.scenario_path("strategies_tiny").read_text()
    from_text = cellplan.loads(text)
    from_mapping = cellplan.loads(yaml.safe_load(text))
    assert from_mapping.scenario.digest() == from_text.scenario.digest()
    with pytest.raises(ScenarioError, match="expected YAML text or a mapping, got int"):
        cellplan.loads(3)  # type: ignore[arg-type]
