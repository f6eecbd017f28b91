"""Pictures of disc assemblies: Fig. 1-2 style sequences, GIFs, and Section 5 error-bar plots.

matplotlib is imported lazily through :mod:`cellplan.plots`; every file is written
atomically by its helpers.
"""

from __future__ import annotations

from collections.abc import Sequence
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
    for ax, idx, label in zip(
        axes[0], _moments(path, 4), ("(i)", "(ii)", "(iii)", "(iv)"), strict=True
    ):
        draw_configuration(ax, problem, path, idx, label)
    if title:
        fig.suptitle(title)
    return save_figure(fig, out)


def save_animation(
    problem: DiscProblem, path: Array, out: str | Path, frames: int = 40, title: str = ""
) -> Path:
    """An animated GIF of the assembly, frames evenly spaced in arc length."""
    from cellplan.plots import figure_to_rgb, new_figure, save_gif

    images = []
    for idx in _moments(path, frames):
        fig, axes = new_figure(size=3.6)
        draw_configuration(axes[0][0], problem, path, idx, title)
        images.append(figure_to_rgb(fig, dpi=70))
        import matplotlib.pyplot as plt

        plt.close(fig)
    return save_gif(images, out, fps=10.0)


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
