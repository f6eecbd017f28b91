"""Pictures of disc assemblies: Fig. 1-2 style sequences, GIFs, and Section 5 error-bar plots.

matplotlib is imported lazily through :mod:`cellplan.plots`; every file is written
atomically by its helpers.
"""

from __future__ import annotations

import textwrap
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellplan.assembly.palette import disc_colors
from cellplan.assembly.problems import CircleWorkspace, DiscProblem
from cellplan.trajectory import Trajectory

Array = NDArray[np.float64]


UNIT = "workcell units"
"""The unit of a disc problem's coordinates (those of the scenario file), on every axis."""


def _moments(path: Array, count: int) -> list[int]:
    """Indices of ``count`` moments evenly spaced in arc length (the first and last included)."""
    seg = np.linalg.norm(np.diff(path, axis=0).reshape(len(path) - 1, path[0].size), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] == 0:
        return [0] * (count - 1) + [len(path) - 1]
    targets = np.linspace(0.0, s[-1], count)
    return [int(min(np.searchsorted(s, t), len(path) - 1)) for t in targets]


class _Scene:
    """The artists of one 2-D moment, made once and moved by :meth:`show`.

    A GIF of many frames draws one figure whose discs, numbers and path lines are moved
    from frame to frame: building a figure per frame spent most of ``assemble``'s time in
    figure construction, layout and the cycle collector (issue 34,
    docs/benchmarks.md "Drawing time").
    """

    def __init__(self, ax: Any, problem: DiscProblem) -> None:
        import matplotlib.patches as mpatches
        from matplotlib.patches import PathPatch
        from matplotlib.transforms import Affine2D

        self.ax = ax

        ws = problem.workspace
        if isinstance(ws, CircleWorkspace):
            ax.add_patch(
                mpatches.Circle(tuple(ws.center), ws.radius, fill=False, lw=1.5, color="k")
            )
            lo, hi = ws.center - ws.radius, ws.center + ws.radius
        else:
            ax.add_patch(
                mpatches.Rectangle(tuple(ws.lo), *(ws.hi - ws.lo), fill=False, lw=1.5, color="k")
            )
            lo, hi = ws.lo, ws.hi
        self.path: Array = np.zeros((1, problem.n, 2))
        self.lines: list[Any] = []
        self.discs: list[Any] = []
        self.numbers: list[Any] = []
        self.places: list[Any] = []  # each number's translation, data units
        fontsize = 8 if problem.n <= 20 else 6
        for i, color in enumerate(disc_colors(problem.n)):
            r = float(problem.radii[i])
            goal = tuple(problem.goal[i])
            # where the disc must go: a dashed outline in its colour, numbered
            ax.add_patch(mpatches.Circle(goal, r, fill=False, ls="--", lw=1.0, color=color))
            ax.text(*goal, str(i + 1), ha="center", va="center", fontsize=fontsize, color=color)
            (line,) = ax.plot([], [], lw=0.9, color=color)
            disc = mpatches.Circle(goal, r, color=color, alpha=0.8)
            ax.add_patch(disc)
            self.lines.append(line)
            self.discs.append(disc)
            # the number on the disc is a glyph outline moved with it: a path is drawn
            # in well under a millisecond, a text object in several (issue 34)
            number = PathPatch(_glyphs(str(i + 1), 0.8 * r), color="white", lw=0, zorder=3)
            ax.add_patch(number)
            self.numbers.append(number)
            self.places.append(Affine2D())
        ax.set_xlim(lo[0] - 0.5, hi[0] + 0.5)
        ax.set_ylim(lo[1] - 0.5, hi[1] + 0.5)
        ax.set_aspect("equal")
        ax.set_xlabel(f"x ({UNIT})", fontsize=8)
        spec = ax.get_subplotspec()
        if spec is None or spec.is_first_col():  # panels in a row share the left one's
            ax.set_ylabel(f"y ({UNIT})", fontsize=8)
        ax.tick_params(labelsize=7)

    def artists(self) -> list[Any]:
        """The artists :meth:`show` changes, in the order a full draw paints them
        (patches, lines, texts): discs, paths, numbers."""
        return [*self.discs, *self.lines, *self.numbers]

    def show(self, path: Array, upto: int) -> None:
        """Move the discs to ``path[upto]`` and draw each disc's path up to it."""
        for i, (line, disc, number, place) in enumerate(
            zip(self.lines, self.discs, self.numbers, self.places, strict=True)
        ):
            line.set_data(path[: upto + 1, i, 0], path[: upto + 1, i, 1])
            center = (float(path[upto, i, 0]), float(path[upto, i, 1]))
            disc.set_center(center)
            place.clear().translate(*center)
            number.set_transform(place + self.ax.transData)


