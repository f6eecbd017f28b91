"""cellplan solve / simulate / plot end to end on a tiny scenario, and their errors."""

from __future__ import annotations

import json

import pytest
from strategies_helpers import TINY


@pytest.fixture
def scenario(tmp_path):
    path = tmp_path / "tiny.yaml"
    path.write_text(TINY.replace("CELLS", "16"))
    return path


def test_solve_simulate_plot(cellplan, scenario, tmp_path):
    # A 12 x 12 grid and 10 stages: the GIF draws a frame per stage up to 40, and drawing
    # them was most of this test's time; every command and file is the same.
    scenario.write_text(TINY.replace("CELLS", "12"))
    npz = tmp_path / "s.npz"
    r = cellplan("solve", str(scenario), "-o", str(npz))
    assert r.returncode == 0, r.stderr
    assert "gain g =" in r.stdout and npz.exists()
    out = tmp_path / "sim"
    r = cellplan(
        "simulate",
        str(scenario),
        "--strategy",
        str(npz),
        "--stages",
        "10",
        "--seed",
        "3",
        "-o",
        str(out),
    )
    assert r.returncode == 0, r.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["metrics"]["stages"] == 10
    assert (out / "simulation.gif").stat().st_size > 0
    assert (out / "frames.png").exists() and not (out / "frame_001.png").exists()
    fig = tmp_path / "w.png"
    r = cellplan("plot", str(scenario), "--strategy", str(npz), "--mode", "1,1,1,W", "-o", str(fig))
    assert r.returncode == 0, r.stderr
    assert fig.stat().st_size > 0


def test_unconverged_solve_exits_1_and_saves_nothing(cellplan, scenario, tmp_path):
    text = scenario.read_text() + "  solver: {method: general, max_sweeps: 2}\n"
    scenario.write_text(text)
    npz = tmp_path / "s.npz"
    r = cellplan("solve", str(scenario), "-o", str(npz))
    assert r.returncode == 1
    first = r.stdout.splitlines()[0]
    assert first.startswith("not_converged: did not converge within 2 sweeps")
    assert "nothing saved" in first and not npz.exists()
    r = cellplan("solve", str(scenario), "-o", str(npz), "--json")
    assert r.returncode == 1 and not npz.exists()
    payload = json.loads(r.stdout)
    assert payload["status"] == "not_converged" and payload["success"] is False
    assert "did not converge" in payload["message"] and payload["outputs"] == {}
    r = cellplan("solve", str(scenario), "-o", str(npz), "--save-unconverged")
    assert r.returncode == 1 and npz.exists()


def test_bad_arguments_exit_2(cellplan, scenario, tmp_path):
    r = cellplan("solve", str(scenario), "-o", str(tmp_path / "s.txt"))
    assert r.returncode == 2 and "--output" in r.stderr
    npz = tmp_path / "s.npz"
    assert cellplan("solve", str(scenario), "-o", str(npz)).returncode == 0
    r = cellplan("simulate", str(scenario), "--strategy", str(npz), "--stages", "0")
    assert r.returncode == 2 and "--stages" in r.stderr
    r = cellplan(
        "plot",
        str(scenario),
        "--strategy",
        str(npz),
        "--mode",
        "7,7,7,W",
        "-o",
        str(tmp_path / "x.png"),
    )
    assert r.returncode == 2 and "--mode" in r.stderr
    r = cellplan("plot", "strategies_p1", "--strategy", str(npz), "-o", str(tmp_path / "x.png"))
    assert r.returncode == 2 and "different scenario" in r.stderr


def test_no_snap_solve_records_the_transition_law(cellplan, scenario, tmp_path):
    import numpy as np

    npz = tmp_path / "strict.npz"
    r = cellplan("solve", str(scenario), "--no-snap", "-o", str(npz))
    assert r.returncode == 0, r.stderr
    with np.load(npz) as data:
        meta = json.loads(str(data["meta"]))
    assert meta["transitions"] == "no-snap"


