"""Helpers every CLI command shares: the ``--json`` option, summaries, exit statuses.

Exit statuses (also in docs/reliability.md): 0 solved, 1 ran but did not solve (the
status line says why), 2 bad input or arguments, 70 internal error (a bug), 130
interrupted. With ``--json`` a command prints exactly one JSON object on stdout
(status, message, stats, output files) and nothing else there; progress and notes go
to stderr.
"""

from __future__ import annotations

import contextlib
import dataclasses
import inspect
import logging
import os
import sys
import typing
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer
from numba.core import event
from rich.console import Console

from cellplan.core import Progress, Result
from cellplan.errors import ArgumentError, CellplanError, Problem, printable
from cellplan.fileio import check_distinct, check_replaceable, dumps_json
from cellplan.plots import GIF_SIZE, GIF_SIZE_RANGE
from cellplan.registry import resolve_scenario_path

EXIT_SOLVED = 0
EXIT_NOT_SOLVED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERNAL = 70
EXIT_INTERRUPTED = 130

JsonOpt = Annotated[
    bool,
    typer.Option(
        "--json", help="print one JSON object (status, message, stats, outputs) on stdout"
    ),
]
GifSizeOpt = Annotated[
    str | None,  # parsed by cellplan.plots.check_gif_size, so a bad value is one line
    typer.Option(
        "--gif-size",
        metavar="PIXELS",
        help=f"width of the GIF's frames in pixels, {GIF_SIZE_RANGE[0]}-{GIF_SIZE_RANGE[1]} "
        f"(default {GIF_SIZE})",
    ),
]
ScenarioArg = Annotated[
    str, typer.Argument(help="scenario file, or the name of a bundled scenario")
]


@contextlib.contextmanager
def as_flags(names: Mapping[str, str] | None = None) -> Iterator[None]:
    """Name the library's option problems as the command-line flags that set them.

    ``plan(..., max_sweeps=-1)`` reports ``max_sweeps: ...``; on the command line the
    same problem reads ``--max-sweeps: ...``. ``names`` maps an argument whose flag is
    named otherwise (``{"size": "--gif-size"}``). Duplicate lines are dropped.
    """
    renamed = dict(names or {})
    try:
        yield
    except ArgumentError as exc:
        flagged = [
            Problem(renamed.get(p.field) or "--" + p.field.replace("_", "-"), p.message)
            if p.field and not p.field.startswith("-")
            else p
            for p in exc.problems
        ]
        raise ArgumentError(list(dict.fromkeys(flagged))) from None


@contextlib.contextmanager
def progress_bar(enabled: bool, title: str, counts: bool = False) -> Iterator[Progress | None]:
    """A planner's ``progress`` callback drawing a bar on stderr, or None when disabled.

    Pass ``progress_enabled(as_json)`` as ``enabled``: bars are drawn only on a terminal
    and never with ``--json``. ``counts`` adds "done/total" (tasks, stages).
    """
    if not enabled:
        yield None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn
    from rich.progress import Progress as Bar

    columns = [TextColumn(f"[bold]{title}[/]"), BarColumn()]
    if counts:
        columns.append(MofNCompleteColumn())
    columns += [TextColumn("{task.description}"), TimeElapsedColumn()]
    with Bar(*columns, console=stderr(), transient=True) as bar:
        task = bar.add_task("", total=None)

        def update(done: float, total: float | None, text: str) -> None:
            bar.update(task, completed=done, total=total, description=text)

        yield update


def stdout() -> Console:
    """A console for summaries: stdout, never hard-wrapped (safe to pipe)."""
    return Console(soft_wrap=True, highlight=False)


def stderr() -> Console:
    """A console for progress and notes."""
    return Console(stderr=True, soft_wrap=True, highlight=False)


def progress_enabled(as_json: bool) -> bool:
    """Progress bars are drawn only on a terminal, never with ``--json``."""
    return not as_json and sys.stderr.isatty()


def finish(
    result: Result,
    as_json: bool,
    summary: str,
    outputs: Mapping[str, str | Path] | None = None,
    extra: Mapping[str, Any] | None = None,
) -> None:
    """Print the result (a summary line, or one JSON object) and exit 0 if solved, else 1.

    The summary line starts with the status when the plan did not succeed, so a person
    sees at once why the exit status is 1.
    """
    files = {k: str(v) for k, v in (outputs or {}).items()}
    if as_json:
        payload = result.summary()
        payload["outputs"] = files
        if extra:
            payload.update(dict(extra))
        sys.stdout.write(dumps_json(payload) + "\n")
        sys.stdout.flush()
    else:
        line = summary if result.success else f"{result.status.value}: {result.message}. {summary}"
        stdout().print(printable(line), markup=False)
    raise typer.Exit(EXIT_SOLVED if result.success else EXIT_NOT_SOLVED)


def print_json(payload: Mapping[str, Any]) -> None:
    """Write one JSON object on stdout (non-finite numbers become null)."""
    sys.stdout.write(dumps_json(dict(payload)) + "\n")
    sys.stdout.flush()


