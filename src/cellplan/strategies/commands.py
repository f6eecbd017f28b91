"""CLI commands of the strategies package: ``solve``, ``simulate``, ``plot``.

Each goes through the library API (:func:`cellplan.api.plan`,
:func:`~cellplan.strategies.sim.simulate.simulate_result`), prints one summary line on
stdout (or one JSON object with ``--json``) and exits 0 when solved, 1 when it ran but
did not solve (the status line says why), 2 on bad input. Options the library defaults
are ``None`` here and passed on only when given, so the CLI holds no default of its own.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
import typer

from cellplan.cliutil import (
    GifSizeOpt,
    JsonOpt,
    ScenarioArg,
    as_flags,
    check_inputs_kept,
    check_output,
    command_from,
    finish,
    folder_files,
    print_json,
    progress_bar,
    progress_enabled,
    scenario_file,
    stdout,
)
from cellplan.errors import ArgumentError, CellplanError, printable
from cellplan.fileio import staged_folder, write_json
from cellplan.strategies.planners import (
    MAX_STAGES,
    SIMULATE_SEED,
    SIMULATE_STAGES,
    StrategiesOptions,
)
from cellplan.strategies.sim.options import SimulationOptions

if TYPE_CHECKING:
    from cellplan.setup import Setup
    from cellplan.strategies.policy.strategy import Strategy

#: Every file ``simulate`` may write into its output folder (``frame_NNN.png``: one per
#: segment of the sample path).
SIMULATE_FILES = (
    "trajectory.csv",
    "frame_*.png",
    "frames.png",
    "simulation.gif",
    "viewer.html",
    "metrics.json",
)

StrategyOpt = Annotated[
    Path, typer.Option("--strategy", help="strategy file from 'cellplan solve'")
]


def _default(option: str) -> object:
    """The library's default of a planner option, for the help text."""
    return StrategiesOptions.model_fields[option].default


def _load(scenario: str) -> Setup:
    from cellplan.api import load

    setup = load(scenario)
    setup.section("strategy")
    return setup


def _cells(text: str | None) -> list[int] | None:
    if text is None:
        return None
    try:
        return [int(v) for v in text.split(",")]
    except ValueError:
        raise ArgumentError(
            f"expected comma-separated integers, e.g. 100,100, got {text!r}", "--cells"
        ) from None


def _check_suffix(path: Path, allowed: tuple[str, ...], option: str) -> None:
    if path.suffix.lower() not in allowed:
        raise ArgumentError(f"expected a {' or '.join(allowed)} file, got {path.name!r}", option)
    check_output(path, option)


def _existing(inputs: Mapping[str, Path | None]) -> dict[str, Path]:
    """The inputs given, to keep unreplaced."""
    return {k: v for k, v in inputs.items() if v is not None}


def _load_strategy(path: Path, setup: Setup) -> Strategy:
    from cellplan.strategies.policy.strategy import Strategy

    if path.is_dir():  # also an empty --strategy, which the parser turns into "."
        raise ArgumentError(f"{path} is a folder, not a strategy file", "--strategy")
    return Strategy.load(path, setup.scenario).attach(setup.workcell)


@dataclass(frozen=True)
class SolveArgs:
    """The options of ``cellplan solve``, one field each
    (:func:`~cellplan.cliutil.command_from`)."""

    scenario: ScenarioArg
    output: Annotated[Path, typer.Option("-o", "--output", help="strategy file (.npz)")] = Path(
        "strategy.npz"
    )
    cells: Annotated[
        str | None, typer.Option(help="grid cells per axis, e.g. 100,100 (default: the scenario's)")
    ] = None
    method: Annotated[
        str | None,
        typer.Option(help="auto, structured, policy or general (default: strategy.solver.method)"),
    ] = None
    snap: Annotated[
        bool | None,
        typer.Option(
            "--snap/--no-snap",
            help="--no-snap drops moves whose interpolation snaps the robot sideways "
            "(stricter model, docs/strategies.md)",
            show_default=False,
        ),
    ] = None
    sample_stages: Annotated[
        int | None,
        typer.Option(
            help=f"stages of the sample run in the result (default {_default('sample_stages')})"
        ),
    ] = None
    seed: Annotated[
        int | None, typer.Option(help=f"seed of the sample run (default {_default('seed')})")
    ] = None
    save_unconverged: Annotated[
        bool, typer.Option(help="save the strategy even if the solve did not converge")
    ] = False
    as_json: JsonOpt = False


