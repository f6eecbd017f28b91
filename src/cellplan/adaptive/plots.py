"""Pictures of the adaptive package: G over the workcell, snapshots, the ratio curve (Figure 5).

matplotlib is imported lazily through :mod:`cellplan.plots`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cellplan import plots as shared
from cellplan.adaptive.graph import FREE, UNKNOWN, ExperienceGraph
from cellplan.adaptive.runner import Snapshot
from cellplan.workcell import Workcell

STRATEGY_COLORS = {
    "A0": "#7f7f7f",
    "A1": "#1f77b4",
    "A2": "#ff7f0e",
    "A3": "#d62728",
    "rrtconnect": "#2ca02c",
    "prm": "#9467bd",
}


def _tool_trace(cell: Workcell, qa: np.ndarray, qb: np.ndarray, samples: int = 16) -> np.ndarray:
    # the robot's difference: periodic joints go the short way round, as Reach does
    t = np.linspace(0.0, 1.0, samples)[:, None]
    return cell.robot.tool_pose(cell.robot.wrap(qa + t * cell.robot.difference(qa, qb)))[:, :2]


CURVE_LABELS = {
    "A0": "A0: forget G after a change",
    "A1": "A1: verify every edge after a change",
    "A2": "A2: repair G actively",
    "A3": "A3: repair G on demand",
    "rrtconnect": "Solve alone (RRTConnect from scratch)",
    "prm": "PRM, roadmap kept",
}
"""Legend text of each curve of :func:`save_ratio_curves` (the paper's shorthand spelt out)."""

COST_PARTS = {
    "reach": "reach: R searching G with Reach",
    "trace": "trace: T verifying G's edges",
    "solve": "solve: Solve, the global planner",
    "abstract": "abstract: Abstract cutting Solve's path",
    "cut": "cut: corner cutting (Sec. 2.6)",
    "repair": "repair: Repair of G after a change",
}

GRAPH_COLOR = "#1f4e9c"
GOAL_COLOR = "#c0392b"


def graph_legend(arm: bool = False) -> list[Any]:
    """Legend handles for :func:`draw_graph`: what each colour, dash and marker means."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [
        Line2D([], [], color=GRAPH_COLOR, lw=1.0, label="edge of G, known free"),
        Line2D([], [], color=GRAPH_COLOR, lw=1.0, ls="--", label="edge of G, not yet checked"),
        Line2D(
            [],
            [],
            marker="o",
            ls="none",
            color=GRAPH_COLOR,
            ms=4,
            label="subgoal attached to an object",
        ),
        Line2D(
            [],
            [],
            marker="s",
            ls="none",
            color=GRAPH_COLOR,
            mfc="white",
            ms=4,
            label="subgoal fixed in the world",
        ),
        Line2D([], [], marker="*", ls="none", color=GOAL_COLOR, ms=9, label="goal (named)"),
        Line2D([], [], color=GOAL_COLOR, lw=0.8, alpha=0.6, label="path of the last task"),
        Patch(color=shared.COLORS["obstacle"], label="obstacle"),
    ]
    if arm:
        handles.append(Patch(color=shared.COLORS["robot"], alpha=0.35, label="arm at its position"))
    return handles


def draw_graph(ax: Any, snap: Snapshot, title: str = "") -> None:
    """G over the workcell: vertices at the tool point, edges as the tool's trace along them."""
    cell = snap.cell
    shared.draw_workcell(ax, cell)
    g: ExperienceGraph = snap.graph
    for (a, b), e in g.edges.items():
        if e.status not in (FREE, UNKNOWN):
            continue
        xy = _tool_trace(cell, g.vertices[a].q, g.vertices[b].q)
        ax.plot(
            xy[:, 0],
            xy[:, 1],
            "-" if e.status == FREE else "--",
            color=GRAPH_COLOR,
            lw=1.0,
            alpha=0.8,
        )
    if len(g):
        ids, Q = g.arrays()
        xy = cell.robot.tool_pose(Q)[:, :2]
        attached = np.array([g.vertices[i].obj is not None for i in ids])
        ax.plot(
            xy[attached, 0],
            xy[attached, 1],
            "o",
            color=GRAPH_COLOR,
            ms=4,
            label="subgoal (attached)",
        )
        ax.plot(
            xy[~attached, 0],
            xy[~attached, 1],
            "s",
            color=GRAPH_COLOR,
            mfc="white",
            ms=4,
            label="subgoal (world)",
        )
    for name, (x, y) in snap.goals.items():
        ax.plot(x, y, "*", color=GOAL_COLOR, ms=9)
        ax.annotate(
            name, (x, y), xytext=(3, 3), textcoords="offset points", fontsize=7, color=GOAL_COLOR
        )
    if snap.path is not None and len(snap.path) > 1:
        dense = np.concatenate(
            [_tool_trace(cell, a, b, 8) for a, b in zip(snap.path[:-1], snap.path[1:], strict=True)]
        )
        ax.plot(dense[:, 0], dense[:, 1], color=GOAL_COLOR, lw=0.8, alpha=0.6)
    if cell.robot.kind == "arm":
        shared.draw_robot(ax, cell, snap.u, alpha=0.35)
    ax.set_xlabel("x (workcell units)", fontsize=8)
    ax.set_ylabel("y (workcell units)", fontsize=8)
    ax.set_title(
        title or (f"after task {snap.task}: {len(g)} subgoals, {len(g.usable_edges())} edges in G"),
        fontsize=9,
    )


def save_snapshots(snaps: Sequence[Snapshot], path: str | Path, ncols: int = 4) -> Path:
    """A grid of G snapshots (Figure 3 style), with one legend for the whole grid below it."""
    n = max(1, len(snaps))
    ncols = min(ncols, n)
    nrows = (n + ncols - 1) // ncols
    fig, axes = shared.new_figure(ncols=ncols, nrows=nrows, size=3.6)
    for k, ax in enumerate(axes.flat):
        if k < len(snaps):
            draw_graph(ax, snaps[k])
        else:
            ax.axis("off")
    arm = bool(snaps) and snaps[0].cell.robot.kind == "arm"
    fig.legend(
        handles=graph_legend(arm),
        loc="outside lower center",
        ncols=min(4, max(2, 2 * ncols)),
        fontsize=8,
        frameon=False,
    )
    return shared.save_figure(fig, path)


def save_ratio_curves(
    curves: Mapping[str, np.ndarray],
    path: str | Path,
    change_after: Sequence[int] = (),
    title: str = "Collision checks so far: Adapt's divided by Solve alone's",
) -> Path:
    """Figure 5: cumulative-cost ratio against task number, one curve per strategy.

    Curves are named by :data:`CURVE_LABELS` (A0-A3 spelt out); the ratio is of counts of
    collision checks, so it has no unit. The axis is logarithmic: a ratio and its
    inverse lie equally far from 1 (nothing is stacked on it).
    """
    fig, axes = shared.new_figure(size=5.0)
    ax = axes[0, 0]
    for name, ratio in curves.items():
        tasks = np.arange(1, len(ratio) + 1)
        ax.plot(
            tasks,
            ratio,
            label=CURVE_LABELS.get(name, name),
            color=STRATEGY_COLORS.get(name),
            lw=1.6,
        )
    last = max((len(r) for r in curves.values()), default=0)
    shown = [t for t in change_after if t < last]  # a change after the last task is not seen
    for k, t in enumerate(shown):
        label = "workcell change" if k == 0 else None
        ax.axvline(t + 0.5, color="black", ls=":", lw=1, label=label)
    ax.axhline(1.0, color="gray", lw=0.8, label="equal cost (ratio 1)")
    ax.set_xlabel("task number")
    ax.set_ylabel("cumulative collision checks, Adapt / Solve alone (no unit)")
    ax.set_yscale("log")
    # plain numbers (0.5, 2) on the ratio axis, not powers of ten
    from matplotlib.ticker import MaxNLocator, ScalarFormatter

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # tasks are whole numbers

    ax.yaxis.set_major_formatter(ScalarFormatter())
    ax.yaxis.set_minor_formatter(ScalarFormatter())
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8)
    return shared.save_figure(fig, path)