def check_output(path: Path, option: str = "--output", folder: bool = False) -> Path:
    """Refuse an output path that cannot be written, before any work starts.

    ``folder``: the path is a folder to create or fill (it must not be a file); otherwise
    a file to write (it must not be a folder). Missing parent folders are created later,
    so every existing ancestor must be a folder, and the nearest one writable.

    Raises
    ------
    ArgumentError
        One line naming ``option``.
    """
    if str(path) == "":
        raise ArgumentError("is empty; give a path", option)
    if folder and path.exists() and not path.is_dir():
        raise ArgumentError(f"{path} exists and is not a folder", option)
    for parent in path.absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise ArgumentError(f"{parent} is a file, not a folder", option)
            if not os.access(parent, os.W_OK | os.X_OK):
                raise ArgumentError(f"cannot write in {parent} (permission denied)", option)
            break
    if not folder:
        # A link, device, FIFO or folder is never replaced; nor a name too long to write.
        check_replaceable(path, option)
    return path


def check_inputs_kept(
    outputs: Iterable[tuple[str, Path]], inputs: Mapping[str, Path | None]
) -> None:
    """Refuse, before any work, an output that would land on one of the command's inputs.

    Parameters
    ----------
    outputs
        ``(option, file)`` for every file the command writes (a folder output: each of
        the names it writes there, see :func:`folder_files`).
    inputs
        ``option -> path`` of what the command reads or updates (a scenario argument
        through :func:`scenario_file`); None stands for an input not given.

    Raises
    ------
    ArgumentError
        One line per output that is an input (the same file by any name: a link, a hard
        link, a relative path).
    """
    check_distinct(outputs, {k: v for k, v in inputs.items() if v is not None})


def scenario_file(arg: str | None) -> Path | None:
    """The file a scenario argument names (a bundled scenario's own file for a name), or
    None where it names none: that is reported when the scenario is loaded."""
    if arg is None:
        return None
    try:
        return resolve_scenario_path(arg)
    except CellplanError:
        return None


def folder_files(option: str, folder: Path, names: Iterable[str]) -> list[tuple[str, Path]]:
    """``(option, folder / name)`` for each file a command writes into an output folder."""
    return [(option, folder / name) for name in names]


#: The note printed when a kernel compiles during a command (once per process); the
#: cache it names is described in :mod:`cellplan.warmup`.
SHORT_HELP_WIDTH = 60
"""Most characters of a command's line in ``cellplan --help``: click cuts a longer one with
"..." in an 80-column terminal (its width less the indent and the longest command name)."""


_Args = TypeVar("_Args")


def command_from(fields: type[_Args], run: Callable[[_Args], None]) -> Callable[..., None]:
    """A CLI command whose options are the fields of a frozen dataclass.

    A typer command needs one parameter per option; a command with many options takes
    them as one dataclass instead, whose fields carry the typer ``Annotated`` metadata
    and the defaults. The command returned has exactly those fields as its signature
    (typer reads ``inspect.signature``, which honours ``__signature__``), ``run``'s name
    and docstring (the command's help), and calls ``run(fields(...))``. A name that is
    not a field is refused (``TypeError`` from Python; click's exit 2 on the command line).
    """
    hints = typing.get_type_hints(fields, include_extras=True)
    signature = inspect.Signature(
        [
            inspect.Parameter(
                f.name,
                inspect.Parameter.POSITIONAL_OR_KEYWORD,
                default=inspect.Parameter.empty if f.default is dataclasses.MISSING else f.default,
                annotation=hints[f.name],
            )
            for f in dataclasses.fields(fields)  # type: ignore[arg-type]  # a dataclass
        ]
    )

    def command(*args: Any, **options: Any) -> None:
        # bind() raises TypeError for a name not in the signature: nothing is swallowed.
        bound = signature.bind(*args, **options)
        bound.apply_defaults()
        run(fields(**bound.arguments))

    command.__signature__ = signature  # type: ignore[attr-defined]
    command.__name__ = run.__name__
    command.__qualname__ = run.__qualname__
    command.__doc__ = run.__doc__
    command.__module__ = run.__module__
    return command


def short_help(text: str) -> str:
    """A command's line for ``cellplan --help``: its help's first sentence, without the
    parenthesis or colon that details it, and without reST markup.

    A line still longer than :data:`SHORT_HELP_WIDTH` is returned whole: the test of the
    command list then names the command, whose docstring should begin shorter.
    """
    first = " ".join(text.strip().split("\n\n")[0].split())
    first = first.split(". ")[0].rstrip(".")
    for stop in (" (", ": ", "; "):
        head = first.split(stop)[0]
        if len(first) > SHORT_HELP_WIDTH and head:
            first = head
    return first.replace("``", "")


COMPILE_NOTE = (
    "compiling numba kernels for this code path (first use after an install or an update; "
    "cached afterwards: `make install` compiles them ahead, `make clean-kernels` clears "
    "the cache)"
)


class _FirstCompile(event.Listener):
    """Logs :data:`COMPILE_NOTE` as a warning at the first compile it sees, then nothing."""

    def __init__(self) -> None:
        self.seen = False

    def on_start(self, ev: event.Event) -> None:
        if not self.seen:
            self.seen = True
            logging.getLogger("cellplan.kernels").warning(COMPILE_NOTE)

    def on_end(self, ev: event.Event) -> None:
        """Nothing to say when a compile ends."""


@contextlib.contextmanager
def announce_compiles() -> Iterator[None]:
    """A context in which the first numba compile logs :data:`COMPILE_NOTE`, once.

    numba fires its ``numba:compile`` event only for a real compile, not for a kernel
    loaded from its on-disk cache, so a warm run says nothing. The CLI prints the
    warning as one ``note:`` line on stderr.
    """
    with event.install_listener("numba:compile", _FirstCompile()):
        yield