def _glyphs(text: str, height: float) -> Any:
    """``text`` in bold as a path centred on the origin, ``height`` tall (data units: the
    number grows with its disc)."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.path import Path as MplPath
    from matplotlib.textpath import TextPath

    glyphs = TextPath((0.0, 0.0), text, size=1.0, prop=FontProperties(weight="bold"))
    vertices = np.asarray(glyphs.vertices, dtype=float)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    scale = height / max(float(hi[1] - lo[1]), 1e-9)
    return MplPath((vertices - (lo + hi) / 2.0) * scale, glyphs.codes)


def draw_configuration(
    ax: Any, problem: DiscProblem, path: Array, upto: int, title: str = ""
) -> None:
    """Discs at ``path[upto]`` (filled, numbered), goals as dashed outlines of the same
    colour and number, paths so far as lines (Fig. 1-2); axes in workcell units.

    Spheres (3-D problems) are drawn on 3-D axes put in ``ax``'s place
    (:func:`plots3d.draw_configuration3d`).
    """
    if problem.dim == 3:
        from cellplan.assembly.plots3d import draw_configuration3d

        draw_configuration3d(ax, problem, path, upto, title, UNIT)
        return
    _Scene(ax, problem).show(path, upto)
    if title:
        ax.set_title(title, fontsize=10)


def save_sequence(problem: DiscProblem, path: Array, out: str | Path, title: str = "") -> Path:
    """Four moments of an assembly, (i) start to (iv) end, as in the paper's Figs. 1-2."""
    from cellplan.plots import new_figure, save_figure

    # shared axes: one set of y tick labels instead of four (the layout measures each)
    shared = {} if problem.dim == 3 else {"sharex": True, "sharey": True}
    fig, axes = new_figure(ncols=4, size=3.2, **shared)
    last = len(path) - 1
    for ax, idx, label in zip(
        axes[0], _moments(path, 4), ("(i)", "(ii)", "(iii)", "(iv)"), strict=True
    ):
        draw_configuration(ax, problem, path, idx, f"{label} step {idx} of {last}")
    if title:
        fig.suptitle(f"{title}, {problem.n} {'spheres' if problem.dim == 3 else 'discs'}")
    handles = sequence_legend(problem.n, problem.dim)
    fig.legend(
        handles=handles,
        loc="outside lower center",
        ncols=min(len(handles), 7),
        fontsize=8,
        frameon=False,
    )
    return save_figure(fig, out)


LEGEND_DISCS = 10
"""Discs named one by one in a sequence's legend; more share one entry."""


