"""The adaptive package's declaration: its scenario section, planners, experiments, commands.

This is the only place the core learns about the package (see
:data:`cellplan.registry.BUILTIN_PACKAGES`). It imports nothing heavy: planners import
their algorithm modules when they run.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from cellplan.adaptive.drawing import draw_adaptive
from cellplan.adaptive.planners import (
    AdaptiveOptions,
    PeerOptions,
    run_adaptive_planner,
    run_prm,
    run_rrtconnect,
)
from cellplan.adaptive.section import AdaptiveSection
from cellplan.core import Fact, Package, PlannerSpec, ShowcaseItem

if TYPE_CHECKING:
    from cellplan.setup import Setup

TITLE = "Adaptive experience-graph planning in changing workcells"
CITATION = (
    "P. C. Chen, “Adaptive Path Planning for Flexible Manufacturing”, Sandia National "
    "Laboratories, 1994."
)
SUMMARY = (
    "Section 4 runs Adapt on a planar 2-link (SCARA-like) workcell with 5 obstacles and 9 "
    "goals, adding an obstacle and a goal after task 40, and plots the ratio of cumulative "
    "planning cost (distance evaluations) of Adapt to Solve alone, averaged over 100 runs "
    "(Fig. 5): 2.5 at task 1, 1.0 at task 16, 0.67 by task 40; after the change the "
    "on-demand repair A3 is best, then A1, then A0, while A2 jumps and then approaches A3."
)


def describe(setup: Setup) -> Sequence[Fact]:
    """``cellplan validate`` facts; runs the check every adaptive run starts with.

    Every goal must have an inverse-kinematics solution and be free at every stage of
    the change schedule (:func:`~cellplan.adaptive.world.preflight`). Values are typed
    for ``validate --json``: the goals' names, the task count with how they are chosen,
    the number of changes, and the repair, Solve and Reach settings by name.
    """
    from cellplan.adaptive.runner import listed_count, settings_for
    from cellplan.adaptive.section import RandomTasks
    from cellplan.adaptive.world import preflight

    sc = setup.scenario
    sec: AdaptiveSection = setup.section("adaptive")
    settings = settings_for(sc, None, None)
    preflight(sc, settings.resolution, settings.seed)
    random = isinstance(sec.tasks, RandomTasks)
    seed = sec.tasks.seed if isinstance(sec.tasks, RandomTasks) else None
    kind = f"random, seed {seed}" if random else "listed"
    goals = sorted(sec.goals)
    count = listed_count(sec)  # preflight ran task_count's time check (and notice) once
    return [
        Fact("adaptive_goals", "adaptive goals", goals, f"{len(goals)} ({', '.join(goals)})"),
        Fact(
            "adaptive_tasks",
            "adaptive tasks",
            {"count": count, "random": random, "seed": seed},
            f"{count} ({kind})",
        ),
        Fact("workcell_changes", "workcell changes", len(sec.changes), str(len(sec.changes))),
        Fact(
            "repair_solve_reach",
            "repair / Solve / Reach",
            {"repair": sec.repair, "solve": sec.solve, "reach": sec.reach},
            f"{sec.repair} / {sec.solve} / {sec.reach}",
        ),
    ]


def _showcase(folder: Any) -> Sequence[ShowcaseItem]:
    from cellplan.adaptive.showcase import showcase

    return showcase(folder)


PACKAGE = Package(
    name="adaptive",
    title=TITLE,
    citation=CITATION,
    summary=SUMMARY,
    section="adaptive",
    section_model=AdaptiveSection,
    planners=(
        PlannerSpec(
            name="adaptive",
            package="adaptive",
            summary="Adapt: experience graph with Reach, Solve (OMPL) and repair A0-A3 over "
            "the scenario's tasks (Chen 1994)",
            options=AdaptiveOptions,
            run=run_adaptive_planner,
            section="adaptive",
            smoke=("adaptive_fig4", {"tasks": 6, "seed": 0}),
        ),
        PlannerSpec(
            name="adaptive.rrtconnect",
            package="adaptive",
            summary="Solve only: OMPL RRTConnect from scratch on every task",
            options=PeerOptions,
            run=run_rrtconnect,
            section="adaptive",
            smoke=("adaptive_fig4", {"tasks": 3, "seed": 0}),
        ),
        PlannerSpec(
            name="adaptive.prm",
            package="adaptive",
            summary="OMPL PRM with its roadmap kept across tasks (rebuilt after a change)",
            options=PeerOptions,
            run=run_prm,
            section="adaptive",
            smoke=("adaptive_fig4", {"tasks": 3, "seed": 0}),
            deterministic=False,  # OMPL's PRM: roadmap growth depends on thread timing
        ),
    ),
    describe=describe,
    showcase=_showcase,
    draw=draw_adaptive,
    experiments="cellplan.adaptive.experiments",
    commands="cellplan.adaptive.commands",
    paper_runs=100,
    workcells=("2d", "3d"),
)
