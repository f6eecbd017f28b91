"""The ``adaptive:`` section on the scenario picture of ``cellplan show``.

Goals are labelled stars at their tool points; scheduled changes are drawn where they
happen: an added object as a dashed outline, a moved object as an arrow, each labelled
with the task after which it happens.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from cellplan.scenario3d import planar_workcell

if TYPE_CHECKING:
    from cellplan.setup import Setup


def draw_adaptive(setup: Setup, ax: Any) -> list[Any]:
    """Draw the goals and the scheduled changes; return legend handles."""
    from matplotlib.lines import Line2D

    from cellplan.plots import draw_geometry

    sec = setup.scenario.adaptive
    obstacles = {
        n: s.to_shapely() for n, s in planar_workcell(setup.scenario).planar_obstacles.items()
    }
    for name, goal in sec.goals.items():
        ax.plot(*goal.at, marker="*", color="#8e44ad", ms=11, mec="black", mew=0.5)
        ax.annotate(
            name,
            goal.at,
            xytext=(4, 4),
            textcoords="offset points",
            fontsize=8,
            color="#5b2c6f",
            weight="bold",
        )
    for _, change in sec.ordered_changes():
        when = f"after task {change.after_task}"
        if change.type == "add_object":
            geom = change.shape.to_shapely()
            obstacles[change.object] = geom
            draw_geometry(ax, geom, facecolor="none", edgecolor="#c0392b", lw=1.5, ls="--")
            p = geom.representative_point()
            ax.annotate(
                f"+{change.object} ({when})",
                (p.x, p.y),
                fontsize=7,
                color="#c0392b",
                ha="center",
                va="center",
            )
        elif change.type == "move_object" and change.object in obstacles:
            p = obstacles[change.object].representative_point()
            ax.annotate(
                "",
                (p.x + change.by[0], p.y + change.by[1]),
                (p.x, p.y),
                arrowprops={"arrowstyle": "->", "color": "#c0392b", "lw": 1.5},
            )
            ax.annotate(
                f"{change.object} moves ({when})",
                (p.x, p.y),
                xytext=(0, -10),
                textcoords="offset points",
                fontsize=7,
                color="#c0392b",
                ha="center",
            )
        elif change.type == "add_goal":
            ax.plot(*change.at, marker="*", color="none", mec="#8e44ad", ms=11)
            ax.annotate(
                f"{change.goal} ({when})",
                change.at,
                xytext=(4, 4),
                textcoords="offset points",
                fontsize=7,
                color="#8e44ad",
            )
    return [
        Line2D([], [], marker="*", ls="none", color="#8e44ad", ms=10, label="goal"),
        Line2D([], [], color="#c0392b", ls="--", label="scheduled change (after task N)"),
    ]
