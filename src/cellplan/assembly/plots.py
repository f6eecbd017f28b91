"""Pictures of disc assemblies: Fig. 1-2 style sequences, GIFs, and Section 5 error-bar plots.

matplotlib is imported lazily through :mod:`cellplan.plots`; every file is written
atomically by its helpers.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellplan.assembly.problems import CircleWorkspace, DiscProblem

Array = NDArray[np.float64]


def _moments(path: Array, count: int) -> list[int]:
    """Indices of ``count`` moments evenly spaced in arc length (the first and last included)."""
    seg = np.linalg.norm(np.diff(path, axis=0).reshape(len(path) - 1, path[0].size), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] == 0:
        return [0] * (count - 1) + [len(path) - 1]
    targets = np.linspace(0.0, s[-1], count)
    return [int(min(np.searchsorted(s, t), len(path) - 1)) for t in targets]


def draw_configuration(
    ax: Any, problem: DiscProblem, path: Array, upto: int, title: str = ""
) -> None:
    """Discs at ``path[upto]``, goals as dashed outlines, paths so far as lines (Fig. 1-2)."""
    import matplotlib.patches as mpatches

    ws = problem.workspace
    if isinstance(ws, CircleWorkspace):
        ax.add_patch(mpatches.Circle(tuple(ws.center), ws.radius, fill=False, lw=1.5, color="k"))
        lo, hi = ws.center - ws.radius, ws.center + ws.radius
    else:
        ax.add_patch(
            mpatches.Rectangle(tuple(ws.lo), *(ws.hi - ws.lo), fill=False, lw=1.5, color="k")
        )
        lo, hi = ws.lo, ws.hi
    import matplotlib.pyplot as plt

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
    if title:
        ax.set_title(title, fontsize=10)


def save_sequence(problem: DiscProblem, path: Array, out: str | Path, title: str = "") -> Path:
    """Four moments of an assembly, (i) start to (iv) end, as in the paper's Figs. 1-2."""
    from cellplan.plots import new_figure, save_figure

    fig, axes = new_figure(ncols=4, size=3.2)
    last = len(path) - 1
    for ax, idx, label in zip(
        axes[0], _moments(path, 4), ("(i)", "(ii)", "(iii)", "(iv)"), strict=True
    ):
        draw_configuration(ax, problem, path, idx, f"{label} step {idx} of {last}")
    if title:
        fig.suptitle(f"{title}, {problem.n} discs")
    handles = sequence_legend(problem.n)
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


def sequence_legend(n: int) -> list[Any]:
    """Legend handles for :func:`draw_configuration`: each disc's colour (up to
    :data:`LEGEND_DISCS`), its goal outline, and its path so far."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    cmap = plt.get_cmap("tab10" if n <= 10 else "tab20")
    handles: list[Any] = []
    if n <= LEGEND_DISCS:
        handles += [
            Line2D(
                [],
                [],
                marker="o",
                ls="none",
                ms=8,
                alpha=0.75,
                color=cmap(i % cmap.N),
                label=f"disc {i + 1}",
            )
            for i in range(n)
        ]
    else:
        handles.append(
            Line2D(
                [],
                [],
                marker="o",
                ls="none",
                ms=8,
                alpha=0.75,
                color=cmap(0),
                label=f"discs 1-{n} (one colour each)",
            )
        )
    handles += [
        Patch(fill=False, ls="--", edgecolor="grey", label="goal (dashed outline, disc's colour)"),
        Line2D([], [], color="grey", lw=0.9, label="path so far"),
    ]
    return handles


def save_animation(
    problem: DiscProblem,
    path: Array,
    out: str | Path,
    frames: int = 40,
    title: str = "",
    size: int | None = None,
    times: Array | None = None,
    time_unit: str = "",
) -> Path:
    """An animated GIF of the assembly, frames evenly spaced in arc length.

    ``size`` is the frame width in pixels (default :data:`cellplan.plots.GIF_SIZE`). Every
    frame carries a counter: the time ``times[i]`` of its step (in ``time_unit``) when the
    times are given, the step number otherwise.
    """
    import matplotlib.pyplot as plt

    from cellplan.plots import (
        GIF_SIZE,
        check_gif_size,
        figure_to_rgb,
        frame_counter,
        new_figure,
        save_gif,
    )

    size = check_gif_size(GIF_SIZE if size is None else size, "size")
    last = len(path) - 1

    def images() -> Iterator[Array]:  # drawn one at a time, as save_gif writes them
        for idx in _moments(path, frames):
            fig, axes = new_figure(size=4.8)
            ax = axes[0][0]
            draw_configuration(ax, problem, path, idx, title)
            if times is not None:
                unit = f" {time_unit}" if time_unit else ""
                frame_counter(ax, f"t = {float(times[idx]):.3g}{unit} (step {idx} / {last})")
            else:
                frame_counter(ax, f"step {idx} / {last}")
            rgb = figure_to_rgb(fig, size)
            plt.close(fig)
            yield rgb

    return save_gif(images(), out, fps=10.0)


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