def sequence_legend(n: int, dim: int = 2) -> list[Any]:
    """Legend handles for :func:`draw_configuration`: each disc's colour (up to
    :data:`LEGEND_DISCS`), its goal outline, and its path so far (``dim`` 3: spheres,
    goals as wire spheres)."""
    body = "sphere" if dim == 3 else "disc"
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    colors = disc_colors(n)
    handles: list[Any] = []
    if n <= LEGEND_DISCS:
        handles += [
            Line2D([], [], marker="o", ls="none", ms=8, alpha=0.8, color=c, label=f"{body} {i + 1}")
            for i, c in enumerate(colors)
        ]
    else:
        handles.append(
            Line2D(
                [],
                [],
                marker="o",
                ls="none",
                ms=8,
                alpha=0.8,
                color=colors[0],
                label=f"{body}s 1-{n} (numbered, one colour each)",
            )
        )
    goal = (
        "goal (wire sphere, sphere's colour)"
        if dim == 3
        else "goal (dashed outline, disc's colour and number)"
    )
    handles += [
        Patch(fill=False, ls="--", edgecolor="grey", label=goal),
        Line2D([], [], color="grey", lw=0.9, label="path so far"),
    ]
    return handles


#: Event kinds that start a new stage of the GIF's counter: a grasp (sequential: one
#: disc picked, moved, released), an escape (k lowered), the place rule's finish and its
#: spreading move.
STAGE_EVENTS = frozenset({"grasp", "escape", "finish", "spread"})


def frame_stages(traj: Trajectory) -> tuple[NDArray[np.int64], int]:
    """The stage (from 1) of every row of ``traj`` and the number of stages.

    A stage starts at row 0 and at every :data:`STAGE_EVENTS` event (several events at
    one row start one stage).
    """
    starts = sorted({0, *(e.index for e in traj.events if e.kind in STAGE_EVENTS)})
    rows = np.arange(len(traj.t))
    return np.searchsorted(np.asarray(starts), rows, side="right").astype(np.int64), len(starts)


def _counter(traj: Trajectory | None, stages: NDArray[np.int64], count: int, idx: int) -> str:
    """A GIF frame's counter: stage (with what moves) and time, then the step."""
    if traj is None:
        return f"step {idx}"
    mode = traj.modes[int(traj.mode[idx])] if len(traj.modes) else "all discs"
    moving = f"{mode} moving" if mode.startswith(("disc", "sphere")) else f"{mode} move"
    t = float(traj.t[idx])
    clock = (
        f"path length {t:.3g} {UNIT}"
        if traj.time_unit == "path"
        else f"t = {t:.3g} {traj.time_unit}"
    )
    return f"stage {int(stages[idx])} / {count}: {moving}\n{clock}"


def save_animation(
    problem: DiscProblem,
    path: Array,
    out: str | Path,
    frames: int = 24,
    title: str = "",
    size: int | None = None,
    trajectory: Trajectory | None = None,
) -> Path:
    """An animated GIF of the assembly, frames evenly spaced in arc length.

    ``size`` is the frame width in pixels (default :data:`cellplan.plots.GIF_SIZE`).
    Every frame carries a counter: the stage (see :func:`frame_stages`) and what moves,
    the time (or path length) of its row in ``trajectory`` when given (rows of
    ``path``), and the step. A 2-D assembly is one figure whose artists move from frame
    to frame (:class:`_Scene`); spheres are drawn afresh on one figure each frame
    (matplotlib cannot move a 3-D surface).
    """
    import matplotlib.pyplot as plt

    from cellplan import plots as core_plots

    size = core_plots.check_gif_size(core_plots.GIF_SIZE if size is None else size, "size")
    last = len(path) - 1
    traj = trajectory if trajectory is not None and len(trajectory.t) == len(path) else None
    stages, count = frame_stages(traj) if traj is not None else (np.ones(len(path), np.int64), 1)
    moments = _moments(path, frames)

    def label(idx: int) -> str:
        head = _counter(traj, stages, count, idx)
        step = f"step {idx} / {last}"
        return f"{head} · {step}" if traj is not None else step

    if problem.dim == 3:

        def images() -> Iterator[NDArray[np.uint8]]:
            for idx in moments:
                fig, axes = core_plots.new_figure(size=4.8)
                draw_configuration(axes[0][0], problem, path, idx, textwrap.fill(title, 60))
                core_plots.frame_counter(fig.axes[0], label(idx))
                rgb = core_plots.figure_to_rgb(fig, size)
                plt.close(fig)
                yield rgb

        return core_plots.save_gif(images(), out, fps=10.0)

    fig, axes = core_plots.new_figure(size=4.8)
    ax = axes[0][0]
    scene = _Scene(ax, problem)
    if title:
        # a spelled-out title is longer than one 4.8-inch frame: wrapped, never cut
        ax.set_title(textwrap.fill(title, 60), fontsize=10)
    core_plots.frame_counter(ax, label(moments[-1]))
    counter = next(t for t in ax.texts if t.get_gid() == "frame-counter")
    moving = [*scene.artists(), counter]
    try:
        return core_plots.save_gif(
            _blitted(fig, ax, moving, size, _frames(scene, counter, path, moments, label)),
            out,
            fps=10.0,
            # one figure, no per-frame garbage: the per-frame collection is not needed
            collect=False,
        )
    finally:
        plt.close(fig)


