"""The ``cellplan`` command line.

Core commands live here; each registered package adds its own through the module its
declaration names (:attr:`cellplan.core.Package.commands`, a ``register(app)``
function). Every command goes through the library API. Every user mistake surfaces as a
:class:`~cellplan.errors.CellplanError`: :func:`main` prints one line per problem to
stderr and exits with status 2, without a traceback; any other exception is a bug and
exits 70 with one line naming it (see :mod:`cellplan.cliutil` for every exit status).
"""

from __future__ import annotations

import json
import logging
import signal
import sys
import threading
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from cellplan.cliutil import (
    EXIT_BAD_INPUT,
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    JsonOpt,
    ScenarioArg,
    announce_compiles,
    as_flags,
    check_inputs_kept,
    check_output,
    print_json,
    scenario_file,
    short_help,
)
from cellplan.errors import ArgumentError, CellplanError, Interrupted, printable

app = typer.Typer(
    name="cellplan",
    help="Plan robot motions in assembly workcells (strategies, adaptive planning, disc assembly).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # click's plain help wraps every line at the terminal's width; rich's boxed help cuts
    # long option names and defaults with an ellipsis when the terminal is 80 wide.
    rich_markup_mode=None,
    context_settings={"help_option_names": ["-h", "--help"]},
)
console = Console(stderr=True, soft_wrap=True)
out = Console(soft_wrap=True)


def _version(value: bool) -> None:
    if value:
        from cellplan import __version__

        print(f"cellplan {__version__}")
        raise typer.Exit(0)


@app.callback()
def _root(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True, help="print the version"),
    ] = False,
) -> None:
    """Plan robot motions in assembly workcells (strategies, adaptive planning, disc assembly)."""


OutputOpt = Annotated[Path, typer.Option("-o", "--output", help="output file")]


@app.command()
def schema(as_json: JsonOpt = False) -> None:
    """Print the JSON Schema of scenario files (``--json``: on one line)."""
    from cellplan.scenario import json_schema

    if as_json:
        print_json(json_schema())
        return
    print(json.dumps(json_schema(), indent=2))


@app.command()
def scenarios(as_json: JsonOpt = False) -> None:
    """List the bundled scenarios."""
    from cellplan.api import load
    from cellplan.registry import scenario_names

    rows: list[dict[str, Any]] = []
    for name in scenario_names():
        sc = load(name).scenario
        rows.append(
            {
                "name": name,
                "robot": sc.robot.type if sc.robot else None,
                "sections": list(sc.section_names()),
                "description": first_sentence(sc.description),
            }
        )
    if as_json:
        print_json({"scenarios": rows})
        return
    table = Table("name", "robot", "sections", "description")
    for row in rows:
        table.add_row(
            row["name"], row["robot"] or "-", ", ".join(row["sections"]) or "-", row["description"]
        )
    out.print(table)


def first_sentence(text: str) -> str:
    """The first sentence of a description, its line breaks joined."""
    flat = " ".join(text.split())
    end = flat.find(". ")
    return flat if end < 0 else flat[: end + 1]


@app.command()
def planners(as_json: JsonOpt = False) -> None:
    """List the registered planners."""
    from cellplan.api import planners as registered

    if as_json:
        print_json(
            {
                "planners": [
                    {
                        "name": spec.name,
                        "package": spec.package,
                        "section": spec.section,
                        "summary": spec.summary,
                        "options": [
                            {
                                "name": key,
                                "default": plain_value(info.default),
                                "description": info.description or "",
                            }
                            for key, info in spec.options.model_fields.items()
                        ],
                    }
                    for spec in registered().values()
                ]
            }
        )
        return
    table = Table("name", "section", "summary", "options (default)")
    for spec in registered().values():
        options = ", ".join(f"{name} ({default})" for name, default, _ in spec.option_table())
        table.add_row(spec.name, spec.section or "-", spec.summary, options)
    out.print(table)


def plain_value(value: Any) -> Any:
    """An option's default as JSON keeps it: numbers, text, flags, None and lists of these
    as they are, an enum as its value, anything else as its ``repr``."""
    import enum

    if isinstance(value, enum.Enum):
        value = value.value
    if value is None or isinstance(value, str | int | float | bool):
        return value
    if isinstance(value, list | tuple):
        return [plain_value(v) for v in value]
    return repr(value)


