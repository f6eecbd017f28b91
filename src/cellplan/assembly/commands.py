"""CLI commands of the assembly package, registered on the main app by :func:`register`.

``cellplan assemble FILE --algorithm gradient|sequential|control`` plans the scenario's
``discs:`` section; ``cellplan assemble --random N --seed S ...`` first builds a scenario
with a ``discs: generate:`` section (:func:`~cellplan.assembly.problems.random_setup`)
and plans it the same way. Both go through :func:`cellplan.api.plan`; every option
defaults to ``None`` and is passed on only when given, so the defaults are those of
the planners' option models and the scenario section. The run writes a Fig. 1-2 style
sequence, an animated GIF, ``trajectory.csv`` and ``metrics.json``; the exit status is
0 when the discs are assembled, 1 when the run stopped short (stuck, budget spent), 2
for bad input.

``--algorithm robot`` runs planner ``assembly.robot`` (the sequential assembly executed
by the scenario's URDF arm, as in ``ur5_assembly``; a scenario FILE, not ``--random``)
and writes ``trajectory.csv`` (the arm's path), ``viewer.html`` (the 3-D viewer, the
held part on the tool) and ``metrics.json``; an option of another algorithm is refused
in one line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from pydantic import BaseModel

from cellplan.assembly.layout import DEFAULT_FILL
from cellplan.assembly.options import STEP_MAX_RULE, GradientOptions, SequentialOptions
from cellplan.assembly.robot_options import RobotAssemblyOptions
from cellplan.assembly.run import DEFAULT_FRAMES, MAX_FRAMES
from cellplan.assembly.section import GeneratorSpec
from cellplan.cliutil import (
    GifSizeOpt,
    JsonOpt,
    as_flags,
    check_inputs_kept,
    check_output,
    folder_files,
    scenario_file,
)
from cellplan.core import Result
from cellplan.errors import ArgumentError, Problem
from cellplan.fileio import staged_folder, write_json
from cellplan.setup import Setup
from cellplan.workcell3d import Workcell3D

ALGORITHMS = ("gradient", "sequential", "control", "robot")

#: Every file ``assemble`` writes into its output folder.
OUTPUT_FILES = (
    "sequence.png",
    "assembly.gif",
    "trajectory.csv",
    "metrics.json",
    "viewer.html",
)


def _default(model: type[BaseModel], field: str) -> Any:
    """The default of a model field, for help texts (the model is its one source)."""
    return model.model_fields[field].default


# Help texts quote the defaults from their one source (module level: typer resolves the
# annotations in this module's namespace).
_ESCAPES_HELP = (
    "halve-k escape and paper rule: times k may be halved when stuck (0: no escape, k "
    "alone; default "
    f"{_default(SequentialOptions, 'escapes')})"
)
_ESCAPE_HELP = (
    "gradient: when stuck, place (the place rule finishes) or halve-k (default "
    f"{_default(GradientOptions, 'escape')})"
)
_INTEGRATOR_HELP = (
    f"gradient: auto | implicit | rk4 (default {_default(GradientOptions, 'integrator')})"
)
_STEP_MAX_HELP = f"gradient, implicit step: largest step in R^2n (default {STEP_MAX_RULE})"
_RULE_HELP = f"sequential rule: paper | place (default: {_default(SequentialOptions, 'rule')})"
_FINISH_HELP = (
    "sequential: place (the place rule finishes a run that stopped short) or none "
    f"(default {_default(SequentialOptions, 'finish')})"
)
_HOVER_HELP = (
    "robot: tool height above a disc's centre, m (default "
    f"{_default(RobotAssemblyOptions, 'hover')})"
)
_LIFT_HELP = (
    f"robot: how far the tool rises over a pick and a place, m (default "
    f"{_default(RobotAssemblyOptions, 'lift')})"
)
_REPAIR_HELP = (
    f"robot: repair strategy of the experience graph, A0-A3 (default "
    f"{_default(RobotAssemblyOptions, 'repair')})"
)
_SEED_HELP = f"--random: seed (default {_default(GeneratorSpec, 'seed')})"
_RADIUS_HELP = f"--random: disc radius (default {_default(GeneratorSpec, 'radius'):g})"
_FILL_HELP = f"--random: fraction of the workspace the discs cover (default {DEFAULT_FILL:g})"
_PICTURES_HELP = (
    "also draw sequence.png and assembly.gif (several times the planner's time on "
    "15-50 discs, so off unless asked; --frames or --gif-size ask too)"
)

#: ``random_setup`` parameter -> the command-line option that sets it
_RANDOM_FLAGS = {
    "n": "--random",
    "seed": "--seed",
    "radius": "--radius",
    "fill": "--fill",
    "log10_beta": "--log10-beta",
    "dim": "--dim",
    "pattern": "--pattern",
}


def register(app: typer.Typer) -> None:
    """Add this package's commands to the ``cellplan`` app."""

    @app.command()
    def assemble(
        scenario: Annotated[
            str | None,
            typer.Argument(
                help="scenario file with a discs: section, or a bundled scenario's name"
            ),
        ] = None,
        algorithm: Annotated[
            str, typer.Option(help="gradient|sequential|control|robot")
        ] = "gradient",
        k: Annotated[
            float | None, typer.Option("--k", help="exponent k (default: the scenario's discs.k)")
        ] = None,
        epsilon: Annotated[
            float | None, typer.Option(help="normalisation epsilon (default: discs.epsilon)")
        ] = None,
        tolerance: Annotated[
            float | None, typer.Option(help="goal tolerance in R^2n (default: discs.tolerance)")
        ] = None,
        rule: Annotated[str | None, typer.Option(help=_RULE_HELP)] = None,
        escapes: Annotated[int | None, typer.Option(help=_ESCAPES_HELP)] = None,
        escape: Annotated[str | None, typer.Option(help=_ESCAPE_HELP)] = None,
        integrator: Annotated[str | None, typer.Option(help=_INTEGRATOR_HELP)] = None,
        step_max: Annotated[float | None, typer.Option(help=_STEP_MAX_HELP)] = None,
        random_n: Annotated[int | None, typer.Option("--random", help="generate N discs")] = None,
        seed: Annotated[int | None, typer.Option(help=_SEED_HELP)] = None,
        permutation: Annotated[
            bool, typer.Option(help="--random: starts permute the goals")
        ] = False,
        log10_beta: Annotated[
            float | None, typer.Option(help="--random: goal difficulty log10 beta(d)")
        ] = None,
        radius: Annotated[float | None, typer.Option(help=_RADIUS_HELP)] = None,
        fill: Annotated[float | None, typer.Option(help=_FILL_HELP)] = None,
        dim: Annotated[
            int | None, typer.Option(help="--random: 2 (discs, default) or 3 (spheres in a ball)")
        ] = None,
        pattern: Annotated[
            str | None,
            typer.Option(help="--random: goals hex (default; close-packed in 3-D) or stack (3-D)"),
        ] = None,
        finish_rule: Annotated[str | None, typer.Option("--finish", help=_FINISH_HELP)] = None,
        hover: Annotated[float | None, typer.Option(help=_HOVER_HELP)] = None,
        lift: Annotated[float | None, typer.Option(help=_LIFT_HELP)] = None,
        repair: Annotated[str | None, typer.Option(help=_REPAIR_HELP)] = None,
        pictures: Annotated[bool, typer.Option("--pictures", help=_PICTURES_HELP)] = False,
        frames: Annotated[
            int | None,
            typer.Option(
                help=f"GIF frames, 2 to {MAX_FRAMES} (default {DEFAULT_FRAMES}); implies --pictures"
            ),
        ] = None,
        gif_size: GifSizeOpt = None,
        output: Annotated[Path, typer.Option("-o", "--output", help="output folder")] = Path(
            "assembly-out"
        ),
        as_json: JsonOpt = False,
    ) -> None:
        """Plan a disc assembly (Whitcomb & Koditschek 1991): trajectory, metrics, and with
        --pictures the sequence and GIF."""
        from cellplan import api
        from cellplan.assembly.problems import random_setup
        from cellplan.assembly.run import write_outputs
        from cellplan.cliutil import finish, progress_bar, progress_enabled
        from cellplan.plots import GIF_SIZE, check_gif_size
        from cellplan.registry import parse_options, planner

        problems: list[Problem] = []
        if (scenario is None) == (random_n is None):
            problems.append(Problem("FILE", "give a scenario FILE or --random N, not both"))
        if scenario is not None:
            given = {
                "--seed": seed,
                "--radius": radius,
                "--fill": fill,
                "--log10-beta": log10_beta,
                "--permutation": permutation or None,
                "--dim": dim,
                "--pattern": pattern,
            }
            problems.extend(
                Problem(flag, "only with --random N")
                for flag, value in given.items()
                if value is not None
            )
        if algorithm not in ALGORITHMS:
            problems.append(
                Problem("--algorithm", f"unknown {algorithm!r}; use {', '.join(ALGORITHMS)}")
            )
        if algorithm == "robot" and random_n is not None:
            problems.append(
                Problem("--random", "--algorithm robot needs a scenario FILE with a URDF arm")
            )
        # Drawing costs several times the planner (docs/benchmarks.md, "Drawing in
        # assemble"), so it is asked for: --pictures, or a GIF option.
        draw = pictures or frames is not None or gif_size is not None
        if frames is not None and not 2 <= frames <= MAX_FRAMES:
            problems.append(Problem("--frames", f"must be in [2, {MAX_FRAMES}], got {frames}"))
        frames = DEFAULT_FRAMES if frames is None else frames
        width = GIF_SIZE
        try:
            width = check_gif_size(GIF_SIZE if gif_size is None else gif_size)
        except ArgumentError as exc:
            problems.extend(exc.problems)
        try:
            check_output(output, "--output", folder=True)
            check_inputs_kept(
                folder_files("--output", output, OUTPUT_FILES), {"FILE": scenario_file(scenario)}
            )
        except ArgumentError as exc:
            problems.extend(exc.problems)
        options: dict[str, Any] = {
            key: value
            for key, value in (
                ("k", k),
                ("epsilon", epsilon),
                ("tolerance", tolerance),
                ("rule", rule),
                ("escapes", escapes),
                ("escape", escape),
                ("integrator", integrator),
                ("step_max", step_max),
                ("finish", finish_rule),
                ("hover", hover),
                ("lift", lift),
                ("repair", repair),
            )
            if value is not None
        }
        name = f"assembly.{algorithm}"
        if algorithm in ALGORITHMS:
            try:
                parse_options(planner(name), options, flag=True)
            except ArgumentError as exc:
                problems.extend(exc.problems)
        setup = None
        if random_n is not None:
            try:
                setup = random_setup(
                    random_n,
                    seed,
                    radius,
                    fill,
                    permutation,
                    log10_beta,
                    2 if dim is None else dim,
                    pattern,
                )
            except ArgumentError as exc:
                problems.extend(
                    Problem(_RANDOM_FLAGS.get(p.field, p.field), p.message) for p in exc.problems
                )
        if problems:
            raise ArgumentError(problems)
        if setup is None:
            assert scenario is not None
            setup = api.load(scenario)
        with progress_bar(progress_enabled(as_json), name) as progress:
            result = api.plan(setup, name, progress=progress, **options)
            if progress is not None:
                drawing = f"; drawing {frames} frames" if draw else ""
                progress(1.0, 1.0, f"{result.status.value}{drawing}")
            # Written into a staging folder, moved in whole: an error leaves --output as it was.
            keep = {"FILE": file} if (file := scenario_file(scenario)) else None
            # The pictures check the GIF's memory again, now that the plan holds its own.
            with as_flags({"size": "--gif-size"}), staged_folder(output, keep=keep) as stage:
                staged = (
                    _write_robot(result, setup, stage)
                    if algorithm == "robot"
                    else write_outputs(result, stage, frames, width, pictures=draw)
                )
        files = {key: output / path.relative_to(stage) for key, path in staged.items()}
        summary = f"{result.message}; wrote {output}" if result.success else f"wrote {output}"
        finish(result, as_json, summary, outputs=files, extra={"scenario": setup.name})


def _write_robot(result: Result, setup: Setup, output: Path) -> dict[str, Path]:
    """``assembly.robot``'s files: the arm's trajectory, the 3-D viewer page (the held part
    drawn on the tool) and the metrics; a run that stopped before any arm motion writes
    the metrics alone."""
    from cellplan.assembly.robot import held_parts
    from cellplan.scene3d import cell_scene
    from cellplan.view3d import write_viewer

    files: dict[str, Path] = {}
    traj = result.trajectory
    cell = setup.workcell
    if traj is not None and isinstance(cell, Workcell3D):
        files["trajectory"] = traj.save(output / "trajectory.csv")
        scene = cell_scene(cell, traj.q, traj.t, carrying=held_parts(traj))
        write_viewer(scene, output / "viewer.html")
        files["viewer"] = output / "viewer.html"
    metrics = {
        "status": result.status.value,
        "message": result.message,
        "algorithm": "robot",
        **result.options,
        **result.stats,
    }
    files["metrics"] = write_json(output / "metrics.json", metrics)
    return files
