"""Problems, scenario sections and the CLI: legal generation, bad input named, exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cellplan.assembly.problems import (
    DEFAULT_FILL,
    default_workspace,
    gap_for_beta,
    generate_problem,
    hex_pattern,
    legality_problems,
    log10_beta_pairs,
)
from cellplan.assembly.section import GeneratorSpec
from cellplan.cli import app
from cellplan.errors import ScenarioError
from cellplan.plots import GIF_SIZE
from cellplan.scenario import load_scenario, loads_scenario

runner = CliRunner()

BASE = """cellplan: 1
workcell:
  bounds: {xmin: 0, ymin: 0, xmax: 10, ymax: 10}
discs:
"""


@pytest.mark.parametrize("target", [-2.0, -9.0, -16.0, -28.0, -44.0])
def test_pattern_difficulty_hits_beta(target: float) -> None:
    gap = gap_for_beta(7, 1.0, target)
    pos = hex_pattern(7, 1.0, gap, np.zeros(2))
    assert abs(log10_beta_pairs(pos, np.ones(7)) - target) < 1e-6
    assert not legality_problems(pos, np.ones(7), default_workspace(7))


@pytest.mark.parametrize("starts", ["random", "permutation"])
def test_generated_problems_are_legal_and_seeded(starts: str) -> None:
    gen = GeneratorSpec(n=10, seed=3, starts=starts)  # type: ignore[arg-type]
    a = generate_problem(gen, default_workspace(10))
    b = generate_problem(gen, default_workspace(10))
    assert np.array_equal(a.start, b.start)
    for pos in (a.start, a.goal):
        assert not legality_problems(pos, a.radii, a.workspace)
    if starts == "permutation":
        assert sorted(map(tuple, a.start)) == sorted(map(tuple, a.goal))


@pytest.mark.parametrize("n", [1, 7, 10, 50])
@pytest.mark.parametrize("fill", [0.02, 0.05, 0.2])
def test_default_workspace_has_the_stated_fill(n: int, fill: float) -> None:
    # n discs of radius rho cover the fraction fill of the circle: n rho^2 / R^2
    ws = default_workspace(n, 0.5, fill)
    assert n * 0.5**2 / ws.radius**2 == pytest.approx(fill, rel=1e-12)
    assert default_workspace(n).radius == pytest.approx(np.sqrt(n / DEFAULT_FILL))


def test_bundled_scenarios_use_the_default_workspace() -> None:
    # the bundled Figs. 1-2 problems are the generator's default distribution
    for name, n in (("discs_seven", 7), ("discs_ten", 10)):
        section = load_scenario(name).discs
        assert section is not None and section.boundary.type == "disc"
        assert section.boundary.radius == pytest.approx(default_workspace(n).radius, abs=0.01)


def test_bundled_scenarios_load() -> None:
    for name in ("discs_seven", "discs_ten", "discs_swap"):
        assert load_scenario(name).discs is not None


def test_overlapping_discs_are_named() -> None:
    text = (
        BASE
        + """  boundary: {type: workcell}
  discs:
    - {radius: 1, start: [2, 2], goal: [8, 8]}
    - {radius: 1, start: [3, 2], goal: [5, 5]}
    - {radius: 1, start: [9.5, 5], goal: [2, 8]}