def test_solve_json_then_simulate_writes_the_trajectory(cellplan, scenario, tmp_path):
    from cellplan.api import load
    from cellplan.strategies.policy.strategy import Strategy
    from cellplan.strategies.sim.simulate import simulate_result
    from cellplan.trajectory import Trajectory

    npz = tmp_path / "s.npz"
    r = cellplan("solve", str(scenario), "-o", str(npz), "--json")
    assert r.returncode == 0, r.stderr
    payload = json.loads(r.stdout)  # exactly one JSON object, nothing else on stdout
    assert payload["status"] == "solved" and payload["message"].startswith("gain ")
    assert payload["outputs"] == {"strategy": str(npz)} and npz.exists()
    assert payload["stats"]["sweeps"] > 0 and "sim_served" in payload["stats"]
    assert r.stderr == ""  # no progress bar when piped or with --json

    out = tmp_path / "sim"
    args = ["simulate", str(scenario), "--strategy", str(npz), "--stages", "150"]
    r = cellplan(*args, "--seed", "4", "-o", str(out), "--no-gif", "--json")
    assert r.returncode == 0, r.stderr
    payload = json.loads(r.stdout)
    assert payload["status"] == "solved" and payload["stats"]["stages"] == 150
    assert payload["outputs"]["trajectory"] == str(out / "trajectory.csv")
    assert "gif" not in payload["outputs"]
    traj = Trajectory.load(out / "trajectory.csv")
    setup = load(str(scenario))
    again = simulate_result(Strategy.load(npz, setup.scenario), 150, 4, cell=setup.workcell)
    assert traj == again.trajectory
    assert len(traj) == 151 and traj.events_of("request")
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["status"] == "solved" and metrics["metrics"]["seed"] == 4

    # A run that leaves a request waiting past --max-wait ran but failed: exit 1.
    r = cellplan(*args, "-o", str(out), "--no-gif", "--max-wait", "1")
    assert r.returncode == 1
    assert r.stdout.startswith("failed: request 1 (")
    r = cellplan(*args, "-o", str(out), "--max-wait", "-1")
    assert r.returncode == 2 and "--max-wait" in r.stderr


def test_cells_are_checked_against_one_range(cellplan, scenario, tmp_path):
    from cellplan.schema import CELLS_RANGE

    npz = tmp_path / "s.npz"
    low = CELLS_RANGE[0] - 1
    r = cellplan("solve", str(scenario), "-o", str(npz), "--cells", f"{low},{low}")
    assert r.returncode == 2 and r.stderr.count("--cells") == 1
    assert f"greater than or equal to {CELLS_RANGE[0]}" in r.stderr
    r = cellplan("solve", str(scenario), "-o", str(npz), "--cells", "12,12,12")
    assert r.returncode == 2 and "--cells: needs 2 values" in r.stderr
    r = cellplan("solve", str(scenario), "-o", str(npz), "--cells", "12;12")
    assert r.returncode == 2 and "--cells" in r.stderr
    r = cellplan("solve", str(scenario), "-o", str(npz), "--method", "fast")
    assert r.returncode == 2 and "--method" in r.stderr and not npz.exists()


@pytest.mark.parametrize("value", ["100", "5000", "wide", "-3"])
def test_bad_gif_size_is_one_line_and_writes_nothing(cellplan, scenario, tmp_path, value):
    out = tmp_path / "sim"
    r = cellplan(
        "simulate",
        str(scenario),
        "--strategy",
        str(tmp_path / "none.npz"),
        "--gif-size",
        value,
        "-o",
        str(out),
    )
    assert r.returncode == 2
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "--gif-size" in lines[0] and "pixels" in lines[0]
    assert not out.exists()


def test_gif_frames_are_wide_and_carry_a_stage_counter(tmp_path, frame_counters):
    from PIL import Image
    from strategies_helpers import tiny

    from cellplan.plots import GIF_SIZE
    from cellplan.strategies.experiments.plots import save_animation
    from cellplan.strategies.policy.strategy import solve_scenario
    from cellplan.strategies.sim.simulate import simulate

    sc, cell = tiny(12)
    strategy, _ = solve_scenario(sc, cell)
    sim = simulate(strategy, 30, seed=1, cell=cell)
    counters = frame_counters
    gif = save_animation(strategy, cell, sim, tmp_path / "a.gif", max_frames=5)
    with Image.open(gif) as im:
        assert im.size[0] == GIF_SIZE >= 480
    assert len(counters) == 5 and counters[0] == "stage  0 / 30" and counters[-1] == "stage 30 / 30"
    small = save_animation(strategy, cell, sim, tmp_path / "b.gif", max_frames=2, size=320)
    with Image.open(small) as im:
        assert im.size[0] == 320


def test_frames_png_shows_every_segment_laid_out_for_the_cell(tmp_path, monkeypatch):
    from strategies_helpers import tiny

    import cellplan.plots
    from cellplan.strategies.experiments import plots
    from cellplan.strategies.policy.strategy import solve_scenario
    from cellplan.strategies.sim.simulate import simulate

    sc, cell = tiny(12)
    strategy, _ = solve_scenario(sc, cell)
    sim = simulate(strategy, 200, seed=2, cell=cell)
    segments = len(sim.segments())
    assert segments > 12  # more than the old grid showed
    saved = {}
    save = cellplan.plots.save_figure

    def spy(fig, path, dpi=110):
        saved[path.name] = [ax for ax in fig.axes if ax.axison]
        return save(fig, path, dpi)

    monkeypatch.setattr(cellplan.plots, "save_figure", spy)
    plots.plot_frames(strategy, cell, sim, tmp_path)
    shown = saved["frames.png"]
    assert len(shown) == segments
    assert shown[-1].get_title().startswith(f"({segments}) ")