def solve(args: SolveArgs) -> None:
    """Compute the optimal strategy of a scenario (Section IV) and save it as .npz."""
    from cellplan.api import plan
    from cellplan.core import Status

    output = args.output
    _check_suffix(output, (".npz",), "--output")
    check_inputs_kept([("--output", output)], {"SCENARIO": scenario_file(args.scenario)})
    given: dict[str, Any] = {
        "cells": _cells(args.cells),
        "method": args.method,
        "snap": args.snap,
        "sample_stages": args.sample_stages,
        "seed": args.seed,
    }
    options = {k: v for k, v in given.items() if v is not None}
    setup = _load(args.scenario)
    with as_flags(), progress_bar(progress_enabled(args.as_json), "solving") as progress:
        result = plan(setup, "strategies", progress=progress, **options)
    s = result.stats
    summary = (
        f"gain g = {s['gain']:.6f} per stage (bounds [{s['gain_lower']:.6f}, "
        f"{s['gain_upper']:.6f}], span {s['span']:.2e}); method "
        f"{result.solution.meta['method']}, {int(s['sweeps'])} sweeps, "
        f"{int(s['outer_iterations'])} outer iterations, {s['seconds']:.2f} s; policy "
        + ("stable" if s["stable"] else f"changes at {int(s['policy_changes'])} states")
    )
    outputs: dict[str, Path] = {}
    if result.status is not Status.NOT_CONVERGED or args.save_unconverged:
        result.solution.save(output)
        outputs["strategy"] = output
        summary += f"; wrote {output}"
    else:
        summary += "; nothing saved (use --save-unconverged to keep it)"
    finish(result, args.as_json, summary, outputs)


solve_command = command_from(SolveArgs, solve)


def write_motion_viewer(strategy: Strategy, setup: Setup, sim: Any, path: Path) -> Path:
    """The simulated motion of a 3-D arm as one offline viewer page
    (:func:`cellplan.view3d.write_viewer`): a frame per stage, the part drawn on the tool
    while a mode carries it."""
    from cellplan.scene3d import cell_scene
    from cellplan.strategies.sim.records import carried_part
    from cellplan.view3d import write_viewer

    modes = strategy.mdp.modes
    held = [carried_part(modes[int(m)]) for m in sim.modes]
    scene = cell_scene(
        setup.workcell,  # type: ignore[arg-type]  # a 3-D scenario's workcell is a Workcell3D
        sim.q,
        np.arange(len(sim.q), dtype=float),
        held,
        title=f"{setup.name}: simulated assembly process",
        time_label="stage",
    )
    write_viewer(scene, path)
    return path


@dataclass(frozen=True)
class SimulateArgs:
    """The options of ``cellplan simulate``, one field each
    (:func:`~cellplan.cliutil.command_from`)."""

    scenario: ScenarioArg
    strategy: StrategyOpt
    stages: Annotated[
        int | None,
        typer.Option(help=f"number of stages, 1 to {MAX_STAGES:,} (default {SIMULATE_STAGES})"),
    ] = None
    seed: Annotated[int | None, typer.Option(help=f"random seed (default {SIMULATE_SEED})")] = None
    output: Annotated[Path, typer.Option("-o", "--output", help="output folder")] = Path(
        "simulation"
    )
    policy: Annotated[
        str | None,
        typer.Option(
            help="optimal, reactive or home (default optimal); with simultaneous requests "
            "optimal, fcfs, nearest or reactive"
        ),
    ] = None
    max_wait: Annotated[
        float | None,
        typer.Option(
            help="longest acceptable wait of a request, in time units (default: ten crossings "
            "of the C-space box, docs/strategies.md)"
        ),
    ] = None
    gif: Annotated[bool, typer.Option(help="write an animated GIF")] = True
    gif_size: GifSizeOpt = None
    frame_files: Annotated[
        bool,
        typer.Option(
            help="also write each mode segment as its own frame_NNN.png (frames.png always "
            "holds them all)"
        ),
    ] = False
    as_json: JsonOpt = False


def simulate(args: SimulateArgs) -> None:
    """Simulate the assembly process under a strategy: trajectory.csv, frames, GIF, metrics
    (in a 3-D cell, viewer.html, where the arm's motion plays, instead of frames and GIF)."""
    from cellplan.plots import GIF_SIZE, check_gif_size
    from cellplan.strategies.sim.simulate import simulate_result

    output = args.output
    if args.gif_size is not None and not args.gif:
        raise ArgumentError("only with --gif (the default)", "--gif-size")
    width = check_gif_size(GIF_SIZE if args.gif_size is None else args.gif_size)
    check_output(output, "--output", folder=True)
    inputs = {"SCENARIO": scenario_file(args.scenario), "--strategy": args.strategy}
    check_inputs_kept(folder_files("--output", output, SIMULATE_FILES), inputs)
    setup = _load(args.scenario)
    strat = _load_strategy(args.strategy, setup)
    given: dict[str, Any] = {"policy": args.policy, "max_wait": args.max_wait}
    options = SimulationOptions(**{k: v for k, v in given.items() if v is not None})
    bar = progress_bar(progress_enabled(args.as_json), "simulating", counts=True)
    with bar as progress:
        with as_flags():
            result = simulate_result(
                strat,
                SIMULATE_STAGES if args.stages is None else args.stages,
                SIMULATE_SEED if args.seed is None else args.seed,
                options,
                cell=setup.workcell,
                progress=progress,
                robot_spec=setup.scenario.robot,  # seconds at the scenario's robot.speed
            )
        sim = result.solution
        assert result.trajectory is not None
        n = len(sim.actions)
        if progress is not None:
            progress(n, n, f"drawing {len(sim.segments())} frames")
        metrics: dict[str, Any] = dict(sim.metrics())
        metrics.update(
            policy=result.options["policy"], seed=result.options["seed"], gain=strat.gain
        )
        # Every file is written into a staging folder and moved into place only when all
        # are written: a full disk or an error leaves --output as it was.
        with (
            as_flags({"size": "--gif-size"}),
            staged_folder(output, keep=_existing(inputs)) as stage,
        ):
            names = _write_simulation(
                stage,
                (strat, setup, result, metrics),
                width if args.gif else None,
                args.frame_files,
            )
    outputs = {key: output / name for key, name in names.items()}
    m = metrics
    summary = (
        f"{int(m['served'])} requests served, mean waiting time {m['mean_wait']:.2f} "
        f"(delivered) / {m['mean_wait_all']:.2f} (all, open ones at their age), loss per "
        f"stage {m['loss_per_stage']:.3f} (gain {strat.gain:.3f}), idle fraction "
        f"{m['idle_fraction']:.2f}"
    )
    if "mean_open" in m:  # simultaneous requests (Section VI-2)
        summary += (
            f", {m['mean_open']:.2f} requests open on average, {int(m['turned_away'])} turned away"
        )
    summary += f"; wrote {output}"
    finish(result, args.as_json, summary, outputs)


