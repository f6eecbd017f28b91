"""The ``cellplan`` command line.

Core commands live here; each paper package adds its own through
``<package>.commands.register``. Every user mistake surfaces as a
:class:`~cellplan.errors.CellplanError`: :func:`main` prints one line per
problem to stderr and exits with status 2, without a traceback.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from cellplan.errors import ArgumentError, CellplanError

app = typer.Typer(
    name="cellplan",
    help="Plan robot motions in assembly workcells (strategies, adaptive planning, disc assembly).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console(stderr=True)
out = Console()

ScenarioArg = Annotated[
    str, typer.Argument(help="scenario file, or the name of a bundled scenario")
]
OutputOpt = Annotated[Path, typer.Option("-o", "--output", help="output file")]


@app.command()
def schema() -> None:
    """Print the JSON Schema of scenario files."""
    from cellplan.scenario import json_schema

    print(json.dumps(json_schema(), indent=2))


@app.command()
def scenarios() -> None:
    """List the bundled scenarios."""
    from cellplan.registry import scenario_names, scenario_path
    from cellplan.scenario import load_scenario

    table = Table("name", "robot", "sections", "description")
    for name in scenario_names():
        sc = load_scenario(scenario_path(name))
        table.add_row(
            name,
            sc.robot.type if sc.robot else "-",
            ", ".join(sc.section_names()) or "-",
            sc.description.split("\n")[0],
        )
    out.print(table)


@app.command()
def planners() -> None:
    """List the registered planners."""
    from cellplan.registry import planners as registered

    table = Table("name", "paper", "summary")
    for entry in registered().values():
        table.add_row(entry.name, entry.paper, entry.summary)
    out.print(table)


@app.command()
def validate(scenario: ScenarioArg) -> None:
    """Validate a scenario and print a short summary (modes, C-space dimension, free fraction)."""
    from cellplan.scenario import load_scenario
    from cellplan.summary import summarize
    from cellplan.workcell import Workcell

    sc = load_scenario(scenario)
    cell = Workcell.from_scenario(sc) if sc.robot is not None else None
    for key, value in summarize(sc, cell).items():
        out.print(f"{key:>22}: {value}")


@app.command()
def show(scenario: ScenarioArg, output: OutputOpt = Path("workcell.png")) -> None:
    """Draw the workcell: obstacles, sources, destinations, robot at start, a carried part."""
    from cellplan import plots
    from cellplan.workcell import load_workcell

    _, cell = load_workcell(scenario)
    check_image_path(output)
    plots.save_workcell(cell, output)
    out.print(f"wrote {output}")


@app.command()
def cspace(
    scenario: ScenarioArg,
    output: OutputOpt = Path("cspace.png"),
    carrying: Annotated[str | None, typer.Option(help="part carried (default: none)")] = None,
    cells: Annotated[
        str | None, typer.Option(help="cells per axis, comma-separated (e.g. 128,128,64)")
    ] = None,
    slice_index: Annotated[
        int | None, typer.Option("--slice", help="index of the 2-D slice of a 3-D space")
    ] = None,
) -> None:
    """Draw the free-configuration bitmap (a slice for 3-D spaces)."""
    from cellplan import plots
    from cellplan.cspace import Grid, free_bitmap
    from cellplan.workcell import load_workcell

    _, cell = load_workcell(scenario)
    check_image_path(output)
    if carrying is not None and carrying not in cell.parts:
        raise ArgumentError(
            f"unknown part {carrying!r} (parts: {', '.join(cell.parts) or 'none'})", "--carrying"
        )
    shape = parse_cells(cells, cell.robot.dim) if cells else cell.default_cells
    grid = Grid.for_robot(cell.robot, shape)
    free = free_bitmap(cell, grid, carrying=carrying)
    plots.save_cspace(
        cell,
        grid,
        free,
        output,
        slice_index=slice_index,
        title_extra=f"carrying {carrying}" if carrying else "empty",
    )
    out.print(f"wrote {output}  (free fraction {free.mean():.3f})")


@app.command()
def demo(output: OutputOpt = Path("cellplan-out")) -> None:
    """Run quick versions of every experiment and write OUTPUT/index.html (about 1 minute)."""
    from cellplan.demo import run_demo

    index = run_demo(output, console=console)
    out.print(f"demo written: {index}")


def parse_cells(text: str, dim: int) -> tuple[int, ...]:
    """Parse ``--cells 128,128,64``."""
    try:
        shape = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise ArgumentError(f"expected comma-separated integers, got {text!r}", "--cells") from None
    if len(shape) != dim:
        raise ArgumentError(f"needs {dim} values for this robot, got {len(shape)}", "--cells")
    if any(n < 2 or n > 4096 for n in shape):
        raise ArgumentError("each value must be in [2, 4096]", "--cells")
    return shape


def check_image_path(path: Path) -> None:
    """Refuse output names matplotlib cannot write, before any work is done."""
    if path.suffix.lower() not in {".png", ".svg", ".pdf", ".jpg", ".jpeg"}:
        raise ArgumentError(
            f"unsupported image type {path.suffix!r}; use .png, .svg or .pdf", "--output"
        )


def _register_package_commands() -> None:
    from cellplan import reproduce_cli
    from cellplan.adaptive import commands as adaptive_commands
    from cellplan.assembly import commands as assembly_commands
    from cellplan.strategies import commands as strategy_commands

    for module in (strategy_commands, adaptive_commands, assembly_commands, reproduce_cli):
        module.register(app)


_register_package_commands()


def main() -> None:
    """Entry point: run the app; user errors become one line each and exit status 2."""
    try:
        app(standalone_mode=False)
    except CellplanError as exc:
        for problem in exc.problems:
            console.print(f"[bold red]error[/]: {problem}", highlight=False, soft_wrap=True)
        sys.exit(2)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except (typer.Abort, KeyboardInterrupt):
        console.print("aborted")
        sys.exit(130)
    except Exception as exc:
        # Usage errors (unknown option, missing argument) arrive here in non-standalone
        # mode; recent typer versions raise their own copy of click's exceptions.
        if isinstance(exc, _usage_error_types()):
            exc.show()  # type: ignore[attr-defined]
            sys.exit(getattr(exc, "exit_code", 2))
        raise


def _usage_error_types() -> tuple[type[BaseException], ...]:
    import click

    found = [getattr(typer, "TyperException", None), getattr(click, "ClickException", None)]
    return tuple(t for t in found if isinstance(t, type))


if __name__ == "__main__":
    main()
