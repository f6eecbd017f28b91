"""Planners of the strategies package, for the registry (CLI, benchmarks, conformance test)."""

from __future__ import annotations

from cellplan.core import PlannerEntry, PlanResult, Status

_TINY = """
cellplan: 1
name: strategies-smoke
workcell:
  bounds: {xmin: 0, ymin: 0, xmax: 30, ymax: 30}
  obstacles:
    middle: {type: box, min: [12, 12], max: [18, 16]}
robot:
  type: translating
  shape: {type: box, min: [-1, -1], max: [1, 1]}
  start: [15, 8]
parts:
  P1: {shape: {type: box, min: [-2, -0.5], max: [2, 0.5]}}
sources:
  S1: {components: [{type: box, min: [2, 2], max: [6, 5]}]}
  S2: {components: [{type: box, min: [24, 2], max: [28, 5]}]}
destinations:
  D1: {components: [{type: box, min: [13, 25], max: [17, 28]}]}
strategy:
  speed: 2.5
  arrival: {probability: 0.1}
  fine_motion: {time: 1.5}
  cells: [12, 12]
  actions: {headings: 8}
  solver: {method: METHOD}
"""


def _smoke(method: str, seed: int) -> PlanResult:
    from cellplan.scenario import loads_scenario
    from cellplan.strategies.simulate import simulate
    from cellplan.strategies.strategy import solve_scenario
    from cellplan.workcell import Workcell

    sc = loads_scenario(_TINY.replace("METHOD", method))
    cell = Workcell.from_scenario(sc)
    strategy, result = solve_scenario(sc, cell)
    sim = simulate(strategy, 300, seed, start=cell.robot.start)
    stats = {**result.stats(), **{f"sim_{k}": v for k, v in sim.metrics().items() if v == v}}
    status = Status.SOLVED if result.converged else Status.NOT_CONVERGED
    return PlanResult(status, stats, strategy)


def smoke_structured(seed: int) -> PlanResult:
    """Structured average-cost DP on a 12 x 12 two-source cell, then a 300-stage simulation."""
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
