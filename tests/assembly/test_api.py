"""The assembly planners through the planning API and the ``assemble`` command.

Each planner on a small bundled problem (solved; the trajectory's columns, modes and
events; CSV and JSON round trips), option validation, one source per default, the
command's exit statuses and JSON, the showcase, and that loading a disc scenario runs
no algorithm code.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import cellplan
from cellplan.assembly.layout import rule_k
from cellplan.assembly.options import SEQUENTIAL_TOLERANCE, GradientOptions
from cellplan.assembly.problems import random_setup
from cellplan.assembly.section import DiscsSection
from cellplan.cli import app
from cellplan.core import Result, Status
from cellplan.errors import ArgumentError
from cellplan.trajectory import Trajectory

from .assembly_scenarios import JAM

runner = CliRunner()
COLUMNS = ("disc1.x", "disc1.y", "disc2.x", "disc2.y", "disc3.x", "disc3.y")
SECTION_K = DiscsSection.model_fields["k"].default


@pytest.fixture(scope="module")
def swap() -> cellplan.Setup:
    return cellplan.load("discs_swap")


def _traj(result: Result) -> Trajectory:
    assert result.trajectory is not None
    return result.trajectory


def _round_trips(traj: Trajectory, tmp_path: Path) -> None:
    for suffix in (".csv", ".json"):
        assert Trajectory.load(traj.save(tmp_path / f"traj{suffix}")) == traj


@pytest.mark.parametrize(
    ("planner", "time_unit"),
    [("assembly.gradient", "path"), ("assembly.control", "s")],
)
def test_all_discs_planners_solve_and_give_the_motion(
    swap: cellplan.Setup, planner: str, time_unit: str, tmp_path: Path
) -> None:
    result = cellplan.plan(swap, planner)
    assert result.status is Status.SOLVED and result.planner == planner
    assert result.message.startswith(("assembled", "at rest"))
    traj = _traj(result)
    run = result.solution
    assert traj.columns == COLUMNS and set(traj.units) == {"workcell"}
    assert traj.time_unit == time_unit and traj.modes == ("all discs",)
    assert traj.events == ()
    # the trajectory is the run's path, disc by disc, from the start to the goal
    np.testing.assert_array_equal(traj.q, run.path.reshape(len(run.path), -1))
    np.testing.assert_array_equal(traj.q[0], run.problem.start.reshape(-1))
    assert np.linalg.norm(traj.q[-1] - run.problem.goal.reshape(-1)) < 1e-3
    assert traj.t[0] == 0.0 and np.all(np.diff(traj.t) > 0)
    if time_unit == "path":  # t is the length travelled in R^2n
        assert traj.t[-1] == pytest.approx(result.stats["length"])
    else:
        assert traj.t[-1] == pytest.approx(result.stats["settling_time"])
    assert traj.meta["k"] == 32.0  # the file's k
    _round_trips(traj, tmp_path)


@pytest.mark.parametrize("rule", ["paper", "place"])
def test_sequential_moves_one_disc_at_a_time_with_grasp_events(
    swap: cellplan.Setup, rule: str, tmp_path: Path
) -> None:
    result = cellplan.plan(swap, "assembly.sequential", rule=rule)
    assert result.status is Status.SOLVED
    traj, run = _traj(result), result.solution
    assert traj.columns == COLUMNS and traj.time_unit == "path"
    grasps = traj.events_of("grasp")
    assert len(grasps) == run.switches == result.stats["switches"]
    assert [e.detail for e in grasps] == [f"disc {g.disc + 1}" for g in run.grasps]
    switches = traj.events_of("switch")
    changes = sum(a.disc != b.disc for a, b in zip(run.grasps, run.grasps[1:], strict=False))
    assert len(switches) == changes
    # between two rows only the disc named by the later row's mode moves
    names = traj.mode_names
    moved = np.abs(np.diff(traj.q, axis=0)).reshape(len(traj) - 1, 3, 2).max(axis=2) > 0
    for row, step in enumerate(moved):
        assert set(np.flatnonzero(step)) <= {int(names[row + 1].split()[1]) - 1}
    assert traj.meta["rule"] == rule
    assert traj.meta["tolerance"] == max(
        DiscsSection.model_fields["tolerance"].default, SEQUENTIAL_TOLERANCE
    )
    _round_trips(traj, tmp_path)


def test_options_default_to_the_section_and_override_it(swap: cellplan.Setup) -> None:
    assert _traj(cellplan.plan(swap, "assembly.control")).meta["k"] == 32.0
    given = _traj(cellplan.plan(swap, "assembly.control", k=24.0, tolerance=0.01))
    assert given.meta["k"] == 24.0 and given.meta["tolerance"] == 0.01
    # a generated scenario sets no k: the section's default (None) means the rule
    setup = random_setup(3, seed=1)
    result = cellplan.plan(setup, "assembly.control")
    problem = result.solution.problem
    assert SECTION_K is None
    assert _traj(result).meta["k"] == rule_k(problem.radii, problem.workspace)
    # escapes: one default, the options model's, which the planner runs with
    planned = cellplan.plan(swap, "assembly.gradient")
    assert planned.options["escapes"] == GradientOptions().escapes == 6


@pytest.mark.parametrize(
    ("planner", "options", "field", "text"),
    [
        ("assembly.gradient", {"epsilonn": 0.1}, "epsilonn", "did you mean 'epsilon'"),
        ("assembly.sequential", {"rul": "place"}, "rul", "did you mean 'rule'"),
        ("assembly.gradient", {"k": 0}, "k", "greater than 0"),
        ("assembly.control", {"k": -2.0}, "k", "greater than 0"),
        ("assembly.sequential", {"rule": "magic"}, "rule", "paper"),
        ("assembly.gradient", {"escapes": 21}, "escapes", "20"),
        ("assembly.control", {"escapes": 2}, "escapes", "options: k, tolerance"),
    ],
)
def test_bad_options_are_one_line_each(
    swap: cellplan.Setup, planner: str, options: dict[str, object], field: str, text: str
) -> None:
    with pytest.raises(ArgumentError) as err:
        cellplan.make(swap, planner, **options)
    (problem,) = err.value.problems
    assert problem.field == field and text in problem.message
    assert "\n" not in str(problem)


def test_random_setup_names_its_parameters() -> None:
    with pytest.raises(ArgumentError) as err:
        random_setup(0)
    assert [p.field for p in err.value.problems] == ["n"]
    with pytest.raises(ArgumentError) as err:
        random_setup(5, fill=0.9)
    assert [p.field for p in err.value.problems] == ["fill"]
    setup = random_setup(5, seed=3, permutation=True)
    gen = setup.scenario.discs.generate
    assert (gen.n, gen.seed, gen.starts) == (5, 3, "permutation")
    assert setup.scenario.discs.k == SECTION_K


def _assemble(*args: str) -> tuple[int, str]:
    res = runner.invoke(app, ["assemble", *args])
    return res.exit_code, res.stdout


def test_assemble_exits_1_when_stuck_and_says_why(tmp_path: Path) -> None:
    # four discs at k=4 (far below the threshold k) end in a spurious minimum
    args = ["--random", "4", "--seed", "2", "--k", "4", "--escapes", "0", "--frames", "2"]
    code, out = _assemble(*args, "-o", str(tmp_path / "h"))
    assert code == 1
    assert out.startswith("stuck: stuck at a spurious minimum at k=4")
    code, out = _assemble(*args, "-o", str(tmp_path / "j"), "--json")
    assert code == 1
    payload = json.loads(out)
    assert payload["status"] == "stuck" and "spurious minimum" in payload["message"]
    assert payload["stats"]["solved_at_k"] is False  # a flag stays a JSON boolean
    traj = Trajectory.load(payload["outputs"]["trajectory"])
    assert traj.columns[:2] == ("disc1.x", "disc1.y") and traj.dim == 8
    metrics = json.loads((tmp_path / "j" / "metrics.json").read_text())
    assert metrics["status"] == "stuck" and metrics["k"] == 4.0


def test_assemble_json_on_a_solved_run(tmp_path: Path) -> None:
    code, out = _assemble(
        "discs_swap",
        "--algorithm",
        "sequential",
        "--rule",
        "place",
        "--frames",
        "2",
        "-o",
        str(tmp_path),
        "--json",
    )
    assert code == 0
    payload = json.loads(out)  # one object, nothing else on stdout
    assert payload["status"] == "solved" and payload["message"].startswith("assembled")
    assert payload["options"]["rule"] == "place" and payload["options"]["k"] is None
    assert set(payload["outputs"]) == {"sequence", "animation", "trajectory", "metrics"}
    assert Trajectory.load(tmp_path / "trajectory.csv").events_of("grasp")


def test_assemble_random_uses_the_section_default_k(tmp_path: Path) -> None:
    code, _ = _assemble(
        "--random", "3", "--algorithm", "control", "--frames", "2", "-o", str(tmp_path)
    )
    assert code == 0
    setup = random_setup(3)
    problem = cellplan.plan(setup, "assembly.control").solution.problem
    expected = rule_k(problem.radii, problem.workspace)
    assert json.loads((tmp_path / "metrics.json").read_text())["k"] == expected


def test_loading_a_disc_scenario_imports_no_algorithm_module() -> None:
    code = (
        "import sys, cellplan; cellplan.load('discs_seven'); cellplan.load('discs_swap');"
        "cellplan.planners();"
        "print(sorted(m for m in sys.modules if m.startswith('cellplan.assembly')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded = set(eval(out.stdout))  # a printed list of module names
    assert "cellplan.assembly.section" in loaded
    heavy = {
        "navigation",
        "flows",
        "kernels",
        "eigen",
        "sequential",
        "control",
        "routes",
        "problems",
        "planners",
    }
    assert not {f"cellplan.assembly.{m}" for m in heavy} & loaded


def test_showcase_plans_through_the_api_and_prints_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from cellplan.assembly import showcase

    monkeypatch.setattr(showcase, "FRAMES", 3)
    make = cellplan.registry.packages()["assembly"].showcase
    assert make is not None
    items = make(tmp_path)
    assert capsys.readouterr() == ("", "")
    assert len(items) == 3
    assert [len(item.figures) for item in items] == [2, 1, 1]
    assert "spheres" in items[2].title
    assert all(Path(f).stat().st_size > 0 for item in items for f in item.figures)
    assert all("cellplan.plan(" in item.code and "solved" in item.caption for item in items)


def test_sequential_budget_exhausted_exits_1(tmp_path: Path) -> None:
    scenario = tmp_path / "jam.yaml"
    scenario.write_text(JAM)
    args = [str(scenario), "--algorithm", "sequential", "--frames", "2", "--json"]
    code, out = _assemble(*args, "--escapes", "0", "--finish", "none", "-o", str(tmp_path / "a"))
    payload = json.loads(out)
    assert code == 1 and payload["status"] == "budget_exhausted"
    assert payload["message"].startswith("budget spent at k=48 (140 switches")
    # the default finish (issue 35): the place rule takes over where the T map stopped
    code, out = _assemble(*args, "--escapes", "0", "-o", str(tmp_path / "b"))
    payload = json.loads(out)
    assert code == 0 and payload["status"] == "solved"
    assert "the paper's T map stopped at k=48 (140 switches" in payload["message"]


def test_sequential_escape_is_an_event_where_the_next_stage_starts(tmp_path: Path) -> None:
    scenario = tmp_path / "jam.yaml"
    scenario.write_text(JAM)
    result = cellplan.plan(cellplan.load(scenario), "assembly.sequential")
    assert result.success and result.stats["escapes"] == 1.0
    run, traj = result.solution, _traj(result)
    first = run.stages[0].steps  # grasps of the stage at k=48
    (escape,) = traj.events_of("escape")
    assert escape.detail == "k=24"
    assert escape.index == sum(len(g.path) - 1 for g in run.grasps[:first])
    # the escape comes with the first grasp of the stage at k=24
    assert any(e.kind == "grasp" and e.index == escape.index for e in traj.events)
