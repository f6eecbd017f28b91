"""The strategies package's declaration: its scenario section, planners, experiments, commands.

This is the only place the core learns about the package (see
:data:`cellplan.registry.BUILTIN_PACKAGES`). It imports nothing heavy: planners import
their algorithm modules when they run.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING

from cellplan.budget import NOTICE_SECONDS
from cellplan.core import Fact, Package, PlannerSpec
from cellplan.strategies.planners import (
    StrategiesOptions,
    build_seconds,
    check_memory,
    run_strategies,
)
from cellplan.strategies.section import StrategySection

TITLE = "Optimal motion strategies under a stochastic assembly process"
CITATION = (
    "R. Sharma, S. M. LaValle, S. Hutchinson, “Optimizing Robot Motion Strategies for "
    "Assembly with Stochastic Models of the Assembly Process”, IEEE Transactions on "
    "Robotics and Automation, 1996."
)
SUMMARY = (
    "Section V solves six workcells (translating, rotating and 3-link robots) for the "
    "state-feedback strategy that minimises the expected time parts wait. The paper "
    "reports behaviours rather than numbers: while no request is pending the robot waits "
    "near the sources (P1, P3); it passes a narrow opening when empty and detours when "
    "carrying (P1); it delivers to the nearer component of a split destination (P2); it "
    "turns at once toward a changed destination (P4); it picks the source component that "
    "suits the destination (P6); and anticipation saves about as many stages as the robot "
    "spent idle (Section V-C)."
)

if TYPE_CHECKING:
    from pathlib import Path

    from cellplan.core import ShowcaseItem
    from cellplan.setup import Setup


VALIDATE_BUILD_SECONDS = NOTICE_SECONDS
"""Longest model build (estimated with
:func:`~cellplan.strategies.planners.build_seconds`) that ``cellplan
validate`` runs for its checks: a build long enough to be announced is left to the solve,
with a note. The estimate is cautious (about 9 times the build of strategies_p3 and P6 on
2 cores), so every bundled scenario is built (P6 is estimated at 89 s, built in about
10 s)."""

log = logging.getLogger(__name__)


def describe(setup: Setup) -> Sequence[Fact]:
    """``cellplan validate`` facts; runs the checks ``cellplan solve`` runs before solving.

    Typed values for ``validate --json``: ``assembly_modes`` (int), ``failure_modes`` (int:
    the fine motions that can fail), ``noisy_motion`` (int: landings per move),
    ``strategy_grid`` (list of cells per axis), ``free_live_nr`` (``{"free": float,
    "live": float}``, fractions of the grid).

    Builds the model on the strategy's grid (:func:`~cellplan.strategies.model.mdp.build_model`,
    the same call the planner makes), which refuses a request that can never be served
    (a source or destination no configuration reaches, a part that cannot be carried to
    its destination, a free space split between a destination and a source) and a robot
    start outside the strategy's domain, naming the region, the request or the field.
    A model estimated to take longer than :data:`VALIDATE_BUILD_SECONDS` to build is not
    built: a note says that the solve runs those checks, and only the modes and the grid
    are given.
    """
    import numpy as np

    from cellplan.budget import format_duration
    from cellplan.strategies.model.mdp import build_model, grid_shape
    from cellplan.strategies.model.spec import compiled

    sc, cell = setup.scenario, setup.workcell
    spec = compiled(sc)  # once, for the memory check and the build
    est = check_memory(setup, None, spec=spec)  # before allocating, as the planner does
    build_s = build_seconds(est)
    if build_s > VALIDATE_BUILD_SECONDS:
        # validate answers in seconds: a model that takes minutes to build is checked by
        # the solve, first thing, and the user is told so.
        log.warning(
            "strategy: the checks that build the model (every request can be served, the "
            "robot's start in the strategy's domain) were not run: building it takes about "
            "%s; cellplan solve runs them before it solves",
            format_duration(build_s),
        )
        grid = [int(n) for n in grid_shape(sc, cell, None)]
        return [
            Fact("assembly_modes", "assembly modes", int(est.modes), f"{est.modes}"),
            Fact("strategy_grid", "strategy grid", grid, " x ".join(map(str, grid)) + " cells"),
        ]
    mdp = build_model(spec, cell, start=cell.robot.start)
    shape = " x ".join(str(int(n)) for n in mdp.shape)
    free_nr = float(np.mean(mdp.free[mdp.vcls[0]]))
    live_nr = float(np.mean(mdp.live[0]))
    modes = f"{mdp.n_modes} (Section III-A; {mdp.n_requests} requests)"
    facts: list[Fact] = []
    for variant in mdp.variants:
        modes = variant.modes_line(mdp, sc.strategy) or modes
        facts.extend(Fact(*fact) for fact in variant.facts(mdp))
    facts.insert(0, Fact("assembly_modes", "assembly modes", int(mdp.n_modes), modes))
    facts.append(
        Fact("strategy_grid", "strategy grid", [int(n) for n in mdp.shape], f"{shape} cells")
    )
    facts.append(
        Fact(
            "free_live_nr",
            "free / live (NR)",
            {"free": free_nr, "live": live_nr},
            f"{free_nr:.3f} / {live_nr:.3f} of the grid (live: every request can be served "
            "from there)",
        )
    )
    return facts


def showcase(folder: Path) -> list[ShowcaseItem]:
    """The demo's pictures of this package (Figs. 8 and 9), made through the API."""
    from cellplan.strategies.experiments.showcase import showcase as make

    return make(folder)


STRATEGIES = PlannerSpec(
    name="strategies",
    package="strategies",
    summary="optimal assembly strategy under the stochastic assembly process (Sec. IV), "
    "then a sample run of it",
    options=StrategiesOptions,
    run=run_strategies,
    section="strategy",
    smoke=("strategies_tiny", {}),
)

PACKAGE = Package(
    name="strategies",
    title=TITLE,
    citation=CITATION,
    summary=SUMMARY,
    section="strategy",
    section_model=StrategySection,
    planners=(STRATEGIES,),
    experiments="cellplan.strategies.experiments.paper",
    commands="cellplan.strategies.commands",
    paper_runs=10,
    describe=describe,
    showcase=showcase,
    # A 3-D cell works through the validity interface when its arm has 1 to 3 active
    # joints (the grid's dimension); section.check refuses other arms in one line.
    workcells=("2d", "3d"),
)
