"""Planners of the strategies package, for the registry (CLI, benchmarks, conformance test)."""

from __future__ import annotations

from cellplan.core import PlannerEntry, PlanResult, Status
from cellplan.scenario import Scenario


def _smoke(method: str, seed: int) -> PlanResult:
    from cellplan.scenario import load_scenario
    from cellplan.strategies.simulate import simulate
    from cellplan.strategies.strategy import solve_scenario
    from cellplan.workcell import Workcell

    sc = with_solver(load_scenario("strategies_tiny"), method)
    cell = Workcell.from_scenario(sc)
    strategy, result = solve_scenario(sc, cell)
    sim = simulate(strategy, 300, seed, start=cell.robot.start)
    stats = {**result.stats(), **{f"sim_{k}": v for k, v in sim.metrics().items() if v == v}}
    status = Status.SOLVED if result.converged else Status.NOT_CONVERGED
    return PlanResult(status, stats, strategy)


def with_solver(sc: Scenario, method: str) -> Scenario:
    """The scenario with its ``strategy.solver.method`` replaced."""
    assert sc.strategy is not None
    solver = sc.strategy.solver.model_copy(update={"method": method})
    return sc.model_copy(update={"strategy": sc.strategy.model_copy(update={"solver": solver})})


def smoke_structured(seed: int) -> PlanResult:
    """Structured average-cost DP on the bundled ``strategies_tiny`` cell (12 x 12), then a
    300-stage simulation."""
    return _smoke("structured", seed)


def smoke_general(seed: int) -> PlanResult:
    """General relative value iteration on the same cell, then a 300-stage simulation."""
    return _smoke("general", seed)


PLANNERS: list[PlannerEntry] = [
    PlannerEntry(
        "strategies.structured",
        "strategies",
        "optimal assembly strategy: layered shortest paths + NR fixed point (Sec. IV)",
        smoke_structured,
    ),
    PlannerEntry(
        "strategies.general",
        "strategies",
        "optimal assembly strategy: relative value iteration over all states (Sec. IV)",
        smoke_general,
    ),
]