def _frames(
    scene: _Scene, counter: Any, path: Array, moments: Sequence[int], label: Any
) -> Iterator[str]:
    """Move ``scene`` to each moment in turn; yields the frame's counter text."""
    for idx in moments:
        scene.show(path, idx)
        text = label(idx)
        counter.set_text(text)
        yield text


def _blitted(
    fig: Any, ax: Any, moving: Sequence[Any], width: int, frames: Iterator[str]
) -> Iterator[NDArray[np.uint8]]:
    """RGB frames ``width`` pixels wide of a figure whose ``moving`` artists change.

    The still part (workspace, goals, axes, ticks, title) is drawn once, with the
    figure's layout, and copied under every frame; only the moving artists are drawn
    per frame (matplotlib's blitting). Text drawing dominated the per-frame cost before
    (issue 34). :func:`frame_rgb` sees each frame (the counter texts in tests).
    """
    for artist in moving:
        artist.set_animated(True)  # left out of the full draw: the still background
    fig.set_dpi(width / fig.get_figwidth())
    fig.canvas.draw()
    fig.set_layout_engine("none")  # the first layout holds: moving artists stay inside
    background = fig.canvas.copy_from_bbox(fig.bbox)
    for _text in frames:
        fig.canvas.restore_region(background)
        for artist in moving:
            ax.draw_artist(artist)
        yield frame_rgb(fig)


def frame_rgb(fig: Any) -> NDArray[np.uint8]:
    """The figure's canvas as it stands, as an ``(H, W, 3)`` uint8 array (no redraw)."""
    rgba = np.asarray(fig.canvas.buffer_rgba())
    return np.array(rgba[..., :3])


def save_errorbars(
    series: Sequence[tuple[str, Array, Array, Array]],
    out: str | Path,
    xlabel: str,
    ylabel: str,
    title: str,
    logx: bool = False,
    reference: float | None = None,
    plain_ticks: bool = False,
) -> Path:
    """Mean and standard-deviation bars per series ``(label, x, mean, std)`` (Figs. 3-9)."""
    from cellplan.plots import new_figure, save_figure

    fig, axes = new_figure(size=4.6)
    ax = axes[0][0]
    for offset, (label, x, mean, std) in enumerate(series):
        xs = np.asarray(x, dtype=float)
        shift = (offset - (len(series) - 1) / 2) * 0.01 * (np.ptp(xs) if len(xs) > 1 else 1.0)
        ax.errorbar(
            xs + (0 if logx else shift), mean, yerr=std, marker="o", capsize=3, label=label, lw=1
        )
    if reference is not None:
        ax.axhline(reference, color="grey", ls=":", lw=1)
    if logx:
        ax.set_xscale("log")
    if plain_ticks:
        from matplotlib.ticker import NullFormatter, ScalarFormatter

        ticks = sorted({float(v) for _, x, _, _ in series for v in np.asarray(x)})
        ax.set_xticks(ticks)
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    if len(series) > 1:
        ax.legend(fontsize=8)
    return save_figure(fig, out)