def save_cost_split(rows: Sequence[Mapping[str, Any]], path: str | Path) -> Path:
    """Per-task collision checks: Adapt's split by phase (stacked) beside Solve alone's.

    A linear axis (issue 34): on a logarithmic one, stacked bars show each part's share
    wrongly. Each task has two bars side by side: Adapt's checks stacked by the phase that
    made them (:data:`COST_PARTS`), and the Solve-only run's (black).
    """
    fig, axes = shared.new_figure(size=5.0)
    # wider with more tasks, so that two bars per task stay visible
    fig.set_size_inches(min(16.0, max(6.0, 3.0 + 0.13 * len(rows))), 5.0)
    ax = axes[0, 0]
    tasks = np.array([int(r["task"]) for r in rows])
    bottom = np.zeros(len(rows))
    for key in COST_PARTS:
        vals = np.array([float(r[key]) for r in rows])
        ax.bar(tasks - 0.2, vals, bottom=bottom, label=key, width=0.4)
        bottom += vals
    ax.bar(
        tasks + 0.2,
        [float(r["baseline"]) for r in rows],
        width=0.4,
        color="black",
        label="Solve only",
    )
    ax.set_xlabel("task number (left bar: Adapt by phase; right bar: Solve alone)")
    ax.set_ylabel("collision checks (configurations tested)")
    ax.set_title(
        "Collision checks per task\n" + "; ".join(COST_PARTS.values()),
        fontsize=7,
        wrap=True,
    )
    # Outside the axes: inside, it covered the bars of the last tasks.
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return shared.save_figure(fig, path)
