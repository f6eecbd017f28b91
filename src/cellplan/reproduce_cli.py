"""``cellplan reproduce``: run the papers' experiments and write the HTML report.

Registered on the main app by :func:`register`. Every argument is checked
before any work; a bad one is one line naming the option and exit status 2
(through :class:`~cellplan.errors.ArgumentError` and ``cli.main``).
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer

from cellplan.cliutil import JsonOpt, print_json
from cellplan.errors import ArgumentError, Interrupted, Problem
from cellplan.experiments import SweepResult

T = TypeVar("T")


def targets() -> tuple[str, ...]:
    """The registered packages, in report order, and ``all``."""
    from cellplan.registry import packages

    return (*packages(), "all")


def paper_runs() -> dict[str, int]:
    """Default repetitions per parameter point: each package's own
    (:attr:`cellplan.core.Package.paper_runs`, the paper's count)."""
    from cellplan.registry import packages

    return {p.name: p.paper_runs for p in packages().values()}


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
    known = targets()
    if text not in known:
        raise ArgumentError(f"unknown target {text!r} (choose from {', '.join(known)})", "TARGET")
    return list(known[:-1]) if text == "all" else [text]


def check_output_dir(path: Path) -> Path:
    """``-o``: a folder, existing or not, but not a file, where one can be written."""
    from cellplan.cliutil import check_output

    return check_output(path, "--output", folder=True)


def reproduce_sweep(
    papers: Sequence[str] | None,
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
    extra: Sequence[Any] | Callable[[], Sequence[Any]] = (),
    progress: bool = True,
    time_budget_s: float | None = None,
    demo: bool = False,
) -> tuple[Path, SweepResult]:
    """Discover, sweep and report the experiments of ``papers``.

    ``runs`` overrides every paper's default count (:func:`paper_runs`); ``only``
    restricts the sweep to the named experiments (all must exist); ``time_budget_s``
    is passed to :func:`~cellplan.experiments.run_sweep`.

    ``extra``: further report sections, or a function returning them, called once the
    sweep is done (the demo makes its pictures in a thread meanwhile).

    ``demo``: the demo's sweep. Only the experiments with a
    :attr:`~cellplan.core.Experiment.demo_runs` run, in their quick version with that
    many seeds (``runs`` and ``quick`` are ignored); the others, and any claim their
    runs leave undecided, are listed apart in the report with the full reproduction's
    command (:func:`demo_split`, :func:`cellplan.report.set_apart_undecided`).

    Returns
    -------
    tuple
        ``outdir/index.html``, and the sweep that filled it (its failures decide the
        command's exit status).
    """
    from cellplan.experiments import discover, run_sweep
    from cellplan.report import (
        ToDecide,
        make_pieces,
        reproduce_command,
        set_apart_undecided,
        write_report,
    )

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
    to_decide: list[ToDecide] = []
    if demo:
        quick = True
        for f in found:
            f.experiments, left = demo_split(f.experiments)
            to_decide += [
                ToDecide(
                    e.name,
                    e.paper,
                    e.title,
                    "its claims need more seeds or larger problems than the demo's time allows",
                    full_command(e),
                )
                for e in left
            ]
    experiments = [e for f in found for e in f.experiments]
    defaults = paper_runs()
    per_paper: dict[str, int] = {
        p: runs or defaults.get(p, 10) for p in {e.paper for e in experiments}
    }
    if demo:
        per_paper.update({e.name: e.demo_runs for e in experiments if e.demo_runs is not None})
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
        n = per_paper.get(exp.name, per_paper[exp.paper])
        return reproduce_command(exp, n, quick, outdir, scheduler)

    # Before any report draws: the demo's pictures may still be drawing in a thread.
    sections = extra() if callable(extra) else extra
    pieces = make_pieces(sweep, command_for)
    if demo:
        to_decide += set_apart_undecided(pieces, full_command)
    index = write_report(
        outdir, found, pieces, sweep, title=title, intro=intro, extra=sections, to_decide=to_decide
    )
    return index, sweep


FULL_OUTPUT = Path("cellplan-reproduce")
"""The report folder of the full reproduction (``reproduce -o``'s default), which the
demo's "run ``cellplan reproduce`` to decide" commands name."""


def demo_split(experiments: Sequence[Any]) -> tuple[list[Any], list[Any]]:
    """The experiments the demo runs (those with ``demo_runs``) and those it lists apart."""
    return (
        [e for e in experiments if e.demo_runs is not None],
        [e for e in experiments if e.demo_runs is None],
    )


def full_command(exp: Any) -> str:
    """The full reproduction of one experiment (its paper's runs, not quick)."""
    from cellplan.report import reproduce_command

    return reproduce_command(exp, None, False, FULL_OUTPUT)


def failure_line(sweep: SweepResult, index: Path, output: Path) -> str:
    """The one line of a sweep whose runs did not all finish (exit status 1).

    Says how many runs failed and why the sweep gave up on some (a lost scheduler, no
    worker left), where the report is, and that the same command resumes: finished runs
    are cached, failed ones are not.
    """
    why = f" ({sweep.lost})" if sweep.lost else ""
    broken = f"; {sweep.n_broken} experiments could not list their runs" if sweep.n_broken else ""
    return (
        f"error: {sweep.n_failed} of {sweep.n_runs} runs failed{why}{broken}; "
        f"report written: {index}; {cached_runs(output)} runs cached in {output / 'cache'}: "
        "run the same command to retry the rest"
    )


def register(app: typer.Typer) -> None:
    """Add ``cellplan reproduce`` to the app."""

    @app.command("reproduce")
    def reproduce_command_line(
        target: Annotated[
            str,
            typer.Argument(
                metavar="TARGET", help="a registered package (see cellplan planners) or all"
            ),
        ] = "all",
        runs: Annotated[
            str | None,
            typer.Option(
                "--runs",
                metavar="N",
                help="repetitions (seeds) per parameter point; default: each paper's own count",
            ),
        ] = None,
        output: Annotated[
            Path, typer.Option("-o", "--output", metavar="DIR", help="report folder")
        ] = FULL_OUTPUT,
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
        as_json: JsonOpt = False,
    ) -> None:
        """Run the papers' experiments (cached, on Dask) and write OUTPUT/index.html."""
        from rich.console import Console

        from cellplan.scheduler import check_scheduler_address

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
        names = [n.strip() for n in (only or "").split(",") if n.strip()]
        if only is not None and not names:
            problems.append(Problem("--only", "no experiment names given"))
        if problems or papers is None:
            raise ArgumentError(problems)
        console = Console(stderr=True)
        created = not output.exists()
        try:
            index, sweep = reproduce_sweep(
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
        except OSError:
            # A full disk or an unwritable place before any run was kept: leave no folder
            # behind that was not there (a cache with runs in it stays, to resume from).
            if created and cached_runs(output) == 0:
                shutil.rmtree(output, ignore_errors=True)
            raise
        except KeyboardInterrupt:
            cached = cached_runs(output)
            raise Interrupted(
                f"interrupted; {cached} runs cached in {output / 'cache'}; "
                "run the same command to resume"
            ) from None
        failed = bool(sweep.n_failed or sweep.n_broken)
        if as_json:
            print_json(sweep_payload(sweep, index, output))
        elif not failed:
            typer.echo(f"report written: {index}")
        if failed:
            console.print(
                failure_line(sweep, index, output),
                highlight=False,
                markup=False,
                soft_wrap=True,
            )
            raise typer.Exit(1)


def sweep_payload(sweep: SweepResult, index: Path, output: Path) -> dict[str, Any]:
    """``reproduce --json``: one object with the report's path and the sweep's counts
    (integers), ``status`` "written" or "failed" (some runs failed; exit status 1)."""
    failed = bool(sweep.n_failed or sweep.n_broken)
    return {
        "status": "failed" if failed else "written",
        "message": failure_line(sweep, index, output) if failed else f"report written: {index}",
        "outputs": {"report": str(index)},
        "runs": int(sweep.n_runs),
        "failed_runs": int(sweep.n_failed),
        "broken_experiments": int(sweep.n_broken),
        "cached_runs": cached_runs(output),
    }


def cached_runs(output: Path) -> int:
    """How many finished runs the cache under ``output`` holds (what a rerun will reuse)."""
    folder = output / "cache"
    return sum(1 for _ in folder.rglob("*.json")) if folder.is_dir() else 0
