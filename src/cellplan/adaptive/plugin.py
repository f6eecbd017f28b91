"""The adaptive package's declaration: its scenario section, planners, experiments, commands.

This is the only place the core learns about the package (see
:data:`cellplan.registry.BUILTIN_PACKAGES`). It imports nothing heavy: planners import
their algorithm modules when they run.
"""

from __future__ import annotations

from cellplan.adaptive.section import AdaptiveSection
from cellplan.core import Package

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

PACKAGE = Package(
    name="adaptive",
    title=TITLE,
    citation=CITATION,
    summary=SUMMARY,
    section="adaptive",
    section_model=AdaptiveSection,
    planners=(),
    experiments="cellplan.adaptive.experiments",
    commands="cellplan.adaptive.commands",
    paper_runs=100,
)
