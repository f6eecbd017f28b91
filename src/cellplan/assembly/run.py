"""The files of one assembly run: pictures, the trajectory and the metrics of a :class:`Result`.

What ``cellplan assemble`` writes (and what a script can write after
``cellplan.plan(setup, "assembly.gradient")``): ``sequence.png`` (four moments, Figs. 1-2
style), ``assembly.gif``, ``trajectory.csv`` (the :class:`~cellplan.trajectory.Trajectory`)
and ``metrics.json`` (status, message, the parameters the run used, its statistics, and
for the sequential algorithm the pick / move / release actions).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cellplan.core import Result
from cellplan.errors import ArgumentError
from cellplan.fileio import write_json

#: Most frames of the GIF: each is a drawn figure (about 50 ms and 0.7 MB of pixels at
#: 480 px), so 500 frames take under a minute; more would not make a smoother picture.
MAX_FRAMES = 500


def run_title(result: Result) -> str:
    """``gradient k=96``, ``sequential k=96 (paper)``: a picture title for the run."""
    assert result.trajectory is not None
    meta = result.trajectory.meta
    algorithm = result.planner.removeprefix("assembly.") or "assembly"
    rule = f" ({meta['rule']})" if "rule" in meta else ""
    return f"{algorithm} k={float(meta['k']):g}{rule}"


def write_outputs(
    result: Result, output: Path, frames: int = 40, gif_size: int | None = None
) -> dict[str, Path]:
    """Write the run's files under ``output``; returns them by name.

    ``result`` is a result of one of the assembly planners (its ``solution`` carries the
    problem and the path); ``gif_size`` is the GIF's width in pixels (default
    :data:`cellplan.plots.GIF_SIZE`).
    """
    from cellplan.assembly import plots

    if not 2 <= frames <= MAX_FRAMES:
        raise ArgumentError(f"must be in [2, {MAX_FRAMES}], got {frames}", "frames")
    run = result.solution
    problem = run.problem
    traj = result.trajectory
    assert traj is not None and problem is not None
    output.mkdir(parents=True, exist_ok=True)
    title = run_title(result)
    files = {
        "sequence": plots.save_sequence(problem, run.path, output / "sequence.png", title),
        "animation": plots.save_animation(
            problem,
            run.path,
            output / "assembly.gif",
            frames,
            title,
            size=gif_size,
            times=traj.t if len(traj.t) == len(run.path) else None,
            time_unit=traj.time_unit,
        ),
        "trajectory": traj.save(output / "trajectory.csv"),
    }
    metrics: dict[str, Any] = {
        "status": result.status.value,
        "message": result.message,
        "algorithm": result.planner.removeprefix("assembly."),
        **{key: traj.meta[key] for key in ("k", "epsilon", "tolerance", "n") if key in traj.meta},
        **result.stats,
    }
    if "rule" in traj.meta:
        metrics["rule"] = traj.meta["rule"]
        metrics["actions"] = run.actions()
    metrics["start"] = problem.start
    metrics["goal"] = problem.goal
    metrics["final"] = np.asarray(run.path[-1])
    files["metrics"] = write_json(output / "metrics.json", metrics)
    return files
