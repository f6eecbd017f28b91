"""Every registered planner obeys the contract (the Gymnasium-style conformance check).

The check ships as :func:`cellplan.testing.check_planner`, so a plug-in from another
distribution runs the same one. For each planner, its smoke problem is planned through
the public API twice with the same options. The result must be a :class:`Result` with a
:class:`Status`, a one-line message, finite statistics and a non-empty
:class:`Trajectory` that round-trips through CSV and JSON; the smoke problem must be
*solved* (a planner that always reports stuck fails here); and the run must be
deterministic (timing statistics aside).
"""

from __future__ import annotations

import functools
import gc
import pickle

import numpy as np
import pytest

import cellplan
from cellplan.core import Options, Result, Status
from cellplan.registry import packages as registry_packages
from cellplan.registry import scenario_names
from cellplan.testing import ConformanceError, check_planner
from cellplan.trajectory import Trajectory

PLANNERS = cellplan.planners()
TIMING = ("time", "seconds", "wall")


def _deterministic_part(stats):
    return {k: v for k, v in stats.items() if not any(t in k for t in TIMING)}


def test_every_package_registers_planners():
    packages = {spec.package for spec in PLANNERS.values()}
    assert {"strategies", "adaptive", "assembly"} <= packages


def test_registry_entries_are_well_formed():
    for name, spec in PLANNERS.items():
        assert name == spec.name
        assert name == spec.package or name.startswith(spec.package + ".")
        assert spec.summary
        assert issubclass(spec.options, Options)
        scenario, options = spec.smoke
        assert scenario in scenario_names()
        spec.options.model_validate(dict(options))  # the smoke options are valid options
        for key, _default, description in spec.option_table():
            assert description, f"{name}: option {key} has no description"


@functools.cache
def _two_runs(name):
    """Two runs of the planner's smoke problem, checked by the shipped conformance check
    (:func:`cellplan.testing.check_planner`), shared by the tests below."""
    runs = check_planner(name)
    gc.collect()
    return runs


@pytest.mark.parametrize("name", sorted(PLANNERS))
def test_planner_conformance(name):
    # Raises ConformanceError, listing every rule broken, for a planner that breaks one.
    first, second = _two_runs(name)
    for result in (first, second):
        assert isinstance(result, Result) and result.planner == name
        assert result.status is Status.SOLVED and result.success


@pytest.mark.parametrize("name", sorted(PLANNERS))
def test_result_pickles(name):
    """A Result crosses to a multiprocessing or Dask worker (issue 36): no closures inside.
    Pickling our own object only; cellplan never loads a pickle it did not write."""
    first, _ = _two_runs(name)
    copy = pickle.loads(pickle.dumps(first))
    assert copy.status is first.status
    assert copy.message == first.message
    assert dict(copy.stats) == dict(first.stats)
    assert copy.trajectory == first.trajectory
    assert type(copy.solution) is type(first.solution)


@pytest.mark.parametrize("name", sorted(n for n, s in PLANNERS.items() if s.deterministic))
def test_planner_is_deterministic(name):
    first, second = _two_runs(name)
    assert _deterministic_part(first.stats) == _deterministic_part(second.stats)
    assert np.array_equal(first.trajectory.q, second.trajectory.q)


def test_only_thread_timed_planners_are_declared_nondeterministic():
    assert sorted(n for n, s in PLANNERS.items() if not s.deterministic) == ["adaptive.prm"]


@pytest.mark.parametrize("name", sorted(PLANNERS))
def test_unknown_option_is_one_line_naming_it(name):
    spec = PLANNERS[name]
    scenario, _ = spec.smoke
    with pytest.raises(cellplan.ArgumentError) as err:
        cellplan.make(scenario, name, no_such_option=1)
    assert [p.field for p in err.value.problems] == ["no_such_option"]


def test_a_package_for_planar_cells_refuses_a_3d_cell_in_one_line(monkeypatch):
    """A package that declares 2-D workcells only (here the toy package of
    tests/toy_package.py) has a 3-D cell with its section refused when the scenario is
    loaded, in one line naming the section; the papers' packages declare both kinds."""
    import yaml

    from cellplan import registry
    from cellplan import scenario as scenario_module
    from cellplan.errors import ScenarioError
    from cellplan.scenario import parse_yaml, scenario_from_data

    monkeypatch.setattr(registry, "BUILTIN_PACKAGES", (*registry.BUILTIN_PACKAGES, "toy_package"))
    registry.packages.cache_clear()
    registry.planners.cache_clear()
    # The scenario model is built at import from the registered packages: rebuild it.
    monkeypatch.setattr(scenario_module, "Scenario", scenario_module.build_scenario_model())
    try:
        assert registry.packages()["toy"].workcells == ("2d",)
        data = parse_yaml(registry.scenario_path("ur5_cell").read_text())
        data["toy"] = yaml.safe_load("goal: [0.3, 0.2]")
        with pytest.raises(ScenarioError) as err:
            scenario_from_data(data)
    finally:
        monkeypatch.undo()
        registry.packages.cache_clear()
        registry.planners.cache_clear()
        lines = str(err.value).splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("toy: the toy planners work in 2d workcells; this one is 3d")