@app.command()
def validate(scenario: ScenarioArg, as_json: JsonOpt = False) -> None:
    """Validate a scenario and print a short summary (modes, C-space dimension, free fraction)."""
    from cellplan.api import load
    from cellplan.cliutil import progress_bar, progress_enabled
    from cellplan.summary import facts

    setup = load(scenario)
    with progress_bar(progress_enabled(as_json), "validating") as progress:
        found = facts(setup, progress)
    if as_json:
        # Machine keys and typed values (counts int, fractions float, names lists); the
        # labels the text output prints stay beside them.
        print_json(
            {
                "status": "valid",
                "message": "the scenario is valid",
                "summary": {f.key: f.value for f in found},
                "labels": {f.key: f.label for f in found},
            }
        )
        return
    for fact in found:
        out.print(printable(f"{fact.label:>22}: {fact.text}"), markup=False)


@app.command()
def show(
    scenario: ScenarioArg,
    output: OutputOpt = Path("workcell.png"),
    view: Annotated[str, typer.Option(help="3-D cells: iso, front, side or top")] = "iso",
    as_json: JsonOpt = False,
) -> None:
    """Draw the scenario: the workcell, the robot at its start carrying a part, and what
    each section adds (discs' starts and goals, adaptive goals and workcell changes)."""
    from cellplan.api import load
    from cellplan.drawing import draw

    check_image_path(output)
    check_inputs_kept([("--output", output)], {"SCENARIO": scenario_file(scenario)})
    setup = load(scenario)
    with as_flags({"robot": "robot"}):  # --view for the view; the scenario's robot as is
        draw(setup, output, view=view)
    written(as_json, {"image": output}, f"wrote {output}")


def written(
    as_json: bool, outputs: dict[str, Path], line: str, extra: dict[str, Any] | None = None
) -> None:
    """A command that writes files says so: ``line`` on stdout, or with ``--json`` one
    object ``{"status": "written", "message": line, "outputs": {...}, **extra}``."""
    if as_json:
        payload = {"status": "written", "message": line, "outputs": outputs}
        print_json(payload | (extra or {}))
    else:
        out.print(printable(line), markup=False)


@app.command()
def view(
    scenario: ScenarioArg,
    output: OutputOpt = Path("cell.html"),
    trajectory: Annotated[
        Path | None,
        typer.Option(help="a trajectory of the scenario's robot to play (CSV, JSON or NPZ)"),
    ] = None,
    as_json: JsonOpt = False,
) -> None:
    """Write an interactive 3-D viewer page of a 3-D cell: one self-contained HTML file
    (no network), where the cell can be rotated and a trajectory played."""
    from cellplan.api import load
    from cellplan.scene3d import HOLD_ENDS, HOLD_STARTS, cell_scene, held_from_events
    from cellplan.trajectory import Trajectory
    from cellplan.view3d import write_viewer
    from cellplan.workcell3d import Workcell3D

    if output.suffix.lower() not in (".html", ".htm"):
        raise ArgumentError(f"the viewer is an HTML page; got {output.suffix!r}", "--output")
    check_output(output)
    inputs = {"SCENARIO": scenario_file(scenario), "--trajectory": trajectory}
    check_inputs_kept([("--output", output)], inputs)
    setup = load(scenario)
    cell = setup.workcell if setup.has_robot else None
    if not isinstance(cell, Workcell3D):
        raise ArgumentError("the viewer shows 3-D cells (bounds with zmin and zmax)", "SCENARIO")
    if trajectory is None:
        scene = cell_scene(cell, title=f"{setup.name} (start)")
    else:
        traj = Trajectory.load(trajectory)
        if traj.dim != cell.robot.dim:
            raise ArgumentError(
                f"has {traj.dim} columns; the robot has {cell.robot.dim} joints", "--trajectory"
            )
        unit = "s" if traj.time_unit == "s" else traj.time_unit
        # The part held between pick and place events is drawn on the tool (the same
        # reading as the viewer of `assemble --algorithm robot`).
        unknown = sorted(
            {e.part for e in traj.events if e.kind in HOLD_STARTS + HOLD_ENDS and e.part}
            - set(cell.parts)
        )
        if unknown:
            raise ArgumentError(
                f"its pick/place events name parts the scenario lacks: {', '.join(unknown)} "
                f"(known: {', '.join(cell.parts) or 'none'})",
                "--trajectory",
            )
        scene = cell_scene(
            cell,
            traj.q,
            traj.t,
            carrying=held_from_events(traj.events, len(traj)),
            title=f"{setup.name}: {trajectory.name}",
            time_label=f"t ({unit})",
        )
    write_viewer(scene, output)
    written(as_json, {"page": output}, f"wrote {output}")


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
    as_json: JsonOpt = False,
) -> None:
    """Draw the free-configuration bitmap (a slice for 3-D spaces)."""
    from cellplan import plots
    from cellplan.api import load
    from cellplan.cspace import Grid, check_memory, free_bitmap

    check_image_path(output)
    check_inputs_kept([("--output", output)], {"SCENARIO": scenario_file(scenario)})
    cell = load(scenario).workcell
    if carrying is not None and carrying not in cell.parts:
        raise ArgumentError(
            f"unknown part {carrying!r} (parts: {', '.join(cell.parts) or 'none'})", "--carrying"
        )
    if cell.robot.dim not in (2, 3):
        raise ArgumentError(
            f"pictures of configuration space show 2 or 3 axes; this robot has "
            f"{cell.robot.dim} (a URDF arm's robot.joints chooses the active ones)",
            "SCENARIO",
        )
    shape = parse_cells(cells, cell.robot.dim) if cells is not None else cell.default_cells
    grid = Grid.for_robot(cell.robot, shape)
    if slice_index is not None and (grid.ndim != 3 or not 0 <= slice_index < grid.shape[2]):
        limit = f"[0, {grid.shape[2] - 1}]" if grid.ndim == 3 else "a 3-D C-space only"
        raise ArgumentError(f"must be in {limit}, got {slice_index}", "--slice")
    check_memory(cell, grid, carrying, field="--cells" if cells else "cspace.cells")
    free = free_bitmap(cell, grid, carrying=carrying)
    plots.save_cspace(
        cell,
        grid,
        free,
        output,
        slice_index=slice_index,
        title_extra=f"carrying {carrying}" if carrying else "empty",
        carrying=carrying is not None,
    )
    fraction = float(free.mean())
    written(
        as_json,
        {"image": output},
        f"wrote {output}  (free fraction {fraction:.3f})",
        {
            "free_fraction": fraction,
            "cells": [int(n) for n in grid.shape],
            "carrying": carrying,
            "slice": slice_index,
        },
    )


