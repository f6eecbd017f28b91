"""CLI commands of the strategies package: ``solve``, ``simulate``, ``plot``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from cellplan.errors import ArgumentError, Problem

ScenarioArg = Annotated[
    str, typer.Argument(help="scenario file, or the name of a bundled scenario")
]


def _load(scenario: str) -> tuple[Any, Any]:
    from cellplan.errors import ScenarioError
    from cellplan.workcell import load_workcell

    sc, cell = load_workcell(scenario)
    if sc.strategy is None:
        raise ScenarioError([Problem("strategy", "this scenario has no 'strategy:' section")])
    return sc, cell


def _cells(text: str | None, dim: int) -> list[int] | None:
    if text is None:
        return None
    try:
        shape = [int(v) for v in text.split(",")]
    except ValueError:
        raise ArgumentError(f"expected comma-separated integers, got {text!r}", "--cells") from None
    if len(shape) != dim or any(n < 4 or n > 1024 for n in shape):
        raise ArgumentError(f"needs {dim} values in [4, 1024]", "--cells")
    return shape


def _check_suffix(path: Path, allowed: tuple[str, ...], option: str) -> None:
    if path.suffix.lower() not in allowed:
        raise ArgumentError(f"expected a {' or '.join(allowed)} file, got {path.name!r}", option)


def solve_command(
    scenario: ScenarioArg,
    output: Annotated[Path, typer.Option("-o", "--output", help="strategy file (.npz)")] = Path(
        "strategy.npz"
    ),
    cells: Annotated[str | None, typer.Option(help="grid cells per axis, e.g. 100,100")] = None,
    method: Annotated[str | None, typer.Option(help="auto, structured or general")] = None,
    save_unconverged: Annotated[
        bool, typer.Option(help="save even if the solve did not converge")
    ] = False,
    snap: Annotated[
        bool,
        typer.Option(
            help="--no-snap drops moves whose interpolation snaps the robot sideways "
            "(stricter model, docs/strategies.md)"
        ),
    ] = True,
) -> None:
    """Compute the optimal strategy of a scenario (Section IV) and save it as .npz."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from cellplan.errors import CellplanError
    from cellplan.strategies.strategy import solve_scenario

    _check_suffix(output, (".npz",), "--output")
    if method is not None and method not in ("auto", "structured", "general"):
        raise ArgumentError("must be auto, structured or general", "--method")
    sc, cell = _load(scenario)
    shape = _cells(cells, cell.robot.dim)
    console = Console(stderr=True)
    with Progress(
        TextColumn("[bold]solving[/]"),
        BarColumn(),
        TextColumn("{task.fields[info]}"),
        TimeElapsedColumn(),
        console=console,
        transient=False,
    ) as bar:
        task = bar.add_task("solve", total=None, info="building the model")

        def progress(sweep: int, residual: float, gain: float) -> None:
            bar.update(task, info=f"sweep {sweep}  residual {residual:.3g}  gain {gain:.6f}")

        strategy, result = solve_scenario(
            sc, cell, cells=shape, method=method, progress=progress, snap=snap
        )
        bar.update(
            task, info=f"sweeps {result.sweeps}  span {result.span:.3g}  gain {result.gain:.6f}"
        )
    out = Console()
    out.print(
        f"gain g = {result.gain:.6f} per stage "
        f"(bounds [{result.gain_lower:.6f}, {result.gain_upper:.6f}], "
        f"span {result.span:.2e}); method {result.method}, {result.sweeps} sweeps, "
        f"{result.outer_iterations} outer iterations, {result.seconds:.2f} s; "
        f"policy {'stable' if result.stable else f'changes at {result.policy_changes} states'}"
    )
    if not result.converged and not save_unconverged:
        raise CellplanError(
            [
                Problem(
                    "solver",
                    f"did not converge within {sc.strategy.solver.max_sweeps} sweeps "
                    f"(span {result.span:.3g} >= {sc.strategy.solver.tolerance:g}); nothing saved "
                    "(use --save-unconverged to keep it)",
                )
            ]
        )
    strategy.save(output)
    out.print(f"wrote {output}")