def test_every_package_declares_its_workcell_kinds():
    kinds = {name: set(pkg.workcells) for name, pkg in registry_packages().items()}
    assert all(k and k <= {"2d", "3d"} for k in kinds.values()), kinds


@pytest.mark.parametrize(
    "package", sorted(n for n, p in registry_packages().items() if "3d" in p.workcells)
)
def test_a_package_for_3d_cells_has_a_bundled_3d_scenario(package):
    """Each package that declares 3-D workcells runs on one of the bundled 3-D cells."""
    from cellplan.registry import scenario_names
    from cellplan.scenario3d import is_3d

    pkg = registry_packages()[package]
    bundled = [cellplan.load(n) for n in scenario_names()]
    ours = [
        s.name for s in bundled if is_3d(s.scenario) and pkg.section in s.scenario.section_names()
    ]
    assert ours, f"no bundled 3-D scenario has a '{pkg.section}:' section"


def _toy_line(setup, samples: int):
    """A straight line from the robot's start, 1 unit along its first axis."""
    from cellplan.units import axis_units

    start = setup.workcell.robot.start
    s = np.linspace(0.0, 1.0, samples)
    q = start + s[:, None] * np.eye(len(start))[0]
    names = setup.workcell.robot.axis_names
    modes = np.zeros(samples, np.int64)
    return Trajectory(s, q, modes, ("moving",), names, axis_units(names), "path")


def _toy_spec(name, run):
    from cellplan.core import PlannerSpec
    from toy_package import StraightOptions

    return PlannerSpec(name, "toy", "a toy planner of the conformance tests", StraightOptions, run)


def test_check_planner_passes_a_plugin_planner_that_keeps_the_contract():
    # A planner registered nowhere (a plug-in under development) is checked from its spec.
    def run(setup, options, progress):
        traj = _toy_line(setup, options.samples)
        stats = {"length": 1.0}
        return Result(Status.SOLVED, "a line", stats=stats, solution=traj.q, trajectory=traj)

    first, second = check_planner(_toy_spec("toy.line", run), "strategies_tiny")
    assert first.planner == "toy.line" and first.status is Status.SOLVED
    assert np.array_equal(first.trajectory.q, second.trajectory.q)


def test_check_planner_catches_a_broken_toy_planner():
    calls = []

    def run(setup, options, progress):
        calls.append(1)
        traj = _toy_line(setup, options.samples + len(calls))  # differs from run to run
        return Result(
            Status.STUCK,
            "stuck\nat the start",
            stats={"length": float("nan"), "count": np.int64(3)},
            solution=traj.q,
            trajectory=traj,
        )

    with pytest.raises(ConformanceError) as err:
        check_planner(_toy_spec("toy.broken", run), "strategies_tiny")
    failures = err.value.failures
    text = "\n".join(failures)
    assert "message is not one line" in text
    assert "stats:" in text and "did not solve" in text
    assert all(f.startswith(("run 1:", "run 2:")) for f in failures)
    assert str(err.value).startswith("planner toy.broken breaks")


def test_check_planner_catches_a_bad_registry_entry():
    def run(setup, options, progress):
        raise AssertionError("not reached: the entry is checked first")

    with pytest.raises(ConformanceError) as err:
        check_planner(_toy_spec("other.name", run), "strategies_tiny")
    assert err.value.failures == ["its name is not 'toy' or 'toy.<variant>'"]


def test_check_planner_catches_a_nondeterministic_planner():
    calls = []

    def run(setup, options, progress):
        calls.append(1)
        traj = _toy_line(setup, options.samples)
        traj = Trajectory(
            traj.t, traj.q * len(calls), traj.mode, traj.modes, traj.columns, traj.units, "path"
        )
        stats = {"runs": len(calls)}
        return Result(Status.SOLVED, "a line", stats=stats, solution=traj.q, trajectory=traj)

    with pytest.raises(ConformanceError) as err:
        check_planner(_toy_spec("toy.random", run), "strategies_tiny")
    assert err.value.failures == [
        "declared deterministic, but two runs differ in stats ['runs']",
        "declared deterministic, but two runs give different trajectories",
    ]
