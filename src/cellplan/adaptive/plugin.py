"""The adaptive package's declaration: its scenario section, planners, experiments, commands.

This is the only place the core learns about the package (see
:data:`cellplan.registry.BUILTIN_PACKAGES`). It imports nothing heavy: planners import
their algorithm modules when they run.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from cellplan.adaptive.planners import (
    AdaptiveOptions,
    PeerOptions,
    run_adaptive_planner,
    run_prm,
    run_rrtconnect,
)
from cellplan.adaptive.section import AdaptiveSection
from cellplan.core import Package, PlannerSpec, ShowcaseItem

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
        ),
    ),
    showcase=_showcase,
    experiments="cellplan.adaptive.experiments",
    commands="cellplan.adaptive.commands",
    paper_runs=100,
)