@app.command()
def export(
    trajectory: Annotated[Path, typer.Argument(help="a trajectory file (.csv, .json, .npz)")],
    output: Annotated[Path, typer.Option("-o", "--output", help="output file (bag: folder)")],
    fmt: Annotated[
        str, typer.Option("--format", "-f", help="ros2-yaml, ros2-bag (MCAP folder) or csv")
    ] = "ros2-yaml",
    retime: Annotated[
        bool, typer.Option("--retime", help="time-optimal timing first (TOPP-RA)")
    ] = False,
    velocity_limits: Annotated[
        str | None,
        typer.Option(
            help="retime with these speeds per column, comma-separated (units/s, degrees/s "
            "for angles; default: the trajectory's)"
        ),
    ] = None,
    acceleration_limits: Annotated[
        str | None,
        typer.Option(help="retime with these accelerations (units/s^2, degrees/s^2 for angles)"),
    ] = None,
    frame_id: Annotated[str, typer.Option(help="header.frame_id of the messages")] = "",
    as_json: JsonOpt = False,
) -> None:
    """Write a trajectory for a controller: ROS 2 JointTrajectory YAML, a ROS 2 bag, or CSV."""
    from cellplan import export as ros
    from cellplan import timing, units
    from cellplan.cliutil import as_flags
    from cellplan.trajectory import Trajectory

    ros.check_format(fmt)
    if fmt == "ros2-bag" and (output.exists() or output.is_symlink()):
        raise ArgumentError("exists; a bag folder is never replaced", "--output")
    if fmt != "ros2-bag":
        check_output(output)
    check_inputs_kept([("--output", output)], {"TRAJ": trajectory})
    traj = Trajectory.load(trajectory)
    limits = {}
    for option, text in (
        ("--velocity-limits", velocity_limits),
        ("--acceleration-limits", acceleration_limits),
    ):
        if text is not None:
            try:
                values = [float(v) for v in text.split(",")]
            except ValueError:
                raise ArgumentError(
                    f"expected comma-separated numbers, got {text!r}", option
                ) from None
            checked = timing.check_limits(values, traj.dim, option)  # in the given units
            limits[option] = units.config_from_file(
                traj.columns, checked.tolist(), [u == units.ANGLE for u in traj.units]
            )
    if retime or limits:
        with as_flags():
            traj = traj.retime(limits.get("--velocity-limits"), limits.get("--acceleration-limits"))
    written = ros.export(traj, fmt, output, frame_id)
    if as_json:
        print_json(
            {
                "output": str(written),
                "format": fmt,
                "samples": len(traj),
                "seconds": traj.duration_s,
                "retimed": bool(retime or limits),
            }
        )
    else:
        out.print(
            printable(f"wrote {written}  ({len(traj)} samples, {traj.duration_s:.3f} s)"),
            markup=False,
        )


