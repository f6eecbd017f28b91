"""Benchmark: where the time of ``cellplan assemble`` goes, drawing against planning (issue 34).

Run: ``.venv/bin/python benchmarks/bench_drawing.py`` (``--quick``: the bundled
``discs_seven`` alone). For each problem (the bundled ``discs_seven``, and the 15 discs
of ``cellplan assemble --random 15 --seed 1``) it plans once with ``assembly.gradient``
and then, in the same process on the same path, writes:

- the GIF the old way (the baseline, kept here): a new figure per frame, drawn whole,
  and the GIF writer's full garbage collection after every frame;
- the GIF the new way (:func:`cellplan.assembly.plots.save_animation`): one figure,
  the still part drawn once and the moving discs blitted on it, no per-frame collection;
- ``sequence.png`` (the same code before and after) and ``trajectory.csv``.

It prints seconds for each and the ratio of drawing (sequence + GIF) to planning, old and
new, and the machine's load before and after. Old and new at 40 frames (the CLI's
default before issue 34), the new also at its default of 24; 640 px (the default width).
"""

from __future__ import annotations

import argparse
import gc
import os
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from cellplan import api
from cellplan.assembly import plots
from cellplan.assembly.problems import CircleWorkspace, DiscProblem, random_setup
from cellplan.assembly.run import DEFAULT_FRAMES, run_title

FRAMES = 40
WIDTH = 640


def _old_configuration(ax, problem: DiscProblem, path: np.ndarray, upto: int, title: str) -> None:
    """The baseline's frame: every artist built afresh (the code before issue 34)."""
    import matplotlib.patches as mpatches
    import matplotlib.pyplot as plt

    ws = problem.workspace
    if isinstance(ws, CircleWorkspace):
        ax.add_patch(mpatches.Circle(tuple(ws.center), ws.radius, fill=False, lw=1.5, color="k"))
        lo, hi = ws.center - ws.radius, ws.center + ws.radius
    else:
        ax.add_patch(
            mpatches.Rectangle(tuple(ws.lo), *(ws.hi - ws.lo), fill=False, lw=1.5, color="k")
        )
        lo, hi = ws.lo, ws.hi
    cmap = plt.get_cmap("tab10" if problem.n <= 10 else "tab20")
    for i in range(problem.n):
        color = cmap(i % cmap.N)
        ax.add_patch(
            mpatches.Circle(
                tuple(problem.goal[i]), problem.radii[i], fill=False, ls="--", lw=0.8, color=color
            )
        )
        ax.plot(path[: upto + 1, i, 0], path[: upto + 1, i, 1], lw=0.9, color=color)
        ax.add_patch(
            mpatches.Circle(tuple(path[upto, i]), problem.radii[i], color=color, alpha=0.75)
        )
    ax.set_xlim(lo[0] - 0.5, hi[0] + 0.5)
    ax.set_ylim(lo[1] - 0.5, hi[1] + 0.5)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(title, fontsize=10)


def old_animation(problem: DiscProblem, path: np.ndarray, out: Path, title: str) -> Path:
    """The GIF as ``assemble`` wrote it before issue 34: one new figure per frame."""
    import matplotlib.pyplot as plt

    from cellplan.plots import figure_to_rgb, frame_counter, new_figure, save_gif

    last = len(path) - 1

    def images() -> Iterator[np.ndarray]:
        for idx in plots._moments(path, FRAMES):
            fig, axes = new_figure(size=4.8)
            _old_configuration(axes[0][0], problem, path, idx, title)
            frame_counter(axes[0][0], f"step {idx} / {last}")
            rgb = figure_to_rgb(fig, WIDTH)
            plt.close(fig)
            yield rgb

    return save_gif(images(), out, fps=10.0)  # collect=True: the writer's old default


def _timed(fn, *args, **kw) -> float:
    gc.collect()
    t0 = time.perf_counter()
    fn(*args, **kw)
    return time.perf_counter() - t0


def bench(name: str, setup, folder: Path) -> None:
    t0 = time.perf_counter()
    result = api.plan(setup, "assembly.gradient")
    plan_s = time.perf_counter() - t0
    run, traj = result.solution, result.trajectory
    problem, path = run.problem, run.path
    title = run_title(result)
    seq_s = _timed(plots.save_sequence, problem, path, folder / "sequence.png", title)
    old_s = _timed(old_animation, problem, path, folder / "old.gif", title)
    new_s, default_s = (
        _timed(
            plots.save_animation,
            problem,
            path,
            folder / "new.gif",
            frames,
            title,
            size=WIDTH,
            trajectory=traj,
        )
        for frames in (FRAMES, DEFAULT_FRAMES)
    )
    csv_s = _timed(traj.save, folder / "trajectory.csv")
    print(f"\n{name}: {problem.n} discs, {len(path)} rows, status {result.status.value}")
    print(f"  planner (api.plan)            {plan_s:7.2f} s")
    print(f"  sequence.png                  {seq_s:7.2f} s")
    print(f"  GIF old (figure per frame)    {old_s:7.2f} s")
    print(f"  GIF new (one figure, blitted) {new_s:7.2f} s   old/new {old_s / new_s:.1f}x")
    print(f"  GIF new, {DEFAULT_FRAMES} frames (default)  {default_s:7.2f} s")
    print(f"  trajectory.csv                {csv_s:7.2f} s")
    old_ratio, new_ratio = (seq_s + old_s) / plan_s, (seq_s + new_s) / plan_s
    print(
        f"  drawing / planning: old {old_ratio:.2f}, new {new_ratio:.2f} ({FRAMES} frames), "
        f"{(seq_s + default_s) / plan_s:.2f} ({DEFAULT_FRAMES} frames)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="discs_seven alone")
    args = parser.parse_args()
    print("load before:", " ".join(f"{v:.2f}" for v in os.getloadavg()))
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        # warm: numba kernels and matplotlib's fonts, so neither is charged to a side
        bench("warm-up discs_swap", api.load("discs_swap"), folder)
        bench("discs_seven", api.load("discs_seven"), folder)
        if not args.quick:
            bench(
                "--random 15 --seed 1",
                random_setup(15, 1, None, None, False, None, 2, None),
                folder,
            )
    print("\nload after:", " ".join(f"{v:.2f}" for v in os.getloadavg()))


if __name__ == "__main__":
    main()
