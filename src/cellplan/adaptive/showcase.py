"""The adaptive package's part of the demo report: Chen's Figure 3 through the API.

:func:`showcase` runs the bundled ``adaptive_fig3`` scenario (a point robot inspecting
objects A and B; C appears after task 5, B moves after task 6, C moves away after
task 8) with the ``adaptive`` planner through :func:`cellplan.plan`, and draws the
experience graph G after the first tasks and around each change, as Figure 3 does.
It also asks the resulting :class:`~.experience.ExperiencePlanner` one free query.
:func:`showcase_ur5` plans three goals of ``adaptive_ur5`` (a UR5, 6 joints) with an
``ExperiencePlanner`` and asks the first again, drawing the cell with the arm at the
end of the repeated query and the executed tool path. It prints nothing.
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


CODE_UR5 = """\
import cellplan

planner = cellplan.ExperiencePlanner(cellplan.load("adaptive_ur5"))
for goal in ("a1", "f1", "b2"):
    planner.plan(None, goal)   # Reach through G, else Solve (OMPL RRTConnect)
again = planner.plan(None, "a1")  # a repeated task: through G
print(again.stats["checks"], again.trajectory.q[-1])"""


def showcase(folder: str | Path) -> list[ShowcaseItem]:
    """Figure 3 (planar) and the UR5 item."""
    return [*showcase_fig3(folder), *showcase_ur5(folder)]


def showcase_ur5(folder: str | Path) -> list[ShowcaseItem]:
    """Adapt on a UR5: three goals, then a repeated one, drawn in 3-D under ``folder``."""
    import numpy as np

    from cellplan import api
    from cellplan.adaptive.experience import ExperiencePlanner
    from cellplan.scene3d import cell_scene
    from cellplan.view3d import draw_png
    from cellplan.workcell3d import Workcell3D

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    planner = ExperiencePlanner(api.load("adaptive_ur5"), seed=0)
    first = [planner.plan(None, goal) for goal in ("a1", "f1", "b2")]
    again = planner.plan(None, "a1")
    assert again.trajectory is not None
    path = np.concatenate([r.trajectory.q for r in [*first, again] if r.trajectory is not None])
    cell = planner.world.workcell()
    assert isinstance(cell, Workcell3D)
    figure = out / "adaptive_ur5.png"
    scene = cell_scene(cell, path, title="Adapt on a UR5: the executed paths of four queries")
    draw_png(scene, figure, frame=len(path) - 1, size_px=(900, 700))
    costs = ", ".join(str(int(r.stats["checks"])) for r in first)
    calls = sum(int(r.stats["solve_calls"]) for r in first)
    return [
        ShowcaseItem(
            title="Adapt on a UR5 (adaptive_ur5, 6 joints)",
            figures=[figure],
            caption=(
                f"An ExperiencePlanner on the UR5 cell: goals over bin_a (under its hood), the "
                f"fixture and bin_b cost {costs} collision checks ({calls} "
                f"Solve calls); asking a1 again costs {int(again.stats['checks'])} checks, "
                f"through G (|V| = {len(planner.graph)}). The arm stands at the end of the "
                f"repeated query; the line is the tool path of all four."
            ),
            code=CODE_UR5,
        )
    ]


def showcase_fig3(folder: str | Path) -> list[ShowcaseItem]:
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