@app.command()
def demo(output: OutputOpt = Path("cellplan-out"), as_json: JsonOpt = False) -> None:
    """Run every experiment quickly and write OUTPUT/index.html (about 2 minutes)."""
    from cellplan.demo import run_demo

    index = run_demo(output, console=console)
    written(as_json, {"report": index}, f"demo written: {index}")


def parse_cells(text: str, dim: int) -> tuple[int, ...]:
    """Parse ``--cells 128,128,64`` (each value within :data:`cellplan.cspace.CELLS_RANGE`)."""
    from cellplan.cspace import CELLS_RANGE

    lo, hi = CELLS_RANGE
    try:
        shape = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise ArgumentError(f"expected comma-separated integers, got {text!r}", "--cells") from None
    if len(shape) != dim:
        raise ArgumentError(f"needs {dim} values for this robot, got {len(shape)}", "--cells")
    if any(n < lo or n > hi for n in shape):
        raise ArgumentError(f"each value must be in [{lo}, {hi}]", "--cells")
    return shape


def check_image_path(path: Path) -> None:
    """Refuse output names matplotlib cannot write, before any work is done."""
    if path.suffix.lower() not in {".png", ".svg", ".pdf", ".jpg", ".jpeg"}:
        raise ArgumentError(
            f"unsupported image type {path.suffix!r}; use .png, .svg or .pdf", "--output"
        )
    check_output(path)


def _register_package_commands() -> None:
    import importlib

    from cellplan import reproduce_cli
    from cellplan.registry import packages

    for pkg in packages().values():
        if pkg.commands is not None:
            importlib.import_module(pkg.commands).register(app)
    reproduce_cli.register(app)
    for info in app.registered_commands:
        text = info.help or (info.callback.__doc__ if info.callback else None)
        if info.short_help is None and text:
            info.short_help = short_help(text)


_register_package_commands()


MAX_PROBLEM_LINES = 100
"""Most problems printed for one command; a count of the rest follows (a file with a
million wrong values gets 101 lines, not a million)."""


def main() -> None:
    """Entry point: :func:`_dispatch` the command, with Ctrl-C made reliable.

    Python turns SIGINT into ``KeyboardInterrupt`` wherever the main thread is; raised
    inside a finaliser or a callback from compiled code (OMPL's, SQLite's), it is printed
    as "Exception ignored" and the run goes on to exit 0. So SIGINT also sets a flag, a
    swallowed interrupt is not printed, and a run that saw one ends with ``interrupted``
    and status 130 whatever it was about to return.
    """
    interrupted = threading.Event()
    previous_hook = sys.unraisablehook

    def on_sigint(signum: int, frame: object) -> None:
        interrupted.set()
        raise KeyboardInterrupt

    def unraisable(info: Any) -> None:
        if isinstance(info.exc_value, KeyboardInterrupt):
            interrupted.set()
            return
        previous_hook(info)

    # A background job of a non-interactive shell starts with SIGINT ignored: keep that.
    previous_handler = signal.getsignal(signal.SIGINT)
    catch = previous_handler is signal.default_int_handler
    if catch:
        signal.signal(signal.SIGINT, on_sigint)
    sys.unraisablehook = unraisable
    notes = _NoteHandler()
    library_log = logging.getLogger("cellplan")
    library_log.addHandler(notes)
    try:
        with announce_compiles():
            _dispatch()
        code: str | int | None = 0
    except SystemExit as exc:
        code = exc.code
    finally:
        # main() may run in-process (tests, the fuzzers): leave the process as it was.
        sys.unraisablehook = previous_hook
        library_log.removeHandler(notes)
        if catch:
            signal.signal(signal.SIGINT, previous_handler)
    if interrupted.is_set() and code != EXIT_INTERRUPTED:
        # Swallowed on the way (the command went on): say it here, once.
        console.print("interrupted", markup=False)
        code = EXIT_INTERRUPTED
    sys.exit(code)