simulate_command = command_from(SimulateArgs, simulate)


def _write_simulation(
    stage: Path, run: tuple[Strategy, Setup, Any, dict[str, Any]], gif: int | None, each: bool
) -> dict[str, str]:
    """Write a simulated run's files into ``stage``: the trajectory, the frames (or, in a
    3-D cell, the viewer page), the GIF (``gif``: its width; None: none) and the metrics;
    ``run`` is the strategy, the setup, the simulation's result and its metrics."""
    from cellplan.scenario3d import is_3d
    from cellplan.strategies.experiments import plots

    strat, setup, result, metrics = run
    sim = result.solution
    names = {"trajectory": result.trajectory.save(stage / "trajectory.csv").name}
    if is_3d(setup.scenario):
        # A 3-D cell has no planar frames: its motion plays in the viewer page.
        names["viewer"] = write_motion_viewer(strat, setup, sim, stage / "viewer.html").name
    else:
        drawn = plots.plot_frames(strat, setup.workcell, sim, stage, each=each)
        names["frames"] = drawn[-1].name
        if gif is not None:
            names["gif"] = plots.save_animation(
                strat, setup.workcell, sim, stage / "simulation.gif", size=gif
            ).name
    names["metrics"] = write_json(
        stage / "metrics.json",
        {
            "status": str(result.status),
            "message": result.message,
            "metrics": metrics,
            "requests": [vars(r) for r in sim.requests],
        },
    ).name
    return names


def plot_command(
    scenario: ScenarioArg,
    strategy: StrategyOpt,
    mode: Annotated[
        str,
        typer.Option(
            help="mode: NR, 'p,s,d,W|C' (1-based indices or names), or a label as it prints "
            "(e.g. '{P1,S1,D1; P2,S2,D1} + <P1,S1,D2>', or '<P1,S1,D1,W>@3' at phase 3 of a "
            "time-varying strategy)"
        ),
    ] = "NR",
    phase: Annotated[
        int | None,
        typer.Option(
            help="phase of the period of a time-varying strategy (Section VI-1), 0 to the "
            "period - 1 (default 0; a stationary strategy has phase 0 only)"
        ),
    ] = None,
    output: Annotated[Path, typer.Option("-o", "--output", help="image file")] = Path(
        "strategy.png"
    ),
    as_json: JsonOpt = False,
) -> None:
    """Draw one mode's cost-to-go contours and optimal actions (Fig. 8), at one
    phase of a time-varying strategy."""
    from cellplan.strategies.experiments import plots

    _check_suffix(output, (".png", ".svg", ".pdf"), "--output")
    check_inputs_kept(
        [("--output", output)], {"SCENARIO": scenario_file(scenario), "--strategy": strategy}
    )
    setup = _load(scenario)
    # The mode plots draw the plane; a 3-D cell is refused in one line before the strategy
    # is read (its motion plays in the viewer page that simulate writes).
    cell = setup.planar_workcell
    strat = _load_strategy(strategy, setup)
    try:
        m = strat.mode_index(mode, phase)
    except CellplanError as exc:  # names the option (--mode or --phase) already
        raise ArgumentError(list(exc.problems)) from None
    plots.plot_mode(strat, cell, m, output, fixed=cell.robot.start)
    if as_json:
        mdp = strat.mdp
        print_json(
            {
                "output": str(output),
                "mode": strat.modes[m].label,
                "layer": int(m),
                "phase": max(int(strat.modes[m].phase), 0),
                "live_fraction": float(np.mean(mdp.live[m])),
                "gain": float(strat.gain),
            }
        )
        return
    stdout().print(printable(f"wrote {output}"), markup=False)


COMMANDS: tuple[tuple[str, Callable[..., None]], ...] = (
    ("solve", solve_command),
    ("simulate", simulate_command),
    ("plot", plot_command),
)


def register(app: typer.Typer) -> None:
    """Add this package's commands to the ``cellplan`` app."""
    for name, command in COMMANDS:
        app.command(name)(command)
