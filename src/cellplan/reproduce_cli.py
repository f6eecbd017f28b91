"""``cellplan reproduce``: run the papers' experiments and write the HTML report.

Registered on the main app by :func:`register`. Every argument is checked
before any work; a bad one is one line naming the option and exit status 2
(through :class:`~cellplan.errors.ArgumentError` and ``cli.main``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer

from cellplan.errors import ArgumentError, Problem

T = TypeVar("T")

TARGETS = ("strategies", "adaptive", "assembly", "all")

PAPER_RUNS: dict[str, int] = {"strategies": 10, "adaptive": 100, "assembly": 25}
"""Default repetitions per parameter point: the papers' own counts (Chen: 100 runs,
Whitcomb and Koditschek: 25 random starts); the strategies paper reports single
sample paths, so 10 seeded simulations per problem give confidence intervals."""


def parse_runs(text: str | None) -> int | None:
    """``--runs``: a positive integer, or ``None`` for each paper's own count."""
    if text is None:
        return None
    try:
        value = int(text)
    except ValueError:
        raise ArgumentError(f"expected a positive integer, got {text!r}", "--runs") from None
    if value < 1 or value > 100_000:
        raise ArgumentError(f"must be between 1 and 100000, got {value}", "--runs")
    return value


def parse_target(text: str) -> list[str]:
    """The positional target: one paper, or ``all``."""
    if text not in TARGETS:
        raise ArgumentError(f"unknown target {text!r} (choose from {', '.join(TARGETS)})", "TARGET")
    return list(TARGETS[:-1]) if text == "all" else [text]


def check_output_dir(path: Path) -> Path:
    """``-o``: a folder, existing or not, but not a file."""
    if path.exists() and not path.is_dir():
        raise ArgumentError(f"{path} exists and is not a folder", "--output")
    return path


def reproduce(
    papers: Sequence[str],
    outdir: Path,
    runs: int | None = None,
    quick: bool = False,
    scheduler: str | None = None,
    serial: bool = False,
    only: Sequence[str] = (),
    fresh: bool = False,
    console: Any = None,
    title: str = "cellplan: the three papers, reproduced",
    intro: str = "",
    extra: Sequence[Any] = (),
    progress: bool = True,
    time_budget_s: float | None = None,
) -> Path:
    """Discover, sweep and report the experiments of ``papers``; return ``outdir/index.html``.

    ``runs`` overrides every paper's default count (:data:`PAPER_RUNS`); ``only``
    restricts the sweep to the named experiments (all must exist); ``time_budget_s``
    is passed to :func:`~cellplan.experiments.run_sweep`.
    """
    from cellplan.experiments import discover, run_sweep
    from cellplan.report import make_pieces, reproduce_command, write_report

    found = discover(papers)
    known = {e.name: e for f in found for e in f.experiments}
    unknown = [name for name in only if name not in known]
    if unknown:
        listed = ", ".join(sorted(known)) or "none yet"
        raise ArgumentError(
            [Problem("--only", f"unknown experiment {n!r} (known: {listed})") for n in unknown]
        )
    if only:
        for f in found:
            f.experiments = [e for e in f.experiments if e.name in only]
    if console is not None:
        for f in found:
            if f.note:
                console.print(f"[yellow]note[/]: {f.paper}: {f.note}", highlight=False)
    experiments = [e for f in found for e in f.experiments]
    per_paper = {p: runs or PAPER_RUNS.get(p, 10) for p in {e.paper for e in experiments}}
    sweep = run_sweep(
        experiments,
        per_paper,
        quick,
        outdir,
        scheduler=scheduler,
        serial=serial,
        progress=progress,
        console=console,
        use_cache=not fresh,
        time_budget_s=time_budget_s,
    )

    def command_for(exp: Any) -> str:
        return reproduce_command(exp, per_paper[exp.paper], quick, outdir, scheduler)

    pieces = make_pieces(sweep, command_for)
    return write_report(outdir, found, pieces, sweep, title=title, intro=intro, extra=extra)


def register(app: typer.Typer) -> None:
    """Add ``cellplan reproduce`` to the app."""

    @app.command("reproduce")
    def reproduce_command_line(
        target: Annotated[
            str, typer.Argument(metavar="TARGET", help="strategies, adaptive, assembly or all")
        ] = "all",
        runs: Annotated[
            str | None,
            typer.Option(
                "--runs",
                metavar="N",
                help="repetitions (seeds) per parameter point; default: each paper's own "
                "(strategies 10, adaptive 100, assembly 25)",
            ),
        ] = None,
        output: Annotated[
            Path, typer.Option("-o", "--output", metavar="DIR", help="report folder")
        ] = Path("cellplan-reproduce"),
        scheduler: Annotated[
            str | None,
            typer.Option(
                metavar="ADDRESS", help="an existing Dask scheduler, e.g. tcp://HOST:8786"
            ),
        ] = None,
        serial: Annotated[
            bool, typer.Option("--serial", help="run in this process, without Dask")
        ] = False,
        quick: Annotated[
            bool, typer.Option("--quick", help="the small version of each experiment (the demo's)")
        ] = False,
        only: Annotated[
            str | None,
            typer.Option(metavar="NAMES", help="comma-separated experiment names to run"),
        ] = None,
        fresh: Annotated[
            bool, typer.Option("--fresh", help="ignore cached runs and recompute everything")
        ] = False,
    ) -> None:
        """Run the papers' experiments (cached, on Dask) and write OUTPUT/index.html."""
        from rich.console import Console

        from cellplan.experiments import check_scheduler_address

        problems: list[Problem] = []

        def attempt(check: Callable[[], T]) -> T | None:
            try:
                return check()
            except ArgumentError as exc:  # collect every bad option, then report them all
                problems.extend(exc.problems)
                return None

        papers = attempt(lambda: parse_target(target))
        n_runs = attempt(lambda: parse_runs(runs))
        attempt(lambda: check_output_dir(output))
        if scheduler is not None:
            attempt(lambda: check_scheduler_address(scheduler))
            if serial:
                problems.append(Problem("--serial", "--serial and --scheduler exclude each other"))
        if problems or papers is None:
            raise ArgumentError(problems)
        names = [n.strip() for n in (only or "").split(",") if n.strip()]
        console = Console(stderr=True)
        index = reproduce(
            papers,
            output,
            runs=n_runs,
            quick=quick,
            scheduler=scheduler,
            serial=serial,
            only=names,
            fresh=fresh,
            console=console,
        )
        typer.echo(f"report written: {index}")