class _NoteHandler(logging.Handler):
    """The library's warnings (long work announced, :data:`cellplan.budget.NOTICE_SECONDS`)
    as one ``note:`` line each on stderr, input escaped like every line printed."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)

    def emit(self, record: logging.LogRecord) -> None:
        text = " ".join(printable(record.getMessage()).split())
        console.print(f"note: {text}", markup=False, highlight=False, soft_wrap=True)


def _dispatch() -> None:
    """Run the app and turn every outcome into an exit status.

    User errors (ours and the command-line parser's) become one line each, ``error:
    WHERE: what``, and exit 2; an unexpected exception is a bug: one line naming its
    type, exit 70 (``CELLPLAN_DEBUG=1`` shows the traceback). Every line is printed as
    plain text: a name or value from the input is never read as console markup.
    """
    import os

    try:
        code = app(standalone_mode=False)
    except CellplanError as exc:
        for problem in exc.problems[:MAX_PROBLEM_LINES]:
            _error_line(str(problem))
        if len(exc.problems) > MAX_PROBLEM_LINES:
            more = len(exc.problems) - MAX_PROBLEM_LINES
            _error_line(f"{more} more problem{'s' if more > 1 else ''} not shown")
        sys.exit(EXIT_BAD_INPUT)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except (typer.Abort, KeyboardInterrupt):
        console.print("interrupted", markup=False)
        sys.exit(EXIT_INTERRUPTED)
    except Interrupted as exc:
        console.print(printable(str(exc)), markup=False, highlight=False, soft_wrap=True)
        sys.exit(EXIT_INTERRUPTED)
    except OSError as exc:
        # A path the user named cannot be read or written (a folder where a file is
        # expected, a missing parent, no permission): their input, not a bug.
        where = exc.filename if exc.filename is not None else "output"
        _error_line(f"{where}: {exc.strerror or exc}")
        sys.exit(EXIT_BAD_INPUT)
    except Exception as exc:
        # Usage errors (unknown option, missing argument, a value of the wrong type)
        # arrive here in non-standalone mode; recent typer versions raise their own copy
        # of click's exceptions.
        if isinstance(exc, _usage_error_types()):
            _error_line(_usage_line(exc))
            sys.exit(getattr(exc, "exit_code", EXIT_BAD_INPUT))
        if os.environ.get("CELLPLAN_DEBUG"):
            raise
        detail = " ".join(str(exc).split())[:300]
        _error_line(
            f"{type(exc).__name__}: {detail}",
            label="internal error (a bug in cellplan, please report it)",
        )
        sys.exit(EXIT_INTERNAL)
    if code == EXIT_INTERRUPTED:  # typer's answer to a Ctrl-C it caught: no line of its own
        console.print("interrupted", markup=False)
    sys.exit(code if isinstance(code, int) else 0)


def _error_line(text: str, label: str = "error") -> None:
    """Print ``label: text`` on stderr as one line, ``text`` never read as markup nor
    sent to the terminal with its control characters (:func:`cellplan.errors.printable`)."""
    from rich.text import Text

    line = Text.assemble((label, "bold red"), ": ", printable(" ".join(text.split())))
    console.print(line, highlight=False, soft_wrap=True)


def _usage_line(exc: Exception) -> str:
    """A command-line parser error as ``WHERE: what (see 'cellplan CMD -h')``.

    WHERE is the option (its long name) or the argument (upper case) at fault; the
    parser's own ``Invalid value for '--x':`` preamble is dropped since WHERE says it.
    """
    import re

    param = getattr(exc, "param", None)
    where = getattr(exc, "option_name", None) or ""
    if param is not None:
        opts = [o for o in getattr(param, "opts", []) if o.startswith("--")]
        if getattr(param, "param_type_name", "") == "argument" or not opts:
            where = str(getattr(param, "name", "") or "argument").upper()
        else:
            where = max(opts, key=len)
    message = exc.format_message() if hasattr(exc, "format_message") else str(exc)
    message = re.sub(r"^Invalid value for [^:]*: ", "", message)
    ctx = getattr(exc, "ctx", None)
    command = getattr(ctx, "command_path", None) or "cellplan"
    hint = f" (see '{command} -h')"
    return f"{where}: {message}{hint}" if where else f"{command}: {message}{hint}"


def _usage_error_types() -> tuple[type[BaseException], ...]:
    import click

    found = [getattr(typer, "TyperException", None), getattr(click, "ClickException", None)]
    return tuple(t for t in found if isinstance(t, type))


if __name__ == "__main__":
    main()