"""
    )
    with pytest.raises(ScenarioError) as err:
        loads_scenario(text)
    fields = [p.field for p in err.value.problems]
    assert "discs.discs[1].start" in fields  # overlaps disc 0
    assert "discs.discs[2].start" in fields  # outside the workspace
    assert len(fields) == 2


@pytest.mark.parametrize(
    ("snippet", "field"),
    [
        ("  k: 0\n  generate: {n: 3}\n", "discs.k"),
        ("  epsilon: -1\n  generate: {n: 3}\n", "discs.epsilon"),
        ("  generate: {n: 3, gap: 0.1, log10_beta_goal: 40}\n", "discs.generate.log10_beta_goal"),
        ("  generate: {n: 90}\n", "discs.generate.n"),
    ],
)
def test_bad_parameters_are_named(snippet: str, field: str) -> None:
    with pytest.raises(ScenarioError) as err:
        loads_scenario(BASE + snippet)
    assert [p.field for p in err.value.problems] == [field]


def test_illegal_goal_pattern_is_reported(tmp_path: Path) -> None:
    text = (
        BASE + "  boundary: {type: disc, center: [5, 5], radius: 4.2}\n"
        "  generate: {n: 7, gap: 1.5}\n"
    )
    with pytest.raises(ScenarioError) as err:
        loads_scenario(text)
    assert all(p.field == "discs.generate" for p in err.value.problems)


@pytest.mark.parametrize(
    ("args", "name"),
    [
        (["--random", "5", "--k", "0"], "--k"),
        (["--random", "5", "--k", "-3"], "--k"),
        (["--random", "5", "--epsilon", "0"], "--epsilon"),
        (["--random", "5", "--algorithm", "magic"], "--algorithm"),
        (["--random", "5", "--rule", "magic"], "--rule"),
        (["--random", "0"], "--random"),
        (["--random", "5", "--escapes", "-1"], "--escapes"),
        (["--random", "5", "--step-max", "0"], "--step-max"),
        (["--random", "5", "--algorithm", "sequential", "--step-max", "0.1"], "--step-max"),
        (["--random", "5", "--fill", "0"], "--fill"),
        (["--random", "5", "--fill", "0.7"], "--fill"),
        (["--random", "5", "--tolerance", "0"], "--tolerance"),
        (["--random", "5", "--algorithm", "control", "--escapes", "2"], "--escapes"),
        (["discs_swap", "--seed", "3"], "--seed"),
        (["--random", "5", "--frames", "1"], "--frames"),
        (["--random", "5", "--gif-size", "100"], "--gif-size"),
        (["--random", "5", "--gif-size", "big"], "--gif-size"),
    ],
)
def test_cli_bad_arguments_exit_2_naming_the_parameter(
    args: list[str], name: str, tmp_path: Path
) -> None:
    import subprocess
    import sys

    out = subprocess.run(
        [sys.executable, "-m", "cellplan.cli", "assemble", *args, "-o", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        check=False,
    )
    assert out.returncode == 2
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and name in lines[0]
    assert "Traceback" not in out.stderr
    assert not (tmp_path / "o").exists()


def test_cli_bad_scenario_exit_2(tmp_path: Path) -> None:
    import subprocess
    import sys

    bad = tmp_path / "bad.yaml"
    bad.write_text(
        BASE + "  boundary: {type: workcell}\n  discs:\n"
        "    - {radius: 1, start: [2, 2], goal: [8, 8]}\n"
        "    - {radius: 1, start: [8, 8], goal: [8.5, 8]}\n"
    )
    out = subprocess.run(
        [sys.executable, "-m", "cellplan.cli", "assemble", str(bad)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert out.returncode == 2
    assert "discs.discs[1].goal" in out.stderr and "Traceback" not in out.stderr


def test_cli_writes_frames_gif_trajectory_and_metrics(tmp_path: Path) -> None:
    res = runner.invoke(app, ["assemble", "discs_swap", "--frames", "3", "-o", str(tmp_path)])
    assert res.exit_code == 0, res.output
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["status"] == "solved" and metrics["min_clearance"] > 0
    assert metrics["k"] == 32.0 and metrics["message"].startswith("assembled at k=32")
    assert (tmp_path / "trajectory.csv").read_text().startswith("# cellplan-trajectory")
    assert (tmp_path / "sequence.png").stat().st_size > 0
    assert (tmp_path / "assembly.gif").read_bytes()[:3] == b"GIF"
    from PIL import Image

    with Image.open(tmp_path / "assembly.gif") as gif:
        assert gif.size[0] == GIF_SIZE >= 480
    res = runner.invoke(
        app, ["assemble", "discs_swap", "--frames", "2", "--gif-size", "300", "-o", str(tmp_path)]
    )
    assert res.exit_code == 0, res.output
    with Image.open(tmp_path / "assembly.gif") as gif:
        assert gif.size[0] == 300


def test_every_animation_frame_has_a_stage_and_time_counter(tmp_path: Path, monkeypatch) -> None:
    import cellplan.assembly.plots as plots
    from cellplan import api

    counters: list[str] = []
    render = plots.frame_rgb

    def spy(fig):
        counters.extend(
            t.get_text() for ax in fig.axes for t in ax.texts if t.get_gid() == "frame-counter"
        )
        return render(fig)

    monkeypatch.setattr(plots, "frame_rgb", spy)
    result = api.plan(api.load("discs_swap"), "assembly.sequential")
    traj = result.trajectory
    plots.save_animation(
        result.solution.problem, result.solution.path, tmp_path / "a.gif", 4, trajectory=traj
    )
    assert len(counters) == 4
    assert all(c.startswith("stage ") and "path length" in c for c in counters)
    last = len(result.solution.path) - 1
    assert counters[0].startswith("stage 1 / ") and counters[0].endswith(f"step 0 / {last}")
    _, count = plots.frame_stages(traj)
    assert counters[-1].startswith(f"stage {count} / {count}: disc ")
    assert counters[-1].endswith(f"step {last} / {last}")
