"""The ``discs:`` section on the scenario picture of ``cellplan show``: starts and goals."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cellplan.setup import Setup


def draw_discs(setup: Setup, ax: Any) -> list[Any]:
    """Each disc at its start (hatched outline) and its goal (filled), numbered from 1."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle

    from cellplan.assembly.problems import problem_from_section

    sc = setup.scenario
    problem = problem_from_section(sc.discs, sc)
    boundary = sc.discs.boundary
    handles: list[Any] = []
    if boundary.type == "disc":
        ax.add_patch(Circle(boundary.center, boundary.radius, fill=False, ec="black", lw=1.2))
        handles.append(Line2D([], [], color="black", label="disc workspace boundary"))
    for i, (r, s, g) in enumerate(zip(problem.radii, problem.start, problem.goal, strict=True)):
        ax.add_patch(Circle(g, r, facecolor="#3b6fb6", alpha=0.35, edgecolor="#3b6fb6"))
        ax.add_patch(Circle(s, r, fill=False, edgecolor="#c0392b", lw=1.4, ls="--"))
        ax.annotate(str(i + 1), s, ha="center", va="center", fontsize=7, color="#c0392b")
        ax.annotate(str(i + 1), g, ha="center", va="center", fontsize=7, color="#1f3b73")
    return [
        *handles,
        Line2D([], [], marker="o", ls="none", mfc="none", mec="#c0392b", label="disc at start"),
        Line2D([], [], marker="o", ls="none", color="#3b6fb6", alpha=0.5, label="disc at goal"),
    ]
