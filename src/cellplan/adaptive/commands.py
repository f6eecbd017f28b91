"""CLI commands of the adaptive package, registered on the main app by :func:`register`.

``cellplan adapt FILE --repair A3 --tasks 80 --seed 0 --db exp.sqlite -o DIR`` runs the
``adaptive`` planner through :func:`cellplan.api.plan` (a progress bar on stderr when
it is a terminal) and writes, into DIR:

* ``paths.csv``: the executed paths of every task run in this call as one trajectory
  (:class:`~cellplan.trajectory.Trajectory`; mode = the task's goal, events ``task``,
  ``arrive``, ``fail``, ``change``; radians for joint angles) and ``paths.png`` (each
  coordinate against the path length, modes shaded, events marked);
* ``tasks.csv``: per-task costs with the R/T/S/Abstract split and the Solve-only baseline
  (every task of the database when continuing);
* ``ratio.png`` (the cumulative cost ratio, Figure 5), ``costs.png``, ``graph.png`` and
  ``snapshots.png`` (G over the workcell, Figure 3 style; planar cells only),
  ``graph.graphml`` and ``summary.json``.

It prints one summary line on stdout (or one JSON object with ``--json``) and exits 0
when every task reached its goal, 1 when some failed (the line names them), 2 on bad
input. Options are ``None`` unless given, so the defaults are the scenario section's.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from cellplan.cliutil import (
    JsonOpt,
    ScenarioArg,
    as_flags,
    check_inputs_kept,
    check_output,
    finish,
    folder_files,
    progress_bar,
    progress_enabled,
    scenario_file,
)
from cellplan.fileio import staged_folder

#: Every file ``adapt`` may write into its output folder (module docstring).
OUTPUT_FILES = (
    "paths.csv",
    "paths.png",
    "tasks.csv",
    "graph.graphml",
    "ratio.png",
    "costs.png",
    "graph.png",
    "snapshots.png",
    "summary.json",
)

if TYPE_CHECKING:
    from cellplan.core import Result


def register(app: typer.Typer) -> None:
    """Add this package's commands to the ``cellplan`` app."""

    @app.command()
    def adapt(
        scenario: ScenarioArg,
        repair: Annotated[
            str | None,
            typer.Option(help="repair strategy A0, A1, A2 or A3 (default: the scenario's)"),
        ] = None,
        tasks: Annotated[
            int | None, typer.Option(help="number of tasks (default: the scenario's)")
        ] = None,
        seed: Annotated[
            int | None,
            typer.Option(help="seed of the task sequence and of Solve (default: the scenario's)"),
        ] = None,
        db: Annotated[
            Path | None, typer.Option(help="experience database (SQLite); continued if it exists")
        ] = None,
        output: Annotated[Path, typer.Option("-o", "--output", help="output folder")] = Path(
            "adapt-out"
        ),
        baseline: Annotated[
            bool | None,
            typer.Option(
                "--baseline/--no-baseline",
                help="also run Solve alone on every task, for the ratio (default: yes)",
                show_default=False,
            ),
        ] = None,
        as_json: JsonOpt = False,
    ) -> None:
        """Adaptive experience-graph planning (Chen 1994) over a task sequence."""
        run_adapt_command(scenario, repair, tasks, seed, db, output, baseline, as_json)


def run_adapt_command(
    scenario_arg: str,
    repair: str | None,
    tasks: int | None,
    seed: int | None,
    db: Path | None,
    output: Path,
    baseline: bool | None,
    as_json: bool = False,
) -> None:
    """The body of ``cellplan adapt`` (importable for tests); exits through ``finish``."""
    from cellplan.api import load, plan
    from cellplan.registry import parse_options, planner

    given: dict[str, Any] = {
        k: v
        for k, v in {
            "repair": repair,
            "tasks": tasks,
            "seed": seed,
            "db": None if db is None else str(db),
            "baseline": baseline,
        }.items()
        if v is not None
    }
    with as_flags():
        parse_options(planner("adaptive"), given)
    check_output(output, "--output", folder=True)
    if db is not None:
        # The database is reached through links (one lock per file, whatever its name),
        # so what must be a regular file or absent is the file it resolves to.
        check_output(Path(os.path.realpath(db)), "--db")
    check_inputs_kept(
        folder_files("--output", output, OUTPUT_FILES),
        {"SCENARIO": scenario_file(scenario_arg), "--db": db},
    )
    setup = load(scenario_arg)
    with progress_bar(progress_enabled(as_json), "adapt", counts=True) as progress, as_flags():
        result = plan(setup, "adaptive", progress=progress, **given)
    with staged_folder(output, keep={"--db": db} if db is not None else None) as stage:
        staged = write_outputs(result, stage)
    outputs = {name: output / path.relative_to(stage) for name, path in staged.items()}
    summary = (
        f"{result.message}; wrote {output}"
        if result.success
        else f"{int(result.stats['solved'])} of {int(result.stats['tasks'])} solved; wrote {output}"
    )
    finish(result, as_json, summary, outputs)


def write_outputs(result: Result, output: Path) -> dict[str, Path]:
    """Write the run's files into ``output`` (see the module docstring); their paths by name."""
    import csv
    import gc
    import io

    from cellplan.adaptive import plots
    from cellplan.adaptive.runner import cumulative_ratio
    from cellplan.adaptive.store import export_graphml
    from cellplan.fileio import write_json, write_text

    ep = result.solution
    rows = ep.tasks
    output.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {}
    assert result.trajectory is not None
    files["paths"] = result.trajectory.save(output / "paths.csv")
    result.trajectory.plot(output / "paths.png")
    files["paths_plot"] = output / "paths.png"
    buf = io.StringIO()
    if rows:
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    files["tasks"] = write_text(output / "tasks.csv", buf.getvalue())
    files["graph"] = export_graphml(ep.graph, output / "graph.graphml")
    section = ep.scenario.adaptive if ep.scenario is not None else None
    change_tasks = sorted({c.after_task for c in section.changes}) if section else []
    if rows and result.options.get("baseline", True):
        files["ratio_plot"] = plots.save_ratio_curves(
            {ep.settings.repair: cumulative_ratio(rows)}, output / "ratio.png", change_tasks
        )
    if rows:
        files["costs_plot"] = plots.save_cost_split(rows, output / "costs.png")
    # G drawn over the workcell (Figure 3 style) is a planar picture.
    if ep.snapshots:
        files["graph_plot"] = plots.save_snapshots(ep.snapshots[-1:], output / "graph.png", ncols=1)
        files["snapshots_plot"] = plots.save_snapshots(ep.snapshots[:12], output / "snapshots.png")
    summary: dict[str, object] = {
        "scenario": ep.name,
        "status": str(result.status),
        "message": result.message,
        "repair": ep.settings.repair,
        "seed": ep.settings.seed,
        "tasks": len(rows),
        "successes": sum(int(r["success"]) for r in rows),
        "paths_ok_at_4x": sum(int(r["path_ok"]) for r in rows),
        "vertices": len(ep.graph),
        "edges": len(ep.graph.usable_edges()),
        "adapt_checks": sum(float(r["adapt"]) for r in rows),
        "solve_only_checks": sum(float(r["baseline"]) for r in rows),
    }
    if "ratio" in result.stats:
        summary["final_ratio"] = float(result.stats["ratio"])
    files["summary"] = write_json(output / "summary.json", summary)
    gc.collect()
    return files
