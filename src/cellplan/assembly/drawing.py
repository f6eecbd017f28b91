"""The ``discs:`` section on the scenario picture of ``cellplan show``: starts and goals.

The convention is that of ``cellplan assemble``'s pictures (:mod:`cellplan.assembly.plots`):
each disc filled where it is (its start), a dashed outline of the same colour where it
must go (its goal), both carrying the disc's number (from 1, as everywhere a user sees a
disc; docs/assembly.md "Disc numbers").
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cellplan.setup import Setup


def draw_discs(setup: Setup, ax: Any) -> list[Any]:
    """Each disc at its start (filled) and its goal (dashed outline, same colour), both
    numbered from 1; returns the legend handles. Spheres (a 3-D cell: ``ax`` is 3-D
    axes) are drawn as ``assemble`` draws them (:mod:`cellplan.assembly.plots3d`)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle, Patch

    from cellplan.assembly.palette import disc_colors
    from cellplan.assembly.problems import problem_from_section

    sc = setup.scenario
    problem = problem_from_section(sc.discs, sc)
    if problem.dim == 3:  # spheres, on the 3-D axes cellplan.drawing gives a 3-D cell
        from cellplan.assembly.plots import UNIT, sequence_legend
        from cellplan.assembly.plots3d import draw_configuration3d

        draw_configuration3d(ax, problem, problem.start[None], 0, "", UNIT)
        return [h for h in sequence_legend(problem.n, 3) if h.get_label() != "path so far"]
    boundary = sc.discs.boundary
    handles: list[Any] = []
    if boundary.type == "disc":
        ax.add_patch(Circle(boundary.center, boundary.radius, fill=False, ec="black", lw=1.2))
        handles.append(Line2D([], [], color="black", label="disc workspace boundary"))
    colors = disc_colors(problem.n)
    for i, (r, s, g) in enumerate(zip(problem.radii, problem.start, problem.goal, strict=True)):
        color = colors[i]
        ax.add_patch(Circle(g, r, fill=False, edgecolor=color, lw=1.2, ls="--"))
        ax.add_patch(Circle(s, r, facecolor=color, alpha=0.8, edgecolor=color))
        ax.annotate(str(i + 1), g, ha="center", va="center", fontsize=7, color=color)
        ax.annotate(
            str(i + 1), s, ha="center", va="center", fontsize=7, color="white", fontweight="bold"
        )
    return [
        *handles,
        Line2D(
            [], [], marker="o", ls="none", color=colors[0], alpha=0.8, label="disc at its start"
        ),
        Patch(fill=False, ls="--", edgecolor="grey", label="its goal (dashed, disc's colour)"),
    ]
