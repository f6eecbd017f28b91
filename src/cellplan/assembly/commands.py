"""CLI commands of the assembly package, registered on the main app by :func:`register`.

``cellplan assemble FILE --algorithm gradient|sequential|control --k K -o DIR`` and
``cellplan assemble --random N --seed S ...``: every argument is validated before any
work; the run writes a Fig. 1-2 style sequence, an animated GIF and ``metrics.json``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cellplan.assembly.problems import DEFAULT_FILL
from cellplan.errors import ArgumentError, Problem

ALGORITHMS = ("gradient", "sequential", "control")


def check_arguments(scenario: str | None, random_n: int | None, algorithm: str, k: float | None,
                    epsilon: float | None, rule: str, radius: float, frames: int,
                    escapes: int = 0, fill: float = DEFAULT_FILL) -> None:
    """Every mistake in the arguments, one :class:`Problem` each (raised together)."""
    from cellplan.assembly.sequential import RULES

    problems: list[Problem] = []
    if (scenario is None) == (random_n is None):
        problems.append(Problem("FILE", "give a scenario FILE or --random N, not both"))
    if random_n is not None and not 1 <= random_n <= 200:
        problems.append(Problem("--random", f"must be between 1 and 200, got {random_n}"))
    if algorithm not in ALGORITHMS:
        known = ", ".join(ALGORITHMS)
        problems.append(Problem("--algorithm", f"unknown {algorithm!r}; use {known}"))
    if k is not None and not k > 0:
        problems.append(Problem("--k", f"must be > 0, got {k:g}"))
    if epsilon is not None and not epsilon > 0:
        problems.append(Problem("--epsilon", f"must be > 0, got {epsilon:g}"))
    if rule not in RULES:
        problems.append(Problem("--rule", f"unknown {rule!r}; use {', '.join(RULES)}"))
    if not radius > 0:
        problems.append(Problem("--radius", f"must be > 0, got {radius:g}"))
    if not 0 < fill <= 0.5:
        problems.append(Problem("--fill", f"must be in (0, 0.5], got {fill:g}"))
    if frames < 2:
        problems.append(Problem("--frames", f"must be at least 2, got {frames}"))
    if not 0 <= escapes <= 20:
        problems.append(Problem("--escapes", f"must be between 0 and 20, got {escapes}"))
    if problems:
        raise ArgumentError(problems)


def register(app: typer.Typer) -> None:
    """Add this package's commands to the ``cellplan`` app."""

    @app.command()
    def assemble(
        scenario: Annotated[str | None, typer.Argument(help="scenario (discs: section)")] = None,
        algorithm: Annotated[str, typer.Option(help="gradient|sequential|control")] = "gradient",
        k: Annotated[float | None, typer.Option("--k", help="exponent k (default: file's)")] = None,
        epsilon: Annotated[float | None, typer.Option(help="normalisation epsilon")] = None,
        rule: Annotated[str, typer.Option(help="sequential rule: paper | place")] = "paper",
        random_n: Annotated[int | None, typer.Option("--random", help="generate N discs")] = None,
        seed: Annotated[int, typer.Option(help="seed of --random")] = 0,
        permutation: Annotated[bool, typer.Option(help="--random: starts permute goals")] = False,
        log10_beta: Annotated[float | None, typer.Option(help="--random: goal difficulty")] = None,
        radius: Annotated[float, typer.Option(help="--random: disc radius")] = 1.0,
        fill: Annotated[float, typer.Option(
            help="--random: fraction of the workspace area the discs cover")] = DEFAULT_FILL,
        frames: Annotated[int, typer.Option(help="GIF frames")] = 40,
        escapes: Annotated[int, typer.Option(
            help="gradient and paper rule: times k may be halved when stuck (0: k alone)")] = 6,
        output: Annotated[Path, typer.Option("-o", "--output", help="output folder")] = Path(
            "assembly-out"),
    ) -> None:
        """Plan a disc assembly (Whitcomb & Koditschek 1991): frames, GIF and metrics JSON."""
        from cellplan.assembly.run import run_assembly

        check_arguments(scenario, random_n, algorithm, k, epsilon, rule, radius, frames, escapes,
                        fill)
        metrics = run_assembly(scenario, random_n, algorithm, k, epsilon, rule, seed,
                               permutation, log10_beta, radius, frames, output, escapes, fill)
        lowered = int(metrics.get("escapes", 0))
        note = (f" (stuck at k={metrics['k']:g}; k lowered {lowered}x to "
                f"{metrics['k_final']:g})" if lowered else "")
        typer.echo(f"{metrics['status']}{note}: ratio {metrics['ratio']:.3f}, min clearance "
                   f"{metrics['min_clearance']:.3g}; wrote {output}")
