"""cellplan: motion planning for robots in assembly workcells.

The data flow is scenario file -> :class:`cellplan.scenario.Scenario` (validated)
-> :class:`cellplan.workcell.Workcell` (geometry, robot, exact collision checks)
-> :mod:`cellplan.cspace` (configuration-space bitmaps) -> a planner from one of the
paper packages (:mod:`cellplan.strategies`, :mod:`cellplan.adaptive`,
:mod:`cellplan.assembly`) -> simulation, metrics, pictures and report.
"""

from cellplan.errors import CellplanError, Problem, ScenarioError
from cellplan.scenario import Scenario, load_scenario

__all__ = ["CellplanError", "Problem", "Scenario", "ScenarioError", "load_scenario"]
__version__ = "0.1.0"