def test_a_long_run_draws_at_most_max_frames_pictures(tmp_path):
    from strategies_helpers import tiny

    from cellplan.strategies.experiments import plots
    from cellplan.strategies.policy.strategy import solve_scenario
    from cellplan.strategies.sim.simulate import simulate

    sc, cell = tiny(12)
    strategy, _ = solve_scenario(sc, cell)
    sim = simulate(strategy, 200, seed=2, cell=cell)
    assert len(sim.segments()) > 5
    paths = plots.plot_frames(strategy, cell, sim, tmp_path, max_frames=5, each=True)
    assert sorted(p.name for p in tmp_path.glob("frame_*.png")) == [
        f"frame_{i:03d}.png" for i in range(1, 6)
    ]
    assert paths[-1].name == "frames.png"
    # By default only frames.png (the separate PNGs were most of simulate's time).
    assert [p.name for p in plots.plot_frames(strategy, cell, sim, tmp_path / "one")] == [
        "frames.png"
    ]
    assert list((tmp_path / "one").glob("frame_*.png")) == []


@pytest.mark.parametrize("speed", [1.0, 4.0])
def test_seconds_follow_the_scenarios_robot_speed(cellplan, tmp_path, speed):
    """``robot.speed`` sets the seconds of the solve's sample run and of ``simulate``: a
    stage lasts its longest step at that speed (timing.stage_duration), so it scales as
    1 / speed."""
    from cellplan.api import load, plan
    from cellplan.strategies.policy.strategy import Strategy
    from cellplan.trajectory import Trajectory

    text = TINY.replace("CELLS", "16").replace(
        "  start: [15, 8]", f"  start: [15, 8]\n  speed: [{speed}, {speed}]"
    )
    path = tmp_path / "fast.yaml"
    path.write_text(text)
    setup = load(str(path))
    assert setup.scenario.robot.speed is not None
    result = plan(setup, "strategies")
    assert result.trajectory is not None
    strategy = result.solution
    assert isinstance(strategy, Strategy)
    # The longest step of a move, in workcell units (a translating robot's x and y).
    step = float(abs(strategy.mdp.disp).max())
    assert result.trajectory.stage_duration == pytest.approx(step / speed)
    npz = tmp_path / "s.npz"
    strategy.save(npz)
    out = tmp_path / "sim"
    r = cellplan(
        "simulate", str(path), "--strategy", str(npz), "--stages", "40", "--no-gif", "-o", str(out)
    )
    assert r.returncode == 0, r.stderr
    traj = Trajectory.load(out / "trajectory.csv")
    assert traj.stage_duration == pytest.approx(step / speed)
    assert traj.seconds[-1] == pytest.approx(40 * step / speed)


def test_solve_json_keeps_counts_as_integers_and_flags_as_booleans(cellplan, scenario, tmp_path):
    # Issue 34: "sweeps": 311, "stable": true, "sim_served": 9 (not 311.0, 1.0, 9.0).
    r = cellplan("solve", str(scenario), "-o", str(tmp_path / "s.npz"), "--json")
    assert r.returncode == 0, r.stderr
    stats = json.loads(r.stdout)["stats"]
    counts = ["sweeps", "full_sweeps", "eval_sweeps", "outer_iterations", "policy_changes"]
    counts += ["sim_stages", "sim_requests", "sim_served", "sim_open_requests"]
    counts += ["sim_fmp_refused", "sim_corrections", "sim_fmp_failures"]
    for key in counts:
        assert type(stats[key]) is int, key
    assert type(stats["stable"]) is bool
    assert type(stats["gain"]) is float and type(stats["sim_loss_per_stage"]) is float


@pytest.mark.parametrize(
    ("command", "typo"), [("solve", "--sample-stagse"), ("simulate", "--stagse")]
)
def test_an_unknown_option_is_refused_with_exit_2(cellplan, scenario, tmp_path, command, typo):
    # The commands take their options as one dataclass (cliutil.command_from); the
    # signature typer reads is exactly its fields, so a typo is an error, not swallowed.
    npz, out = tmp_path / "s.npz", tmp_path / "out"
    given = ["-o", str(npz)] if command == "solve" else ["--strategy", str(npz), "-o", str(out)]
    r = cellplan(command, str(scenario), *given, typo, "3")
    assert r.returncode == 2 and f"No such option: {typo}" in r.stderr
    assert not npz.exists() and not out.exists()


def test_command_signatures_are_the_option_dataclasses():
    import dataclasses
    import inspect

    from cellplan.strategies.commands import (
        SimulateArgs,
        SolveArgs,
        simulate_command,
        solve_command,
    )

    for command, args in ((solve_command, SolveArgs), (simulate_command, SimulateArgs)):
        params = inspect.signature(command).parameters
        fields = dataclasses.fields(args)
        assert list(params) == [f.name for f in fields]
        for f in fields:
            default = f.default if f.default is not dataclasses.MISSING else params[f.name].empty
            assert params[f.name].default == default
        required = [p for p in params.values() if p.default is p.empty]
        with pytest.raises(TypeError, match="stagse"):
            command(*["x"] * len(required), stagse=3)
