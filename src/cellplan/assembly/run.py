"""The files of one assembly run: pictures, the trajectory and the metrics of a :class:`Result`.

What ``cellplan assemble`` writes (and what a script can write after
``cellplan.plan(setup, "assembly.gradient")``): ``sequence.png`` (four moments, Figs. 1-2
style), ``assembly.gif``, ``trajectory.csv`` (the :class:`~cellplan.trajectory.Trajectory`)
and ``metrics.json`` (status, message, the parameters the run used, its statistics, and
for the sequential algorithm the pick / move / release actions). The command draws the two
pictures only when asked (``--pictures``, ``--frames``, ``--gif-size``): they cost several
times the planner (docs/benchmarks.md "Drawing in assemble").
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cellplan.core import Result
from cellplan.errors import ArgumentError
from cellplan.fileio import write_json

#: Most frames of the GIF: each is one drawing of a reused figure (about 30-60 ms and 0.7
#: MB of pixels at 480 px), so 500 frames take well under a minute; more would not make a
#: smoother picture.
MAX_FRAMES = 500

#: GIF frames by default (``--frames``): 24 frames at 10 per second show an assembly in
#: about 3 s; 40 (before issue 34) made the GIF most of a run's time for little smoothness.
DEFAULT_FRAMES = 24


#: What each planner's short name means, for picture titles (no paper shorthand).
ALGORITHM_TITLES = {
    "gradient": "gradient flow (all discs at once)",
    "sequential": "sequential (one disc at a time)",
    "control": "damped controller (discs with mass)",
}


def run_title(result: Result) -> str:
    """A picture title that spells out the run, e.g. ``gradient flow (all discs at once),
    navigation exponent k = 96`` or ``sequential (one disc at a time), paper's rule T,
    navigation exponent k = 96``."""
    assert result.trajectory is not None
    meta = result.trajectory.meta
    algorithm = result.planner.removeprefix("assembly.") or "assembly"
    name = ALGORITHM_TITLES.get(algorithm, algorithm)
    rule = ""
    if "rule" in meta:
        rule = ", paper's rule T" if meta["rule"] == "paper" else f", {meta['rule']} rule"
    return f"{name}{rule}, navigation exponent k = {float(meta['k']):g}"


def write_outputs(
    result: Result,
    output: Path,
    frames: int = DEFAULT_FRAMES,
    gif_size: int | None = None,
    pictures: bool = True,
) -> dict[str, Path]:
    """Write the run's files under ``output``; returns them by name.

    ``result`` is a result of one of the assembly planners (its ``solution`` carries the
    problem and the path); ``gif_size`` is the GIF's width in pixels (default
    :data:`cellplan.plots.GIF_SIZE`). ``pictures=False`` writes the trajectory and the
    metrics alone (``cellplan assemble`` without ``--pictures``: drawing costs several
    times the planner, docs/benchmarks.md "Drawing in assemble").
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
    files: dict[str, Path] = {}
    if pictures:
        files["sequence"] = plots.save_sequence(problem, run.path, output / "sequence.png", title)
        files["animation"] = plots.save_animation(
            problem,
            run.path,
            output / "assembly.gif",
            frames,
            title,
            size=gif_size,
            trajectory=traj,
        )
    files["trajectory"] = traj.save(output / "trajectory.csv")
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