def simulate_command(
    scenario: ScenarioArg,
    strategy: Annotated[
        Path, typer.Option("--strategy", help="strategy file from 'cellplan solve'")
    ],
    stages: Annotated[int, typer.Option(help="number of stages")] = 400,
    seed: Annotated[int, typer.Option(help="random seed")] = 0,
    output: Annotated[Path, typer.Option("-o", "--output", help="output folder")] = Path(
        "simulation"
    ),
    policy: Annotated[str, typer.Option(help="optimal, reactive or home")] = "optimal",
    gif: Annotated[bool, typer.Option(help="write an animated GIF")] = True,
) -> None:
    """Simulate the assembly process under a strategy: frames, GIF and metrics JSON."""
    import numpy as np
    from rich.console import Console

    from cellplan.fileio import write_json
    from cellplan.strategies import plots
    from cellplan.strategies.simulate import POLICIES, simulate
    from cellplan.strategies.strategy import Strategy

    if stages < 1 or stages > 1_000_000:
        raise ArgumentError("must be between 1 and 1000000", "--stages")
    if policy not in POLICIES:
        raise ArgumentError(f"must be one of {', '.join(POLICIES)}", "--policy")
    if output.exists() and not output.is_dir():
        raise ArgumentError(f"{output} exists and is not a folder", "--output")
    sc, cell = _load(scenario)
    strat = Strategy.load(strategy, sc)
    start = np.array(strat.meta.get("start", cell.robot.start), float)
    home = np.array(strat.meta.get("home", cell.robot.start), float)
    sim = simulate(
        strat,
        stages,
        seed,
        policy=policy,
        start=start,
        cell=cell,
        regions=strat.meta.get("regions", "contact"),
        home=home,
    )
    output.mkdir(parents=True, exist_ok=True)
    plots.plot_frames(strat, cell, sim, output)
    if gif:
        plots.save_animation(strat, cell, sim, output / "simulation.gif")
    metrics: dict[str, Any] = dict(sim.metrics())
    metrics.update(policy=policy, seed=seed, gain=strat.gain)
    write_json(
        output / "metrics.json",
        {
            "metrics": metrics,
            "requests": [vars(r) for r in sim.requests],
        },
    )
    Console().print(
        f"{int(metrics['served'])} requests served, mean waiting time "
        f"{metrics['mean_wait']:.2f} (delivered) / {metrics['mean_wait_all']:.2f} (all, open "
        f"ones at their age), loss per stage {metrics['loss_per_stage']:.3f} "
        f"(gain {strat.gain:.3f}), idle fraction {metrics['idle_fraction']:.2f}; wrote {output}"
    )


def plot_command(
    scenario: ScenarioArg,
    strategy: Annotated[
        Path, typer.Option("--strategy", help="strategy file from 'cellplan solve'")
    ],
    mode: Annotated[
        str, typer.Option(help="mode: NR, 'p,s,d,W|C' (1-based indices or names)")
    ] = "NR",
    output: Annotated[Path, typer.Option("-o", "--output", help="image file")] = Path(
        "strategy.png"
    ),
) -> None:
    """Draw the cost-to-go contours and the optimal actions of one mode (Fig. 8)."""
    from rich.console import Console

    from cellplan.strategies import plots
    from cellplan.strategies.strategy import Strategy

    _check_suffix(output, (".png", ".svg", ".pdf"), "--output")
    sc, cell = _load(scenario)
    strat = Strategy.load(strategy, sc)
    try:
        m = strat.mode_index(mode)
    except Exception as exc:  # PersistenceError names the option already
        raise ArgumentError(str(exc).split(": ", 1)[-1], "--mode") from None
    plots.plot_mode(strat, cell, m, output, fixed=cell.robot.start)
    Console().print(f"wrote {output}")


def register(app: typer.Typer) -> None:
    """Add this package's commands to the ``cellplan`` app."""
    app.command("solve")(solve_command)
    app.command("simulate")(simulate_command)
    app.command("plot")(plot_command)
