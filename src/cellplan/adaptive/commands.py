"""CLI commands of the adaptive package, registered on the main app by :func:`register`.

``cellplan adapt FILE --repair A3 --tasks 80 --seed 0 --db exp.sqlite -o DIR`` runs
Adapt over the scenario's tasks with a progress bar and writes, into DIR:
``tasks.csv`` (per-task costs with the R/T/S/Abstract split and the Solve-only
baseline), ``ratio.png`` (the cumulative cost ratio), ``costs.png``,
``graph.png`` and ``snapshots.png`` (G over the workcell), ``graph.graphml`` and
``summary.json``.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Annotated

import typer

from cellplan.errors import ArgumentError


def register(app: typer.Typer) -> None:
    """Add this package's commands to the ``cellplan`` app."""

    @app.command()
    def adapt(
        scenario: Annotated[
            str, typer.Argument(help="scenario file with an adaptive section, or a bundled name")
        ],
        repair: Annotated[
            str | None,
            typer.Option(help="repair strategy A0, A1, A2 or A3 (default: the scenario's)"),
        ] = None,
        tasks: Annotated[
            int | None, typer.Option(help="number of tasks (default: the scenario's)")
        ] = None,
        seed: Annotated[
            int | None, typer.Option(help="seed of the task sequence and of Solve")
        ] = None,
        db: Annotated[
            Path | None, typer.Option(help="experience database (SQLite); continued if it exists")
        ] = None,
        output: Annotated[Path, typer.Option("-o", "--output", help="output folder")] = Path(
            "adapt-out"
        ),
        baseline: Annotated[
            bool, typer.Option(help="also run Solve alone on every task (for the ratio)")
        ] = True,
    ) -> None:
        """Adaptive experience-graph planning (Chen 1994) over a task sequence."""
        run_adapt_command(scenario, repair, tasks, seed, db, output, baseline)


def run_adapt_command(
    scenario_arg: str,
    repair: str | None,
    tasks: int | None,
    seed: int | None,
    db: Path | None,
    output: Path,
    baseline: bool,
) -> None:
    """The body of ``cellplan adapt`` (importable for tests)."""
    import gc

    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from cellplan.adaptive import plots
    from cellplan.adaptive.repair import STRATEGIES
    from cellplan.adaptive.runner import cumulative_ratio, run_adaptive, task_count
    from cellplan.adaptive.store import ExperienceStore, export_graphml
    from cellplan.fileio import write_json, write_text
    from cellplan.scenario import load_scenario

    if repair is not None and repair not in STRATEGIES:
        raise ArgumentError(
            f"unknown repair strategy {repair!r}; choose one of {', '.join(STRATEGIES)}", "--repair"
        )
    if output.exists() and not output.is_dir():
        raise ArgumentError(f"{output} exists and is not a folder", "--output")
    sc = load_scenario(scenario_arg)
    n_tasks = task_count(sc, tasks)
    console = Console(stderr=True)
    store = ExperienceStore(db, sc) if db is not None else None
    try:
        with Progress(
            TextColumn("[bold]adapt[/]"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.description}"),
            TimeElapsedColumn(),
            console=console,
            transient=False,
        ) as progress:
            bar = progress.add_task("", total=n_tasks)

            def on_task(done: int, total: int, row: dict[str, object]) -> None:
                progress.update(
                    bar, completed=done, description=f"{row['goal']} |V|={row['vertices']}"
                )

            change_tasks = (
                sorted({c.after_task for c in sc.adaptive.changes}) if sc.adaptive else []
            )
            marks = {0, n_tasks, *change_tasks, *(t + 1 for t in change_tasks)}
            outcome = run_adaptive(
                sc,
                repair,
                tasks,
                seed,
                store,
                baseline,
                on_task=on_task,
                snapshot_at=lambda t: t in marks or t <= 4,
            )
        adapter = outcome.adapter
        assert adapter is not None
        rows = outcome.rows
        output.mkdir(parents=True, exist_ok=True)
        buf = io.StringIO()
        if rows:
            writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        write_text(output / "tasks.csv", buf.getvalue())
        export_graphml(adapter.graph, output / "graph.graphml")
        summary: dict[str, object] = {
            "scenario": sc.name,
            "repair": adapter.settings.repair,
            "seed": adapter.settings.seed,
            "tasks": len(rows),
            "successes": sum(int(r["success"]) for r in rows),
            "paths_ok_at_4x": sum(int(r["path_ok"]) for r in rows),
            "vertices": len(adapter.graph),
            "edges": len(adapter.graph.usable_edges()),
            "adapt_checks": sum(float(r["adapt"]) for r in rows),
            "solve_only_checks": sum(float(r["baseline"]) for r in rows),
        }
        if rows and baseline:
            ratio = cumulative_ratio(rows)
            summary["final_ratio"] = float(ratio[-1])
            plots.save_ratio_curves(
                {adapter.settings.repair: ratio}, output / "ratio.png", change_tasks
            )
        if rows:
            plots.save_cost_split(rows, output / "costs.png")
        if outcome.snapshots:
            plots.save_snapshots(outcome.snapshots[-1:], output / "graph.png", ncols=1)
            plots.save_snapshots(outcome.snapshots[:12], output / "snapshots.png")
        write_json(output / "summary.json", summary)
    finally:
        if store is not None:
            store.close()
        gc.collect()
    console.print(
        f"{summary['tasks']} tasks, {summary['successes']} solved, "
        f"G: {summary['vertices']} vertices; "
        + (f"cumulative ratio {summary['final_ratio']:.3f}; " if "final_ratio" in summary else "")
        + f"wrote {output}"
    )
