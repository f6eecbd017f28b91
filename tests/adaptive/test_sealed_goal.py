"""Issue 35, part 3: a goal sealed off on purpose. Solve's first failure toward it costs
its budget; later queries toward it in the same workcell generation cost a small fraction,
say why, and survive a reopened database; a workcell change asks Solve again."""

from __future__ import annotations

import numpy as np

import cellplan
from cellplan.registry import scenario_path
from cellplan.scenario import load_scenario
from cellplan.workcell import Workcell

GOAL = [8.0, 2.0]
WALLS = {
    "south": {"type": "box", "min": [7.4, 1.4], "max": [8.6, 1.5]},
    "north": {"type": "box", "min": [7.4, 2.5], "max": [8.6, 2.6]},
    "west": {"type": "box", "min": [7.4, 1.4], "max": [7.5, 2.6]},
    "east": {"type": "box", "min": [8.5, 1.4], "max": [8.6, 2.6]},
}


def sealed_planner(db=None) -> cellplan.ExperiencePlanner:
    cell = Workcell.from_scenario(load_scenario(scenario_path("adaptive_fig3")))
    planner = cellplan.ExperiencePlanner(cell, resolution=0.05, db=db)
    planner.settings.max_solve_checks = 8_000
    return planner


def seal(planner: cellplan.ExperiencePlanner) -> None:
    for name, shape in WALLS.items():
        planner.add(name, shape)


def test_a_repeated_failure_toward_a_sealed_goal_costs_under_one_percent(tmp_path):
    db = tmp_path / "sealed.sqlite"
    planner = sealed_planner(db)
    seal(planner)
    first = planner.plan(None, GOAL)
    assert not first.success
    assert first.stats["checks"] >= 8_000
    assert "certified clearance" in first.message and "resolution" in first.message
    for _ in range(3):
        again = planner.plan(None, GOAL)
        assert not again.success
        assert again.stats["checks"] <= 0.01 * first.stats["checks"]
        assert again.stats["solve_calls"] == 0
        assert "remembered" in again.message
    planner.close()
    reopened = sealed_planner(db)
    later = reopened.plan(None, GOAL)
    assert not later.success and later.stats["checks"] <= 0.01 * first.stats["checks"]
    # Opening the seal is a workcell change: Solve is asked again and succeeds.
    reopened.remove("east")
    opened = reopened.plan(None, GOAL)
    assert opened.success, opened.message
    np.testing.assert_allclose(opened.trajectory.q[-1], GOAL)
    reopened.close()


SEALED_RUN = """
cellplan: 1
name: sealed-run
workcell:
  bounds: {xmin: 0, ymin: 0, xmax: 10, ymax: 10}
  obstacles:
    south: {type: box, min: [7.4, 1.4], max: [8.6, 1.5]}
    north: {type: box, min: [7.4, 2.5], max: [8.6, 2.6]}
    west: {type: box, min: [7.4, 1.4], max: [7.5, 2.6]}
    east: {type: box, min: [8.5, 1.4], max: [8.6, 2.6]}
robot: {type: point, start: [1.0, 1.0]}
adaptive:
  resolution: 0.05
  max_solve_checks: 4000
  goals:
    sealed: {at: [8.0, 2.0]}
  tasks: [sealed, sealed, sealed, sealed]
"""


def test_a_continued_adapt_run_remembers_its_failures(tmp_path):
    """Issue 35 part 3 for ``cellplan adapt --db``: the run state keeps S's failures of
    the generation, so the continued run's first task toward the sealed goal is cheap."""
    setup = cellplan.loads(SEALED_RUN)
    db = tmp_path / "run.sqlite"
    first = cellplan.plan(setup, "adaptive", tasks=2, db=str(db))
    rows = first.solution.tasks
    assert [r["success"] for r in rows] == [False, False]
    assert rows[0]["solve_calls"] > 0 and rows[1]["solve_calls"] == 0
    first.solution.close()
    more = cellplan.plan(setup, "adaptive", tasks=4, db=str(db))
    rows = more.solution.tasks
    assert len(rows) == 4
    for row in rows[2:]:
        assert row["solve_calls"] == 0 and "remembered" in row["note"]
        assert row["adapt"] <= 0.01 * rows[0]["adapt"]
    more.solution.close()
