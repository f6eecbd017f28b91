"""The adaptive package's part of the demo report: Chen's Figure 3 through the API.

:func:`showcase` runs the bundled ``adaptive_fig3`` scenario (a point robot inspecting
objects A and B; C appears after task 5, B moves after task 6, C moves away after
task 8) with the ``adaptive`` planner through :func:`cellplan.plan`, and draws the
experience graph G after the first tasks and around each change, as Figure 3 does.
It also asks the resulting :class:`~.experience.ExperiencePlanner` one free query. It
prints nothing.
"""

from __future__ import annotations

from pathlib import Path

from cellplan.core import ShowcaseItem

SCENARIO = "adaptive_fig3"

CODE = """\
import cellplan
from cellplan.adaptive.plots import save_snapshots

result = cellplan.plan(cellplan.load("adaptive_fig3"), "adaptive")
planner = result.solution  # the ExperiencePlanner the task list drove
save_snapshots(planner.snapshots, "snapshots.png")
answer = planner.plan([1.5, 2.5], "w2")  # a new query, through G"""


def showcase(folder: str | Path) -> list[ShowcaseItem]:
    """G of Figure 3 growing and being repaired, with a picture under ``folder``."""
    from cellplan import api
    from cellplan.adaptive.plots import save_snapshots

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    result = api.plan(api.load(SCENARIO), "adaptive")
    planner = result.solution
    figure = save_snapshots(planner.snapshots, out / "adaptive_fig3_snapshots.png")
    query = planner.plan([1.5, 2.5], "w2")
    return [
        ShowcaseItem(
            title="Experience graph of Chen's Figure 3 (adaptive_fig3)",
            figures=[figure],
            caption=(
                f"G after each task (squares: world subgoals, dots: subgoals attached to "
                f"an object; red: the executed path). The first goals need Solve, later "
                f"ones go through G; C (added after task 5) breaks an edge that T repairs "
                f"on demand (A3), and the subgoals attached to B move with it after task 6. "
                f"{result.status.value}: {result.message}. A later query from (1.5, 2.5) to w2 "
                f"costs {int(query.stats['checks'])} collision checks "
                f"({query.status.value})."
            ),
            code=CODE,
        )
    ]
