"""Pictures of sphere assemblies (3-D): the Fig. 1-2 style moment on matplotlib's 3-D axes.

:func:`plots.draw_configuration` hands a 3-D problem here: the 2-D axes it was given are
replaced by 3-D axes in the same place, so the sequence and the GIF of
:mod:`cellplan.assembly.plots` draw spheres unchanged. Each sphere is a shaded surface in
its colour with its number, its goal a wire sphere, its path so far a line; the axes carry
the workcell's unit.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellplan.assembly.palette import disc_colors
from cellplan.assembly.problems import CircleWorkspace, DiscProblem

Array = NDArray[np.float64]

#: Points per great circle of a drawn sphere (surface and wire frame).
SPHERE_POINTS = 14


def _sphere_mesh(center: Array, radius: float, m: int = SPHERE_POINTS) -> tuple[Array, ...]:
    u = np.linspace(0.0, 2.0 * np.pi, m)
    v = np.linspace(0.0, np.pi, m // 2 + 1)
    x = center[0] + radius * np.outer(np.cos(u), np.sin(v))
    y = center[1] + radius * np.outer(np.sin(u), np.sin(v))
    z = center[2] + radius * np.outer(np.ones_like(u), np.cos(v))
    return x, y, z


def to_3d_axes(ax: Any) -> Any:
    """The 3-D axes that replace the 2-D axes ``ax`` in its place on the figure."""
    fig = ax.figure
    spec = ax.get_subplotspec()
    ax.remove()
    return fig.add_subplot(spec, projection="3d")


def draw_configuration3d(
    ax: Any, problem: DiscProblem, path: Array, upto: int, title: str = "", unit: str = ""
) -> Any:
    """Spheres at ``path[upto]`` (numbered), goals as wire spheres of the same colour and
    number, paths so far as lines.

    ``ax`` is a 2-D axes (replaced, see :func:`to_3d_axes`) or a 3-D one; returns the 3-D
    axes drawn on.
    """
    if getattr(ax, "name", "") != "3d":
        ax = to_3d_axes(ax)
    for i, color in enumerate(disc_colors(problem.n)):
        r = float(problem.radii[i])
        goal = problem.goal[i]
        ax.plot_wireframe(*_sphere_mesh(goal, r), color=color, lw=0.3, alpha=0.5)
        # the goal carries the sphere's number too, in its colour (the sphere's is black)
        ax.text(goal[0], goal[1], goal[2], str(i + 1), fontsize=7, ha="center", color=color)
        ax.plot(
            path[: upto + 1, i, 0],
            path[: upto + 1, i, 1],
            path[: upto + 1, i, 2],
            lw=0.9,
            color=color,
        )
        ax.plot_surface(*_sphere_mesh(path[upto, i], r), color=color, alpha=0.8, linewidth=0)
        c = path[upto, i]
        ax.text(c[0], c[1], c[2] + 1.15 * r, str(i + 1), fontsize=7, ha="center", color="black")
    ws = problem.workspace
    if isinstance(ws, CircleWorkspace):
        lo, hi = ws.center - ws.radius, ws.center + ws.radius
        ax.plot_wireframe(*_sphere_mesh(ws.center, ws.radius, 24), color="grey", lw=0.2, alpha=0.3)
    else:
        lo, hi = ws.lo, ws.hi
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect((1.0, 1.0, 1.0))
    suffix = f" ({unit})" if unit else ""
    ax.set_xlabel(f"x{suffix}", fontsize=7)
    ax.set_ylabel(f"y{suffix}", fontsize=7)
    ax.set_zlabel(f"z{suffix}", fontsize=7)
    ax.tick_params(labelsize=6)
    if title:
        ax.set_title(title, fontsize=10)
    return ax
