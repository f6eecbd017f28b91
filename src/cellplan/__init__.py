"""cellplan: motion planning for robots in assembly workcells.

The planning API::

    import cellplan

    setup = cellplan.load("strategies_p1")        # validated scenario + workcell
    result = cellplan.plan(setup, "strategies")   # any registered planner
    result.status, result.message, result.stats   # one Result for every planner
    result.trajectory.save("motion.csv")          # the motion, for a controller

:func:`planners` lists every registered planner with its options; :func:`make` builds one
without running it; :func:`draw` draws a scenario (what ``cellplan show`` writes). Each
paper package registers its planners (:mod:`cellplan.strategies`, :mod:`cellplan.adaptive`,
:mod:`cellplan.assembly`). Three conveniences are imported on
first use, so that ``import cellplan`` loads no numba kernel or OMPL:
``cellplan.simulate`` (:func:`cellplan.strategies.sim.simulate.simulate_result`) runs a solved
strategy in the stochastic assembly process, with the run's ``cellplan.SimulationOptions``
(:class:`cellplan.strategies.sim.options.SimulationOptions`), and ``cellplan.ExperiencePlanner``
(:class:`cellplan.adaptive.ExperiencePlanner`) answers start-to-goal queries against an
experience graph.
"""

from typing import TYPE_CHECKING, Any

from cellplan import units
from cellplan.api import Planner, load, loads, make, plan, planners
from cellplan.core import Result, Status
from cellplan.drawing import draw
from cellplan.errors import ArgumentError, CellplanError, PersistenceError, Problem, ScenarioError
from cellplan.scenario import Scenario as Scenario  # not in __all__: built at import
from cellplan.scenario import load_scenario
from cellplan.setup import Setup
from cellplan.trajectory import Event, Trajectory

if TYPE_CHECKING:
    from cellplan.adaptive import ExperiencePlanner as ExperiencePlanner
    from cellplan.strategies.sim.options import SimulationOptions as SimulationOptions
    from cellplan.strategies.sim.simulate import simulate_result

    simulate = simulate_result

__all__ = [
    "ArgumentError",
    "CellplanError",
    "Event",
    "ExperiencePlanner",
    "PersistenceError",
    "Planner",
    "Problem",
    "Result",
    "ScenarioError",
    "Setup",
    "SimulationOptions",
    "Status",
    "Trajectory",
    "draw",
    "load",
    "load_scenario",
    "loads",
    "make",
    "plan",
    "planners",
    "simulate",
    "units",
]
__version__ = "0.1.0"

# Conveniences that live in a package, imported on first use so that ``import cellplan``
# does not load numba kernels or OMPL.
_LAZY = {
    "simulate": ("cellplan.strategies.sim.simulate", "simulate_result"),
    "SimulationOptions": ("cellplan.strategies.sim.options", "SimulationOptions"),
    "ExperiencePlanner": ("cellplan.adaptive", "ExperiencePlanner"),
}


def __dir__() -> list[str]:
    # What the package offers, not the names its own code imports (Any, TYPE_CHECKING).
    return sorted([*__all__, "__version__"])


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        value = getattr(importlib.import_module(module), attr)
        globals()[name] = value  # found directly from now on (PEP 562's usual memo)
        return value
    raise AttributeError(f"module 'cellplan' has no attribute {name!r}")
